"""A G-code line read the way the firmware reads it: C string functions over bytes.

The printer never tokenises a line. A parameter is found with `strchr` (the
first occurrence of that exact, case-sensitive letter anywhere in the line) and
read with `strtol` / `strtoul` / `strtod` from the byte after it. So `g1 x10`
is no G-code at all, `M104 S` has an S without a number, and in `G1 X1 X2` only
the first X counts. The line ends at the first CR, LF, `;` or `(`, or at a NUL
byte (the end of a C string). This module is that reading, in one place.

Numbers: `strtod` accepts leading white space, a sign, decimal digits with an
optional point and exponent, hexadecimal floats (`0x1.8p3`), `inf`/`infinity`
and `nan`; the result is rounded to a C `float`, as `get_float` returns one.
`strtol` saturates at the limits of the host's `long` (64 bits on the PC the
reference recordings were made on).
"""

from __future__ import annotations

import builtins
import math
import re
from typing import Final

from robox.firmware.carith import f32
from robox.formats import float8
from robox.formats.float8 import short_decimal, skip_blanks
from robox.packed import i64, vec

LONG_MAX: Final = (1 << 63) - 1
LONG_MIN: Final = -(1 << 63)
ULONG_MAX: Final = (1 << 64) - 1
_TAGGED: Final = (1 << 62) - 1  # the most a compiled int holds without a heap number
_DEC: Final = re.compile(rb"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?")
_HEX: Final = re.compile(rb"([+-]?)0[xX]((?:[0-9a-fA-F]+\.?[0-9a-fA-F]*|\.[0-9a-fA-F]+))"
                         rb"(?:[pP]([+-]?\d+))?")
_SPECIAL: Final = re.compile(rb"([+-]?)(inf(?:inity)?|nan(?:\([0-9A-Za-z_]*\))?)", re.IGNORECASE)
_INT: Final = re.compile(rb"[+-]?\d+")
_FLOAT32_MAX: Final = 3.4028234663852886e38
MOVE_LETTERS: Final = b"XYZEDBF"  # the letters Line.move_letters finds, in its order
# each byte's place in MOVE_LETTERS, plus one (0: none of them)
_MOVE_SLOT: Final = bytes(MOVE_LETTERS.find(bytes((c,))) + 1 for c in range(256))


float32 = f32  # `value` rounded to C float precision (overflow gives infinity, as C does)


def report_float(value: float, keep: bool = True) -> bytes:
    """A float as the status report carries it: float8, NUL padded (`keep`: a figure
    that may well come again, kept)."""
    value = f32(value)
    # Formatting is most of a status report's cost, and its figures (targets, diameters,
    # settled temperatures, a standing head) repeat from report to report: the fields
    # of the latest ones are kept. (A zero is left out, -0.0 being equal to 0.0 as a
    # key, and so is NaN, which equals nothing.)
    if value == 0.0 or value != value or not keep:
        return float8.encode(value, b"\0")
    field = _REPORTED.get(value)
    if field is None:
        if len(_REPORTED) >= REPORTED_KEPT:
            _REPORTED.clear()
        field = float8.encode(value, b"\0")
        _REPORTED[value] = field
    return field


#: report_float's fields, by value (cleared when full).
_REPORTED: Final[dict[float, bytes]] = {}
REPORTED_KEPT: Final = 4096


def strtod(text: bytes) -> tuple[float, int]:
    """C's strtod: the value and the number of bytes consumed (0: no number)."""
    return _strtod_at(text, 0)


def _plain_number_end(text: bytes, i: int, point: bool) -> int:
    """Where a plain number starting at `i` ends: a sign, decimal digits and (with
    `point`, for strtod) one decimal point and no exponent or hexadecimal prefix
    after it; at least one digit (-1: not such a number). Nearly every number a
    slicer writes is one, and Python's float() and int() read it as strtod and
    strtol do (strtol in base 10 stops at any letter, so an integer needs no check
    of what follows)."""
    n = len(text)
    j = i + 1 if i < n and (text[i] == 43 or text[i] == 45) else i  # + or -
    k = j
    while k < n and 48 <= text[k] <= 57:
        k += 1
    digits = k - j
    if point and k < n and text[k] == 46:  # .
        k += 1
        m = k
        while k < n and 48 <= text[k] <= 57:
            k += 1
        digits += k - m
    if digits == 0 or (point and k < n and text[k] in b"eExX"):
        return -1
    return k


def _strtod_at(text: bytes, start: int) -> tuple[float, int]:
    """strtod over `text` from `start` on (no copy of the rest is made)."""
    i = skip_blanks(text, start)
    k = _plain_number_end(text, i, True)
    if k >= 0:
        return float(text[i:k]), k - start
    j = i + 1 if i < len(text) and text[i] in b"+-" else i
    if text[j : j + 2] in (b"0x", b"0X"):  # only then can it be a hexadecimal float
        match = _HEX.match(text, i)
        if match:
            sign, digits, exponent = match.groups()
            mantissa = digits.decode()
            value = float.fromhex(("-" if sign == b"-" else "") + "0x" + mantissa +
                                  "p" + (exponent.decode() if exponent else "0")) \
                if exponent is None or abs(int(exponent)) < 100000 else \
                (math.inf if int(exponent) > 0 and mantissa.strip("0.") else 0.0)
            return value, match.end() - start
    match = _DEC.match(text, i)
    if match:
        return float(match.group()), match.end() - start
    match = _SPECIAL.match(text, i)
    if match:
        sign, word = match.groups()
        value = math.nan if word[:1] in b"nN" else math.inf
        return (-value if sign == b"-" else value), match.end() - start
    return 0.0, 0


