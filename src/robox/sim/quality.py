"""Print quality from the deposition record: blobs, starved stretches, and a picture.

The record (`robox.hardware.deposition`) is in machine millimetres per nozzle; here
each row is brought into the job's frame (less the nozzle's offsets, as the firmware
adds them) and only what lands on the build plate is judged: a purge over the bin at
the plate's front edge is meant to be a blob.

- A blob: plastic (`BLOB_MM3` or more) left while the head stood still (a row shorter
  than `STANDING_MM`): a valve shut standing, plastic held under pressure let out.
- A starved stretch: a moving row that laid down less than `STARVED` of the plastic
  driven into the nozzle for it (fed by the extruder, pushed by the needle): what a
  void below an opened needle swallows, or a needle shutting into a void.
- Paths opened before the job proper (the start sequence's purge) are left out.
- Layers: the nozzle heights of the plastic, nearest first; heights within
  `LAYER_MERGE_MM` of each other (a levelled bed's washout) are one layer, numbered
  from 1.
"""

from __future__ import annotations

import bisect
import heapq
import math
import os
from collections.abc import Iterator
from typing import BinaryIO, Final

from robox.formats.float8 import short_decimal
from robox.hardware.deposition import BLOB_MM3, STANDING_MM, Deposition
from robox.packed import i64, vec

# (Final: compiled, constants in the code, where a plain module global is looked up and
# unboxed at every row)
STARVED: Final = 0.8
LAYER_MERGE_MM: Final = 0.04
EDGE_MM: Final = 0.5  # plastic this far beyond the plate's edge still counts as on it
WORST: Final = 5


class Place:
    def __init__(self, kind: str, layer: int, x: float, y: float, z: float, mm3: float,
                 length_mm: float = 0.0) -> None:
        self.kind = kind  # "blob" or "starved"
        self.layer = layer
        self.x = x
        self.y = y
        self.z = z
        self.mm3 = mm3  # the blob's volume, or the plastic a starved stretch lacks
        self.length_mm = length_mm
        self.line: int | None = None

    def as_dict(self) -> dict:
        return {"kind": self.kind, "layer": self.layer, "line": self.line,
                "x": round(self.x, 2), "y": round(self.y, 2), "mm3": round(self.mm3, 3),
                "length_mm": round(self.length_mm, 2)}


