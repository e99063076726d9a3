"""The firmware's number reading (cline) against the C library's own strtod and strtol.

get_float, get_int and get_uint are strtod, strtol and strtoul from the byte after
a parameter's letter. The C library of this machine is the oracle: every value and
every count of bytes consumed must be the same, for plain slicer numbers (read by a
fast path) and for everything else a hostile line can hold (signs alone, points alone,
exponents, hexadecimal floats, inf, nan, white space, trailing garbage).
"""

import ctypes
import ctypes.util
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from robox.firmware.carith import struct_f32
from robox.firmware.cline import REPORTED_KEPT, Line, report_float, strtod, strtol, strtoul
from robox.formats.float8 import short_decimal

_LIBC_NAME = ctypes.util.find_library("c")
pytestmark = pytest.mark.skipif(
    _LIBC_NAME is None or ctypes.sizeof(ctypes.c_long) != 8,
    reason="needs a C library with 64-bit long (the recordings' PC)")

if _LIBC_NAME is not None:
    _libc = ctypes.CDLL(_LIBC_NAME)
    _libc.strtod.restype = ctypes.c_double
    _libc.strtod.argtypes = [ctypes.c_char_p, ctypes.POINTER(ctypes.c_char_p)]
    _libc.strtol.restype = ctypes.c_long
    _libc.strtol.argtypes = [ctypes.c_char_p, ctypes.POINTER(ctypes.c_char_p), ctypes.c_int]
    _libc.strtoul.restype = ctypes.c_ulong
    _libc.strtoul.argtypes = [ctypes.c_char_p, ctypes.POINTER(ctypes.c_char_p), ctypes.c_int]
    _libc.snprintf.restype = ctypes.c_int


def _c_call(function, text: bytes, *base: int):
    buf = ctypes.create_string_buffer(text)
    end = ctypes.c_char_p()
    value = function(buf, ctypes.byref(end), *base)
    return value, ctypes.cast(end, ctypes.c_void_p).value - ctypes.addressof(buf)


def _same_double(a: float, b: float) -> bool:
    if math.isnan(a) or math.isnan(b):
        return math.isnan(a) and math.isnan(b)
    return a == b and math.copysign(1.0, a) == math.copysign(1.0, b)


_CHARS = st.sampled_from(list(b"0123456789.+-eExXpPabcdfinINFtyAN()_ \t"))
_HOSTILE = st.lists(_CHARS, max_size=16).map(bytes)
_PLAIN = st.builds(
    lambda sign, whole, point, frac, tail: sign + whole + point + frac + tail,
    st.sampled_from([b"", b"-", b"+"]),
    st.text("0123456789", max_size=12).map(str.encode),
    st.sampled_from([b"", b"."]),
    st.text("0123456789", max_size=12).map(str.encode),
    st.sampled_from([b"", b" ", b" Y2", b"e", b"e3", b"E-2", b"x", b"\n", b";c", b"X"]))
_TEXTS = st.one_of(_PLAIN, _HOSTILE)


@settings(max_examples=4000, deadline=None)
@given(_TEXTS)
def test_strtod_reads_what_the_c_library_reads(text):
    value, used = strtod(text)
    c_value, c_used = _c_call(_libc.strtod, text)
    assert used == c_used, text
    assert _same_double(value, c_value), (text, value, c_value)


@settings(max_examples=4000, deadline=None)
@given(_TEXTS)
def test_strtol_and_strtoul_read_what_the_c_library_reads(text):
    assert strtol(text) == _c_call(_libc.strtol, text, 10)[0], text
    assert strtoul(text) == _c_call(_libc.strtoul, text, 10)[0], text


@settings(max_examples=2000, deadline=None)
@given(st.sampled_from([b"", b" ", b"\t "]), st.sampled_from([b"", b"-", b"+"]),
       st.text("0123456789", min_size=15, max_size=24).map(str.encode),
       st.sampled_from([b"", b"X", b"5", b".5", b" 7"]))
def test_long_integers_read_as_the_c_library_reads_them(blank, sign, digits, tail):
    """Up to 18 digits are added up natively; from 19 on Python's integers read them,
    and past a long's range strtol saturates and strtoul wraps or saturates."""
    text = blank + sign + digits + tail
    assert strtol(text) == _c_call(_libc.strtol, text, 10)[0], text
    assert strtoul(text) == _c_call(_libc.strtoul, text, 10)[0], text
    assert Line(b"M" + text).int("M") == _c_call(_libc.strtol, text, 10)[0], text


@settings(max_examples=2000, deadline=None)
@given(_TEXTS)
def test_a_parameter_is_the_c_float_of_strtod_after_its_letter(text):
    line = Line(b"G1 X" + text)
    expected = struct_f32(_c_call(_libc.strtod, line.text[4:])[0])  # the line ends at ; ( CR LF
    assert _same_double(line.float("X"), expected), text


