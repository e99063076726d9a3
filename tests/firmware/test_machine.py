"""Position, motion, heaters, bookkeeping, reprogramming and parameters of the model."""

import math

import pytest

from robox.errors import PowerCut
from robox.formats.eeprom import EepromIndex
from robox.formats.firmware import to_sd_text, word_sum
from robox.formats.protocol import ErrorBit
from robox.hardware.faults import Landing, PowerPlan
from robox.sim import images
from tests.firmware.wire import float8, ident, job_text


@pytest.fixture
def wire(wire):
    wire.clear()
    return wire


def run_lines(wire, *lines: str) -> None:
    wire.gcode(job_text(list(lines)))
    job = wire.fw.job
    assert wire.printer.run_until(lambda: not job.execute_buffer and job.current is None
                                  and wire.fw.motion.empty(), 10000)


def test_m109_and_m190_finish_in_simulated_time(wire):
    start = wire.fw.clock.now
    run_lines(wire, "M140 S60", "M104 S210", "M190", "M109")
    heaters = wire.printer.hw.machine.heaters
    assert abs(heaters["nozzle0"].temperature - 210) <= 210 * 0.017 + 1
    assert abs(heaters["bed"].temperature - 60) <= 60 * 0.03 + 1
    assert 30 < wire.fw.clock.now - start < 3600
    m105 = wire.gcode(b"M105\r")
    assert m105.startswith(b"S:2") and m105.endswith(b"ok\r\n")


def test_remaining_filament_is_booked_to_the_reel_every_7_2_s(wire):
    eeproms = wire.fw.eeproms
    before = eeproms.get_float(EepromIndex.REEL0, "remaining_filament")
    run_lines(wire, "G1 E500 F600")  # 500 mm³ = 207.9 mm of 1.75 mm filament
    used = 500 / (math.pi * 1.75**2 / 4)
    wire.printer.run_until(lambda: False, 8.0)
    after = eeproms.get_float(EepromIndex.REEL0, "remaining_filament")
    assert before - after == math.floor(used)
    assert wire.fw.position.destination[3] == pytest.approx(used - math.floor(used),
                                                                abs=0.01)
    wire.printer.settle()
    chip = bytes(wire.printer.hw.eeprom_bus.sockets[1].data)
    assert chip[0xB8:0xC0] == f"{after:f}"[:8].encode()


def test_m109_ignores_s_it_only_waits(wire):
    run_lines(wire, "M109 S200")
    nozzle = wire.fw.heaters.nozzle[0]
    assert nozzle.mode == 0 and nozzle.target[0] == 210  # the reel's target, unchanged


def test_head_hours_grow_while_the_head_is_hot(wire):
    run_lines(wire, "M104 S200", "M109")
    hours = wire.fw.eeproms.get_float(EepromIndex.HEAD, "head_hours")
    wire.printer.run_until(lambda: False, 72.0)
    grown = wire.fw.eeproms.get_float(EepromIndex.HEAD, "head_hours") - hours
    assert grown == pytest.approx(0.02, abs=0.0025)


def test_a_new_reel_loads_its_settings(wire):
    from robox.hardware.eeprom import EepromChip
    bus = wire.printer.hw.eeprom_bus
    bus.sockets[1].unplug()
    wire.printer.run_until(lambda: wire.fw.eeproms.status(EepromIndex.REEL0) == 0, 2)
    chip = EepromChip(images.reel_eeprom(1000.0), wire.printer.hw.clock)
    data = bytearray(chip.data)
    data[0x50:0x58] = b"2.850000"
    from robox.formats.eeprom import chip_image
    chip = EepromChip(chip_image(bytes(data[:192])), wire.printer.hw.clock)
    bus.insert(EepromIndex.REEL0, chip)
    wire.printer.run_until(lambda: wire.fw.eeproms.status(EepromIndex.REEL0) == 2, 2)
    assert wire.fw.position.diameter[0] == pytest.approx(2.85)


# ------------------------------------------------------------ reprogramming
def upload_firmware(wire, image: bytes, file_id: str = "firmware") -> None:
    wire.upload(file_id, to_sd_text(image), job=False)


