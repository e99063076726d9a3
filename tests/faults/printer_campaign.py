"""Power cut at every write of a print still being uploaded: card, EEPROMs and flash.

The scenario: a host on a slow link uploads a heated job through the real client
and the pyusb backend; the printer starts it after the second chunk, catches up
with the upload again and again (the host resumes each pause), extrudes, books
filament and head hours to the reel and head EEPROMs every 7.2 s, finishes, and
writes the job's run time to the hours page of its flash. Every write to a
nonvolatile medium is counted in one sequence (hardware.faults.PowerPlan).

As in the card campaign, the scenario runs once while recording those writes:
the printer that survives a cut during write N holds the initial media plus
writes 1..N-1 plus write N landed whole or torn (a card block torn as a prefix,
a byte mix or erased; an EEPROM byte left holding another value; a flash page
erased and partly programmed). A cut between two writes, during a card read,
or while the job reads its file leaves the same media as one right after the
last write before it, so these cases cover every moment of the run.
`replay(case_id)` runs a cut for real, from the top, through the PowerPlan.

At every cut the survivor is judged (`check`, through a `Judge`): the card mounts with every file
committed before the cut intact, the job either absent or whole, the last job
and the nonvolatile bytes old or new; after power-up each EEPROM loads VALID
holding one of the last two images the firmware was writing to it (so the
reel's remaining filament is one of its last two values written); the hours
page holds its old or new text (torn by a cut during its own page write, which
the firmware does not guard against, it still reads back as the page holds
it); the image is intact; and `send_file(..., resume=True)` then stores the job
byte-identical.

Every survivor is powered up whole and its chips, flash and hours report are judged
on it. Two judgements depend on the card alone, and are made once per distinct card
(the `Judge` keeps them): the mount, and the upload sent again with resume. The
upload is the command object's and the file system's, which own the card; on a
printer freshly powered up, with no job, the only other thing that path sees is
whether each EEPROM is there (the status report), so the EEPROMs' states are part of
the key, with the blocks power-up wrote to the card (the mount's recovery).
`test_survivors_that_share_an_upload_verdict_upload_alike` checks the premise: on
survivors that share a key but differ in their EEPROMs, the upload leaves the same
card. A survivor's card is named without hashing
its bytes: by how many card writes it holds, and how the last one landed when the cut
was one.
"""

from __future__ import annotations

import bisect
import hashlib
import math
import random
from dataclasses import dataclass
from functools import cache, cached_property

import usb.core

from robox.errors import PowerCut
from robox.firmware.error_flags import ErrorFlags
from robox.firmware.file_system import FileSystem
from robox.formats.eeprom import DATA_SIZE, EepromIndex
from robox.formats.firmware import HOURS_PAGE, PAGE_SIZE
from robox.formats.protocol import ErrorBit
from robox.formats.sdcard import BLOCK_SIZE, Directory, make_id
from robox.hardware.faults import PowerPlan
from robox.hardware.sdcard import SdCard
from robox.hardware.storage import MemoryStorage
from robox.host.client import Printer, catch_up_lines
from robox.host.transport import UsbTransport
from robox.sim.printer import Media, VirtualPrinter
from robox.sim.usb_backend import VirtualRoboxBackend
from tests.faults.campaign import Case, State, observe

CARD_BLOCKS = 2048  # the smallest card on which a new file may start past block 1
JOB_ID = "part"
HOST_IDLE_S = 8.0  # a slow link: simulated seconds the host spends per chunk
CHIPS = (EepromIndex.HEAD, EepromIndex.REEL0)


def job_bytes(lines: int = 400) -> bytes:
    text = ["M104 S210", "G28 X Y", "M109 S210", "G90"]
    for i in range(lines):
        a = i * 0.1
        text.append(f"G1 X{100 + 30 * math.cos(a):.3f} Y{75 + 30 * math.sin(a):.3f} E0.05 "
                    "F3000")
    text.append("M104 S0")
    return "".join(line + "\r" for line in text).encode()


JOB = job_bytes()


def connect(virtual: VirtualPrinter) -> Printer:
    backend = VirtualRoboxBackend(virtual)
    device = usb.core.find(idVendor=0x16D0, idProduct=0x081B, backend=backend)
    return Printer(UsbTransport(device), idle=lambda s: virtual.run_until(
        lambda: False, s))


@cache
def initial_media() -> Media:
    """A settled printer whose card already holds two jobs, the last one printed."""
    virtual = VirtualPrinter(card_blocks=CARD_BLOCKS)
    virtual.settle()
    printer = connect(virtual)
    printer.send_file(b"G1 X20 Y20 F3000\rG1 X40 Y40\r" * 100, "first", run=False)
    printer.send_file(b"G28 X Y\rG1 X50 Y50 F3000\r" * 30, "older")
    virtual.run_until(lambda: not virtual.firmware.job.running, 100)
    virtual.cool_down()
    virtual.settle()
    printer.clear_errors()
    return virtual.media()


