"""Motion: a queue of 16 blocks executed in simulated time with trapezoidal profiles.

Simple for now: each block knows its steps per axis, its length in mm and its
cruise speed. When a block starts, the exit speeds of the queued blocks are
computed backwards from the last one (which ends at rest): each is the lower
of the junction speed with its successor (the lower cruise speed, scaled by
the change of direction) and what the deceleration distance allows. The
block's duration follows from its entry speed (the previous block's exit).
Blocks start at the `maintain()` after they are queued, so everything a line
queued in one pass is looked ahead to.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

QUEUE_LENGTH = 16
# The model's own acceleration for its trapezoids (the firmware's integer ramp, driven by
# M201 S, is the machine model's work).
ACCEL_MM_S2 = 1500.0


@dataclass
class Block:
    steps: dict[str, int]
    length: float  # mm along the path (XYZ, or the longest other axis)
    speed: float  # cruise, mm/s
    direction: tuple[float, float, float] = (0.0, 0.0, 0.0)
    start: float = 0.0
    end: float = 0.0
    exit_speed: float = 0.0
    homing: str | None = None  # axis homed by this block
    extra: dict = field(default_factory=dict)


def trapezoid_time(length: float, entry: float, cruise: float, exit_: float,
                   accel: float) -> float:
    """Seconds to cover `length` from `entry` to `exit_` speed, cruising at most `cruise`."""
    if length <= 0:
        return 0.0
    cruise = max(cruise, 1e-6)
    entry, exit_ = min(entry, cruise), min(exit_, cruise)
    up = (cruise**2 - entry**2) / (2 * accel)
    down = (cruise**2 - exit_**2) / (2 * accel)
    if up + down <= length:
        return (cruise - entry) / accel + (cruise - exit_) / accel + (length - up - down) / cruise
    # no cruise phase: peak speed where acceleration and deceleration meet
    peak = math.sqrt(max(0.0, accel * length + (entry**2 + exit_**2) / 2))
    peak = max(peak, entry, exit_)
    return max(0.0, (peak - entry) / accel) + max(0.0, (peak - exit_) / accel)


class Motion:
    def __init__(self, firmware):
        self.fw = firmware

    def initialise(self) -> None:
        self.queue: deque[Block] = deque()
        self.running: Block | None = None
        self.moved_seconds = 0.0

    @property
    def accel(self) -> float:
        return ACCEL_MM_S2

    def room(self) -> bool:
        return len(self.queue) + (self.running is not None) < QUEUE_LENGTH

    def idle(self) -> bool:
        return self.running is None and not self.queue

    def next_event(self) -> float | None:
        if self.running is not None:
            return self.running.end
        if self.queue:
            return self.fw.clock.now
        return None

    def add(self, block: Block) -> None:
        """Queue a block (the caller has waited for room); it starts at the next maintain."""
        self.queue.append(block)

    def motors_off(self) -> None:
        """M84: the drivers are disabled; positions are kept (the model has no step loss)."""

    @staticmethod
    def _junction(a: Block, b: Block) -> float:
        (ax, ay, az), (bx, by, bz) = a.direction, b.direction
        cos = ax * bx + ay * by + az * bz
        return min(a.speed, b.speed) * cos if cos > 0 else 0.0

    def _start_next(self) -> None:
        if not self.queue:
            self.running = None
            return
        entry = self.running.exit_speed if self.running is not None else 0.0
        exit_speed = 0.0  # the last queued block ends at rest
        blocks = list(self.queue)
        twice_accel = 2 * self.accel
        junction = self._junction
        for later, earlier in zip(reversed(blocks[1:]), reversed(blocks[:-1]), strict=True):
            reachable = math.sqrt(exit_speed * exit_speed + twice_accel * later.length)
            exit_speed = min(junction(earlier, later), reachable)
        block = self.queue.popleft()
        block.exit_speed = exit_speed
        start = max(self.fw.clock.now, self.running.end if self.running else 0.0)
        duration = trapezoid_time(block.length, entry, block.speed, exit_speed, self.accel)
        block.start, block.end = start, start + duration
        self.moved_seconds += duration
        self.running = block

    def maintain(self) -> None:
        if self.running is None and self.queue:
            self._start_next()
        while self.running is not None and self.running.end <= self.fw.clock.now:
            self._complete(self.running)
            previous = self.running
            if self.queue:
                self._start_next()
                if self.running is previous:  # pragma: no cover
                    break
            else:
                self.running = None

    def _complete(self, block: Block) -> None:
        axes = self.fw.hw.machine.axes
        if block.homing is not None:
            axes[block.homing].position = 0
        for name, steps in block.steps.items():
            axes[name].position += steps
        self.fw.position.completed(block)
