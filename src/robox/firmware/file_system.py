"""The printer's circular SD-card file system (spec/sdcard.md), hardened against power cuts.

Design (docs/sdcard.md has the full argument):

- Every block-0 update is written in *steps*. Each step differs from the block
  it overwrites only in ways whose every byte-mix is a legal directory: ring
  indices (first_file, next_file) and last_job are single bytes, so a torn
  write lands each of them whole, old or new; a slot is changed only while it
  lies outside the ring; next_write_block is derived state, recomputed at
  mount from the chain of files. So a torn block 0 always mounts as the state
  before or after its step.
- While block 0 is being rewritten, a *recovery copy* of the new directory
  sits in a free block (the write position), written before and erased after.
  Mount falls back to it only when block 0 is not a valid directory at all
  (damage beyond a byte mix, such as a block left erased).
- Mount follows wrapped files as they really lie, unlike the printer's walk.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from robox.errors import CardAbsent, CardReadError
from robox.firmware.error_flags import ErrorFlags
from robox.formats.protocol import ErrorBit
from robox.formats.sdcard import (
    BLOCK_SIZE,
    COPY_MAGIC,
    DIRECTORY_BLOCK,
    EMPTY_SLOT,
    FILE_START_BLOCK,
    ID_SIZE,
    NO_JOB,
    SLOT_COUNT,
    TRAILER_OFFSET,
    Directory,
    FileSlot,
    Verdict,
    decode_copy,
    encode_copy,
    file_blocks,
    following_block,
    newest_with_id,
    printer_walk,
    project_walk,
    stamp_generation,
    start_for,
    stored_id,
    trailer_generation,
)
from robox.hardware.sdcard import SdCard

#: Blocks read at a time when scanning the card for recovery copies.
SCAN_BATCH = 2048


@dataclass(frozen=True)
class RecoveryCopy:
    block: int
    generation: int
    directory: Directory
    verdict: Verdict


@dataclass(frozen=True)
class MountPlan:
    """What mounting a card does, decided without writing anything."""

    action: str  # "keep", "recover" (from a copy) or "format"
    raw: bytes  # block 0 as read
    on_card: Directory  # block 0 decoded
    printer: Verdict  # what a printer's walk says of block 0
    project: Verdict  # what the project's walk says of block 0
    directory: Directory | None  # the directory in use after mount (None: format)
    copy: RecoveryCopy | None  # the copy recovered from
    generation: int  # generation of the directory in use
    repairs: tuple[str, ...]  # derived fields corrected in memory
    copies: tuple[RecoveryCopy, ...] | None = None  # every valid copy (None: not scanned,
    # as block 0 was valid)


def derive(d: Directory, verdict: Verdict, capacity: int) -> tuple[Directory, tuple[str, ...]]:
    """The in-memory directory for an on-card one: derived state recomputed."""
    repairs = []
    nwb = d.next_write_block
    if verdict.chain_next_block is not None:
        nwb = verdict.chain_next_block
    elif not FILE_START_BLOCK <= nwb < capacity:
        nwb = FILE_START_BLOCK
    if nwb != d.next_write_block:
        repairs.append(f"next_write_block {d.next_write_block} -> {nwb} (the block after the "
                       "newest file)" if verdict.chain_next_block is not None else
                       f"next_write_block {d.next_write_block} -> {nwb}")
    last_job = d.last_job
    if last_job != NO_JOB and not d.in_ring(last_job):
        repairs.append(f"last_job {last_job} is not a committed file: none")
        last_job = NO_JOB
    return replace(d, next_write_block=nwb, last_job=last_job), tuple(repairs)


def scan_copies(card: SdCard) -> list[RecoveryCopy]:
    """Every valid recovery copy on the card, newest first. Reads the whole card."""
    import numpy as np  # only here: keeps robox-cli start-up fast

    found = []
    magic = np.frombuffer(COPY_MAGIC, np.uint8)
    block = FILE_START_BLOCK
    while block < card.capacity:
        count = min(SCAN_BATCH, card.capacity - block)
        data = card.read_blocks(block, count)
        rows = np.frombuffer(data, np.uint8).reshape(count, BLOCK_SIZE)
        hits = np.nonzero((rows[:, TRAILER_OFFSET : TRAILER_OFFSET + 4] == magic).all(axis=1))[0]
        for hit in hits:
            where = block + int(hit)
            decoded = decode_copy(bytes(rows[hit]), where)
            if decoded is None:
                continue
            generation, directory = decoded
            verdict = project_walk(directory, card.capacity)
            if verdict.valid:
                found.append(RecoveryCopy(where, generation, directory, verdict))
        block += count
    found.sort(key=lambda c: (c.generation, c.block), reverse=True)
    return found


def plan_mount(card: SdCard) -> MountPlan:
    """Decide what mounting does. Reads only; raises CardAbsent / CardReadError."""
    raw = card.read_block(DIRECTORY_BLOCK)
    on_card = Directory.decode(raw)
    printer = printer_walk(on_card, card.capacity)
    project = project_walk(on_card, card.capacity)
    if project.valid:
        directory, repairs = derive(on_card, project, card.capacity)
        return MountPlan("keep", raw, on_card, printer, project, directory, None,
                         trailer_generation(on_card) or 0, repairs)
    copies = scan_copies(card)
    if copies:
        copy = copies[0]
        directory, repairs = derive(copy.directory, copy.verdict, card.capacity)
        return MountPlan("recover", raw, on_card, printer, project, directory, copy,
                         copy.generation, repairs, tuple(copies))
    return MountPlan("format", raw, on_card, printer, project, None, None,
                     trailer_generation(on_card) or 0, (), ())


def extent_blocks(start: int, count: int, capacity: int) -> tuple[range, ...]:
    """Blocks of an extent as one or two ranges (it may wrap past the end)."""
    end = start + count
    if end <= capacity:
        return (range(start, end),)
    return (range(start, capacity), range(FILE_START_BLOCK, end - capacity + FILE_START_BLOCK))


def _inside(block: int, start: int, count: int, capacity: int) -> bool:
    return any(block in r for r in extent_blocks(start, count, capacity))


class _Reader:
    def __init__(self, slot: int, block: int, offset: int) -> None:
        self.slot = slot
        self.block = block  # next block to read
        self.offset = offset  # bytes delivered so far


class FileSystem:
    """The file-system object of the firmware: one card, errors through ErrorFlags.

    Operations return True on success; on failure they have set the error bit
    a printer would set. A PowerCut raised by the card propagates untouched.
    """

    def __init__(self, card: SdCard, errors: ErrorFlags, *, recovery_copies: bool = True):
        self.card = card
        self.errors = errors
        self.recovery_copies = recovery_copies
        self.initialise()

    # ----------------------------------------------------------------- state
    def initialise(self) -> None:
        self._dir: Directory | None = None  # in memory; None when not mounted
        self._on_card: Directory | None = None  # what block 0 holds
        self._generation = 0
        self._insertion = -1
        self._writing = False
        self._write_pos = 0  # next block of the file being written
        self._write_length = 0  # its length so far (kept here, as in the printer's RAM)
        self._reader: _Reader | None = None
        self.last_mount: MountPlan | None = None

    def maintain(self) -> None:
        """Drop the mounted state as soon as the card-detect switch opens."""
        if self._dir is not None and not self.card.present:
            self._unmount()

    @property
    def mounted(self) -> bool:
        return self._dir is not None

    @property
    def directory(self) -> Directory | None:
        return self._dir

    def _d(self) -> Directory:
        """The directory in memory, where the caller has it mounted."""
        d = self._dir
        assert d is not None, "the card is not mounted"
        return d

    def _card_dir(self) -> Directory:
        """What block 0 holds, where the caller has read it."""
        d = self._on_card
        assert d is not None, "block 0 has not been read"
        return d

    def _unmount(self) -> None:
        self._dir = None
        self._on_card = None
        self._writing = False
        self._reader = None

    def _fail(self) -> bool:
        self.errors.set(ErrorBit.SD_CARD)
        self._unmount()
        return False

    def _ensure_mounted(self) -> bool:
        if not self.card.present:
            return self._fail()
        if self._dir is not None and self._insertion == self.card.insertions:
            return True
        self._unmount()
        return self._mount()

    def _mount(self) -> bool:
        self._insertion = self.card.insertions
        try:
            plan = self._with_retry(lambda: plan_mount(self.card))
        except (CardAbsent, CardReadError):
            return self._fail()
        self.last_mount = plan
        self._on_card = plan.on_card
        self._generation = plan.generation
        if plan.action == "format":
            return self._format_fresh()
        self._dir = plan.directory
        if plan.action == "recover":
            # Block 0 straight from the copy, which stays valid until block 0 is
            # whole again: a cut here recovers from the same copy next time.
            # Everything but the capacity first, then the capacity alone, so a
            # torn write never leaves a valid-looking mix of copy and debris.
            restored = stamp_generation(plan.copy.directory, plan.generation)
            for image in (replace(restored, capacity=0), restored):
                if not self._write_block(DIRECTORY_BLOCK, image.encode()):
                    return False
            self._on_card = restored
            return self._write_block(plan.copy.block, bytes(BLOCK_SIZE))
        return True

    def _with_retry(self, read):
        """A failed read is retried once after re-initialising the card."""
        try:
            return read()
        except CardReadError:
            self.card.initialise()
            return read()

    def _read_block(self, block: int) -> bytes | None:
        try:
            return self._with_retry(lambda: self.card.read_block(block))
        except (CardAbsent, CardReadError):
            self._fail()
            return None

    def _write_block(self, block: int, data: bytes) -> bool:
        try:
            self.card.write_block(block, data)
        except CardAbsent:
            return self._fail()
        return True

    # ------------------------------------------------------- directory writes
    def _update(self, steps: list[Directory]) -> bool:
        """Write the directory: recovery copy, each step, the in-memory state, erase the copy.

        Each step must differ from the one before only in a mix-safe way (see the
        module docstring); the callers build them so. The copy lives only while
        block 0 is being rewritten, so a copy found on a card is always the
        update that was in flight, never an old state.
        """
        self._generation += 1
        target = self._dir = self._with_write_length(self._d())
        where = self._copy_location(target) if self.recovery_copies else None
        if where is not None and not self._write_block(
                where, encode_copy(stamp_generation(target, self._generation), where)):
            return False
        for step in [*steps, target]:
            stamped = stamp_generation(step, self._generation)
            if self._on_card is not None and stamped == stamp_generation(
                    self._on_card, self._generation):
                continue
            if not self._write_block(DIRECTORY_BLOCK, stamped.encode()):
                return False
            self._on_card = stamped
        return where is None or self._write_block(where, bytes(BLOCK_SIZE))

    def _with_write_length(self, d: Directory) -> Directory:
        """The directory as the printer's RAM holds it: the upload's length in its slot."""
        if not self._writing:
            return d
        slot = d.slots[d.next_file]
        if slot.length == self._write_length:
            return d
        return d.with_slot(d.next_file, replace(slot, length=self._write_length))

    def _length(self, index: int) -> int:
        d = self._d()
        if self._writing and index == d.next_file:
            return self._write_length
        return d.slots[index].length

    def _copy_location(self, target: Directory) -> int | None:
        """The write position, if no committed file (before or after) lies there."""
        where = self._write_pos if self._writing else target.next_write_block
        capacity = self.card.capacity
        for d in (self._on_card, target):
            if d is None:
                continue
            verdict = project_walk(d, capacity)
            for extent in verdict.extents:
                if _inside(where, extent.start_block, extent.blocks, capacity):
                    return None
        return where

    # ---------------------------------------------------------------- format
    def format(self) -> bool:
        """Format the card: every file is dropped, a fresh directory written."""
        if not self.card.present:
            return self._fail()
        if self._dir is None or self._insertion != self.card.insertions:
            self._unmount()
            self._insertion = self.card.insertions
            raw = self._read_block(DIRECTORY_BLOCK)
            if raw is None:
                return False
            self._on_card = Directory.decode(raw)
            self._generation = trailer_generation(self._on_card) or 0
        self._writing = False
        self._reader = None
        on_card = self._card_dir()
        if not project_walk(on_card, self.card.capacity).valid:
            return self._format_fresh()
        # Empty the ring first (one index byte), then zero slots that are now
        # outside it, and only then move the empty ring to slot 0.
        k = on_card.next_file
        emptied = replace(on_card, first_file=k, last_job=NO_JOB)
        zeroed = replace(Directory.fresh(self.card.capacity), first_file=k, next_file=k)
        self._dir = Directory.fresh(self.card.capacity)
        return self._update([emptied, zeroed])

    def _format_fresh(self) -> bool:
        self._dir = Directory.fresh(self.card.capacity)
        self._writing = False
        self._reader = None
        return self._update([])

    # ------------------------------------------------------------- writing
    def start_write_file(self, file_id: bytes | str, is_job: bool) -> bool:
        if not self._ensure_mounted():
            return False
        raw = file_id.encode("ascii") if isinstance(file_id, str) else bytes(file_id)
        self._writing = False
        d = self._d()
        ring = d.ring()
        if ring:
            newest = ring[-1]
            slot = d.slots[newest]
            if not slot.job and not (self._reader and self._reader.slot == newest):
                # Macros and other non-job files must not push jobs off the card.
                self._dir = replace(d, next_file=newest,
                                    next_write_block=slot.start_block).with_slot(newest,
                                                                                 EMPTY_SLOT)
                rewound = replace(self._card_dir(), next_file=newest,
                                  next_write_block=slot.start_block)
                if not self._update([rewound]):
                    return False
        d = self._d()
        n = d.next_file
        if self._reader and self._reader.slot == n:
            self._clobber_reader()
        start = start_for(d.next_write_block, self.card.capacity)
        self._dir = d.with_slot(n, FileSlot(id=stored_id(raw), is_job=1 if is_job else 0,
                                            start_block=start, length=0))
        self._writing = True
        self._write_pos = start
        self._write_length = 0
        return self._make_space(after_write=False)

    def _clobber_reader(self) -> None:
        self._reader = None
        self.errors.set(ErrorBit.FILE_READ_CLOBBERED)

    def _make_space(self, after_write: bool) -> bool:
        """Drop the oldest file while the write position has reached its start."""
        while True:
            d = self._d()
            if d.first_file == d.next_file:  # no committed file left
                writing = d.slots[d.next_file]
                if after_write and self._write_pos == writing.start_block:
                    self.errors.set(ErrorBit.FILE_TOO_LARGE)
                    self._abandon_write()
                    return False
                return True
            oldest = d.first_file
            if d.slots[oldest].start_block != self._write_pos:
                return True
            if self._reader and self._reader.slot == oldest:
                self._clobber_reader()
            last_job = NO_JOB if d.last_job == oldest else d.last_job
            self._dir = replace(d, first_file=(oldest + 1) % SLOT_COUNT, last_job=last_job)
            if not self._update([]):
                return False

    def _abandon_write(self) -> None:
        d = self._d()
        n = d.next_file
        if self._reader and self._reader.slot == n:
            self._reader = None
        if d.last_job == n:
            self._dir = replace(d, last_job=NO_JOB)
        self._writing = False

    def _expected_chunk(self) -> int:
        return self._write_length // BLOCK_SIZE

    def write_chunk(self, sequence: int, data: bytes) -> bool:
        """Store one 512-byte chunk of the file being written."""
        if not self._ensure_mounted():
            return False
        if not self._writing:
            self.errors.set(ErrorBit.CHUNK_SEQUENCE)
            return False
        expected = self._expected_chunk()
        if sequence < expected:
            return True  # a resent chunk: already stored
        if sequence > expected:
            self.errors.set(ErrorBit.CHUNK_SEQUENCE)
            return False
        return self._store_block(bytes(data).ljust(BLOCK_SIZE, b"\0")[:BLOCK_SIZE])

    def _store_block(self, block: bytes) -> bool:
        if not self._write_block(self._write_pos, block):
            return False
        self._write_pos = following_block(self._write_pos, 1, self.card.capacity)
        if not self._make_space(after_write=True):
            return False
        self._write_length += BLOCK_SIZE
        return True

    def end_write_file(self, sequence: int, data: bytes) -> bool:
        """Store the tail (0..512 bytes) and commit the file."""
        if not self._ensure_mounted():
            return False
        if not self._writing or sequence != self._expected_chunk():
            self.errors.set(ErrorBit.CHUNK_SEQUENCE)
            return False
        tail = bytes(data)[:BLOCK_SIZE]
        if tail:
            if not self._store_block(tail.ljust(BLOCK_SIZE, b"\0")):
                return False
            self._write_length = sequence * BLOCK_SIZE + len(tail)
        d = self._dir = self._with_write_length(self._d())
        n = d.next_file
        if d.slots[n].length == 0:
            self._abandon_write()  # a zero-length file is not committed
            return True
        self._writing = False
        after = (n + 1) % SLOT_COUNT
        ring_full = after == d.first_file
        first = (d.first_file + 1) % SLOT_COUNT if ring_full else d.first_file
        last_job = NO_JOB if d.last_job == after else d.last_job
        self._dir = replace(d, next_file=after, first_file=first, last_job=last_job,
                            next_write_block=self._write_pos)
        # Step 1: the new slot (still outside the ring), the ring-full drop, and
        # last_job parked at "none" if it is to change; step 2: the ring grows.
        on = self._card_dir()
        staged = replace(on, first_file=first,
                         last_job=on.last_job if on.last_job == last_job else NO_JOB)
        staged = staged.with_slot(n, d.slots[n])
        return self._update([staged])

    # ------------------------------------------------------------- reading
    def _find(self, file_id: bytes) -> int | None:
        """The printer's search, newest first: a file whose 16 id bytes equal `file_id`
        (the upload under way too, unless the id is empty), or, for an empty id, the
        last job. An empty id therefore opens a newer file stored with an empty id."""
        d = self._d()
        empty = file_id[0] == 0
        candidates = list(reversed(d.ring()))
        if not empty and self._writing:
            candidates.insert(0, d.next_file)
        for index in candidates:
            slot = d.slots[index]
            if slot.id == file_id or (empty and index == d.last_job and slot.job):
                return index
        return None

    def start_read_file(self, file_id: bytes | str) -> bool:
        """Open the newest file with that id (all 16 bytes compared); NUL id: last job."""
        if not self._ensure_mounted():
            return False
        raw = file_id.encode("ascii") if isinstance(file_id, str) else bytes(file_id)
        lookup = raw[:ID_SIZE].ljust(ID_SIZE, b"\0")
        self._reader = None
        index = self._find(lookup)
        if index is None:
            return False
        d = self._d()
        slot = d.slots[index]
        self._reader = _Reader(index, slot.start_block, 0)
        if slot.job and d.last_job != index:
            self._dir = replace(d, last_job=index)
            if not (self._writing and index == d.next_file):
                return self._update([])
        return True

    def read_committed(self, file_id: bytes) -> bytes | None:
        """The whole newest committed file with that id (not one still being written),
        without touching the open read or the last job. None if there is none."""
        if not self._ensure_mounted():
            return None
        d = self._d()
        index = newest_with_id(d, bytes(file_id)[:ID_SIZE].ljust(ID_SIZE, b"\0"))
        if index is None:
            return None
        parts = []
        for block, size in file_blocks(d.slots[index], self.card.capacity):
            data = self._read_block(block)
            if data is None:
                return None
            parts.append(data[:size])
        return b"".join(parts)

    def _reading_file_being_written(self) -> bool:
        return self._writing and self._reader is not None and \
            self._reader.slot == self._d().next_file

    def read(self) -> bytes:
        """Up to 512 bytes of the file open for reading; b"" for nothing (yet)."""
        reader = self._reader
        if reader is None or not self._ensure_mounted() or self._reader is None:
            return b""
        available = self._length(reader.slot)
        if reader.offset >= available:
            return b""
        data = self._read_block(reader.block)
        if data is None:
            return b""
        take = min(BLOCK_SIZE, available - reader.offset)
        reader.block = following_block(reader.block, 1, self.card.capacity)
        reader.offset += take
        return data[:take]

    def eof(self) -> bool:
        """True once the open file is complete and fully read (or nothing is open)."""
        reader = self._reader
        if reader is None or self._dir is None:
            return True
        if self._reading_file_being_written():
            return False
        return reader.offset >= self._length(reader.slot)

    def upload_length(self) -> int:
        """Bytes stored so far of the upload under way, when the reader is open on that
        same file; else -1."""
        if self._reader is None or self._dir is None or not self._reading_file_being_written():
            return -1
        return self._write_length

    def upload_unread(self) -> int:
        """Bytes of the upload under way that the reader open on that same file has still
        to read; -1 when the open file (if any) is not being written."""
        length = self.upload_length()
        reader = self._reader
        return -1 if length < 0 or reader is None else length - reader.offset

    def close(self) -> None:
        self._reader = None

    @property
    def reading(self) -> bytes | None:
        """Id of the file open for reading, or None."""
        if self._reader is None or self._dir is None:
            return None
        return self._d().slots[self._reader.slot].id

    # ----------------------------------------------------------- reporting
    def file_list(self) -> list[bytes]:
        """Ids of the committed files, oldest first."""
        if not self._ensure_mounted():
            return []
        d = self._d()
        return [d.slots[i].id for i in d.ring()]

    def send_file_report(self) -> tuple[bytes, int]:
        """Id of the file being written (all NUL if none) and its next chunk number."""
        if self._dir is None or not self._writing:
            return bytes(ID_SIZE), 0
        d = self._d()
        return d.slots[d.next_file].id, self._expected_chunk()

    def _mounted_quietly(self) -> bool:
        """Mounted, or mounted now; no card is no error here (nonvolatile data is
        silently unavailable without one)."""
        if not self.card.present:
            return False
        errors = self.errors.bits
        mounted = self._ensure_mounted()
        if not mounted:
            self.errors.bits = errors
        return mounted

    def nonvolatile(self, index: int) -> int:
        if not self._mounted_quietly():
            return 0
        return self._d().nonvolatile[index]

    def set_nonvolatile(self, index: int, value: int) -> bool:
        if not self._mounted_quietly():
            return False
        d = self._d()
        data = bytearray(d.nonvolatile)
        if data[index] == value:
            return True
        data[index] = value
        self._dir = replace(d, nonvolatile=bytes(data))
        return self._update([])

    def check_for_head_change(self, dual_material: bool) -> None:
        """Nonvolatile byte 1 remembers the head type; when it changes the last job is
        forgotten, so a button press cannot reprint it with the wrong head."""
        if not self._mounted_quietly():
            return
        d = self._d()
        if d.nonvolatile[1] != int(dual_material):
            self._dir = replace(d, last_job=NO_JOB)
            self.set_nonvolatile(1, int(dual_material))
