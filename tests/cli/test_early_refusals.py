"""Refused early and in proportion: what the printer or the image would refuse is
refused before the first chunk is sent, or before the file is hashed."""

import json

import pytest
from click.testing import CliRunner

from robox.cli import cli
from robox.cli import sdcard as sdcard_cli
from robox.errors import ImageError
from robox.formats import firmware as fw
from robox.formats.protocol import JOB_LINE_LIMIT
from robox.offline.sdcard import format_image, list_image, put_file
from tests.cli.test_firmware_cli import firmware_bytes


def run(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def test_send_job_refuses_a_line_the_printer_would_abort_on_before_sending(tmp_path):
    state = tmp_path / "printer"
    job = tmp_path / "long.gcode"
    job.write_bytes(b"G28 X Y\n" * 3 + b"M117 " + b"x" * (JOB_LINE_LIMIT - 5) + b"\nG4 P1\n")
    before = json.loads(run("--device", f"sim-once:{state}", "files", "--json").output)
    result = run("--device", f"sim-once:{state}", "send-job", job, "--raw")
    assert result.exit_code == 1
    assert result.output.splitlines()[-1] == (
        f"robox-cli: error: {job}: job line 4 is {JOB_LINE_LIMIT} bytes; the printer reads "
        f"lines of at most {JOB_LINE_LIMIT - 1} (it would abort the job there)")
    assert json.loads(run("--device", f"sim-once:{state}", "files", "--json").output) == before


def test_send_job_takes_a_line_one_byte_shorter(tmp_path):
    state = tmp_path / "printer"
    job = tmp_path / "long.gcode"
    job.write_bytes(b"M117 " + b"x" * (JOB_LINE_LIMIT - 6) + b"\nG4 P1\n")
    result = run("--device", f"sim-once:{state}", "send-job", job, "--raw", "--id", "long",
                 "--wait", "--json")
    assert result.exit_code == 0, result.output
    assert json.loads(result.output)["errors"] == []


def test_sdcard_put_refuses_a_file_too_large_by_its_size_before_hashing(tmp_path, monkeypatch):
    card = tmp_path / "card.img"
    format_image(card, 2048)
    big = tmp_path / "big.gcode"
    with open(big, "wb") as f:
        f.truncate(2048 * 512)  # sparse: larger than the card holds

    def no_hashing(*_args):
        raise AssertionError("hashed before the size was checked")

    monkeypatch.setattr(sdcard_cli.hashlib, "sha1", no_hashing)
    result = run("sdcard", "put", card, big)
    assert result.exit_code == 1
    assert result.output.splitlines() == [
        f"robox-cli: error: {big}: {2048 * 512} bytes; the largest file {card} holds is "
        f"{2046 * 512} bytes"]
    assert list_image(card)["files"] == []


def test_from_sd_refuses_a_truncated_file(tmp_path):
    text = fw.to_sd_text(firmware_bytes())
    cut = tmp_path / "cut.txt"
    cut.write_bytes(text[: len(text) - 100])
    out = tmp_path / "out.bin"
    result = run("firmware", "from-sd", cut, "-o", out)
    assert result.exit_code == 1
    assert result.output.splitlines() == [
        f"robox-cli: error: {cut}: not a whole SD firmware file ({len(text) - 100} characters "
        f"({(len(text) - 100) / 2:g} bytes): a printer takes a multiple of 512 characters, at "
        "least 8192); was it cut short?"]
    assert not out.exists()
    whole = tmp_path / "whole.txt"
    whole.write_bytes(text)
    assert run("firmware", "from-sd", whole, "-o", out).exit_code == 0
    assert out.read_bytes() == firmware_bytes()


def test_a_card_too_small_is_refused_naming_the_users_path(tmp_path):
    card = tmp_path / "card.img"
    with pytest.raises(ImageError) as refused:
        format_image(card, 1024)
    assert str(refused.value) == (f"{card}: 1024 blocks is too small for a card image "
                                  "(at least 2048)")
    assert list(tmp_path.iterdir()) == []


def test_fsck_of_a_valid_card_reads_what_a_mount_reads(tmp_path, monkeypatch):
    """A mount reads block 0, and the whole card only when block 0 is not a valid
    directory (to look for a recovery copy): fsck reads the same, unless --deep."""
    from robox.hardware.storage import FileStorage

    card = tmp_path / "card.img"
    format_image(card, 1 << 17)  # 64 MiB
    read = []  # the blocks each read of the image takes (the card reads through it)
    real_read = FileStorage.read
    monkeypatch.setattr(FileStorage, "read", lambda self, offset, length:
                        read.append(length // 512) or real_read(self, offset, length))
    shallow = json.loads(run("sdcard", "fsck", card, "--json").output)
    assert sum(read) <= 2 and shallow["recovery_copies"] is None
    read.clear()
    deep = json.loads(run("sdcard", "fsck", card, "--json", "--deep").output)
    assert sum(read) >= (1 << 17) - 2 and deep["recovery_copies"] == 0
    text = run("sdcard", "fsck", card).output
    assert "recovery copy: not looked for (block 0 is valid, so a mount reads none; " \
        "--deep scans the card)" in text


CARD_BLOCKS = 2048  # a 1 MiB card: the largest file it holds is every block but two
LARGEST = (CARD_BLOCKS - 2) * 512


def small_card_printer(tmp_path):
    state = tmp_path / "printer"
    state.mkdir()
    format_image(state / "sdcard.img", CARD_BLOCKS)
    put_file(state / "sdcard.img", b"G28\r", "kept", True)
    return state


def dwell_job(path, size):
    """A job of exactly `size` bytes (lines "G4 P0", the last one padded)."""
    lines, rest = divmod(size, 6)
    path.write_bytes(b"G4 P0\n" * (lines - 1) + b"G4 P0" + b"0" * rest + b"\n")
    return path


def test_send_job_refuses_a_job_larger_than_a_virtual_printers_card_before_sending(tmp_path):
    state = small_card_printer(tmp_path)
    job = dwell_job(tmp_path / "big.gcode", LARGEST + 1)
    before = list_image(state / "sdcard.img")["files"]
    assert [f["id"] for f in before] == ["kept"]  # an upload too large would drop it
    result = run("--device", f"sim-once:{state}", "send-job", job, "--raw", "--id", "big")
    assert result.exit_code == 1
    assert result.output.splitlines()[-1] == (
        f"robox-cli: error: the job is {LARGEST + 1} bytes; the printer's card holds files "
        f"of at most {LARGEST} bytes (1.0 MiB): nothing sent")
    assert list_image(state / "sdcard.img")["files"] == before


def test_send_job_takes_a_job_the_size_of_the_card(tmp_path):
    state = small_card_printer(tmp_path)
    job = dwell_job(tmp_path / "full.gcode", LARGEST)
    result = run("--device", f"sim-once:{state}", "send-job", job, "--raw", "--id", "full")
    assert result.exit_code == 0, result.output
    files = list_image(state / "sdcard.img")["files"]
    assert [(f["id"], f["length"]) for f in files] == [("full", LARGEST)]


def test_a_printer_that_refused_a_job_as_too_large_has_larger_ones_refused_before_sending(
        tmp_path):
    """A printer's card size is not on the wire: reached as a real printer is (a serial
    port), the host learns it from the printer's refusal, and keeps it."""
    from tests.sim.serving import served

    state = small_card_printer(tmp_path)
    big = dwell_job(tmp_path / "big.gcode", LARGEST + 2048)
    small = dwell_job(tmp_path / "small.gcode", 3000)
    with served(state) as pty:
        device = ("--device", f"serial:{pty}")
        first = run(*device, "send-job", big, "--raw", "--id", "big")
        assert first.exit_code == 1
        assert first.output.splitlines()[-1] == (
            f"robox-cli: error: chunk {LARGEST // 512}: the printer reports file too large "
            f"for the SD card: the job is {LARGEST + 2048} bytes and the card holds files of "
            f"at most {LARGEST} bytes (a larger job is refused before upload from now on)")
        assert run(*device, "errors", "--clear").exit_code == 0
        assert run(*device, "send-job", small, "--raw", "--id", "small").exit_code == 0
        again = run(*device, "send-job", big, "--raw", "--id", "big")
        assert again.exit_code == 1
        assert again.output.splitlines()[-1] == (
            f"robox-cli: error: the job is {LARGEST + 2048} bytes; the printer's card holds "
            f"files of at most {LARGEST} bytes (1.0 MiB): nothing sent")
        listed = json.loads(run(*device, "files", "--json").output)
    assert [f["id"] for f in listed] == ["small"]
