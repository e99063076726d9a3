"""robox-cli simulate: a job printed offline on a fresh virtual printer, and its report."""

import json
import math
import re
import shutil
from pathlib import Path

import pytest
from click.testing import CliRunner

from robox.cli import cli
from robox.gcode import code_part, split_lines, words
from tests.gcode.test_translate import slice_small
from tests.installed import EXAMPLE

AREA = math.pi * 1.75 ** 2 / 4


def simulate(*args):
    result = CliRunner().invoke(cli, ["simulate", *map(str, args)])
    assert "Traceback" not in result.output
    return result


def report(*args, status=0):
    result = simulate(*args, "--json")
    assert result.exit_code == status, result.output
    return json.loads(result.stdout)


def e_sum(path: Path) -> float:
    """The E words of a Robox job, added up (mm3)."""
    total = 0.0
    for raw in split_lines([path.read_bytes()]):
        line = code_part(raw)
        if line:
            _, args = words(line)
            total += float(args.get("E", 0) or 0)
    return total


def job(tmp_path, text: str, name="job.gcode") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def test_the_example_prints_to_its_end_with_nothing_to_warn_of():
    data = report(EXAMPLE)
    assert data["completed"] and data["errors"] == [] and data["warnings"] == []
    assert data["translation"] is None  # a Robox job: run as it is
    lines = sum(1 for raw in split_lines([EXAMPLE.read_bytes()]) if code_part(raw))
    assert data["lines"] == data["lines_run"] == lines
    assert data["extruders"]["E"]["mm3"] == pytest.approx(e_sum(EXAMPLE), abs=0.05)
    assert data["extruders"]["E"]["filament_m"] == pytest.approx(
        e_sum(EXAMPLE) / AREA / 1000, abs=0.001)
    assert set(data["extruders"]) == {"E"}  # a single-material head has one reel
    peaks = data["peak_temperatures_c"]
    assert 205 < peaks["nozzle0"] < 216 and 57 < peaks["bed"] < 64  # M109 S210, M190 S60
    assert peaks["nozzle1"] < 30  # never heated
    assert data["extent_mm"] == {"X": [95.0, 115.0], "Y": [65.0, 85.0], "Z": [0.3, 2.1]}
    assert 60 < data["print_time_s"] < 600  # heating from cold, then ten small layers


def test_the_table_says_the_same(tmp_path):
    result = simulate(EXAMPLE)
    assert result.exit_code == 0
    assert re.search(r"^extruder E  96\.0 mm3, 0\.04 m of 1\.75 mm filament", result.output,
                     re.M)
    assert "no warnings, no errors" in result.output


def test_extrusion_with_the_valve_shut_is_a_warning(tmp_path):
    text = EXAMPLE.read_text().replace("G0 B1 ; open the valve", "")
    data = report(job(tmp_path, text))
    warnings = [w for w in data["warnings"] if "valve shut" in w]
    assert len(warnings) == 1, data["warnings"]
    # at least the job's plastic: against the shut needle (simulate loads the filament)
    # the head fills, the drive slips, and the firmware's slip retries push again
    pushed = float(warnings[0].split(" mm3 pushed")[0])
    assert pushed >= e_sum(EXAMPLE) - 0.05
    assert data["deposition"]["pushed_into_shut_head_mm3"] >= 0.99
    first = next(n for n, raw in enumerate(
        (c for c in map(code_part, split_lines([text.encode()])) if c), 1)
        if b" E" in raw)
    assert f"lines {first}, {first + 1}," in warnings[0]


def test_a_head_without_a_valve_has_no_valve_to_shut(tmp_path):
    text = EXAMPLE.read_text().replace("G0 B1 ; open the valve", "")
    data = report(job(tmp_path, text), "--head", "RBX01-SL")
    assert data["warnings"] == [] and data["completed"]


def test_extrusion_off_the_plate_and_beyond_the_travel(tmp_path):
    text = EXAMPLE.read_text().replace("G1 X115.000 Y85.000 E2.40000",
                                       "G1 X212.000 Y85.000 E2.40000", 1)
    text = text.replace("G1 Z30 F600", "G0 X300 Y10\nG1 Z30 F600")
    data = report(job(tmp_path, text))
    off = [w for w in data["warnings"] if "build plate" in w]
    assert len(off) == 1 and "X 95.0..212.0" in off[0], data["warnings"]
    assert data["extent_mm"]["X"] == [95.0, 212.0]
    lines = [c for c in map(code_part, split_lines([text.encode()])) if c]
    clamp = lines.index(b"G0 X300 Y10") + 1
    assert any(w.startswith("moves beyond the axes' travel") and f"line {clamp})" in w
               for w in data["warnings"]), data["warnings"]


