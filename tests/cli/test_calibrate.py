"""robox-cli calibrate against a virtual printer whose head is given true imperfections
(`sim head` / `sim serve --nozzle-z-difference --b-open --xy-offset`): each calibration
finds what it was given, within the printer's resolution, and writes it to the head's
EEPROM (read from the chip dump, both banks and their CRCs checked here). The steps a
person judges are answered as a person who sees the truth would: the paper under the
nozzle, the plastic at the nozzle, the pair of lines that lines up. Ctrl-C at every
prompt leaves the head's data as it was and the heaters off."""

import json
import math
import time

import click
import pytest
import usb.core
from click.testing import CliRunner

from robox import calibration
from robox.cli import cli
from robox.cli import maintenance as cli_maintenance
from robox.hardware.machine import STEPS_PER_MM, Z
from robox.host import devices
from robox.sim.printer import VirtualPrinter
from robox.sim.usb_backend import VirtualRoboxBackend
from tests.cli.test_maintenance import head_data, status
from tests.cli.test_sdcard_cli import one_line_error
from tests.sim.serving import served
from tests.sim.test_virtual_head import flawed, gcode

Z_STEP_MM = 1.0 / STEPS_PER_MM[Z]


def run(*args: str, **kwargs):
    return CliRunner().invoke(cli, list(args), catch_exceptions=False, **kwargs)


def head_float(data: bytes, offset: int) -> float:
    """A float field as the firmware reads it (strtof: blank reads 0)."""
    text = data[offset : offset + 8].split(b"\0", 1)[0].decode("ascii")
    return float(text) if text.strip() else 0.0


def offsets(state) -> dict:
    """The nozzle offsets in the head's chip dump (spec: nozzle 0's X, Y, Z, B from
    0x40, nozzle 1's from 0x70, 8 bytes each)."""
    data = head_data(state)
    return {f"{axis}{n}": head_float(data, base + 8 * i)
            for n, base in ((0, 0x40), (1, 0x70)) for i, axis in enumerate("xyzb")}


def apart_from_hours(data: bytes) -> bytes:
    return data[:0xB8]


def attach(monkeypatch, state) -> VirtualPrinter:
    """The printer of `state` behind the pyusb backend, running while the host sleeps."""
    virtual = VirtualPrinter(state)
    virtual.settle()
    device = usb.core.find(idVendor=0x16D0, idProduct=0x081B,
                           backend=VirtualRoboxBackend(virtual))
    monkeypatch.setattr(devices, "_usb_devices", lambda: [device])
    monkeypatch.setattr(time, "sleep", lambda seconds: virtual.run_until(None, seconds))
    monkeypatch.setattr(cli_maintenance, "at_terminal", lambda: True)
    return virtual


# ------------------------------------------------------------------ nozzle height
def test_nozzle_height_finds_the_z_difference_and_writes_the_offsets(tmp_path):
    truth = 0.137
    state = flawed(tmp_path, "--nozzle-z-difference", str(truth))
    before = head_data(state)
    result = run("--device", f"sim-once:{state}", "calibrate", "nozzle-height", "--yes",
                 "--paper-z", "0.1", "--json")
    assert result.exit_code == 0, result.output
    out = json.loads(result.output)
    found = out["measured"]["z_difference_mm"]
    assert abs(found - truth) <= Z_STEP_MM  # the probe's resolution: a microstep of Z
    assert len(out["measured"]["z_deltas_mm"]["nozzle1"]) == 6
    o = offsets(state)
    # AutoMaker's split: -(paper) -/+ half the difference
    assert o["z0"] == pytest.approx(-0.1 - found / 2, abs=1e-5)
    assert o["z1"] == pytest.approx(-0.1 + found / 2, abs=1e-5)
    assert o["z1"] - o["z0"] == pytest.approx(truth, abs=Z_STEP_MM + 1e-5)
    after = head_data(state)
    assert after[:0x50] == before[:0x50] and after[0x58:0x80] == before[0x58:0x80]
    assert after[0x88:0xB8] == before[0x88:0xB8]
    assert status(state)["temperatures"]["nozzle0"]["mode"] == "0"