@settings(max_examples=2000, deadline=None)
@given(_TEXTS)
def test_an_integer_parameter_is_strtol_after_its_letter(text):
    line = Line(b"M" + text)
    assert line.int("M") == _c_call(_libc.strtol, line.text[1:], 10)[0], text


@settings(max_examples=3000, deadline=None)
@given(st.text("0123456789", min_size=1, max_size=17), st.integers(0, 17),
       st.sampled_from([b"", b"-", b"+"]))
def test_short_decimals_read_as_strtod_reads_them(digits, point, sign):
    """Up to 15 digits a parameter is read without strtod's general path: every place of
    the point, leading and trailing zeros, and past 15 digits the general path again."""
    text = sign + digits[:point].encode() + b"." + digits[point:].encode()
    line = Line(b"G1 E" + text + b" F1")
    c_value = _c_call(_libc.strtod, text)[0]
    assert _same_double(line.float("E"), struct_f32(c_value)), text
    # the double itself, before the cast to float hides most of a wrong rounding
    value = short_decimal(b"E" + text, 1)
    assert _same_double(value, c_value) if len(digits) <= 15 else math.isnan(value), text
    # ended by `end` as by a slice there: what follows (a digit, an exponent) is not read
    for after in (b"7", b"e5", b" Y1"):
        bounded = short_decimal(b"E" + text + after, 1, True, 1 + len(text))
        assert _same_double(bounded, short_decimal(b"E" + text, 1, True)), (text, after)


@pytest.mark.parametrize("text, value, used", [
    (b"12.5 Y3", 12.5, 4),      # the fast path: a plain decimal, then more of the line
    (b"-0", -0.0, 2),           # its sign kept
    (b"5.", 5.0, 2),            # a point with no digits after it belongs to the number
    (b".5", 0.5, 2),
    (b"1e3", 1000.0, 3),        # an exponent: not the fast path, the same reading
    (b"1e", 1.0, 1),            # an exponent with no digits is not part of the number
    (b"0x1p4", 16.0, 5),        # a hexadecimal float
    (b"0x", 0.0, 1),            # the 0 alone
    (b"+", 0.0, 0),             # no number at all
    (b" \t7", 7.0, 3),          # leading white space is skipped and counted
])
def test_strtod_examples(text, value, used):
    assert _c_call(_libc.strtod, text) == (value, used)  # the oracle agrees with the table
    got = strtod(text)
    assert _same_double(got[0], value) and got[1] == used


_MOVE_BYTES = st.lists(st.sampled_from(list(b"XYZEDBFGxyzedbf0123456789.- \t;\x00\xc3\xa9")),
                       max_size=40).map(bytes)


@settings(max_examples=3000, deadline=None)
@given(_MOVE_BYTES)
def test_a_moves_letters_are_where_strchr_finds_them(raw):
    line = Line(raw)
    _libc.strchr.restype = ctypes.c_void_p
    _libc.strchr.argtypes = [ctypes.c_char_p, ctypes.c_int]
    buf = ctypes.create_string_buffer(line.text)
    found = line.move_letters()
    assert len(found) == 7
    for slot, letter in enumerate(b"XYZEDBF"):
        hit = _libc.strchr(buf, letter)
        expected = -1 if hit is None else hit - ctypes.addressof(buf)
        assert found[slot] == expected, (raw, chr(letter))
        if expected >= 0:
            c_value = struct_f32(_c_call(_libc.strtod, line.text[expected + 1:])[0])
            assert _same_double(line.float_after(found[slot]), c_value), raw


def _c_report_field(value: float) -> bytes:
    """The status report's float field as the firmware makes it: the first 8 characters
    of C's "%f" of the float, NUL padded."""
    buf = ctypes.create_string_buffer(400)
    _libc.snprintf(buf, 400, b"%f", ctypes.c_double(struct_f32(value)))
    return buf.value[:8].ljust(8, b"\0")


@settings(max_examples=300, deadline=None)
@given(st.lists(st.one_of(st.floats(width=32, allow_nan=False),
                          st.sampled_from([0.0, -0.0, 210.0, 1.75, math.nan])), max_size=40))
def test_a_report_field_is_cs_printf_every_time_it_is_asked(values):
    """The fields are kept by value: a repeat, a zero of either sign, a NaN, an infinity
    give what C's printf gives, the first time and every time after. (A NaN with its
    sign bit set is left out: this C library prints it "-nan", Python "nan".)"""
    for value in values + values[::-1]:
        assert report_float(value) == _c_report_field(value), value
        assert report_float(value, keep=False) == _c_report_field(value), value


def test_report_fields_are_right_past_the_number_kept():
    values = [i * 0.37 + 0.001 for i in range(REPORTED_KEPT + 500)]
    for value in values + values[:600]:
        assert report_float(value) == _c_report_field(value), value
