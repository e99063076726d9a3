"""The virtual printer's head given true imperfections (`robox-cli sim head`, or the same
options on `sim serve`): the Z switch is the selected nozzle touching the bed, and the
record in the state directory is checked before it is kept."""

import json

import pytest
from click.testing import CliRunner

from robox.cli import cli
from robox.hardware.machine import STEPS_PER_MM, Z
from robox.sim.printer import VirtualPrinter
from tests.cli.test_sdcard_cli import one_line_error

Z_STEP_MM = 1.0 / STEPS_PER_MM[Z]


def run(*args: str, **kwargs):
    return CliRunner().invoke(cli, list(args), catch_exceptions=False, **kwargs)


def flawed(tmp_path, *options: str, filament: bool = False):
    """A virtual printer's state with its head's flaws (and filament at the nozzle)."""
    state = tmp_path / "p"
    result = run("sim", "head", "--state", str(state), *options)
    assert result.exit_code == 0, result.output
    if filament:
        assert run("sim", "load", "--state", str(state)).exit_code == 0
    return state


def gcode(virtual: VirtualPrinter, line: str, seconds: float = 40.0) -> None:
    """A line through the execute buffer, then `seconds` of the printer's time."""
    data = line.encode() + b"\r"
    virtual.transact(b"\x95" + b"%04x" % len(data) + data)
    virtual.run_until(None, seconds)


def test_the_z_switch_is_the_selected_nozzle_touching_the_bed(tmp_path):
    """With nozzle 1 0.25 mm lower, homing Z with it selected stops 0.25 mm higher:
    M113 after T1 and G28 Z? says so, as the printer's own probe would."""
    state = flawed(tmp_path, "--nozzle-z-difference", "0.25")
    virtual = VirtualPrinter(state)
    virtual.settle()
    for line in ("G90", "T0", "G28 X Y", "G0 X105 Y75", "G28 Z"):
        gcode(virtual, line)
    machine = virtual.hw.machine
    assert abs(machine.tip_height()) <= 2  # where the switch trips (within microsteps)
    gcode(virtual, "T1")
    assert machine.b < 0  # the valve on nozzle 1's side: its tip is the lower one
    assert machine.tip_height() == pytest.approx(machine.nozzle_height() - 0.25 / Z_STEP_MM)
    gcode(virtual, "G28 Z?")
    reply = virtual.transact(b"\x950005M113\r")
    delta = float(reply[5:].split(b"\r\n")[0].split(b":")[1])
    assert delta == pytest.approx(0.25, abs=2 * Z_STEP_MM)
    virtual.close()


def test_sim_head_shows_records_and_refuses(tmp_path):
    state = tmp_path / "p"
    result = run("sim", "head", "--state", str(state), "--b-open", "0.8,-0.64", "--json")
    assert json.loads(result.output)["flaws"] == {"b_open": [0.8, -0.64]}
    result = run("sim", "head", "--state", str(state), "--xy-offset", "0.1,-0.05")
    assert "needles open at B 0.8 (nozzle 0) and -0.64 (nozzle 1)" in result.output
    assert "nozzle 1 off by X 0.1 mm, Y -0.05 mm" in result.output
    assert json.loads((state / "flaws.json").read_text()) == {
        "b_open": [0.8, -0.64], "xy_offset_mm": [0.1, -0.05]}
    one_line_error(run("sim", "head", "--state", str(state), "--b-open", "0.8,0.6"), 2,
                   "nozzle 1's at a negative one")
    one_line_error(run("sim", "head", "--state", str(state), "--nozzle-z-difference", "5"),
                   2, "5 is beyond ±2")
    one_line_error(run("sim", "head", "--state", str(state), "--xy-offset", "0.1"), 2,
                   "two numbers with a comma between")
    assert run("sim", "head", "--state", str(state), "--perfect").output.startswith(
        "head: perfect")
    assert not (state / "flaws.json").exists()
