"""The needle valve driven as AutoMaker drove it: closes on the move, opens that refill.

A stage after the translator (robox.gcode.translate), which writes a job that shuts
the valve standing still (`G0 B0` where the slicer retracts, at a tool change, at the
end) and opens it standing still (`G0 B1` before an extrusion). Reading that job a line
at a time, the stage keeps the moves since the last open in a look-behind buffer and
rewrites each close and open (AutoMaker's post-processor, `CloseLogic` and
`UtilityMethods.insertOpens`, gives the behaviour; docs/valve.md explains it):

- A close is made over the path's last ejection volume: the moves that carry it lose
  their E and get a B that falls with the volume still to come (B 1 where the close
  starts, 0 at the path's end), the move across that point split there. The needle's
  stroke pushes out what the removed E would have laid down, on the same stretch.
- An outer wall's close is made on the adjacent inner wall (the last inner wall run
  before it in the same path): the head steps onto it at the point nearest the seam
  and runs back along it with the B falling, the E of that stretch of the inner wall
  removed, so its plastic comes from the needle instead. Without an inner wall in
  the buffer the close is made over the outer wall's own end.
- A path shorter than the ejection volume is opened partly (B = its volume over the
  ejection volume, at least `PARTIAL_B_MINIMUM`) and closed over its whole length.
- Every open refills the void its needle leaves: `G1 B<b> E<b x ejection> F150`, at
  AutoMaker's slow feed; the next move gets the slicer's feed back. Where a path was
  shorter than the partial minimum's stroke, the stroke pushed out more than its
  plastic, and the nozzle's next refill is that much less (AutoMaker refilled what the
  last close had taken off): the job's volume stays the slicer's.
- A tool change, and the nozzle's re-selection after `OPENS_BEFORE_RESELECT` opens
  (a T makes the firmware measure the valve against its switch), is made with the
  valve shut as part of the travel before the next path (`T1 X.. Y..`). On a
  dual-material head the nozzle is waited for (M109) before its first open after a
  tool change.

Streaming: the buffer holds one path and the lines after its close up to the next
open; a path of more than `MAX_BUFFER` lines is written out from its oldest lines,
keeping the tail a close needs. Lines in a relative-axes stretch (G91) pass through
with their standing opens and closes.
"""

from __future__ import annotations

import math
import re
from typing import Final

from robox.formats.float8 import short_decimal, skip_blanks
from robox.formats.heads import OPENS_BEFORE_RESELECT, PARTIAL_B_MINIMUM, HeadValves
from robox.gcode.text import number
from robox.packed import i64

#: Lines the look-behind buffer holds before it writes out the oldest.
MAX_BUFFER: Final = 4000
#: AutoMaker's feed (mm/min) for the refill as the valve opens.
REFILL_FEED: Final = b"150"
EPSILON: Final = 1e-9

# what a line is to the stage
OTHER: Final = 0
EXTRUDE: Final = 1
TRAVEL: Final = 2
OPEN: Final = 3
CLOSE_MOVE: Final = 4  # a move of a close made on another path (no E, a B)
TOOL: Final = 5

# feature classes, from the slicers' ;TYPE: names
OUTER: Final = "outer"
INNER: Final = "inner"
_FEATURES = {
    "external perimeter": OUTER, "overhang perimeter": OUTER, "outer wall": OUTER,
    "overhang wall": OUTER, "wall-outer": OUTER,
    "perimeter": INNER, "inner wall": INNER, "wall-inner": INNER,
}

_WORD = re.compile(rb"([A-Za-z])\s*([-+]?[0-9]*\.?[0-9]*)")
_FEED = re.compile(rb"[Ff]\s*([-+]?[0-9]*\.?[0-9]+)")


def _spaced(line: bytes) -> list[bytes]:
    return [letter + value for letter, value in _WORD.findall(line[2:])]


def _float(value: bytes) -> float:
    plain = short_decimal(value, 0, True)  # (nearly every value: no generic float())
    if plain == plain:
        return plain
    try:
        return float(value) if value else 0.0
    except ValueError:
        return 0.0


