"""float8: a number as 8 ASCII characters, the first 8 of C's printf("%f").

Space padded in EEPROM fields, NUL padded in protocol reports. Read back like
C's strtof: leading white space skipped, the leading number taken, the rest
ignored, float precision.
"""

from __future__ import annotations

import math
import re
import struct

from robox.errors import UsageError

WIDTH = 8
_NUMBER = re.compile(
    rb"\s*([+-]?(?:(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?|inf(?:inity)?|nan))", re.IGNORECASE)
_FLOAT32_MAX = 3.4028234663852886e38


def to_float32(value: float) -> float:
    """`value` rounded to C float precision (overflow gives infinity, as strtof does)."""
    if math.isnan(value) or math.isinf(value):
        return value
    if abs(value) > _FLOAT32_MAX:
        return math.copysign(math.inf, value)
    return struct.unpack("<f", struct.pack("<f", value))[0]


def fits(value: float) -> bool:
    """True when the integer part (and sign) of `value` fits in 8 characters."""
    if not math.isfinite(value):
        return False
    return len(f"{value:f}".split(".")[0]) <= WIDTH


def encode(value: float, pad: bytes = b" ") -> bytes:
    """The 8 bytes of `value`: the first 8 characters of "%f", padded with `pad`."""
    text = f"{value:f}"[:WIDTH].encode("ascii")
    return text.ljust(WIDTH, pad)


def encode_checked(value: float, pad: bytes = b" ") -> bytes:
    """encode(), refusing numbers whose integer part would be cut off."""
    if not fits(value):
        raise UsageError(f"{value!r} does not fit in 8 characters")
    return encode(value, pad)


def parse(raw: bytes | bytearray) -> float:
    """Read like strtof: the leading number, 0.0 when there is none."""
    match = _NUMBER.match(bytes(raw))
    if not match:
        return 0.0
    return to_float32(float(match.group(1)))