class Quality:
    """The deposition record in the job's frame, and the figures drawn from it, read as
    a stream (the record may be longer than memory holds: see Deposition.spill)."""

    def __init__(self, dep: Deposition, offsets: list[tuple[float, float, float]],
                 bed: tuple[float, float]):
        self.dep = dep
        self.bed = bed
        # the plate's far edges with the margin, worked out once (on_plate() is asked
        # for every row)
        self._x_high = bed[0] + EDGE_MM
        self._y_high = bed[1] + EDGE_MM
        self.paths = [p for p in dep.paths if p.judged]
        self.unjudged = {p.number for p in dep.paths if not p.judged}
        # (the start sequence's numbers: looked up in the set only within their range)
        self._unjudged_low = min(self.unjudged) if self.unjudged else 0
        self._unjudged_high = max(self.unjudged) if self.unjudged else -1
        self.offsets = offsets
        # one pass over the record: the figures, and the heights the layers come from (a
        # place's layer is given once they are known)
        heights: set[float] = set()
        self._figures, self._worst = self._judge(heights)
        self.layers = _merged(sorted(heights))
        self._figures["layers"] = len(self.layers)
        for place in self._worst:
            place.layer = self.layer_of(place.z)

    def rows(self) -> Iterator[tuple[float, float, float, float, float, float, float, int,
                                     int]]:
        """(x0, y0, x1, y1, z, deposited, driven, nozzle, path) in the job's frame, the
        start sequence's paths left out."""
        for x0, y0, x1, y1, z, dep, drv, nozzle, path in self.dep.iter_rows():
            n, p = int(nozzle), int(path)
            if self._left_out(p):
                continue
            ox, oy, oz = self._offset(n)
            yield x0 - ox, y0 - oy, x1 - ox, y1 - oy, z - oz, dep, drv, n, p

    def _left_out(self, path: int) -> bool:
        """Whether the row's path is one of the start sequence's, not judged."""
        return self._unjudged_low <= path <= self._unjudged_high and path in self.unjudged

    def _offset(self, nozzle: int) -> tuple[float, float, float]:
        """What takes a nozzle's row from the machine's frame to the job's (a travel's,
        nozzle -1, by nozzle 0's)."""
        return self.offsets[nozzle] if nozzle >= 0 else self.offsets[0]

    def on_plate(self, x: float, y: float) -> bool:
        return -EDGE_MM <= x <= self._x_high and -EDGE_MM <= y <= self._y_high

    def layer_of(self, z: float) -> int:
        """The layer (from 1) a height belongs to; 0 below the first."""
        return bisect.bisect_right(self.layers, z + LAYER_MERGE_MM)

    def figures(self) -> tuple[dict, list[Place]]:
        """The figures, and the worst places (at most WORST, the worst first)."""
        return self._figures, self._worst

    def _judge(self, heights: set[float]) -> tuple[dict, list[Place]]:
        """The figures and the worst places (their layers not yet given), the plastic's
        heights rounded into `heights` on the way."""
        blob = starved_mm = deposited = driven = 0.0
        blobs = 0
        worst: list[tuple[float, int, Place]] = []  # a heap of the worst places
        count = 0

        def keep(place: Place) -> None:
            nonlocal count
            count += 1
            if place.mm3 <= 1e-4:
                return
            item = (place.mm3, -count, place)  # (of equals, the earliest stay)
            if len(worst) < WORST:
                heapq.heappush(worst, item)
            elif item[0] > worst[0][0]:
                heapq.heapreplace(worst, item)

        run: Place | None = None  # the starved stretch being followed
        last_path = -2
        added_z = math.nan  # the height last rounded into `heights` (a row's mostly repeats)
        # the heights (times 100) that round as the last one rounded did: the nozzle's
        # height follows the carriage by fractions of a microstep on a levelled gantry,
        # so it seldom repeats exactly, but stays within a layer's band
        band_low = band_high = math.nan
        hypot = math.hypot  # (a local: compiled, the module's attribute is not looked up per row)
        # rows() walked by index over the record's columns (compiled, natively: a row of
        # rows() is a tuple of boxed numbers)
        k: i64
        for columns in self.dep.iter_columns():
            cx0, cy0, cx1, cy1 = columns[0], columns[1], columns[2], columns[3]
            cz, cdep, cdrv, cnozzle, cpath = (columns[4], columns[5], columns[6],
                                               columns[7], columns[8])
            for k in range(len(cx0)):
                path = int(cpath[k])
                if self._left_out(path):
                    continue
                ox, oy, oz = self._offset(int(cnozzle[k]))
                x0, y0, x1, y1 = cx0[k] - ox, cy0[k] - oy, cx1[k] - ox, cy1[k] - oy
                z, dep, drv = cz[k] - oz, cdep[k], cdrv[k]
                on_plate = self.on_plate(x1, y1)
                if dep > 0.0 and on_plate and z != added_z:
                    added_z = z
                    hundredths = z * 100.0
                    if not band_low < hundredths < band_high:
                        heights.add(_round2(z))
                        band_low, band_high = _round2_band(hundredths)
                if path < 0 or not on_plate:
                    continue
                deposited += dep
                driven += drv
                length = hypot(x1 - x0, y1 - y0)
                if length < STANDING_MM:
                    if dep >= BLOB_MM3:
                        blob += dep
                        blobs += 1
                        keep(Place("blob", 0, x1, y1, z, dep))
                    continue
                if dep < STARVED * drv:
                    starved_mm += length
                    if run is not None and last_path == path and (run.x, run.y) == (x0, y0):
                        run.mm3 += drv - dep
                        run.length_mm += length
                        run.x, run.y = x1, y1
                    else:
                        if run is not None:
                            keep(run)
                        run = Place("starved", 0, x1, y1, z, drv - dep, length)
                    last_path = path
                elif run is not None:
                    keep(run)
                    run = None
        if run is not None:
            keep(run)
        ends = sum(1 for p in self.paths if p.closed and self.on_plate(
            p.end[0] - self.offsets[p.nozzle][0], p.end[1] - self.offsets[p.nozzle][1]))
        opens = sum(1 for p in self.paths if self.on_plate(
            p.start[0] - self.offsets[p.nozzle][0], p.start[1] - self.offsets[p.nozzle][1]))
        places = [place for _, _, place in sorted(worst, key=lambda item: (-item[0], -item[1]))]
        figures = {
            "path_ends": ends, "opens": opens, "layers": 0,  # (once they are known)
            "deposited_mm3": round(deposited, 2), "driven_mm3": round(driven, 2),
            "blob_mm3": round(blob, 3), "blobs": blobs,
            "starved_mm": round(starved_mm, 2),
            "blob_mm3_per_path_end": round(blob / ends, 4) if ends else 0.0,
            "starved_mm_per_open": round(starved_mm / opens, 4) if opens else 0.0,
        }
        return figures, places


def _merged(heights: list[float]) -> list[float]:
    """Layers from sorted heights: those within LAYER_MERGE_MM of a layer are in it."""
    layers: list[float] = []
    for z in heights:
        if not layers or z - layers[-1] > LAYER_MERGE_MM:
            layers.append(z)
    return layers