def test_a_good_firmware_file_is_flashed_and_the_printer_resets(wire):
    image = images.firmware_image("r999new", size=32 * 1024, seed=5)
    upload_firmware(wire, image)
    assert set(wire.ack(b"\x8f" + ident("firmware"))) == {"0"}
    wire.printer.run_until(lambda: wire.fw.resets == 1, 1.0)
    assert wire.fw.resets == 1
    assert wire.raw(b"\xb4") == b"\xe4r999new\0"
    flash = wire.printer.hw.flash
    assert flash.read(0, len(image)) == image
    assert not wire.fw.errors.is_set(ErrorBit.FLASH_CHECKSUM)


@pytest.mark.parametrize("damage", ["checksum", "short", "missing", "odd"])
def test_a_bad_firmware_file_leaves_flash_alone(wire, damage):
    flash_before = wire.printer.hw.flash.read(0, 131072)
    image = bytearray(images.firmware_image("r1bad", size=8192, seed=9))
    if damage == "checksum":
        image[100] ^= 1
        upload_firmware(wire, bytes(image))
    elif damage == "short":
        upload_firmware(wire, images.firmware_image("r1", size=2048))
    elif damage == "odd":
        wire.upload("firmware", to_sd_text(bytes(image)) + b"0", job=False)
    errors = wire.ack(b"\x8f" + ident("firmware"))
    assert errors[ErrorBit.BAD_FIRMWARE_FILE] == "1"
    wire.printer.run_until(lambda: False, 0.5)
    assert wire.fw.resets == 0 and wire.printer.hw.flash.read(0, 131072) == flash_before


def test_a_firmware_file_still_being_written_does_not_count(wire):
    text = to_sd_text(images.firmware_image("r2", size=8192))
    wire.ok(b"\x90" + ident("fw"))
    wire.ok(b"\x91" + b"00000000" + text[:512])
    assert wire.ack(b"\x8f" + ident("fw"))[ErrorBit.BAD_FIRMWARE_FILE] == "1"


def test_a_power_cut_while_flashing_shows_at_boot(wire):
    image = images.firmware_image("r3cut", size=16 * 1024, seed=3)
    upload_firmware(wire, image)
    wire.printer.supply(PowerPlan(cut_at=10, landing=Landing("partial", 100)))
    wire.usb.host_write(b"\x8f" + ident("firmware"))
    wire.printer.run_until(lambda: wire.usb.reply_waiting >= 65, 1.0)
    wire.usb.host_read(65)
    with pytest.raises(PowerCut):
        wire.printer.run_until(lambda: False, 1.0)
    wire.printer.supply(None)
    from robox.firmware.main import Firmware
    fw = Firmware(wire.printer.hw)  # power comes back
    assert fw.errors.is_set(ErrorBit.FLASH_CHECKSUM)


def test_boot_checks_the_flash_sum(wire):
    flash = wire.printer.hw.flash
    page = bytearray(flash.page(3))
    page[7] ^= 0xFF
    flash.write_page(3, bytes(page))
    wire.raw(b"\xfd")
    wire.printer.run_until(lambda: wire.fw.resets == 1, 1.0)
    assert wire.fw.errors.is_set(ErrorBit.FLASH_CHECKSUM)
    assert word_sum(flash.read(0, images.IMAGE_BYTES)) != 0


def test_parameters_survive_a_reset_but_not_another_build(wire):
    wire.gcode(b"M92 X100 Y101\rM500\r")
    wire.printer.run_until(lambda: not wire.fw.job.execute_buffer, 5)
    wire.raw(b"\xfd")
    wire.printer.run_until(lambda: wire.fw.resets == 1, 1.0)
    m503 = wire.line(b"M503\n")
    assert b"M92 X100.000000 Y101.000000 Z6400.000000" in m503
    version = wire.fw.parameters.version
    assert m503.startswith(f"Ver: {version:08x}\r\n".encode())
    upload_firmware(wire, images.firmware_image("r4", size=8192, seed=4))
    wire.raw(b"\x8f" + ident("firmware"))
    wire.printer.run_until(lambda: wire.fw.resets == 2, 1.0)
    assert b"M92 X133.699997" in wire.line(b"M503\n")  # another build: defaults


def test_m502_restores_defaults_and_m501_reloads(wire):
    run_lines(wire, "M92 X90", "M500", "M502")
    assert wire.fw.parameters.values["steps_per_unit"]["X"] == pytest.approx(133.7)
    run_lines(wire, "M501")
    assert wire.fw.parameters.values["steps_per_unit"]["X"] == 90.0


