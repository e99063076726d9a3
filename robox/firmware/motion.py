"""Motion: a queue of 16 blocks executed in simulated time with trapezoidal profiles.

Simple for now: each block knows its steps per axis, its length in mm and its
cruise speed; the speed at the junction with the next queued block is the
lower of the two cruise speeds, scaled down by the change of direction, and
the last queued block ends at rest. A block's duration is fixed when it
starts, from its entry speed (the previous block's exit speed).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

QUEUE_LENGTH = 16


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
        return self.fw.parameters.values["M201"]["A"]

    def room(self) -> bool:
        return len(self.queue) + (self.running is not None) < QUEUE_LENGTH

    def idle(self) -> bool:
        return self.running is None and not self.queue

    def next_event(self) -> float | None:
        if self.running is not None:
            return self.running.end
        return None

    def add(self, block: Block) -> None:
        """Queue a block (the caller has waited for room)."""
        self.queue.append(block)
        if self.running is None:
            self._start_next()

    def stop(self) -> None:
        """Abort: finish the move under way, drop the rest (their steps never happen)."""
        self.queue.clear()

    def _junction(self, a: Block, b: Block) -> float:
        cos = sum(x * y for x, y in zip(a.direction, b.direction, strict=True))
        return min(a.speed, b.speed) * max(0.0, cos)

    def _start_next(self) -> None:
        if not self.queue:
            self.running = None
            return
        entry = self.running.exit_speed if self.running is not None else 0.0
        block = self.queue.popleft()
        exit_speed = self._junction(block, self.queue[0]) if self.queue else 0.0
        block.exit_speed = exit_speed
        start = max(self.fw.clock.now, self.running.end if self.running else 0.0)
        duration = trapezoid_time(block.length, entry, block.speed, exit_speed, self.accel)
        block.start, block.end = start, start + duration
        self.moved_seconds += duration
        self.running = block

    def maintain(self) -> None:
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
