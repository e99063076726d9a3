"""A simulated print watched from outside the firmware: every queued move, every pass.

`simulate` attaches a `Watch` to the position object (its watcher, told of each move
it queues) and runs the printer with `Watch.passes()` as the condition looked at after
every pass (`Watch.sample`). Both run hundreds of thousands of times in a print, so
this module is part of the compiled core (robox.native), and the firmware calls both
natively (`MoveWatcher`, `PassCondition`); `robox.sim.simulate` turns what it saw into
the report.
"""

from __future__ import annotations

import math
from typing import Any, Final

# (Firmware imported at run time, not only for the type checker: the compiled module
# reads its attributes natively, through its class, which must be there first)
from robox.firmware.main import Firmware
from robox.firmware.position import MoveWatcher
from robox.hardware.clock import PassCondition
from robox.hardware.deposition import Deposition
from robox.hardware.machine import B, D, E, ThermalModel, X, Y, Z
from robox.packed import vec

#: The build plate, in the job's frame (its origin at the plate's front left corner).
BED_X_MM: Final = 210.0
BED_Y_MM: Final = 150.0
#: A valve opened less than this (of 0..1) counts as shut.
VALVE_SHUT: Final = 0.05
EPSILON_MM: Final = 1e-3


class Watch(MoveWatcher):
    """What the queued moves did, and the heaters' peaks and the job's furthest line
    over the passes."""

    def __init__(self, fw: Firmware, has_valve: bool) -> None:
        self.fw = fw
        self.has_valve = has_valve
        # (packed vectors: compiled, read and written natively at every queued move,
        # where a list's item is a boxed float)
        self.low = vec[float]([math.inf] * 3)
        self.high = vec[float]([-math.inf] * 3)
        self.outside_lines: list[int] = []
        self.clamped_lines: list[int] = []
        self.shut_lines: list[int] = []
        self.shut_mm = vec[float]([0.0, 0.0])  # per reel
        self.asked = vec[float]([math.nan, math.nan])  # X, Y
        self.start_lines = 0  # the job's start sequence: its plastic is not judged
        self.deposition: Deposition | None = None
        self.heaters: list[ThermalModel] = []  # read at every pass
        self.peak = vec[float]([])  # each heater's peak reading
        self.reached = 0  # the furthest line the job came to

    def attach(self) -> None:
        self.fw.position.watcher = self

    def passes(self) -> PassCondition:
        """The condition to run the printer with: sample() after every pass."""
        return _Sampled(self)

    def watch_heaters(self, heaters: list[ThermalModel]) -> None:
        self.heaters = heaters
        self.peak = vec[float]([-math.inf] * len(heaters))

    def sample(self) -> bool:
        """After a pass: the peaks and the furthest line brought up to date; whether the
        job has ended or paused."""
        peak = self.peak
        heaters = self.heaters
        for k in range(len(heaters)):
            reading = heaters[k].temperature
            if reading > peak[k]:
                peak[k] = reading
        job = self.fw.job
        line: int = job.line_number
        if line > self.reached:
            self.reached = line
        return not job.running or bool(job.pause)

    @staticmethod
    def _note(lines: list[int], line: int) -> None:
        if not lines or lines[-1] != line:
            lines.append(line)

    def on_move(self, moves: Any) -> None:
        """moved(), for a caller in Python: `moves` taken as any object (a compiled
        method that takes a packed vector through its Python entry keeps a reference
        to each one passed, and the segments' vectors would pile up, one per queued
        move), unboxed once here."""
        distances: vec[float] = moves
        self.moved(distances)

    def moved(self, moves: vec[float]) -> None:
        distances = moves
        fw = self.fw
        p = fw.position
        line: int = fw.job.line_number
        deposition = self.deposition
        if deposition is not None and line > self.start_lines:
            deposition.judging = True
        dest, off, homed = p.destination, p.tool_offset, p.homing_done
        asked = self.asked
        limits = fw.parameters.travel  # (M520's, by axis: a packed vector, read natively)
        for i in range(X, Y + 1):
            wanted = dest[i] + off[i]
            if homed[i] and wanted != asked[i]:  # a new destination on this axis
                asked[i] = wanted
                travel: float = limits[i]
                if wanted < -EPSILON_MM or wanted > travel + EPSILON_MM:
                    self._note(self.clamped_lines, line)
        if distances[E] <= 0.0 and distances[D] <= 0.0:
            return
        low, high = self.low, self.high
        for i in range(X, Z + 1):
            w = dest[i]
            if w < low[i]:
                low[i] = w
            if w > high[i]:
                high[i] = w
        x, y = dest[X], dest[Y]
        if not (-EPSILON_MM <= x <= BED_X_MM + EPSILON_MM
                and -EPSILON_MM <= y <= BED_Y_MM + EPSILON_MM):
            self._note(self.outside_lines, line)
        if self.has_valve and (not homed[B] or abs(p.position[B]) < VALVE_SHUT):
            self._note(self.shut_lines, line)
            for n in range(2):
                pushed = distances[E + n]
                if pushed > 0.0:
                    self.shut_mm[n] += pushed


class _Sampled(PassCondition):
    """Watch.sample as the condition Firmware.run_until asks natively."""

    def __init__(self, watch: Watch) -> None:
        self.watch = watch

    def holds(self) -> bool:
        return self.watch.sample()
