"""The EEPROM object's state machine, transition by transition (spec/eeprom.md)."""

import pytest

from robox.firmware.eeprom import TIMEOUT_S, Eeproms, Status
from robox.firmware.error_flags import ErrorFlags
from robox.formats import eeprom as fmt
from robox.formats import float8
from robox.formats.eeprom import EepromIndex
from robox.formats.protocol import ErrorBit
from robox.hardware.clock import SimClock
from robox.hardware.eeprom import EepromChip
from robox.hardware.eeprom_bus import EepromBus

REEL = EepromIndex.REEL0
PASS_S = 0.001


def reel_data(**fields) -> bytes:
    data = bytearray(192)
    values = {"filament_diameter": "1.75", "remaining_filament": "240000", **fields}
    for name, value in values.items():
        fmt.set_field(data, "reel", name, value)
    return bytes(data)


class Rig:
    """Firmware EEPROM object on a bus, with a clock advanced one pass at a time."""

    def __init__(self, reel0=None, head=None, reel1=None, mux=False):
        self.clock = SimClock()
        self.errors = ErrorFlags()
        for chip in (reel0, head, reel1):
            if chip is not None:
                chip.clock = self.clock
                chip.write_cycle = 0.005
        self.bus = EepromBus(head, reel0, reel1, mux)
        self.eeproms = Eeproms(self.bus, self.clock, self.errors)
        self.valid_events = []
        self.lost_events = []
        self.eeproms.on_valid.append(self.valid_events.append)
        self.eeproms.on_lost.append(self.lost_events.append)

    def passes(self, count: int) -> None:
        for _ in range(count):
            self.eeproms.maintain()
            self.clock.advance(PASS_S)

    def until(self, condition, limit: int = 20000) -> int:
        for n in range(limit):
            if condition():
                return n
            self.passes(1)
        raise AssertionError("condition never held")


def test_a_healthy_chip_goes_straight_to_valid_in_196_steps():
    rig = Rig(reel0=EepromChip(fmt.chip_image(reel_data())))
    rig.passes(195)
    assert rig.eeproms.status(REEL) == Status.NOT_PRESENT
    rig.passes(1)
    assert rig.eeproms.status(REEL) == Status.VALID
    assert rig.valid_events == [REEL]
    assert rig.eeproms.get_float(REEL, "remaining_filament") == 240000.0


@pytest.mark.parametrize("content", [b"\xff" * 512, bytes(512), bytes(range(256)) * 2])
def test_a_chip_with_no_good_bank_is_present_but_not_valid(content):
    rig = Rig(reel0=EepromChip(content))
    rig.passes(196)
    assert rig.eeproms.status(REEL) == Status.NOT_PRESENT  # bank 0 bad: try bank 1
    rig.passes(196)
    assert rig.eeproms.status(REEL) == Status.PRESENT
    assert rig.eeproms.host_read(REEL) == bytes(192)
    assert rig.errors.is_set(ErrorBit.REEL0_EEPROM)
    assert rig.valid_events == []


def test_host_writes_to_an_eeprom_that_is_not_valid_set_its_error():
    rig = Rig(head=EepromChip())
    assert not rig.eeproms.host_write(EepromIndex.HEAD, 0, b"x")
    assert rig.errors.is_set(ErrorBit.HEAD_EEPROM)
    rig.errors.clear()
    rig.eeproms.host_read(EepromIndex.REEL1)
    assert rig.errors.is_set(ErrorBit.REEL1_EEPROM)


def test_a_corrupt_bank_0_with_a_good_bank_1_loads_bank_1_and_repairs_bank_0():
    chip = bytearray(fmt.chip_image(reel_data(remaining_filament="5000")))
    chip[0x10] ^= 0x01
    rig = Rig(reel0=EepromChip(bytes(chip)))
    rig.passes(392)
    assert rig.eeproms.status(REEL) == Status.VALID
    assert rig.eeproms.get_float(REEL, "remaining_filament") == 5000.0
    rig.until(lambda: rig.eeproms.settled(REEL))
    data = bytes(rig.bus.sockets[REEL].data)
    assert fmt.read_bank(data, 0) == fmt.read_bank(data, 1) and fmt.bank_good(data[:196])