def scenario(virtual: VirtualPrinter) -> None:
    """The host's side: upload on a slow link while printing, then follow to the end."""
    printer = connect(virtual)
    printer.send_file(JOB, JOB_ID, progress=lambda done, total: printer.idle(HOST_IDLE_S))
    caught_up = catch_up_lines(JOB)
    while virtual.firmware.job.running:
        printer.resume_if_caught_up(JOB_ID, caught_up)
        printer.idle(1.0)
    virtual.settle()


# ------------------------------------------------------------------ recording
@dataclass(frozen=True)
class Write:
    medium: str  # "card", "head", "reel0", "flash"
    address: int  # block, byte address, page
    data: bytes
    time: float
    #: what the firmware held in RAM for each chip of CHIPS as this write reached its medium
    intents: tuple[bytes, ...]


@dataclass
class Recording:
    initial: Media
    writes: list[Write]
    final: Media

    def initial_files(self) -> State:
        """The initial card as a mount shows it (worked out once)."""
        return self._initial_files

    def chip_images(self, n: int, chip: int) -> list[bytes]:
        """The distinct RAM images of a chip the firmware had asked for up to write n."""
        changes = self._chip_changes[chip]
        return [image for at, image in changes[: bisect.bisect_left(changes, (n, b""))]]

    def directory_writes(self) -> list[tuple[int, bytes]]:
        """(write number, nonvolatile bytes) of the initial directory (number 0) and of
        each write to the card's directory."""
        return self._directories

    @cached_property
    def _initial_files(self) -> State:
        return files_of(self.initial)

    @cached_property
    def _directories(self) -> list[tuple[int, bytes]]:
        blocks = [(0, self.initial.card[:BLOCK_SIZE])] + [
            (k, write.data) for k, write in enumerate(self.writes, 1)
            if write.medium == "card" and write.address == 0]
        return [(k, Directory.decode(block).nonvolatile) for k, block in blocks]

    @cached_property
    def _chip_changes(self) -> list[list[tuple[int, bytes]]]:
        # per chip, (index of the write it first rode on, image) for each distinct image
        changes: list[list[tuple[int, bytes]]] = [[] for _ in CHIPS]
        for k, write in enumerate(self.writes):
            for chip, image in enumerate(write.intents):
                if not changes[chip] or changes[chip][-1][1] != image:
                    changes[chip].append((k, image))
        return changes


class _Recorder(PowerPlan):
    def __init__(self, virtual: VirtualPrinter):
        super().__init__()
        self.virtual = virtual
        hw = virtual.hw
        self.names = {id(hw.card): "card", id(hw.flash): "flash"}
        for index in CHIPS:
            self.names[id(hw.eeprom_bus.sockets[index])] = index.name.lower()
        self.records: list[Write] = []

    def write(self, device, address, data):
        fw = self.virtual.firmware
        self.records.append(Write(self.names[id(device)], address, bytes(data), fw.clock.now,
                                 tuple(bytes(fw.eeproms.states[i].data) for i in CHIPS)))
        return super().write(device, address, data)


@cache
def record() -> Recording:
    initial = initial_media()
    virtual = VirtualPrinter(media=initial)
    virtual.settle()  # switched on a moment ago: the EEPROMs have loaded
    recorder = _Recorder(virtual)
    virtual.supply(recorder)
    scenario(virtual)
    return Recording(initial, recorder.records, virtual.media())


# ---------------------------------------------------------------------- cases
def cases(rec: Recording) -> list[Case]:
    """Every write, landed whole and torn in each way its medium can tear."""
    rng = random.Random(2026)
    builder = MediaBuilder(rec)
    out = []
    for n, write in enumerate(rec.writes, 1):
        out.append(Case("whole", n))
        if write.medium == "card":
            out.append(Case("prefix", n, rng.randrange(1, BLOCK_SIZE)))
            out.append(Case("mix", n, n))
            if write.address in (0, 1):
                out.append(Case("erase", n))
        elif write.medium == "flash":
            out += [Case("partial", n, 0), Case("partial", n, rng.randrange(1, 8))]
        else:
            old = builder.chip_byte(n, write)
            out.append(Case("garble", n, next(v for v in (old ^ 0xFF, 0x55, 0xAA)
                                              if v not in (old, write.data[0]))))
    return out