def _float_in(line: bytes, start: i64, end: i64) -> float:
    """_float(line[start:end]), made without the slice where the value is a short plain
    decimal (nearly every one)."""
    plain = short_decimal(line, start, True, end)
    return plain if plain == plain else _float(line[start:end])


def _code(line: bytes) -> bytes:
    """The line's first word, upper-cased (b"" for none): line.split(None, 1)[0].upper()
    found in one native loop (compiled, the two method calls cost more than the rest of
    a line's look at it)."""
    n: i64 = len(line)
    i: i64 = skip_blanks(line, 0)
    j: i64 = i
    lower = False
    while j < n and not (line[j] == 32 or 9 <= line[j] <= 13):
        if 97 <= line[j] <= 122:
            lower = True
        j += 1
    word = line[i:j]
    return word.upper() if lower else word


def feature_class(name: str) -> str:
    return _FEATURES.get(name.strip().lower(), "other")


class Step:
    """A line in the look-behind buffer. (A plain class: compiled, a dataclass's
    generated __init__ would run interpreted for every line.)"""

    def __init__(self, kind: int, line: bytes = b"", sx: float = 0.0, sy: float = 0.0,
                 x: float = 0.0, y: float = 0.0, e: float = 0.0, b: float = -1.0,
                 feed: bytes = b"", feed_in_force: bytes = b"", feature: str = "other",
                 rest: bytes = b"", word: bytes = b" E", raw: bytes = b"") -> None:
        self.kind = kind
        self.line = line  # OTHER, TOOL: the line; moves: the code and axis words
        self.sx = sx  # where the move starts
        self.sy = sy
        self.x = x  # where it ends
        self.y = y
        self.e = e  # mm3 (EXTRUDE, OPEN's refill)
        self.b = b  # the valve at the move's end (-1: not written)
        self.feed = feed  # the F written on the line (b"": none)
        self.feed_in_force = feed_in_force  # the slicer's feed rate for this move
        self.feature = feature
        self.rest = rest  # a move's words after X, Y (Z), kept as they were
        self.word = word  # the extruder's word
        self.changed = False  # written anew (else `raw`, the line as it came)
        self.raw = raw


class ValveCounts:
    def __init__(self) -> None:
        self.closes_on_move = 0
        self.closes_on_inner_wall = 0
        self.partial_opens = 0
        self.standing_closes = 0
        self.refill_mm3 = 0.0
        self.removed_mm3 = 0.0
        self.tool_changes_in_travel = 0
        self.reselects = 0

    def as_dict(self) -> dict:
        return {"closes_on_move": self.closes_on_move,
                "closes_on_inner_wall": self.closes_on_inner_wall,
                "partial_opens": self.partial_opens, "standing_closes": self.standing_closes,
                "refill_mm3": round(self.refill_mm3, 3),
                "removed_mm3": round(self.removed_mm3, 3),
                "tool_changes_in_travel": self.tool_changes_in_travel,
                "reselects": self.reselects}


