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
from robox.offline.sdcard import format_image, list_image
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
    from robox.hardware.sdcard import SdCard

    card = tmp_path / "card.img"
    format_image(card, 1 << 17)  # 64 MiB
    read = []
    real_one, real_many = SdCard.read_block, SdCard.read_blocks
    monkeypatch.setattr(SdCard, "read_block",
                        lambda self, b: read.append(1) or real_one(self, b))
    monkeypatch.setattr(SdCard, "read_blocks",
                        lambda self, b, n: read.append(n) or real_many(self, b, n))
    shallow = json.loads(run("sdcard", "fsck", card, "--json").output)
    assert sum(read) <= 2 and shallow["recovery_copies"] is None
    read.clear()
    deep = json.loads(run("sdcard", "fsck", card, "--json", "--deep").output)
    assert sum(read) >= (1 << 17) - 2 and deep["recovery_copies"] == 0
    text = run("sdcard", "fsck", card).output
    assert "recovery copy: not looked for (block 0 is valid, so a mount reads none; " \
        "--deep scans the card)" in text
