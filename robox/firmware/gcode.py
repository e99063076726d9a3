"""The job engine: execute and job buffers, G-code lines, run / pause / resume / abort.

Two 1024-byte buffers: the execute buffer (lines from the host) always runs
before the job buffer (lines read from the job file, a block at a time).
`maintain_job()` starts at most one line per loop pass. A line that must wait
(G4, M400, M109, M190, a full motion queue, homing, parking) runs as a
generator that `maintain_job()` resumes once per pass until it is done, and no
other line starts meanwhile; the rest of the loop keeps running, so USB keeps
being answered. This is the printer's "wait by spinning do_everything_else()"
turned inside out, with the same observable order (docs/firmware-model.md).
Each yield says what the line waits for, so the loop can jump the clock to it.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from dataclasses import dataclass
from enum import IntEnum

from robox.formats.protocol import ErrorBit

BUFFER_SIZE = 1024
LINE_LIMIT = 512
IDLE_PAUSE_S = 600.0
IDLE_ABORT_S = 3600.0
REPORTING = {105, 111, 112, 113, 114, 115, 119, 503, 997, 999}
PARK = {"X": 5.0, "Y": 145.0}
PARK_LIFT = 5.0

_NUMBER = re.compile(rb"[ \t]*([+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?)")


@dataclass(frozen=True)
class Wait:
    """What a suspended line waits for: motion, a time, a heater, or just the next pass."""

    motion: bool = False
    until: float | None = None
    heater: str | None = None


NEXT_PASS = Wait()


def wait_for(condition, wait: Wait = NEXT_PASS) -> Iterator[Wait]:
    while not condition():
        yield wait


class PauseState(IntEnum):
    RUNNING = 0
    PAUSING = 1
    PAUSED = 2
    RESUMING = 3
    SELFIE = 4


def strip_comment(line: bytes) -> bytes:
    for mark in (b";", b"("):
        at = line.find(mark)
        if at >= 0:
            line = line[:at]
    return line.strip()


def parse_words(line: bytes) -> list[tuple[str, float]]:
    """Letter and number pairs; a number is read as strtod would (0 if there is none)."""
    words = []
    i, n = 0, len(line)
    while i < n:
        c = line[i]
        if 0x41 <= c <= 0x5A or 0x61 <= c <= 0x7A:
            match = _NUMBER.match(line, i + 1)
            if match:
                words.append((chr(c).upper(), float(match.group(1))))
                i = match.end()
            else:
                words.append((chr(c).upper(), 0.0))
                i += 1
        else:
            i += 1
    return words


def first_line(data: bytearray) -> int | None:
    """Index of the first line terminator (CR or LF), or None."""
    for i, c in enumerate(data):
        if c in (0x0A, 0x0D):
            return i
    return None


class Job:
    def __init__(self, firmware):
        self.fw = firmware

    def initialise(self) -> None:
        self.execute_buffer = bytearray()
        self.job_buffer = bytearray()
        self.running = False
        self.job_id: bytes | None = None
        self.line_number = 0
        self.pause_state = PauseState.RUNNING
        self.waiting_for_data = False
        self.parked: dict | None = None
        self.last_activity = self.fw.clock.now
        self.current: Iterator[Wait] | None = None  # the line (or park) under way
        self.current_owes_ok = False
        self.oks_owed = 0  # Pronterface lines queued and not yet answered
        self.waiting: Wait | None = None
        self.lines_executed = 0
        self.jobs_completed = 0

    # ------------------------------------------------------- host side
    def activity(self) -> None:
        self.last_activity = self.fw.clock.now

    def _reporting(self, line: bytes) -> int | None:
        words = parse_words(strip_comment(line))
        if words and words[0][0] == "M" and int(words[0][1]) in REPORTING:
            return int(words[0][1])
        return None

    def execute_now(self, line: bytes) -> bytes | None:
        """A Pronterface line: a reporting code runs at once (its response and ok are
        returned); another is queued and owed an ok once it has run (b""). None when
        the execute buffer has no room yet."""
        if self._reporting(line) is not None:
            return self.report(line)
        if len(self.execute_buffer) + len(line) + 1 > BUFFER_SIZE:
            return None
        self.execute_buffer += line + b"\r"
        self.oks_owed += 1
        return b""

    def report(self, line: bytes) -> bytes:
        """Run a reporting code now: its response text, ended by ok."""
        gen = self.execute(line)
        for _ in gen:  # reporting codes never wait
            pass
        return self.last_response + b"ok\r\n"

    def execute_from_host(self, text: bytes) -> bytes:
        """Command 0x95: reporting lines run now, the rest is queued (or dropped if full)."""
        queued = bytearray()
        response = bytearray()
        rest = bytes(text)
        while rest:
            end = first_line(bytearray(rest))
            if end is None:
                queued += rest  # no terminator: queued as is, no response
                break
            line, rest = rest[:end], rest[end + 1 :]
            if self._reporting(line) is not None:
                response += self.report(line)
            else:
                queued += line + b"\r"
        if queued:
            if len(self.execute_buffer) + len(queued) > BUFFER_SIZE:
                self.fw.errors.set(ErrorBit.GCODE_BUFFER_OVERRUN)
            else:
                self.execute_buffer += queued
        return bytes(response)

    # ------------------------------------------------------ job control
    def run_job(self, file_id: bytes) -> bool:
        if self.running:
            return False
        if not self.fw.file_system.start_read_file(file_id):
            return False
        self.running = True
        self.job_id = self.fw.file_system.reading
        self.job_buffer.clear()
        self.line_number = 0
        self.pause_state = PauseState.RUNNING
        self.waiting_for_data = False
        self.activity()
        self.fw.events.append(("job started", self.job_id))
        return True

    def upload_started(self) -> None:
        pass

    def data_arrived(self) -> None:
        if self.waiting_for_data:
            self.waiting_for_data = False

    def pause(self, selfie: bool = False) -> None:
        """Pausing: the line under way ends, then the head parks (see maintain_job)."""
        if not self.running or self.pause_state != PauseState.RUNNING:
            return
        self.pause_state = PauseState.PAUSING
        self.selfie = selfie

    def _park(self) -> Iterator[Wait]:
        position = self.fw.position
        yield from wait_for(self.fw.motion.idle, Wait(motion=True))
        self.parked = position.save_state()
        yield from position.park(PARK, PARK_LIFT)
        self.pause_state = PauseState.SELFIE if self.selfie else PauseState.PAUSED

    def _unpark(self) -> Iterator[Wait]:
        if self.parked is not None:
            yield from self.fw.position.restore_state(self.parked)
        self.parked = None
        self.pause_state = PauseState.RUNNING

    def error_pause(self) -> None:
        if self.running:
            self.pause()

    def resume(self) -> None:
        """Resuming: the head goes back (see maintain_job), then the job continues."""
        if not self.running or self.pause_state not in (PauseState.PAUSED, PauseState.SELFIE):
            return
        self.pause_state = PauseState.RESUMING
        self.activity()

    def abort(self) -> None:
        """Stop reading, empty both buffers, wait for motion, heaters off, reload reels."""
        was = self.running
        self.fw.file_system.close()
        self.running = False
        self.job_id = None
        self.execute_buffer.clear()
        self.job_buffer.clear()
        self.pause_state = PauseState.RUNNING
        self.parked = None
        self.waiting_for_data = False
        self.current = None
        self.waiting = None
        self.oks_owed = 0
        self.current_owes_ok = False
        self.fw.motion.stop()
        self.fw.heaters.all_off()
        self.fw.position.reload_reels()
        if was:
            self.fw.events.append(("job aborted", None))

    def abort_if_reading(self) -> None:
        if self.running:
            self.abort()

    def _finish(self) -> None:
        self.fw.file_system.close()
        self.running = False
        self.fw.heaters.all_off()
        self.jobs_completed += 1
        self.fw.events.append(("job finished", self.job_id))
        self.job_id = None

    # ------------------------------------------------------------ status
    def pause_state_char(self) -> bytes:
        return str(int(self.pause_state)).encode()

    def busy_char(self) -> bytes:
        busy = bool(self.execute_buffer) or self.current is not None or \
            not self.fw.motion.idle() or (self.running and self.pause_state == PauseState.RUNNING)
        return b"1" if busy else b"0"

    def runnable(self) -> bool:
        """True when the next pass has a line to start (so the clock must not jump)."""
        if self.current is not None:
            return self.waiting is None or self.waiting == NEXT_PASS
        if first_line(self.execute_buffer) is not None:
            return True
        if self.pause_state in (PauseState.PAUSING, PauseState.RESUMING):
            return True
        return self.running and self.pause_state == PauseState.RUNNING and \
            not self.waiting_for_data

    # ------------------------------------------------------------- loop
    def maintain_job(self) -> None:
        if self.current is not None:
            self._drive()
            return
        if self.pause_state == PauseState.PAUSING:
            self._start(self._park())
            return
        if self.pause_state == PauseState.RESUMING:
            self._start(self._unpark())
            return
        now = self.fw.clock.now
        if now - self.last_activity >= IDLE_ABORT_S and (self.running or
                                                        self.fw.heaters.any_on()):
            self.abort()
            self.fw.heaters.all_off()
            self.activity()
            return
        if self.running and self.pause_state == PauseState.RUNNING and \
                now - self.last_activity >= IDLE_PAUSE_S:
            self.pause()
            return
        owed = self.oks_owed > 0 and first_line(self.execute_buffer) is not None
        line = self._next_line()
        if line is not None:
            self.activity()
            if owed:
                self.oks_owed -= 1
            self.current_owes_ok = owed
            self._start(self.execute(line))

    def _start(self, line: Iterator[Wait]) -> None:
        self.current = line
        self._drive()

    def _drive(self) -> None:
        try:
            self.waiting = next(self.current)
        except StopIteration:
            self.current = None
            self.waiting = None
            if self.current_owes_ok:
                self.current_owes_ok = False
                self.fw.command.send(b"ok\r\n")

    def _take_line(self, buffer: bytearray) -> bytes | None:
        end = first_line(buffer)
        if end is None:
            return None
        line = bytes(buffer[:end])
        del buffer[: end + 1]
        return line

    def _next_line(self) -> bytes | None:
        line = self._take_line(self.execute_buffer)
        if line is not None:
            return line
        if not self.running or self.pause_state != PauseState.RUNNING:
            return None
        line = self._take_line(self.job_buffer)
        if line is not None and len(line) > LINE_LIMIT:
            self.fw.errors.set(ErrorBit.GCODE_LINE_TOO_LONG)
            self.abort()
            return None
        if line is not None:
            self.line_number += 1
            return line
        fs = self.fw.file_system
        if len(self.job_buffer) >= LINE_LIMIT:  # half full, no line end: too long
            self.fw.errors.set(ErrorBit.GCODE_LINE_TOO_LONG)
            self.abort()
            return None
        data = fs.read()
        if data:
            self.waiting_for_data = False
            self.job_buffer += data
            return None
        if fs.reading is None and not fs.eof():
            self.abort()  # the file went away (card removed, clobbered)
            return None
        if not fs.eof():
            self.waiting_for_data = True  # caught up with the upload: wait for chunks
            return None
        if self.job_buffer:
            line = bytes(self.job_buffer)
            self.job_buffer.clear()
            self.line_number += 1
            return line
        if self.fw.motion.idle():
            self._finish()
        else:
            self.waiting_for_data = False
        return None

    # -------------------------------------------------------- execution
    def execute(self, raw: bytes) -> Iterator[Wait]:
        """Run one line (a generator: it yields while it waits). A reporting code leaves
        its response text in `last_response`."""
        self.last_response = b""
        line = strip_comment(raw)
        words = parse_words(line)
        if not words:
            return
        self.lines_executed += 1
        letter, number = words[0]
        params = {}
        for key, value in words[1:]:
            params.setdefault(key, value)
        code = int(number)
        try:
            if letter == "G":
                yield from self._g(code, params)
            elif letter == "M":
                yield from self._m(code, params)
            elif letter == "T":
                yield from self.fw.position.select_tool(code)
        except Exception as exc:  # pragma: no cover - a model bug must not stop the loop
            self.fw.note_fault(exc)

    def _g(self, code: int, p: dict) -> Iterator[Wait]:
        pos = self.fw.position
        if code in (0, 1):
            yield from pos.move(p)
        elif code == 4:
            seconds = p.get("S", 0.0) + p.get("P", 0.0) / 1000.0
            yield from wait_for(self.fw.motion.idle, Wait(motion=True))
            end = self.fw.clock.now + max(0.0, seconds)
            yield from wait_for(lambda: self.fw.clock.now >= end, Wait(until=end))
        elif code == 28:
            axes = [a for a in "XYZB" if a in p] or ["X", "Y", "Z"]
            yield from pos.home(axes)
        elif code == 90:
            pos.relative = False
        elif code == 91:
            pos.relative = True
        elif code == 92:
            pos.set_position(p)

    def _m(self, code: int, p: dict) -> Iterator[Wait]:
        fw = self.fw
        heaters = fw.heaters
        if code == 1:
            self.pause(selfie="C" in p)
        elif code in (104, 109):
            yield from heaters.set_nozzle(p, wait=code == 109)
        elif code == 103:
            heaters.set_first_layer_nozzle(p)
        elif code in (140, 190):
            yield from heaters.set_bed(p, wait=code == 190)
        elif code == 139:
            heaters.set_first_layer_bed(p)
        elif code == 170:
            heaters.set_ambient(p)
        elif code == 105:
            self.last_response = heaters.m105_text()
        elif code == 106:
            fw.hw.machine.head_fan = min(255.0, max(0.0, p.get("S", 255.0))) / 255.0
        elif code == 107:
            fw.hw.machine.head_fan = 0.0
        elif code == 114:
            self.last_response = fw.position.m114_text()
        elif code == 115:
            self.last_response = f"FIRMWARE_NAME: robox {fw.revision}\r\n".encode()
        elif code == 119:
            self.last_response = fw.position.m119_text()
        elif code == 400:
            yield from wait_for(fw.motion.idle, Wait(motion=True))
        elif code == 503:
            self.last_response = fw.parameters.m503_text()
        elif code in (500, 501, 502):
            {500: fw.parameters.save, 501: fw.parameters.load,
             502: fw.parameters.defaults}[code]()
        elif code in fw.parameters.CODES:
            fw.parameters.set_from_gcode(code, p)
        elif code == 84:
            pass  # motors off: the model keeps positions