class ValveStage:
    """Feed the translator's job lines to `feed()`; it returns the lines to write."""

    def __init__(self, valves: HeadValves) -> None:
        self.valves = valves
        self.word = b" E"  # the extruder word of the current tool
        self.counts = ValveCounts()
        self.buf: list[Step] = []
        self.open_at = -1  # the current path's OPEN in the buffer (-1: none, or written)
        self.is_open = False
        self.x = self.y = 0.0
        self.relative = False
        self.feed_in_force = b""  # the slicer's feed rate as of now
        self.feature = "other"
        self.nozzle = 0
        self.opens = 0  # since the nozzle was last selected
        self.selected = False  # a T since the last open (the valve measured)
        self.tool_changed = False  # (dual-material heads: M109 before the next open)
        self.owed: dict[int, float] = {}  # per nozzle: mm3 its next refill leaves out
        self.pending_tool: Step | None = None  # a T waiting for the travel it goes with
        self._written_feed = b""  # the feed rate the lines written so far leave in force

    # ------------------------------------------------------------ input
    def feed(self, line: bytes, out: list[bytes]) -> None:
        """One of the translator's lines; the lines ready to write are added to `out`."""
        if line.startswith(b";TYPE:"):
            self.feature = feature_class(line[6:].decode("ascii", "replace"))
            return
        code = _code(line)
        if self.relative:
            if code == b"G90":
                self.relative = False
            out.append(line)
            return
        if code in (b"G0", b"G1"):
            self._move(line, out)
        elif code == b"G91":
            self._flush(out, len(self.buf))
            self.open_at = -1
            self.relative = True
            out.append(line)
        elif code == b"G92":
            self._add(Step(OTHER, line))
            for part in _spaced(line):
                if part[0] & 0xDF == 0x58:
                    self.x = _float(part[1:])
                elif part[0] & 0xDF == 0x59:
                    self.y = _float(part[1:])
        elif code[:1] == b"T" and code[1:].isdigit():
            self._tool(int(code[1:]), out)
        else:
            if code == b"G36" and self.pending_tool is not None:
                # filament pushed until the drive slips: against the needle the selected
                # nozzle shuts, wherever the valve stood before (not the T after it)
                self.buf.append(self.pending_tool)
                self.pending_tool = None
            self._add(Step(OTHER, line))
        if len(self.buf) > MAX_BUFFER:
            self._trim(out)

    def finish(self) -> list[bytes]:
        out: list[bytes] = []
        if self.is_open:
            self._close(out)
        if self.pending_tool is not None:
            self.buf.append(self.pending_tool)
            self.pending_tool = None
        self._flush(out, len(self.buf))
        return out

    # ------------------------------------------------------------ lines
    def _move(self, line: bytes, out: list[bytes]) -> None:
        b = e = -1.0
        has_b = has_e = has_xy = False
        x, y = self.x, self.y
        f = b""
        rest = b""
        # one pass over a job's own line (code, then words of a letter and its value,
        # one blank apart); the head is the code and the X, Y and Z words before any
        # other, a slice of the line where they come first
        n: i64 = len(line)  # (native integers: compiled, indexing is native)
        i: i64 = 2
        start: i64
        head_end: i64 = 2
        tidy = True
        head_parts: list[bytes] = []
        while i < n:
            c = line[i]
            if c == 32 or c == 9:
                i += 1
                continue
            start = i
            i += 1
            while i < n and line[i] != 32 and line[i] != 9:
                if 0x41 <= line[i] & 0xDF <= 0x5A:  # a letter in a value: not a job's own
                    self._move_spaced(line, out)
                    return
                i += 1
            upper = line[start] & 0xDF
            if i - start < 2 or not 0x41 <= upper <= 0x5A:
                self._move_spaced(line, out)
                return
            if upper == 0x58 or upper == 0x59 or upper == 0x5A:  # X, Y, Z
                if upper == 0x58:
                    x = _float_in(line, start + 1, i)
                    has_xy = True
                elif upper == 0x59:
                    y = _float_in(line, start + 1, i)
                    has_xy = True
                if tidy and start == head_end + 1:
                    head_end = i
                    continue
                if tidy:  # the words so far, one blank apart after the code: one part
                    tidy = False
                    if head_end > 2:
                        head_parts.append(line[3:head_end])
                head_parts.append(line[start:i])
                continue
            if upper == 0x42:  # B
                b = _float_in(line, start + 1, i)
                has_b = True
            elif upper == 0x45 or upper == 0x44:  # E, D
                e = _float_in(line, start + 1, i)
                has_e = True
                self.word = b" D" if upper == 0x44 else b" E"
            elif upper == 0x46:  # F
                f = line[start + 1:i]
            else:
                rest += b" " + line[start:i]
        head = line[:head_end] if tidy else b" ".join([line[:2], *head_parts])
        self._moved(line, out, head, x, y, has_xy, b, has_b, e, has_e, f, rest)

    def _move_spaced(self, line: bytes, out: list[bytes]) -> None:
        """A move whose words are not each a letter and its value with blanks between
        (a macro's, say): read word by word."""
        b = e = -1.0
        has_b = has_e = has_xy = False
        x, y = self.x, self.y
        f = b""
        rest = b""
        head_parts = [line[:2]]
        for part in _spaced(line):
            upper = part[0] & 0xDF
            value = part[1:]
            if upper == 0x58:
                x = _float(value)
                has_xy = True
                head_parts.append(part)
            elif upper == 0x59:
                y = _float(value)
                has_xy = True
                head_parts.append(part)
            elif upper == 0x5A:
                head_parts.append(part)
            elif upper == 0x42:
                b = _float(value)
                has_b = True
            elif upper == 0x45 or upper == 0x44:
                e = _float(value)
                has_e = True
                self.word = b" D" if upper == 0x44 else b" E"
            elif upper == 0x46:
                f = value
            else:
                rest += b" " + part
        self._moved(line, out, b" ".join(head_parts), x, y, has_xy, b, has_b, e, has_e, f,
                    rest)

    def _moved(self, line: bytes, out: list[bytes], head: bytes, x: float, y: float,
               has_xy: bool, b: float, has_b: bool, e: float, has_e: bool, f: bytes,
               rest: bytes) -> None:
        """A move read: a valve word the translator wrote, a T's travel, or a step."""
        if f:
            self.feed_in_force = f
        if has_b and not has_xy and len(head) == 2 and not has_e:
            if b >= 0.5 and not self.is_open:
                self._open(out)
            elif b < 0.5 and self.is_open:
                self._close(out)
            # a valve word the stage did not write (a macro's, in a sequence) otherwise
            # stays as it is
            elif b != (1.0 if self.is_open else 0.0):
                self._add(Step(OTHER, line))
            return
        if has_b:  # a move with a valve word of its own: as it is
            self._add(Step(OTHER, line))
            self.x, self.y = x, y
            return
        if self.pending_tool is not None and has_xy and not has_e and b" Z" not in head:
            # a T the slicer wrote before its travel: the two as one (`T1 X.. Y..`)
            tool, self.pending_tool = self.pending_tool, None
            tool.line += head[2:]
            self.buf.append(tool)
            if f:
                self.buf.append(Step(OTHER, b"G1 F" + f))
            self.counts.tool_changes_in_travel += 1
            self.x, self.y = x, y
            return
        step = Step(TRAVEL, head, self.x, self.y, x, y, feed=f,
                    feed_in_force=self.feed_in_force, feature=self.feature, rest=rest,
                    raw=line)
        if has_e and e > EPSILON and self.is_open:
            step.kind = EXTRUDE
            step.e = e
            step.word = self.word
        elif has_e and abs(e) > EPSILON:
            step.kind = OTHER  # plastic with the valve shut (a macro's): as it is
            step.line = line
        self.x, self.y = x, y
        self._add(step)

    def _add(self, step: Step) -> None:
        self.buf.append(step)

    def _tool(self, tool: int, out: list[bytes]) -> None:
        if self.is_open:
            self._close(out)
        if tool != self.nozzle:
            self.tool_changed = True
        self.nozzle = tool
        self.opens = 0
        self.selected = True
        self._merge_tool(Step(TOOL, b"T%d" % tool))

    def _merge_tool(self, tool: Step) -> None:
        """A T into the last travel since the close (`T1 X.. Y..`), or the next travel
        before the open, or just before the open."""
        for k in range(len(self.buf) - 1, -1, -1):
            s = self.buf[k]
            if s.kind != TRAVEL or b" Z" in s.line:
                break  # only feed rates may stand between the travel and the T
            if b" X" in s.line or b" Y" in s.line:
                tool.line += s.line[2:]
                self.buf[k] = tool
                if s.feed:  # the travel's feed rate stays the one in force
                    self.buf.insert(k + 1, Step(OTHER, b"G1 F" + s.feed))
                self.counts.tool_changes_in_travel += 1
                return
        if self.pending_tool is not None:
            self.buf.append(self.pending_tool)
        self.pending_tool = tool

    # ------------------------------------------------------------ open and close
    def _open(self, out: list[bytes]) -> None:
        if not self.selected and self.opens >= OPENS_BEFORE_RESELECT:
            self.counts.reselects += 1
            self.opens = 0
            self._merge_tool(Step(TOOL, b"T%d" % self.nozzle))
        self.selected = False
        self.opens += 1
        if self.pending_tool is not None:
            self.buf.append(self.pending_tool)
            self.pending_tool = None
        self._flush(out, len(self.buf))
        if self.tool_changed and self.valves.kind == "dual":
            self.buf.append(Step(OTHER, b"M109"))
        self.tool_changed = False
        self.open_at = len(self.buf)
        self.buf.append(Step(OPEN, b=1.0, feed=REFILL_FEED))
        self.is_open = True

    def _ejection(self) -> float:
        ejection = self.valves.ejection_mm3
        return ejection[self.nozzle] if self.nozzle < len(ejection) else ejection[-1]

    def _close(self, out: list[bytes]) -> None:
        self.is_open = False
        ej = self._ejection()
        buf = self.buf
        moves: list[int] = []
        total = 0.0  # (a loop: sum() adds generically compiled, with compensation from 3.12)
        k: i64 = self.open_at + 1 if self.open_at >= 0 else 0
        n: i64 = len(buf)
        while k < n:
            s = buf[k]
            if s.kind == EXTRUDE:
                moves.append(k)
                total += s.e
            k += 1
        opening = 1.0
        excess = 0.0
        if not moves:
            self.counts.standing_closes += 1
            self.buf.append(Step(OTHER, b"G0 B0"))
        elif self.buf[moves[-1]].feature == OUTER and self._close_on_inner(moves, ej):
            self.counts.closes_on_inner_wall += 1
            self.counts.closes_on_move += 1
        elif total >= ej - EPSILON or self.open_at < 0:
            self._overwrite(moves[-1], ej, 1.0)
            self.counts.closes_on_move += 1
        else:  # a short path: opened partly, closed over its whole length
            opening = max(total / ej, PARTIAL_B_MINIMUM)
            excess = opening * ej - total
            self._overwrite(moves[-1], total, opening)
            self.counts.partial_opens += 1
            self.counts.closes_on_move += 1
        if self.open_at >= 0:
            o = self.buf[self.open_at]
            o.b = opening
            o.e = self._refill(opening * ej)
            o.word = self.buf[moves[0]].word if moves else self.word
        if excess > EPSILON:
            # the stroke pushed out more than the path's plastic: the next open of this
            # nozzle refills that much less (AutoMaker's balance: the job's volume stays
            # the slicer's)
            self.owed[self.nozzle] = self.owed.get(self.nozzle, 0.0) + excess
        self.open_at = -1
        if len(self.buf) > MAX_BUFFER:
            self._flush(out, len(self.buf))

    def _refill(self, void: float) -> float:
        """The plastic an open feeds: its void, less what the nozzle's last stroke
        pushed out beyond its path's plastic."""
        owed = min(self.owed.pop(self.nozzle, 0.0), void)
        self.counts.refill_mm3 += void - owed
        return void - owed

    def _overwrite(self, last: int, volume: float, opening: float) -> None:
        """The B falls from `opening` to 0 over the last `volume` mm3 of the moves up to
        `last`, their E removed (the move across the start split)."""
        remaining = 0.0
        k = last
        while k >= 0 and volume - remaining > EPSILON:
            s = self.buf[k]
            if s.kind == OPEN:
                break
            if s.kind != EXTRUDE:
                k -= 1
                continue
            v = s.e
            if remaining + v > volume + 1e-7:  # the close starts inside this move: split
                keep = remaining + v - volume
                first = self._split(k, keep / v)
                first.changed = True
                s = self.buf[k + 1]
                v = s.e
            s.b = opening * remaining / volume
            s.e = 0.0
            s.changed = True
            self.counts.removed_mm3 += v
            remaining += v
            k -= 1

    def _split(self, k: int, f: float) -> Step:
        """Move k cut at fraction f of its length: the first part inserted before it,
        with that share of its plastic; returns the first part."""
        s = self.buf[k]
        mx = s.sx + (s.x - s.sx) * f
        my = s.sy + (s.y - s.sy) * f
        first = Step(EXTRUDE, b"G1 X" + number(mx) + b" Y" + number(my), s.sx, s.sy, mx, my,
                     s.e * f, feed=s.feed, feed_in_force=s.feed_in_force, feature=s.feature,
                     word=s.word)
        s.feed = b""
        s.sx, s.sy = mx, my
        s.e -= first.e
        s.changed = first.changed = True
        self.buf.insert(k, first)
        if self.open_at > k:
            self.open_at += 1
        return first

    def _close_on_inner(self, moves: list[int], ej: float) -> bool:
        """The close of an outer wall made on the inner wall run before it."""
        k = len(moves) - 1
        while k >= 0 and self.buf[moves[k]].feature == OUTER:
            k -= 1
        end = k
        while k >= 0 and self.buf[moves[k]].feature == INNER:
            k -= 1
        run = moves[k + 1:end + 1]
        if not run:
            return False
        buf = self.buf
        total = 0.0
        for i in run:
            total += buf[i].e
        if total < ej:
            return False
        # contiguous moves of the run only (a travel inside it breaks the line)
        seam_x, seam_y = self.x, self.y
        best_d = math.inf
        at = -1
        t = 0.0
        for i in run:
            s = buf[i]
            dx, dy = s.x - s.sx, s.y - s.sy
            length2 = dx * dx + dy * dy
            u = 0.0 if length2 == 0 else max(0.0, min(1.0, ((seam_x - s.sx) * dx
                                                              + (seam_y - s.sy) * dy)
                                                             / length2))
            d = math.hypot(s.sx + dx * u - seam_x, s.sy + dy * u - seam_y)
            if d < best_d:
                best_d, at, t = d, i, u
        backwards = self._volume_along(run, at, t, -1)
        forwards = self._volume_along(run, at, t, 1)
        if backwards >= ej:
            direction = -1
        elif forwards >= ej:
            direction = 1
        else:
            return False
        self._copy_close(at, t, direction, ej)
        return True

    def _volume_along(self, run: list[int], at: int, t: float, direction: int) -> float:
        """The plastic of the run's connected moves from move `at` (at fraction t)."""
        s = self.buf[at]
        total = s.e * (t if direction < 0 else 1.0 - t)
        i = run.index(at)
        prev = s
        while 0 <= i + direction < len(run):
            i += direction
            s = self.buf[run[i]]
            joined = (s.x, s.y) == (prev.sx, prev.sy) if direction < 0 else \
                (s.sx, s.sy) == (prev.x, prev.y)
            if not joined:
                break
            total += s.e
            prev = s
        return total

    def _copy_close(self, at: int, t: float, direction: int, ej: float) -> None:
        """Step onto the inner wall at move `at` (fraction t) and run along it in
        `direction` over `ej` of its plastic, the B falling, that plastic's E removed."""
        # the first move run along: the point splits its move (backwards: the part
        # before it, forwards: the part after); at a move's end, backwards is that move
        # and forwards the next; at its start, forwards is that move, backwards the last
        if 0.0 < t < 1.0:
            self._split(at, t)
            if direction > 0:
                at += 1
        elif (t >= 1.0) == (direction > 0):
            at += direction
        feed = self.feed_in_force
        here = (self.x, self.y)
        start = (self.buf[at].x, self.buf[at].y) if direction < 0 else \
            (self.buf[at].sx, self.buf[at].sy)
        moves: list[Step] = []
        if start != here:
            moves.append(Step(CLOSE_MOVE, b"G1 X" + number(start[0]) + b" Y" + number(start[1]),
                              here[0], here[1], start[0], start[1], feed_in_force=feed))
        done = 0.0
        k = at
        prev: Step | None = None
        while ej - done > EPSILON and 0 <= k < len(self.buf):
            s = self.buf[k]
            if s.kind == OTHER or (s.kind == TRAVEL and s.x == s.sx and s.y == s.sy):
                k += direction  # a line that does not move the head (a fan, a feed rate)
                continue
            if s.kind != EXTRUDE:
                break
            if prev is not None and ((s.x, s.y) != (prev.sx, prev.sy) if direction < 0
                                     else (s.sx, s.sy) != (prev.x, prev.y)):
                break
            v = s.e
            if done + v > ej + 1e-7:  # the close ends inside this move: split it
                need = ej - done
                if direction < 0:
                    self._split(k, (v - need) / v)
                    k += 1
                else:
                    self._split(k, need / v)
                s = self.buf[k]
                v = s.e
            a, b = ((s.x, s.y), (s.sx, s.sy)) if direction < 0 else ((s.sx, s.sy), (s.x, s.y))
            done += v
            s.e = 0.0
            s.changed = True
            self.counts.removed_mm3 += v
            moves.append(Step(CLOSE_MOVE, b"G1 X" + number(b[0]) + b" Y" + number(b[1]),
                              a[0], a[1], b[0], b[1], b=max(0.0, 1.0 - done / ej),
                              feed_in_force=s.feed_in_force))
            prev = s
            k += direction
        if moves:
            moves[-1].b = 0.0
            back = moves[-1]
            self.buf.extend(moves)
            # the head stands where the close ended: the next travel starts there
            self.x, self.y = back.x, back.y

    # ------------------------------------------------------------ output
    def _trim(self, out: list[bytes]) -> None:
        """Write out the oldest lines of a long path, keeping the tail a close needs."""
        keep_volume = 2.0 * max(self.valves.ejection_mm3 or (1.0,))
        volume = 0.0
        k = len(self.buf)
        while k > 0 and (volume < keep_volume or len(self.buf) - k < 16):
            k -= 1
            if self.buf[k].kind == EXTRUDE:
                volume += self.buf[k].e
        k = min(k, len(self.buf) - MAX_BUFFER // 2)
        if k <= 0:
            return
        if self.open_at >= 0 and self.open_at < k:
            o = self.buf[self.open_at]
            o.b, o.e, o.word = 1.0, self._refill(self._ejection()), self.word
            self.open_at = -1
        self._flush(out, k)

    def _flush(self, out: list[bytes], count: int) -> None:
        """Write the buffer's first `count` lines."""
        feed = self._written_feed
        for s in self.buf[:count]:
            kind = s.kind
            if kind in (OTHER, TOOL):
                out.append(s.line)
                if b"F" in s.line:  # a feed rate it writes holds for the moves after it
                    m = _FEED.search(s.line)
                    if m and s.line[:1] in b"Gg":
                        feed = m.group(1)
                continue
            if kind == OPEN:
                out.append(b"G1 B" + number(s.b) + s.word + number(s.e) + b" F" + REFILL_FEED
                           if s.e > EPSILON else b"G0 B" + number(s.b))
                if s.e > EPSILON:
                    feed = REFILL_FEED
                continue
            if not s.changed and s.raw:  # as it came, with the feed rate it assumed
                if s.feed:
                    feed = s.feed
                    out.append(s.raw)
                elif s.feed_in_force and feed != s.feed_in_force and len(s.line) > 2:
                    feed = s.feed_in_force
                    out.append(s.raw + b" F" + feed)
                else:
                    out.append(s.raw)
                continue
            line = s.line
            if kind == EXTRUDE and s.e > EPSILON:
                line += s.word + number(s.e)
            if s.b >= 0.0:
                line += b" B" + number(s.b)
            line += s.rest
            if s.feed:
                line += b" F" + s.feed
                feed = s.feed
            elif s.feed_in_force and feed != s.feed_in_force and len(line) > 2:
                line += b" F" + s.feed_in_force
                feed = s.feed_in_force
            out.append(line)
        self._written_feed = feed
        del self.buf[:count]
        if self.open_at >= 0:
            self.open_at -= count
            if self.open_at < 0:
                self.open_at = -1
