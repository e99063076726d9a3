"""robox-cli firmware and the build-pipeline tools: results, refusals, untouched files."""

import json
import os
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from pyfakefs.helpers import reset_ids, set_uid

from robox.cli import cli
from tests.cli.test_sdcard_cli import one_line_error
from tests.unit.test_firmware_format import struct_sum

ROOT = Path(__file__).resolve().parents[2]


def run(*args: str):
    return CliRunner().invoke(cli, list(args), catch_exceptions=False)


def firmware_bytes(size: int = 16384, seed: int = 1) -> bytes:
    data = bytearray(np.random.default_rng(seed).integers(0, 256, size, dtype=np.uint8))
    data[0xBC:0xC0] = bytes(4)
    return bytes(data)


@pytest.fixture
def image(fs):
    path = Path("/fw.bin")
    path.write_bytes(firmware_bytes())
    return path


@pytest.fixture
def user(fs):
    """Run as an ordinary user, so that file permissions apply."""
    set_uid(1000)
    yield
    reset_ids()


def test_inject_then_verify(image):
    result = run("firmware", "inject", "/fw.bin")
    assert result.exit_code == 0 and "anti-checksum 0x" in result.output
    data = image.read_bytes()
    assert struct_sum(data) == 0
    assert result.output.split("0x")[1][:8] == f"{struct.unpack_from('<I', data, 0xBC)[0]:08x}"
    report = json.loads(run("firmware", "verify", "/fw.bin", "--json").output)
    assert report["accepted"] and report["checksum"] == "00000000"
    assert report["size"] == 16384 and report["page_aligned"] and report["kind"] == "binary"
    assert report["word_at_offset"] == data[0xBC:0xC0][::-1].hex()


def test_inject_at_another_offset(image):
    data = bytearray(image.read_bytes())
    data[0x200:0x204] = bytes(4)
    image.write_bytes(bytes(data))
    assert run("firmware", "inject", "/fw.bin", "--offset", "200").exit_code == 0
    assert struct_sum(image.read_bytes()) == 0 and image.read_bytes()[0xBC:0xC0] == bytes(4)


def test_verify_refuses_an_image_without_its_anti_checksum(image):
    result = run("firmware", "verify", "/fw.bin")
    assert result.exit_code == 1 and "does not sum to zero" in result.output


def test_to_sd_from_sd_round_trip_and_verify_the_text(image):
    run("firmware", "inject", "/fw.bin")
    assert run("firmware", "to-sd", "/fw.bin", "-o", "/fw.txt").exit_code == 0
    text = Path("/fw.txt").read_bytes()
    assert text == image.read_bytes().hex().upper().encode()
    report = json.loads(run("firmware", "verify", "/fw.txt", "--json").output)
    assert report["kind"] == "sd-text" and report["accepted"] and report["characters"] == 32768
    Path("/lower.txt").write_bytes(text.lower())
    assert run("firmware", "from-sd", "/lower.txt", "-o", "/back.bin").exit_code == 0
    assert Path("/back.bin").read_bytes() == image.read_bytes()


@pytest.mark.parametrize("size,rule", [(4096 - 256, "TOO_SHORT"), (16384 + 100, "LENGTH"),
                                       (131072 + 256, "TOO_LONG")])
def test_verify_names_the_failed_rule(fs, size, rule):
    data = bytearray(firmware_bytes(size))
    data[0:4] = struct.pack("<I", (-struct_sum(bytes(data))) & 0xFFFFFFFF)
    Path("/f.bin").write_bytes(bytes(data))
    result = run("firmware", "verify", "/f.bin", "--json")
    assert result.exit_code == 1
    assert next(f["rule"] for f in json.loads(result.output)["failures"]).startswith(rule)


@pytest.mark.parametrize("content,offset,words", [
    (bytes(131072 + 256), "0xBC", "larger than the flash"),
    (bytes(4097), "0xBC", "multiple of 256"),
    (bytes(256), "0x100", "outside"),
    (bytes(0xBC) + b"\x01" + bytes(256 - 0xBD), "0xBC", "not zero"),
])
def test_inject_refusals_leave_the_file_byte_identical(fs, content, offset, words):
    Path("/f.bin").write_bytes(content)
    one_line_error(run("firmware", "inject", "/f.bin", "--offset", offset), 1, words)
    assert Path("/f.bin").read_bytes() == content


def test_inject_refuses_a_read_only_file(image, user):
    os.chmod("/fw.bin", 0o444)
    before = image.read_bytes()
    one_line_error(run("firmware", "inject", "/fw.bin"), 1, "read-only")
    assert image.read_bytes() == before


def test_an_unreadable_file(image, user):
    os.chmod("/fw.bin", 0o000)
    one_line_error(run("firmware", "verify", "/fw.bin"), 1, "not readable")


@pytest.mark.parametrize("command", [["inject", "/fw.bin"], ["verify", "/fw.bin"]])
def test_an_offset_that_is_not_hexadecimal(image, command):
    before = image.read_bytes()
    one_line_error(run("firmware", *command, "--offset", "0xZZ"), 2, "not hexadecimal")
    assert image.read_bytes() == before


