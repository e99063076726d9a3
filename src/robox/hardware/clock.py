"""Simulated time: a clock the firmware loop advances; nothing here reads the wall clock."""

from __future__ import annotations

import math
from typing import Final

from robox.packed import i64


class PassCondition:
    """What Firmware.run_until looks at after every pass. Compiled, a subclass's holds()
    is called there natively, where any other callable goes through Python's call
    protocol at every pass (hundreds of thousands in a print); called, it answers
    holds()."""

    def holds(self) -> bool:
        raise NotImplementedError

    def __call__(self) -> bool:
        return self.holds()


class SimClock:
    """Seconds since power-up, advanced explicitly."""

    def __init__(self, start: float = 0.0):
        self.now = start

    def advance(self, seconds: float, times: int = 1) -> None:
        """Move on `times` steps of `seconds`: the sum of `times` additions, each rounded
        (so n passes of 1 ms land exactly where n single passes would)."""
        if seconds < 0:
            raise ValueError("time does not run backwards")
        self.now = accumulate(self.now, seconds, times)


def accumulate(x: float, step: float, count: i64) -> float:
    """`x` after `count` additions `x = x + step`, each rounded to the nearest double.

    While the sums stay in one binade (or among the subnormals around 0) the grid is
    uniform, so each increment depends only on the parity of the sum on it: after the
    first addition the increments repeat with period one or two (the firmware's float
    sums, carith.f32_accumulate, work the same way). Whole periods are taken at once
    and single additions only near a change of grid: a clock's thousands of 1 ms
    passes cost a few additions."""
    while count > 0:
        if count < _WORTH_A_PERIOD:  # (a few native additions a step: quicker one by one)
            while count > 0:
                x = x + step
                count -= 1
            return x
        y = x + step
        if y - y != 0.0 or y == x:  # NaN or infinite (then it stays so), or stuck
            return y  # (stuck: y is x, but for a zero's sign, -0.0 + 0.0 being 0.0)
        if -_TOP_BINADE < y < _TOP_BINADE:  # (the top binade's end would be inf)
            y2 = y + step
            y3 = y2 + step
            y4 = y3 + step
            y5 = y4 + step
            # the open interval around y where the grid is uniform: its binade, or the
            # subnormals' around 0
            lo, hi = -_SMALLEST_DOUBLE, _SMALLEST_DOUBLE
            a = -y if y < 0.0 else y
            if a >= _SMALLEST_DOUBLE:
                exponent = math.frexp(a)[1]
                lo, hi = math.ldexp(1.0, exponent - 1), math.ldexp(1.0, exponent)
                if y < 0.0:
                    lo, hi = -hi, -lo
            period = y3 - y
            if (lo < y5 < hi and y5 - y3 == period and y4 - y3 == y2 - y
                    and lo < y < hi and period != 0.0):
                room: i64 = math.floor(((hi if period > 0 else lo) - y5) / period) - 1
                pairs: i64 = (count - 5) // 2
                if room < pairs:
                    pairs = room
                if pairs > 0:
                    x = y5 + float(pairs) * period
                    count -= 5 + 2 * pairs
                    continue
        x = y
        count -= 1
    return x


_SMALLEST_DOUBLE: Final = 2.0 ** -1022  # the least normal double
_TOP_BINADE: Final = 2.0 ** 1023
_WORTH_A_PERIOD: Final = 1024  # additions: fewer cost less than finding the period