def test_nozzle_height_at_a_terminal_with_a_person_and_paper_through_pyusb(monkeypatch,
                                                                           tmp_path):
    """The person raises nozzle 0 until the 0.1 mm paper drags, looking at the real gap;
    after the calibration both nozzles stand at the paper's height over the bed at Z 0."""
    truth, paper = -0.21, 0.1
    state = flawed(tmp_path, "--nozzle-z-difference", str(truth))
    virtual = attach(monkeypatch, state)
    machine = virtual.hw.machine
    monkeypatch.setattr(click, "confirm", lambda *a, **k: True)
    seen = []

    def person(text, **_kwargs):
        gap = machine.tip_height() * Z_STEP_MM
        seen.append(round(gap, 3))
        return "y" if gap >= paper - 1e-6 else "u"

    monkeypatch.setattr(click, "prompt", person)
    result = run("--device", "usb", "calibrate", "nozzle-height", "--json")
    assert result.exit_code == 0, result.output
    out = json.loads(result.output)
    assert seen == pytest.approx([0.0, 0.05, 0.1], abs=0.002)
    assert out["measured"]["paper_z_mm"] == 0.1
    assert abs(out["measured"]["z_difference_mm"] - truth) <= Z_STEP_MM
    # the offsets at work, after a power cycle (the levelling the calibration did is
    # forgotten): each nozzle at Z 0 is a paper's height over the bed
    virtual.close()
    virtual = VirtualPrinter(state)
    virtual.settle()
    machine = virtual.hw.machine
    for line in ("G90", "T0", "G28 X Y", "G0 X105 Y75", "G28 Z", "G0 Z0"):
        gcode(virtual, line)
    assert machine.tip_height() * Z_STEP_MM == pytest.approx(paper, abs=3 * Z_STEP_MM)
    gcode(virtual, "T1")
    gcode(virtual, "G0 Z0")
    assert machine.b < 0
    assert machine.tip_height() * Z_STEP_MM == pytest.approx(paper, abs=3 * Z_STEP_MM)
    virtual.close()


# ------------------------------------------------------------------ nozzle opening
def test_nozzle_opening_finds_where_each_needle_opens_watching_the_plastic(monkeypatch,
                                                                          tmp_path):
    """The person says yes when plastic has come out of the nozzle being calibrated."""
    truth = (0.83, -0.61)
    state = flawed(tmp_path, "--b-open", "0.83,-0.61", filament=True)
    virtual = attach(monkeypatch, state)
    deposition = virtual.hw.machine.deposition
    monkeypatch.setattr(click, "confirm", lambda *a, **k: True)
    asked = []

    def person(text, **_kwargs):
        n = int(text.split("nozzle ")[1][0])
        asked.append(n)
        return "y" if deposition.released_mm3[n] > 0.0 else "n"

    monkeypatch.setattr(click, "prompt", person)
    result = run("--device", "usb", "calibrate", "nozzle-opening", "--json")
    assert result.exit_code == 0, result.output
    out = json.loads(result.output)
    o = out["written"]["head"]
    # the last B each stayed shut at: within one step of the seat, on its shut side
    assert truth[0] - calibration.B_STEP <= o["nozzle0_b_offset"] <= truth[0]
    assert truth[1] <= o["nozzle1_b_offset"] <= truth[1] + calibration.B_STEP
    assert asked.count(0) == math.ceil((truth[0] - calibration.B_START) / calibration.B_STEP) + 1
    # and the head's chip says the same
    virtual.close()
    assert offsets(state)["b0"] == o["nozzle0_b_offset"]
    assert offsets(state)["b1"] == o["nozzle1_b_offset"]


