"""Simulated I2C EEPROMs (512 bytes) in the head and reel sockets, and the reel-1 mux.

Transactions are single-byte reads and writes. A chip that is not plugged in,
sits behind an absent multiplexer, or is busy with its internal write cycle
does not acknowledge: the transaction returns None / False and changes nothing.
"""

from __future__ import annotations

from robox.errors import PowerCut
from robox.formats.eeprom import CHIP_SIZE
from robox.hardware.clock import SimClock
from robox.hardware.faults import EepromFaultPlan, PowerPlan

#: Internal write cycle of a small serial EEPROM: it ignores the bus meanwhile.
WRITE_CYCLE_S = 0.005


class EepromChip:
    """A 512-byte EEPROM. Starts from any content: blank 0xFF by default."""

    def __init__(self, content: bytes | None = None, clock: SimClock | None = None,
                 faults: EepromFaultPlan | None = None, write_cycle: float = WRITE_CYCLE_S):
        data = bytes([0xFF]) * CHIP_SIZE if content is None else bytes(content)
        if len(data) != CHIP_SIZE:
            raise ValueError(f"an EEPROM chip holds {CHIP_SIZE} bytes, not {len(data)}")
        # bytes, made anew by a write (rare): compiled, a read or a run of them is a native
        # index or slice, where a bytearray's are generic
        self.data: bytes = data
        self.clock = clock
        self.faults = faults or EepromFaultPlan()
        self.write_cycle = write_cycle if clock is not None else 0.0
        self.plugged = True
        self.transactions = 0
        self.reads = 0
        self.writes = 0
        self.nacks = 0
        self._busy_until = 0.0
        #: The printer's supply (a PowerPlan shared with the other media), if watched.
        self.power: PowerPlan | None = None
        #: With a list here, the kind of every transaction from then on ("read", "write")
        #: is appended to it, in order.
        self.journal: list[str] | None = None

    def unplug(self) -> None:
        self.plugged = False

    def plug(self) -> None:
        self.plugged = True

    def _now(self) -> float:
        return self.clock.now if self.clock is not None else 0.0

    def _acknowledges(self, kind: str) -> bool:
        self.transactions += 1
        if self.journal is not None:
            self.journal.append(kind)
        unplug_at = self.faults.unplug_at
        if unplug_at is not None and unplug_at == self.transactions:  # (compiled: native)
            self.plugged = False
        if not self.plugged or self._now() < self._busy_until:
            self.nacks += 1
            return False
        return True

    def will_acknowledge(self, at: float) -> bool:
        """Whether the next transaction, made at time `at`, will be acknowledged."""
        unplug_at = self.faults.unplug_at  # (tested for None first: compiled, nothing boxed)
        return self.plugged and (unplug_at is None or unplug_at != self.transactions + 1) \
            and (self.clock is None or at >= self._busy_until)

    def peek_run(self, address: int, n: int) -> bytes:
        """`n` bytes from `address`, looked at without a transaction (for planning)."""
        return bytes(self.data[(address + i) % CHIP_SIZE] for i in range(n)) \
            if address + n > CHIP_SIZE else self.data[address : address + n]

    def read_run(self, address: int, n: int) -> bytes:
        """`n` single-byte reads from `address` on, all acknowledged (the caller made
        sure: see will_acknowledge), as `n` calls of read() would count them."""
        self.transactions += n
        self.reads += n
        if self.journal is not None:
            self.journal.extend(["read"] * n)
        return self.peek_run(address, n)

    def read(self, address: int) -> int | None:
        """One single-byte read; None when not acknowledged."""
        if not self._acknowledges("read"):
            return None
        self.reads += 1
        return self.data[address % CHIP_SIZE]

    def read_matches(self, address: int, expected: int) -> int:
        """read(), its byte compared with `expected`: 1 when they match, 0 when not, -1
        when the read is not acknowledged (a verify step's read: compiled, no byte
        made an object on its way out)."""
        if not self._acknowledges("read"):
            return -1
        self.reads += 1
        return 1 if self.data[address % CHIP_SIZE] == expected else 0

    def write(self, address: int, value: int) -> bool:
        """One single-byte write; False when not acknowledged."""
        ordinal = self.transactions + 1
        if not self._acknowledges("write"):
            if self.faults.unplug_at == ordinal and self.faults.write_lands:
                self._put(address % CHIP_SIZE, value)
            return False
        self.writes += 1
        cell, value = address % CHIP_SIZE, value & 0xFF
        landing = None if self.power is None else self.power.write(self, cell, bytes([value]))
        if landing is not None:
            self._put(cell, landing.param if landing.mode == "garble" else value)
            raise PowerCut(f"power cut while writing EEPROM byte {cell:#x}")
        self._put(cell, value)
        self._busy_until = self._now() + self.write_cycle
        return True

    def _put(self, cell: int, value: int) -> None:
        self.data = self.data[:cell] + bytes((value & 0xFF,)) + self.data[cell + 1 :]
