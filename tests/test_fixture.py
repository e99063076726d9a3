"""fixtures/sdcard.img: what it holds, and that tools/mkfixture makes exactly it."""

import subprocess
import sys
from pathlib import Path

from robox.offline import sdcard as images

ROOT = Path(__file__).resolve().parent.parent
FIXTURE = ROOT / "fixtures" / "sdcard.img"


def test_the_fixture_holds_two_jobs_and_a_non_job():
    assert FIXTURE.stat().st_size <= 8 * 1024 * 1024
    files = images.list_image(FIXTURE)["files"]
    assert sum(f["job"] for f in files) >= 2 and sum(not f["job"] for f in files) >= 1
    tower = images.get_file(FIXTURE, "square_tower")
    assert tower.startswith(b"M104 S210\r") and b";" not in tower


def test_mkfixture_regenerates_the_fixture_byte_for_byte(tmp_path):
    out = tmp_path / "again.img"
    subprocess.run([sys.executable, str(ROOT / "tools" / "mkfixture"), str(out)], check=True,
                   capture_output=True)
    assert out.read_bytes() == FIXTURE.read_bytes()


def test_the_bundled_card_and_example_job_are_the_generated_ones(tmp_path):
    assert (ROOT / "src" / "robox" / "data" / "sdcard.img").read_bytes() == FIXTURE.read_bytes()
    import importlib.machinery
    import importlib.util
    loader = importlib.machinery.SourceFileLoader("mkfixture", str(ROOT / "tools" / "mkfixture"))
    mkfixture = importlib.util.module_from_spec(importlib.util.spec_from_loader("mkfixture",
                                                                                 loader))
    loader.exec_module(mkfixture)
    example = ROOT / "src" / "robox" / "data" / "example.gcode"
    assert example.read_text() == mkfixture.example_job()