def test_nozzle_opening_over_the_served_printers_pty(tmp_path):
    """`sim serve --b-open`, and the answers given as options (the B a person saw)."""
    state = tmp_path / "p"
    assert run("sim", "load", "--state", str(state)).exit_code == 0
    with served(state, options=("--b-open", "0.77,-0.705")):
        # (sim:DIR reaches the printer served for DIR through its pty, as a host does,
        # and lets the fast printer's time pass as it polls, not the wall clock's)
        result = run("--device", f"sim:{state}", "calibrate", "nozzle-opening", "--yes",
                     "--opens-at", "0.78,-0.72", "--json")
    assert result.exit_code == 0, result.output
    assert json.loads(result.output)["measured"] == {"nozzle0_opens_at": "0.78",
                                                     "nozzle1_opens_at": "-0.72"}
    o = offsets(state)
    assert (o["b0"], o["b1"]) == (0.76, -0.7)
    assert json.loads((state / "flaws.json").read_text())["b_open"] == [0.77, -0.705]


def test_nozzle_opening_without_filament_is_refused_before_anything_moves(tmp_path):
    state = tmp_path / "p"  # empty feeds, as at power-up
    before = head_data(state) if (state / "head.eeprom").exists() else None
    one_line_error(run("--device", f"sim-once:{state}", "calibrate", "nozzle-opening",
                       "--yes", "--opens-at", "0.8,-0.8"), 1,
                   "feed E has no filament at its sensor")
    assert before is None or head_data(state) == before
    assert status(state)["position"] == {"X": 0.0, "Y": 0.0, "Z": 0.0, "B": 0.0}
    one_line_error(run("--device", f"sim-once:{state}", "calibrate", "nozzle-opening",
                       "--yes", "--opens-at", "0.7,-0.7x"), 2, "two numbers")


# ------------------------------------------------------------------ X and Y
def test_xy_prints_the_pattern_and_writes_what_the_person_read(tmp_path):
    """Nozzle 1 lands 0.1 mm right of and 0.15 mm in front of nozzle 0: its lines are
    shifted 0.05 mm more per pair, so pair D (-2) lines up across X, 9 (+3) along Y."""
    dx, dy = 0.1, -0.15
    state = flawed(tmp_path, "--xy-offset", f"{dx},{dy}", filament=True)
    before = offsets(state)
    length = json.loads((state / "filament.json").read_text())["E"]["length_mm"]
    kx, ky = round(-dx / calibration.XY_STEP), round(-dy / calibration.XY_STEP)
    letter, digit = "ABCDEFGHIJK"[kx + 5], str(ky + 6)
    assert (letter, digit) == ("D", "9")
    result = run("--device", f"sim-once:{state}", "calibrate", "xy", "--yes", "--x-pair",
                 letter, "--y-pair", digit, "--json")
    assert result.exit_code == 0, result.output
    out = json.loads(result.output)
    assert out["measured"]["nozzle1_off_by_mm"] == [dx, dy]
    after = offsets(state)
    # nozzle 1 moved by -(dx, dy) relative to nozzle 0, half each way (AutoMaker's split)
    assert (after["x1"] - after["x0"]) - (before["x1"] - before["x0"]) == \
        pytest.approx(-dx, abs=1e-4)
    assert (after["y1"] - after["y0"]) - (before["y1"] - before["y0"]) == \
        pytest.approx(-dy, abs=1e-4)
    assert after["x0"] == pytest.approx(before["x0"] + dx / 2, abs=1e-4)
    # the pattern was printed: each nozzle's prime line and 22 lines, each line the void
    # its opening leaves (the head's ejection volume) and the nozzle's width x 0.3 mm
    # over the part laid before the needle closes on the move; and what pressurising
    # each nozzle's feed took (at most 1 mm3)
    expected = 0.0
    for width, ejection in ((0.3, 0.3), (0.8, 0.6)):
        flow = width * 0.3
        expected += ejection + flow * 15  # the prime line
        expected += 22 * (ejection + flow * (12 - min(6, ejection / flow)))
    used_mm3 = (length - json.loads((state / "filament.json").read_text())["E"]
                ["length_mm"]) * 3.141592653589793 * 1.75 ** 2 / 4
    assert expected <= used_mm3 <= expected + 2.5


