"""The job engine: execute and job buffers, G-code lines, run / pause / resume / abort.

It follows the firmware's `maintain_job()`: each pass first lets "the boss"
decide on automatic pauses and aborts, then does exactly one thing, in this
order of priority: finish an abort once motion has stopped; run the next line
of the execute buffer (the host's lines); park for a pause or unpark after
one; run the next job line; give up on a line that fills half the job buffer;
end the job at end of file once motion has stopped; read the next block of
the file, or pause when the reader has caught up with an upload still under
way (the job then stays paused until a host resumes it).

On the printer a line that waits (G4, M400, M109, a full motion queue,
parking) spins `do_everything_else()` inside the call. Here such a line is a
generator: `maintain_job()` resumes it once per pass, and no other job line
starts meanwhile, so a host sees the same order. Each yield says what the
line waits for, so the loop can jump the clock to it. A line a host sends in
Pronterface mode, or a reporting line in Robox mode, runs the same way but is
owned by the command object, which reads no more input until it is done
(docs/firmware-model.md).
"""

from __future__ import annotations

from collections.abc import Generator
from typing import TYPE_CHECKING, Any, Final

from robox.firmware.carith import f32, to_ulong
from robox.firmware.cline import Line, strtol
from robox.formats.protocol import JOB_LINE_LIMIT, ErrorBit
from robox.packed import i64

if TYPE_CHECKING:
    from robox.firmware.main import Firmware

BUFFER_SIZE: Final = 1024
LINE_LIMIT: Final = JOB_LINE_LIMIT  # BUFFER_SIZE // 2
IDLE_PAUSE_S: Final = 600.0
IDLE_ABORT_S: Final = 3600.0
SLIP_COUNT_DECAY_S: Final = 300.0
REPORTING: Final = {105, 111, 112, 113, 114, 115, 119, 503, 997, 999}
#: builtins.next, held here: compiled, next() with a default is looked up in the
#: builtins module at every call, a Final is a static
_NEXT: Final = next


class Wait:
    """What a suspended line waits for: motion, a time, a heater, or just the next pass.
    (A plain class, not a dataclass: compiled, making one and reading it are native.)"""

    __slots__ = ("heater", "motion", "until")

    def __init__(self, motion: str | None = None, until: float | None = None,
                 heater: str | None = None) -> None:
        self.motion = motion  # "ready": room in the motion queue; "empty": motion done
        self.until = until
        self.heater = heater

    def next_pass(self) -> bool:
        """Whether it waits for nothing but the next pass."""
        return self.motion is None and self.until is None and self.heater is None

    def __repr__(self) -> str:
        return f"Wait(motion={self.motion!r}, until={self.until!r}, heater={self.heater!r})"


def heater_looked(before: Wait | None, after: Wait | None) -> bool:
    """Whether a line that was resumed from a wait on a heater (`before`) and waits on one
    again (`after`) has looked at its heater since it began to wait: it found it short.
    (A line's first wait on a heater comes before any look: heaters.c's waits are
    `do { do_everything_else(); look } while (...)`.)"""
    return after is not None and after.heater is not None \
        and before is not None and before.heater is not None


# A routine that may wait, as a generator: it yields what it waits for while the firmware
# would spin do_everything_else(), and may return a value when done.
Waits = Generator[Wait, None, Any]

NEXT_PASS: Final = Wait()
#: What a line yields, and yields again, while it waits for room in the motion queue
#: (`while not motion.ready_for_more(): yield READY_WAIT`) or for motion to end
#: (`wait_for(motion.empty, EMPTY_WAIT)`); nothing else yields them.
READY_WAIT: Final = Wait(motion="ready")
EMPTY_WAIT: Final = Wait(motion="empty")


class Resumable:
    """A buffered line's routine that only ever waits for room in the motion queue, kept
    as an object instead of a generator (a G0/G1: position.MoveRun). The job runs it as
    `current` (see _line_step), resuming it with resume() once there is room; `waits()`
    is the same routine as a generator, for a line run anywhere else. (Compiled, a
    generator's frame is made, resumed through next() and cleared for every line, a
    native object's method is called directly.)"""

    def resume(self) -> bool:
        """Run on until the routine must wait for room (False) or has ended (True)."""
        raise NotImplementedError

    def waits(self) -> Waits:
        while not self.resume():
            yield READY_WAIT


