"""The SD card's circular file system: directory block layout and validity walks.

Layout and rules are those of spec/sdcard.md. Block 0 is the directory; files
occupy consecutive blocks from block 1 on, wrapping from block C-1 to block 1.
Two validity walks live here: the printer's own (with its 32-bit arithmetic and
its wrap bug, so that `fsck` can say what a printer would do) and the project's
(which follows wrapped files as they really lie and rejects extents outside the
card).
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass, field, replace

from robox.formats.card_file import BLOCK_SIZE as BLOCK_SIZE
from robox.formats.card_file import ID_SIZE as ID_SIZE
from robox.formats.card_file import default_id as default_id
from robox.formats.card_file import id_text as id_text
from robox.formats.card_file import make_id as make_id

DIRECTORY_BLOCK = 0
FILE_START_BLOCK = 1
#: A new file never starts within the last CONTIGUOUS_BLOCKS blocks of the card.
CONTIGUOUS_BLOCKS = 1024
SLOT_COUNT = 16
NO_JOB = 0xFF
#: The smallest card the tools create or accept (1 MiB).
MIN_CARD_BLOCKS = 2048

_HEADER = struct.Struct("<IIBBB2s51s")
_SLOT = struct.Struct("<16sB3sII")
SLOTS_OFFSET = 64
SLOT_SIZE = _SLOT.size
assert _HEADER.size == SLOTS_OFFSET and SLOT_SIZE == 28
assert SLOTS_OFFSET + SLOT_COUNT * SLOT_SIZE == BLOCK_SIZE

_U32 = 0xFFFFFFFF


def card_blocks(size_bytes: int) -> int:
    """Capacity C in blocks of a card (or image file) of `size_bytes` bytes."""
    return (size_bytes // 1024) * 2


def blocks_for(length: int) -> int:
    """Blocks a file of `length` bytes occupies."""
    return -(-length // BLOCK_SIZE)


@dataclass(frozen=True)
class FileSlot:
    """One 28-byte directory slot. `is_job` and `unused` are kept raw."""

    id: bytes = bytes(ID_SIZE)
    is_job: int = 0
    unused: bytes = bytes(3)
    start_block: int = 0
    length: int = 0

    def __post_init__(self) -> None:
        if len(self.id) != ID_SIZE or len(self.unused) != 3:
            raise ValueError("a slot holds a 16-byte id and 3 unused bytes")

    @property
    def job(self) -> bool:
        return self.is_job != 0

    @property
    def blocks(self) -> int:
        return blocks_for(self.length)

    def encode(self) -> bytes:
        return _SLOT.pack(self.id, self.is_job, self.unused, self.start_block, self.length)

    @classmethod
    def decode(cls, raw: bytes) -> FileSlot:
        file_id, is_job, unused, start, length = _SLOT.unpack(raw)
        return cls(file_id, is_job, unused, start, length)


EMPTY_SLOT = FileSlot()


@dataclass(frozen=True)
class Directory:
    """The directory block. Bytes the printer does not interpret are kept as read."""

    capacity: int
    next_write_block: int = FILE_START_BLOCK
    first_file: int = 0
    next_file: int = 0
    last_job: int = NO_JOB
    nonvolatile: bytes = bytes(2)
    padding: bytes = bytes(51)
    slots: tuple[FileSlot, ...] = field(default=(EMPTY_SLOT,) * SLOT_COUNT)

    @classmethod
    def fresh(cls, capacity: int) -> Directory:
        """What a format writes: zeroed, capacity C, next block 1, no last job."""
        return cls(capacity=capacity)

    @classmethod
    def decode(cls, block: bytes) -> Directory:
        if len(block) != BLOCK_SIZE:
            raise ValueError(f"a directory block is {BLOCK_SIZE} bytes, not {len(block)}")
        capacity, nwb, first, nxt, last, nonvolatile, padding = _HEADER.unpack_from(block, 0)
        slots = tuple(
            FileSlot.decode(block[offset : offset + SLOT_SIZE])
            for offset in range(SLOTS_OFFSET, BLOCK_SIZE, SLOT_SIZE)
        )
        return cls(capacity, nwb, first, nxt, last, nonvolatile, padding, slots)

    def encode(self) -> bytes:
        header = _HEADER.pack(
            self.capacity & _U32,
            self.next_write_block & _U32,
            self.first_file,
            self.next_file,
            self.last_job,
            self.nonvolatile,
            self.padding,
        )
        return header + b"".join(slot.encode() for slot in self.slots)

    def with_slot(self, index: int, slot: FileSlot) -> Directory:
        slots = list(self.slots)
        slots[index] = slot
        return replace(self, slots=tuple(slots))

    def ring(self) -> list[int]:
        """Slots of the committed files, oldest first (first_file up to next_file)."""
        if self.first_file >= SLOT_COUNT or self.next_file >= SLOT_COUNT:
            return []
        count = (self.next_file - self.first_file) % SLOT_COUNT
        return [(self.first_file + i) % SLOT_COUNT for i in range(count)]

    def in_ring(self, slot: int) -> bool:
        return slot in self.ring()


def following_block(block: int, count: int, capacity: int) -> int:
    """The block `count` blocks after `block`, wrapping from C-1 back to block 1."""
    data_blocks = capacity - FILE_START_BLOCK
    return (block - FILE_START_BLOCK + count) % data_blocks + FILE_START_BLOCK


def file_blocks(slot: FileSlot, capacity: int):
    """(block, bytes of the file in it) for each block of a file, wrap included."""
    block, remaining = slot.start_block, slot.length
    while remaining > 0:
        yield block, min(BLOCK_SIZE, remaining)
        remaining -= BLOCK_SIZE
        block = following_block(block, 1, capacity)


def newest_with_id(d: Directory, file_id: bytes) -> int | None:
    """Slot of the newest committed file whose 16-byte id is `file_id`."""
    return next((i for i in reversed(d.ring()) if d.slots[i].id == file_id), None)


def start_for(block: int, capacity: int) -> int:
    """Where a new file starts if the previous one ended before `block`."""
    if block + CONTIGUOUS_BLOCKS > capacity:  # fewer than 1024 blocks remain
        return FILE_START_BLOCK
    return block


@dataclass(frozen=True)
class Extent:
    """Where a committed file lies on the card."""

    slot: int
    start_block: int
    blocks: int
    end_block: int  # last block of the file (== start_block - 1 wrapped for an empty file)
    wraps: bool


@dataclass(frozen=True)
class Verdict:
    """The outcome of a validity walk."""

    valid: bool
    reason: str = ""
    extents: tuple[Extent, ...] = ()
    #: Where the chain says the next file goes (the block after the newest file);
    #: None when no file is committed.
    chain_next_block: int | None = None


def _header_problem(d: Directory, capacity: int) -> str:
    if d.capacity != capacity:
        return f"capacity field says {d.capacity} blocks, the card has {capacity}"
    if d.first_file >= SLOT_COUNT:
        return f"first_file {d.first_file} is not a slot number"
    if d.next_file >= SLOT_COUNT:
        return f"next_file {d.next_file} is not a slot number"
    return ""


def printer_walk(d: Directory, capacity: int) -> Verdict:
    """The printer's own validity check, 32-bit arithmetic and wrap bug included."""
    problem = _header_problem(d, capacity)
    if not problem and not FILE_START_BLOCK <= d.next_write_block < capacity:
        problem = f"next_write_block {d.next_write_block} is outside 1..{capacity - 1}"
    if problem:
        return Verdict(False, problem)
    ring = d.ring()
    expected = None
    for index in ring:
        slot = d.slots[index]
        if expected is not None and slot.start_block != expected:
            return Verdict(False, f"slot {index} starts at block {slot.start_block}, "
                                  f"a printer expects {expected}")
        expected = (slot.start_block + slot.blocks) & _U32
        if (expected + CONTIGUOUS_BLOCKS) & _U32 > capacity:
            expected = FILE_START_BLOCK
    return Verdict(True)


