"""Simulated EEPROM chips: transactions, write cycle, hot-unplug, the reel-1 mux."""

from robox.formats.eeprom import EepromIndex
from robox.hardware.clock import SimClock
from robox.hardware.eeprom import WRITE_CYCLE_S, EepromChip
from robox.hardware.eeprom_bus import EepromBus
from robox.hardware.faults import EepromFaultPlan


def test_single_byte_transactions_and_counters():
    chip = EepromChip(bytes(range(256)) * 2)
    assert chip.read(0x105) == 5
    assert chip.write(7, 0xAB) and chip.data[7] == 0xAB
    assert (chip.transactions, chip.reads, chip.writes, chip.nacks) == (2, 1, 1, 0)


def test_a_compared_read_is_a_read_as_the_chip_and_its_journal_count_it():
    """read_matches(): the verify step's read, its byte compared where it is read (the
    address wraps at the chip's end as read()'s does); unanswered, -1."""
    clock = SimClock()
    chip = EepromChip(bytes(range(256)) * 2, clock)
    twin = EepromChip(bytes(range(256)) * 2, clock)
    chip.journal, twin.journal = [], []
    assert chip.read_matches(0x105, 5) == 1 and twin.read(0x105) == 5
    assert chip.read_matches(0x205, 5) == 1 and twin.read(0x205) == 5  # (wrapped: 0x005)
    assert chip.read_matches(0x105, 6) == 0 and twin.read(0x105) != 6
    assert chip.write(3, 1) and twin.write(3, 1)  # the write cycle: the bus ignored
    assert chip.read_matches(3, 1) == -1 and twin.read(3) is None
    clock.advance(WRITE_CYCLE_S)
    chip.unplug()
    twin.unplug()
    assert chip.read_matches(3, 1) == -1 and twin.read(3) is None
    counts = (chip.transactions, chip.reads, chip.writes, chip.nacks, chip.journal)
    assert counts == (twin.transactions, twin.reads, twin.writes, twin.nacks, twin.journal)
    assert counts[:4] == (6, 3, 1, 2)


def test_blank_by_default_and_any_starting_content():
    assert EepromChip().data == b"\xff" * 512
    assert EepromChip(bytes(512)).data == bytes(512)


def test_an_unplugged_chip_acknowledges_nothing_and_changes_nothing():
    chip = EepromChip(bytes(512))
    chip.unplug()
    assert chip.read(0) is None and not chip.write(0, 1)
    assert chip.data[0] == 0 and chip.nacks == 2
    chip.plug()
    assert chip.read(0) == 0


def test_the_write_cycle_ignores_the_bus_for_five_milliseconds():
    clock = SimClock()
    chip = EepromChip(bytes(512), clock)
    assert chip.write(1, 9)
    assert chip.read(1) is None
    clock.advance(WRITE_CYCLE_S)
    assert chip.read(1) == 9


def test_unplug_mid_write_lands_or_not():
    for lands in (True, False):
        chip = EepromChip(bytes(512), faults=EepromFaultPlan(unplug_at=2, write_lands=lands))
        assert chip.write(0, 1)
        assert not chip.write(1, 2)
        assert chip.data[1] == (2 if lands else 0) and not chip.plugged


def test_reel_1_is_reached_only_through_the_multiplexer():
    chip = EepromChip(bytes(512))
    bus = EepromBus(reel1=chip)
    assert bus.chip(EepromIndex.REEL1) is None  # behind an absent multiplexer
    bus.mux_present = True
    assert bus.chip(EepromIndex.REEL1) is chip
    assert bus.chip(EepromIndex.HEAD) is None  # empty socket