def _as_waits(step: Waits | Resumable | None) -> Waits | None:
    """A routine as a generator, to run inside another."""
    return step.waits() if isinstance(step, Resumable) else step


def wait_for(condition, wait: Wait = NEXT_PASS) -> Waits:
    while not condition():
        yield wait


def line_length(buffer: bytes) -> int:
    """The firmware's get_gcode_line_length: 0 while the first line has no CR or LF
    (a NUL ends the string); otherwise its length with its terminator (CR LF or LF CR
    count once) and any blanks after it."""
    # byte by byte (compiled, a native loop over the line's few dozen bytes, native
    # integers indexing it, where a method call or a search of the whole buffer costs
    # several times as much)
    n: i64 = len(buffer)
    i: i64 = 0
    while i < n:
        c = buffer[i]
        if c == 13 or c == 10 or c == 0:  # the first CR, LF or NUL
            break
        i += 1
    if i >= n or buffer[i] == 0:
        return 0
    nxt = buffer[i + 1] if i + 1 < n else 0
    if (buffer[i] == 0x0A and nxt == 0x0D) or (buffer[i] == 0x0D and nxt == 0x0A):
        i += 1
    i += 1
    while i < n and (buffer[i] == 0x20 or buffer[i] == 0x09):
        i += 1
    return i


def is_reporting(text: bytes) -> bool:
    """The firmware's is_gcode_reporting: the number after the first 'M' anywhere in
    the text (up to a NUL), whatever line it is on."""
    text = bytes(text).split(b"\0", 1)[0]
    at = text.find(b"M")
    return at >= 0 and strtol(text[at + 1 :]) in REPORTING


