"""robox-cli purge and level-gantry against the virtual printer: what they measure and
write (the head EEPROM checked in its chip dump, both banks and their CRCs computed
here), the question and its option, --dry-run, and Ctrl-C or a refusal at every point
leaving the printer cold and its EEPROMs as they were."""

import json
import struct
import time
from pathlib import Path

import click
import pytest
import usb.core
from click.testing import CliRunner

from robox import maintenance
from robox.cli import cli
from robox.host import devices
from robox.sim.printer import VirtualPrinter
from robox.sim.usb_backend import VirtualRoboxBackend
from tests.cli.test_sdcard_cli import one_line_error
from tests.sim.serving import served
from tests.unit.test_eeprom_format import reference_crc

AREA_MM2 = 3.141592653589793 * 1.75 * 1.75 / 4


def run(*args: str, **kwargs):
    return CliRunner().invoke(cli, list(args), catch_exceptions=False, **kwargs)


def head_data(state: Path) -> bytes:
    raw = (state / "head.eeprom").read_bytes()
    for start in (0, 0x100):
        data, crc = raw[start : start + 192], raw[start + 192 : start + 196]
        assert struct.pack("<I", reference_crc(data)) == crc
    assert raw[:192] == raw[0x100:0x1C0]
    return raw[:192]


def left_mm(state: Path) -> float:
    return json.loads((state / "filament.json").read_text())["E"]["length_mm"]


@pytest.fixture
def loaded(tmp_path):
    """A virtual printer with filament at the nozzle and a PETG reel (240 °C) where the
    head last melted 210 °C."""
    state = tmp_path / "p"
    assert run("sim", "load", "--state", str(state)).exit_code == 0
    assert run("--device", f"sim-once:{state}", "reel", "program", "PETG").exit_code == 0
    return state


def status(state: Path) -> dict:
    result = run("--device", f"sim-once:{state}", "status", "--json")
    assert result.exit_code == 0, result.output
    return json.loads(result.output)


def test_purge_heats_halfway_lays_the_lines_and_records_the_new_material(loaded):
    before = head_data(loaded)
    assert before[0xB0:0xB8] == b"210.0000"
    length = left_mm(loaded)
    result = run("--device", f"sim-once:{loaded}", "purge", "--yes", "--json")
    assert result.exit_code == 0, result.output
    out = json.loads(result.output)
    # AutoMaker's purge temperature: halfway from 210 to 240
    assert out["measured"]["heater0"] == {"reel_c": 240, "last_c": 210, "purge_c": 225}
    assert out["measured"]["nozzles"] == [0, 1]  # a single-material head: both nozzles
    assert out["written"] == {"head": {"nozzle0_last_filament_temperature": 240}}
    after = head_data(loaded)
    assert after[0xB0:0xB8] == b"240.0000"
    assert after[:0xB0] == before[:0xB0]
    # and the head's hours went on counting while it was hot (the firmware's own write)
    assert float(after[0xB8:0xC0]) > float(before[0xB8:0xC0])
    # six lines of 20 mm3, and what pressurising the shut head took (at most 1 mm3 each)
    used = length - left_mm(loaded)
    assert 6 * 20 / AREA_MM2 <= used <= (6 * 20 + 6) / AREA_MM2 + 1
    s = status(loaded)
    assert s["temperatures"]["nozzle0"]["mode"] == "0"  # heater off at the end
    # and the next purge finds nothing to change: the head holds the reel's material
    again = json.loads(run("--device", f"sim-once:{loaded}", "purge", "--yes",
                           "--json").output)
    assert again["measured"]["heater0"] == {"reel_c": 240, "last_c": 240, "purge_c": 240}


