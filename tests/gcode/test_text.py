"""The words of a G-code line, against the rule written as a regular expression; the
numbers a job writes, against printf."""

import re

from hypothesis import example, given, settings
from hypothesis import strategies as st

from robox.gcode.text import number, words

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


@settings(max_examples=1000, deadline=None)
@given(st.one_of(st.floats(-20000, 20000), st.floats(allow_nan=True, allow_infinity=True),
                 st.integers(-2**24, 2**24).map(lambda n: n / 2**10),  # halves, exactly
                 st.integers(-10**9, 10**9).map(lambda n: n / 100000)))
@example(0.015625)  # 1562.5 hundred-thousandths: a tie, to even (0.01562)
@example(-0.000004)  # rounds to "-0.00000": "0"
@example(9999.999995)
def test_a_number_is_written_as_printf_writes_it_to_5_places(value):
    """A job's number is printf's "%.5f" with the trailing zeros and point cut off."""
    text = f"{value:.5f}"
    if "." in text:
        text = text.rstrip("0").rstrip(".")
    assert number(value) == (b"0" if text in ("-0", "") else text.encode())