class MediaBuilder:
    """The media as they stand after writes 1..n, advanced one write at a time."""

    def __init__(self, rec: Recording):
        self.rec = rec
        self._reset()

    def _reset(self) -> None:
        initial = self.rec.initial
        self.card = bytearray(initial.card)
        self.chips = {"head": bytearray(initial.chips[EepromIndex.HEAD]),
                      "reel0": bytearray(initial.chips[EepromIndex.REEL0])}
        self.flash = bytearray(initial.flash)
        self.applied = 0

    def _apply(self, write: Write, data: bytes | None = None) -> None:
        data = write.data if data is None else data
        if write.medium == "card":
            self.card[write.address * BLOCK_SIZE : (write.address + 1) * BLOCK_SIZE] = data
        elif write.medium == "flash":
            self.flash[write.address * PAGE_SIZE : (write.address + 1) * PAGE_SIZE] = data
        else:
            self.chips[write.medium][write.address] = data[0]

    def advance_to(self, n: int) -> None:
        if n < self.applied:
            self._reset()
        while self.applied < n:
            self._apply(self.rec.writes[self.applied])
            self.applied += 1

    def card_key(self, case: Case) -> tuple:
        """Names the survivor's card: equal keys, equal card bytes."""
        writes = self.rec.writes
        held = self._writes_before("card", case.write)
        if writes[case.write - 1].medium != "card":
            return (held,)
        return (held, case.mode, case.param)

    def _writes_before(self, medium: str, n: int) -> int:
        """How many of writes 1..n-1 went to `medium`."""
        counts = self.__dict__.setdefault("_counts", {})
        if medium not in counts:
            running = [0]
            for write in self.rec.writes:
                running.append(running[-1] + (write.medium == medium))
            counts[medium] = running
        return counts[medium][n - 1]

    def chip_byte(self, n: int, write: Write) -> int:
        self.advance_to(n - 1)
        return self.chips[write.medium][write.address]

    def survivor(self, case: Case) -> Media:
        """The media after power failed during `case`'s write."""
        self.advance_to(case.write - 1)
        write = self.rec.writes[case.write - 1]
        card, flash = self._frozen("card"), self._frozen("flash")
        chips = {name: bytes(data) for name, data in self.chips.items()}
        landed = write.data
        if write.medium == "card":
            offset = write.address * BLOCK_SIZE
            tear = case.landing().tear()
            if tear is not None:
                landed = tear.apply(card[offset : offset + BLOCK_SIZE], write.data)
            card = _spliced(self.card, offset, landed)
        elif write.medium == "flash":
            count = PAGE_SIZE if case.mode == "whole" else case.param
            landed = write.data[:count] + b"\xff" * (PAGE_SIZE - count)
            flash = _spliced(self.flash, write.address * PAGE_SIZE, landed)
        else:
            byte = case.param if case.mode == "garble" else write.data[0]
            chips[write.medium] = _spliced(self.chips[write.medium], write.address,
                                           bytes([byte]))
        return Media(card, (chips["head"], chips["reel0"], None), flash)

    def _frozen(self, medium: str) -> bytes:
        """The card's or the flash's bytes as they stand, copied once per change: the
        survivors of cuts that did not touch a medium share its bytes."""
        frozen = self.__dict__.setdefault("_frozen_media", {})
        held = self._writes_before(medium, self.applied + 1)
        if medium not in frozen or frozen[medium][0] != held:
            frozen[medium] = (held, bytes(getattr(self, medium)))
        return frozen[medium][1]


def _spliced(data: bytearray, offset: int, landed: bytes) -> bytes:
    """`data` with `landed` written at `offset`, in a single copy."""
    view = memoryview(data)
    return b"".join((view[:offset], landed, view[offset + len(landed) :]))


# --------------------------------------------------------------------- judging
def files_of(media: Media) -> State:
    """The card's state as a mount shows it."""
    return observe(FileSystem(SdCard(MemoryStorage(media.card)), ErrorFlags()))


def _nonvolatile_written(rec: Recording, n: int) -> set[bytes]:
    """Nonvolatile bytes the directory held as of write n-1, and those of write n."""
    latest, legal = None, set()
    for k, nonvolatile in rec.directory_writes():
        if k < n:
            latest = nonvolatile
        elif k == n:
            legal.add(nonvolatile)
        else:
            break
    return legal | {latest}


def job_digest() -> str:
    return hashlib.sha1(JOB).hexdigest()


def judge_card(rec: Recording, case: Case, state: State) -> list[str]:
    before = rec.initial_files()
    problems = [f"committed file {f[0]!r} lost or changed" for f in before.files
                if f not in state.files]
    new_id = make_id(JOB_ID)
    for file_id, digest in state.files:
        if (file_id, digest) in before.files:
            continue
        if file_id != new_id:
            problems.append(f"file {file_id!r} appeared")
        elif digest != job_digest():
            problems.append("the job is listed but is not the whole job")
    if len(set(state.files)) != len(state.files):
        problems.append("a file is listed twice")
    listed = {file_id for file_id, _ in state.files}
    # the job became the last job when it started, while still uploading; if the cut
    # then lost it, the last job can only be none
    lost = None if new_id not in listed else new_id
    if state.last_job not in (before.last_job, new_id, lost):
        problems.append(f"last job {state.last_job!r} is neither the old nor the new one")
    if state.nonvolatile not in _nonvolatile_written(rec, case.write):
        problems.append(f"nonvolatile bytes {state.nonvolatile.hex()} were never written")
    return problems


