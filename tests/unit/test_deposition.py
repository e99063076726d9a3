"""Where the plastic lands (src/robox/hardware/deposition.py), on the real machine model.

Volumes are worked out here from the machine's own constants: 747 E microsteps per mm
of 1.75 mm filament, 2,500 B microsteps per valve unit, the RBX01-SM's 0.3 mm3 stroke on
nozzle 0 and a calibrated seat at B 0.65.
"""

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from robox.formats.heads import head_valves
from robox.hardware.deposition import COLUMNS, PRESSURE_LIMIT_MM3, STANDING_MM, Deposition
from robox.hardware.machine import NOZZLE_MM, B, E, Machine, X, Y

MM3_PER_STEP = math.pi * 1.75 * 1.75 / 4 / 747
SEAT = 0.65
STROKE = 0.3
B_UNIT = 2500


def machine(seat_b: bool = True) -> tuple[Machine, Deposition]:
    m = Machine()
    m.heaters["nozzle0"].temperature = 210.0
    m.insert_filament(E, tip_mm=NOZZLE_MM)  # loaded up to the nozzle
    if seat_b:
        m.b = round(SEAT * B_UNIT)  # the valve shut on nozzle 0's seat
    dep = Deposition(head_valves("RBX01-SM"), (1.75, 1.75), (SEAT, -0.70))
    dep.attach(m)
    return m, dep


def rows(dep: Deposition) -> list[dict]:
    r = dep.rows
    return [{name: r[name][i] for name in r} for i in range(len(r["x0"]))]


