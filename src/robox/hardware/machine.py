"""The printer's mechanics and thermals as the firmware drives them.

Motors count microsteps; the switches, the Z-top switch, the filament sensors
and the index wheels follow the positions (docs/firmware-model.md, "The
machine"). Positions are at the factory steps/mm, 0 at each switch's trip
point:

- X, Y: the switch is actuated at 0 and below.
- Z: two leadscrew motors (ZA at X = -37.546 mm, ZB at X = 251.5 mm); the
  nozzle height is the gantry line between them at the carriage's X, and
  the Z switch is actuated at height 0 and below, the Z-top switch at 95 mm
  and above. The Z switch is the selected nozzle touching the bed: a head whose
  nozzle 1 sits lower (`nozzle1_drop`, a virtual printer's `--nozzle-z-difference`)
  trips it that much higher with the valve on nozzle 1's side of its switch.
- B: the valve; its switch is actuated at 0 and above (the nozzle-0 side). At
  power-up the valve rests 0.7 B units (1,750 microsteps) on that side, where the
  recording rig's machine starts it (`VALVE_REST_STEPS`): how far the first tool
  change or valve move has to travel, and so when the motion after it ends.
- E, D: filament paths. Along a path (in the extruder's microsteps) the
  drive and its index wheel sit at 0, the filament sensor just after them and
  the nozzle at the end. A filament occupies [tail, tip]; the drive moves it
  while it is under the drive; pushed against a nozzle below 150 C it does
  not move (the drive slips), above that it is extruded (the tip stays, the
  tail follows). The index wheel's level toggles every 256 microsteps of
  filament passing it.

Where the plastic goes is watched by a deposition model where one is attached
(`deposition`, robox.hardware.deposition): the valve's steps and the filament that
leaves the drive's path are reported to it, and a shut head it reports full makes the
drive slip.

Faults: a switch stuck at a level (`stuck`), a wheel that does not turn
(`wheel_slipping`), filament that runs out (a short `tail`), a hand feeding
filament in (`feed_by_hand`, what starts an automatic load). The door's latch
opens when the carriage goes beyond Y's travel.

The motion object moves motors with `step(axis, n)`; `quiet_steps(select)`
bounds how far any motor may move before a watched switch could change, and
`wheel_steps(axis, forward)` how far a drive may move before its index wheel could, so
whole runs of interrupts can be done at once.
"""

from __future__ import annotations

import math
from typing import Final

from robox.hardware.deposition import Deposition
from robox.packed import i64, vec

AXES: Final = "XYZEDB"
X: Final = 0
Y: Final = 1
Z: Final = 2
E: Final = 3
D: Final = 4
B: Final = 5
X_STEPS_PER_MM: Final = 133.7  # (a Final float: compiled, a constant, not a lookup)
# not Final: mypyc leaves a Final tuple of floats unset (NameError when read)
STEPS_PER_MM = (X_STEPS_PER_MM, 133.7, 6400.0, 747.0, 747.0, 2500.0)
ZA_X_MM: Final = -37.546
ZB_X_MM: Final = 251.5
Z_TOP_MM: Final = 95.0
Z_TOP_STEPS: Final = Z_TOP_MM * STEPS_PER_MM[Z]  # where the Z-top switch closes
# The carriage's X (microsteps) a step inside the span between the leadscrews,
# ceil(ZA_X_MM * 133.7) + 1 and floor(ZB_X_MM * 133.7) - 1, and a height (microsteps) a
# step below the Z-top switch, 95 * 6400 - 1: with both leadscrews' ends below it and the
# carriage within the span, the gantry line there is below it too (z_top_pin() answers
# without working out the height). (Literals: compiled, constants in the code, where a
# computed Final is a module attribute looked up and checked at every use.)
SPAN_X_LO: Final = -5018
SPAN_X_HI: Final = 33624
BELOW_TOP: Final = 607999
INDEX_EDGE_SHIFT: Final = 8
INDEX_EDGE_STEPS: Final = 1 << INDEX_EDGE_SHIFT  # the index wheel's level toggles this often
SENSOR_MM: Final = 10.0  # filament sensor after the drive
NOZZLE_MM: Final = 380.0  # drive to nozzle, through the Bowden tube
MELT_C: Final = 150.0
HAND_SPEED_MM_S: Final = 20.0
DOOR_UNLOCK_Y_MM: Final = 158.0
NEVER: Final = 1 << 60
VALVE_REST_STEPS: Final = round(0.7 * STEPS_PER_MM[B])  # where the valve is at power-up


