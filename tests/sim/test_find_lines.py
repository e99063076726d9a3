"""Which job line a place in the deposition record comes from (quality.find_lines)."""

import math
import random
import re

from hypothesis import given, settings
from hypothesis import strategies as st

from robox.sim.quality import Place, find_lines

JOB = b"""; a comment line
G90
G1 Z0.3 F600
G1 X10 Y10 E1 ; first corner
G1 X20 Y10 E1
g1 x20 y20 e1
G0 X10 Y10
G91
G1 Z0.2
G1 X5 Y0 E1
G90
G1 X10 Y10 E1
M104 S200
G1 X40.5 Y-3 Z0.9
"""


def ends(job: bytes) -> list[tuple[int, float, float, float]]:
    """Every move's end (line, x, y, z), followed by hand: G0/G1, G90/G91."""
    out, pos, relative = [], {"X": 0.0, "Y": 0.0, "Z": 0.0}, False
    for number, raw in enumerate(job.decode().splitlines(), 1):
        words = raw.split(";")[0].upper().split()
        if words[:1] == ["G91"]:
            relative = True
        elif words[:1] == ["G90"]:
            relative = False
        if words[:1] in (["G0"], ["G1"]):
            for word in words[1:]:
                if word[0] in pos:
                    pos[word[0]] = pos[word[0]] + float(word[1:]) if relative \
                        else float(word[1:])
            out.append((number, pos["X"], pos["Y"], pos["Z"]))
    return out


def nearest(job: bytes, x: float, y: float, z: float) -> int:
    """The first of the moves whose end is nearest (height weighed 100 times)."""
    return min(ends(job), key=lambda e: (e[1] - x) * (e[1] - x) + (e[2] - y) * (e[2] - y)
               + 100.0 * ((e[3] - z) * (e[3] - z)))[0]


def test_a_place_gets_the_first_of_the_nearest_moves(tmp_path):
    """Moves that end at the same point give the first of them (lines 4 and 7 at X10
    Y10 Z0.3; lines 9 and 12 there 0.2 mm higher, after a relative move); a place off
    every layer gets the move nearest by height first; random places agree with a
    scan of every move."""
    job = tmp_path / "job.gcode"
    job.write_bytes(JOB)
    places = [Place("blob", 1, 10.0, 10.0, 0.3, 0.1), Place("blob", 2, 10.0, 10.0, 0.5, 0.1),
              Place("starved", 1, 20.0, 20.0, 0.3, 0.1),
              Place("starved", 3, 15.0, 10.0, 0.5, 0.1),
              Place("blob", 9, 40.0, -3.0, 3.0, 0.1)]
    rng = random.Random(7)
    places += [Place("starved", 1, rng.uniform(-5, 45), rng.uniform(-5, 25),
                     rng.uniform(0, 1.2), 0.1) for _ in range(200)]
    find_lines(job, places)
    assert [p.line for p in places[:5]] == [4, 9, 6, 10, 14]
    assert [p.line for p in places] == [nearest(JOB, p.x, p.y, p.z) for p in places]


def test_a_job_without_moves_leaves_places_unplaced(tmp_path):
    job = tmp_path / "job.gcode"
    job.write_bytes(b"M104 S200\nG90\n")
    place = Place("blob", 1, 1.0, 1.0, 0.2, 0.1)
    find_lines(job, [place])
    assert place.line is None


# The reading a job's moves are found by, as two regular expressions over text read as
# latin-1 with universal newlines: a move is G0 or G1 after any blanks and before no
# digit (up to a `;`), its X, Y and Z words a letter, blanks and a decimal number; G90
# and G91 are the first three characters after the blanks.
_MOVE = re.compile(r"^\s*G[01](?!\d)", re.I)
_WORD = re.compile(r"([XYZ])\s*([-+]?\d*\.?\d+)", re.I)


def moves_as_expressions_read(job: bytes) -> list[tuple[int, float, float, float]]:
    out, x, y, z, relative = [], 0.0, 0.0, 0.0, False
    text = job.decode("latin-1").replace("\r\n", "\n").replace("\r", "\n")
    for number, raw in enumerate(text.split("\n"), 1):
        line = raw.split(";", 1)[0]
        head = line.lstrip()[:3].upper()
        if head in ("G90", "G91"):
            relative = head == "G91"
        if not _MOVE.match(line):
            continue
        for letter, value in _WORD.findall(line):
            v, letter = float(value), letter.upper()
            if letter == "X":
                x = x + v if relative else v
            elif letter == "Y":
                y = y + v if relative else v
            else:
                z = z + v if relative else v
        out.append((number, x, y, z))
    return out