def _nearest_hundredth(y: float) -> float:
    """For y = value * 100: the whole number nearest to it, where y is far enough from a
    half for its rounding not to matter (within 1e-6 of one, or too large: NaN)."""
    if abs(y) < 1e9:
        whole = float(math.floor(y))
        frac = y - whole
        if abs(frac - 0.5) > 1e-6:
            return whole + 1.0 if frac > 0.5 else whole
    return math.nan


def _round2(value: float) -> float:
    """round(value, 2), worked out natively (compiled, round() is a generic call) where
    value * 100 is far enough from a half for its rounding not to matter: the whole
    number nearest to it, over 100, is then the double nearest the two-place decimal,
    as round() gives; round() itself otherwise."""
    nearest = _nearest_hundredth(value * 100.0)
    if nearest == nearest:
        return nearest / 100.0 if nearest != 0.0 else math.copysign(0.0, value)
    return round(value, 2)


def _round2_band(y: float) -> tuple[float, float]:
    """For y = value * 100: the open interval of such products whose values _round2()
    rounds as it rounds this one, the same whole number of hundredths, each far enough
    from a half (by more than 1e-6) for its rounding not to matter. Empty (NaN bounds)
    where this one's is not."""
    nearest = _nearest_hundredth(y)
    return nearest - 0.499999, nearest + 0.499999


def _blank(c: int) -> bool:
    """Whether a byte of a job read as latin-1 is white space to str.isspace() (and so to
    a regular expression's \\s)."""
    return c == 32 or 9 <= c <= 13 or 28 <= c <= 31 or c == 133 or c == 160


#: How much of a job find_lines reads at a time.
JOB_BLOCK: Final = 1 << 16


def job_lines(f: BinaryIO, block: int = JOB_BLOCK) -> Iterator[bytes]:
    """The lines of the binary file `f` as text with universal newlines reads them (CR
    LF, CR and LF each end a line), each with its line end as it was; read `block`
    bytes at a time, so memory stays flat in the file's size whatever its line ends (a
    Robox job's are CRs). A line that runs on into the next block waits for it, as does
    a CR that ends a block (an LF may follow it)."""
    pending = b""
    while True:
        data = f.read(block)
        if not data:
            if pending:
                yield from pending.splitlines(keepends=True)
            return
        lines = (pending + data).splitlines(keepends=True)
        pending = lines.pop()
        yield from lines
        if pending.endswith(b"\n"):  # whole (an LF, or a CR LF)
            yield pending
            pending = b""


def find_lines(job: str | os.PathLike, places: list[Place]) -> None:
    """Each place's line: the job's move that ends nearest to it (its layer's height
    weighed heavily; of equals, the first), found in one pass over the job. A move is
    measured against a place only where its height alone leaves it a chance: the
    heights' part is worked out once per height the job moves to (a job keeps one for
    a layer's moves), and the places it already puts further than their nearest so
    far are passed by.

    A line is read byte by byte (compiled, native): up to a `;`, a move is a G0 or G1
    (either case) after any blanks and before no digit; its X, Y and Z (either case)
    are each a letter, blanks, and a decimal number (a sign, digits, and a point only
    with digits after it); G90 and G91 set absolute and relative."""
    if not places:
        return
    n = len(places)
    px = vec[float]([p.x for p in places])
    py = vec[float]([p.y for p in places])
    pz = vec[float]([p.z for p in places])
    best = vec[float]([math.inf] * n)
    floors = vec[float]([0.0] * n)  # 100 (z - the place's z)^2 at the moves' height
    floors_z = math.nan
    x = y = z = 0.0
    relative = False
    number: i64 = 0
    # (the job's lines as universal newlines reads them, each with its own line end, CR
    # LF, CR or LF: the reading below takes any of them for a blank; compiled, no line is
    # decoded into text and back)
    with open(job, "rb") as f:
        for text in job_lines(f):
            number += 1
            # (native integers: compiled, an index's step is a plain add)
            end: i64 = len(text)
            k: i64
            for k in range(end):
                if text[k] == 59:  # ;
                    end = k
                    break
            i: i64 = 0
            while i < end and _blank(text[i]):
                i += 1
            if i + 1 >= end or text[i] | 0x20 != 0x67:  # G
                continue
            code = text[i + 1]
            after = text[i + 2] if i + 2 < end else 0
            if code == 0x39:  # G9: G90, G91 (whatever follows)
                if after == 0x31:
                    relative = True
                elif after == 0x30:
                    relative = False
                continue
            if (code != 0x30 and code != 0x31) or 48 <= after <= 57:
                continue  # not G0 or G1
            j: i64 = 0
            while j < end:
                letter = text[j] | 0x20
                j += 1
                if letter < 0x78 or letter > 0x7A:  # x, y, z
                    continue
                k = j
                while k < end and _blank(text[k]):
                    k += 1
                first = k
                if k < end and (text[k] == 43 or text[k] == 45):  # + -
                    k += 1
                while k < end and 48 <= text[k] <= 57:
                    k += 1
                digits = k > first and 48 <= text[k - 1] <= 57
                if k + 1 < end and text[k] == 46 and 48 <= text[k + 1] <= 57:  # .digits
                    k += 2
                    while k < end and 48 <= text[k] <= 57:
                        k += 1
                    digits = True
                if not digits:
                    continue
                v = short_decimal(text, first)
                if v != v:  # (not a short one: float() reads what was found)
                    v = float(text[first:k])
                if letter == 0x78:
                    x = x + v if relative else v
                elif letter == 0x79:
                    y = y + v if relative else v
                else:
                    z = z + v if relative else v
                j = k
            if z != floors_z:
                for h in range(n):
                    dz = z - pz[h]  # (products, not ** 2: compiled, a power is generic)
                    floors[h] = 100.0 * (dz * dz)
                floors_z = z
            for h in range(n):
                floor = floors[h]
                if floor > best[h]:
                    continue  # (the whole distance is at least this)
                dx, dy = x - px[h], y - py[h]
                d = dx * dx + dy * dy + floor
                if d < best[h]:
                    best[h] = d
                    places[h].line = number