def _steps(axis: int, mm: float) -> int:
    return round(mm * STEPS_PER_MM[axis])


# each axis's microsteps from the drive to the filament sensor and to the nozzle
SENSOR_STEPS: Final = tuple(_steps(axis, SENSOR_MM) for axis in range(len(STEPS_PER_MM)))
NOZZLE_STEPS: Final = tuple(_steps(axis, NOZZLE_MM) for axis in range(len(STEPS_PER_MM)))


class Filament:
    """A length of filament in an extruder's path, in that extruder's microsteps."""

    # (native integers: compiled, every feed step's sums and comparisons are native)
    tip: i64
    tail: i64

    def __init__(self, tip: i64, tail: i64) -> None:
        self.tip = tip
        self.tail = tail

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Filament) and self.tip == other.tip \
            and self.tail == other.tail

    def __repr__(self) -> str:
        return f"Filament(tip={self.tip}, tail={self.tail})"


class ThermalModel:
    """A heated mass and the thermistor that reads it.

    The mass: d(core)/dt = (gain * duty - (core - ambient)) / tau. The thermistor lags
    the mass: d(T)/dt = (core - T) / lag. Both are integrated exactly for a constant duty.
    The lag is what lets the firmware's PID settle: its derivative term (kd 0.55 per
    degree a second on a nozzle) over a plant that answered a duty change within the
    same one-second sample would flip the heater fully on and off every sample and hold
    the nozzle a few degrees off its target, which no real hot end does."""

    def __init__(self, name: str, gain: float, tau: float, lag: float = 0.0) -> None:
        self.name = name
        self.gain = gain  # degrees above ambient at full power
        self.tau = tau  # seconds
        self.lag = lag  # seconds; 0: the thermistor reads the mass itself
        self.ambient = 20.0
        self.core = 20.0
        self.sensed = 20.0
        self.duty = 0.0  # 0..1
        self.thermistor_ok = True
        # the decays over the last step's length (steps of one pass repeat: exp() once)
        self._step = -1.0
        self._step_tau = self._step_lag = 0.0
        self._fall = self._lag_fall = 1.0

    @property
    def temperature(self) -> float:
        """What the thermistor reads."""
        return self.sensed

    @temperature.setter
    def temperature(self, value: float) -> None:
        """The mass and its thermistor both at `value` (settled)."""
        self.core = self.sensed = value

    def advance(self, seconds: float) -> None:
        target = self.ambient + self.gain * self.duty
        if self.core == target and self.sensed == target:
            return  # at rest: the formulas below would give these very values again
        if seconds != self._step or self.tau != self._step_tau or self.lag != self._step_lag:
            self._step, self._step_tau, self._step_lag = seconds, self.tau, self.lag
            self._fall = math.exp(-seconds / self.tau)
            # (used only where the lag is not <= 0, the test below)
            self._lag_fall = 0.0 if self.lag <= 0.0 else math.exp(-seconds / self.lag)
        core = self.core - target
        fall = self._fall
        self.core = target + core * fall
        if self.lag <= 0.0:
            self.sensed = self.core
            return
        follow = core * self.tau / (self.tau - self.lag)
        self.sensed = target + follow * fall + (self.sensed - target - follow) * self._lag_fall


