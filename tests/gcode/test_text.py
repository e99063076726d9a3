"""The words of a G-code line, against the rule written as a regular expression."""

import re

from hypothesis import example, given, settings
from hypothesis import strategies as st

from robox.gcode.text import words

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
