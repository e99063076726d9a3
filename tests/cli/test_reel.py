"""robox-cli reel: program a reel EEPROM for any filament and read it back, against the
virtual printer in this process, served over its pty, and attached through the pyusb
backend. The chip is checked byte for byte in the printer's dump: the spec's offsets,
8-character numbers, AutoMaker's material character, both banks with a CRC computed here."""

import json
import struct
from pathlib import Path

import pytest
import usb.core
from click.testing import CliRunner

from robox.cli import cli
from robox.host import devices
from robox.sim.printer import VirtualPrinter
from robox.sim.usb_backend import VirtualRoboxBackend
from tests.cli.test_sdcard_cli import one_line_error
from tests.sim.serving import served
from tests.unit.test_eeprom_format import reference_crc


def run(*args: str):
    return CliRunner().invoke(cli, list(args), catch_exceptions=False)


def chip(state: Path) -> bytes:
    return (state / "reel0.eeprom").read_bytes()


def both_banks(raw: bytes) -> bytes:
    """The data both banks hold, each checked against its CRC."""
    for start in (0, 0x100):
        data, crc = raw[start : start + 192], raw[start + 192 : start + 196]
        assert struct.pack("<I", reference_crc(data)) == crc
    assert raw[:192] == raw[0x100:0x1C0]
    return raw[:192]


@pytest.fixture
def state(tmp_path):
    s = tmp_path / "p"
    assert run("--device", f"sim-once:{s}", "status").exit_code == 0  # a printer made
    return s


def test_a_catalogue_material_is_written_as_the_spec_lays_it_out(state):
    result = run("--device", f"sim-once:{state}", "reel", "program", "petg",
                 "--remaining", "300", "--colour", "#ff8000", "--json")
    assert result.exit_code == 0, result.output
    out = json.loads(result.output)
    assert out["definition"]["material_type"] == "PETG" and out["written"]
    data = both_banks(chip(state))
    assert data[0x00:0x10] == b"RBX-GEN-PETG".ljust(16, b"\0")
    assert data[0x10:0x16] == b"FF8000"
    assert data[0x28:0x30] == b"245.0000" and data[0x30:0x38] == b"240.0000"
    assert data[0x38:0x40] == b"80.00000" and data[0x40:0x48] == b"80.00000"
    assert data[0x48:0x50] == b"35.00000" and data[0x50:0x58] == b"1.750000"
    assert data[0x58:0x60] == b"1.000000" and data[0x60:0x68] == b"1.000000"
    assert data[0x68:0x90] == b"Generic PETG".ljust(40, b"\0")
    assert data[0x90:0x91] == bytes([ord("A") + 16])  # AutoMaker's 17th material
    assert data[0xB8:0xC0] == b"300000.0"


def test_show_reads_it_back_in_the_same_terms_and_its_json_programs_the_same_chip(
        state, tmp_path):
    assert run("--device", f"sim-once:{state}", "reel", "program", "TPU").exit_code == 0
    shown = run("--device", f"sim-once:{state}", "reel", "show", "--json")
    assert shown.exit_code == 0, shown.output
    definition = json.loads(shown.output)
    assert definition["material_type"] == "TPU" and definition["feed_rate_multiplier"] == 0.5
    assert definition["remaining_m"] == 240  # the reel's own length, kept
    text = run("--device", f"sim-once:{state}", "reel", "show").output
    assert "catalogue material TPU" in text and "nozzle                225 °C" in text
    first = chip(state)
    # the same definition through a file, after another material: the same chip data
    assert run("--device", f"sim-once:{state}", "reel", "program", "PLA").exit_code == 0
    assert both_banks(chip(state)) != both_banks(first)
    path = tmp_path / "tpu.json"
    path.write_text(json.dumps(definition))
    result = run("--device", f"sim-once:{state}", "reel", "program", "--from", str(path))
    assert result.exit_code == 0, result.output
    assert both_banks(chip(state)) == both_banks(first)


def test_a_toml_definition_starts_from_a_material_and_replaces_what_it_names(state, tmp_path):
    path = tmp_path / "acme.toml"
    path.write_text('material = "ABS"\nname = "Acme ABS black"\nid = "ACME-ABS-7"\n'
                    'colour = "101010"\nbed_c = 95\nremaining_m = 500.5\n')
    result = run("--device", f"sim-once:{state}", "reel", "program", "--from", str(path))
    assert result.exit_code == 0, result.output
    data = both_banks(chip(state))
    assert data[0:10] == b"ACME-ABS-7" and data[0x68:0x76] == b"Acme ABS black"
    assert data[0x40:0x48] == b"95.00000" and data[0x30:0x38] == b"250.0000"
    assert data[0xB8:0xC0] == b"500500.0" and data[0x90:0x91] == b"A"


