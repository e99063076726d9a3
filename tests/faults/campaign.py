"""Power-cut campaign: cut, or tear, every block write of a scenario and judge the survivor.

The scenario runs once on a recording card; since the file system is
deterministic, the card that survives a cut at write N is the initial card
plus writes 1..N-1 plus write N landed whole or torn. `Media.surviving_card`
builds exactly that (a test replays sample cut points through the real
FaultPlan and compares the bytes), which keeps the campaign linear in the
number of writes.

Every failure names a case id (`mode:N:param`); `replay(case_id)` runs that
cut for real, from the top, through the FaultPlan, and returns the card.
"""

from __future__ import annotations

import hashlib
import random
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from robox.errors import PowerCut
from robox.firmware.error_flags import ErrorFlags
from robox.firmware.file_system import FileSystem
from robox.formats.sdcard import BLOCK_SIZE, NO_JOB
from robox.hardware.faults import FaultPlan, Landing, Tear
from robox.hardware.sdcard import SdCard
from robox.hardware.storage import MemoryStorage
from tests.cards import pattern, read_back, upload

CAPACITY = 2048

#: Uploads that lay files end to end, delete a macro, fill the 16-slot ring,
#: wrap a file past the end of the card (dropping old files as it goes),
#: record last jobs, change a nonvolatile byte, and format.
SCENARIO: list[tuple] = [
    ("mount",),
    ("put", "j1", 200 * 512 + 17, True),
    ("put", "m1", 3 * 512, False),
    ("put", "j2", 400 * 512 + 100, True),
    ("open", "j1"),
    ("nv", 1, 1),
    ("put", "j3", 300 * 512, True),
    *[("put", f"s{i}", 600, True) for i in range(13)],
    ("open", "s3"),
    ("put", "big", 1400 * 512 + 5, True),
    ("put", "m2", 100, False),
    ("put", "j5", 600 * 512, True),
    ("open", ""),
    ("format",),
    ("put", "j6", 1000, True),
]

MODES = ("cut", "prefix", "mix", "erase")


def content(name: str, size: int) -> bytes:
    return pattern(size, int.from_bytes(hashlib.sha1(name.encode()).digest()[:4], "little"))


def run_op(fs: FileSystem, op: tuple) -> None:
    kind = op[0]
    if kind == "mount":
        fs.file_list()
    elif kind == "put":
        _, name, size, job = op
        upload(fs, name, content(name, size), job)
    elif kind == "open":
        fs.start_read_file(op[1].encode() or bytes(16))
        fs.close()
    elif kind == "nv":
        fs.set_nonvolatile(op[1], op[2])
    elif kind == "format":
        fs.format()
    else:  # pragma: no cover
        raise ValueError(kind)


@dataclass(frozen=True)
class State:
    """What a mount shows: files (id, digest) oldest first, last job id, nonvolatile."""

    files: tuple[tuple[bytes, str], ...]
    last_job: bytes | None
    nonvolatile: bytes