def project_walk(d: Directory, capacity: int) -> Verdict:
    """The project's validity check: files chained as they really lie, inside the card.

    Next_write_block is derived state here (the block after the newest file), so
    it is not a reason to reject a directory whose files are all intact.
    """
    problem = _header_problem(d, capacity)
    if problem:
        return Verdict(False, problem)
    data_blocks = capacity - FILE_START_BLOCK
    extents: list[Extent] = []
    used = 0  # blocks from the oldest file's start to the newest file's end
    expected = None
    previous_end = FILE_START_BLOCK
    for index in d.ring():
        slot = d.slots[index]
        if not FILE_START_BLOCK <= slot.start_block < capacity:
            return Verdict(False, f"slot {index} starts at block {slot.start_block}, "
                                  f"outside the card (1..{capacity - 1})")
        if expected is not None:
            if slot.start_block != expected:
                return Verdict(False, f"slot {index} starts at block {slot.start_block}, "
                                      f"the previous file ends before block {expected}")
            used += (slot.start_block - previous_end) % data_blocks
        blocks = slot.blocks
        used += blocks
        if used > data_blocks:
            return Verdict(False, f"slot {index} overlaps the oldest file "
                                  f"(the files need more than {data_blocks} blocks)")
        previous_end = following_block(slot.start_block, blocks, capacity)
        last = following_block(slot.start_block, blocks - 1, capacity) if blocks else None
        wraps = blocks > 0 and slot.start_block + blocks - 1 > capacity - 1
        extents.append(Extent(index, slot.start_block, blocks,
                              last if last is not None else slot.start_block, wraps))
        expected = start_for(previous_end, capacity)
    chain_next = previous_end if extents else None
    return Verdict(True, "", tuple(extents), chain_next)


