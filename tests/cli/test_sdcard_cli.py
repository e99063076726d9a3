"""robox-cli sdcard, as a user runs it: exit codes, output, and files left untouched."""

import hashlib
import json
import os
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import pytest
from click.testing import CliRunner

from robox.cli import cli
from robox.formats import sdcard as f
from robox.gcode import code_part
from robox.offline import sdcard as images
from tests.conftest import pattern

FIXTURE = Path(__file__).resolve().parents[2] / "fixtures" / "sdcard.img"


def run(*args: str):
    result = CliRunner().invoke(cli, list(args), catch_exceptions=False)
    return result


@pytest.fixture
def fake(fs):
    """A fake file system holding a copy of the fixture card."""
    fs.add_real_file(FIXTURE, read_only=True, target_path="/fixture.img")
    Path("/card.img").write_bytes(Path("/fixture.img").read_bytes())
    return fs


def one_line_error(result, status: int, words: str) -> None:
    assert result.exit_code == status, result.output
    lines = [line for line in result.stderr.splitlines() if line]
    assert len(lines) == 1 and lines[0].startswith("robox-cli: error: "), result.stderr
    assert words in lines[0], lines[0]
    assert "Traceback" not in result.output


# ------------------------------------------------------------------ format
@pytest.mark.parametrize("size,blocks", [("8MiB", 16384), ("1024KiB", 2048), ("16384b", 16384),
                                         ("1gib", 2 * 1024 * 1024)])
def test_format_creates_an_image_of_the_given_size(fs, size, blocks):
    result = run("sdcard", "format", "/new.img", "--size", size)
    assert result.exit_code == 0, result.output
    raw = Path("/new.img").read_bytes() if blocks < 100000 else None
    assert os.path.getsize("/new.img") == blocks * 512
    if raw is not None:
        fresh = f.Directory.fresh(blocks).encode()
        assert raw[:44] == fresh[:44] and raw[64:512] == fresh[64:]


@pytest.mark.parametrize("size,words", [
    ("512KiB", "at least 2048"), ("2049b", "odd number"), ("8MB", "not like"),
    ("1536", "not like"), ("1500b", "at least 2048"),
])
def test_format_refuses_bad_sizes(fs, size, words):
    one_line_error(run("sdcard", "format", "/new.img", "--size", size), 2, words)
    assert not Path("/new.img").exists()


def test_format_needs_a_size_to_create(fs):
    one_line_error(run("sdcard", "format", "/new.img"), 2, "--size")


def test_reformat_of_an_existing_card_drops_its_files(fake):
    assert run("sdcard", "format", "/card.img", "--yes").exit_code == 0
    listing = json.loads(run("sdcard", "ls", "/card.img", "--json").output)
    assert listing["files"] == []


def test_reformat_refuses_a_file_that_is_not_a_card(fs):
    data = pattern(2048 * 512, 3)
    Path("/thesis.pdf").write_bytes(data)
    one_line_error(run("sdcard", "format", "/thesis.pdf"), 1, "not a card")
    assert Path("/thesis.pdf").read_bytes() == data


def test_reformat_refuses_to_resize(fake):
    before = Path("/card.img").read_bytes()
    one_line_error(run("sdcard", "format", "/card.img", "--size", "8MiB"), 1, "not resized")
    assert Path("/card.img").read_bytes() == before


# --------------------------------------------------------------------- ls
def test_ls_lists_the_fixture_oldest_first_with_the_last_job(fake):
    result = run("sdcard", "ls", "/card.img")
    assert result.exit_code == 0
    lines = result.output.splitlines()
    assert "square_tower" in lines[1] and "last job" in lines[1]
    assert "spiral_vase" in lines[2] and "home_macro" in lines[3] and " no " in lines[3]
    data = json.loads(run("sdcard", "ls", "/card.img", "--json").output)
    assert [e["id"] for e in data["files"]] == ["square_tower", "spiral_vase", "home_macro"]
    assert [e["job"] for e in data["files"]] == [True, True, False]
    assert data["files"][0]["start_block"] == 1 and data["files"][0]["last_job"]
    assert data["last_job"] == 0 and data["capacity_blocks"] == 4096


@pytest.mark.parametrize("size,words", [(2048 * 512 + 100, "512-byte blocks"),
                                        (1000 * 512, "too small")])
