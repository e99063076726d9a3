"""The printer's I2C bus to its EEPROMs: the head and reel 0 sockets, and reel 1 behind
the dual-reel adaptor's multiplexer. Part of the compiled core (robox.native), as the
chips are (robox.hardware.eeprom): the firmware model reaches them through it on every
pass. A test that watches a chip's transactions reads its journal.
"""

from __future__ import annotations

from robox.hardware.eeprom import EepromChip


class EepromBus:
    """The printer's I2C bus: head and reel 0 sockets, and reel 1 behind the dual-reel
    adaptor's multiplexer (absent unless an adaptor is fitted)."""

    def __init__(self, head: EepromChip | None = None, reel0: EepromChip | None = None,
                 reel1: EepromChip | None = None, mux_present: bool = False):
        self.sockets: list[EepromChip | None] = [head, reel0, reel1]
        self.mux_present = mux_present
        self.inserts = 0  # how many times insert() has put a chip in or taken one out

    def chip(self, index: int) -> EepromChip | None:
        if index == 2 and not self.mux_present:  # reel 1 (EepromIndex.REEL1)
            return None
        return self.sockets[index]

    def writes(self) -> int:
        """Byte writes the chips in the sockets have taken (a count that moves on with
        every write that lands)."""
        total = 0
        for chip in self.sockets:
            if chip is not None:
                total += chip.writes
        return total

    def insert(self, index: int, chip: EepromChip | None) -> None:
        self.sockets[index] = chip
        self.inserts += 1