@pytest.mark.parametrize(("lines", "spu"), [(("M92 X90",), 90.0),
                                             (("M92 X90", "M502"), 133.7),
                                             (("M92 X90", "M500", "M502", "M501"), 90.0)])
def test_moves_take_the_steps_per_unit_in_force(wire, lines, spu):
    """A move is made with the steps per unit the parameters hold now: M92 changes them,
    M502 brings back the factory's (in the parameters the motion reads, not a copy),
    M501 the saved ones."""
    run_lines(wire, "G92 X0 Y0 Z0", *lines, "G1 X10 F3000")
    wire.printer.run_until(lambda: wire.fw.motion.empty(), 10.0)
    # in 2 mm segments of whole steps, the rounding carried from one to the next
    assert abs(wire.printer.hw.machine.x - 10 * spu) <= 1


@pytest.mark.parametrize(("lines", "x"), [(("M520 X5",), 5.0), (("M520 X5", "M502"), 10.0)])
def test_m502_brings_back_the_travel_a_move_is_held_to(wire, lines, x):
    """M520 shortens X's travel, M502 restores the factory's 210 mm for the moves that
    follow."""
    run_lines(wire, "G28 X Y", *lines)
    at_zero = wire.printer.hw.machine.x
    run_lines(wire, "G1 X10 F3000")
    assert abs(wire.printer.hw.machine.x - at_zero - x * 133.7) <= 1


def test_powered_off_whilst_hot(wire):
    run_lines(wire, "M104 S200", "M109")
    wire.printer.run_until(lambda: False, 0.1)
    from robox.firmware.main import Firmware
    fw = Firmware(wire.printer.hw)  # power cut and back, nozzle still hot
    assert fw.errors.is_set(ErrorBit.POWEROFF_WHILST_HOT)


def test_a_tool_change_applies_the_heads_tool_offsets(wire):
    offset = b"2.500000"
    wire.ok(b"\xa0" + b"70" + b"08" + offset)  # nozzle1_x_offset in the head EEPROM
    wire.printer.settle()
    run_lines(wire, "G92 X0 Y0 Z0", "G1 X10 F3000", "T1", "G1 X10")
    machine_x = wire.printer.hw.machine.x / 133.7
    assert machine_x == pytest.approx(12.5, abs=0.01)
    # less the tool offset: 12.5 mm is 1671 whole steps, 12.49813 mm
    reported = wire.gcode(b"M114\r")
    assert float(reported.split(b" ")[0][2:]) == pytest.approx(9.99813, abs=2e-6)
    assert wire.gcode(b"M114\r").endswith(b"T:1\r\nok\r\n")


def test_set_d_filament_info(wire):
    wire.ok(b"\xc9" + float8(2.85) + float8(0.9))
    position = wire.fw.position
    assert [position.diameter[1], position.multiplier[1]] == [pytest.approx(2.85),
                                                              pytest.approx(0.9)]


_THERMISTORS = {"bed": ErrorBit.BED_THERMISTOR, "nozzle0": ErrorBit.NOZZLE0_THERMISTOR,
                "nozzle1": ErrorBit.NOZZLE1_THERMISTOR}


@pytest.mark.parametrize("plant, seen_after_s, other", [("bed", 60, "nozzle0"),
                                                        ("nozzle0", 20, "bed")])
def test_a_thermistor_fault_sets_its_error_and_turns_that_heater_off(wire, plant,
                                                                     seen_after_s, other):
    """A lost thermistor reads cold, so its heater runs at full power; after
    `seen_after_s` of that the fault is seen: that heater's error, that heater off."""
    run_lines(wire, "M104 S200", "M140 S60")
    wire.printer.hw.machine.heaters[plant].thermistor_ok = False
    heaters = wire.fw.heaters
    controller = {"bed": heaters.bed, "nozzle0": heaters.nozzle[0]}
    wire.printer.run_until(lambda: False, seen_after_s - 5)
    assert not wire.fw.errors.is_set(_THERMISTORS[plant])
    wire.printer.run_until(lambda: False, 10)
    assert [name for name, bit in _THERMISTORS.items() if wire.fw.errors.is_set(bit)] == [plant]
    assert controller[plant].mode == 0 and controller[other].mode == 1