def test_ls_refuses_files_that_cannot_be_cards(fs, size, words):
    Path("/odd.img").write_bytes(bytes(size))
    one_line_error(run("sdcard", "ls", "/odd.img"), 1, words)


def test_ls_of_a_missing_image(fs):
    one_line_error(run("sdcard", "ls", "/nope.img"), 1, "no such file")


def test_ls_of_a_card_a_printer_would_format(fs):
    Path("/bad.img").write_bytes(b"\xff" * 4096 * 512)
    one_line_error(run("sdcard", "ls", "/bad.img"), 1, "would format")


# ------------------------------------------------------------- put / get
def test_put_then_get_round_trips_byte_exact(fake):
    data = pattern(123457, 8)  # any bytes: without --job a file is stored as it is
    Path("/a_rather_long_file_name.gcode").write_bytes(data)
    result = run("sdcard", "put", "/card.img", "/a_rather_long_file_name.gcode")
    assert result.exit_code == 0, result.output
    ids = [e["id"] for e in json.loads(run("sdcard", "ls", "/card.img", "--json").output)["files"]]
    # send-job's rule: the name's first alphanumerics, then the content's SHA-1
    expected_id = "arather_" + hashlib.sha1(data).hexdigest()[:8]
    assert ids[-1] == expected_id
    assert "home_macro" not in ids  # the newest non-job made room
    assert run("sdcard", "get", "/card.img", expected_id, "-o", "/out.bin").exit_code == 0
    assert Path("/out.bin").read_bytes() == data
    stdout = CliRunner().invoke(cli, ["sdcard", "get", "/card.img", expected_id])
    assert stdout.stdout_bytes == data


def test_put_with_an_explicit_id_keeps_a_non_job(fake):
    Path("/m.g").write_bytes(b"G28\r")
    assert run("sdcard", "put", "/card.img", "/m.g", "--id", "macro2").exit_code == 0
    entry = json.loads(run("sdcard", "ls", "/card.img", "--json").output)["files"][-1]
    assert (entry["id"], entry["job"], entry["length"]) == ("macro2", False, 4)


def test_get_does_not_write_the_image(fake):
    before = Path("/card.img").read_bytes()
    assert run("sdcard", "get", "/card.img", "spiral_vase", "-o", "/v").exit_code == 0
    assert run("sdcard", "fsck", "/card.img", "--json").exit_code == 0
    assert run("sdcard", "ls", "/card.img").exit_code == 0
    assert Path("/card.img").read_bytes() == before  # opening a job did not record it


def test_get_of_an_unknown_id(fake):
    one_line_error(run("sdcard", "get", "/card.img", "nothing"), 1, "no file with id")


@pytest.mark.parametrize("args,status,words", [
    (["--id", "x" * 17], 2, "17 bytes"),
    (["--id", "caf\u00e9"], 2, "not ASCII"),
])
def test_put_refuses_bad_ids_and_leaves_the_image(fake, args, status, words):
    Path("/g").write_bytes(b"G28\r")
    before = Path("/card.img").read_bytes()
    one_line_error(run("sdcard", "put", "/card.img", "/g", *args), status, words)
    assert Path("/card.img").read_bytes() == before


def test_put_names_a_non_ascii_file_from_its_ascii_letters(fake):
    Path("/t\u00e9st.gcode").write_bytes(b"G28\r")
    result = run("sdcard", "put", "/card.img", "/t\u00e9st.gcode", "--json")
    assert result.exit_code == 0, result.output
    assert json.loads(result.output)["id"] == "tst_" + hashlib.sha1(b"G28\r").hexdigest()[:12]


def test_put_refuses_a_file_larger_than_the_card(fake):
    Path("/huge").write_bytes(bytes(4095 * 512))
    before = Path("/card.img").read_bytes()
    one_line_error(run("sdcard", "put", "/card.img", "/huge"), 1, "largest file")
    assert Path("/card.img").read_bytes() == before


def test_put_refuses_an_empty_file(fake):
    Path("/empty").write_bytes(b"")
    before = Path("/card.img").read_bytes()
    one_line_error(run("sdcard", "put", "/card.img", "/empty"), 1, "empty")
    assert Path("/card.img").read_bytes() == before


def test_put_of_a_missing_file(fake):
    one_line_error(run("sdcard", "put", "/card.img", "/missing.gcode"), 1, "missing.gcode")


