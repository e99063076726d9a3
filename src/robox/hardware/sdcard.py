"""A simulated SD card: 512-byte blocks over a byte store, card-detect, faults, counters.

Part of the compiled core (robox.native): the firmware model looks at the card-detect
switch on every pass. The fault campaigns extend the class to record writes.
"""

from __future__ import annotations

from robox.errors import CardAbsent, CardReadError, PowerCut
from robox.formats.sdcard import BLOCK_SIZE, card_blocks
from robox.hardware.faults import FaultPlan, PowerPlan, mypyc_attr
from robox.hardware.storage import MemoryStorage, Storage


@mypyc_attr(allow_interpreted_subclasses=True)
class SdCard:
    """Block device with the card-detect switch and the injectable faults of a FaultPlan.

    `capacity` (C, in blocks) is derived from the store's size as a card's
    capacity is: whole KiB times two. Counters: `reads`, `writes`,
    `initialisations`; `insertions` counts card insertions so a reader can tell
    the card was swapped between two looks at the switch.
    """

    def __init__(self, storage: Storage, faults: FaultPlan | None = None):
        self.storage = storage
        self.faults = faults or FaultPlan()
        self.capacity = card_blocks(storage.size)
        self.present = True
        self.insertions = 1
        self.reads = 0
        self.writes = 0
        self.initialisations = 0
        self._accesses = 0
        #: The printer's supply (a PowerPlan shared with the other media), if watched.
        self.power: PowerPlan | None = None

    @classmethod
    def blank(cls, blocks: int, faults: FaultPlan | None = None) -> SdCard:
        return cls(MemoryStorage(bytes(blocks * BLOCK_SIZE)), faults)

    # card-detect switch
    def remove(self) -> None:
        self.present = False

    def insert(self) -> None:
        if not self.present:
            self.present = True
            self.insertions += 1

    def initialise(self) -> None:
        """Re-initialise the card (what the firmware does before retrying a read)."""
        self._check_access()
        self.initialisations += 1

    def _check_access(self) -> None:
        self._accesses += 1
        if self.faults.remove_before_access == self._accesses:
            self.present = False
        if not self.present:
            raise CardAbsent("no SD card")

    def _check_block(self, block: int) -> None:
        if not 0 <= block < self.capacity:
            raise ValueError(f"block {block} is outside the card (0..{self.capacity - 1})")

    def read_block(self, block: int) -> bytes:
        self._check_block(block)
        self._check_access()
        self.reads += 1
        if self.reads in self.faults.failing_reads:
            raise CardReadError(f"read of block {block} failed")
        return self.storage.read(block * BLOCK_SIZE, BLOCK_SIZE)

    def read_blocks(self, block: int, count: int) -> bytes:
        """`count` consecutive blocks in one access (counted as `count` reads)."""
        if count <= 0:
            return b""
        self._check_block(block)
        self._check_block(block + count - 1)
        self._check_access()
        first = self.reads + 1
        self.reads += count
        if any(first <= n <= self.reads for n in self.faults.failing_reads):
            raise CardReadError(f"read of blocks {block}..{block + count - 1} failed")
        return self.storage.read(block * BLOCK_SIZE, count * BLOCK_SIZE)

    def write_block(self, block: int, data: bytes) -> None:
        if len(data) != BLOCK_SIZE:
            raise ValueError(f"a block write is {BLOCK_SIZE} bytes, not {len(data)}")
        self._check_block(block)
        self._check_access()
        self.writes += 1
        offset = block * BLOCK_SIZE
        landing = self.power.write(self, block, data) if self.power is not None else None
        torn = self.faults.tear_write == self.writes
        if torn or landing is not None:
            tear = self.faults.tear if torn or landing is None else landing.tear()
            old = self.storage.read(offset, BLOCK_SIZE)
            self.storage.write(offset, tear.apply(old, bytes(data)) if tear else bytes(data))
            raise PowerCut(f"power cut during write {self.writes} (block {block})")
        self.storage.write(offset, bytes(data))
        if self.faults.cut_after_write == self.writes:
            raise PowerCut(f"power cut after write {self.writes} (block {block})")

    def flush(self) -> None:
        self.storage.flush()