class Job:
    # (scalars set at power-up, in initialise; the defaults only spare the compiled
    # code a test at every read of whether the attribute was ever set)
    execute_buffer: bytes = b""
    job_buffer: bytes = b""
    line_number: int = 0
    abort_flag: bool = False
    pause: int = 0
    parked: bool = False
    running: bool = False
    idle_since: float = 0.0
    current: Waits | Resumable | None = None
    waiting: Wait | None = None
    heater_looked: bool = False
    _taking: i64 = 0
    _taking_job: bool = False
    lines_executed: int = 0
    jobs_completed: int = 0
    slip_count_since: float = 0.0

    def __init__(self, firmware: Firmware):
        self.fw = firmware

    def initialise(self) -> None:
        now = self.fw.clock.now
        # the firmware's two line buffers (bytes, made anew as they change: compiled,
        # read byte by byte natively, where a bytearray's items are generic lookups)
        self.execute_buffer = b""
        self.job_buffer = b""
        self.line_number = 0
        self.abort_flag = False
        self.pause = 0  # 0 running, 1 paused, 2 "selfie" pause
        self.parked = False
        self.running = False
        self.idle_since = now
        self.current = None  # the job-level step under way
        self.waiting = None
        # whether the heater the line waits on has been looked at since it began to
        # wait: it yielded a wait on it again (see Firmware._only_heater_awaited)
        self.heater_looked = False
        # a buffered line's own routine run as `current` (see _line_step): the bytes its
        # end takes off a buffer (0: none), and which (True: the job's)
        self._taking = 0
        self._taking_job = False
        self.lines_executed = 0
        self.jobs_completed = 0
        self.slip_count = [0, 0]
        self.slip_count_since = now

    # ------------------------------------------------------------ queries
    def aborting(self) -> bool:
        return self.abort_flag

    def paused(self) -> bool:
        return self.pause > 0

    def non_selfie_paused(self) -> bool:
        return self.pause == 1

    @property
    def job_id(self) -> bytes | None:
        return self.fw.file_system.reading

    # ------------------------------------------------------- host side
    def execute_gcode(self, data: bytes) -> None:
        """Queue G-code text; dropped whole (GCODE_BUFFER_OVERRUN) if it would not fit."""
        if len(self.execute_buffer) + len(data) >= BUFFER_SIZE:
            self.fw.errors.set(ErrorBit.GCODE_BUFFER_OVERRUN)
            return
        self.execute_buffer += data

    def run_now(self, text: bytes) -> Waits:
        """The firmware's gcode_handler on `text`: the first complete line runs at once and
        its response (ending in ok) is the generator's return value; b"" if `text` holds
        no complete line."""
        if line_length(text) == 0:
            return b""
        return (yield from self.process_line(text))

    # ------------------------------------------------------ job control
    def run_job(self, file_id: bytes) -> None:
        """0x94: restart, whatever is running; the file is looked up afresh."""
        self.line_number = 0
        self.pause = 0
        self.parked = False
        self.running = True
        self.job_buffer = b""
        self.idle_since = self.fw.clock.now
        self.fw.file_system.start_read_file(file_id)
        self.fw.events.append(("job started", self.job_id))

    def pause_resume(self, flag: bytes) -> None:
        """0x98: '1' pauses a running job; anything else resumes."""
        self.pause = 1 if flag[:1] == b"1" and self.running else 0
        self.idle_since = self.fw.clock.now

    def invert_pause(self) -> None:
        self.pause = 0 if self.pause else (1 if self.running else 0)
        self.idle_since = self.fw.clock.now

    def abort(self) -> None:
        """Stop reading and empty both buffers; the rest happens once motion has stopped."""
        self.abort_flag = True
        self.job_buffer = b""
        self.execute_buffer = b""
        self.fw.file_system.close()

    # ------------------------------------------------------------ status
    def state_text(self) -> bytes:
        """Status bytes 17..26: line number, pause state, busy."""
        if self.pause == 0:
            state = b"3" if self.parked else b"0"
        elif self.pause == 1:
            state = b"2" if self.parked else b"1"
        else:
            state = b"4" if self.parked else b"1"
        busy = self.fw.position.busy_state()
        if busy is None:
            idle = not self.execute_buffer and self.fw.motion.empty() and \
                (self.pause or not self.running)
            busy = b"0" if idle else b"1"
        return b"%08x" % (self.line_number & 0xFFFFFFFF) + state + busy

    def runnable(self) -> bool:
        """True when the next pass has something to do at once (the clock must not jump)."""
        if self.current is not None:
            wait = self.waiting
            # (a heater's first look is at the next pass: see Firmware._only_heater_awaited)
            return wait is None or wait.next_pass() or \
                (wait.heater is not None and not self.heater_looked)
        if self.abort_flag:
            return self.fw.motion.idle()  # the abort ends once motion has stopped
        if line_length(self.execute_buffer):
            return True
        if not self.running:
            return False
        if self.pause:
            return not self.parked
        return True  # a line to run, a block to read, or unparking to do

    # ------------------------------------------------------------- loop
    def maintain_job(self) -> None:
        if self.current is not None:
            # A line waiting for room in the motion queue, or for motion to end, would
            # look, find it still not so and yield the same wait: left suspended instead
            # (compiled, resuming it goes through a generator for every routine it is in).
            wait = self.waiting
            if wait is READY_WAIT:
                if not self.fw.motion.ready_for_more():
                    return
            elif wait is EMPTY_WAIT and not self.fw.motion.empty():
                return
            self._drive()
            return
        slipped = self._the_boss()
        step = self._slip_handling(slipped) if slipped is not None else self._action(True)
        if step is not None:
            self._start(step)

    def _action(self, direct: bool = False) -> Waits | Resumable | None:
        """The one thing maintain_job does this pass; a generator when it may wait.
        `direct`: a buffered line's own routine, to be run as `current` (_line_step; a
        move's is a Resumable)."""
        fw = self.fw
        if self.abort_flag:
            if fw.motion.empty():
                fw.heaters.turn_off()
                was = self.running
                self.abort_flag = False
                self.pause = 0
                self.parked = False
                self.running = False
                self.line_number = 0
                fw.heaters.targets_from_reel()
                fw.position.filament_info_from_reel()
                if was:
                    fw.events.append(("job aborted", None))
            return None
        n = line_length(self.execute_buffer)
        if n:
            return self._line_step(False, n) if direct else self._buffer_line(False, n)
        if not self.running:
            return None
        if self.pause:
            return None if self.parked else self._park()
        if self.parked:
            return self._unpark()
        if (n := line_length(self.job_buffer)) > 0:
            self.line_number += 1
            return self._line_step(True, n) if direct else self._buffer_line(True, n)
        if len(self.job_buffer) >= LINE_LIMIT:
            fw.errors.set(ErrorBit.GCODE_LINE_TOO_LONG)
            self.abort()
        elif fw.file_system.eof():
            if fw.motion.empty():
                self._finish()
        else:
            data = fw.file_system.read()
            if not data:
                self.pause = 1  # caught up with the upload: stays paused until resumed
            else:
                self.job_buffer += data
        return None

    def _the_boss(self) -> int | None:
        """Automatic pauses and aborts; returns the extruder whose filament slipped (while
        printing, not paused) when that needs the slip handling, which waits."""
        fw = self.fw
        now = fw.clock.now
        motion = fw.motion
        slipped = None
        if not self.running:
            self.slip_count = [0, 0]
            self.slip_count_since = now
        else:
            if now - self.slip_count_since >= SLIP_COUNT_DECAY_S:
                self.slip_count = [max(0, c - 1) for c in self.slip_count]
                self.slip_count_since = now
            for i in range(2):  # (a range: compiled, a tuple's iterator is generic)
                if slipped is None and motion.is_filament_slip_error(i) and not self.pause:
                    slipped = i
                    break
        if slipped is None:
            self._auto_pause(now)
        return slipped

    def _auto_pause(self, now: float) -> None:
        if self.running and self.fw.command.is_error():
            self.pause = 1
        if self.running and now - self.idle_since >= IDLE_PAUSE_S:
            self.pause = 1
        elif now - self.idle_since >= IDLE_ABORT_S:
            self.abort()  # even with no job: it turns the heaters off
            self.idle_since = now

    def _slip_handling(self, i: int) -> Waits:
        """A filament slip while printing: the fourth within the decay time is an error;
        before that, park and try backing the filament off and pushing it back; if the
        wheel does not turn, the filament has run out: pause, and unload it."""
        fw = self.fw
        self.slip_count[i] += 1
        if self.slip_count[i] >= 4:
            fw.errors.set(ErrorBit.D_FILAMENT_SLIP if i else ErrorBit.E_FILAMENT_SLIP)
        else:
            yield from fw.position.park()
            retried = yield from fw.position.filament_slip_retry(i)
            if retried:
                yield from fw.position.unpark(reselect_tool=True)
            else:
                self.slip_count[i] = 0
                self.pause = 1
                self.parked = True
                fw.errors.set(ErrorBit.D_NO_FILAMENT if i else ErrorBit.E_NO_FILAMENT)
                self.execute_gcode(b"M121 D\n" if i else b"M121 E\n")
        fw.motion.is_filament_slip_error(i)
        for j in (0, 1):  # the rest of the boss's round, then this pass's action
            if j > i and fw.motion.is_filament_slip_error(j) and not self.pause:
                yield from self._slip_handling(j)
                return
        self._auto_pause(fw.clock.now)
        step = _as_waits(self._action())
        if step is not None:
            yield from step

    def pause_and_park(self) -> Waits:
        """Before an unload: a running job is paused and parked."""
        if self.running:
            self.pause = 1
            if not self.parked:
                yield from self.fw.position.park()
                self.parked = True

    def delay_aborting(self, seconds: float) -> Waits:
        """delay_aborting(seconds): (unsigned long)(seconds * 1000) ticks."""
        yield from self.delay_ticks(to_ulong(seconds * 1000))

    def delay_ticks(self, ticks: int) -> Waits:
        """delay_aborting_i(): wait `ticks` of the 1 ms counter, ending early on abort.
        (A negative or NaN time converts to no tick, a huge one to 2**32 - 1.)"""
        if ticks == 0:
            return
        end = self.fw.clock.now + ticks / 1000.0
        while not self.abort_flag and self.fw.clock.now < end:
            yield Wait(until=end)

    def _finish(self) -> None:
        fw = self.fw
        job_id = self.job_id
        fw.file_system.close()
        fw.heaters.turn_off()
        self.pause = 0
        self.running = False
        self.job_buffer = b""
        self.line_number = 0
        fw.heaters.targets_from_reel()
        fw.position.filament_info_from_reel()
        self.jobs_completed += 1
        fw.events.append(("job finished", job_id))

    def _start(self, step: Waits | Resumable) -> None:
        self.current = step
        self.waiting = None  # (what the last line waited for, if it left it: not this one's)
        if isinstance(step, Resumable):
            self.waiting = READY_WAIT  # (it has run up to its wait: see _line_step)
            return
        self._drive()

    def _drive(self) -> None:
        step = self.current
        assert step is not None
        before = self.waiting
        waiting: Wait | None
        if isinstance(step, Resumable):
            waiting = None if step.resume() else READY_WAIT
        else:
            # (a default, not StopIteration caught: a line's routine yields only Waits,
            # and compiled, an exception caught costs a traceback entry at every line's
            # end)
            waiting = _NEXT(step, None)
        if waiting is None:
            self.current = None
            taking = self._taking
            if taking:  # a buffered line's routine has ended (_line_step)
                self._taking = 0
                self._line_done(self._taking_job, taking)
        self.waiting = waiting
        self.heater_looked = heater_looked(before, waiting)

    def _buffer_line(self, job: bool, n: int) -> Waits:
        """The first line (`n` bytes) of the job buffer or of the execute buffer, run and
        then taken off the buffer as it is by then."""
        # (a buffered line's response goes nowhere: its routine runs one generator down
        # from here, not inside process_line's, where most passes resume it)
        step = _as_waits(self._code_step((self.job_buffer if job else self.execute_buffer)[:n]))
        if step is not None:
            yield from step
        self._line_done(job, n)

    def _line_step(self, job: bool, n: i64) -> Waits | Resumable | None:
        """What _buffer_line does, without a generator around the line's own: the line
        run at once, its routine (if it has one) returned to run as `current`, and the
        line taken off its buffer when that ends (_drive), in the same pass, as the
        generator's end would. (Compiled, every pass a line waits resumes it through
        one generator fewer.) A move is begun here, up to its first wait for room (a
        generator would run that far when _start first drives it, in this same pass),
        and comes back as a Resumable, or as None if it needed no wait."""
        step = self._code_step((self.job_buffer if job else self.execute_buffer)[:n], True)
        if step is None:
            self._line_done(job, n)
            return None
        self._taking = n
        self._taking_job = job
        return step

    def _line_done(self, job: bool, n: i64) -> None:
        """A buffered line of `n` bytes has run: taken off its buffer."""
        # an abort may have emptied the buffer meanwhile, and a host's lines may have
        # joined the execute buffer
        if job:
            if len(self.job_buffer) >= n:
                self.job_buffer = self.job_buffer[n:]
        elif len(self.execute_buffer) >= n:
            self.execute_buffer = self.execute_buffer[n:]
        self.idle_since = self.fw.clock.now

    def _park(self) -> Waits:
        yield from self.fw.position.park()
        self.parked = True

    def _unpark(self) -> Waits:
        yield from self.fw.position.unpark()
        self.parked = False

    # -------------------------------------------------------- execution
    def process_line(self, raw: bytes) -> Waits:
        """Run one line (a generator: it yields while it waits); returns its response
        text, which always ends in ok."""
        step = _as_waits(self._code_step(raw))
        response = (yield from step) if step is not None else None
        return (response or b"") + b"ok\r\n"

    def _code_step(self, raw: bytes, begun: bool = False) -> Waits | Resumable | None:
        """The line, counted as executed, and the routine that runs its code (G before M
        before T, each found anywhere in the line), returning an M-code's response
        text; None for none. `begun`: a move is begun now (see _line_step); otherwise
        it is a generator, as every other routine is."""
        line = Line(raw)
        self.lines_executed += 1
        if line.has("G"):
            code = line.int("G")
            if code == 0 or code == 1:  # nearly every line: the move itself, directly
                if begun:
                    return self.fw.position.begin_move(line, code == 0)
                return self.fw.position.move(line, rapid=code == 0)
            return self._g(code, line)
        if line.has("M"):
            return self._m(line.int("M"), line)
        if line.has("T"):
            return self.fw.position.select_tool(line.int("T"), line)
        return None

    def _g(self, code: int, line: Line) -> Waits:
        pos = self.fw.position
        motion = self.fw.motion
        # (G0 and G1 never come here: _code_step runs the move itself)
        if code == 4:
            yield from motion.wait_until_empty()
            if line.has("S"):
                # the float S times the int 1000 is a float product
                yield from self.delay_ticks(to_ulong(f32(line.float("S") * 1000)))
            elif line.has("P"):
                yield from self.delay_aborting(line.float("P") / 1000.0)
        elif code == 28:
            yield from pos.home(line)
        elif code == 36:
            yield from pos.move_filament_until_slip(line)
        elif code == 37:
            yield from pos.unlock_cover(line)
        elif code == 38:
            yield from pos.level_gantry()
        elif code == 39:
            pos.level_bed(line)
        elif code == 90:
            pos.relative = False
        elif code == 91:
            pos.relative = True
        elif code == 92:
            yield from pos.set_position(line)

    def _m(self, code: int, line: Line) -> Waits:
        fw = self.fw
        heaters = fw.heaters
        pos = fw.position
        if code == 1:
            if self.running:
                self.pause = 2 if line.has("C") else 1
        elif code == 84:
            yield from fw.motion.wait_until_empty()
            fw.motion.motors_off()
        elif code == 103:
            heaters.set_nozzle_temperature(line, 1)
        elif code == 104:
            heaters.set_nozzle_temperature(line, 0)
        elif code == 105:
            return heaters.m105_text()
        elif code == 106:
            heaters.set_head_fan(min(255, line.uint("S")) if line.has("S") else 255)
        elif code == 107:
            heaters.set_head_fan(0)
        elif code == 109:
            yield from heaters.wait_for_nozzle()
        elif code in (111, 112, 113, 999):
            return pos.delta_text({111: "X", 112: "Y", 113: "Z", 999: "B"}[code])
        elif code == 114:
            return pos.m114_text()
        elif code == 115:
            return f"FIRMWARE_NAME: robox {fw.revision}\r\n".encode()
        elif code == 119:
            return fw.motion.m119_text()
        elif code == 120:
            yield from pos.load_filament(line)
        elif code in (121, 122):
            yield from pos.unload_filament(line, pause=code == 121)
        elif code in (126, 127):
            heaters.set_head_power(code == 127)
        elif code == 128:
            fw.hw.machine.head_lights = False
        elif code == 129:
            heaters.set_head_power(True)
            fw.hw.machine.head_lights = True
        elif code == 139:
            heaters.set_bed_temperature(line, 1)
        elif code == 140:
            heaters.set_bed_temperature(line, 0)
        elif code == 150:
            heaters.nozzle_targets_from_reel(line)
        elif code == 154:
            heaters.bed_targets_from_reel()
        elif code == 157:
            heaters.ambient_target_from_reel()
        elif code == 170:
            heaters.set_ambient_temperature(line)
        elif code == 190:
            yield from heaters.wait_for_bed(line)
        elif code == 201:
            fw.motion.set_acceleration(line)
        elif code == 400:
            yield from fw.motion.wait_until_empty()
        elif code == 503:
            return fw.parameters.m503_text()
        elif code in (500, 501, 502):
            {500: fw.parameters.save, 501: fw.parameters.load,
             502: fw.parameters.defaults}[code]()
        elif code == 997:
            return b""
        elif code == 998:
            if line.has("S"):
                bit = line.int("S")
                if 0 <= bit < 64:
                    fw.errors.bits |= 1 << bit
        else:
            fw.parameters.set_from_line(code, line)
        return b""
