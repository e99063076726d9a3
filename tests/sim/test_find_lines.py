"""Which job line a place in the deposition record comes from (quality.find_lines)."""

import random

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
    return min(ends(job), key=lambda e: (e[1] - x) ** 2 + (e[2] - y) ** 2
               + 100.0 * (e[3] - z) ** 2)[0]


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
