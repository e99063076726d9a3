"""C arithmetic as the printer's processor does it, for numbers a host can make absurd.

The Robox runs on an ARM Cortex-M3 without a floating-point unit: every float or
double operation is a call into GCC's soft-float library, and C's conversions from
floating point to integers are its `__aeabi_f2iz` / `__aeabi_d2iz` (to a signed
32-bit `long`) and `__aeabi_f2uiz` / `__aeabi_d2uiz` (to an unsigned one). Those
never trap, whatever the value:

- to signed: truncation toward zero; values at or beyond +2**31 give 0x7fffffff,
  values at or below -2**31 give -0x80000000; NaN gives 0;
- to unsigned: truncation toward zero; every negative value gives 0; values at or
  beyond 2**32 give 0xffffffff; NaN gives 0;
- to `unsigned short` or `unsigned char`: GCC converts to a signed int first (every
  value of the narrow type fits in one) and keeps the low bits.

Float division by zero gives an infinity (or NaN for 0/0), `sqrt` of a negative
number gives NaN, and the firmware's `min` / `max` are the macros
`((a)<(b)?(a):(b))` and `((a)>(b)?(a):(b))`: with a NaN on either side the
comparison is false, so `max(0.0, NaN)` is NaN while `max(NaN, 0.0)` is 0.0.
Python's own `min`, `max`, `int` and `/` differ on every one of these points, so
the model computes with the functions here wherever a host's number can reach.
"""

from __future__ import annotations

import math
import struct
from typing import Final

INT_MAX: Final = 0x7FFFFFFF
INT_MIN: Final = -0x80000000
UINT_MAX: Final = 0xFFFFFFFF

_F32: Final = struct.Struct("<f")

try:  # a native 64-bit integer where the compiled core is built (robox.native)
    from mypy_extensions import i64
except ImportError:  # otherwise only an annotation: int
    i64 = int  # type: ignore[misc,assignment]


def isqrt32(x: i64) -> i64:
    """math.isqrt() of a whole number below 2**53, in native arithmetic when compiled: the
    double's square root is within one of the answer, and the answer is checked both ways."""
    r: i64 = int(math.sqrt(float(x)))  # float(): compiled, the native square root
    if r * r > x:
        r -= 1
    elif (r + 1) * (r + 1) <= x:
        r += 1
    return r


native_isqrt32 = isqrt32  # the body above, whichever runs (for the tests)


def struct_f32(value: float) -> float:
    """`value` rounded to a C float (overflow gives an infinity, as C does), by the struct
    module's own conversion."""
    try:
        return _F32.unpack(_F32.pack(value))[0]
    except OverflowError:
        return math.copysign(math.inf, value)


_SPLIT: Final = 536870913.0  # 2**29 + 1: Veltkamp's constant, a double's top 24 bits
_SPLIT23: Final = 1073741825.0  # 2**30 + 1: its top 23 bits
_F32_TINY: Final = 1.1754943508222875e-38  # 2**-126, the least normal float
_F32_BIG: Final = 1.7014118346046923e38  # 2**127


def f32(value: float) -> float:
    """`value` rounded to a C float (overflow gives an infinity, as C does).

    Compiled (robox.native), the build gives this function C's own conversion,
    `(double)(float)value`, as its body (buildsys/robox_build.py, C_BODIES). The body
    here is what mypyc compiles where that is not done, in native double arithmetic:
    Veltkamp's split takes a normal number's nearest 24-bit neighbour; at a tie (the
    other neighbour, as far on the other side, has 24 bits too) the even one is taken,
    the one that fits in 23 bits. A subnormal, a huge, infinite or NaN value goes to
    struct_f32. Interpreted, the name is struct_f32."""
    if value == 0.0:
        return value  # either zero, its sign kept
    a = abs(value)
    if _F32_TINY <= a < _F32_BIG:
        c = value * _SPLIT
        hi = c - (c - value)
        lo = value - hi
        if lo == 0.0:
            return hi
        other = hi + 2.0 * lo
        c = other * _SPLIT
        if c - (c - other) != other:
            return hi
        # a tie: the neighbour whose last bit is 0, the one that has 23 bits
        c = hi * _SPLIT23
        return hi if c - (c - hi) == hi else other
    return struct_f32(value)


native_f32 = f32  # for the tests: compiled, C's conversion; interpreted, the body above