class Machine:
    """Everything physical the firmware touches, besides the card, chips, flash and USB."""

    def __init__(self) -> None:
        self.x = 0
        self.y = 0
        self.za = 0
        self.zb = 0
        self.b = VALVE_REST_STEPS
        # ZA runs the other way (the firmware's gantry levelling)
        self.gantry_rotation = False
        # per extruder, indexed by axis (E, D; the other places are unused): lists, which
        # the step interrupt's calls read natively compiled, where dicts are looked up
        self.filament: list[Filament | None] = [None] * 6
        # (packed vectors: compiled, the interrupt's steps add to them natively, where a
        # list's item is a boxed int)
        self.wheel_passed = vec[i64]([0] * 6)
        self.wheel_base = [False, False, False, True, False, False]
        self.wheel_slipping = [False] * 6
        self.stuck: dict[str, bool] = {}  # input name -> level it sticks at
        self.extruded = vec[i64]([0] * 6)  # through a nozzle
        # mm still to feed (a packed vector: compiled, hand_busy() on every pass reads it
        # natively)
        self.hand = vec[float]([0.0] * 6)
        self.heaters = {
            "nozzle0": ThermalModel("nozzle0", gain=253.0, tau=71.0, lag=2.0),
            "nozzle1": ThermalModel("nozzle1", gain=253.0, tau=71.0, lag=2.0),
            "bed": ThermalModel("bed", gain=150.0, tau=280.0),
            "ambient": ThermalModel("ambient", gain=40.0, tau=600.0)}
        self.head_fan = 0.0
        self.ambient_led = (0, 0, 0)
        self.button_led = (0, 0, 0)
        self.lid_closed = True
        self.button_pressed = False
        self.head_power = True
        self.head_shorted = False
        self.head_lights = False
        self.supply_24v = True
        self.hardware_revision = 2
        self.motors_on = False
        # the head's build: how far (Z microsteps) nozzle 1's tip sits below nozzle 0's
        # (the Z switch trips when the nozzle the valve has selected touches the bed)
        self.nozzle1_drop = 0
        # where plastic lands (robox.hardware.deposition), watched only where attached
        self.deposition: Deposition | None = None
        # the heat models in a list, which advance() goes through (compiled, a list is
        # walked natively where a dict's values are iterated through the generic protocol)
        self._heater_list = list(self.heaters.values())
        # and the two nozzles', read on every feed step (no lookups by name)
        self._nozzles = (self.heaters["nozzle0"], self.heaters["nozzle1"])
        # where each path's filament sensor and nozzle are (packed vectors: read natively)
        self._sensor_steps = vec[i64](list(SENSOR_STEPS))
        self._nozzle_steps = vec[i64](list(NOZZLE_STEPS))

    # ------------------------------------------------------------ motors
    def step(self, axis: int, n: int) -> None:
        """`n` microsteps (signed) of one of the firmware's axes."""
        dep = self.deposition
        if dep is not None and dep.feed_waiting and axis <= Z:
            dep.flush_feed()  # (a run of steps moves X, Y, Z, E, D, B in that order)
        if axis == X:
            self.x += n
        elif axis == Y:
            self.y += n
        elif axis == Z:
            self.zb += n
            self.za += -n if self.gantry_rotation else n
        elif axis == B:
            self.b += n
            if self.deposition is not None:
                self.deposition.valve(self.b)
        else:
            self._drive(axis, n)

    def _drive(self, axis: int, n: i64) -> None:
        f = self.filament[axis]
        if f is None or not f.tail <= 0 <= f.tip:
            return  # nothing under the drive
        # a run of steps moves the filament only until it leaves the drive, as the
        # same steps one at a time would: its tail a step past it, or its tip a step
        # behind it
        if n > 1 - f.tail:
            n = 1 - f.tail
        elif n < -1 - f.tip:
            n = -1 - f.tip
        nozzle: i64 = self._nozzle_steps[axis]
        moved: i64 = n
        if n < 0 and self.deposition is not None:
            self.deposition.drawn_back(axis, -n)
        if n > 0 and f.tip + n > nozzle:
            # the nozzles hot enough to melt it (either: both melt the one path's filament)
            nozzle0, nozzle1 = self._nozzles
            if nozzle0.sensed >= MELT_C or nozzle1.sensed >= MELT_C:
                out: i64 = f.tip + n - (f.tip if f.tip > nozzle else nozzle)
                dep = self.deposition
                if dep is not None:
                    taken = dep.fed(axis, out)
                    if taken < out:  # a shut head full under pressure: the drive slips
                        n -= out - taken
                        out = taken
                self.extruded[axis] += out
                f.tail += n
                if nozzle > f.tip:
                    f.tip = nozzle
                if not self.wheel_slipping[axis]:  # (_turn_wheel, written out: every run)
                    self.wheel_passed[axis] += n
                return
            moved = 0  # pushed against a cold nozzle: the drive slips
            if nozzle > f.tip:
                moved = nozzle - f.tip
        f.tip += moved
        f.tail += moved
        self._turn_wheel(axis, moved)

    def _turn_wheel(self, axis: int, n: i64) -> None:
        if not self.wheel_slipping[axis]:
            self.wheel_passed[axis] += n

    # ------------------------------------------------------------ inputs
    def nozzle_height(self) -> float:
        """Z microsteps of the gantry line at the carriage's X."""
        if self.za == self.zb:
            return self.za
        x_mm = self.x / X_STEPS_PER_MM
        return self.za + (self.zb - self.za) * (x_mm - ZA_X_MM) / (ZB_X_MM - ZA_X_MM)

    def tip_height(self) -> float:
        """Z microsteps of the selected nozzle's tip over the bed: nozzle 0's on the
        positive side of the valve's switch, nozzle 1's (`nozzle1_drop` lower) beyond it."""
        if self.nozzle1_drop and self.b < 0:
            return self.nozzle_height() - self.nozzle1_drop
        return self.nozzle_height()

    def filament_present(self, axis: int) -> bool:
        f = self.filament[axis]
        if f is None:
            return False
        sensor: i64 = self._sensor_steps[axis]
        return f.tail <= sensor <= f.tip

    def sensor_margin(self, axis: i64, forward: bool, back: bool) -> i64:
        """The fewest microsteps drive `axis` (E, D) must make, feeding where `forward`
        and drawing back where `back`, before its filament sensor reads otherwise
        (NEVER: it cannot). The filament moves only while it spans the drive, a
        microstep a step at most (no hand is on it), and the sensor is in front of the
        drive."""
        if self.stuck and AXES[axis] in self.stuck:
            return NEVER  # (a sensor stuck at one reading)
        f = self.filament[axis]
        if f is None or not f.tail <= 0 <= f.tip:
            return NEVER  # nothing under the drive: nothing moves
        sensor: i64 = self._sensor_steps[axis]
        if f.tip < sensor:  # the tip short of the sensor: fed, it reaches it unless the
            # tail leaves the drive first (the drive moves it 1 - tail steps at most)
            if forward and sensor - f.tip <= 1 - f.tail:
                return sensor - f.tip
            return NEVER
        # at the sensor: drawn back, the tip falls short of it (while still in the
        # drive, which is behind the sensor); fed, the tail leaves the drive first
        # (statements, not a conditional expression: compiled, one whose arms mix an
        # i64 and an int goes through a boxed number)
        if back:
            return f.tip - sensor + 1
        return NEVER

    def actuated(self, axis: int) -> bool:
        """Whether the axis's switch (E, D: the filament sensor) is actuated."""
        if self.stuck:
            name = AXES[axis]
            if name in self.stuck:
                return self.stuck[name]
        if axis == X:
            return self.x <= 0
        if axis == Y:
            return self.y <= 0
        if axis == Z:
            return self.tip_height() <= 0
        if axis == B:
            return self.b >= 0
        return self.filament_present(axis)

    def switch_pin(self, axis: int) -> int:
        """The input level: X/Y/Z/B switches read 1 when actuated, filament sensors 0."""
        if E <= axis <= D and not self.stuck:  # (E, D: compiled, no tuple)
            return 0 if self.filament_present(axis) else 1  # (each pass reads both)
        return int(self.actuated(axis)) ^ int(E <= axis <= D)

    def sensor_pins(self) -> i64:
        """Both filament sensors' input levels at once, E's in bit 0 and D's in bit 1
        (each as switch_pin() reads it): the foreground looks at both on every pass, and
        one native call answers it."""
        if self.stuck:
            return self.switch_pin(E) | (self.switch_pin(D) << 1)
        sensors = self._sensor_steps
        pins: i64 = 3
        f = self.filament[E]
        if f is not None and f.tail <= sensors[E] <= f.tip:
            pins = 2
        f = self.filament[D]
        if f is not None and f.tail <= sensors[D] <= f.tip:
            pins &= 1
        return pins

    def z_top_pin(self) -> int:
        """The Z-top input reads 0 when actuated."""
        if self.stuck and "Z+" in self.stuck:
            return int(not self.stuck["Z+"])
        if self.za < BELOW_TOP and self.zb < BELOW_TOP and SPAN_X_LO <= self.x <= SPAN_X_HI:
            return 1  # (asked at every run of interrupts; between its ends, the line is lower)
        return int(self.nozzle_height() < Z_TOP_STEPS)

    def index_wheel(self, axis: int) -> int:
        # (a shift: compiled, a native one, where a floor division calls a function)
        level: i64 = (self.wheel_passed[axis] >> INDEX_EDGE_SHIFT) & 1
        return int(level) ^ 1 if self.wheel_base[axis] else int(level)

    def index_levels(self) -> i64:
        """Both index wheels' levels at once, E's in bit 0 and D's in bit 1 (each as
        index_wheel() gives it): the step interrupt looks at both at every run of
        interrupts, and one native call answers it."""
        passed = self.wheel_passed
        base = self.wheel_base
        e: i64 = (passed[E] >> INDEX_EDGE_SHIFT) & 1
        d: i64 = (passed[D] >> INDEX_EDGE_SHIFT) & 1
        if base[E]:
            e ^= 1
        if base[D]:
            d ^= 1
        return e | (d << 1)

    def lid_pin(self) -> int:
        return int(self.lid_closed)

    def quiet_steps(self, select: int | None) -> int:
        """How many microsteps any motor may make before the selected switch (None: no
        switch watched) can change (an index wheel: `wheel_steps`)."""
        if select is not None and AXES[select] not in self.stuck:
            return self._switch_margin(select)
        return NEVER

    def wheel_steps(self, axis: i64, forward: bool) -> i64:
        """The microsteps of drive `axis` (E, D) in one direction (`forward`: feeding)
        whose last may change its index wheel's level: the wheel turns with the
        filament, at most a microstep a step and never against the drive, so its next
        edge that way is the nearest; NEVER where it cannot turn."""
        if self.filament[axis] is None or self.wheel_slipping[axis]:
            return NEVER
        r: i64 = self.wheel_passed[axis] & (INDEX_EDGE_STEPS - 1)  # (its modulo, natively)
        return INDEX_EDGE_STEPS - r if forward else r + 1

    def _switch_margin(self, axis: int) -> int:
        if axis == X:
            return abs(self.x) + 1
        if axis == Y:
            return abs(self.y) + 1
        if axis == Z:
            slope = abs(self.zb - self.za) / ((ZB_X_MM - ZA_X_MM) * X_STEPS_PER_MM)
            margin = int(abs(self.tip_height()) / (1.0 + slope)) + 1
            if self.nozzle1_drop:  # the valve crossing its switch selects the other tip
                margin = min(margin, abs(self.b) + 1)
            return margin
        if axis == B:
            return abs(self.b) + 1
        f = self.filament[axis]
        if f is None:
            return NEVER
        sensor: i64 = self._sensor_steps[axis]
        to_tip: i64 = f.tip - sensor
        to_tail: i64 = f.tail - sensor
        if to_tip < 0:
            to_tip = -to_tip
        if to_tail < 0:
            to_tail = -to_tail
        return (to_tip if to_tip < to_tail else to_tail) + 1

    # ------------------------------------------------------------ people
    def insert_filament(self, axis: int, length_mm: float = 240_000.0,
                        tip_mm: float = 0.0) -> None:
        """Filament from a reel, its tip `tip_mm` along the path (0: at the drive)."""
        tip = _steps(axis, tip_mm)
        self.filament[axis] = Filament(tip=tip, tail=tip - _steps(axis, length_mm))

    def nozzle_steps(self, axis: int) -> int:
        return NOZZLE_STEPS[axis]

    def door_unlocked(self) -> bool:
        """The door's latch is released by the carriage beyond Y's travel (G37)."""
        return self.y >= DOOR_UNLOCK_Y_MM * STEPS_PER_MM[Y]

    def feed_by_hand(self, axis: int, mm: float) -> None:
        """Push the filament in by hand (it turns the index wheel as it goes)."""
        self.hand[axis] += mm

    def hand_busy(self) -> bool:
        hand = self.hand
        return hand[E] > 0 or hand[D] > 0

    def advance(self, seconds: float) -> None:
        for heater in self._heater_list:
            heater.advance(seconds)
        if not self.hand_busy():
            return
        for axis in (E, D):
            left = self.hand[axis]
            f = self.filament[axis]
            if left <= 0 or f is None:
                continue
            mm = min(left, HAND_SPEED_MM_S * seconds)
            self.hand[axis] = left - mm
            n = _steps(axis, mm)
            f.tip += n
            f.tail += n
            self._turn_wheel(axis, n)