def _slot_bytes(data: bytearray, start: int, length: int, capacity: int) -> bytes:
    blocks = -(-length // BLOCK_SIZE)
    first = min(blocks, capacity - start)
    out = bytes(data[start * BLOCK_SIZE : (start + first) * BLOCK_SIZE])
    if blocks > first:
        out += bytes(data[BLOCK_SIZE : (1 + blocks - first) * BLOCK_SIZE])
    return out[:length]


def observe(fs: FileSystem, digests=None) -> State:
    """Mount (if needed) and read the state; file content straight from the medium.

    `digests(start, length)`, when given, may answer a file's digest from a cache; it is
    not asked if the mount wrote to the card."""
    writes = fs.card.writes
    fs.file_list()
    d = fs.directory
    assert d is not None, "a present, working card always mounts"
    data = fs.card.storage.data
    capacity = fs.card.capacity
    if digests is None or fs.card.writes != writes:
        def digests(start, length):
            return hashlib.sha1(_slot_bytes(data, start, length, capacity)).hexdigest()
    files = tuple((d.slots[i].id, digests(d.slots[i].start_block, d.slots[i].length))
                  for i in d.ring())
    last = None if d.last_job == NO_JOB else d.slots[d.last_job].id
    return State(files, last, d.nonvolatile)


class RecordingCard(SdCard):
    def __init__(self, storage):
        super().__init__(storage)
        self.log: list[tuple[int, bytes, int]] = []
        self.op = 0

    def write_block(self, block: int, data: bytes) -> None:
        self.log.append((block, bytes(data), self.op))
        super().write_block(block, data)


@dataclass
class Recording:
    initial: bytes
    writes: list[tuple[int, bytes, int]]  # (block, data, op index)
    states: list[State]  # states[k + 1] = after op k; states[0] = before everything


def record(scenario: list[tuple] = SCENARIO, capacity: int = CAPACITY) -> Recording:
    initial = bytes(capacity * BLOCK_SIZE)
    card = RecordingCard(MemoryStorage(initial))
    fs = FileSystem(card, ErrorFlags())
    states = [State((), None, bytes(2))]
    for index, op in enumerate(scenario):
        card.op = index
        run_op(fs, op)
        states.append(observe(fs))
    return Recording(initial, card.log, states)


@dataclass(frozen=True)
class Case:
    mode: str  # "cut" (write N lands whole), "prefix", "mix", "erase" (block left zero);
    # in the printer campaign also a Landing's "whole", "garble" and "partial"
    write: int  # 1-based write ordinal; "cut" with 0 = power lost before any write
    param: int = 0

    @property
    def id(self) -> str:
        return f"{self.mode}:{self.write}:{self.param}"

    @classmethod
    def parse(cls, text: str) -> Case:
        mode, write, param = text.split(":")
        return cls(mode, int(write), int(param))

    def landing(self) -> Landing:
        return Landing(self.mode, self.param)

    def tear(self) -> Tear | None:
        return self.landing().tear()


def cases(rec: Recording, modes: tuple[str, ...] = MODES) -> Iterator[Case]:
    """Every cut point in every mode (erase only where block 0 is written)."""
    rng = random.Random(2026)
    for n in range(0 if "cut" in modes else 1, len(rec.writes) + 1):
        if "cut" in modes:
            yield Case("cut", n)
        if n == 0:
            continue
        split = rng.randrange(1, BLOCK_SIZE)
        if "prefix" in modes:
            yield Case("prefix", n, split)
        if "mix" in modes:
            yield Case("mix", n, n)
        if "erase" in modes and rec.writes[n - 1][0] == 0:
            yield Case("erase", n)


class Media:
    """The card as it stands after writes 1..n, advanced one write at a time."""

    def __init__(self, rec: Recording):
        self.rec = rec
        self._reset()
        self._digests: dict[tuple, str] = {}

    def _reset(self) -> None:
        self.data = bytearray(self.rec.initial)
        self.applied = 0
        #: per block, the ordinal of the last write applied to it (0: none)
        self.last_write = np.zeros(len(self.data) // BLOCK_SIZE, dtype=np.int64)

    def advance_to(self, n: int) -> None:
        if n < self.applied:
            self._reset()
            self._digests.clear()
        while self.applied < n:
            block, data, _ = self.rec.writes[self.applied]
            self.data[block * BLOCK_SIZE : (block + 1) * BLOCK_SIZE] = data
            self.applied += 1
            self.last_write[block] = self.applied

    def surviving_card(self, case: Case) -> SdCard:
        """The card after power failed at `case`."""
        self._case = case
        if case.write == 0:
            self.advance_to(0)
            return SdCard(MemoryStorage(self.data))
        self.advance_to(case.write - 1)
        block, new, _ = self.rec.writes[case.write - 1]
        data = bytearray(self.data)
        offset = block * BLOCK_SIZE
        tear = case.tear()
        data[offset : offset + BLOCK_SIZE] = tear.apply(
            bytes(data[offset : offset + BLOCK_SIZE]), new) if tear else new
        self._survivor = data
        return SdCard(MemoryStorage.adopt(data))

    def digest(self, start: int, length: int) -> str:
        """The digest of a file of the last surviving card, cached by what wrote its
        blocks: the same blocks last written by the same writes hold the same bytes."""
        capacity = len(self.data) // BLOCK_SIZE
        blocks = -(-length // BLOCK_SIZE)
        first = min(blocks, capacity - start)
        spans = [(start, start + first)] + ([(1, 1 + blocks - first)] if blocks > first else [])
        newest = max((int(self.last_write[a:b].max()) for a, b in spans if b > a), default=0)
        case = self._case
        torn = case.write and any(a <= self.rec.writes[case.write - 1][0] < b for a, b in spans)
        key = (start, length, newest, case.id if torn else None)
        if key not in self._digests:
            self._digests[key] = hashlib.sha1(
                _slot_bytes(self._survivor, start, length, capacity)).hexdigest()
        return self._digests[key]


def op_of(rec: Recording, case: Case) -> int:
    return rec.writes[case.write - 1][2] if case.write else 0


def judge(rec: Recording, case: Case, state: State) -> list[str]:
    """Problems with a surviving state for a cut during its operation (empty: legal)."""
    op = op_of(rec, case)
    return judge_states(rec.states[op], rec.states[op + 1], state)


def judge_states(before: State, after: State, state: State) -> list[str]:
    """Problems with `state` as the outcome of an operation cut between before and after."""
    problems = []
    kept = set(before.files) & set(after.files)
    allowed = set(before.files) | set(after.files)
    listed = set(state.files)
    problems += [f"committed file {f[0]!r} lost or changed" for f in sorted(kept - listed)]
    problems += [f"listed file {f[0]!r} is neither its old nor its new version"
                 for f in sorted(listed - allowed)]
    if len(state.files) != len(listed):
        problems.append("a file is listed twice")
    if state.last_job not in (before.last_job, after.last_job, None):
        problems.append(f"last job {state.last_job!r} is neither the old nor the new one")
    if state.nonvolatile not in (before.nonvolatile, after.nonvolatile):
        problems.append(f"nonvolatile bytes {state.nonvolatile.hex()} are neither old nor new")
    return problems


def use_again(fs: FileSystem, state: State) -> list[str]:
    """After a cut the card must work: store a file and read everything back."""
    data = content("after-cut", 700)
    if not upload(fs, "after-cut", data):
        return [f"upload after the cut failed: {fs.errors.describe()}"]
    if read_back(fs, "after-cut") != data:
        return ["the file stored after the cut does not read back"]
    survivors = set(state.files)
    return [f"after the cut, {f[0]!r} appeared" for f in observe(fs).files
            if f not in survivors and f[0].rstrip(b"\0") != b"after-cut"]


def check(rec: Recording, media: Media, case: Case, again: bool = True) -> list[str]:
    """Mount the card that survives `case`, judge it, and use it again."""
    card = media.surviving_card(case)
    fs = FileSystem(card, ErrorFlags())
    state = observe(fs, media.digest if case.write else None)
    problems = judge(rec, case, state)
    if case.mode == "erase" and fs.last_mount.action == "format" and state.files == ():
        # Beyond the byte-mix model: with no copy in flight (an update that
        # drops files to make room has no free block for one) the card is
        # formatted, as a printer would; it never lists a wrong file.
        problems = []
    if not problems and again:
        problems = use_again(fs, state)
    return [f"[{case.id}] {p}" for p in problems]


def replay(case_id: str, scenario: list[tuple] = SCENARIO) -> SdCard:
    """Run one case for real: the scenario from the top with the FaultPlan."""
    case = Case.parse(case_id)
    card = SdCard.blank(CAPACITY)
    tear = case.tear()
    if tear is not None:
        card.faults = FaultPlan(tear_write=case.write, tear=tear)
    elif case.write:
        card.faults = FaultPlan(cut_after_write=case.write)
    if case.mode == "cut" and case.write == 0:
        return card
    fs = FileSystem(card, ErrorFlags())
    try:
        for op in scenario:
            run_op(fs, op)
    except PowerCut:
        pass
    else:
        raise AssertionError(f"{case_id}: the scenario ended before the cut")
    card.faults = FaultPlan()
    return card