def to_long(value: float) -> int:
    """(signed long)value on the printer (`__aeabi_f2iz`, `__aeabi_d2iz`)."""
    if value != value:
        return 0
    if value >= 2147483648.0:
        return INT_MAX
    if value <= -2147483648.0:
        return INT_MIN
    return int(value)


def to_ulong(value: float) -> int:
    """(unsigned long)value on the printer (`__aeabi_f2uiz`, `__aeabi_d2uiz`)."""
    if value != value or value <= 0.0:
        return 0
    if value >= 4294967296.0:
        return UINT_MAX
    return int(value)


def to_ushort(value: float) -> int:
    """(unsigned short)value: through a signed int, then the low 16 bits."""
    return to_long(value) & 0xFFFF


def to_uchar(value: float) -> int:
    """(unsigned char)value: through a signed int, then the low 8 bits."""
    return to_long(value) & 0xFF


def floor_long(value: float) -> int:
    """(signed long)floor(value)."""
    return to_long(math.floor(value)) if math.isfinite(value) else to_long(value)


def cfloor(value: float) -> float:
    """C's floor, as a float: infinities and NaN come back as they are."""
    return float(math.floor(value)) if math.isfinite(value) else value


def wrap_long(value: int) -> int:
    """An integer result kept to a signed 32-bit long, as the ARM's registers keep it."""
    return ((value + 0x80000000) & UINT_MAX) - 0x80000000


def cmax(a: float, b: float) -> float:
    """The firmware's max(a, b) macro (on floats, as every use is: compiled, native)."""
    return a if a > b else b


def cmin(a: float, b: float) -> float:
    """The firmware's min(a, b) macro (on floats, as every use is: compiled, native)."""
    return a if a < b else b


def div(a: float, b: float) -> float:
    """IEEE division: by zero it gives a signed infinity, or NaN for 0/0 and NaN."""
    if b != 0.0:
        return a / b
    if a != a or a == 0.0:
        return math.nan
    return math.copysign(math.inf, a) * math.copysign(1.0, b)


def sqrt(value: float) -> float:
    """C's sqrt: NaN for a negative number."""
    return math.sqrt(value) if value >= 0.0 else math.nan


def f32_accumulate(x: float, step: float, count: int) -> float:
    """`x` after `count` float additions `x = x + step` (both float values).

    Each sum is rounded to the float grid around it, ties to the even neighbour. While
    the values stay where that grid is uniform (one binade, or the subnormals around
    zero), the increment depends only on the parity of `x` on the grid, so after the
    first addition the increments repeat with period one or two. Whole periods are
    taken at once and single additions only near a change of grid, so even the four
    thousand million additions of a G1 split into 2 mm segments cost little."""
    x, step = f32(x), f32(step)
    while count > 0:
        y = f32(x + step)
        if y != y or math.isinf(y) or y == x:
            return y  # (stuck: y is x, but for a zero's sign, -0.0 + 0.0 being 0.0)
        if count >= 8:
            y2 = f32(y + step)
            y3 = f32(y2 + step)
            y4 = f32(y3 + step)
            y5 = f32(y4 + step)
            lo, hi = _uniform_grid(y)
            period = y3 - y
            if (lo < y5 < hi and y5 - y3 == period and y4 - y3 == y2 - y
                    and lo < y < hi and period != 0.0):
                room = math.floor(((hi if period > 0 else lo) - y5) / period) - 1
                pairs = min(room, (count - 5) // 2)
                if pairs > 0:
                    x = y5 + pairs * period
                    count -= 5 + 2 * pairs
                    continue
        x, count = y, count - 1
    return x


_SMALLEST_NORMAL: Final = 2.0 ** -126


def _uniform_grid(x: float) -> tuple[float, float]:
    """An open interval around `x` over which the float grid is evenly spaced."""
    if abs(x) < _SMALLEST_NORMAL:
        return -_SMALLEST_NORMAL, _SMALLEST_NORMAL
    exponent = math.frexp(abs(x))[1]  # abs(x) in [2**(exponent-1), 2**exponent)
    lo, hi = math.ldexp(1.0, exponent - 1), math.ldexp(1.0, exponent)
    return (lo, hi) if x > 0 else (-hi, -lo)


if __file__.endswith(".py"):  # interpreted, the library's own conversions are the quicker
    isqrt32 = math.isqrt  # type: ignore[assignment]
    f32 = struct_f32  # type: ignore[assignment]