def _leading_integer(text: bytes, start: int = 0) -> int:
    # (native integers: compiled, up to 18 digits are added up without a slice or
    # int()'s parsing, and every such number is far inside a long)
    data: bytes = text if isinstance(text, bytes) else bytes(text)
    n: i64 = len(data)
    k = skip_blanks(data, start)
    negative = k < n and data[k] == 45  # -
    if k < n and (data[k] == 43 or data[k] == 45):
        k += 1
    whole: i64 = 0
    digits: i64 = 0
    while k < n and 48 <= data[k] <= 57:
        if digits == 18:
            return _long_integer(data, start)
        whole = whole * 10 + (data[k] - 48)
        digits += 1
        k += 1
    return -whole if negative else whole


def _long_integer(text: bytes, start: int) -> int:
    """_leading_integer's reading of 19 digits and more, in Python's integers."""
    i = skip_blanks(text, start)
    k = _plain_number_end(text, i, False)
    if k >= 0:
        return int(text[i:k])
    match = _INT.match(text, i)
    return int(match.group()) if match else 0


def strtol(text: bytes, start: int = 0) -> int:
    """C's strtol(text + start, NULL, 10), saturating at the limits of a 64-bit long."""
    value = _leading_integer(text, start)
    # (compared only past 2**62: compiled, the limits are heap numbers, not tagged ones)
    if -_TAGGED <= value <= _TAGGED:
        return value
    return max(LONG_MIN, min(LONG_MAX, value))


def strtoul(text: bytes, start: int = 0) -> int:
    """C's strtoul(text + start, NULL, 10): a negative number wraps, overflow saturates."""
    value = _leading_integer(text, start)
    if 0 <= value <= _TAGGED:
        return value
    return ULONG_MAX if abs(value) > ULONG_MAX else value & ULONG_MAX


def strtof(text: bytes) -> float:
    """C's strtof, as the firmware reads an 8-character float field."""
    return f32(strtod(bytes(text).split(b"\0", 1)[0])[0])


def _find(text: bytes, c: int) -> int:
    """strchr: where byte `c` first is in `text`, -1 if nowhere (compiled, a native loop
    over a line's few dozen bytes costs less than calling bytes.find)."""
    k: i64
    for k in range(len(text)):
        if text[k] == c:
            return k
    return -1


class Line:
    """One G-code line as the firmware's parameter accessors see it."""

    __slots__ = ("text",)

    def __init__(self, raw: bytes):
        # the first CR, LF, ';', '(' or NUL, byte by byte (compiled, a native loop: a
        # regular expression's character class costs several times as much here)
        n: i64 = len(raw)  # (native integers: compiled, indexing is native)
        end: i64 = n
        k: i64
        for k in range(n):
            c = raw[k]
            if c < 60 and (c == 13 or c == 10 or c == 59 or c == 40 or c == 0):
                end = k
                break
        text = raw[:end] if end < n else raw
        # (a bytearray made bytes; bytes kept as they are: compiled, bytes() is a
        # generic call, and it costs a line more than all the rest of reading it)
        self.text = text if isinstance(text, bytes) else bytes(text)

    # A parameter is found by its letter's first occurrence (strchr) and read from the
    # byte after it, in place.
    def has(self, letter: str) -> bool:
        return ord(letter) in self.text  # (`in` takes no argument parsing, find() does)

    def has_float(self, letter: str) -> bool:
        at = _find(self.text, ord(letter))
        return at >= 0 and _strtod_at(self.text, at + 1)[1] > 0

    def float(self, letter: str) -> float:
        at = _find(self.text, ord(letter))
        return 0.0 if at < 0 else self.float_after(at)

    def move_letters(self) -> vec[i64]:
        """Where G0/G1's letters X, Y, Z, E, D, B and F first are (strchr for each, in
        that order), -1 where absent: one walk along the line for all seven, each then
        read in place with float_after."""
        found = vec[i64]([-1, -1, -1, -1, -1, -1, -1])
        text = self.text
        k: i64
        for k in range(len(text)):
            slot: i64 = _MOVE_SLOT[text[k]]
            if slot and found[slot - 1] < 0:
                found[slot - 1] = k
        return found

    def float_after(self, at: i64) -> builtins.float:  # `float` here is the method above
        """get_float of the letter found at `at`: the number after it, a C float."""
        text = self.text
        value = short_decimal(text, at + 1)
        if value != value:  # (NaN: not a short plain decimal)
            value = _strtod_at(text, at + 1)[0]
        return f32(value)

    def int(self, letter: str) -> int:
        at = _find(self.text, ord(letter))
        return 0 if at < 0 else strtol(self.text, at + 1)

    def uint(self, letter: str) -> builtins.int:  # `int` here is the method above
        at = _find(self.text, ord(letter))
        return 0 if at < 0 else strtoul(self.text, at + 1)

    def bool(self, letter: str) -> bool:
        return self.int(letter) != 0
