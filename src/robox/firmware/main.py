"""The firmware's single foreground loop: objects in a registry, power-up, passes, reset.

One pass = `do_everything_else()` (motion, EEPROMs, file system, commands, user
interface, heaters, hours counter, in that order) then `maintain_job()`. Each
pass advances the simulated clock by PASS_S, one float addition at a time as the
printer's own tick count would, so it never leaves the millisecond grid the
recording rig kept. `plan()` decides how many passes to take at once: when nothing
can happen before a known event (a dwell's end, a heater sample, the bookkeeping
tick) the passes short of it are counted, not run; while a line only waits for the
motion queue, the step interrupts run ahead to the moment it would go on and the
passes in between are counted (docs/firmware-model.md, "The loop").
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, Final

from robox.firmware.carith import i64
from robox.firmware.command import Command
from robox.firmware.eeprom import Eeproms
from robox.firmware.error_flags import ErrorFlags
from robox.firmware.file_system import FileSystem
from robox.firmware.gcode import Job
from robox.firmware.heaters import Heaters
from robox.firmware.motion import Motion
from robox.firmware.parameters import HoursCounter, Parameters
from robox.firmware.position import Position
from robox.firmware.reprogram import Reprogram
from robox.firmware.user_interface import UserInterface
from robox.formats.firmware import IMAGE_PAGES, PAGE_SIZE, flashed_image_pages, image_revision
from robox.formats.firmware import word_sum as image_sum
from robox.formats.protocol import ErrorBit
from robox.hardware.clock import PassCondition, SimClock
from robox.hardware.eeprom_bus import EepromBus
from robox.hardware.flash import Flash
from robox.hardware.machine import Machine
from robox.hardware.sdcard import SdCard
from robox.hardware.usb import UsbLink

PASS_S: Final = 0.001  # simulated duration of one loop pass
HEATER_STEP_S: Final = 0.25  # longest clock jump while a heater is being waited for
IDLE_STEP_S: Final = 1.0  # longest clock jump when nothing at all is pending
DEFAULT_REVISION: Final = "unknown"

POWER_UP_ORDER: Final = ("parameters", "hours", "eeproms", "command", "job", "heaters",
                         "motion", "position", "file_system", "reprogram", "user_interface")


class Hardware:
    """Everything outside the microcontroller; it persists across resets."""

    def __init__(self, card: SdCard, eeprom_bus: EepromBus, flash: Flash | None = None,
                 usb: UsbLink | None = None, machine: Machine | None = None,
                 clock: SimClock | None = None) -> None:
        self.card = card
        self.eeprom_bus = eeprom_bus
        self.flash = Flash() if flash is None else flash
        self.usb = UsbLink() if usb is None else usb
        self.machine = Machine() if machine is None else machine
        self.clock = SimClock() if clock is None else clock


class Firmware:
    """The model of the printer's firmware, running on `Hardware`."""

    #: Run light passes together (see _run_light_passes); off, every such pass runs whole
    #: (the reference the tests compare with).
    light_passes = True

    def __init__(self, hw: Hardware):
        self.hw = hw
        self.clock = hw.clock
        self.resets = 0
        self.whole_passes = 0  # do_everything_else() run, all power-ups together
        self.step_passes = 0  # passes that took only the EEPROMs' steps (_step_pass)
        # plan() to run_pass(): the last pass planned may take only the EEPROMs' steps
        self._may_step = False
        self.power_up()

    # ------------------------------------------------------------ registry
    def lookup(self, name: str):
        return self.objects[name]

    # ------------------------------------------------------------ power up
    def power_up(self) -> None:
        """Everything in RAM starts afresh; card, chips and flash keep their content."""
        self.errors = ErrorFlags()
        self.events: list[tuple[str, object]] = []
        self.reset_requested = False
        hw = self.hw
        self.parameters = Parameters(self)
        self.hours = HoursCounter(self)
        self.eeproms = Eeproms(hw.eeprom_bus, hw.clock, self.errors)
        self.command = Command(self)
        self.job = Job(self)
        self.heaters = Heaters(self)
        self.motion = Motion(self)
        self.position = Position(self)
        self.file_system = FileSystem(hw.card, self.errors)
        self.reprogram = Reprogram(self)
        self.user_interface = UserInterface(self)
        self.objects: dict[str, Any] = {name: getattr(self, name) for name in POWER_UP_ORDER}
        self.eeproms.firmware = self
        for name in POWER_UP_ORDER:
            self.objects[name].initialise()
        image = hw.flash.read(0, len(IMAGE_PAGES) * PAGE_SIZE)
        pages = flashed_image_pages(image)
        self.revision = image_revision(image[: pages * PAGE_SIZE]) or DEFAULT_REVISION
        if pages == 0 or image_sum(image[: pages * PAGE_SIZE]) != 0:
            self.errors.set(ErrorBit.FLASH_CHECKSUM)
        if hw.card.present:
            self.heaters.check_for_poweroff_whilst_hot()

    def request_reset(self) -> None:
        self.reset_requested = True

    def _reset(self) -> None:
        self.resets += 1
        self.hw.flash.flush()
        self.power_up()

    # ---------------------------------------------------------------- loop
    def do_everything_else(self) -> None:
        """One pass of the loop's objects, in the firmware's order (direct calls: compiled,
        each is a native call)."""
        self.whole_passes += 1
        self.motion.maintain()
        self.eeproms.maintain()
        if not self.hw.card.present:  # all the file system's maintain() looks at
            self.file_system.maintain()
        self.command.maintain()
        self.user_interface.maintain()
        self.heaters.maintain()
        self.hours.maintain()

    def maintain_job(self) -> None:
        if not self.command.busy_line():  # the printer is still inside maintain_commands
            self.job.maintain_job()

    def busy(self) -> bool:
        """True when the next pass has work to do now (so the clock must not jump)."""
        return self._busy_apart_from_light() or self._light_work()

    def _light_work(self) -> bool:
        """Work a light pass does (see _run_light_passes): an EEPROM stepping, or a packet
        from the host crossing the bus while no job runs."""
        return self._light_usb() or not self.eeproms.all_quiet()

    def _light_usb(self) -> bool:
        # While a job runs, its line may start, end or look again at any pass: the
        # passes a transfer crosses in are light only while that line waits on motion
        # alone, or on a heater alone (they end with the frame that lands it, and the
        # pass that takes it, a pause say, is whole; the hours counter is brought up to
        # date before it).
        return self._usb_coming() and (not self.job.running or self._only_motion_awaited()
                                       or self._only_heater_awaited())

    def _usb_coming(self) -> bool:
        """Host bytes on their way: delivered and not taken, or queued for a read that
        can take them."""
        usb = self.hw.usb
        return usb.delivering or usb.received > 0

    def _frames_to_act(self) -> int:
        """How many frames until one delivers a packet the command object acts on (the
        ones before it bring bytes it only buffers: the rest of a Robox command)."""
        return self.hw.usb.frames_within(self.command.inert_bytes()) + 1

    def _busy_apart_from_light(self) -> bool:
        usb = self.hw.usb
        command = self.command
        wait = command.waiting
        # (a line's first look at a heater is at the next pass: see _only_heater_awaited)
        line_ready = command.line is not None and (
            wait is None or wait.next_pass()
            or (wait.heater is not None and not command.heater_looked))
        # (comparisons and bools throughout: compiled, nothing is boxed to be tested)
        received = usb.received
        return ((received > 0 and received > command.inert_bytes() and not command.deaf)
                or line_ready
                or (self._usb_coming() and self.job.running
                    and not self._only_motion_awaited() and not self._only_heater_awaited())
                or self.heaters.conversion_ready
                or command.pending_after_reply is not None or self.job.runnable()
                or self.reset_requested or self.hours.due())

    def _only_motion_awaited(self) -> bool:
        """Motion runs and all that waits is a job line waiting on it: room in the queue
        or the queue empty (no dwell, no heater)."""
        wait = self.job.waiting
        return (not self.motion.empty()
                and self.job.current is not None and wait is not None
                and wait.motion is not None and wait.until is None and wait.heater is None
                and self.command.waiting is None)

    def _only_heater_awaited(self) -> bool:
        """Motion has stopped and all that waits is a line waiting on a heater alone (an
        M109 or M190, say: no time, no motion) that has looked at it once and found it
        not there yet. Such a line looks again only at the passes plan() stops at (a
        heater's step, a conversion), as it does with no light work: what it looks at
        changes only at a heater's sample, at a host's command (the frame that brings it
        ends a light run) or at an EEPROM step that is not inert (which ends one too).
        Its first look is at the pass after it began to wait, as the firmware's."""
        job = self.job
        wait = job.waiting
        return (job.heater_looked and job.current is not None and wait is not None
                and wait.heater is not None and wait.motion is None and wait.until is None
                and self.command.waiting is None and self.motion.empty())

    def next_step(self, limit: float | None = None) -> float:
        """How far the clock may move before the next pass (see `plan`)."""
        step, passes = self.plan(limit, skip=False)
        if passes > 1:  # pragma: no cover - callers of next_step() get a single pass
            raise AssertionError("next_step() cannot skip passes")
        return step

    def plan(self, limit: float | None = None, skip: bool = True) -> tuple[float, int]:
        """The next pass: (step, n) moves the clock on n steps before it (n > 1 only with
        `skip`: passes in which nothing would happen are skipped); see `passes_planned`."""
        return PASS_S, self.passes_planned(math.inf if limit is None else limit, skip)

    def passes_planned(self, limit: float, skip: bool = True) -> i64:
        """`plan()`'s n, each step PASS_S, the clock moving no further than `limit`
        seconds (infinite: no limit). (Native arguments and answer: compiled, the loop's
        calls box nothing.)

        While motion runs the firmware spins pass by pass; when all that waits is a line
        waiting for room in the motion queue (or for motion to end), the step interrupts
        are run ahead to the moment that happens and the clock moves on to the first
        pass after it, as if every pass in between had looked and found nothing. When
        the only work is light (an EEPROM stepping, a command's packets crossing the bus: see
        _run_light_passes), the passes up to a pass short of the next moment any object
        waits for are light, and the last one is whole; while motion runs, that last one
        may take the EEPROMs' steps alone instead (run_pass() decides: _step_pass)."""
        light = stepping = False
        self._may_step = False
        if self._busy_apart_from_light():
            return 1
        if self._light_work():
            if not self.light_passes or not skip or self.hw.machine.hand_busy() \
                    or self.command.line is not None:
                return 1
            if self.motion.empty() and (self.job.current is None
                                        or self._only_heater_awaited()):
                light = True
            elif self._only_motion_awaited():
                stepping = True  # motion runs ahead while the EEPROMs' steps are inert
            else:
                # a line part-way (waiting on a time, say) looks again at every pass
                return 1
        now = self.clock.now
        # the nearest moment anything waits for (compared one by one: compiled, native
        # floats, where min() over a list would box each)
        horizon = now + IDLE_STEP_S
        soon = now + HEATER_STEP_S
        kind = None
        for which in range(2):  # the job's wait, then the command's (no list made each pass)
            wait = self.job.waiting if which == 0 else self.command.waiting
            if wait is None:
                continue
            until = wait.until
            if until is not None and until < horizon:
                horizon = until
            if wait.heater is not None and soon < horizon:
                horizon = soon
            if wait.motion == "ready" or (wait.motion == "empty" and kind is None):
                kind = wait.motion
        if soon < horizon and self.heaters.any_on():
            horizon = soon
        due = self.eeproms.update_due
        if due < horizon:
            horizon = due
        due = self.heaters.conversion_started + 1.0
        if due < horizon:
            horizon = due
        if now + limit < horizon:
            horizon = now + limit
        if light:  # light passes, then the pass that sees what they led to
            # ending a pass short of the horizon: the passes that reach it are whole, so
            # each object meets its moment at the pass it would one pass at a time
            n: i64 = max(1, int((horizon - now) / PASS_S + 1e-9) - 1)
            if self._usb_coming():
                n = min(n, self._frames_to_act() + 1)
            return n
        motion = self.motion
        if not motion.empty() or self.hw.machine.hand_busy():
            if not skip or horizon - now < 2 * PASS_S:
                return 1
            ahead: i64 = motion.passes_ahead(now, PASS_S)
            if ahead < 2:
                return 1
            most: i64 = int((horizon - now) / PASS_S + 1e-9)
            if ahead < most:
                most = ahead
            may_step = False
            if stepping:  # light passes up to the first EEPROM step that is not inert
                if self._usb_coming():  # and to the frame that brings what acts
                    most = min(most, self._frames_to_act() + 1)
                inert = self.eeproms.inert_passes(PASS_S, most - 1)
                # that step's pass short of every other moment (a horizon, the pass that
                # takes a packet that acts): it may be a step pass (see _step_pass)
                may_step = inert + 1 < most
                most = min(most, inert + 1)
                if most < 2 and not may_step:
                    return 1
            when = motion.run_ahead(now + float(most) * PASS_S, kind or "empty")
            if when is None:
                self._may_step = may_step
                return most
            tick = motion.tick_of(when)
            t = now
            k: i64 = 0  # (native integers: compiled, the count below is a plain add)
            # the first pass that sees it, the clock added up as it will be; the passes
            # well short of it are only added up (a pass is 3000 ticks: two short of
            # the quotient is short of it, whatever the sums' rounding)
            short: i64 = min(most, int((when - now) / PASS_S)) - 2
            while k < short:
                t += PASS_S
                k += 1
            while True:
                t += PASS_S
                k += 1
                if motion.tick_of(t) >= tick or k >= most:
                    return k
        if not skip:
            return 1
        # idle up to the horizon: the passes short of it are skipped, the clock added up
        # as the tick adds it, a millisecond at a time (it stays on the grid the
        # firmware's millisecond counter keeps); the pass that reaches it runs as it would
        # one pass at a time, whichever side of it the sums' rounding puts it
        t = now
        idle: i64 = 0
        stop = horizon - 0.5 * PASS_S
        while idle < 1 or t + PASS_S < stop:
            t += PASS_S
            idle += 1
        return idle

    def run_pass(self, step: float | None = None, passes: int = 1) -> None:
        """One pass of the loop after the clock moves on by `step` (default: as far as
        nothing is missed), `passes` times over (the passes between do nothing)."""
        if step is None:
            may_step = self._may_step  # (what the last plan() left, kept across this one)
            step = self.next_step()
            self._may_step = may_step
        self.run_passes(step, passes)

    def run_passes(self, dt: float, passes: i64) -> None:
        """`run_pass(dt, passes)`, its arguments native (compiled: nothing boxed)."""
        may_step, self._may_step = self._may_step, False
        # (whatever light work plan() saw: the interrupts it ran ahead may since have
        # emptied the queue, which ends the wait that let a transfer's frames be light)
        if passes > 1 and (self._usb_coming() or not self.eeproms.all_quiet()):
            self._run_light_passes(dt, passes - 1)
            passes = 1
        if may_step and passes == 1 and self.eeproms.light_steps(self.clock.now + dt):
            self._step_pass(dt)
            return
        self.clock.advance(dt, passes)
        self.hw.machine.advance(dt * float(passes))
        self.motion.catch_up()
        self.do_everything_else()
        self.maintain_job()
        self.hw.usb.frame()
        if self.reset_requested:
            self._reset()

    def _step_pass(self, dt: float) -> None:
        """A pass whose only work is the EEPROMs' steps, taken without the other objects:
        plan() found the job's line still waiting on motion at it and no other moment
        due, and Eeproms.light_steps() that none of the steps can change what another
        object looks at (a verifying EEPROM's read or write, a settled one's inert
        read). A write is made with the clock, the machine and the interrupts where
        they are in a whole pass, so a power cut at it finds them there too."""
        self.step_passes += 1
        self.clock.advance(dt, 1)
        self.hw.machine.advance(dt)
        self.motion.catch_up()
        self.eeproms.maintain()
        self.hours.maintain()
        self.hw.usb.frame()

    def _run_light_passes(self, dt: float, most: int) -> None:
        """Up to `most` light passes: passes in which the only work is an EEPROM's step
        (Eeproms.run_inert_passes) or a packet from the host crossing the bus that the
        command object only adds to its buffer (the rest of a Robox command: taken here,
        the read armed again, as its maintain() would). The other objects would idle
        through them, so they are skipped as in any other skipped pass; they end at the
        latest with the pass whose frame brings a packet that acts, and the caller runs
        the next pass whole."""
        usb, eeproms = self.hw.usb, self.eeproms
        coming = self._usb_coming()
        if coming:
            most = min(most, self._frames_to_act())
        if eeproms.all_quiet():
            self.clock.advance(dt, most)
            done = most
        else:
            done = eeproms.run_inert_passes(dt, most)
        if done:
            command = self.command
            for _ in range(done if coming else 0):
                if usb.received:  # the packet the pass before brought: only buffered
                    command.take_inert()
                usb.frame()
            self.hw.machine.advance(dt * done)
            self.motion.catch_up()
            eeproms.after_steps()
            # the hours counter adds up time from pass to pass: brought up to now, so the
            # next pass (which may start or pause a job before it) counts only its own
            self.hours.maintain()

    def run_until(self, condition: Callable[[], bool] | None, timeout: float = 3600.0,
                  max_passes: int = 50_000_000) -> bool:
        """Run passes until `condition()` holds or `timeout` simulated seconds pass (None:
        no condition, the whole timeout runs; it spares a call after every pass).

        The condition is looked at after every pass, as a USB host sees the printer: a
        reply sent while a line waits (a Pronterface line inside maintain_commands, say) is
        there to read at once, the lines before it answered."""
        end = self.clock.now + timeout
        # a compiled condition is asked natively (see PassCondition)
        native: PassCondition | None = None
        if isinstance(condition, PassCondition):
            native = condition
        _count: i64  # (a native count: compiled, `_` would be boxed at every pass)
        for _count in range(max_passes):
            if native is not None:
                if native.holds():
                    return True
            elif condition is not None and condition():
                return True
            if self.clock.now >= end:
                return False
            self.run_passes(PASS_S, self.passes_planned(max(PASS_S, end - self.clock.now)))
        return condition is not None and condition()

    def working(self) -> bool:
        """Whether anything would change on its own: a pass has work, a job is under
        way, motion is queued or a heater is on (else the printer waits for a host)."""
        job = self.job
        return self.busy() or job.running or job.current is not None or \
            not self.motion.idle() or self.heaters.any_on()

    def run_for_host(self, timeout: float, max_passes: int = 2000,
                     reader_margin: int = 0) -> int:
        """Passes for a host at the end of a live link: at least one, then on while the
        printer is working, until `timeout` simulated seconds pass, a reply waits for the
        host, or `max_passes` have run (so the link is looked at often enough); none when
        `timeout` is not positive. With `reader_margin`, the run also ends once a job
        reading its own upload has fewer than that many stored bytes left to read, while
        nothing of the host's is on its way in. The number of passes run."""
        end = self.clock.now + timeout
        usb = self.hw.usb
        passes = 0
        while passes < max_passes and timeout > 0.0:
            self.run_passes(PASS_S, self.passes_planned(max(PASS_S, end - self.clock.now)))
            passes += 1
            if usb.in_flight or self.clock.now >= end or not self.working():
                break
            if reader_margin > 0 and self.reader_near_upload_end(reader_margin):
                break
        return passes

    def reader_near_upload_end(self, margin: int) -> bool:
        """A job reading its own upload has fewer than `margin` stored bytes of it left
        to read, and nothing of the host's is on its way in (the next chunk, say)."""
        usb = self.hw.usb
        return not usb.arriving and not usb.received and \
            0 <= self.file_system.upload_unread() < margin

    # ------------------------------------------------------------- debug
    def debug_text(self) -> str:
        job = self.job
        return (f"robox model {self.revision}; t={self.clock.now:.3f}s; lines "
                f"{job.lines_executed}; jobs {job.jobs_completed}; resets {self.resets}")

    def board_test_text(self) -> str:
        m = self.hw.machine
        return (f"24V {'ok' if m.supply_24v else 'off'}; "
                f"lid {'closed' if m.lid_closed else 'open'}; "
                f"head power {'on' if m.head_power else 'off'}")
