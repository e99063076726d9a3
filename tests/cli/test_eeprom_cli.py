"""robox-cli eeprom on dump files: new, show, set, fsck; bad input leaves files unchanged."""

import json
import struct
from pathlib import Path

import pytest
from click.testing import CliRunner

from robox.cli import cli
from tests.cli.test_sdcard_cli import one_line_error
from tests.unit.test_eeprom_format import reference_crc


def run(*args: str):
    return CliRunner().invoke(cli, list(args), catch_exceptions=False)


def bank_ok(raw: bytes, start: int) -> bool:
    data, crc = raw[start : start + 192], raw[start + 192 : start + 196]
    return struct.pack("<I", reference_crc(data)) == crc


@pytest.fixture
def reel(fs):
    result = run("eeprom", "new", "reel", "-o", "/reel.eeprom",
                 "--set", "filament_diameter=1.75", "--set", "remaining_filament=240000",
                 "--set", "filament_id=PLA-1", "--set", "display_colour=112233")
    assert result.exit_code == 0, result.output
    return Path("/reel.eeprom")


def test_new_writes_both_banks_valid_with_the_fields(reel):
    raw = reel.read_bytes()
    assert len(raw) == 512 and bank_ok(raw, 0) and bank_ok(raw, 0x100)
    assert raw[0x50:0x58] == b"1.750000" and raw[0xB8:0xC0] == b"240000.0"
    assert raw[0:16] == b"PLA-1" + bytes(11) and raw[0x10:0x16] == b"112233"
    assert raw[:0xC4] == raw[0x100:0x1C4]


def test_new_head_with_its_fields(fs):
    assert run("eeprom", "new", "head", "-o", "/h", "--set", "type_code=RBX01-DM",
               "--set", "head_hours=12.5").exit_code == 0
    report = json.loads(run("eeprom", "show", "/h", "--json").output)
    assert report["kind"] == "head"
    assert report["fields"]["type_code"]["value"] == "RBX01-DM"
    assert report["fields"]["head_hours"]["value"] == 12.5


def test_show_reports_banks_the_loaded_copy_and_fields(reel):
    report = json.loads(run("eeprom", "show", "/reel.eeprom", "--json").output)
    assert [b["crc_good"] for b in report["banks"]] == [True, True]
    assert report["loaded_bank"] == 0 and report["kind"] == "reel"
    assert report["fields"]["filament_diameter"]["value"] == 1.75
    assert report["fields"]["remaining_filament"]["raw"] == "240000.0"
    human = run("eeprom", "show", "/reel.eeprom").output
    assert "bank 0 at 0x000: CRC good" in human and "filament_id" in human


def test_show_of_a_corrupt_bank_0_loads_bank_1(reel):
    raw = bytearray(reel.read_bytes())
    raw[0x50] = ord("9")
    reel.write_bytes(bytes(raw))
    report = json.loads(run("eeprom", "show", "/reel.eeprom", "--json").output)
    assert [b["crc_good"] for b in report["banks"]] == [False, True]
    assert report["loaded_bank"] == 1
    assert report["fields"]["filament_diameter"]["value"] == 1.75
    assert reel.read_bytes() == bytes(raw)  # show never writes


def test_set_changes_fields_as_a_printer_and_leaves_both_banks_valid(reel):
    result = run("eeprom", "set", "/reel.eeprom", "remaining_filament=1234.5",
                 "friendly_name=Robox PLA")
    assert result.exit_code == 0, result.output
    raw = reel.read_bytes()
    assert bank_ok(raw, 0) and bank_ok(raw, 0x100) and raw[:0xC4] == raw[0x100:0x1C4]
    assert raw[0xB8:0xC0] == b"1234.500" and raw[0x68:0x71] == b"Robox PLA"
    assert raw[0x50:0x58] == b"1.750000"


def test_set_repairs_a_corrupt_bank_the_way_a_printer_does(reel):
    raw = bytearray(reel.read_bytes())
    raw[0x5] = 0x7E
    reel.write_bytes(bytes(raw))
    assert run("eeprom", "set", "/reel.eeprom", "nozzle_temperature=210").exit_code == 0
    raw = reel.read_bytes()
    assert bank_ok(raw, 0) and bank_ok(raw, 0x100) and raw[0x30:0x38] == b"210.0000"
    assert raw[0:5] == b"PLA-1"  # bank 1 was loaded, so the corrupt byte is gone


def test_fsck_exit_status(reel):
    result = run("eeprom", "fsck", "/reel.eeprom")
    assert result.exit_code == 0 and "valid" in result.output
    raw = bytearray(reel.read_bytes())
    raw[0x10] ^= 1
    raw[0x110] ^= 1
    reel.write_bytes(bytes(raw))
    result = run("eeprom", "fsck", "/reel.eeprom", "--json")
    assert result.exit_code == 1
    report = json.loads(result.output)
    assert not report["valid"] and "both banks" in report["reason"]
    assert reel.read_bytes() == bytes(raw)


def test_fsck_of_a_blank_chip_fails(fs):
    Path("/blank").write_bytes(b"\xff" * 512)
    assert run("eeprom", "fsck", "/blank").exit_code == 1


def test_set_on_a_chip_with_no_good_bank_is_refused(fs):
    Path("/blank").write_bytes(b"\xff" * 512)
    one_line_error(run("eeprom", "set", "/blank", "filament_diameter=1.75"), 1, "bad CRC")
    assert Path("/blank").read_bytes() == b"\xff" * 512


@pytest.mark.parametrize("assignment,words", [
    ("nope=1", "no reel EEPROM field"), ("remaining_filament=123456789", "8 characters"),
    ("filament_id=" + "x" * 17, "holds 16"), ("friendly_name=caf\u00e9", "ASCII"),
    ("filament_diameter", "FIELD=VALUE"),
])
def test_bad_assignments_change_nothing(reel, assignment, words):
    before = reel.read_bytes()
    one_line_error(run("eeprom", "set", "/reel.eeprom", "filament_multiplier=1", assignment),
                   2, words)
    assert reel.read_bytes() == before


@pytest.mark.parametrize("size", [0, 511, 513, 1024])
def test_a_dump_that_is_not_512_bytes(fs, size):
    Path("/d").write_bytes(bytes(size))
    for command in (["show", "/d"], ["fsck", "/d"], ["set", "/d", "head_hours=1"]):
        one_line_error(run("eeprom", *command), 1, "512 bytes")
    assert Path("/d").read_bytes() == bytes(size)


def test_a_missing_dump(fs):
    one_line_error(run("eeprom", "show", "/none"), 1, "no such file")


def test_new_refuses_bad_fields_and_writes_nothing(fs):
    one_line_error(run("eeprom", "new", "head", "-o", "/h", "--set", "filament_id=x"), 2,
                   "no head EEPROM field")
    assert not Path("/h").exists()


def test_kind_can_be_forced(reel):
    report = json.loads(run("eeprom", "show", "/reel.eeprom", "--kind", "head", "--json").output)
    assert report["kind"] == "head" and "head_hours" in report["fields"]


def test_bytes_with_the_top_bit_set_are_reported_masked(reel):
    data = bytes([0x50 | 0x80, 0x4C | 0x80, 0x41]) + bytes(189)  # "PLA", two bytes unmasked
    bank = data + struct.pack("<I", reference_crc(data))  # a CRC-good bank over raw bytes
    reel.write_bytes(bank + b"\xff" * 60 + bank + b"\xff" * 60)
    report = json.loads(run("eeprom", "show", "/reel.eeprom", "--json").output)
    assert report["loaded_bank"] == 0
    assert report["fields"]["filament_id"]["value"] == "PLA"
