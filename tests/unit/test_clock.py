"""The simulated clock: its sums of many passes are the sums of the passes one by one."""

import math
import random

import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from robox.hardware.clock import SimClock, accumulate


def one_by_one(x: float, step: float, count: int) -> float:
    for _ in range(count):
        x = x + step
    return x


def same(a: float, b: float) -> bool:
    return (a != a and b != b) or (a == b and math.copysign(1.0, a) == math.copysign(1.0, b))


# steps that land on ties of the grid (half a unit, one and a half) and ordinary ones,
# from sums that cross binades, start among the subnormals or sit at a power of two
_X = st.one_of(st.floats(0, 1e5), st.floats(-1e5, 1e5), st.sampled_from(
    [0.0, -0.0, 2.0**-1074, 2.0**-1022 - 2.0**-1074, 1024.0, 4096.0 - 2.0**-40, 1e300]))
_STEP = st.one_of(st.sampled_from([0.001, 0.000125, 0.25, 1e-3 / 3, -0.001, 0.0]),
                  st.floats(-10, 10), st.integers(-4, 4).map(lambda k: k * 2.0**-1075),
                  st.integers(1, 7).map(lambda k: k * 2.0**-41))


@settings(max_examples=1500, deadline=None)
@given(_X, _STEP, st.integers(0, 4000))  # (from 1024 on, whole periods at once)
@example(4096.0 - 2.0**-40, 2.0**-41, 3000)  # ties to even either side of a binade
@example(1.0, 2.0**-53, 2000)  # each sum a tie that rounds back: stuck at once
@example(1.0 + 2.0**-52, 2.0**-53, 2000)  # one rounds up to even, then stuck
@example(2.0**-1074, 2.0**-1074, 3000)  # out of the subnormals into the normals
@example(1e308, 1e307, 2000)  # to infinity, which stays
@example(-0.0, 0.0, 1)  # -0.0 + 0.0 is 0.0
@example(-0.0, 0.0, 2000)
def test_the_sum_of_many_steps_is_the_sum_one_by_one(x, step, count):
    assert same(accumulate(x, step, count), one_by_one(x, step, count))


def test_a_long_idle_lands_where_its_passes_would():
    """A clock advanced by hours of 1 ms passes at once, from random moments, is where
    the passes one by one would leave it (a million of them: minutes simulated)."""
    rng = random.Random(7)
    for _ in range(5):
        start = rng.uniform(0, 40_000)
        clock = SimClock(start)
        clock.advance(0.001, 1_000_000)
        assert clock.now == one_by_one(start, 0.001, 1_000_000)
    with pytest.raises(ValueError):
        clock.advance(-0.001)