def test_a_valve_shut_standing_leaves_its_stroke_as_a_blob():
    m, dep = machine()
    m.step(B, B_UNIT)  # open standing: a void of a stroke
    m.step(E, 93)  # the refill: into the void, nothing leaves
    for _ in range(1337):  # 10 mm along X, feeding evenly
        m.step(X, 1)
        if m.x % 4 == 0:
            m.step(E, 1)
    m.step(B, -B_UNIT)  # shut standing still
    dep.finish()
    out = rows(dep)
    refill = out[0]
    assert refill["x0"] == refill["x1"] and refill["deposited"] == 0
    assert refill["driven"] == pytest.approx(93 * MM3_PER_STEP)
    line = [r for r in out if r["x1"] - r["x0"] >= STANDING_MM]
    fed = (1337 // 4) * MM3_PER_STEP
    # 93 steps filled 0.2994 of the 0.3 void: the line's first plastic finishes it
    assert sum(r["deposited"] for r in line) == pytest.approx(fed - (STROKE - 93 * MM3_PER_STEP))
    blob = out[-1]  # (where the last feed step was: 1336 X steps)
    assert blob["x1"] - blob["x0"] < STANDING_MM and blob["x1"] == pytest.approx(10.0)
    assert blob["deposited"] == pytest.approx(STROKE)
    assert dep.paths[0].closed and dep.paths[0].end[0] == pytest.approx(10.0)


def test_an_open_without_a_refill_starves_the_paths_first_millimetres():
    m, dep = machine()
    m.step(B, B_UNIT)  # no refill: the void takes the first 0.3 mm3 of the line
    per_x = 0.05  # mm3 per X step: the line lays 0.05 * 133.7 mm3/mm
    steps = round(per_x / MM3_PER_STEP)
    for _ in range(200):
        m.step(X, 1)
        m.step(E, steps)
    dep.finish()
    starved = [r for r in rows(dep) if r["x1"] > r["x0"] and r["deposited"] < 0.8 * r["driven"]]
    length = sum(r["x1"] - r["x0"] for r in starved)
    # the void is full after 0.3 / (steps * MM3_PER_STEP) X steps
    assert length == pytest.approx(STROKE / (steps * MM3_PER_STEP) / 133.7, abs=1.5 / 133.7)


def test_a_shut_head_fills_to_its_limit_then_the_drive_slips_and_opening_lets_it_out():
    m, dep = machine()
    m.step(E, 1000)  # against the shut needle
    taken = math.floor(PRESSURE_LIMIT_MM3 / MM3_PER_STEP)
    assert m.wheel_passed[E] == taken and m.extruded[E] == taken
    assert dep.slipped_steps == 1000 - taken
    m.step(B, B_UNIT)
    dep.finish()
    out = rows(dep)
    assert out[-1]["deposited"] == pytest.approx(taken * MM3_PER_STEP - STROKE)


@pytest.mark.parametrize("seat", [0.65, -0.70])
def test_a_needle_on_its_seat_is_shut_though_the_seat_is_a_float32(seat):
    # The seats are the head EEPROM's float32 B offsets: -0.70 is -0.699999988, and the
    # needle parked on it (-1,750 microsteps, -0.7 exactly) is 1.2e-8 of a unit short of
    # it. That is shut: pressurising against it fills the head and the drive slips.
    import struct

    seat32 = struct.unpack("<f", struct.pack("<f", seat))[0]
    assert seat32 != seat
    m = Machine()
    m.heaters["nozzle0"].temperature = m.heaters["nozzle1"].temperature = 210.0
    m.insert_filament(E, tip_mm=NOZZLE_MM)
    m.b = round(seat * B_UNIT)
    seats = (seat32, -0.70) if seat > 0 else (0.65, seat32)
    dep = Deposition(head_valves("RBX01-SM"), (1.75, 1.75), seats)
    dep.attach(m)
    assert list(dep.opening) == [0.0, 0.0]
    m.step(E, 1000)
    assert dep.slipped_steps == 1000 - math.floor(PRESSURE_LIMIT_MM3 / MM3_PER_STEP)
    m.step(B, 1 if seat > 0 else -1)  # a microstep off the seat: open
    assert max(dep.opening) == pytest.approx(1 / B_UNIT, abs=1e-7)


def test_a_close_on_the_move_lays_its_stroke_along_the_path():
    m, dep = machine()
    m.step(B, B_UNIT)
    m.step(E, 93)
    for _ in range(B_UNIT):  # B from 1 to 0 over 2,500 X steps: 0.3 mm3 over 18.7 mm
        m.step(X, 1)
        m.step(B, -1)
    dep.finish()
    line = [r for r in rows(dep) if r["x1"] > r["x0"]]
    assert sum(r["deposited"] for r in line) == pytest.approx(STROKE - (STROKE - 93 * MM3_PER_STEP))
    assert not [r for r in rows(dep) if r["x1"] == r["x0"] and r["deposited"] >= 0.01]
    assert len(line) <= 3  # one straight stretch (and the void's end)


moves = st.lists(st.tuples(st.sampled_from([X, Y, E, B]), st.integers(-40, 60)),
                 max_size=200)


@settings(max_examples=150, deadline=None)
@given(moves)
def test_watching_changes_nothing_while_the_head_is_not_full_and_plastic_is_kept(steps):
    """With the needle kept off its seat (no pressure can build), a machine with the
    record attached ends exactly where one without it does; and what the record laid
    down is what was fed and pushed, less the voids the needle opened and still open."""
    plain, _ = machine()
    plain.deposition = None
    watched, dep = machine()
    for m in (plain, watched):
        m.b = round((SEAT + 0.5) * B_UNIT)  # half open
    dep.attach(watched)
    pushed = opened = 0.0
    b = watched.b

    def opening(v: int) -> float:
        return min(1.0, max(0.0, v / B_UNIT - SEAT))

    for axis, n in steps:
        if axis == B:
            n = max(round((SEAT + 0.05) * B_UNIT) - b, min(round((SEAT + 1.2) * B_UNIT) - b, n))
            before, after = opening(b), opening(b + n)
            pushed += max(0.0, before - after) * STROKE
            opened += max(0.0, after - before) * STROKE
            b += n
        plain.step(axis, n)
        watched.step(axis, n)
    dep.finish()
    for name in ("x", "y", "b", "extruded", "wheel_passed"):
        assert getattr(plain, name) == getattr(watched, name), name
    assert plain.filament[E] == watched.filament[E]
    fed = watched.extruded[E] * MM3_PER_STEP
    laid = sum(dep.rows["deposited"])
    assert laid == pytest.approx(fed + pushed - opened + dep.void[0], abs=1e-9)


def test_rows_spilled_to_a_file_read_back_as_kept_in_memory(tmp_path, monkeypatch):
    """With a spill file the record keeps only its newest row in memory past a bound,
    and reads back every row, in order, as one kept wholly in memory does."""
    import robox.hardware.deposition as deposition

    def draw(m: Machine) -> None:
        m.step(B, B_UNIT)
        for i in range(600):  # a zigzag: a row per leg
            m.step(X if (i // 20) % 2 else Y, 1 if (i // 40) % 2 else -1)
            m.step(E, 2)
        m.step(B, -B_UNIT)

    kept_m, kept = machine()
    draw(kept_m)
    kept.finish()
    monkeypatch.setattr(deposition, "SPILL_ROWS", 3)
    spilled_m, spilled = machine()
    spilled.spill = str(tmp_path / "rows")
    draw(spilled_m)
    spilled.finish()
    assert spilled.spilled > 10 and len(spilled.rows["x0"]) <= 4
    # kept wholly in memory, the rows are its columns side by side
    in_memory = list(zip(*(kept.rows[name] for name in COLUMNS), strict=True))
    assert len(in_memory) > 10 and list(kept.iter_rows()) == in_memory
    assert list(spilled.iter_rows()) == list(kept.iter_rows())
    # the same rows as chunks of columns, spilled or kept (what Quality walks)
    for dep in (spilled, kept):
        chunks = [[list(column) for column in chunk] for chunk in dep.iter_columns()]
        assert all(len(chunk) == 9 and len({len(c) for c in chunk}) == 1 for chunk in chunks)
        walked = [row for chunk in chunks for row in zip(*chunk, strict=True)]
        assert walked == list(kept.iter_rows())
    assert len(list(spilled.iter_columns())) > 3  # chunks read back from the file


# Places on the machine's microstep grid (133.7 per mm), and joints on, beside and
# exactly STRAIGHT_MM off the line between them.
_PLACE = st.integers(0, 200 * 134).map(lambda n: n / 133.7)


@settings(max_examples=600, deadline=None)
@given(_PLACE, _PLACE, _PLACE, _PLACE, st.floats(0.0, 1.0),
       st.sampled_from([0.0, 1e-3, 0.01, -0.01, 0.0100001, 0.05]),
       st.floats(0.0, 2.0), st.floats(0.0, 2.0))
def test_joints_and_lumps_are_judged_as_with_math_hypot(px, py, qx, qy, t, off, dep0,
                                                          dep1):
    """A stretch joins the row before on the same judgements as with math.hypot's
    lengths (the record takes them from a native square root, and math.hypot only where
    the two could disagree)."""
    from robox.hardware import deposition

    jx, jy = px + (qx - px) * t + off, py + (qy - py) * t
    dx, dy = qx - px, qy - py
    if (px == jx and py == jy) or (jx == qx and jy == qy):
        straight = px == jx and py == jy and jx == qx and jy == qy
    elif (jx - px) * dx + (jy - py) * dy <= 0.0 or (qx - jx) * dx + (qy - jy) * dy < 0.0:
        straight = False
    else:
        straight = abs((jx - px) * dy - (jy - py) * dx) \
            <= deposition.STRAIGHT_MM * math.hypot(dx, dy)
    assert deposition._straight(px, py, jx, jy, qx, qy) == straight
    bound = 4.0 * dep0 * math.hypot(qx - jx, qy - jy) / max(math.hypot(jx - px, jy - py),
                                                            1e-9) + deposition.BLOB_MM3
    for laid in (dep1, bound, math.nextafter(bound, 0.0), math.nextafter(bound, 9.0)):
        assert deposition._no_lump(dep0, laid, px, py, jx, jy, qx, qy) == (laid <= bound)


def test_quality_judges_the_paths_opened_once_the_record_judges():
    """A path opened while the record is told not to judge (a start sequence's purge) is
    left out of the figures, whatever its number; the paths after it are judged."""
    from robox.sim.quality import Quality

    m, dep = machine()

    def purge_at(x_steps: int) -> None:
        m.x, m.y = x_steps, 2674  # (20 mm in)
        m.step(B, B_UNIT)  # open standing
        m.step(E, 400)  # the refill, then plastic left standing: a blob
        m.step(B, -B_UNIT)

    dep.judging = False
    purge_at(2674)  # the first path, at X 20 mm: not judged
    dep.judging = True
    purge_at(4011)  # at X 30 mm
    purge_at(5348)  # at X 40 mm
    dep.finish()
    assert [p.judged for p in dep.paths] == [False, True, True]
    quality = Quality(dep, [(0.0, 0.0, 0.0)] * 2, (210.0, 150.0))
    figures, places = quality.figures()
    assert figures["blobs"] == 2
    assert sorted(round(place.x) for place in places) == [30, 40]
    # rows() leaves the first path out too: travels (-1) and the judged paths are left
    judged = {p.number for p in dep.paths if p.judged}
    assert len(judged) == 2 and {path for *_, path in quality.rows()} == {-1} | judged


def test_the_layers_are_every_height_plastic_was_laid_at_in_any_order():
    """Quality's layers are the heights the plate's plastic was laid at (to 0.01 mm),
    whether a height repeats row after row or comes back after another; each place's
    layer is its height's place among them."""
    from robox.sim.quality import Quality

    m, dep = machine()
    heights_mm = [0.2, 0.2, 0.45, 0.2, 0.7, 0.45]
    for k, z in enumerate(heights_mm):
        m.za = m.zb = round(z * 6400)
        m.x, m.y = 2674 + 1337 * k, 2674  # X 20 mm, then 10 mm apart
        m.step(B, B_UNIT)  # open standing, refill, plastic left standing: a blob
        m.step(E, 400)
        m.step(B, -B_UNIT)
    dep.finish()
    quality = Quality(dep, [(0.0, 0.0, 0.0)] * 2, (210.0, 150.0))
    distinct = sorted(set(heights_mm))
    assert quality.layers == distinct
    figures, places = quality.figures()
    assert figures["layers"] == len(distinct) and figures["blobs"] == len(heights_mm)
    for place in places:  # (the worst five: all alike, so the first five)
        k = round((place.x - 20.0) / 10.0)
        assert place.layer == distinct.index(heights_mm[k]) + 1


@settings(max_examples=200, deadline=None)
@given(st.sampled_from(["RBX01-SM", "RBX01-DM"]),
       st.lists(st.tuples(st.sampled_from([B, E]), st.integers(-3000, 3000)), max_size=30))
def test_the_open_nozzle_kept_for_each_feed_follows_the_needles(head, runs):
    """The feed steps ask which nozzle of their feed is open (the first whose needle is off
    its seat): kept as the needles move, it is what the openings say after every run."""
    m = Machine()
    m.heaters["nozzle0"].temperature = m.heaters["nozzle1"].temperature = 210.0
    m.insert_filament(E, tip_mm=NOZZLE_MM)
    m.b = round(SEAT * B_UNIT)
    dep = Deposition(head_valves(head), (1.75, 1.75), (SEAT, -0.70))
    dep.attach(m)
    for axis, n in runs:
        if axis == E and n < 0:
            n = -n  # fed, so that the plastic and the needle move in one run
        m.step(axis, n)
        for feed in (E, E + 1):
            nozzles = [k for k in range(len(dep.opening))
                       if dep.feed_axis[k] == feed and dep.opening[k] > 0.0]
            assert dep._open_nozzle(feed) == (nozzles[0] if nozzles else -1)


@settings(max_examples=500, deadline=None)
@given(st.floats(-1000.0, 1000.0), st.floats(-0.02, 0.02))
def test_heights_in_a_rounded_height_s_band_round_as_it_does(z, dz):
    """_round2_band: every height whose product with 100 is strictly inside the band of
    another's rounds (_round2, round(value, 2)) as that one does."""
    from robox.sim.quality import _round2, _round2_band

    low, high = _round2_band(z * 100.0)
    other = z + dz
    for near in (other, low / 100.0, high / 100.0, math.nextafter(low, 0.0) / 100.0):
        if low < near * 100.0 < high:
            assert _round2(near) == _round2(z) == round(z, 2)


def test_the_layers_on_a_tilted_gantry_are_each_row_s_height_rounded():
    """On a gantry whose two ends stand at different heights the nozzle's height follows
    the carriage by fractions of a microstep, so hardly a row repeats another's height
    exactly: the layers are still every row's height rounded to 0.01 mm (merged as
    close ones are), as working each one out gives."""
    from robox.sim.quality import LAYER_MERGE_MM, Quality, _round2

    m, dep = machine()
    for k in range(60):
        base = round((0.2 + 0.15 * (k // 12)) * 6400)
        m.za, m.zb = base, base + 37 + k % 5  # the gantry's right end higher
        m.x, m.y = 2674 + 400 * k, 2674 + 90 * (k % 7)
        m.step(B, B_UNIT)
        m.step(E, 400)
        m.step(X, 300)
        m.step(E, 200)
        m.step(B, -B_UNIT)
    dep.finish()
    quality = Quality(dep, [(0.0, 0.0, 0.0)] * 2, (210.0, 150.0))
    heights = sorted({_round2(z) for _, _, x1, y1, z, dep_mm3, *_ in quality.rows()
                      if dep_mm3 > 0.0 and quality.on_plate(x1, y1)})
    assert len(heights) > 5
    expected: list[float] = []
    for z in heights:
        if not expected or z - expected[-1] > LAYER_MERGE_MM:
            expected.append(z)
    assert quality.layers == expected