@pytest.mark.parametrize("args,words", [
    (["PC"], "275 °C is above the 260 °C a RBX01-SM head reaches"),
    (["PLA", "--diameter", "0"], "diameter_mm: 0 is not a filament diameter"),
    (["PLA", "--name", "x" * 41], "the field holds 40"),
    (["PLA", "--colour", "red"], "is not a colour"),
    (["PLA", "--remaining", "123456"], "remaining_m: 123456 is not a length"),
    (["WOOD"], "no material 'WOOD' in the catalogue"),
    ([], "name a MATERIAL from the catalogue, or give --from FILE"),
])
def test_what_the_printer_would_clamp_or_cannot_hold_is_refused_before_writing(
        state, args, words):
    before = chip(state)
    one_line_error(run("--device", f"sim-once:{state}", "reel", "program", *args), 2, words)
    assert chip(state) == before


@pytest.mark.parametrize("text,words", [
    ('material = "PLA"\nbed_c = 170\n', "bed_c: 170 °C is above the 160 °C"),
    ('material = "PLA"\nambient_c = 61\n', "ambient_c: 61 °C is above the 60 °C"),
    ('material = "PLA"\nnozzle = 200\n', "unknown key 'nozzle'"),
    ('name = "x"\n', "'id' is missing"),
    ('material = "PLA"\nbed_c = "hot"\n', "bed_c must be a number"),
    ('material = "PLA"\nmaterial_type = "wood"\n', "unknown material type 'wood'"),
    ("material = [\n", "not a TOML reel definition"),
])
def test_a_bad_definition_file_is_one_line_and_writes_nothing(state, tmp_path, text, words):
    path = tmp_path / "reel.toml"
    path.write_text(text)
    before = chip(state)
    one_line_error(run("--device", f"sim-once:{state}", "reel", "program", "--from",
                       str(path)), 2, words)
    assert chip(state) == before


def test_dry_run_shows_the_definition_without_a_printer():
    result = run("--device", "serial:/nonexistent/tty", "reel", "program", "ASA",
                 "--dry-run", "--json")
    assert result.exit_code == 0, result.output
    out = json.loads(result.output)
    assert out["dry_run"] and not out["written"]
    assert out["definition"]["nozzle_c"] == 255 and out["definition"]["remaining_m"] is None


def test_a_blank_chip_is_formatted_only_when_asked(state):
    raw = bytearray(chip(state))
    raw[0:0x200] = b"\xff" * 0x200  # a new chip: no bank with a good CRC
    (state / "reel0.eeprom").write_bytes(bytes(raw))
    one_line_error(run("--device", f"sim-once:{state}", "reel", "show"), 1,
                   "holds no valid data")
    one_line_error(run("--device", f"sim-once:{state}", "reel", "program", "PLA"), 2,
                   "add --format")
    assert chip(state) == bytes(raw)
    result = run("--device", f"sim-once:{state}", "reel", "program", "PLA", "--format",
                 "--yes", "--remaining", "240")
    assert result.exit_code == 0, result.output
    data = both_banks(chip(state))
    assert data[0:11] == b"RBX-GEN-PLA" and data[0xB8:0xC0] == b"240000.0"


def test_over_the_served_printers_pty(tmp_path):
    state = tmp_path / "p"
    with served(state) as pty:
        result = run("--device", f"serial:{pty}", "reel", "program", "HIPS", "--remaining",
                     "100")
        assert result.exit_code == 0, result.output
        shown = json.loads(run("--device", f"serial:{pty}", "reel", "show", "--json").output)
    assert shown["material_type"] == "HIPS" and shown["remaining_m"] == 100
    data = both_banks(chip(state))
    assert data[0x90:0x91] == bytes([ord("A") + 7]) and data[0xB8:0xC0] == b"100000.0"


def test_through_the_pyusb_backend(monkeypatch):
    virtual = VirtualPrinter()
    virtual.settle()
    device = usb.core.find(idVendor=0x16D0, idProduct=0x081B,
                           backend=VirtualRoboxBackend(virtual))
    monkeypatch.setattr(devices, "_usb_devices", lambda: [device])
    result = run("--device", "usb", "reel", "program", "NYLON", "--json")
    assert result.exit_code == 0, result.output
    virtual.settle()
    data = bytes(virtual.hw.eeprom_bus.sockets[1].data)
    assert both_banks(data)[0:13] == b"RBX-GEN-NYLON"
    assert data[0x90:0x91] == bytes([ord("A") + 5])  # PA6
    shown = json.loads(run("--device", "usb", "reel", "show", "--json").output)
    assert shown["name"] == "Generic nylon (PA6)" and shown["nozzle_c"] == 255
