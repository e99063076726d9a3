"""Position: where moves go, in the firmware's float arithmetic (position.c).

The firmware keeps, per axis, a destination (where the host asked for,
relative to the tool) and a position (where the machine will be once the
queued moves are done, float32, the rounding residue of each block carried
into the next). X/Y/Z are absolute (G90) or relative (G91); E and D are
always relative and in cubic millimetres, turned into filament length with
the reel's diameter and multiplier; B (the valve) is absolute, 0..1, its
sign flipped for nozzle 1. G0/G1 are split into segments of at most 2 mm of
XYZ travel; each segment's Z gets the bed-levelling correction interpolated
from the Z homes (inverse distance squared, washed out with height). X/Y
travel is clamped to 0..travel once homed; an axis that is not homed does not
move. Homing, tool changes, gantry levelling, the cover unlock and filament
load/unload follow do_homing, do_tool_change, level_gantry, unlock_cover,
do_filament_load/unload and do_move_filament_until_slip. Every 7.2 s the
whole millimetres of filament used come off the reel's remaining length.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Final

from robox.firmware.carith import UINT_MAX, cfloor, cmax, cmin, div, f32, f32_accumulate, to_ulong
from robox.firmware.cline import Line, report_float, strtof
from robox.firmware.gcode import Resumable, Waits
from robox.firmware.motion import FLT_MAX, READY_WAIT
from robox.formats.eeprom import EepromIndex
from robox.formats.protocol import ErrorBit
from robox.hardware.machine import AXES, B, D, E, X, Y, Z
from robox.packed import append, i64, vec

if TYPE_CHECKING:
    from robox.firmware.main import Firmware

DEFAULT_FEED_RATE: Final = 10.0  # units/s
SEGMENT_MM: Final = 2.0
FILAMENT_LOAD_ABANDON: Final = 150.0
FILAMENT_LOAD_SWITCH_OVERTRAVEL: Final = 5.0
FILAMENT_LOAD_DISTANCE_TO_SLIP: Final = 100.0
FILAMENT_LOAD_SPEED_TO_SLIP: Final = 6.66
FILAMENT_UNLOAD_ABANDON: Final = 550.0
FILAMENT_UNLOAD_DISTANCE: Final = 35.0
FILAMENT_SLIP_OVERTRAVEL: Final = 5.0
FILAMENT_SLIP_RETRY_DISTANCE: Final = 8.3
DEFAULT_DIAMETER: Final = 1.75
MAX_GANTRY_ADJUSTMENT: Final = 10.0
LEVELLING_MIN_X_DELTA: Final = 50.0
LEVELLING_POINTS: Final = 9
PARKING_Z: Final = 2.0
B_POSITION_WARNING_TOLERANCE: Final = 0.15
B_POSITION_LOST_TOLERANCE: Final = 0.4
NORMAL: Final = 0
LOADING_E: Final = 1
UNLOADING_E: Final = 2
LOADING_D: Final = 3
UNLOADING_D: Final = 4
REELS: Final = (EepromIndex.REEL0, EepromIndex.REEL1)
#: Status byte 26 for each filament load and unload (busy_state).
_BUSY_STATE: Final = {LOADING_E: b"2", UNLOADING_E: b"3", LOADING_D: b"4", UNLOADING_D: b"5"}


class MoveWatcher:
    """An observer outside the firmware of the moves the position object queues (such
    as `simulate`'s): set as `Position.watcher`, its moved() is called natively,
    compiled, with each queued move's per-axis distances."""

    def moved(self, moves: vec[float]) -> None:
        raise NotImplementedError


class Position:
    #: Called with each queued move's per-axis distances once the position has taken
    #: them in (an observer outside the firmware; None: nobody). `watcher` is told
    #: first, natively (see MoveWatcher).
    #: The vector is reused for the line's next segment: an observer that keeps it copies it.
    on_move: Callable[[vec[float]], None] | None
    watcher: MoveWatcher | None
    # per axis (X Y Z E D B): packed vectors compiled (robox.packed), lists otherwise
    destination: vec[float]
    position: vec[float]
    tool_offset: vec[float]
    # per extruder (E, D): read at every extruding move and by the slip monitor's pass
    diameter: vec[float]
    multiplier: vec[float]
    extruded_mm: vec[float]  # added to at every extruding line
    # (scalars set at power-up, in initialise; the defaults only spare the compiled
    # code a test at every read of whether the attribute was ever set)
    feed_rate: float = 0.0
    feed_multiplier_select: int = 0
    tool: int = 0
    unpark_tool: int = 0
    relative: bool = False
    unpark_relative: bool = False
    unpark_feed_rate: float = 0.0
    z_made_safe: bool = False
    z_washout: float = 0.0
    what: int = NORMAL

    def __init__(self, firmware: Firmware):
        self.fw = firmware
        self.on_move = None
        self.watcher = None
        # position_report's last fields (_reported) and extruder_present's answer
        self._report_values = vec[float]([math.nan] * 4)
        self._report_fields = [b""] * 4
        self._dual_of: bytes | None = None
        self._dual = False

    def initialise(self) -> None:
        self.motion = self.fw.motion
        self.pa: dict[str, Any] = self.fw.parameters.values
        self.feed_rate = DEFAULT_FEED_RATE
        self.feed_multiplier = [1.0, 1.0]
        self.feed_multiplier_select = 0
        self.tool = self.motion.selected_nozzle()
        self.unpark_tool = 0
        self.relative = False
        self.unpark_relative = False
        self.unpark_feed_rate = 0.0
        self.z_made_safe = False
        self.homing_done = [False] * 6
        self.destination = vec[float]([0.0] * 6)
        self.position = vec[float]([0.0] * 6)
        self.tool_offset = vec[float]([0.0] * 6)
        self.unpark_destination = [0.0] * 6
        self.home_delta = [0.0] * 6
        self.diameter = vec[float]([DEFAULT_DIAMETER, DEFAULT_DIAMETER])
        self.multiplier = vec[float]([1.0, 1.0])
        #: (replaced, never changed in place: z_correction keeps it flattened, by identity)
        self.levelling: list[tuple[float, float, float]] = []
        self._flat_of: list[tuple[float, float, float]] | None = None
        self._flat = vec[float]()
        self.z_washout = 0.0
        self.what = NORMAL
        # filament queued since power-up (a model statistic)
        self.extruded_mm = vec[float]([0.0, 0.0])

    # --------------------------------------------------------- parameters
    def _travel(self, axis: int) -> float:
        return self.pa["travel"][AXES[axis]]

    def _head_float(self, address: int, default: float = 0.0) -> float:
        return self.fw.eeproms.float_at(EepromIndex.HEAD, address, default)

    def _tool_float(self, tool: int, offset: int) -> float:
        """A tool's offset from the head EEPROM (0x40 + 0x30 * tool + offset); tools
        beyond 1 have none."""
        return self._head_float(0x40 + tool * 0x30 + offset) if tool < 2 else 0.0

    def filament_multiplier(self, i: i64) -> float:
        return self.multiplier[i]

    # ------------------------------------------------------ levelling
    def _add_levelling_point(self, x: float, y: float, z_delta: float) -> None:
        shifted = [(px, py, f32(pz - z_delta)) for px, py, pz in self.levelling]
        self.levelling = [(x, y, 0.0), *shifted[: LEVELLING_POINTS - 1]]

    def z_correction(self, x_move: float, y_move: float, z_dest: float) -> float:
        points = self.levelling
        if not points:
            return 0.0
        if points is not self._flat_of:
            # the points as one packed vector (compiled: native floats, where the tuples'
            # items are boxed ones), made again when the list is replaced
            flat = vec[float]()
            for px, py, pz in points:
                flat = append(flat, px)
                flat = append(flat, py)
                flat = append(flat, pz)
            self._flat, self._flat_of = flat, points
        flat = self._flat
        x = f32(f32(self.position[X] + x_move) - self.tool_offset[X])
        y = f32(f32(self.position[Y] + y_move) - self.tool_offset[Y])
        total = acc = 0.0
        j: i64
        for j in range(0, len(flat), 3):
            dx = f32(flat[j] - x)
            dy = f32(flat[j + 1] - y)
            pz = flat[j + 2]
            v = f32(f32(dx * dx) + f32(dy * dy))
            if v < 1.0e-10:
                return pz
            v = f32(1.0 / v)
            total = f32(total + v)
            acc = f32(acc + f32(v * pz))
        acc = f32(acc / total)
        v = f32(max(0.0, min(1.0, 1.0 - f32(z_dest * self.z_washout))))
        return f32(acc * v)

    # ------------------------------------------------------------ moves
    def do_move(self, feed_rate: float, speed_limit: float) -> Waits:
        """Queue the move that brings the position to the destination (travel limits,
        tool offsets, levelling), wait for room in the queue, then book the distances
        the steps really make. Returns whether a block was queued (False: every axis was
        within half a step)."""
        moves = vec[float]([0.0] * 6)
        if self._queue_move(feed_rate, speed_limit, moves):
            motion = self.motion
            while not motion.ready_for_more():
                yield READY_WAIT
        return self._book(moves)

    def _queue_move(self, feed_rate: float, speed_limit: float, moves: vec[float]) -> bool:
        """do_move up to add_block_to_buffer's wait for room: `moves` gets the distances
        the steps make; whether a block was queued."""
        parameters = self.fw.parameters
        pos, dest, off = self.position, self.destination, self.tool_offset
        travel = parameters.travel
        for i in range(X, Y + 1):  # (a range: compiled, a tuple's iterator is generic)
            if self.homing_done[i]:
                target = cmax(0.0, cmin(travel[i], f32(dest[i] + off[i])))
                moves[i] = f32(target - pos[i])
        if self.homing_done[Z]:
            target = cmin(travel[Z],
                          cmax(0.0, dest[Z]) + off[Z] + self.z_correction(moves[X], moves[Y],
                                                                          dest[Z]))
            moves[Z] = f32(target - pos[Z])
        check_z_top = pos[Z] + cmax(moves[Z], 0.0) < parameters.z_top_switch_min
        for i in range(E, D + 1):
            moves[i] = f32(dest[i] - pos[i])
        opening = f32(cmax(0.0, cmin(1.0, dest[B])))
        opening = opening if self.tool == 0 else -opening
        moves[B] = f32(opening - pos[B]) if self.homing_done[B] else 0.0
        return self.motion.queue_block(feed_rate, speed_limit, check_z_top, moves)

    def _book(self, moves: vec[float]) -> bool:
        """After the wait: the position moves on by what the steps make."""
        pos = self.position
        for i in range(6):
            pos[i] = f32(pos[i] + moves[i])
        watcher = self.watcher
        if watcher is not None:
            watcher.moved(moves)
        if self.on_move is not None:
            self.on_move(moves)
        moved = False
        for i in range(6):  # any(moves), in a native loop (compiled, any() is generic)
            if moves[i]:
                moved = True
                break
        return moved

    def _quiet_segments(self, step: vec[float], left: int) -> int:
        """After a segment that queued nothing: how many of the next `left` segments
        (each adding `step` to the destinations) queue nothing too.

        For each axis the target is a monotonic function of its destination (a clamp
        to the travel, an offset), and so are the steps add_block would make of it, so
        the segments that leave an axis under half a step are a run from now: found by
        bisection over the exact float sums (`f32_accumulate`). In those segments the
        firmware only adds to the destinations."""
        dest = self.destination
        if self.levelling and step[Z] and self.homing_done[Z]:
            return 0  # the Z correction washes out with height: not monotonic
        quiet = left
        for i in range(6):
            m = step[i]
            if not m or dest[i] != dest[i] or (i not in (E, D) and not self.homing_done[i]):
                continue
            if self._axis_steps(i, dest[i]):
                return 0
            if not self._axis_steps(i, f32_accumulate(dest[i], m, quiet)):
                continue
            lo, hi = 0, quiet  # no step after lo additions, a step after hi
            while hi - lo > 1:
                mid = (lo + hi) // 2
                if self._axis_steps(i, f32_accumulate(dest[i], m, mid)):
                    hi = mid
                else:
                    lo = mid
            quiet = lo
        return quiet

    def _axis_steps(self, i: int, d: float) -> int:
        """The steps do_move and add_block would give axis `i` were its destination `d`
        (no levelling correction)."""
        pos, off = self.position, self.tool_offset
        if i in (X, Y):
            move = f32(cmax(0.0, cmin(self._travel(i), f32(d + off[i]))) - pos[i])
        elif i == Z:
            move = f32(cmin(self._travel(Z), cmax(0.0, d) + off[Z] + 0.0) - pos[Z])
        elif i == B:
            opening = f32(cmax(0.0, cmin(1.0, d)))
            move = f32((opening if self.tool == 0 else -opening) - pos[B])
        else:
            move = f32(d - pos[i])
        return self.motion.steps_for(i, move)

    def move(self, line: Line, rapid: bool = False) -> Waits:
        """G0/G1 (do_g0_g1), as a generator."""
        run = self.begin_move(line, rapid)
        if run is not None:
            yield from run.waits()

    def begin_move(self, line: Line, rapid: bool) -> MoveRun | None:
        """G0/G1 (do_g0_g1) up to its first wait for room in the motion queue: the rest
        of it (None if it needed no wait)."""
        moves = vec[float]([0.0] * 6)
        has_xyz = has_edb = False
        distance = 0.0
        dest = self.destination
        # the letters found in one walk along the line, each read where it is
        found = line.move_letters()  # X, Y, Z, E, D, B, F (cline.MOVE_LETTERS)
        for i in range(X, Z + 1):  # (ranges here: compiled, a tuple's iterator is generic)
            at = found[i]
            if at >= 0:
                value = line.float_after(at)
                moves[i] = value if self.relative else f32(value - dest[i])
                has_xyz = True
                distance = f32(distance + f32(moves[i] * moves[i]))
        distance = f32(math.sqrt(distance))
        for n in range(2):
            i = E + n  # then D
            at = found[i]
            if at >= 0:
                area = f32(self.diameter[n] * self.diameter[n]) * math.pi / 4.0
                moves[i] = f32(div(f32(line.float_after(at) * self.multiplier[n]), area))
                self.feed_multiplier_select = n
                has_edb = True
        at = found[B]
        if at >= 0:
            moves[B] = f32(line.float_after(at) - dest[B])
            has_edb = True
        at = found[6]  # F
        if at >= 0:
            self.feed_rate = f32(line.float_after(at) / 60.0)
        # (unsigned long) of the quotient saturates, so one past it wraps to no segment
        segments = (1 + to_ulong(distance / SEGMENT_MM)) & UINT_MAX
        if segments == 0:
            return None
        for i in range(6):
            moves[i] = f32(moves[i] / f32(segments))
        for n in range(2):
            booked = moves[E + n] * segments
            if booked - booked == 0.0:  # finite (math.isfinite() is a generic call compiled)
                self.extruded_mm[n] += booked
        run = MoveRun(self, moves, segments, rapid, has_xyz, has_edb)
        return None if run.resume() else run

    def select_tool(self, tool: int, line: Line) -> Waits:
        """T0/T1 (do_tool_change): Z first when it goes up, last when it goes down; the
        new nozzle selected before X/Y when the old one hangs lower, after otherwise."""
        tool = max(0, min(2, tool))
        old = self._tool_float(self.tool, 16)
        new_z = self._tool_float(tool, 16)
        z_diff = f32(new_z - old)
        z_move = z_diff
        dest, off = self.destination, self.tool_offset
        if line.has("Z"):
            z_move = f32(z_move + line.float("Z"))
            if not self.relative:
                z_move = f32(z_move - dest[Z])
        for step in range(5):
            if (step == 0 and z_move >= 0.0) or (step == 4 and z_move < 0.0):
                if line.has("Z"):
                    dest[Z] = f32(dest[Z] + line.float("Z")) if self.relative \
                        else line.float("Z")
                off[Z] = new_z
                yield from self.do_move(FLT_MAX, FLT_MAX)
            if (step == 1 and z_diff < 0.0) or (step == 3 and z_diff >= 0.0):
                yield from self._select_valve(tool, line)
                self.tool = tool
            if step == 2:
                for i in (X, Y):
                    c = AXES[i]
                    if line.has(c):
                        dest[i] = f32(dest[i] + line.float(c)) if self.relative \
                            else line.float(c)
                off[X] = f32(self._tool_float(tool, 0) + self.pa["x_offset"])
                off[Y] = f32(self._tool_float(tool, 8) + self.pa["y_offset"])
                yield from self.do_move(FLT_MAX, FLT_MAX)

    def _select_valve(self, tool: int, line: Line) -> Waits:
        if not self.fw.eeproms.head_has_b_axis():
            return
        dest, off = self.destination, self.tool_offset
        delta = f32(max(0.0, min(1.0, dest[B])))  # the previous opening
        delta = f32(delta + abs(off[B]))  # and B offset
        if line.has("B"):
            dest[B] = line.float("B")
        off[B] = self._tool_float(tool, 24)
        opening = f32(max(0.0, min(1.0, dest[B])))
        opening = opening if tool == 0 else -opening
        measured = yield from self.motion.select_nozzle(f32(opening + off[B]), self._travel(B))
        delta = f32(measured - delta)
        if self.homing_done[B]:
            if abs(delta) > B_POSITION_LOST_TOLERANCE:
                self.fw.heaters.enable_nozzle_forcing()
                self.fw.errors.set(ErrorBit.B_POSITION_LOST)
            elif abs(delta) > B_POSITION_WARNING_TOLERANCE:
                self.fw.errors.set(ErrorBit.B_POSITION_WARNING)
            self.home_delta[B] = delta
        self.position[B] = opening
        self.homing_done[B] = True

    def home(self, line: Line) -> Waits:
        """G28 (do_homing): Z made safe once, then X and Y (absolute), then Z
        (nozzle-relative, adding a levelling point); '?' measures without setting."""
        pa = self.pa
        off = self.tool_offset
        off[X] = f32(self._tool_float(self.tool, 0) + pa["x_offset"])
        off[Y] = f32(self._tool_float(self.tool, 8) + pa["y_offset"])
        off[Z] = self._tool_float(self.tool, 16)
        tweak = f32(0.5 * f32(self._head_float(0x50) + self._head_float(0x80))) \
            if self.tool < 2 else 0.0
        if not self.z_made_safe:
            yield from self.motion.make_z_safe()
            self.z_made_safe = True
        measure_only = line.has("?")
        pos, dest = self.position, self.destination
        for i in (X, Y):
            if not line.has(AXES[i]):
                continue
            home_distance = pa["home_distance"][AXES[i]]
            travel = self._travel(i)
            moved = yield from self.motion.home_axis(i, home_distance, f32(1.5 * travel))
            pos[i] = f32(pos[i] + moved)
            self.home_delta[i] = f32(pos[i] - travel) if home_distance >= 0.0 else pos[i]
            if not measure_only:
                pos[i] = travel if home_distance >= 0.0 else 0.0
                dest[i] = f32(pos[i] - off[i])
                self.homing_done[i] = True
            yield from self.do_move(FLT_MAX, FLT_MAX)
        if line.has("Z"):
            home_distance = pa["home_distance"]["Z"]
            moved = yield from self.motion.home_axis(Z, home_distance,
                                                     f32(1.5 * self._travel(Z)))
            pos[Z] = f32(pos[Z] + moved)
            should = f32(f32(home_distance + tweak) + off[Z])
            self.home_delta[Z] = f32(pos[Z] - should)
            if not measure_only:
                pos[Z] = should
                dest[Z] = 0.0
                self.homing_done[Z] = True
                self._add_levelling_point(f32(pos[X] - off[X]), f32(pos[Y] - off[Y]),
                                          self.home_delta[Z])
            yield from self.do_move(FLT_MAX, FLT_MAX)

    def set_position(self, line: Line) -> Waits:
        """G92: wait for motion; the axes given are where the head is, and count as homed."""
        yield from self.motion.wait_until_empty()
        for i in range(X, Z + 1):  # (ranges here: compiled, a tuple's iterator is generic)
            c = AXES[i]
            if line.has(c):
                self.destination[i] = line.float(c)
                self.position[i] = f32(self.destination[i] + self.tool_offset[i])
                self.homing_done[i] = True
                if i == Z:
                    self.position[Z] = f32(self.position[Z]
                                           + self.z_correction(0.0, 0.0, self.destination[Z]))

    def unlock_cover(self, line: Line) -> Waits:
        """G37: home Y if needed; unless S, heaters off and wait for the bed to cool (the
        ambient fan helping); then Y to the unlock position, beyond its travel."""
        if not self.homing_done[Y]:
            yield from self.home(Line(b"Y"))
        heaters = self.fw.heaters
        if not line.has("S"):
            heaters.turn_off()
            heaters.force_ambient_fan = True
            yield from heaters.wait_for_bed_cool()
            heaters.force_ambient_fan = False
        if not self.fw.job.abort_flag:
            moves = vec[float]([0.0] * 6)
            moves[Y] = f32(self.pa["cover_unlock_y"] - self.position[Y])
            yield from self.motion.add_block(FLT_MAX, FLT_MAX, False, moves)
            self.position[Y] = f32(self.position[Y] + moves[Y])
            self.destination[Y] = f32(self.position[Y] - self.tool_offset[Y])

    def level_gantry(self) -> Waits:
        """G38: from the last two Z homes, at least 50 mm apart in X, turn the gantry
        (clamped to 10 mm, MAX_GANTRY_ADJUSTMENT) and correct Z for where it was homed."""
        if len(self.levelling) < 2:
            return
        pa = self.pa
        self.levelling = self.levelling[:2]
        (x0, _y0, z0), (x1, y1, z1) = self.levelling
        x_delta = f32(x0 - x1)
        z_delta = f32(z0 - z1)
        if x_delta < LEVELLING_MIN_X_DELTA:
            return
        za, zb = pa["za_leadscrew_x"], pa["zb_leadscrew_x"]
        adj = f32(f32(z_delta * f32(zb - za)) / x_delta)
        if abs(adj) > MAX_GANTRY_ADJUSTMENT:
            self.fw.errors.set(ErrorBit.MAX_GANTRY_ADJUSTMENT)
            adj = f32(max(-MAX_GANTRY_ADJUSTMENT, min(MAX_GANTRY_ADJUSTMENT, adj)))
        yield from self.motion.rotate_gantry(adj)
        self.levelling = [self.levelling[0], (x1, y1, 0.0)]
        middle = 0.5 * f32(za + zb)
        self.position[Z] = f32(self.position[Z]
                               - adj * (middle - self.levelling[0][0]) / f32(zb - za))
        yield from self.do_move(FLT_MAX, FLT_MAX)

    def level_bed(self, line: Line) -> None:
        """G39: S sets the washout; without it the levelling points are forgotten."""
        if line.has("S"):
            self.z_washout = line.float("S")
        else:
            self.levelling = []

    # ------------------------------------------------------------ filament
    def load_filament(self, line: Line) -> Waits:
        """M120 (do_filament_load): grab each filament named, carriage to the load X,
        load it, then push it on until it slips."""
        pa = self.pa
        motion = self.motion
        started = {E: False, D: False}
        for i in (E, D):
            if line.has(AXES[i]):
                self.what = LOADING_D if i == D else LOADING_E
                started[i] = yield from motion.grab_filament(
                    i, FILAMENT_LOAD_SWITCH_OVERTRAVEL, FILAMENT_LOAD_ABANDON)
        aborting = self.fw.job
        if not aborting.abort_flag and (started[E] or started[D]):
            if not self.homing_done[X]:
                yield from self.home(Line(b"X"))
            if not aborting.abort_flag:
                self.destination[X] = min(pa["filament_load_x"], self._travel(X))
                yield from self.do_move(FLT_MAX, FLT_MAX)
        for i in (E, D):
            if started[i] and not aborting.abort_flag:
                self.what = LOADING_D if i == D else LOADING_E
                loaded = yield from motion.load_filament(
                    i, FILAMENT_LOAD_SWITCH_OVERTRAVEL, pa["home_distance"][AXES[i]])
                if loaded:
                    yield from motion.move_filament_until_slip(
                        i, FILAMENT_SLIP_OVERTRAVEL, FILAMENT_LOAD_DISTANCE_TO_SLIP,
                        FILAMENT_LOAD_SPEED_TO_SLIP)
        self.what = NORMAL

    def unload_filament(self, line: Line, pause: bool) -> Waits:
        """M121 (pausing a running job first) and M122: carriage to the load X, the
        nozzle to its unload temperature, then the filament back out."""
        job = self.fw.job
        heaters = self.fw.heaters
        dual = self.fw.eeproms.head_dual_material()
        for i in (E, D):
            if not line.has(AXES[i]):
                continue
            self.what = UNLOADING_D if i == D else UNLOADING_E
            if pause:
                yield from job.pause_and_park()
            if not job.abort_flag and not self.homing_done[X]:
                yield from self.home(Line(b"X"))
            if not job.abort_flag:
                self.destination[X] = min(self.pa["filament_load_x"], self._travel(X))
                yield from self.do_move(FLT_MAX, FLT_MAX)
            if dual:  # E feeds nozzle 1 and D nozzle 0 on a dual-material head
                yield from heaters.heat_for_filament_unload(line.has("D"), line.has("E"))
            else:
                yield from heaters.heat_for_filament_unload(line.has("E"), line.has("D"))
            if not job.abort_flag:
                yield from self.motion.unload_filament(i, FILAMENT_UNLOAD_DISTANCE,
                                                       FILAMENT_UNLOAD_ABANDON)
        self.what = NORMAL

    def move_filament_until_slip(self, line: Line) -> Waits:
        """G36: each filament named moves until it slips (F: its own speed, mm/min)."""
        speed = f32(line.float("F") / 60.0) if line.has("F") else FLT_MAX
        for i in (E, D):
            c = AXES[i]
            if not line.has(c):
                continue
            v = line.float(c)
            overtravel = min(FILAMENT_SLIP_OVERTRAVEL, abs(v))
            overtravel = -overtravel if v < 0.0 else overtravel
            moved = yield from self.motion.move_filament_until_slip(i, f32(overtravel),
                                                                    f32(abs(v)), speed)
            self.destination[i] = f32(self.destination[i] + moved)
            self.position[i] = f32(self.position[i] + moved)

    def filament_slip_retry(self, extruder: int) -> Waits:
        """Back the filament off 8.3 mm; if the wheel turned, wait 5 s and push it back
        (True), otherwise back it off again (False)."""
        motion = self.motion
        axis = E + extruder
        yield from motion.wait_until_empty()
        motion.has_index_wheel_moved(extruder)
        self.destination[axis] = f32(self.destination[axis] - FILAMENT_SLIP_RETRY_DISTANCE)
        yield from self.do_move(FLT_MAX, FLT_MAX)
        yield from motion.wait_until_empty()
        if motion.has_index_wheel_moved(extruder):
            yield from self.fw.job.delay_aborting(5.0)
            self.destination[axis] = f32(self.destination[axis] + FILAMENT_SLIP_RETRY_DISTANCE)
            yield from self.do_move(FLT_MAX, FLT_MAX)
            yield from motion.wait_until_empty()
            return True
        self.destination[axis] = f32(self.destination[axis] - FILAMENT_SLIP_RETRY_DISTANCE)
        yield from self.do_move(FLT_MAX, FLT_MAX)
        yield from motion.wait_until_empty()
        return False

    # ---------------------------------------------------------- parking
    def park(self) -> Waits:
        """Wait for motion, remember where the job was, close the valve, lift Z 2 mm."""
        yield from self.motion.wait_until_empty()
        self.unpark_relative = self.relative
        self.unpark_feed_rate = self.feed_rate
        self.unpark_tool = self.tool
        self.unpark_destination = list(self.destination)
        self.destination[B] = 0.0
        yield from self.do_move(FLT_MAX, FLT_MAX)
        self.destination[Z] = f32(self.destination[Z] + PARKING_Z)
        yield from self.do_move(FLT_MAX, FLT_MAX)
        yield from self.motion.wait_until_empty()
        self.fw.heaters.pause()

    def unpark(self, reselect_tool: bool = False) -> Waits:
        """Heaters back to temperature, then back to where the job was, its modes and
        its tool; the valve reopens last."""
        yield from self.fw.heaters.resume()
        if self.fw.job.abort_flag:
            return
        self.relative = self.unpark_relative
        self.feed_rate = self.unpark_feed_rate
        saved = self.unpark_destination
        for i in (X, Y, Z):
            self.destination[i] = saved[i]
        self.destination[B] = min(self.destination[B], saved[B])
        if reselect_tool or self.tool != self.unpark_tool:
            yield from self.select_tool(self.unpark_tool, Line(b""))
        else:
            yield from self.do_move(FLT_MAX, FLT_MAX)
        self.destination[B] = saved[B]
        yield from self.do_move(FLT_MAX, FLT_MAX)

    # ------------------------------------------------------ reel settings
    def filament_info_from_reel(self) -> None:
        """Diameter, multiplier and feed-rate multiplier of each extruder from its reel;
        a value stays as it is when that reel is not VALID."""
        eeproms = self.fw.eeproms
        for n, index in enumerate(REELS):
            self.diameter[n] = eeproms.float_at(index, 0x50, self.diameter[n])
            self.multiplier[n] = eeproms.float_at(index, 0x58, self.multiplier[n])
        for n, index in enumerate(REELS):
            self.feed_multiplier[n] = eeproms.float_at(index, 0x60, self.feed_multiplier[n])

    def update_reel_filament_length(self) -> None:
        """Every 7.2 s: the whole millimetres of each extruder's destination come off its
        reel's remaining length (the field is rewritten even when nothing was used)."""
        eeproms = self.fw.eeproms
        for n, index in enumerate(REELS):
            axis = E + n
            used = cfloor(self.destination[axis])
            eeproms.write_float_at(index, 0xB8, f32(eeproms.float_at(index, 0xB8, 0.0) - used))
            self.destination[axis] = f32(self.destination[axis] - used)
            self.position[axis] = f32(self.position[axis] - used)

    def extruder_present(self, extruder: str) -> bool:
        if extruder == "E":
            return True
        head = self.fw.eeproms
        if head.status(EepromIndex.HEAD) != 2:
            return False
        # (every status report asks: the answer is kept for the bank it was read from,
        # an immutable bytes object replaced whenever the head's EEPROM changes)
        bank = head.states[EepromIndex.HEAD].buffer
        if bank is not self._dual_of:
            self._dual_of = bank
            self._dual = bank[:16].rstrip(b"\0 ").endswith(b"DM")
        return self._dual

    def set_filament_info(self, extruder: str, raw: bytes) -> None:
        """0xc8/0xc9: diameter (at least 0.1) and multiplier (at least 0)."""
        n = "ED".index(extruder)
        self.diameter[n] = max(0.1, strtof(raw[:8]))
        self.multiplier[n] = max(0.0, strtof(raw[8:16]))

    def set_feed_rate_multiplier(self, extruder: str, raw: bytes) -> None:
        self.feed_multiplier["ED".index(extruder)] = max(0.0, strtof(raw[:8]))

    # --------------------------------------------------------- reporting
    def _shown(self) -> tuple[float, float, float, float]:
        pos, off = self.position, self.tool_offset
        z = f32(pos[Z] - f32(off[Z] + self.z_correction(0.0, 0.0, self.destination[Z])))
        b = pos[B] if self.tool == 0 else -pos[B]
        return f32(pos[X] - off[X]), f32(pos[Y] - off[Y]), z, b

    def m114_text(self) -> bytes:
        x, y, z, b = self._shown()
        return f"X:{x:f} Y:{y:f} Z:{z:f} B:{b:f} T:{self.tool}\r\n".encode()

    def delta_text(self, axis: str) -> bytes:
        return f"{axis}delta:{self.home_delta[AXES.index(axis)]:f}\r\n".encode()

    def position_report(self) -> bytes:
        """Status bytes 139..171: X, Y, Z, B as float8 (NUL padded), then the tool."""
        x, y, z, b = self._shown()
        return (self._reported(0, x) + self._reported(1, y) + self._reported(2, z)
                + self._reported(3, b) + b"%d" % self.tool)

    def _reported(self, k: i64, value: float) -> bytes:
        """report_float(value, False) for the k-th figure of position_report, the field
        the last report gave it kept (not in report_float's own store: while a job runs
        the head is somewhere else at every report, but Z within a layer and B repeat).
        A zero is worked out each time (-0.0 equals 0.0 and reads otherwise), and so is
        NaN, which equals nothing."""
        if value == self._report_values[k] and value != 0.0:
            return self._report_fields[k]
        field = report_float(value, False)
        self._report_values[k] = value
        self._report_fields[k] = field
        return field

    def filament_report(self) -> bytes:
        """Status bytes 172..219: E and D diameters and multipliers, then the D and E
        feed-rate multipliers."""
        values = (self.diameter[0], self.multiplier[0], self.diameter[1], self.multiplier[1],
                  self.feed_multiplier[1], self.feed_multiplier[0])
        return b"".join(report_float(v) for v in values)

    def busy_state(self) -> bytes | None:
        """Status byte 26 while filament is being loaded ('2', '4') or unloaded ('3', '5')."""
        return _BUSY_STATE.get(self.what)


class MoveRun(Resumable):
    """A G0/G1's segments, queued one by one (do_move, written out for each), each waiting
    for room in the motion queue before the position takes it in."""

    def __init__(self, position: Position, moves: vec[float], segments: int, rapid: bool,
                 has_xyz: bool, has_edb: bool) -> None:
        self.position = position
        self.moves = moves  # each segment's share of the move, per axis
        self.left: i64 = segments
        self.rapid = rapid
        self.has_xyz = has_xyz
        self.has_edb = has_edb
        self.step = vec[float]([0.0] * 6)  # each segment's distances (nothing keeps them)
        self.queued = False  # a segment is queued, waiting for room before it is taken in

    def resume(self) -> bool:
        p = self.position
        motion = p.motion
        moves, step = self.moves, self.step
        dest = p.destination
        if self.queued:
            if not motion.ready_for_more():
                return False
            self.queued = False
            self._taken_in()
        while self.left:
            for i in range(6):
                dest[i] = f32(dest[i] + moves[i])
                step[i] = 0.0
            self.left -= 1
            if self.rapid:
                queued = p._queue_move(FLT_MAX, FLT_MAX, step)
            elif self.has_xyz:
                rate = p.feed_rate
                if self.has_edb:
                    rate = f32(rate * p.feed_multiplier[p.feed_multiplier_select])
                queued = p._queue_move(rate, FLT_MAX, step)
            else:
                queued = p._queue_move(FLT_MAX, p.feed_rate, step)
            if queued and not motion.ready_for_more():
                self.queued = True
                return False
            self._taken_in()
        return True

    def _taken_in(self) -> None:
        """After a segment's wait: the position takes it in."""
        p = self.position
        moved = p._book(self.step)
        if not moved and self.left > 64:
            # a move far past the travel or on axes not homed: the firmware spins
            # through segments that queue nothing; only the destinations change
            moves = self.moves
            still = p._quiet_segments(moves, self.left)
            if still:
                dest = p.destination
                for i in range(6):
                    if moves[i]:
                        dest[i] = f32_accumulate(dest[i], moves[i], still)
                self.left -= still