def test_a_change_rewrites_the_working_bank_then_the_other_never_both_bad():
    chip = EepromChip(fmt.chip_image(reel_data()))
    rig = Rig(reel0=chip)
    rig.until(lambda: rig.eeproms.status(REEL) == Status.VALID and rig.eeproms.settled(REEL))
    assert rig.eeproms.set_float(REEL, "remaining_filament", 1234.5)
    rig.eeproms.set_float(REEL, "filament_diameter", 2.85)
    new = bytes(rig.eeproms.states[REEL].buffer)
    working = rig.eeproms.states[REEL].working_bank
    order = []
    while not rig.eeproms.settled(REEL):
        rig.passes(1)
        banks = [fmt.read_bank(bytes(chip.data), b) for b in (0, 1)]
        assert any(fmt.bank_good(b) for b in banks), "both banks bad at once"
        for b, bank in enumerate(banks):
            if bank == new and b not in order:
                order.append(b)
    assert order == [working, 1 - working]


def test_host_writes_are_masked_and_stop_at_address_191():
    chip = EepromChip(fmt.chip_image(reel_data()))
    rig = Rig(reel0=chip)
    rig.passes(196)
    assert rig.eeproms.host_write(REEL, 190, b"\xc1\xc2\xc3\xc4")
    assert rig.eeproms.host_write(REEL, 200, b"zz")  # wholly beyond: ignored
    data = rig.eeproms.host_read(REEL)
    assert data[190:192] == b"\x41\x42" and len(data) == 192
    rig.until(lambda: rig.eeproms.settled(REEL))
    assert bytes(chip.data[190:192]) == b"AB" and chip.data[0xC4] == 0xFF


def test_reports_are_masked_even_if_the_ram_copy_is_not():
    rig = Rig(reel0=EepromChip(fmt.chip_image(reel_data())))
    rig.passes(196)
    state = rig.eeproms.states[REEL]
    state.buffer = b"\xc1" + state.buffer[1:]
    assert rig.eeproms.host_read(REEL)[0] == 0x41


def test_no_acknowledge_for_0_2_s_means_gone():
    chip = EepromChip(fmt.chip_image(reel_data()))
    rig = Rig(reel0=chip)
    rig.passes(196)
    chip.unplug()
    rig.passes(int(TIMEOUT_S / PASS_S) - 2)
    assert rig.eeproms.status(REEL) == Status.VALID
    rig.passes(3)
    assert rig.eeproms.status(REEL) == Status.NOT_PRESENT
    assert rig.lost_events == [REEL]
    state = rig.eeproms.states[REEL]
    assert (state.counter, state.working_bank) == (0, 0)
    chip.plug()
    rig.passes(196)
    assert rig.eeproms.status(REEL) == Status.VALID and rig.valid_events == [REEL, REEL]


def test_a_short_unplug_is_ridden_out():
    chip = EepromChip(fmt.chip_image(reel_data()))
    rig = Rig(reel0=chip)
    rig.passes(196)
    chip.unplug()
    rig.passes(100)
    chip.plug()
    rig.passes(500)
    assert rig.eeproms.status(REEL) == Status.VALID and rig.lost_events == []


def test_format_makes_an_eeprom_valid_and_the_chip_follows():
    chip = EepromChip()
    rig = Rig(head=chip)
    rig.passes(392)
    assert rig.eeproms.status(EepromIndex.HEAD) == Status.PRESENT
    rig.eeproms.format(EepromIndex.HEAD)
    assert rig.eeproms.status(EepromIndex.HEAD) == Status.VALID
    assert rig.valid_events == []  # valid by decree, not by a load: nothing "appeared"
    rig.until(lambda: rig.eeproms.settled(EepromIndex.HEAD))
    assert bytes(chip.data) == fmt.chip_image(bytes(192))