def test_dry_run_lists_the_steps_and_changes_nothing(loaded):
    before = (head_data(loaded), left_mm(loaded), (loaded / "sdcard.img").read_bytes())
    result = run("--device", f"sim-once:{loaded}", "purge", "--dry-run", "--nozzle", "1")
    assert result.exit_code == 0, result.output
    assert "would: ask: Purge nozzle 1 at 225 °C" in result.output
    assert "    G36 E500 F400" in result.output and "nothing sent" in result.output
    assert (head_data(loaded), left_mm(loaded), (loaded / "sdcard.img").read_bytes()) == before


def test_away_from_a_terminal_the_question_needs_its_option(loaded):
    before = head_data(loaded)
    one_line_error(run("--device", f"sim-once:{loaded}", "purge"), 2, "answer them with --yes")
    assert head_data(loaded) == before
    assert status(loaded)["position"] == {"X": 0.0, "Y": 0.0, "Z": 0.0, "B": 0.0}


@pytest.mark.parametrize("answer,code", [("n\n", 1), ("\x03", 130)])
def test_at_a_terminal_no_or_ctrl_c_at_the_question_moves_nothing(loaded, monkeypatch,
                                                                    answer, code):
    from robox.cli import maintenance as cli_maintenance

    monkeypatch.setattr(cli_maintenance, "at_terminal", lambda: True)
    if answer == "\x03":
        def interrupted(*_args, **_kwargs):
            raise KeyboardInterrupt
        monkeypatch.setattr(click, "confirm", interrupted)
    before = head_data(loaded)
    result = run("--device", f"sim-once:{loaded}", "purge", input=answer)
    assert result.exit_code == code, result.output
    assert "Traceback" not in result.output
    assert head_data(loaded) == before
    assert status(loaded)["position"] == {"X": 0.0, "Y": 0.0, "Z": 0.0, "B": 0.0}


@pytest.mark.parametrize("at_step", range(1, 10))
def test_ctrl_c_at_any_step_leaves_the_heater_off_and_the_head_as_it_was(loaded, monkeypatch,
                                                                         at_step):
    """Steps: home and level, heat, six purge lines, heaters off; then the head write."""
    real_step = maintenance.Sequence.step
    seen = []

    def step(self, text):
        seen.append(text)
        if len(seen) == at_step + 1:  # Ctrl-C as the next step begins
            raise KeyboardInterrupt
        real_step(self, text)

    monkeypatch.setattr(maintenance.Sequence, "step", step)
    before = head_data(loaded)
    result = run("--device", f"sim-once:{loaded}", "purge", "--yes")
    assert result.exit_code == 130, result.output
    assert "Traceback" not in result.output
    # the head as it was, but for the hours the firmware counts while it is hot
    assert head_data(loaded)[:0xB8] == before[:0xB8]
    s = status(loaded)
    assert s["temperatures"]["nozzle0"]["mode"] == "0" and not s["busy"]


def test_a_missing_reel_is_refused_before_anything_moves(tmp_path):
    state = tmp_path / "p"
    assert run("--device", f"sim-once:{state}", "status").exit_code == 0
    (state / "reel0.eeprom").write_bytes(b"\xff" * 512)  # a reel with a blank chip
    one_line_error(run("--device", f"sim-once:{state}", "purge", "--yes"), 1,
                   "nozzle 0 is fed from reel0, which has no valid EEPROM")
    assert status(state)["position"]["X"] == 0.0


def test_a_formatted_head_is_refused_before_anything_moves(loaded):
    assert run("--device", f"sim-once:{loaded}", "format-eeprom", "head", "--yes").exit_code == 0
    one_line_error(run("--device", f"sim-once:{loaded}", "purge", "--yes"), 1,
                   "the head's EEPROM gives no head type")
    assert status(loaded)["position"]["X"] == 0.0


def test_a_temperature_above_the_heads_is_refused(loaded):
    one_line_error(run("--device", f"sim-once:{loaded}", "purge", "--yes",
                       "--temperature", "270"), 2, "270 °C is above the 260 °C")


