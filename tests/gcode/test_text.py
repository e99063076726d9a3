"""The words of a G-code line, against the rule written as a regular expression; the
numbers a job writes, against printf."""

import ctypes
import ctypes.util
import math
import re

from hypothesis import assume, example, given, settings
from hypothesis import strategies as st

from robox.gcode.text import native_number, number, words

LIBC = ctypes.CDLL(ctypes.util.find_library("c"))

# a word: any character but a blank, then everything up to the next letter or blank
WORD = re.compile(r"(\S)([^\sA-Z]*)")


def reference(line: bytes) -> tuple[str, dict[str, str]]:
    found = WORD.findall(line.decode("ascii").upper())
    if not found:
        return "", {}
    return found[0][0] + found[0][1], {k: v for k, v in found[1:]}


@settings(max_examples=2000, deadline=None)
@given(st.text(alphabet="GMTXYZEFSgxe0123456789.-+ \t\x0b\x0c\x1c\x1d\x1e\x1f*;{`",
               max_size=40))
@example("G1 X10 E.5")
@example("G1X10E.5")
@example("g1 x-1.5 y2 x3")
@example("  \t ")
@example("M117 Hello*7")
@example("G1 X1Y2 F3")
@example("G1 X1\x1fY2 E3")  # a separator to text's split(), not to bytes'
@example("G1 X{1 Y`2")  # the bytes either side of the letters
def test_words_follow_the_rule(text):
    line = text.encode("ascii")
    assert words(line) == reference(line)


def test_words_of_slicer_lines():
    assert words(b"G1 X10.5 Y-3 E.02") == ("G1", {"X": "10.5", "Y": "-3", "E": ".02"})
    assert words(b"G1X10E.5") == ("G1", {"X": "10", "E": ".5"})
    assert words(b"") == ("", {})


def printf_5(value: float) -> bytes:
    """printf's "%.5f" as the C library writes it, cut as a job's numbers are."""
    out = ctypes.create_string_buffer(400)
    LIBC.snprintf(out, 400, b"%.5f", ctypes.c_double(value))
    text = out.value
    if b"." in text:
        text = text.rstrip(b"0").rstrip(b".")
    return b"0" if text in (b"-0", b"") else text


def near(value: float) -> st.SearchStrategy[float]:
    """`value` or one of its neighbours, a unit of the last place either side."""
    return st.sampled_from([math.nextafter(value, -math.inf), value,
                            math.nextafter(value, math.inf)])


@settings(max_examples=3000, deadline=None)
@given(st.one_of(st.floats(-20000, 20000), st.floats(allow_nan=True, allow_infinity=True),
                 st.integers(-2**24, 2**24).map(lambda n: n / 2**10),  # halves, exactly
                 st.integers(-10**9, 10**9).map(lambda n: n / 100000),
                 # exact ties of the fifth place (k + 0.5 hundred-thousandths: a multiple
                 # of 2**-6) and their neighbours, which the product's error decides
                 st.tuples(st.integers(-2**40, 2**40), st.integers(6, 30)).flatmap(
                     lambda t: near(t[0] / 2**t[1])),
                 # around the native arithmetic's limit, 2**52 hundred-thousandths
                 st.floats(4.4e10, 4.6e10).flatmap(near), st.floats(-1e15, 1e15)))
@example(0.015625)  # 1562.5 hundred-thousandths: a tie, to even (0.01562)
@example(0.046875)  # 4687.5: to even, up (0.04688)
@example(-0.000004)  # rounds to "-0.00000": "0"
@example(-0.0)
@example(0.000005)  # a hair above 0.5 hundred-thousandths as a double: "0.00001"
@example(9999.999995)
@example(4503599627370496 / 100000)
@example(5e-324)
def test_a_number_is_written_as_printf_writes_it_to_5_places(value):
    """A job's number is printf's "%.5f" with the trailing zeros and point cut off:
    both the native arithmetic and the formatter (the one an interpreted build uses)
    against the C library's own snprintf."""
    # (a NaN with its sign bit set: this C library writes "-nan", Python's formatter
    # "nan"; a job's numbers are finite, checked as they are read)
    assume(not (math.isnan(value) and math.copysign(1.0, value) < 0))
    wanted = printf_5(value)
    assert native_number(value) == wanted
    assert number(value) == wanted