def test_status_characters_and_the_dual_reel_multiplexer():
    rig = Rig(head=EepromChip(fmt.chip_image(bytes(192))), reel0=EepromChip(),
              reel1=EepromChip(fmt.chip_image(reel_data())))
    rig.passes(392)
    assert rig.eeproms.status_characters() == b"2100"  # reel 1 is behind an absent mux
    rig.bus.mux_present = True
    rig.passes(300)
    assert rig.eeproms.status_characters() == b"2121"


def test_float_fields_for_the_firmware_itself():
    rig = Rig(reel0=EepromChip(fmt.chip_image(reel_data())))
    assert not rig.eeproms.set_float(REEL, "remaining_filament", 1.0)  # not loaded yet
    rig.passes(196)
    assert rig.eeproms.set_float(REEL, "remaining_filament", 239993.25)
    assert rig.eeproms.host_read(REEL)[0xB8:0xC0] == b"239993.2"
    assert rig.eeproms.get_float(REEL, "remaining_filament") == float8.to_float32(239993.2)


def test_a_float_read_follows_every_change_of_its_field():
    """float_at, asked at every heater sample, reads the bank as it is now: after a
    host's write, a change of the firmware's own, an unplug and a replug."""
    rig = Rig(reel0=EepromChip(fmt.chip_image(reel_data(remaining_filament="240000"))))
    assert rig.eeproms.float_at(REEL, 0xB8, -1.0) == -1.0  # not loaded yet: the default
    rig.until(lambda: rig.eeproms.status(REEL) == Status.VALID)
    assert rig.eeproms.float_at(REEL, 0xB8, -1.0) == 240000.0
    assert rig.eeproms.float_at(REEL, 0xB8, -1.0) == 240000.0  # asked again: the same
    rig.eeproms.host_write(REEL, 0xB8, b"1234.5\0\0")
    assert rig.eeproms.float_at(REEL, 0xB8, -1.0) == float8.to_float32(1234.5)
    rig.eeproms.write_float_at(REEL, 0xB8, 99.25)
    assert rig.eeproms.float_at(REEL, 0xB8, -1.0) == 99.25
    assert rig.eeproms.float_at(REEL, 0x50, -1.0) == float8.to_float32(1.75)  # another field
    rig.bus.sockets[REEL].unplug()
    rig.until(lambda: rig.eeproms.status(REEL) == Status.NOT_PRESENT)
    assert rig.eeproms.float_at(REEL, 0xB8, -1.0) == -1.0
    rig.bus.insert(REEL, EepromChip(fmt.chip_image(reel_data(remaining_filament="500"))))
    rig.bus.sockets[REEL].clock = rig.clock
    rig.until(lambda: rig.eeproms.status(REEL) == Status.VALID)
    assert rig.eeproms.float_at(REEL, 0xB8, -1.0) == 500.0


def test_all_quiet_is_each_eeprom_quiet_at_every_pass():
    """all_quiet(), asked on every pass, against quiet() of each EEPROM: through loading,
    verifying, a host's change rewritten, an empty socket, a good chip and a blank one
    (PRESENT), and an unplug (NOT_PRESENT, then given up)."""
    blank = EepromChip()  # no good bank: PRESENT
    reel = EepromChip(fmt.chip_image(reel_data()))
    rig = Rig(reel0=reel, head=blank)  # reel 1: no multiplexer, an empty socket
    seen = set()

    def check(n: int) -> None:
        for _ in range(n):
            rig.passes(1)
            quiet = [rig.eeproms.quiet(i) for i in range(3)]
            assert rig.eeproms.all_quiet() == all(quiet)
            seen.add((tuple(rig.eeproms.status(i) for i in range(3)), tuple(quiet)))

    check(1000)
    assert rig.eeproms.host_write(REEL, 10, b"changed")
    check(1000)
    reel.unplug()
    check(400)
    assert len({all(q) for _, q in seen}) == 2 and len(seen) > 4
