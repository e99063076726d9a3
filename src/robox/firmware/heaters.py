"""Heaters: nozzle 0, nozzle 1, bed and ambient, as the firmware's temperature controllers.

Each controller has a mode (0 off, 1 normal target, 2 first-layer target, 3 the
unload temperature), two targets and a PID controller sampled once a second.
What a host can see follows the firmware: targets only change through the
G-codes, 0xc3 and the reels, M104 S0 turns a nozzle off but keeps its target,
bed targets clamp to 160 and the ambient target to 60, nozzle targets clamp to
the head type's maximum at the next sample, and with a single-material head
nozzle 1 reads 0 degrees. The measured temperatures come from the simulated
thermal plants (a deliberate difference: the physics is the model's own).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Final

from robox.firmware.cline import Line, report_float, strtof
from robox.firmware.gcode import Wait, Waits
from robox.formats.eeprom import EepromIndex
from robox.formats.protocol import ErrorBit

if TYPE_CHECKING:
    from robox.firmware.eeprom import Eeproms
    from robox.firmware.main import Firmware

HEAD, REEL0, REEL1 = EepromIndex.HEAD, EepromIndex.REEL0, EepromIndex.REEL1
SAMPLE_S: Final = 1.0
# The 1 s sampling starts one loop pass after power-up: the phase at which the recordings
# of the real firmware see targets clamp and the over-temperature cut-off act (fitted:
# 0 or 2 ms match fewer recorded sessions than 1 ms).
SAMPLE_PHASE_S: Final = 0.001
NOZZLE_TEMP_MARGIN: Final = 0.017
BED_TEMP_MARGIN: Final = 0.03
NOZZLE_FLUSH_MARGIN_C: Final = 15.0
UNLOAD_NOZZLE_TEMPERATURE: Final = 140.0
UNLOAD_NOZZLE_DWELL_S: Final = 5.0
NOZZLE_PAUSE_AUTO_OFF_S: Final = 300.0
HEAD_FAN_OVERRIDE_TEMPERATURE: Final = 60.0
HEAD_FAN_OVERRIDE_DUTY: Final = int(255 * 0.6)
HEAD_HOT_TEMPERATURE: Final = 60.0
HEAD_DEFAULT_LIMIT: Final = 300.0
HEAD_SHUTDOWN_THRESHOLD: Final = 5.0
BED_HOT_TEMPERATURE: Final = 60.0
BED_DROOP_THRESHOLD: Final = 5.0
MAX_BED_TARGET: Final = 160.0
MAX_AMBIENT_TARGET: Final = 60.0
# time-to-target estimates (final delta above ambient, time constant)
# (tuples of floats are not Final: mypyc leaves those unset)
BED_APPROACH = (150.0, 280.0)
SINGLE_NOZZLE_APPROACH = (253.0, 71.0)
DUAL_NOZZLE_APPROACH = (276.0, 55.0)
HIGH_TEMP_NOZZLE_APPROACH = (434.0, 84.0)
# the firmware's default controller gains (kp, ki, kd)
NOZZLE_GAINS: Final = (0.08, 0.012, 0.55)
BED_GAINS: Final = (0.05, 0.006, 1.4)
AMBIENT_GAINS: Final = (0.1, 0.0, 0.0)
# the errors of a lost thermistor: the bed's, nozzle 0's, nozzle 1's
_THERMISTOR_ERRORS: Final = [ErrorBit.BED_THERMISTOR, ErrorBit.NOZZLE0_THERMISTOR,
                             ErrorBit.NOZZLE1_THERMISTOR]
NOT_WAITING: Final = 0
BED_COOLING: Final = 1
BED_AT_TEMPERATURE: Final = 2
NOZZLE_AT_TEMPERATURE: Final = 3
FLT_MAX: Final = 3.4028234663852886e38
OPEN_THERMISTOR: Final = -40.0
HOT_FLAG_BYTE: Final = 0  # nonvolatile byte of the card directory: "head was hot"


class Controller:
    """One temperature controller's state."""

    def __init__(self, plant: str, target: list[float] | None = None) -> None:
        self.plant = plant
        self.on_head = plant.startswith("nozzle")  # (not the bed's, nor the ambient's)
        self.mode = 0
        self.target = [0.0, 0.0] if target is None else target
        self.measured = 0.0
        self.last_measured = 0.0
        self.integrator = 0.0
        self.pwm_duty = 0
        self.fault_since = 0.0
        self.unload_since = 0.0

    def setpoint(self) -> float:
        if self.mode == 1:
            return self.target[0]
        if self.mode == 2:
            return self.target[1]
        return UNLOAD_NOZZLE_TEMPERATURE