def plot(quality: Quality, target: str | os.PathLike, layer: int | None,
         worst: list[Place], title: str) -> int:
    """Draw a layer from above into a PNG; returns the layer drawn."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection
    from matplotlib.colors import LinearSegmentedColormap, Normalize

    if not quality.layers:
        raise ValueError("no plastic on the build plate: nothing to draw")
    if layer is None:
        layer = worst[0].layer if worst and worst[0].layer else 1
    if not 1 <= layer <= len(quality.layers):
        raise ValueError(f"layer {layer}: the print has layers 1 to {len(quality.layers)}")
    lines, ratios, travels, blobs = [], [], [], []
    for x0, y0, x1, y1, z, dep, drv, _n, path in quality.rows():
        if quality.layer_of(z) != layer:
            continue
        if path < 0 or (dep == 0.0 and drv == 0.0):
            travels.append(((x0, y0), (x1, y1)))
        elif math.hypot(x1 - x0, y1 - y0) < STANDING_MM:
            if dep >= BLOB_MM3 and quality.on_plate(x1, y1):
                blobs.append((x1, y1, dep))
        else:
            lines.append(((x0, y0), (x1, y1)))
            ratios.append(dep / drv if drv > 0 else 2.0)
    fig, ax = plt.subplots(figsize=(8, 8), dpi=110)
    ax.add_collection(LineCollection(travels, colors="#b0b0b0", linewidths=0.4,
                                     alpha=0.5, label="travel"))
    # red where starved (below 0.8), green as meant, blue where more than meant
    cmap = LinearSegmentedColormap.from_list(
        "deposit", [(0.0, "#c00000"), (0.3, "#ff8c00"), (0.4, "#e0c000"), (0.5, "#20a040"),
                    (0.6, "#20a040"), (1.0, "#2050ff")])
    coloured = LineCollection(lines, cmap=cmap, norm=Normalize(0.0, 2.0), linewidths=1.6)
    coloured.set_array([min(r, 2.0) for r in ratios])
    ax.add_collection(coloured)
    fig.colorbar(coloured, ax=ax, shrink=0.7,
                 label="deposited / driven into the nozzle (1: as meant; red: starved)")
    if blobs:
        ax.scatter([b[0] for b in blobs], [b[1] for b in blobs],
                   s=[30 + 400 * b[2] for b in blobs], facecolors="none",
                   edgecolors="#d00000", linewidths=1.2,
                   label=f"blobs ({len(blobs)}, {sum(b[2] for b in blobs):.2f} mm3)")
        ax.legend(loc="upper right")
    points = [p for seg in lines + travels for p in seg] + [(b[0], b[1]) for b in blobs]
    if points:
        xs, ys = [p[0] for p in points], [p[1] for p in points]
        pad = 2.0
        ax.set_xlim(min(xs) - pad, max(xs) + pad)
        ax.set_ylim(min(ys) - pad, max(ys) + pad)
    ax.set_aspect("equal")
    ax.set_xlabel("X (mm)")
    ax.set_ylabel("Y (mm)")
    ax.set_title(f"{title}\nlayer {layer} of {len(quality.layers)} "
                 f"(Z {quality.layers[layer - 1]:.2f} mm)")
    fig.tight_layout()
    fig.savefig(target, format="png")
    plt.close(fig)
    return layer