def test_level_gantry_over_the_served_printers_pty(tmp_path):
    state = tmp_path / "p"
    with served(state) as pty:
        result = run("--device", f"serial:{pty}", "level-gantry", "--yes", "--json")
        assert result.exit_code == 0, result.output
        out = json.loads(result.output)
        position = json.loads(run("--device", f"serial:{pty}", "status", "--json").output)
    assert out["measured"]["z_delta_mm"] == pytest.approx(0.0, abs=0.001)
    assert out["steps"][0].startswith("home, probe Z at each leadscrew")
    assert position["position"]["X"] == pytest.approx(113.0, abs=0.01)  # parked mid-way


def test_purge_through_the_pyusb_backend(monkeypatch, tmp_path):
    virtual = VirtualPrinter(tmp_path / "p")  # a head calibrated as one leaves the factory
    virtual.settle()
    device = usb.core.find(idVendor=0x16D0, idProduct=0x081B,
                           backend=VirtualRoboxBackend(virtual))
    monkeypatch.setattr(devices, "_usb_devices", lambda: [device])
    # the printer behind the backend runs while the host reads; while the host sleeps
    # between looks, it runs for the time slept, as an attached printer would
    monkeypatch.setattr(time, "sleep", lambda seconds: virtual.run_until(None, seconds))
    result = run("--device", "usb", "purge", "--yes", "--nozzle", "0", "--temperature",
                 "215", "--json")
    assert result.exit_code == 0, result.output
    out = json.loads(result.output)
    assert out["measured"]["heater0"]["purge_c"] == 215
    assert virtual.firmware.heaters.nozzle[0].mode == 0


def tip_mm(state: Path) -> float:
    return json.loads((state / "filament.json").read_text())["E"]["tip_mm"]


def test_unload_pulls_the_filament_back_behind_the_drive_and_leaves_the_heater_off(loaded):
    assert tip_mm(loaded) == 380.0  # at the nozzle
    result = run("--device", f"sim-once:{loaded}", "unload", "--yes", "--json")
    assert result.exit_code == 0, result.output
    assert json.loads(result.output)["measured"] == {"unloaded": "E"}
    assert tip_mm(loaded) < 0  # out of the drive, into the person's hand
    assert status(loaded)["temperatures"]["nozzle0"]["mode"] == "0"


def test_head_change_parks_unloads_unlocks_and_reads_the_new_head(loaded):
    result = run("--device", f"sim-once:{loaded}", "head-change", "--yes", "--swapped",
                 "--json")
    assert result.exit_code == 0, result.output
    out = json.loads(result.output)
    assert out["measured"]["new_head"] == {"type_code": "RBX01-SM",
                                           "unique_id": "RBXSIMHEAD0001"}
    assert out["steps"][-2:] == ["unlock the door", "read the new head"]
    assert tip_mm(loaded) < 0


def test_head_change_away_from_a_terminal_needs_every_answer_before_it_moves(loaded):
    one_line_error(run("--device", f"sim-once:{loaded}", "head-change", "--yes"), 2,
                   "answer them with --swapped")
    assert tip_mm(loaded) == 380.0
    assert status(loaded)["position"] == {"X": 0.0, "Y": 0.0, "Z": 0.0, "B": 0.0}


def test_ctrl_c_at_the_swap_question_leaves_the_printer_cold(loaded, monkeypatch):
    from robox.cli import maintenance as cli_maintenance

    monkeypatch.setattr(cli_maintenance, "at_terminal", lambda: True)
    answers = iter([True])

    def confirm(*_args, **_kwargs):
        try:
            return next(answers)
        except StopIteration:
            raise KeyboardInterrupt from None

    monkeypatch.setattr(click, "confirm", confirm)
    result = run("--device", f"sim-once:{loaded}", "head-change")
    assert result.exit_code == 130, result.output
    assert "unlock the door" in result.output and "read the new head" not in result.output
    s = status(loaded)
    assert s["temperatures"]["nozzle0"]["mode"] == "0" and not s["busy"]


