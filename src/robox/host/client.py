"""The client API: one printer, spoken to strictly stop-and-wait.

Every method sends one command and reads its whole reply before returning,
so a host never has two commands in flight. Errors the printer reports in an
ack that were not already latched raise PrinterError, named in words; errors
latched before (say, from before the connection) are reported by `errors()`
and do not stop every command.
"""

from __future__ import annotations

import io
import sys
import time
from array import array
from bisect import bisect_left
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import BinaryIO, NamedTuple

from robox.errors import RoboxError, UsageError
from robox.formats import float8
from robox.formats.card_file import make_id
from robox.formats.protocol import (
    FIXED_REPLY_LENGTH,
    PAUSE_MASK_CONNECTED,
    REPLY_TO,
    ErrorBit,
    error_bits,
    error_names,
    is_text,
    reply_length,
)
from robox.host.transport import NoReply, TransportError

CHUNK = 512
PACKET_SIZE = 64  # the printer's bulk endpoints' packet (USB full speed)
#: How long a reply may take to begin before the printer counts as not answering.
DEFAULT_TIMEOUT_MS = 10_000
#: The "robox.wire" logger (-v logs each command and its reply in a line; -vv adds
#: their bytes in hex), once `wire_logger` has found logging in use.
_wire_log = None
#: While a job prints from its own upload, the status is checked every this many chunks
#: for the pause a printer makes when its reader catches up with the writer (16 KB: about
#: half a second of a real printer's upload, where a catch-up's park and return take
#: seconds; and a printer prints far slower than it stores, so the check mostly finds none).
CATCH_UP_CHECK_CHUNKS = 32
EEPROMS = {"head": 0, "reel0": 1, "reel1": 2}
PAUSE_STATES = {"0": "running", "1": "pausing", "2": "paused", "3": "resuming",
                "4": "selfie pause"}


class CatchUpPoints:
    """The line numbers at which a job reading an upload pauses if its reader catches up
    with the writer after k whole chunks: the complete lines of the first k chunks, for
    each k stored so far. Kept as a sorted array (4 bytes a chunk), not a set."""

    def __init__(self) -> None:
        self.counts = array("I")

    def add(self, lines: int) -> None:
        self.counts.append(lines)

    @property
    def last(self) -> int:
        return self.counts[-1] if self.counts else 0

    def __contains__(self, line: object) -> bool:
        i = bisect_left(self.counts, line)
        return i < len(self.counts) and self.counts[i] == line

    def __iter__(self) -> Iterator[int]:
        return iter(sorted(set(self.counts)))


def _chunks(source: BinaryIO, first: int = 0) -> Iterator[bytes]:
    source.seek(first * CHUNK)
    while block := source.read(CHUNK):
        yield block


def catch_up_lines(data: bytes | BinaryIO, chunks: int | None = None) -> CatchUpPoints:
    """The catch-up points of an upload of `data` after its first k chunks (k = 1..chunks,
    default every whole chunk). A file is read a chunk at a time."""
    source = io.BytesIO(data) if isinstance(data, bytes | bytearray) else data
    points, lines = CatchUpPoints(), 0
    for k, block in enumerate(_chunks(source)):
        if len(block) < CHUNK or (chunks is not None and k >= chunks):
            break
        lines += block.count(b"\r")
        points.add(lines)
    return points


@dataclass(frozen=True)
class Sent:
    """The outcome of send_file: the chunk the upload went on from, whether it had to
    start over (the printer had lost it), and whether the file is a job now printing
    (or left printing by the interrupted upload)."""

    first_chunk: int
    restarted: bool
    printing: bool
    already_stored: bool = False  # `resume` found the upload finished: nothing was sent
    #: the file's catch-up points, as the upload counted them (None: nothing was sent)
    catch_up: CatchUpPoints | None = None


class PrinterError(RoboxError):
    """The printer reported errors in its ack."""

    def __init__(self, bits: int, doing: str):
        self.bits = bits
        super().__init__(f"{doing}: the printer reports {', '.join(error_names(bits))}")


class FileTooLarge(PrinterError):
    """The printer refused an upload as larger than its card: it had stored `largest`
    bytes of it, the most a file on that card can have (the card does not report its
    size; this is how a host learns it)."""

    def __init__(self, bits: int, doing: str, largest: int):
        self.largest = largest
        super().__init__(bits, doing)


class ProtocolError(RoboxError):
    """The printer's reply was not the report the command asks for."""