@pytest.mark.parametrize("text,words", [(b"ABC", "odd number"), (b"ABCG", "not a hex")])
def test_from_sd_refuses_bad_text_and_writes_nothing(fs, text, words):
    Path("/t.txt").write_bytes(text)
    one_line_error(run("firmware", "from-sd", "/t.txt", "-o", "/out.bin"), 1, words)
    assert not Path("/out.bin").exists()


@pytest.mark.parametrize("command", [["inject", "/e"], ["verify", "/e"], ["to-sd", "/e", "-o",
                                     "/o"], ["from-sd", "/e", "-o", "/o"]])
def test_empty_and_missing_files(fs, command):
    Path("/e").write_bytes(b"")
    one_line_error(run("firmware", *command), 1, "empty")
    assert Path("/e").read_bytes() == b"" and not Path("/o").exists()
    missing = [arg.replace("/e", "/missing") for arg in command]
    one_line_error(run("firmware", *missing), 1, "no such file")


# --------------------------------------------------------------- tools/
def tool(name: str, *args: str):
    return subprocess.run([sys.executable, str(ROOT / "tools" / name), *args],
                          capture_output=True, text=True)


def test_anticheckbin_inserts_like_the_c_tool(tmp_path):
    path = tmp_path / "robox.bin"
    path.write_bytes(firmware_bytes())
    done = tool("anticheckbin", str(path), "bc")
    assert done.returncode == 0, done.stderr
    assert struct_sum(path.read_bytes()) == 0
    again = tool("anticheckbin", str(path), "0xBC")
    assert again.returncode == 1 and "not zero" in again.stderr


@pytest.mark.parametrize("content,offset,words", [
    (bytes(131328), "bc", "larger than the flash"), (bytes(300), "bc", "multiple of 256"),
    (bytes(256), "fe", "outside"), (b"\x01" * 512, "bc", "not zero"),
])
def test_anticheckbin_refusals(tmp_path, content, offset, words):
    path = tmp_path / "robox.bin"
    path.write_bytes(content)
    done = tool("anticheckbin", str(path), offset)
    assert done.returncode == 1 and words in done.stderr and "Traceback" not in done.stderr
    assert path.read_bytes() == content


def test_anticheckbin_usage(tmp_path):
    assert tool("anticheckbin", "only-one").returncode == 2
    assert tool("anticheckbin", str(tmp_path / "x"), "zz").returncode == 2


def test_mksdimage_builds_a_card_in_order_with_firmware_as_text(tmp_path):
    job1, job2, fw = tmp_path / "cube.gcode", tmp_path / "vase.gcode", tmp_path / "robox_r776.bin"
    job1.write_bytes(b"G28\rG1 X10\r")
    job2.write_bytes(b"G28\rG1 Y10\r" * 100)
    fw.write_bytes(firmware_bytes())
    card = tmp_path / "card.img"
    done = tool("mksdimage", str(card), "--size", "2MiB", "--job", str(job1), "--job",
                str(job2), "--firmware", str(fw))
    assert done.returncode == 0, done.stderr
    listing = json.loads(CliRunner().invoke(cli, ["sdcard", "ls", str(card), "--json"]).output)
    assert [(f["id"], f["job"]) for f in listing["files"]] == \
        [("cube.gcode", True), ("vase.gcode", True), ("robox_r776.bin", False)]
    text = CliRunner().invoke(cli, ["sdcard", "get", str(card), "robox_r776.bin"]).stdout_bytes
    assert text == fw.read_bytes().hex().upper().encode()


def test_mksdimage_refuses_a_non_job_before_another_file(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    a.write_bytes(b"x")
    b.write_bytes(b"y")
    done = tool("mksdimage", str(tmp_path / "c.img"), "--size", "1MiB", "--file", str(a),
                "--job", str(b))
    assert done.returncode == 2 and "last" in done.stderr
    assert not (tmp_path / "c.img").exists()


def test_mksdimage_missing_input_leaves_no_image(tmp_path):
    done = tool("mksdimage", str(tmp_path / "c.img"), "--size", "1MiB", "--job",
                str(tmp_path / "nope"))
    assert done.returncode == 1 and "no such file" in done.stderr
    assert not (tmp_path / "c.img").exists() and list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("command", [["firmware", "verify"], ["eeprom", "show"],
                                     ["eeprom", "fsck"]])
def test_a_huge_input_is_refused_by_its_kinds_ceiling(tmp_path, command):
    """A 1 GiB sparse file: refused after reading at most one byte past the largest a
    firmware file (256 KiB) or an EEPROM dump (512 bytes) can be; no MemoryError."""
    from tests.cli.test_sdcard_cli import one_line_error

    huge = tmp_path / "huge"
    with open(huge, "wb") as f:
        f.truncate(1 << 30)
    limit = "262144 bytes" if command[0] == "firmware" else "512 bytes"
    one_line_error(CliRunner().invoke(cli, [*command, str(huge)]), 1, limit)