def test_eject_stuck_pushes_through_then_cools_and_pulls_the_filament_out(loaded):
    length = left_mm(loaded)
    result = run("--device", f"sim-once:{loaded}", "eject-stuck", "--yes", "--json")
    assert result.exit_code == 0, result.output
    out = json.loads(result.output)
    # the reel's first-layer temperature (PETG: 245), a neck at 140, snapped at 125
    assert out["measured"] == {"heat_c": 245.0, "neck_c": 140.0, "snap_c": 125.0}
    assert out["steps"][4:7] == ["let nozzle 0 cool to 140 °C", "draw a neck in the filament",
                                 "let nozzle 0 cool to 125 °C"]
    assert tip_mm(loaded) < 0  # out of the drive
    # two pushes of 70 mm3 through the nozzles (and what pressurising took)
    assert 140 / AREA_MM2 <= length - left_mm(loaded) <= 142 / AREA_MM2 + 1
    assert status(loaded)["temperatures"]["nozzle0"]["mode"] == "0"


def test_eject_stuck_frees_each_nozzle_of_a_dual_material_head_with_its_own_heater(tmp_path):
    """Nozzle 0 of an RBX01-DM is fed from reel 1 (D) and heated by heater 0, nozzle 1
    from reel 0 (E) by heater 1: each is pushed through (120 mm3, AutoMaker's dual
    macros), necked at 160 °C, snapped at 125 °C and pulled out of its drive."""
    state = tmp_path / "p"
    assert run("sim", "load", "--state", str(state), "--feed", "both").exit_code == 0
    assert run("eeprom", "new", "reel", "-o", str(state / "reel1.eeprom")).exit_code == 0
    sim = f"sim-once:{state}"
    for args in (("write-eeprom", "head", "type_code=RBX01-DM"),
                 ("reel", "program", "PETG"), ("reel", "program", "PLA", "--reel", "1")):
        result = run("--device", sim, *args)
        assert result.exit_code == 0, result.output
    feeds = json.loads((state / "filament.json").read_text())
    result = run("--device", sim, "eject-stuck", "--yes", "--json")
    assert result.exit_code == 0, result.output
    out = json.loads(result.output)
    pla_c = json.loads(run("reel", "materials", "--json").output)["PLA"][
        "first_layer_nozzle_c"]
    assert out["measured"] == {"heater0": {"heat_c": pla_c, "neck_c": 160.0, "snap_c": 125.0},
                               "heater1": {"heat_c": 245.0, "neck_c": 160.0, "snap_c": 125.0}}
    assert "let nozzle 0 cool to 160 °C" in out["steps"]
    assert "let nozzle 1 cool to 125 °C" in out["steps"]
    after = json.loads((state / "filament.json").read_text())
    for feed in ("D", "E"):
        assert after[feed]["tip_mm"] < 0, feed  # out of its drive
        used = feeds[feed]["length_mm"] - after[feed]["length_mm"]
        assert 120 / AREA_MM2 <= used <= 122 / AREA_MM2 + 1, feed
    s = status(state)
    assert s["temperatures"]["nozzle0"]["mode"] == "0"
    assert s["temperatures"]["nozzle1"]["mode"] == "0"
    result = run("--device", sim, "eject-stuck", "--nozzle", "1", "--dry-run")
    assert "push through nozzle 1" in result.output and "nozzle 0" not in result.output


def test_eject_stuck_with_a_nozzle_on_a_single_material_head_is_refused(loaded):
    one_line_error(run("--device", f"sim-once:{loaded}", "eject-stuck", "--yes", "--nozzle",
                       "1"), 2, "they are freed together")