@dataclass
class Status:
    job: str | None
    line: int
    pause: str
    busy: bool
    temperatures: dict
    eeproms: dict
    sd_card: bool
    position: dict
    tool: int
    filament: dict
    head_power: bool
    raw: bytes = field(repr=False, default=b"")

    @classmethod
    def parse(cls, report: bytes) -> Status:
        report = _status_report(report)
        job, line, pause = Progress.of(report)
        fields = float8.parse_fields  # (compiled: one call for each run of figures)
        temperatures = {}
        for name, start in (("nozzle0", 40), ("nozzle1", 65), ("bed", 90), ("ambient", 115)):
            ambient = name == "ambient"
            values = fields(report, start + 1, 2 if ambient else 3)
            temperatures[name] = {"mode": chr(report[start]), "measured": values[0],
                                  "target": values[1]}
            if not ambient:
                temperatures[name]["first_layer_target"] = values[2]
        states = {"0": "not present", "1": "present, not valid", "2": "valid"}
        eeproms = {name: states.get(chr(report[134 + i]), "?")
                   for i, name in enumerate(("head", "reel0", "reel1"))}
        eeproms["dual_reel_adaptor"] = report[137:138] == b"1"
        position = dict(zip("XYZB", fields(report, 139, 4), strict=True))
        values = fields(report, 172, 6)
        filament = {"E": {"diameter": values[0], "multiplier": values[1],
                          "feed_rate_multiplier": values[5]},
                    "D": {"diameter": values[2], "multiplier": values[3],
                          "feed_rate_multiplier": values[4]}}
        return cls(job, line, pause, report[26:27] != b"0",
                   temperatures, eeproms, report[138:139] == b"1", position,
                   int(chr(report[171])) if chr(report[171]).isdigit() else 0, filament,
                   report[220:221] == b"1", report)


def _status_report(report: bytes) -> bytes:
    """A status report's bytes (as bytes), once they are seen to be one."""
    if report[:1] != b"\xe1" or len(report) != 222:
        raise ProtocolError("malformed status report")
    return bytes(report)  # (the bytes as they are, where it is bytes already)


class Progress(NamedTuple):
    """Of a status report, what following a job looks at: its job, line and pause state,
    as Status has them, read without the rest (the temperatures, positions and the
    like), at every poll of a print followed to its end."""

    job: str | None
    line: int
    pause: str

    @classmethod
    def of(cls, report: bytes) -> Progress:
        """Of a status report (checked: see _status_report)."""
        return cls(report[1:17].split(b"\0", 1)[0].decode("ascii", "replace") or None,
                   int(report[17:25], 16), PAUSE_STATES.get(chr(report[25]), "?"))


def wire_logger():
    """The "robox.wire" logger, or None while no part of the program has imported
    logging: a logger can only be set up through it, so until then there is nothing to
    log to, and a command that does not log need not load it."""
    global _wire_log
    if _wire_log is None and "logging" in sys.modules:
        _wire_log = sys.modules["logging"].getLogger("robox.wire")
    return _wire_log


def log_exchange(wire_log, frame: bytes, reply: bytes) -> None:
    wire_log.info("sent %#04x (%d bytes), got %#04x (%d bytes)", frame[0], len(frame),
                  reply[0], len(reply))
    wire_log.debug("  > %s", frame.hex(" "))
    wire_log.debug("  < %s", reply.hex(" "))