def test_a_nozzle_target_is_held_to_the_limit_of_the_head_fitted_now(wire):
    """The limit follows the head's type as the EEPROM reads it: another head fitted
    (an RBXDV-S1 allows 300 degrees, an RBX01-SM 260), another limit."""
    from robox.hardware.eeprom import EepromChip

    def fit(type_code: str) -> None:
        bus = wire.printer.hw.eeprom_bus
        bus.insert(EepromIndex.HEAD, None)
        wire.printer.run_until(lambda: wire.fw.eeproms.status(EepromIndex.HEAD) == 0, 5.0)
        bus.insert(EepromIndex.HEAD, EepromChip(images.head_eeprom(True, type_code),
                                                wire.printer.hw.clock))
        wire.printer.run_until(lambda: wire.fw.eeproms.status(EepromIndex.HEAD) == 2, 5.0)

    for type_code, limit in (("RBXDV-S1", 300.0), ("RBX01-SM", 260.0), ("RBXDV-S1", 300.0)):
        fit(type_code)
        run_lines(wire, "M104 S290")
        wire.printer.run_until(lambda: False, 2.0)  # a sample or two
        assert wire.fw.heaters.nozzle[0].target[0] == min(290.0, limit), type_code


def _features_by_the_firmware_s_rule(type_code: str) -> tuple[bool, bool, bool, bool]:
    """eeprom.c's does_head_have_*: an old type name, or an "RX" name's digit at 7
    (dual material: & 3 == 2; two fans: & 4) or at 6 (B axis: & 1; PRTD: & 4)."""
    name = type_code.encode().ljust(8, b"\0")[:8]
    rx = name[:2] == b"RX"
    at6, at7 = (name[6] - 0x30) & 0xFF, (name[7] - 0x30) & 0xFF
    return (name == b"RBX01-DM" or (rx and at7 & 3 == 2),
            name == b"RBXDV-S3" or (rx and at7 & 4 != 0),
            name in (b"RBX01-SM", b"RBX01-S2", b"RBX01-DM") or (rx and at6 & 1 != 0),
            name == b"RBXDV-S2" or (rx and at6 & 4 == 4))


def test_the_head_s_features_follow_the_head_fitted_now(wire):
    """Dual material, two fans, a B axis and a PRTD, asked at every heater sample, are
    the type's of the head fitted now: heads swapped back and forth, and none."""
    from robox.hardware.eeprom import EepromChip

    eeproms = wire.fw.eeproms
    bus = wire.printer.hw.eeprom_bus
    for type_code in ("RBX01-DM", "RBX01-SM", "RBXDV-S3", "RBXDV-S2", "RBX01-S2", "RBXDV-S1",
                      "RX000012", "RX000154", "RX000046", "RX0000A7", "RX000022", "RBX01-DM",
                      None, "RX000155"):
        bus.insert(EepromIndex.HEAD, None)
        wire.printer.run_until(lambda: eeproms.status(EepromIndex.HEAD) == 0, 5.0)
        if type_code is None:
            assert (eeproms.head_dual_material(), eeproms.head_has_two_fans(),
                    eeproms.head_has_b_axis(), eeproms.head_has_prtd()) == (False,) * 4
            continue
        bus.insert(EepromIndex.HEAD, EepromChip(images.head_eeprom(True, type_code),
                                                wire.printer.hw.clock))
        wire.printer.run_until(lambda: eeproms.status(EepromIndex.HEAD) == 2, 5.0)
        for _ in range(2):  # (asked twice: the second answer is the one kept)
            assert (eeproms.head_dual_material(), eeproms.head_has_two_fans(),
                    eeproms.head_has_b_axis(), eeproms.head_has_prtd()) == \
                _features_by_the_firmware_s_rule(type_code), type_code


def test_losing_the_head_eeprom_cuts_head_power(wire):
    run_lines(wire, "M104 S200", "M140 S60")
    wire.printer.hw.eeprom_bus.sockets[EepromIndex.HEAD].unplug()
    wire.printer.run_until(lambda: wire.fw.eeproms.status(EepromIndex.HEAD) == 0, 1.0)
    wire.printer.run_until(lambda: False, 1.1)
    assert wire.fw.errors.is_set(ErrorBit.HEAD_POWER_EEPROM)
    assert not wire.printer.hw.machine.head_power
    heaters = wire.printer.hw.machine.heaters
    assert heaters["nozzle0"].duty == 0 and heaters["nozzle1"].duty == 0