def test_ids_read_from_an_image_never_become_paths(fake):
    Path("/x").write_bytes(b"payload")
    assert run("sdcard", "put", "/card.img", "/x", "--id", "../../etc/x").exit_code == 0
    assert run("sdcard", "get", "/card.img", "../../etc/x", "-o", "/safe.out").exit_code == 0
    assert Path("/safe.out").read_bytes() == b"payload"
    assert not Path("/etc/x").exists()


def test_an_id_with_control_bytes_is_printed_escaped(fake):
    card = Path("/card.img").read_bytes()
    d = f.Directory.decode(card[:512])
    slot = d.slots[d.ring()[0]]
    d = d.with_slot(d.ring()[0], replace(slot, id=b"evil\x1b[2J\n".ljust(16, b"\0")))
    Path("/card.img").write_bytes(d.encode() + card[512:])
    result = run("sdcard", "ls", "/card.img")
    assert "evil\\x1b[2J\\x0a" in result.output and "\x1b" not in result.output


# ------------------------------------------------------------------- fsck
def test_fsck_of_a_good_card(fake):
    result = run("sdcard", "fsck", "/card.img")
    assert result.exit_code == 0
    assert "printer at mount: keep" in result.output
    report = json.loads(run("sdcard", "fsck", "/card.img", "--json").output)
    assert report["printer"]["valid"] and report["project"]["action"] == "keep"
    assert [e["start_block"] for e in report["files"]] == [1, 47, 226]
    assert report["recovery_copy"] is None  # copies live only while block 0 is written


def _printer_bug_card() -> bytes:
    capacity = 3000
    d = f.Directory(capacity=capacity, next_write_block=62, first_file=0, next_file=2)
    d = d.with_slot(0, f.FileSlot(b"B".ljust(16, b"\0"), 1, bytes(3), 101, 2950 * 512))
    d = d.with_slot(1, f.FileSlot(b"C".ljust(16, b"\0"), 1, bytes(3), 52, 10 * 512))
    return d.encode() + bytes((capacity - 1) * 512)


def test_fsck_reports_the_printer_bug_card_both_ways(fs):
    Path("/wrap.img").write_bytes(_printer_bug_card())
    result = run("sdcard", "fsck", "/wrap.img", "--json")
    assert result.exit_code == 1  # a printer would format it
    report = json.loads(result.output)
    assert report["printer"]["action"] == "format" and report["project"]["action"] == "keep"
    assert report["files"][0]["wraps"] and report["files"][0]["end_block"] == 51


def test_fsck_flags_a_start_outside_the_card(fs):
    d = f.Directory(capacity=2048, next_write_block=1, first_file=0, next_file=1)
    d = d.with_slot(0, f.FileSlot(b"x".ljust(16, b"\0"), 1, bytes(3), 5000, 512))
    Path("/out.img").write_bytes(d.encode() + bytes(2047 * 512))
    report = json.loads(run("sdcard", "fsck", "/out.img", "--json").output)
    assert report["printer"]["valid"] and not report["project"]["valid"]
    assert "outside the card" in report["project"]["reason"]
    assert report["files_from"] == "invalid directory"
    assert report["files"][0]["start_block"] == 5000


def test_fsck_finds_a_usable_recovery_copy_of_a_lost_block_0(fs):
    from robox.firmware.error_flags import ErrorFlags
    from robox.firmware.file_system import FileSystem
    from robox.hardware.faults import FaultPlan, Tear
    from robox.hardware.sdcard import SdCard
    from tests.conftest import upload

    card = SdCard.blank(2048)
    fsys = FileSystem(card, ErrorFlags())
    upload(fsys, "keep", pattern(5000, 1))
    # the upload's writes: chunk, tail, copy, then block 0: erase that one
    card.faults = FaultPlan(tear_write=card.writes + 4, tear=Tear(fill=0xFF))
    with pytest.raises(BaseException, match="power cut"):
        upload(fsys, "next", pattern(700, 2))
    Path("/lost.img").write_bytes(bytes(card.storage.data))
    result = run("sdcard", "fsck", "/lost.img", "--json")
    report = json.loads(result.output)
    assert result.exit_code == 1 and not report["printer"]["valid"]
    assert report["project"]["action"] == "recover"
    assert report["recovery_copy"]["usable"]
    assert [e["id"] for e in report["files"]] == ["keep", "next"]
    assert run("sdcard", "get", "/lost.img", "keep", "-o", "/k").exit_code == 0
    assert Path("/k").read_bytes() == pattern(5000, 1)