@pytest.mark.parametrize("at_step", [4, 6, 7])
def test_ctrl_c_while_eject_stuck_cools_leaves_the_heater_off(loaded, monkeypatch, at_step):
    real_step = maintenance.Sequence.step
    seen = []

    def step(self, text):
        seen.append(text)
        if len(seen) == at_step + 1:
            raise KeyboardInterrupt
        real_step(self, text)

    monkeypatch.setattr(maintenance.Sequence, "step", step)
    result = run("--device", f"sim-once:{loaded}", "eject-stuck", "--yes")
    assert result.exit_code == 130, result.output
    s = status(loaded)
    assert s["temperatures"]["nozzle0"]["mode"] == "0" and not s["busy"]


def test_load_waits_for_the_printers_own_load_through_the_pyusb_backend(monkeypatch, tmp_path):
    """The question is answered as the person at the printer would: filament pushed into
    the inlet by hand until the drive takes it (the index wheel turns with nothing at
    the sensor, and the printer starts its own load)."""
    from robox.cli import maintenance as cli_maintenance
    from robox.hardware.machine import E

    virtual = VirtualPrinter(tmp_path / "p")
    virtual.settle()
    virtual.run_until(None, 5.0)  # (no automatic load within 4 s of power-up)
    device = usb.core.find(idVendor=0x16D0, idProduct=0x081B,
                           backend=VirtualRoboxBackend(virtual))
    monkeypatch.setattr(devices, "_usb_devices", lambda: [device])
    monkeypatch.setattr(time, "sleep", lambda seconds: virtual.run_until(None, seconds))
    monkeypatch.setattr(cli_maintenance, "at_terminal", lambda: True)
    machine = virtual.hw.machine

    def person(*_args, **_kwargs):
        machine.insert_filament(E, tip_mm=-5.0)
        machine.feed_by_hand(E, 8.0)
        assert virtual.run_until(lambda: virtual.firmware.position.what != 0, 10)
        return True

    monkeypatch.setattr(click, "confirm", person)
    result = run("--device", "usb", "load", "--json")
    assert result.exit_code == 0, result.output
    assert json.loads(result.output)["measured"] == {"loaded": "E"}
    assert machine.filament[E].tip == machine.nozzle_steps(E)  # at the nozzle
    # and again: the sensor sees it, so there is nothing to load
    one_line_error(run("--device", "usb", "load", "--inserted"), 1,
                   "feed E already has filament at its sensor")


def test_load_with_nothing_pushed_in_says_so(tmp_path):
    state = tmp_path / "p"
    one_line_error(run("--device", f"sim-once:{state}", "load", "--inserted"), 1,
                   "no filament reached feed E's sensor")
    one_line_error(run("--device", f"sim-once:{state}", "load"), 2,
                   "answer them with --inserted")


def test_every_guided_command_through_the_served_printers_pty(tmp_path):
    """Each command as a script runs it on a served printer (`sim:DIR` reaches it through
    its pty), its questions answered by their options; `sim-once` (the pyusb backend)
    runs each in the tests above."""
    state = tmp_path / "p"
    assert run("sim", "load", "--state", str(state)).exit_code == 0
    dev = ("--device", f"sim:{state}")
    commands = [
        ("reel", "program", "PETG"),
        ("reel", "show", "--json"),
        ("purge", "--yes", "--json"),
        ("level-gantry", "--yes", "--json"),
        ("calibrate", "nozzle-height", "--yes", "--paper-z", "0.1", "--json"),
        ("calibrate", "nozzle-opening", "--yes", "--opens-at", "0.72,-0.72", "--json"),
        ("calibrate", "xy", "--yes", "--x-pair", "E", "--y-pair", "7", "--json"),
        ("eject-stuck", "--yes", "--json"),
        ("head-change", "--yes", "--swapped", "--json"),
    ]
    with served(state):
        outputs = {}
        for args in commands:
            result = run(*dev, *args)
            assert result.exit_code == 0, (args, result.output)
            if "--json" in args:
                outputs[args[:2]] = json.loads(result.output)
        # what a person does by hand cannot come through a pty: load finds nothing pushed
        one_line_error(run(*dev, "load", "--inserted"), 1, "no filament reached")
        one_line_error(run(*dev, "unload", "--yes", "--feed", "D"), 2,
                       "a RBX01-SM head has no feed D")
    assert outputs[("purge", "--yes")]["written"]["head"] == {
        "nozzle0_last_filament_temperature": 240}
    assert outputs[("calibrate", "nozzle-opening")]["written"]["head"] == {
        "nozzle0_b_offset": 0.7, "nozzle1_b_offset": -0.7}
    assert outputs[("calibrate", "xy")]["measured"]["nozzle1_off_by_mm"] == [0.05, -0.05]
    assert tip_mm(state) < 0  # eject-stuck pulled the filament out
    data = head_data(state)
    # nozzle-height: the paper's 0.1 mm, less half a perfect head's Z difference (0, to
    # the microstep the probe reads)
    assert float(data[0x50:0x58]) == pytest.approx(-0.1, abs=2e-4)


