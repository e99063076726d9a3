"""float8: a number as 8 ASCII characters, the first 8 of C's printf("%f").

Space padded in EEPROM fields, NUL padded in protocol reports. Read back like
C's strtof: leading white space skipped, the leading number taken, the rest
ignored, float precision.
"""

from __future__ import annotations

import math
import re
from typing import Final

from robox.errors import UsageError
from robox.firmware.carith import f32
from robox.packed import i64, vec

WIDTH = 8
_NUMBER = re.compile(
    rb"\s*([+-]?(?:(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?|inf(?:inity)?|nan))", re.IGNORECASE)
_FLOAT32_MAX = 3.4028234663852886e38
_POWERS_OF_TEN: Final = vec[float]([10.0**i for i in range(16)])  # each exact as a double


def to_float32(value: float) -> float:
    """`value` rounded to C float precision (overflow gives infinity, as strtof does)."""
    if value - value != 0.0:  # NaN or infinite (compiled: native, not a call)
        return value
    if abs(value) > _FLOAT32_MAX:
        return math.copysign(math.inf, value)
    return f32(value)


def fits(value: float) -> bool:
    """True when the integer part (and sign) of `value` fits in 8 characters."""
    if not math.isfinite(value):
        return False
    return len(f"{value:f}".split(".")[0]) <= WIDTH


def encode(value: float, pad: bytes = b" ") -> bytes:
    """The 8 bytes of `value`: the first 8 characters of "%f", padded with `pad`."""
    # (printf-style on bytes: compiled, no format-string parsing and no encoding)
    return (b"%f" % value)[:WIDTH].ljust(WIDTH, pad)


def encode_checked(value: float, pad: bytes = b" ") -> bytes:
    """encode(), refusing numbers whose integer part would be cut off."""
    if not fits(value):
        raise UsageError(f"{value!r} does not fit in 8 characters")
    return encode(value, pad)


def parse(raw: bytes | bytearray) -> float:
    """Read like strtof: the leading number, 0.0 when there is none."""
    # (bytes as they are: compiled, bytes() of a union is a generic call)
    text: bytes = raw if isinstance(raw, bytes) else bytes(raw)
    value = short_decimal(text, skip_blanks(text, 0))  # (nearly every field: no pattern matched)
    if value == value:
        return to_float32(value)
    match = _NUMBER.match(text)
    if not match:
        return 0.0
    return to_float32(float(match.group(1)))


def parse_fields(raw: bytes, start: i64, count: i64) -> list[float]:
    """`count` fields of WIDTH bytes one after another from `start`, each read as parse()
    reads it (a status report's figures: compiled, one call for a run of them)."""
    out: list[float] = []
    k: i64
    for k in range(count):
        at: i64 = start + WIDTH * k
        out.append(parse(raw[at : at + WIDTH]))
    return out


def shortest(value: float) -> float:
    """A float32 `value` as a person wrote it: the number with the fewest significant
    digits that reads back (as strtof reads it) as the same float32. 2.85 stored reads
    back as the float32 2.8499999046325684; shown, it is 2.85 again."""
    if value - value != 0.0 or value == 0.0:  # NaN, infinite or zero: as it is
        return value
    target = to_float32(value)
    for digits in range(1, 10):  # 9 significant digits tell every float32 apart
        candidate = float(f"{target:.{digits}g}")
        if to_float32(candidate) == target:
            return candidate
    return target


def skip_blanks(text: bytes, i: i64) -> i64:
    """Where the first byte at or after `i` that is not white space is (len: none)."""
    n: i64 = len(text)  # (native integers: compiled, indexing is native)
    # the white space strtod and strtol skip (the pattern's \s): space, \t \n \v \f \r
    while i < n and (text[i] == 32 or 9 <= text[i] <= 13):
        i += 1
    return i


def short_decimal(text: bytes, i: i64, to_end: bool = False, end: i64 = -1) -> float:
    """strtod's value of a short plain decimal right at `i` (an optional sign, then at
    most 15 digits with at most one point among them, and no exponent or hexadecimal
    prefix after), NaN for anything else. Nearly every number a slicer writes, and
    every float8 a printer writes, is one. With `to_end` the number must end the
    text: then it is also the value float() reads from text[i:]. A text that ends
    before text's own end is given by `end` (>= 0): text[:end] without the slice.
    The digits make a whole number below 2**53 and the point a power of ten up to
    1e15, both exact as doubles, so their quotient is the correctly rounded value
    strtod gives (the classic exact case of decimal conversion)."""
    # (native integers: compiled, the digits are added up without overflow checks; the
    # whole number stops growing past 16 digits, where the answer is NaN anyway; each
    # byte is made a native integer once, where compared as it is it is a tagged one)
    n: i64 = len(text)
    if end >= 0:
        n = end
    negative = False
    k: i64 = i
    c: i64
    if k < n:
        c = text[k]
        if c == 45 or c == 43:  # - or +
            negative = c == 45
            k += 1
    whole: i64 = 0
    digits: i64 = 0
    places: i64 = -1  # digits after the point (-1: no point yet)
    while k < n:
        c = text[k]
        if 48 <= c <= 57:
            if digits <= 15:
                whole = whole * 10 + (c - 48)
            digits += 1
            if places >= 0:
                places += 1
        elif c == 46 and places < 0:  # .
            places = 0
        else:
            break
        k += 1
    after: i64 = 0  # the byte after, lower-cased
    if k < n:
        after = text[k] | 0x20
    if digits == 0 or digits > 15 or after == 101 or after == 120 or (to_end and k < n):
        return math.nan  # (e, x after it: not so short)
    value = float(whole) / _POWERS_OF_TEN[places] if places > 0 else float(whole)
    return -value if negative else value