class Printer:
    """A printer at the other end of a transport."""

    def __init__(self, transport, reply_timeout_ms: int = DEFAULT_TIMEOUT_MS,
                 idle: Callable[[float], None] | None = None):
        self.transport = transport
        self.timeout = reply_timeout_ms
        self.in_flight = False
        self.known_errors = 0
        self.idle = idle or time.sleep
        self.commands_sent = 0
        self.catch_up_resumes = 0  # pauses of a job that caught up with its upload, resumed
        # the most bytes a file on the card can have, where the host can know it (a
        # virtual printer's card image); a printer does not report its card's size
        self.largest_file: int | None = None
        self.known_errors = self.errors()

    # ------------------------------------------------------------ wire
    def transact(self, frame: bytes) -> bytes:
        """Send one command, read its whole reply. Never two in flight."""
        if self.in_flight:
            raise ProtocolError("a command is already in flight")
        self.in_flight = True
        try:
            transport, timeout = self.transport, self.timeout
            transport.write(frame, timeout)
            self.commands_sent += 1
            expected = REPLY_TO.get(frame[0], 0xE3)
            # A report of fixed length in one read of whole packets (its last packet, a
            # short one or the one that fills the buffer, ends the transfer); any other
            # reply's first packet says its length, and the rest follows.
            fixed = FIXED_REPLY_LENGTH.get(expected)
            want = PACKET_SIZE if fixed is None else -(-fixed // PACKET_SIZE) * PACKET_SIZE
            reply = transport.read(want, timeout)
            while True:
                if is_text(reply):
                    raise ProtocolError(f"the printer answered in text ({reply[:8]!r}), not "
                                        "a report: a text (Pronterface) host is using it or "
                                        "left a line unfinished")
                try:
                    length = reply_length(reply)
                except ValueError:
                    raise ProtocolError(f"unexpected reply {reply[:8]!r}") from None
                if length is not None:
                    if len(reply) >= length:
                        break
                    # the rest in one read of whole packets: the reply's last packet, a
                    # short one or the one that fills the buffer, ends the transfer
                    want = -(-(length - len(reply)) // PACKET_SIZE) * PACKET_SIZE
                reply += transport.read(want, timeout)
            wire_log = _wire_log or wire_logger()
            if wire_log is not None and wire_log.isEnabledFor(20):  # logging.INFO
                log_exchange(wire_log, frame, reply)
            if reply[0] != expected or len(reply) != length:
                raise ProtocolError(f"asked {frame[0]:#04x}, got a {reply[0]:#04x} report")
            return reply
        finally:
            self.in_flight = False

    def ack(self, frame: bytes, doing: str) -> int:
        bits = error_bits(self.transact(frame))
        fresh = bits & ~self.known_errors
        self.known_errors = bits
        if fresh:
            raise PrinterError(fresh, doing)
        return bits

    # ----------------------------------------------------------- reports
    def errors(self) -> int:
        return error_bits(self.transact(b"\xb3"))

    def clear_errors(self) -> None:
        self.transact(b"\xc0")
        self.known_errors = 0

    def status(self) -> Status:
        return Status.parse(self.transact(b"\xb0"))

    def progress(self) -> Progress:
        """The status report's job, line and pause state alone (see Progress)."""
        return Progress.of(_status_report(self.transact(b"\xb0")))

    def files(self) -> list[str]:
        reply = self.transact(b"\x96")
        count = int(reply[1:3], 16)
        return [reply[3 + 16 * i : 19 + 16 * i].split(b"\0", 1)[0].decode("ascii", "replace")
                for i in range(count)]

    def revision(self) -> str:
        return self.transact(b"\xb4")[1:].split(b"\0", 1)[0].decode("ascii", "replace")

    def unique_id(self) -> str:
        raw = self.transact(b"\xb2")[1:]
        return raw.split(b"\0", 1)[0].decode("ascii", "replace").strip()

    def hours(self) -> float:
        return float8.parse(self.transact(b"\xb6")[1:])

    def sd_card_present(self) -> bool:
        return self.transact(b"\xbb")[1:2] == b"1"

    def send_file_report(self) -> tuple[str | None, int]:
        reply = self.transact(b"\x93")
        file_id = reply[1:17].split(b"\0", 1)[0].decode("ascii", "replace")
        return (file_id or None), int(reply[17:25], 16)

    # ------------------------------------------------------------ control
    def gcode(self, text: str | bytes) -> str:
        data = text.encode("ascii") if isinstance(text, str) else text
        if len(data) > 1019:
            raise UsageError("G-code text longer than 1019 bytes does not fit one command")
        reply = self.transact(b"\x95" + f"{len(data):04x}".encode() + data)
        return reply[5:].decode("ascii", "replace")

    def run_job(self, file_id: str = "") -> None:
        self.ack(b"\x94" + (make_id(file_id) if file_id else bytes(16)), "run job")

    def pause(self) -> None:
        self.ack(b"\x981", "pause")

    def resume(self) -> None:
        self.ack(b"\x980", "resume")

    def abort(self) -> None:
        self.ack(b"\xff", "abort")

    def reset(self) -> None:
        self.ack(b"\xfd", "reset")

    # ----------------------------------------------------------- EEPROMs
    def read_eeprom(self, which: str) -> bytes:
        index = EEPROMS[which]
        reply = self.transact(bytes([0xA1 + 2 * index]))
        bits = error_bits(self.transact(b"\xb3"))
        bit = (ErrorBit.HEAD_EEPROM, ErrorBit.REEL0_EEPROM, ErrorBit.REEL1_EEPROM)[index]
        if bits >> bit & 1 and not self.known_errors >> bit & 1:
            self.known_errors |= 1 << bit
            raise PrinterError(1 << bit, f"read {which} EEPROM")
        return reply[1:]

    def read_eeprom_fields(self, which: str, shown: bool = False) -> dict:
        """The EEPROM's fields as the printer reads them, or with `shown` as a person
        wrote them (eeprom_format.shown_fields)."""
        from robox.formats import eeprom as eeprom_format

        data = self.read_eeprom(which)
        kind = "head" if which == "head" else "reel"
        return (eeprom_format.shown_fields if shown else eeprom_format.fields_of)(kind, data)

    def write_eeprom(self, which: str, address: int, data: bytes) -> None:
        index = EEPROMS[which]
        for offset in range(0, len(data), 255):
            part = data[offset : offset + 255]
            self.ack(bytes([0xA0 + 2 * index]) + f"{address + offset:02x}{len(part):02x}"
                     .encode() + part, f"write {which} EEPROM")

    def write_eeprom_fields(self, which: str, assignments: dict[str, str]) -> None:
        from robox.formats import eeprom as eeprom_format

        kind = "head" if which == "head" else "reel"
        for name, value in assignments.items():
            f = eeprom_format.field(kind, name)
            self.write_eeprom(which, f.offset, eeprom_format.mask7(f.encode(value)))

    def format_eeprom(self, which: str) -> None:
        self.ack(bytes([0xF8 + EEPROMS[which]]), f"format {which} EEPROM")

    # --------------------------------------------------------- send a job
    def resume_if_caught_up(self, name: str, catch_up_lines: CatchUpPoints,
                            notice: Callable[[str], None] | None = None) -> bool:
        """Resume job `name` if it is paused because its reader caught up with the
        upload: the printer then pauses and stays paused until a host resumes it.

        That pause is told apart from others by where it happened. The reader reads the
        file a 512-byte chunk at a time, so it catches up having run exactly the complete
        lines of the first k chunks, for some k stored: `catch_up_lines` holds those line
        counts. A pause at one of them with no error latched that pauses a job is taken
        as the catch-up; any other pause (the user's, the job's own M1, an error) is left
        alone, and `notice` hears of it."""
        status = self.progress()
        why = self.paused_for(name, catch_up_lines, status)
        if why is None:
            return False
        if why == "catch-up":
            self.resume_catch_up()
            return True
        if notice is not None:
            reason = f"errors: {', '.join(error_names(why))}" if why else \
                "by the user or the job"
            notice(f"{name} is {status.pause} at line {status.line} ({reason}); "
                   "it is left paused")
        return False

    def resume_catch_up(self) -> None:
        """Resume a job paused because it caught up with its upload (and count it)."""
        self.resume()
        self.catch_up_resumes += 1

    def paused_for(self, name: str, catch_up_lines: CatchUpPoints,
                   status: Status | Progress) -> str | int | None:
        """Why job `name` is paused, given its `status`: "catch-up" (its reader caught
        up with the upload), the error bits that pause a job (an int, non-zero), or 0
        (the user, or the job itself); None when it is not paused."""
        if status.job != name or status.pause not in ("pausing", "paused"):
            return None
        pausing = self.errors() & PAUSE_MASK_CONNECTED
        if pausing:
            return pausing
        return "catch-up" if status.line in catch_up_lines else 0

    def send_file(self, data: bytes | BinaryIO, file_id: str, job: bool = True,
                  run: bool = True, resume: bool = False,
                  progress: Callable[[int, int], None] | None = None,
                  notice: Callable[[str], None] | None = None,
                  ready: Callable[[], None] | None = None, follow: bool = False,
                  held: Callable[[], bool] | None = None) -> Sent:
        """Store `data` (bytes, or a seekable binary file read a chunk at a time) as a
        file: start, chunks, end. A job starts printing once more than one chunk is
        stored, and is resumed whenever it pauses because it caught up with the upload
        (see resume_if_caught_up). With `resume`, continue the upload the printer reports
        as open instead of starting over.

        A printer that was switched off or reset has no upload open: its partial file was
        never committed, so with `resume` the file is sent again from the start, and a job
        is then not started (its print was cut short on the bed; run_job prints it from
        the start once the bed is clear).

        `ready` is called once the job could start (more than one chunk stored, or the
        whole file; not on a resumed upload whose job already runs): with `run` False
        and `follow`, another party starts it then (a host such as OctoPrint, with its
        own run command), and the upload still resumes the job whenever it catches up,
        except while `held()` says the job was paused on purpose (a pause at a
        catch-up line looks the same). Returns what happened."""
        source = io.BytesIO(data) if isinstance(data, bytes | bytearray) else data
        size = source.seek(0, io.SEEK_END)
        stored = make_id(file_id)
        name = stored.rstrip(b"\0").decode("ascii")
        chunks = size // CHUNK
        first = 0
        restarted = False
        if resume:
            open_id, first = self.send_file_report()
            if open_id is not None and open_id != name:
                raise RoboxError(f"the printer has no upload of {name!r} to resume (it is "
                                 f"receiving {open_id!r})")
            if open_id is None and name in self.files():
                # the upload finished before the link went: the file is on the card (an
                # id made from the content means the same content), so nothing is sent
                return Sent(chunks + 1, False, job and self.status().job == name, True)
            if open_id is None:
                restarted, first, run = True, 0, False
                if notice is not None:
                    notice(f"the printer has no upload of {name} open (it was switched off or "
                           "reset): sending it again from the start")
        if not resume or restarted:
            self.ack((b"\x97" if job else b"\x90") + stored, f"start {name}")
        # a job whose run command was lost with the link is not running yet: ask
        started = resume and not restarted and first > 1 and self.status().job == name
        start = job and run  # this call runs the job; `watch`: it resumes catch-ups
        watch = start or (job and follow)
        noticed = set()

        def tell(message: str) -> None:
            if notice is not None and message.split(" (")[0] not in noticed:
                noticed.add(message.split(" (")[0])
                notice(message)

        caught_up_at = catch_up_lines(source, first)
        lines = caught_up_at.last
        tail = b""
        for sequence, block in enumerate(_chunks(source, first), first):
            if len(block) < CHUNK:
                tail = block
                break
            self._store(b"\x91" + f"{sequence:08x}".encode() + block, f"chunk {sequence}",
                        sequence * CHUNK)
            lines += block.count(b"\r")
            caught_up_at.add(lines)
            if progress:
                progress((sequence + 1) * CHUNK, size)
            if not started and sequence >= 1:
                if start:
                    self.run_job(name)
                started = True
                if ready is not None:
                    ready()
            elif watch and started and sequence % CATCH_UP_CHECK_CHUNKS == 0 and \
                    not (held and held()):
                self.resume_if_caught_up(name, caught_up_at, tell)
        self._store(b"\x92" + f"{chunks:08x}{len(tail):04x}".encode() + tail, f"end {name}",
                    chunks * CHUNK)
        if progress:
            progress(size, size)
        if not started:
            if start:
                self.run_job(name)
            if ready is not None:
                ready()
        elif watch and not (held and held()):
            # a pause made while the last chunks were on their way stays until resumed
            self.resume_if_caught_up(name, caught_up_at, tell)
        return Sent(first, restarted, start, catch_up=caught_up_at)

    def _store(self, frame: bytes, doing: str, stored: int) -> None:
        """Acknowledge a chunk (or the end) of an upload of which `stored` bytes are on
        the card before it: the card is full when that chunk is refused as too large."""
        try:
            self.ack(frame, doing)
        except PrinterError as exc:
            if exc.bits >> ErrorBit.FILE_TOO_LARGE & 1:
                raise FileTooLarge(exc.bits, doing, stored) from None
            raise

    # ---------------------------------------------------- update firmware
    def update_firmware(self, image: bytes, file_id: str = "robox_firmware",
                        progress: Callable[[int, int], None] | None = None,
                        reconnect: Callable[[], Printer] | None = None) -> Printer:
        """Verify locally, upload as SD text, trigger the update, wait for the printer
        to come back; returns the printer to use afterwards."""
        from robox.formats.firmware import check_binary, to_sd_text

        verdict = check_binary(image)
        if not verdict.accepted:
            reasons = "; ".join(f"{c.value} ({d})" for c, d in verdict.failures)
            raise RoboxError(f"the image would be refused: {reasons}")
        self.send_file(to_sd_text(image), file_id, job=False, progress=progress)
        self.ack(b"\x8f" + make_id(file_id), "update firmware")
        printer = reconnect() if reconnect else self
        deadline = time.monotonic() + 60
        while True:
            try:
                printer.revision()
                return printer
            except (NoReply, TransportError):
                if time.monotonic() > deadline:
                    raise
                self.idle(0.5)