# ------------------------------------------------------------------ the common rules
@pytest.mark.parametrize("command,answers", [
    ("nozzle-height", ["--paper-z", "0.1"]),
    ("nozzle-opening", ["--opens-at", "0.8,-0.8"]),
    ("xy", ["--x-pair", "F", "--y-pair", "6"])])
def test_dry_run_and_unanswered_questions_change_nothing(tmp_path, command, answers):
    state = tmp_path / "p"
    assert run("sim", "load", "--state", str(state)).exit_code == 0
    before = head_data(state)
    result = run("--device", f"sim-once:{state}", "calibrate", command, "--dry-run")
    assert result.exit_code == 0, result.output
    assert "would: ask:" in result.output and "nothing sent" in result.output
    one_line_error(run("--device", f"sim-once:{state}", "calibrate", command, *answers), 2,
                   "answer them with --yes")
    one_line_error(run("--device", f"sim-once:{state}", "calibrate", command, "--yes"), 2,
                   "answer them with --")
    assert head_data(state) == before
    assert status(state)["position"] == {"X": 0.0, "Y": 0.0, "Z": 0.0, "B": 0.0}


def ctrl_c(*_args, **_kwargs):
    raise KeyboardInterrupt


@pytest.mark.parametrize("command,prompt_no", [
    ("nozzle-height", 0), ("nozzle-height", 1), ("nozzle-height", 3),
    ("nozzle-opening", 0), ("nozzle-opening", 1), ("nozzle-opening", 40),
    ("xy", 0), ("xy", 1), ("xy", 2)])
def test_ctrl_c_at_every_prompt_puts_the_head_back_and_the_heaters_off(
        monkeypatch, tmp_path, command, prompt_no):
    """prompt 0 is the first question; later ones are the paper's, the plastic's (the
    40th: nozzle 1's search) and the pattern's."""
    state = flawed(tmp_path, "--nozzle-z-difference", "0.1", "--b-open", "0.76,-0.8",
                   filament=True)
    virtual = attach(monkeypatch, state)
    before = virtual.hw.eeprom_bus.sockets[0].data[:0xB8]
    calls = [0]

    def confirm(*_args, **_kwargs):
        if prompt_no == 0:
            raise KeyboardInterrupt
        return True

    def prompt(text, **_kwargs):
        calls[0] += 1
        if calls[0] == prompt_no:
            raise KeyboardInterrupt
        if command == "nozzle-height":
            return "u"
        if command == "xy":
            return "F"
        n = int(text.split("nozzle ")[1][0])  # plastic seen at the nozzle, or not
        return "y" if virtual.hw.machine.deposition.released_mm3[n] > 0.0 else "n"

    monkeypatch.setattr(click, "confirm", confirm)
    monkeypatch.setattr(click, "prompt", prompt)
    result = run("--device", "usb", "calibrate", command)
    assert result.exit_code == 130, result.output
    assert "Traceback" not in result.output
    assert calls[0] == max(0, prompt_no)
    virtual.run_until(None, 1.0)  # (the firmware writes the chip after its ack)
    chip = bytes(virtual.hw.eeprom_bus.sockets[0].data)
    assert chip[:0xB8] == bytes(before)  # the head as it was, but for its hours
    heaters = virtual.firmware.heaters
    assert heaters.nozzle[0].mode == 0 and heaters.nozzle[1].mode == 0
    virtual.close()


def test_a_head_without_a_second_nozzle_or_reel_is_refused(tmp_path):
    state = tmp_path / "p"
    assert run("--device", f"sim-once:{state}", "write-eeprom", "head",
               "type_code=RBXDV-S1").exit_code == 0
    one_line_error(run("--device", f"sim-once:{state}", "calibrate", "xy", "--yes",
                       "--x-pair", "F", "--y-pair", "6"), 2, "has one nozzle")
    state2 = tmp_path / "q"
    assert run("--device", f"sim-once:{state2}", "format-eeprom", "reel0",
               "--yes").exit_code == 0
    one_line_error(run("--device", f"sim-once:{state2}", "calibrate", "nozzle-height",
                       "--yes", "--paper-z", "0.1"), 1, "reel0 gives no nozzle temperature")
