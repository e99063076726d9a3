"""Real parts sliced by PrusaSlicer, simulated both ways: the valve shut and opened
standing still (`--valve simple`) against AutoMaker's closes on the move and refilling
opens. The deposition model's figures must show the difference: no standing close in
the print body, blobs per path end and starved millimetres per open each at least ten
times smaller, and the slicer's volume on the plate."""

import json
import math
import os
import shutil
import subprocess
from pathlib import Path

import pytest
from click.testing import CliRunner

from robox.cli import cli

AREA = math.pi * 1.75 * 1.75 / 4


def _install_prusa_slicer() -> str | None:
    """PrusaSlicer's command, installed from Debian's packages where it is missing and
    this is root on a machine with apt (as CI's is)."""
    found = shutil.which("prusa-slicer")
    if found or os.geteuid() != 0 or shutil.which("apt-get") is None:
        return found
    env = dict(os.environ, DEBIAN_FRONTEND="noninteractive")
    for command in (["apt-get", "update", "-qq"],
                    ["apt-get", "install", "-y", "-qq", "prusa-slicer"]):
        if subprocess.run(command, env=env, capture_output=True, timeout=900).returncode:
            return None
    return shutil.which("prusa-slicer")


@pytest.fixture(scope="module")
def prusa_slicer():
    command = _install_prusa_slicer()
    if command is None:
        pytest.skip("PrusaSlicer is not installed and could not be (apt-get install "
                    "prusa-slicer needs root and Debian's packages)")
    return command


def _facets(triangles) -> str:
    out = ["solid part"]
    for tri in triangles:
        out.append("facet normal 0 0 0\nouter loop")
        out += [f"vertex {x:.5f} {y:.5f} {z:.5f}" for x, y, z in tri]
        out.append("endloop\nendfacet")
    return "\n".join([*out, "endsolid part\n"])


def _box(x0, y0, x1, y1, h):
    v = [(x, y, z) for x in (x0, x1) for y in (y0, y1) for z in (0.0, h)]
    faces = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    return [t for a, b, c, d in faces for t in ((v[a], v[b], v[c]), (v[a], v[c], v[d]))]


def _ring(cx, cy, r_in, r_out, h, n=36):
    tris = []

    def p(r, a, z):
        return (cx + r * math.cos(a), cy + r * math.sin(a), z)

    for i in range(n):
        a0, a1 = 2 * math.pi * i / n, 2 * math.pi * (i + 1) / n
        o = [p(r_out, a0, 0), p(r_out, a1, 0), p(r_out, a1, h), p(r_out, a0, h)]
        tris += [(o[0], o[1], o[2]), (o[0], o[2], o[3])]
        if r_in > 0:
            q = [p(r_in, a0, 0), p(r_in, a1, 0), p(r_in, a1, h), p(r_in, a0, h)]
            tris += [(q[0], q[2], q[1]), (q[0], q[3], q[2])]
        for z, up in ((0.0, False), (h, True)):
            if r_in > 0:
                c = [p(r_out, a0, z), p(r_out, a1, z), p(r_in, a1, z), p(r_in, a0, z)]
                t = [(c[0], c[1], c[2]), (c[0], c[2], c[3])]
            else:
                centre = (cx, cy, z)
                t = [(centre, p(r_out, a0, z), p(r_out, a1, z))]
            tris += t if up else [(a, c_, b) for a, b, c_ in t]
    return tris


PARTS = {
    "cube": lambda: _box(0, 0, 10, 10, 3.0),
    "tube": lambda: _ring(0, 0, 3.5, 4.5, 3.0),
    "pins": lambda: [t for i in range(3) for j in range(3)
                     for t in _ring(6.0 * i, 6.0 * j, 0.0, 1.2, 3.0, 16)],
}


def _slice(prusa: str, tmp_path: Path, name: str) -> Path:
    stl = tmp_path / f"{name}.stl"
    stl.write_text(_facets(PARTS[name]()))
    out = tmp_path / f"{name}.gcode"
    subprocess.run([prusa, "--export-gcode", str(stl), "--output", str(out),
                    "--layer-height", "0.2", "--nozzle-diameter", "0.4",
                    "--filament-diameter", "1.75", "--temperature", "210",
                    "--bed-temperature", "60", "--center", "105,75"],
                   check=True, capture_output=True, timeout=300)
    return out


def _simulate(gcode: Path, *options: str) -> dict:
    result = CliRunner().invoke(cli, ["simulate", str(gcode), "--json", *options])
    assert result.exit_code == 0, result.output
    return json.loads(result.stdout)


@pytest.mark.parametrize("part", sorted(PARTS))
def test_automakers_valve_against_the_standing_one(prusa_slicer, tmp_path, part):
    gcode = _slice(prusa_slicer, tmp_path, part)
    stated = float(gcode.read_text().split("; filament used [mm] = ")[1].split()[0]) * AREA
    simple = _simulate(gcode, "--valve", "simple")
    automaker = _simulate(gcode)
    s, a = simple["deposition"], automaker["deposition"]
    assert a["path_ends"] == s["path_ends"] > 0
    # no close standing still in the print: every one is a ramp on the move
    valve = automaker["translation"]["valve"]
    assert valve["standing_closes"] == 0 and valve["closes_on_move"] >= a["path_ends"]
    assert a["blobs"] == 0 or s["blob_mm3_per_path_end"] >= 10 * a["blob_mm3_per_path_end"]
    assert s["blob_mm3_per_path_end"] >= 0.25  # a stroke's worth left at each end
    assert s["starved_mm_per_open"] >= 10 * a["starved_mm_per_open"]
    assert s["starved_mm_per_open"] > 0.2  # each standing open's void starves its path
    # the slicer's plastic is what lands on the plate (the purge is in neither)
    assert a["deposited_mm3"] == pytest.approx(stated, rel=0.005)
    assert automaker["completed"] and automaker["errors"] == []


def test_plot_draws_a_layer_and_refuses_one_it_does_not_have(prusa_slicer, tmp_path):
    gcode = _slice(prusa_slicer, tmp_path, "tube")
    picture = tmp_path / "layer.png"
    runner = CliRunner()
    result = runner.invoke(cli, ["simulate", str(gcode), "--plot", str(picture),
                                 "--layer", "3"])
    assert result.exit_code == 0, result.output
    assert "plot: layer 3 drawn in" in result.output
    data = picture.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 20_000
    bad = runner.invoke(cli, ["simulate", str(gcode), "--plot", str(tmp_path / "x.png"),
                              "--layer", "999"])
    assert bad.exit_code == 2 and "layer 999" in bad.output
    assert not (tmp_path / "x.png").exists()
    wrong = runner.invoke(cli, ["simulate", str(gcode), "--plot", str(tmp_path / "x.jpg")])
    assert wrong.exit_code == 2 and "PNG" in wrong.output