def test_a_reel_that_runs_out(tmp_path):
    needed = e_sum(EXAMPLE) / AREA / 1000  # metres
    data = report(EXAMPLE, "--remaining", f"{needed * 0.9:.4f}")
    assert any("runs out" in w and "reel0 holds" in w for w in data["warnings"])
    data = report(EXAMPLE, "--remaining", f"{needed * 1.1:.4f}")
    assert not any("runs out" in w for w in data["warnings"])


def test_a_pause_the_job_makes_is_resumed_and_noted(tmp_path):
    text = EXAMPLE.read_text().replace("; layer 5\n", "; layer 5\nM1\n")
    data = report(job(tmp_path, text))
    lines = [c for c in map(code_part, split_lines([text.encode()])) if c]
    assert data["completed"] and data["lines_run"] == len(lines)
    assert data["warnings"] == [f"the job pauses itself (line {lines.index(b'M1') + 1}); "
                                "resumed"]


def test_a_job_the_printer_aborts_fails_the_simulation(tmp_path):
    """A line longer than 512 bytes: GCODE_LINE_TOO_LONG aborts the job (gcode.c)."""
    text = EXAMPLE.read_text().replace("; layer 3\n", "; layer 3\nM117 " + "x" * 1100 + "\n")
    data = report(job(tmp_path, text), status=1)
    assert not data["completed"]
    assert any("aborted at line" in e for e in data["errors"])
    assert any("line too long" in e.lower() for e in data["errors"]), data["errors"]
    human = simulate(job(tmp_path, text))
    assert human.exit_code == 1 and "error: the job was aborted" in human.output


@pytest.mark.parametrize("bad", ["missing.gcode", ".", "/dev/null"])
def test_bad_input_is_one_line(tmp_path, bad):
    result = simulate(tmp_path / bad if bad != "/dev/null" else bad)
    assert result.exit_code != 0
    assert len(result.stderr.splitlines()) == 1 and "error:" in result.stderr


def test_not_gcode(tmp_path):
    result = simulate(job(tmp_path, "hello world\n"))
    assert result.exit_code != 0 and "not a G-code file" in result.stderr


def test_dual_material_head_books_both_reels(tmp_path):
    text = ("M104 S210 T210\nM140 S60\nG28 X Y Z\nM190\nM109\nG90\nT0\nG0 X50 Y50\nG1 Z0.3\n"
            "G0 B1\nG1 X70 Y50 E5 F1200\nG0 B0\nT1\nG0 X50 Y60\nG0 B1\nG1 X70 Y60 D7 F1200\n"
            "G0 B0\nM104 S0 T0\nM140 S0\n")
    data = report(job(tmp_path, text), "--head", "RBX01-DM", "--remaining", "100",
                  "--remaining", "50")
    assert data["completed"] and data["warnings"] == [], data
    assert data["extruders"]["E"]["mm3"] == pytest.approx(5.0, abs=0.01)
    assert data["extruders"]["D"]["mm3"] == pytest.approx(7.0, abs=0.01)
    assert data["extruders"]["E"]["reel_remaining_m"] == 100
    assert data["extruders"]["D"]["reel_remaining_m"] == 50


@pytest.mark.skipif(shutil.which("slic3r") is None, reason="needs slic3r (apt-get install "
                                                            "slic3r)")
def test_a_slic3r_file_simulated(tmp_path):
    """Slic3r's absolute E in mm: translated, then the printer queues the slicer's stated
    filament plus the start sequence's 15 mm3 purge, less the 3 mm3 the end draws back."""
    gcode = slice_small(tmp_path)
    stated_mm = float(gcode.read_text().split("; filament used = ")[1].split("mm")[0])
    data = report(gcode)
    assert data["translation"]["slicer"].lower().startswith("slic3r")
    assert data["completed"] and data["errors"] == [] and data["warnings"] == []
    assert data["extruders"]["E"]["mm3"] == pytest.approx(stated_mm * AREA + 15 - 3, rel=0.005)
    extruding_x = []
    for raw in split_lines([gcode.read_bytes()]):
        line = code_part(raw)
        if line.startswith(b"G1") and b"E" in line and b"X" in line:
            extruding_x.append(float(words(line)[1]["X"]))
    low, high = data["extent_mm"]["X"]
    assert high == pytest.approx(max(extruding_x), abs=1e-3)
    assert low == pytest.approx(10, abs=1e-3)  # the purge's refill, where its line starts
