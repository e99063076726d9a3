"""Where the plastic lands: the needle valve and the feeds, seen as plastic.

A part of the simulated machine that only watches: attached to a `Machine`
(`machine.deposition`), it hears of every microstep run the firmware makes and keeps a
record of what those steps did to the plastic. Nothing the firmware reads changes,
with one exception that is the physics of a shut valve (below); a machine without one
attached (the served printer, the conformance replays) runs exactly as before and pays
one `None` test per motor call.

The model, per nozzle n (figures from `robox.formats.heads`):

- The needle's opening is o = (B - seat) clamped to 0..1 for nozzle 0 (it opens on
  the positive side of the B switch) and (seat - B) for nozzle 1, in the firmware's B
  units (2,500 microsteps each); a head leaves calibration with its EEPROM's B offsets
  at the seats, so the job's B 0 is shut and B 1 open.
- Closing from o to o' pushes out (o - o') x ejection(n) mm3 where the head is; it
  first takes up any void still below the needle. Opening from o to o' leaves a void
  of (o' - o) x ejection(n), which the next plastic to reach the nozzle fills before
  any leaves it.
- Plastic fed (filament past the nozzle's end, `Machine._drive`) leaves through the
  open nozzle of its feed, where the head is at that moment, void first. With every
  nozzle of its feed shut it is held under pressure in the head; an opening lets it
  out, void first. Past `PRESSURE_LIMIT_MM3` a shut head takes no more: the drive slips
  (what G36 pressurising waits for); filament drawn back relieves it.

Positions: the plastic of each event (a feed's steps, a needle's move) is laid along
the line from where the head stood at the event before to where it stands now, when
that is no further than `ANCHOR_MM` (the steps of one move interleave: X, Y, the feed
and the needle step at their own moments along it); a path's first plastic is laid from
where its valve opened; otherwise the plastic lands where the head is. Plastic
that comes while the head stands waits there: when the head moves on it is laid along
with the next, unless it is a blob (`BLOB_MM3` or more) or a void took it while the
head stood (a refill): those stay a row of their own, a point.

The record, in machine millimetres (`rows`), one row per stretch: start and end X and
Y, nozzle height, mm3 deposited and mm3 driven into the nozzle for it (fed by the
extruder or pushed by the needle), nozzle and path number; travels between plastic (-1
for the path) as rows of their own. A path runs from an opening of a shut valve to its
close (on a head without a valve: from the first plastic to a travel). A stretch that
carries on straight from the last row (its joint within `STRAIGHT_MM` of the line) and
delivers alike (the deposited share of what was driven within 5%) is merged into it, so
the record grows with the job's paths and turns, not with its microsteps; given a
`spill` file, all but the newest rows go there, and memory stays flat in the job's size.
The newest row, the one a stretch may still merge into, is held in plain attributes
(read and merged natively when compiled); when the next row starts it joins the
columns, packed vectors of native floats (`rows` shows them by name).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import TYPE_CHECKING, Final

from robox.formats.heads import E_FEED, HeadValves
from robox.packed import append, floats_from_bytes, floats_to_bytes, i64, vec

if TYPE_CHECKING:
    from robox.hardware.machine import Machine

B_STEPS: Final = 2500.0
SEATED: Final = 0.5 / B_STEPS  # a needle nearer its seat than this (B units) is shut
XY_STEPS: Final = 133.7
Z_STEPS: Final = 6400.0
E_STEPS: Final = 747.0
E_AXIS: Final = 3
D_AXIS: Final = 4
#: mm3 a shut head takes under pressure before its drive slips.
PRESSURE_LIMIT_MM3: Final = 1.0
#: A stretch shorter than this (mm) that leaves BLOB_MM3 or more is plastic left with
#: the head standing (the steps of one move end within a microstep or two of each other).
STANDING_MM: Final = 0.05
#: Plastic left standing still that makes a blob (less is the tail of a move's steps).
BLOB_MM3: Final = 0.01
#: Plastic further than this (mm) from the last plastic lands where the head is; with
#: a valve, a path's plastic is followed from its open (a thin line's feed steps are
#: far apart), without one a travel is told only by the distance.
ANCHOR_MM: Final = 5.0
ANCHOR_PLAIN_MM: Final = 1.0
#: Heights this close (mm) are one for merging: on a levelled gantry the nozzle's
#: height follows the carriage's X by fractions of a microstep.
SAME_Z_MM: Final = 0.005
#: How far (mm) a joint may stand off the line for two stretches to be merged.
STRAIGHT_MM: Final = 0.01
#: A comparison with a length worked out as _near_hypot() does, not math.hypot(), is
#: trusted when the sides differ by more than this share of it.
NEAR: Final = 1e-9
#: The steps a valve move and the plastic fed in the same run of steps are taken in.
INTERLEAVE: Final = 16
#: Rows kept in memory before the older ones go to the spill file, where there is one
#: (not Final: a test makes it small).
SPILL_ROWS = 1 << 16
#: Rows: x0, y0, x1, y1, z, deposited, driven, nozzle, path (-1: a travel).
COLUMNS = ("x0", "y0", "x1", "y1", "z", "deposited", "driven", "nozzle", "path")


class Path:
    def __init__(self, number: int, nozzle: int, z: float, start: tuple[float, float],
                 judged: bool = True) -> None:
        self.number = number
        self.nozzle = nozzle
        self.z = z
        self.start = start
        self.end = (math.nan, math.nan)
        self.closed = False
        self.judged = judged  # False: opened while the record was told not to judge


class Deposition:
    """The record of where plastic went (see the module's docstring)."""

    def __init__(self, valves: HeadValves, diameters_mm: tuple[float, float],
                 seats: tuple[float, float] = (0.0, 0.0), *, recording: bool = True,
                 spill: str | None = None) -> None:
        self.valves = valves
        self.diameters_mm = diameters_mm  # filament of feed E, feed D
        self.seats = seats  # B where nozzle 0, nozzle 1 shut
        self.paths: list[Path] = []
        self.recording = recording  # False: the valve's and the pressure's physics, no record
        self.spill = spill  # a file the older rows go to (None: all kept in memory)
        nozzles = len(self.valves.feeds)
        # a plain attribute: looked at on every valve step (a property of the frozen
        # table would be a call into interpreted code from the compiled machine)
        self.has_valve = self.valves.has_valve
        # per nozzle and per feed, packed vectors (compiled, read and written natively on
        # every valve and feed step, where a list's item is a boxed number)
        self.opening = vec[float]([0.0 if self.has_valve else 1.0] * nozzles)
        self.void = vec[float]([0.0] * nozzles)
        # (per feed, indexed by its axis, E or D, the places before unused: where a
        # dict would be looked up; the frozen table's figures copied, where its
        # attributes are an interpreted object's)
        self.pressure = vec[float]([0.0] * (D_AXIS + 1))
        self.feed_axis = vec[i64]([E_AXIS if f == E_FEED else D_AXIS
                                   for f in self.valves.feeds])
        # per feed, its nozzle whose needle is off its seat (-1: all shut): asked at every
        # feed step, it changes only when a needle moves (_note_openings)
        self._open_of = vec[i64]([-1] * (D_AXIS + 1))
        self.mm3_per_step = vec[float]([0.0] * (D_AXIS + 1))
        for axis, d in ((E_AXIS, self.diameters_mm[0]), (D_AXIS, self.diameters_mm[1])):
            self.mm3_per_step[axis] = math.pi * d * d / 4.0 / E_STEPS
        self.ejection_mm3 = vec[float]([float(v) for v in self.valves.ejection_mm3])
        self.seat = vec[float]([float(self.seats[0]), float(self.seats[1])])
        self.path_of = vec[i64]([-1] * nozzles)  # the open path of each nozzle
        self.b = 0
        # where the last plastic left (two floats: compiled, native, where a tuple's
        # are boxed and compared generically)
        self._ax = self._ay = 0.0
        self.judging = True  # whether paths opened now count (a purge before a job: no)
        # deposited, driven, swallowed since the head moved
        self._pending = vec[float]([0.0, 0.0, 0.0])
        self._pending_z = 0.0  # the nozzle's height when it came
        self._nozzle = self._path = -1
        self.shut_fed_mm3 = 0.0  # fed into a head with its feed's nozzles shut
        self.feed_waiting = False  # plastic fed in the run of steps under way
        self.spilled = 0  # rows in the spill file
        # the newest row, not yet in `rows` (see the module's docstring)
        self._has_last = False
        self._lx0 = self._ly0 = self._lx1 = self._ly1 = self._lz = 0.0
        self._ldep = self._ldrv = 0.0
        self._lnozzle = self._lpath = 0
        self._feed_axis = E_AXIS
        self._feed_mm3 = 0.0
        self.slipped_steps = 0
        self.released_mm3 = vec[float]([0.0] * nozzles)  # plastic that has left each nozzle
        # (the methods last: compiled, an attribute assigned before self is first passed
        # on is known to be set, and read without a test)
        self._note_openings()
        # the columns, in COLUMNS' order: packed vectors in attributes of their own
        # (compiled, an append is native; an array's is a generic method call, and a
        # vector kept in a list or dict is boxed)
        self._empty_columns()

    # ------------------------------------------------------------ machine calls
    def attach(self, machine: Machine) -> None:
        """Start watching `machine` (its valve and head where they are now)."""
        self.machine = machine
        self.b = machine.b
        self._ax, self._ay = machine.x / XY_STEPS, machine.y / XY_STEPS
        self._set_openings(machine.b, record=False)
        machine.deposition = self

    def fed(self, axis: int, steps: int) -> int:
        """`steps` of filament reach the nozzle end of feed `axis`; how many it takes
        (fewer when a shut head is full). The plastic waits for the rest of the run of
        steps (`feed_waiting`): a valve step in the same run moves with it."""
        self.flush_feed()
        mm3 = steps * self.mm3_per_step[axis]
        if self._open_nozzle(axis) < 0:
            room = PRESSURE_LIMIT_MM3 - self.pressure[axis]
            if mm3 > room:
                taken = max(0, int(room / self.mm3_per_step[axis]))
                self.slipped_steps += steps - taken
                steps = taken
                mm3 = taken * self.mm3_per_step[axis]
        self._feed_axis = axis
        self._feed_mm3 = mm3
        self.feed_waiting = mm3 > 0.0
        return steps

    def flush_feed(self) -> None:
        """The waiting plastic, now (the run of steps it came in is over)."""
        if self.feed_waiting:
            self.feed_waiting = False
            self._feed(self._feed_axis, self._feed_mm3)

    def drawn_back(self, axis: int, steps: int) -> None:
        """The feed `axis` draws its filament back: what the head held under pressure
        goes with it."""
        self.flush_feed()
        held = self.pressure[axis]
        if held > 0.0:
            self.pressure[axis] = max(0.0, held - steps * self.mm3_per_step[axis])

    def valve(self, b: int) -> None:
        """The valve's motor now stands at `b` microsteps. Plastic fed in the same run
        of steps came while the needle moved: the two are taken together, a little of
        each at a time (the void an opening leaves filling as it opens)."""
        if self.feed_waiting:
            self.feed_waiting = False
            axis, mm3 = self._feed_axis, self._feed_mm3
            # (native integers: compiled, a generic product of two ints costs ten times)
            start: i64 = self.b
            span: i64 = b - start
            for k in range(1, INTERLEAVE + 1):
                self._set_openings(start + span * k // INTERLEAVE, record=True)
                self._feed(axis, mm3 / INTERLEAVE)
        self.b = b
        self._set_openings(b, record=True)

    def _open_nozzle(self, axis: i64) -> i64:
        """The nozzle of feed `axis` whose needle is off its seat (-1: all shut)."""
        return self._open_of[axis]

    def _note_openings(self) -> None:
        """_open_nozzle's answers, after a needle has moved: for each feed, the first of
        its nozzles that is open."""
        feeds, opening, open_of = self.feed_axis, self.opening, self._open_of
        open_of[E_AXIS] = open_of[D_AXIS] = -1
        n: i64
        for n in range(len(feeds) - 1, -1, -1):  # (backwards: the first one is kept)
            if opening[n] > 0.0:
                open_of[feeds[n]] = n

    def _feed(self, axis: int, mm3: float) -> None:
        n = self._open_nozzle(axis)
        if n >= 0:
            self._out(n, mm3, mm3)
            return
        self.pressure[axis] += mm3
        self.shut_fed_mm3 += mm3

    # ------------------------------------------------------------ the plastic
    def _set_openings(self, b: int, record: bool) -> None:
        if not self.has_valve:
            return
        units = b / B_STEPS
        seat = self.seat
        for n in range(len(self.opening)):
            o = units - seat[0] if n == 0 else seat[1] - units
            # short of half a microstep off its seat a needle is on it (a seat is the
            # EEPROM's float32, the needle's place whole microsteps)
            o = 0.0 if o < SEATED else 1.0 if o > 1.0 else o
            before = self.opening[n]
            if o == before:
                continue
            self.opening[n] = o
            if (o > 0.0) != (before > 0.0):  # off its seat, or back on it
                self._note_openings()
            if not record:
                continue
            ejection = self.ejection_mm3[n]
            if o < before:  # closing: the needle pushes plastic out
                push = (before - o) * ejection
                self._out(n, push, push)
                if o == 0.0:
                    self._close_path(n)
            else:  # opening: a void, then what the head held under pressure
                if before == 0.0:
                    self._open_path(n)
                self.void[n] += (o - before) * ejection
                axis = self.feed_axis[n]
                held = self.pressure[axis]
                if held > 0.0:
                    self.pressure[axis] = 0.0
                    self._out(n, held, held)

    def _out(self, n: int, mm3: float, driven: float) -> None:
        """`mm3` reaches nozzle n's outlet: it fills the void first, the rest leaves,
        laid from the last plastic's place to the head's."""
        void = self.void[n]
        swallowed = mm3 if mm3 < void else void
        self.void[n] = void - swallowed
        self.released_mm3[n] += mm3 - swallowed
        if not self.recording:
            return
        m = self.machine
        hx, hy = m.x / XY_STEPS, m.y / XY_STEPS  # here
        sx, sy = self._ax, self._ay  # the start
        reach = ANCHOR_MM if self.has_valve else ANCHOR_PLAIN_MM
        if (sx != hx or sy != hy) and (abs(hx - sx) > reach or abs(hy - sy) > reach):
            self._standing()  # what was left where the head stood
            self._row(sx, sy, hx, hy, m.nozzle_height() / Z_STEPS, 0.0, 0.0, -1, -1)
            if not self.has_valve:  # without a valve, a travel ends the paths
                for k in range(len(self.path_of)):
                    self._close_path(k)
            sx, sy = hx, hy
        if self.path_of[n] < 0:  # plastic on a head without a valve starts a path
            self._open_path(n)
        self._ax, self._ay = hx, hy
        self._nozzle, self._path = n, self.path_of[n]
        pending = self._pending
        if sx == hx and sy == hy:  # the head has not moved since the last plastic: it waits
            if pending[1] <= 0.0:
                self._pending_z = m.nozzle_height() / Z_STEPS
            pending[0] += mm3 - swallowed
            pending[1] += driven
            pending[2] += swallowed
            return
        if pending[0] >= BLOB_MM3 or pending[2] > 0.0:
            # what waited was left standing: a blob, or a refill the void took
            self._ax, self._ay = sx, sy
            self._standing()
            self._ax, self._ay = hx, hy
        pending[0] += mm3 - swallowed
        pending[1] += driven
        pending[2] += swallowed
        z = m.nozzle_height() / Z_STEPS
        dep, drv, swallowed = pending[0], pending[1], pending[2]
        pending[0] = pending[1] = pending[2] = 0.0
        path = self.path_of[n]
        if swallowed > 0.0 and dep > 0.0:
            # the void takes the stretch's first plastic: split where it is full
            f = swallowed / (swallowed + dep)
            mx, my = sx + (hx - sx) * f, sy + (hy - sy) * f
            self._row(sx, sy, mx, my, z, 0.0, drv * f, n, path)
            self._row(mx, my, hx, hy, z, dep, drv * (1.0 - f), n, path)
        else:
            self._row(sx, sy, hx, hy, z, dep, drv, n, path)

    def _standing(self) -> None:
        """The plastic that waited at the last place: a row of its own where it counts
        (a blob, a refill the void took), otherwise added to the row before."""
        pending = self._pending
        dep, drv, swallowed = pending[0], pending[1], pending[2]
        if drv <= 0.0 and dep <= 0.0:
            return
        pending[0] = pending[1] = pending[2] = 0.0
        z = self._pending_z
        ax, ay = self._ax, self._ay
        if dep < BLOB_MM3 and swallowed <= 0.0 and self._has_last and \
                self._lpath == self._path and self._lx1 == ax and self._ly1 == ay:
            self._ldep += dep
            self._ldrv += drv
            return
        self._row(ax, ay, ax, ay, z, dep, drv, self._nozzle, self._path)

    def finish(self) -> None:
        """Close the record: the plastic still waiting where the head stands, and the
        newest row into the columns."""
        self.flush_feed()
        self._standing()
        self._keep_last()

    def _empty_columns(self) -> None:
        self._cx0 = vec[float]()
        self._cy0 = vec[float]()
        self._cx1 = vec[float]()
        self._cy1 = vec[float]()
        self._cz = vec[float]()
        self._cdep = vec[float]()
        self._cdrv = vec[float]()
        self._cnozzle = vec[float]()
        self._cpath = vec[float]()

    @property
    def rows(self) -> dict[str, vec[float]]:
        """The rows in memory, a column for each name of COLUMNS (the newest apart until
        finish(); with a spill file, those not yet spilled)."""
        return dict(zip(COLUMNS, self._column_list(), strict=True))

    def _column_list(self) -> list[vec[float]]:
        return [self._cx0, self._cy0, self._cx1, self._cy1, self._cz, self._cdep,
                self._cdrv, self._cnozzle, self._cpath]

    def _open_path(self, n: int) -> None:
        if not self.recording:
            self.path_of[n] = 0
            return
        m = self.machine
        self._standing()
        hx, hy = m.x / XY_STEPS, m.y / XY_STEPS
        if self.has_valve and (self._ax != hx or self._ay != hy):  # a travel
            self._row(self._ax, self._ay, hx, hy, m.nozzle_height() / Z_STEPS, 0.0, 0.0, -1,
                      -1)
        self._ax, self._ay = hx, hy  # a new path's plastic is laid from where it opened
        self.path_of[n] = len(self.paths)
        self.paths.append(Path(len(self.paths), n, m.nozzle_height() / Z_STEPS,
                               (m.x / XY_STEPS, m.y / XY_STEPS), judged=self.judging))

    def _close_path(self, n: int) -> None:
        number = self.path_of[n]
        if number >= 0 and self.recording:
            m = self.machine
            path = self.paths[number]
            path.end = (m.x / XY_STEPS, m.y / XY_STEPS)
            path.closed = True
        self.path_of[n] = -1

    def _row(self, x0: float, y0: float, x1: float, y1: float, z: float,
             dep: float, drv: float, nozzle: int, path: int) -> None:
        if self._has_last and self._lpath == path and self._lnozzle == nozzle \
                and self._lx1 == x0 and self._ly1 == y0 and abs(self._lz - z) <= SAME_Z_MM:
            px, py = self._lx0, self._ly0
            if _straight(px, py, x0, y0, x1, y1) and \
                    _alike(self._ldep, self._ldrv, dep, drv) and \
                    _no_lump(self._ldep, dep, px, py, x0, y0, x1, y1):
                self._lx1, self._ly1 = x1, y1
                self._ldep += dep
                self._ldrv += drv
                return
        self._keep_last()
        self._has_last = True
        self._lx0, self._ly0, self._lx1, self._ly1, self._lz = x0, y0, x1, y1, z
        self._ldep, self._ldrv = dep, drv
        self._lnozzle, self._lpath = nozzle, path

    def _keep_last(self) -> None:
        """The newest row into the columns (the next one starts, or the record closes)."""
        if not self._has_last:
            return
        self._has_last = False
        self._cx0 = append(self._cx0, self._lx0)
        self._cy0 = append(self._cy0, self._ly0)
        self._cx1 = append(self._cx1, self._lx1)
        self._cy1 = append(self._cy1, self._ly1)
        self._cz = append(self._cz, self._lz)
        self._cdep = append(self._cdep, self._ldep)
        self._cdrv = append(self._cdrv, self._ldrv)
        self._cnozzle = append(self._cnozzle, float(self._lnozzle))
        self._cpath = append(self._cpath, float(self._lpath))
        if self.spill is not None and len(self._cx0) >= SPILL_ROWS:
            self._spill()

    def _last(self) -> tuple[float, ...]:
        return (self._lx0, self._ly0, self._lx1, self._ly1, self._lz, self._ldep,
                self._ldrv, float(self._lnozzle), float(self._lpath))

    def _spill(self) -> None:
        """The rows in the columns (all but the newest, held apart) to the spill file, a
        chunk of columns: memory stays flat in the job's size."""
        columns = self._column_list()
        n: int = len(columns[0])
        assert self.spill is not None
        with open(self.spill, "ab") as f:
            f.write(n.to_bytes(8, "little"))
            for column in columns:
                f.write(floats_to_bytes(column))
        self._empty_columns()
        self.spilled += n

    def iter_columns(self) -> Iterator[list[vec[float]]]:
        """Every row, oldest first, as chunks of columns (in COLUMNS' order, of equal
        lengths): what iter_rows gives, for a reader that walks the columns by index
        (compiled, natively, where each row of iter_rows is a tuple of boxed numbers)."""
        if self.spill is not None and self.spilled:
            with open(self.spill, "rb") as f:
                while header := f.read(8):
                    n = int.from_bytes(header, "little")
                    columns: list[vec[float]] = []
                    for _ in COLUMNS:
                        data = f.read(8 * n)
                        if len(data) != 8 * n:
                            raise EOFError(f"{self.spill}: the record ends inside a chunk")
                        columns.append(floats_from_bytes(data))
                    yield columns
        yield self._column_list()
        if self._has_last:
            yield [vec[float]([value]) for value in self._last()]

    def iter_rows(self) -> Iterator[tuple[float, ...]]:
        """Every row, oldest first: (x0, y0, x1, y1, z, deposited, driven, nozzle,
        path)."""
        for columns in self.iter_columns():
            yield from zip(*columns, strict=True)


def _straight(px: float, py: float, jx: float, jy: float, qx: float, qy: float) -> bool:
    """Whether a stretch from j to q carries on straight from the row p to j: the joint
    within STRAIGHT_MM of the line from p to q, between them. Standing rows (a point:
    positions are whole microsteps, so a point is exact) join only each other."""
    standing_before = px == jx and py == jy
    standing_now = jx == qx and jy == qy
    if standing_before or standing_now:
        return standing_before and standing_now
    dx, dy = qx - px, qy - py
    if (jx - px) * dx + (jy - py) * dy <= 0.0 or (qx - jx) * dx + (qy - jy) * dy < 0.0:
        return False
    off = abs((jx - px) * dy - (jy - py) * dx)
    h = _near_hypot(dx, dy)
    bound = STRAIGHT_MM * h
    if h >= 0.0 and abs(off - bound) > NEAR * bound:
        return off <= bound
    return off <= STRAIGHT_MM * math.hypot(dx, dy)


def _no_lump(dep0: float, dep1: float, px: float, py: float, jx: float, jy: float,
             qx: float, qy: float) -> bool:
    """Whether a stretch from j to q laying dep1 is no lump after the row from p to j
    that laid dep0: it lays at most four times as much per mm, give or take a blob."""
    h1 = _near_hypot(qx - jx, qy - jy)
    h0 = _near_hypot(jx - px, jy - py)
    if dep0 >= 0.0 and h1 >= 0.0 and h0 >= 0.0:  # a sum of terms of one sign
        bound = 4.0 * dep0 * h1 / max(h0, 1e-9) + BLOB_MM3
        if abs(dep1 - bound) > NEAR * bound:
            return dep1 <= bound
    return dep1 <= 4.0 * dep0 * math.hypot(qx - jx, qy - jy) \
        / max(math.hypot(jx - px, jy - py), 1e-9) + BLOB_MM3


def _near_hypot(dx: float, dy: float) -> float:
    """math.hypot(dx, dy) to a few parts in 10^16: the square root of the sum of the
    squares (compiled, native, where math.hypot is a generic call); -1.0 where a square
    leaves the range of doubles and it could be further off. A comparison with it
    decides as math.hypot would unless the two sides are within NEAR of each other."""
    sq = dx * dx + dy * dy
    if (sq < 1e-200 and (dx != 0.0 or dy != 0.0)) or sq > 1e300:
        return -1.0
    return math.sqrt(sq)


def _alike(dep0: float, drv0: float, dep1: float, drv1: float) -> bool:
    """Whether two stretches delivered the same share of what was driven (to 5%)."""
    share0 = dep0 / drv0 if drv0 > 0.0 else 1.0
    share1 = dep1 / drv1 if drv1 > 0.0 else 1.0
    return abs(share0 - share1) <= 0.05