def time_to_target(target: float, now: float, ambient: float,
                   approach: tuple[float, float]) -> float:
    """Seconds to heat from `now` to `target`, on an exponential approach."""
    final_delta, tconst = approach  # (typed: compiled, unpacked natively)
    v = final_delta + ambient - now
    if v <= 0.0:
        return FLT_MAX
    v = (target - now) / v
    if v <= 0.0:
        return 0.0
    v = 1.0 - v
    if v <= 0.0:
        return FLT_MAX
    return tconst * -math.log(v)


class Heaters:
    # (scalars set at power-up, in initialise; the defaults only spare the compiled
    # code a test at every read of whether the attribute was ever set)
    conversion_started: float = 0.0
    conversion_ready: bool = False
    force_ambient_fan: bool = False
    why_are_we_waiting: int = NOT_WAITING
    timing_pause: bool = False
    pause_since: float = 0.0
    head_fan_requested: int = 0
    head_fan_duty: int = 0
    bed_got_to: float = 0.0
    nozzle_forcing: bool = False
    nozzles_forced_off: bool = False

    def __init__(self, firmware: Firmware):
        self.fw = firmware

    def initialise(self) -> None:
        now = self.fw.clock.now
        self.nozzle = [Controller("nozzle0", target=[180.0, 180.0]),
                       Controller("nozzle1", target=[180.0, 180.0])]
        self.bed = Controller("bed")
        self.ambient = Controller("ambient")
        for c in self.controllers():
            c.fault_since = c.unload_since = now
        self.conversion_started = now + SAMPLE_PHASE_S
        self.conversion_ready = True  # power-up converts every channel once
        self.nozzle_mode_at_pause = [0, 0]
        self.force_ambient_fan = False
        self.why_are_we_waiting = NOT_WAITING
        self.timing_pause = False
        self.pause_since = now
        self.head_fan_requested = 0
        self.head_fan_duty = 0
        self.bed_got_to = -FLT_MAX
        self.nozzle_forcing = False  # the B-axis work-around, enabled once B misbehaves
        self.nozzles_forced_off = False
        self.set_head_power(True)

    def controllers(self) -> tuple[Controller, ...]:
        return (self.nozzle[0], self.nozzle[1], self.bed, self.ambient)

    # ---------------------------------------------------------- helpers
    @property
    def _eeproms(self) -> Eeproms:
        return self.fw.eeproms

    def _reel_float(self, index: EepromIndex, address: int, default: float) -> float:
        return self._eeproms.float_at(index, address, default)

    def head_max_temperature(self) -> float:
        return self._eeproms.head_max_temperature()

    # ------------------------------------------------------------ control
    def maintain(self) -> None:
        """As the firmware: the controllers run when a conversion is ready (the pass after
        one is started, and at the first pass after power-up), and a conversion starts
        once a second has passed since the last one started."""
        now = self.fw.clock.now
        if self.conversion_ready:
            self.conversion_ready = False
            self._sample(now)
        if now - self.conversion_started >= SAMPLE_S:
            self.conversion_ready = True
            self.conversion_started = now

    def _sample(self, now: float) -> None:
        eeproms = self._eeproms
        plants = self.fw.hw.machine.heaters
        limit = self.head_max_temperature()
        for nozzle in self.nozzle:
            target = nozzle.target  # (clamped in place: no list made at every sample)
            for i in range(len(target)):
                if target[i] > limit:
                    target[i] = limit
        self.ambient.measured = _read(plants["ambient"])
        self._control(self.ambient, AMBIENT_GAINS, invert=True)
        self.nozzle[0].measured = _read(plants["nozzle0"])
        self.nozzle[1].measured = _read(plants["nozzle1"]) \
            if eeproms.head_dual_material() else 0.0
        self._control(self.nozzle[0], NOZZLE_GAINS)
        if eeproms.head_has_two_fans():
            self.nozzle[1].pwm_duty = self.head_fan_requested
        else:
            self._control(self.nozzle[1], NOZZLE_GAINS)
        self.bed.measured = _read(plants["bed"])
        self._control(self.bed, BED_GAINS)
        if max(self.nozzle[0].measured, self.nozzle[1].measured) >= \
                HEAD_FAN_OVERRIDE_TEMPERATURE:
            self.head_fan_duty = max(self.head_fan_requested, HEAD_FAN_OVERRIDE_DUTY)
        else:
            self.head_fan_duty = self.head_fan_requested
        limit = eeproms.float_at(HEAD, 0x28, HEAD_DEFAULT_LIMIT)
        if self.nozzle[0].measured - limit >= HEAD_SHUTDOWN_THRESHOLD or \
                self.nozzle[1].measured - limit >= HEAD_SHUTDOWN_THRESHOLD:
            if self.head_power_on():
                self.fw.errors.set(ErrorBit.HEAD_POWER_OVERTEMP)
            self.set_head_power(False)
        for nozzle in self.nozzle:
            if nozzle.measured < UNLOAD_NOZZLE_TEMPERATURE * (1.0 - NOZZLE_TEMP_MARGIN):
                nozzle.unload_since = now
        if self.timing_pause and now - self.pause_since >= NOZZLE_PAUSE_AUTO_OFF_S:
            self.nozzle[0].mode = self.nozzle[1].mode = 0
            self.timing_pause = False
        self._check_bed_droop()
        self._check_thermistors(now)
        self.fw.file_system.set_nonvolatile(HOT_FLAG_BYTE, int(self.head_hot_now()))
        self._drive_plants()

    def _control(self, c: Controller, gains: tuple[float, float, float],
                 invert: bool = False) -> None:
        kp, ki, kd = gains
        if c.mode:
            target = c.setpoint()
            error = (c.measured - target) if invert else (target - c.measured)
            total = kp * error + c.integrator + kd * (c.last_measured - c.measured)
            total = max(0.0, min(1.0, total))
            error = (total - c.integrator) / kp
            c.integrator += ki * error
            c.pwm_duty = int(255.0 * total)
        else:
            c.pwm_duty = 0
            c.integrator = 0.0
        c.last_measured = c.measured

    def _check_bed_droop(self) -> None:
        bed = self.bed
        if bed.mode > 0:
            self.bed_got_to = min(bed.target[bed.mode - 1], max(self.bed_got_to, bed.measured))
            if self.bed_got_to - bed.measured > BED_DROOP_THRESHOLD:
                self.fw.errors.set(ErrorBit.BED_TEMPERATURE_DROOP)
                self.bed_got_to = -FLT_MAX
        else:
            self.bed_got_to = -FLT_MAX

    def _check_thermistors(self, now: float) -> None:
        # (each by its own call: compiled, no tuples and no enum member looked up by
        # name at every sample)
        two_fans = self._eeproms.head_has_two_fans()
        self._check_thermistor(self.bed, now, 60.0, False, 0)
        self._check_thermistor(self.nozzle[0], now, 20.0, False, 1)
        self._check_thermistor(self.nozzle[1], now, 20.0, two_fans, 2)

    def _check_thermistor(self, c: Controller, now: float, after: float, exempt: bool,
                          which: int) -> None:
        """A heater at full power that still reads below 20 degrees for `after` seconds
        has lost its thermistor: its error is raised and the heater switched off."""
        if c.pwm_duty != 255 or exempt:
            c.fault_since = now
        elif now - c.fault_since >= after and c.measured < 20.0:
            self.fw.errors.set(_THERMISTOR_ERRORS[which])
            c.mode = 0

    def _drive_plants(self) -> None:
        """The PWM outputs reach the plants; the head's only while it has power."""
        plants = self.fw.hw.machine.heaters
        powered = self.head_power_on()
        for c in self.controllers():
            on_head = c.on_head
            duty = c.pwm_duty / 255.0
            if c is self.ambient or (on_head and not powered):
                duty = 0.0
            if c is self.nozzle[1] and self._eeproms.head_has_two_fans():
                duty = 0.0
            if on_head and self.nozzles_forced_off:
                duty = 0.0
            plants[c.plant].duty = duty
        self.fw.hw.machine.head_fan = self.head_fan_duty / 255.0

    def any_on(self) -> bool:
        # (the four by name: compiled, no tuple and no generator made on every pass)
        return self.nozzle[0].mode != 0 or self.nozzle[1].mode != 0 or self.bed.mode != 0 \
            or self.ambient.mode != 0

    def turn_off(self) -> None:
        self.timing_pause = False
        for c in self.controllers():
            c.mode = 0
        self.head_fan_requested = 0


    def head_hot_now(self) -> bool:
        return max(self.nozzle[0].measured, self.nozzle[1].measured) > HEAD_HOT_TEMPERATURE

    def head_hot(self) -> bool:
        """For head hours: a nozzle at or above 60 C at the last sample."""
        return max(self.nozzle[0].measured, self.nozzle[1].measured) >= HEAD_HOT_TEMPERATURE

    # ------------------------------------------------- B-axis work-around
    def force_nozzles_off(self, force: bool) -> None:
        """While the valve moves, the nozzle heaters are held off, once the work-around
        has been enabled (after a lost B position)."""
        self.nozzles_forced_off = force and self.nozzle_forcing
        if self.nozzles_forced_off:
            for name in ("nozzle0", "nozzle1"):
                self.fw.hw.machine.heaters[name].duty = 0.0

    def enable_nozzle_forcing(self) -> None:
        self.nozzle_forcing = True

    def heat_for_filament_unload(self, nozzle0: bool, nozzle1: bool) -> Waits:
        """Before an unload: each nozzle named to the unload temperature (the head fan
        helping one that must cool), held there 5 s; then off, the fan as it was."""
        fan = self.head_fan_requested
        self.head_fan_requested = 0
        wanted = [nozzle0, nozzle1]
        for i, want in enumerate(wanted):
            if want:
                self.nozzle[i].mode = 3
                if self.nozzle[i].measured > UNLOAD_NOZZLE_TEMPERATURE:
                    self.head_fan_requested = 255
        self.why_are_we_waiting = NOZZLE_AT_TEMPERATURE
        job = self.fw.job
        while True:
            yield Wait(heater="nozzle0" if nozzle0 else "nozzle1")
            now = self.fw.clock.now
            done = True
            for i, want in enumerate(wanted):
                c = self.nozzle[i]
                if want and c.mode:
                    near = abs(UNLOAD_NOZZLE_TEMPERATURE - c.measured) / \
                        UNLOAD_NOZZLE_TEMPERATURE < NOZZLE_TEMP_MARGIN
                    done = done and near and now - c.unload_since >= UNLOAD_NOZZLE_DWELL_S
            if done or job.abort_flag or not self.head_power_on():
                break
        for i, want in enumerate(wanted):
            if want:
                self.nozzle[i].mode = 0
        self.head_fan_requested = fan
        self.why_are_we_waiting = NOT_WAITING

    # ---------------------------------------------------------- head power
    def head_power_on(self) -> bool:
        return self.fw.hw.machine.head_power

    def set_head_power(self, on: bool) -> None:
        machine = self.fw.hw.machine
        if on and machine.head_shorted:
            self.fw.errors.set(ErrorBit.HEAD_SHORTED)
            on = False
        machine.head_power = on

    def shut_down_head_due_to_eeprom(self) -> None:
        if self.head_power_on():
            self.fw.errors.set(ErrorBit.HEAD_POWER_EEPROM)
        self.set_head_power(False)

    def check_for_poweroff_whilst_hot(self) -> None:
        value = self.fw.file_system.nonvolatile(HOT_FLAG_BYTE)
        if value:
            self.fw.errors.set(ErrorBit.POWEROFF_WHILST_HOT)

    # ------------------------------------------------------ pause, resume
    def pause(self) -> None:
        self.nozzle_mode_at_pause = [self.nozzle[0].mode, self.nozzle[1].mode]
        self.pause_since = self.fw.clock.now
        self.timing_pause = True

    def resume(self) -> Waits:
        self.timing_pause = False
        self.nozzle[0].mode, self.nozzle[1].mode = self.nozzle_mode_at_pause
        yield from self.wait_for_nozzle(ignore_pause=True)
        yield from self.wait_for_bed(Line(b""), ignore_pause=True)

    # ------------------------------------------------------------ G-codes
    def set_nozzle_temperature(self, line: Line, first_layer: int) -> None:
        mode = first_layer + 1
        if not line.has("S") and not line.has("T"):
            self._nozzle_mode(0, mode)
            if self._eeproms.head_dual_material():
                self._nozzle_mode(1, mode)
        else:
            for i, letter in enumerate("ST"):
                if not line.has(letter):
                    continue
                if not line.has_float(letter):
                    self._nozzle_mode(i, mode)
                elif line.float(letter) > 0.0:
                    self.nozzle[i].target[first_layer] = line.float(letter)
                    self._nozzle_mode(i, mode)
                else:  # zero or less: off, the target kept
                    self._nozzle_mode(i, 0)
        if self.nozzle[0].mode or self.nozzle[1].mode:
            self.set_head_power(True)

    def _nozzle_mode(self, i: int, mode: int) -> None:
        self.nozzle[i].mode = self.nozzle_mode_at_pause[i] = mode

    def set_bed_temperature(self, line: Line, first_layer: int) -> None:
        bed = self.bed
        address = 0x38 if first_layer else 0x40
        for letter, reel in (("D", REEL1), ("E", REEL0)):
            if line.has(letter):
                bed.target[first_layer] = min(
                    MAX_BED_TARGET, self._reel_float(reel, address, bed.target[first_layer]))
        if line.has("S"):
            if line.float("S") > 0.0:
                bed.target[first_layer] = min(MAX_BED_TARGET, line.float("S"))
                bed.mode = first_layer + 1
            else:
                bed.mode = 0
        elif bed.target[first_layer] > 0.0:
            bed.mode = first_layer + 1
        else:
            bed.mode = 0

    def set_ambient_temperature(self, line: Line) -> None:
        amb = self.ambient
        for letter, reel in (("D", REEL1), ("E", REEL0)):
            if line.has(letter):
                amb.target[0] = min(MAX_AMBIENT_TARGET,
                                    self._reel_float(reel, 0x48, amb.target[0]))
        if line.has("S"):
            if line.float("S") > 0.0:
                amb.target[0] = min(MAX_AMBIENT_TARGET, line.float("S"))
                amb.mode = 1
            else:
                amb.mode = 0
        else:
            amb.mode = 1

    def set_head_fan(self, duty: int) -> None:
        if duty > 0:
            self.set_head_power(True)
        self.head_fan_requested = duty

    def set_targets(self, params: bytes) -> None:
        """Command 0xc3: seven float8 fields, nozzle 0 first."""
        v = [strtof(params[i : i + 8]) for i in range(0, 56, 8)]
        self.nozzle[0].target = [v[0], v[1]]
        self.nozzle[1].target = [v[2], v[3]]
        self.bed.target = [min(v[4], MAX_BED_TARGET), min(v[5], MAX_BED_TARGET)]
        ambient = min(v[6], MAX_AMBIENT_TARGET)
        self.ambient.target = [ambient, ambient]

    # ------------------------------------------------------ reel targets
    def nozzle_targets_from_reel(self, line: Line) -> None:
        eeproms = self._eeproms
        connected = self.fw.command.host_connected()
        dual = eeproms.head_dual_material()
        n0, n1 = self.nozzle
        if line.has("S") or not line.has("T"):
            reel = REEL1 if dual else REEL0
            n0.target = [self._reel_float(reel, 0x30, n0.target[0]),
                         self._reel_float(reel, 0x28, n0.target[1])]
            if not connected and eeproms.valid(reel):
                melt = eeproms.float_at(HEAD, 0xB0, n0.target[0])
                if abs(melt - n0.target[0]) > NOZZLE_FLUSH_MARGIN_C:
                    self.fw.errors.set(ErrorBit.NOZZLE_FLUSH_NEEDED)
        if line.has("T") or not line.has("S"):
            n1.target = [self._reel_float(REEL0, 0x30, n1.target[0]),
                         self._reel_float(REEL0, 0x28, n1.target[1])]
            if not connected and eeproms.valid(REEL0) and dual:
                melt = eeproms.float_at(HEAD, 0xA8, n1.target[0])
                if abs(melt - n1.target[0]) > NOZZLE_FLUSH_MARGIN_C:
                    self.fw.errors.set(ErrorBit.NOZZLE_FLUSH_NEEDED)

    def bed_targets_from_reel(self) -> None:
        bed = self.bed
        for i, address in ((0, 0x40), (1, 0x38)):
            t = self._reel_float(REEL0, address, bed.target[i])
            t = max(t, self._reel_float(REEL1, address, t))
            bed.target[i] = min(t, MAX_BED_TARGET)

    def ambient_target_from_reel(self) -> None:
        t = self._reel_float(REEL0, 0x48, self.ambient.target[0])
        t = max(t, self._reel_float(REEL1, 0x48, t))
        t = min(t, MAX_AMBIENT_TARGET)
        self.ambient.target = [t, t]

    def targets_from_reel(self) -> None:
        if not self.fw.job.running:
            self.bed_targets_from_reel()
        self.nozzle_targets_from_reel(Line(b"S T"))
        self.ambient_target_from_reel()

    # -------------------------------------------------------------- waits
    def wait_for_nozzle(self, ignore_pause: bool = False) -> Waits:
        """M109: until the selected nozzle (nozzle 0 on a single-material head) is within
        1.7% of its target; no wait when it is off, the head unpowered, or on abort."""
        self.why_are_we_waiting = NOZZLE_AT_TEMPERATURE
        i = self.fw.position.tool if self._eeproms.head_dual_material() else 0
        job = self.fw.job
        while True:
            yield Wait(heater=f"nozzle{min(i, 1)}")
            c = self.nozzle[min(i, 1)]
            v = 0.0
            if (not job.paused() or ignore_pause) and not job.aborting() and \
                    self.head_power_on() and c.mode != 0:
                target = c.setpoint()
                v = abs(target - c.measured) / max(1.0, target)
            if v <= NOZZLE_TEMP_MARGIN:
                break
        self.why_are_we_waiting = NOT_WAITING

    def wait_for_bed(self, line: Line, ignore_pause: bool = False) -> Waits:
        """M190: until the bed is within 3% of its target, or (S, T) it is time to start
        heating a nozzle, or (P) the given seconds before the bed would get there."""
        self.why_are_we_waiting = BED_AT_TEMPERATURE
        eeproms = self._eeproms
        job = self.fw.job
        done = False
        while not done:
            yield Wait(heater="bed")
            bed = self.bed
            if bed.mode == 0:
                break
            target = bed.target[bed.mode - 1]
            bederr = target - bed.measured
            if bederr > 0.0:
                tbed = time_to_target(target, bed.measured, self.ambient.measured, BED_APPROACH)
                if line.has_float("P"):
                    tbed -= line.float("P")
                    done = done or tbed < 0.0
                for i, letter in enumerate("ST"):
                    if not line.has(letter):
                        continue
                    v = line.float(letter) if line.has_float(letter) else \
                        self.nozzle[i].target[bed.mode - 1]
                    approach = DUAL_NOZZLE_APPROACH if eeproms.head_dual_material() else \
                        HIGH_TEMP_NOZZLE_APPROACH if eeproms.head_has_prtd() else \
                        SINGLE_NOZZLE_APPROACH
                    v = time_to_target(v, self.nozzle[i].measured, self.ambient.measured,
                                       approach)
                    done = done or v >= tbed
            done = done or target <= 0.0
            done = done or abs(bederr / max(1.0, target)) <= BED_TEMP_MARGIN
            done = done or (job.paused() and not ignore_pause)
            done = done or job.aborting()
        self.why_are_we_waiting = NOT_WAITING

    def wait_for_bed_cool(self) -> Waits:
        self.why_are_we_waiting = BED_COOLING
        while not self.fw.job.aborting() and self.bed.measured >= BED_HOT_TEMPERATURE:
            yield Wait(heater="bed")
        self.why_are_we_waiting = NOT_WAITING

    # ------------------------------------------------------------ reports
    def report_block(self) -> bytes:
        """Bytes 40..133 of the status report."""
        out = bytearray()
        for c in (self.nozzle[0], self.nozzle[1], self.bed):
            out += b"%d" % c.mode
            out += report_float(c.measured) + report_float(c.target[0]) + report_float(c.target[1])
        out += b"%d" % self.ambient.mode
        out += report_float(self.ambient.measured) + report_float(self.ambient.target[0])
        out += b"1" if self.head_fan_requested > 0 else b"0"
        out += b"%d" % self.why_are_we_waiting
        return bytes(out)

    def m105_text(self) -> bytes:
        n0, n1, bed, amb = self.controllers()
        return (f"S:{_c_int(n0.measured)} @{n0.pwm_duty} T:{_c_int(n1.measured)} "
                f"@{n1.pwm_duty} B:{_c_int(bed.measured)} ${bed.pwm_duty} "
                f"A:{_c_int(amb.measured)} *{amb.pwm_duty}\r\n").encode()


def _read(plant) -> float:
    """What the thermistor input gives: an open thermistor reads far below freezing."""
    return plant.temperature if plant.thermistor_ok else OPEN_THERMISTOR


def _c_int(value: float) -> int:
    return int(value) if math.isfinite(value) else 0