_PIECES = ["G1", "G0", "g1", "G01", "G10", "G90", "G91", "g91", "G9", "G910", " ", "\t",
           "\x85", "\xa0", "\x1c", "X", "x", "Y", "Z", "z", "E", " X1", " Y-2.5", "Z.3",
           "X+.5", "X12.", "X.", "X-", "X1e3", "X1.2.3", "X 7", "X\t-0.25", ";", "(c)",
           "M104", "1", "2.5", "-", "+", ".", "X1234567890123456.5", "Y0.000000000000001"]


@settings(max_examples=300, deadline=None)
@given(st.lists(st.lists(st.sampled_from(_PIECES), max_size=8).map("".join),
                min_size=1, max_size=40),
       st.sampled_from(["\n", "\r\n", "\r"]),
       st.lists(st.tuples(st.floats(-5, 20), st.floats(-5, 20), st.floats(0, 5)),
                min_size=1, max_size=5))
def test_moves_are_read_as_the_expressions_read_them(tmp_path_factory, lines, newline,
                                                     where):
    """Odd lines (blanks beyond ASCII, numbers cut short, words run together, codes
    that only begin like a move) are read byte by byte as the two expressions read
    them: every place gets the line a scan of the moves they find gives."""
    job = "\n".join(lines).replace("\n", newline).encode("latin-1")
    path = tmp_path_factory.mktemp("job") / "job.gcode"
    path.write_bytes(job)
    places = [Place("blob", 1, x, y, z, 0.1) for x, y, z in where]
    find_lines(path, places)
    ends = moves_as_expressions_read(job)
    for place in places:
        if not ends:
            assert place.line is None
            continue
        dist = [(e[1] - place.x) * (e[1] - place.x) + (e[2] - place.y) * (e[2] - place.y)
                + 100.0 * ((e[3] - place.z) * (e[3] - place.z)) for e in ends]
        assert place.line == ends[dist.index(min(dist))][0]


@settings(max_examples=500, deadline=None)
@given(st.one_of(st.floats(allow_nan=False), st.integers(-10**6, 10**6).map(lambda n: n / 200),
                 st.sampled_from([0.0, -0.0, 0.005, -0.005, 2.675, 1.005, 1e-9, -1e-9])))
def test_heights_are_rounded_as_round_rounds_them(value):
    """A layer's height is round(z, 2), halves and the sign of zero as round() has them
    (the record's heights are rounded natively where that cannot differ)."""
    from robox.sim.quality import _round2

    got, expected = _round2(value), round(value, 2)
    assert got == expected and math.copysign(1.0, got) == math.copysign(1.0, expected)


@settings(max_examples=500, deadline=None)
@given(st.lists(st.sampled_from([b"G1 X1", b"\r", b"\n", b"\r\n", b"\r\r", b"\n\r", b";c",
                                 b" ", b"Z2", b"\x85", b"\x0b", b"\x0c"]),
                max_size=30).map(b"".join), st.integers(1, 9))
def test_a_jobs_lines_are_the_lines_text_with_universal_newlines_reads(tmp_path_factory,
                                                                        job, block):
    """find_lines reads a job's lines from its bytes a block at a time: line for line,
    the lines a text file with universal newlines (latin-1) gives, each with its own
    line end (text mode makes each an LF), for any mix of CR, CR LF and LF, a CR at the
    end of the file or of a block, and bytes that some readers take for line ends (NEL,
    VT, FF) but universal newlines does not; blocks of a few bytes put every line and
    every CR LF across their edges."""
    from robox.sim.quality import job_lines

    path = tmp_path_factory.mktemp("job") / "job.gcode"
    path.write_bytes(job)
    with open(path, "rb") as f:
        ours = list(job_lines(f, block))
    with open(path, encoding="latin-1", newline=None) as f:
        text_mode = [line.encode("latin-1") for line in f]
    assert b"".join(ours) == job
    as_text_mode = [line[:-2] + b"\n" if line.endswith(b"\r\n") else
                    line[:-1] + b"\n" if line.endswith(b"\r") else line for line in ours]
    assert as_text_mode == text_mode


def test_a_job_with_cr_line_ends_is_read_a_block_at_a_time(tmp_path):
    """A Robox job's lines end in CR alone: read a block at a time, never the whole job
    as one line, and each line's end is kept."""
    from robox.sim.quality import job_lines

    path = tmp_path / "job.gcode"
    path.write_bytes(b"".join(b"G1 X%d Y1\r" % k for k in range(20000)))
    with open(path, "rb") as f:
        lines = job_lines(f, 4096)
        first = next(lines)
        assert first == b"G1 X0 Y1\r"
        assert f.tell() == 4096  # one block read for the first line, not the whole job
        rest = list(lines)
    assert len(rest) == 19999 and rest[-1] == b"G1 X19999 Y1\r"