# ------------------------------------------------------- real subprocesses
def test_the_installed_command_runs_as_a_subprocess(tmp_path):
    image = tmp_path / "card.img"
    exe = [sys.executable, "-m", "robox.cli"]
    made = subprocess.run([*exe, "sdcard", "format", str(image), "--size", "1MiB"],
                          capture_output=True, text=True)
    assert made.returncode == 0, made.stderr
    assert oct(image.stat().st_mode & 0o777) != "0o600"  # the umask decides, not mkstemp
    bad = subprocess.run([*exe, "sdcard", "get", str(image), "x" * 20], capture_output=True,
                         text=True)
    assert bad.returncode == 2 and bad.stderr.startswith("robox-cli: error:")
    assert "Traceback" not in bad.stderr


def test_usage_errors_exit_2(fs):
    assert run("sdcard", "frobnicate").exit_code == 2
    assert run("sdcard", "ls").exit_code == 2


SLICED = (b"; generated by PrusaSlicer 2.7.1 on 2026-11-26\n;TYPE:External perimeter\n"
          b"M83\nG1 Z0.2 F600\nG1 X20 Y20 F3000\nG1 X40 Y20 E1.2\nG1 E-0.8 F2400\n"
          b"G1 X40 Y40 F3000\nG1 E0.8 F2400\nG1 X20 Y40 E1.2\n")


def test_put_of_a_slicers_file_stores_what_send_job_sends_under_its_id(tmp_path):
    part = tmp_path / "part.gcode"
    part.write_bytes(SLICED)
    card = tmp_path / "card.img"
    assert run("sdcard", "format", str(card), "--size", "8MiB").exit_code == 0
    put = CliRunner().invoke(cli, ["sdcard", "put", str(card), str(part), "--job", "--json"])
    assert put.exit_code == 0, put.output
    stored = json.loads(put.stdout)
    state = tmp_path / "printer"
    sent = CliRunner().invoke(cli, ["--device", f"sim-once:{state}", "send-job", str(part),
                                    "--json"])
    assert sent.exit_code == 0, sent.output
    assert json.loads(sent.stdout)["id"] == stored["id"]
    on_printer = images.get_file(state / "sdcard.img", stored["id"])
    assert images.get_file(card, stored["id"]) == on_printer
    assert b"B" in on_printer and b";" not in on_printer  # valve moves, no comments
    raw = CliRunner().invoke(cli, ["sdcard", "put", str(card), str(part), "--job", "--raw",
                                   "--json"])
    kept = images.get_file(card, json.loads(raw.stdout)["id"])
    assert kept == b"".join(code_part(line) + b"\r" for line in SLICED.split(b"\n")
                            if code_part(line))


def test_get_finds_a_file_by_the_name_it_was_put_under(tmp_path):
    card = tmp_path / "card.img"
    assert run("sdcard", "format", str(card), "--size", "8MiB").exit_code == 0
    part = tmp_path / "part.gcode"
    part.write_bytes(b"G28\nG1 X10 Y10 F3000\n")
    assert run("sdcard", "put", str(card), str(part), "--job").exit_code == 0
    assert run("sdcard", "put", str(card), str(part), "--id", "macro1").exit_code == 0
    out = tmp_path / "back.gcode"
    result = run("sdcard", "get", str(card), "part.gcode", "-o", str(out))
    assert result.exit_code == 0, result.output
    assert out.read_bytes() == b"G28\rG1 X10 Y10 F3000\r"
    ids = [f["id"] for f in images.list_image(card)["files"]]
    missing = run("sdcard", "get", str(card), "other.gcode")
    one_line_error(missing, 1, f"no file with id 'other.gcode' (ids on the card: "
                               f"{', '.join(ids)})")
    part.write_bytes(b"G28\nG1 X20 Y20 F3000\n")  # another part.gcode, another id
    assert run("sdcard", "put", str(card), str(part), "--job").exit_code == 0
    two = run("sdcard", "get", str(card), "part.gcode")
    one_line_error(two, 2, "'part.gcode' could be any of part_")