def judge_printer(rec: Recording, case: Case, media: Media, judge: Judge | None = None,
                  card_key: tuple | None = None) -> list[str]:
    """Power the survivor up, let it load, and judge its chips, flash and upload (the
    upload's verdict shared through `judge` between survivors whose card and loaded
    EEPROMs are the same, when `card_key` names the card)."""
    virtual = VirtualPrinter(media=media)
    card = virtual.hw.card
    powered_up = PowerPlan(log=[])  # what power-up wrote (the mount's recovery, say)
    virtual.supply(powered_up)
    virtual.settle()
    virtual.supply(None)
    fw = virtual.firmware
    problems = []
    for position, index in enumerate(CHIPS):
        name = index.name.lower()
        images = rec.chip_images(case.write, position)[-2:]
        status = fw.eeproms.status(index)
        data = bytes(fw.eeproms.states[index].data[:DATA_SIZE])
        if status.name != "VALID":
            problems.append(f"{name} EEPROM is {status.name} after power-up")
        elif data not in [image[:DATA_SIZE] for image in images]:
            problems.append(f"{name} EEPROM loaded an image that was not one of the last two "
                            "written")
    page = media.flash[HOURS_PAGE * PAGE_SIZE : (HOURS_PAGE + 1) * PAGE_SIZE]
    before = rec.initial.flash[HOURS_PAGE * PAGE_SIZE : (HOURS_PAGE + 1) * PAGE_SIZE]
    written = [w.data for w in rec.writes[: case.write] if w.medium == "flash"]
    torn = case.mode == "partial" and rec.writes[case.write - 1].medium == "flash"
    if page not in [before, *written[-1:]] and not torn:
        problems.append("the hours page holds neither its old nor its new text")
    if virtual.transact(b"\xb6")[1:9] != bytes(b & 0x7F for b in page[:8]):
        problems.append("0xb6 does not report the hours page")
    if fw.errors.is_set(ErrorBit.FLASH_CHECKSUM):
        problems.append("FLASH_CHECKSUM after a cut that never touched the image")
    key = None
    if judge is not None and card_key is not None:
        key = (card_key, tuple((block, data) for device, block, data in powered_up.log
                               if device is card),
               tuple(s.status for s in fw.eeproms.states))
        if key in judge.uploads:
            return problems + judge.uploads[key]
    printer = connect(virtual)
    printer.clear_errors()
    sent = printer.send_file(JOB, JOB_ID, resume=True)
    stored = fw.file_system.read_committed(make_id(JOB_ID))
    upload = []
    # no upload is open after power-up: the file is sent again, or, when the cut came
    # after the upload was committed, found on the card and not sent
    if not sent.restarted and not sent.already_stored:
        upload.append("after power-up the printer still reported the upload open")
    if stored != JOB:
        upload.append("the job sent again with resume is not stored byte-identical")
    if key is not None:
        judge.uploads[key] = upload
    return problems + upload


class Judge:
    """Judges cut points one after another, keeping what depends on the card alone."""

    def __init__(self, rec: Recording):
        self.rec = rec
        self.builder = MediaBuilder(rec)
        self.cards: dict[tuple, State] = {}
        self.uploads: dict[tuple, list[str]] = {}

    def check(self, case: Case) -> list[str]:
        media = self.builder.survivor(case)
        card_key = self.builder.card_key(case)
        state = self.cards.get(card_key)
        if state is None:
            state = self.cards[card_key] = files_of(media)
        problems = judge_card(self.rec, case, state) + \
            judge_printer(self.rec, case, media, self, card_key)
        return [f"[{case.id}] {p}" for p in problems]


def check(rec: Recording, builder: MediaBuilder, case: Case) -> list[str]:
    """One cut point judged afresh, nothing shared with another."""
    media = builder.survivor(case)
    state = files_of(media)
    problems = judge_card(rec, case, state) + judge_printer(rec, case, media)
    return [f"[{case.id}] {p}" for p in problems]


def replay(case_id: str) -> Media:
    """Run one case for real: the scenario from the top, power failing at its write."""
    case = Case.parse(case_id)
    virtual = VirtualPrinter(media=initial_media())
    virtual.settle()
    virtual.supply(PowerPlan(cut_at=case.write, landing=case.landing()))
    try:
        scenario(virtual)
    except PowerCut:
        pass
    else:
        raise AssertionError(f"{case_id}: the scenario ended before the cut")
    return virtual.media()