# --------------------------------------------------------------------------
# Project extension: generation trailer and recovery copies.
#
# The printer neither reads nor changes the directory padding (bytes 13..63)
# except to zero it when formatting, so the project keeps a 20-byte trailer in
# its last bytes. In block 0: magic "RBXd" and the generation of the update
# that wrote it. In a recovery copy (a whole directory image written into a
# free data block, which a printer never reads): magic "RBXc", the block the
# copy sits in, the generation, and a CRC-32 of the 512 bytes.

TRAILER_OFFSET = 44
_TRAILER = struct.Struct("<4sIIII")
assert TRAILER_OFFSET + _TRAILER.size == SLOTS_OFFSET
_PAD_TRAILER = TRAILER_OFFSET - 13  # the trailer's offset inside `padding`
DIRECTORY_MAGIC = b"RBXd"
COPY_MAGIC = b"RBXc"


def stored_id(raw: bytes) -> bytes:
    """The id a printer stores for raw id bytes: up to the first NUL, at most 16, NUL padded."""
    return bytes(raw).split(b"\0", 1)[0][:ID_SIZE].ljust(ID_SIZE, b"\0")


def _with_trailer(d: Directory, magic: bytes, location: int, generation: int) -> Directory:
    trailer = _TRAILER.pack(magic, location, generation & _U32, 0, 0)
    padding = d.padding[:_PAD_TRAILER] + trailer
    return replace(d, padding=padding)


def stamp_generation(d: Directory, generation: int) -> Directory:
    """`d` carrying the block-0 trailer with `generation`."""
    return _with_trailer(d, DIRECTORY_MAGIC, 0, generation)


def trailer_generation(d: Directory) -> int | None:
    """The generation in a block-0 trailer, or None when there is no trailer."""
    magic, _, generation, _, _ = _TRAILER.unpack(d.padding[_PAD_TRAILER:])
    return generation if magic == DIRECTORY_MAGIC else None


def encode_copy(d: Directory, location: int) -> bytes:
    """A recovery copy of `d` (which carries its generation) for block `location`."""
    generation = trailer_generation(d) or 0
    image = bytearray(_with_trailer(d, COPY_MAGIC, location, generation).encode())
    crc = zlib.crc32(image)
    image[SLOTS_OFFSET - 4 : SLOTS_OFFSET] = struct.pack("<I", crc)
    return bytes(image)


def decode_copy(block: bytes, location: int) -> tuple[int, Directory] | None:
    """(generation, directory) of a recovery copy read from block `location`, if valid."""
    magic, where, generation, _, crc = _TRAILER.unpack_from(block, TRAILER_OFFSET)
    if magic != COPY_MAGIC or where != location:
        return None
    image = bytearray(block)
    image[SLOTS_OFFSET - 4 : SLOTS_OFFSET] = bytes(4)
    if zlib.crc32(image) != crc:
        return None
    return generation, stamp_generation(Directory.decode(bytes(block)), generation)