QUESTIONS = {  # command -> its yes/no questions, in the order asked
    "purge": 1, "level-gantry": 1, "unload": 1, "eject-stuck": 1, "head-change": 2,
    "load": 1}


@pytest.mark.parametrize("command,at", [(c, k) for c, n in QUESTIONS.items()
                                        for k in range(1, n + 1)])
def test_ctrl_c_at_each_question_of_each_command(loaded, monkeypatch, command, at):
    """At a terminal, Ctrl-C at the question: status 130, no traceback, the heaters off
    and the head's EEPROM as it was but for the hours the firmware counts."""
    from robox.cli import maintenance as cli_maintenance

    monkeypatch.setattr(cli_maintenance, "at_terminal", lambda: True)
    asked = [0]

    def confirm(*_args, **_kwargs):
        asked[0] += 1
        if asked[0] == at:
            raise KeyboardInterrupt
        return True

    monkeypatch.setattr(click, "confirm", confirm)
    if command == "load":
        assert run("sim", "unload", "--state", str(loaded)).exit_code == 0
    before = head_data(loaded)
    result = run("--device", f"sim-once:{loaded}", command)
    assert result.exit_code == 130, result.output
    assert "Traceback" not in result.output and asked[0] == at
    assert head_data(loaded)[:0xB8] == before[:0xB8]
    s = status(loaded)
    assert s["temperatures"]["nozzle0"]["mode"] == "0" and not s["busy"]
    if at == 1:
        assert s["position"] == {"X": 0.0, "Y": 0.0, "Z": 0.0, "B": 0.0}


class HoursCounting:
    """A head whose firmware counts its hours on between a write and the next read (a
    hot head on a fast printer), and, with `corrupt`, a chip that loses a byte."""

    def __init__(self, data: bytes, corrupt: bool = False):
        self.data = bytearray(data)
        self.corrupt = corrupt

    def write_eeprom(self, which, address, data):
        assert (which, address, len(data)) == ("head", 0, 192)
        self.data[:] = data
        self.data[0xB8:0xC0] = b"12.50000"  # the firmware's own write of the hours
        if self.corrupt:
            self.data[0x50] ^= 0x01

    def read_eeprom(self, which):
        return bytes(self.data)


def test_a_head_write_is_checked_but_for_the_hours_the_firmware_counts_meanwhile():
    from robox.formats import eeprom as fmt

    data = bytearray(192)
    fmt.set_field(data, "head", "type_code", "RBX01-SM")
    fmt.set_field(data, "head", "head_hours", 12.25)
    head = HoursCounting(bytes(data))
    maintenance.write_head(head, bytes(data), {"nozzle0_z_offset": -0.1}, "test")
    assert head.data[0x50:0x58] == b"-0.10000" and head.data[0xB8:0xC0] == b"12.50000"
    with pytest.raises(maintenance.RoboxError, match="reads back other than was written"):
        maintenance.write_head(HoursCounting(bytes(data), corrupt=True), bytes(data),
                               {"nozzle0_z_offset": -0.1}, "test")
