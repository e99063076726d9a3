"""Motion: the block queue, look-ahead and the step interrupt, as motion.c does them.

A move becomes a block: its length (steps of the longest axis, one step
interrupt each), a cruise speed, an end speed and per-axis increments in
16.16 fixed point (the longest axis 1.0). Speeds are in the firmware's units
(SPEED_UNITS steps/s); the interrupt's timer runs at 3 MHz and its period is
(0x10000 << 12) / speed_x4k ticks. Each interrupt steps the axes whose
accumulators carry, ramps speed_x4k by min(period, max_period_for_ramping) *
acceleration, caps it by the block's speed and by what the remaining length
allows (isqrt(2 * length * acceleration + end_speed^2 / 16) << 14), and counts
the block's length down, by one each time unless a switch is being watched
and has not yet tripped (homing, nozzle selection, filament loading) or the
distance to give up at has not run out. When a block is queued the end
speeds of all queued blocks are recomputed backwards from it; the queue is
kept just long enough to stop from the last block's speed plus 0.1 s.

The interrupt is modelled exactly, in simulated time: `catch_up()` runs every
interrupt due by the clock, before each loop pass. Runs of interrupts whose
speed cannot change and during which no input the interrupt reads can change
(the cruise of a block, a homing approach at its steady speed, an idle timer)
are done in one go, with the same integer arithmetic, so the result is the
same as doing them one by one.

The foreground routines that wait on motion (queueing a block, homing, nozzle
selection, filament load and unload) are generators: they yield while the
firmware would spin `do_everything_else()`.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, Final

from robox.firmware.carith import (
    cmax,
    cmin,
    div,
    floor_long,
    i64,
    isqrt32,
    to_ulong,
    to_ushort,
    wrap_long,
)
from robox.firmware.carith import f32 as float32
from robox.firmware.carith import sqrt as csqrt
from robox.firmware.gcode import EMPTY_WAIT, READY_WAIT, Waits, wait_for
from robox.formats.protocol import ErrorBit
from robox.hardware.machine import AXES, B, D, E, Machine, X, Y, Z
from robox.packed import vec

if TYPE_CHECKING:
    from robox.firmware.main import Firmware

BUFFER_SIZE: Final = 16
MASK: Final = BUFFER_SIZE - 1
#: A run of interrupts with no cap on how many count the length down: more than any
#: count, and within a tagged integer's range (compiled, 2^62 and beyond is a boxed
#: number, converted at every use).
NO_CAP: Final = 1 << 61
MIN_SPEED: Final = 2
MAX_SPEED: Final = 1200
BOARD_MCK: Final = 96_000_000
TICKS_PER_S: Final = BOARD_MCK // 32
SPEED_UNITS: Final = BOARD_MCK / (65536.0 * 32.0)  # steps/s per speed unit
MARGIN_UNITS: Final = int(32.0 * SPEED_UNITS * 0.1)  # the queue's 0.1 s margin
IDLE_PERIOD: Final = 0x10000 // MIN_SPEED
#: When the step timer starts counting after power-up: its first compare falls this long
#: after power-up plus one period (the simulated hardware's timing, as the recording
#: rig had it; the phase at which a block queued while idle starts)
TIMER_START_S: Final = 0.002
FLT_MAX: Final = 3.4028234663852886e38
FILAMENT_AUTOLOAD_THRESHOLD: Final = 8
FILAMENT_HOLDOFF_S: Final = 4.0
Z_SAFE_RAISE: Final = 3.0
Z_SAFE_LOWER: Final = -20.0
Z_TOP_DEGLITCH: Final = 10
U32: Final = 0xFFFFFFFF

NORMAL: Final = 0
LOADING: Final = 1
UNLOADING: Final = 2
UNTIL_SLIP: Final = 3


#: The movers of a block for each set of moving axes (bit i: axis i moves): shared, never
#: changed once made (compiled, a block's list is then one lookup, not a vector grown)
MOVERS: Final = tuple(vec[i64]([i for i in range(6) if mask >> i & 1]) for mask in range(64))


def _drive_steps(blk: Block, axis: i64) -> i64:
    """The steps (16.16, their size) a block's length makes on `axis`."""
    step: i64 = blk.inc[axis]
    return (step if step > 0 else -step) * blk.length


class Block:
    __slots__ = ("check_z_top", "end_speed", "inc", "length", "movers", "speed", "turn")

    length: i64
    speed: i64
    end_speed: i64
    inc: vec[i64]  # per axis, 16.16 fixed point
    movers: vec[i64]  # the axes whose increment is not 0
    #: the largest change of increment on any axis from the block queued before it (the
    #: junction's limit: both blocks' increments are fixed once this one is queued)
    turn: i64

    def __init__(self) -> None:
        self.length = 0
        self.speed = MIN_SPEED
        self.end_speed = 0
        self.turn = 0
        self.inc = vec[i64]([0] * 6)
        self.check_z_top = False
        self.movers = vec[i64]()


def _max_speed_step(acceleration: int, allowable_error: int) -> int:
    v = 262144.0 * math.sqrt(2.0 * float32(acceleration) * float32(allowable_error))
    return int(max(1.0, min(4294967296.0, v)))


def _braking_radicand(blk: Block, a: i64) -> i64:
    """What the interrupt takes the square root of: twice the acceleration by the length
    left, less one, at most 2^23, and the end speed's square over 16, wrapped at 32 bits
    as the C's sum is."""
    capped: i64 = blk.length - 1
    if capped > 0x00800000:
        capped = 0x00800000
    end_speed: i64 = blk.end_speed
    return ((capped << 1) * a + ((end_speed * end_speed) >> 4)) & U32


def _braking_root(blk: Block, a: i64) -> i64:
    """The interrupt's square root (in speed units, before its shift to the x4k scale):
    the speed from which the block can still slow to its end speed over the length
    left."""
    return isqrt32(_braking_radicand(blk, a))


def _holds(blk: Block, a: i64, s: i64) -> bool:
    """Whether the interrupt's next speed, max(floor, min(root << 14, cruise)), is `s`
    (the x4k scale) again: worked out from the radicand x against squares, not from its
    root r = isqrt(x), as r <= m holds exactly when x < (m + 1)^2."""
    floor_speed: i64 = MIN_SPEED << 12
    top: i64 = blk.speed << 12
    if s < floor_speed:
        return False
    x = _braking_radicand(blk, a)
    if s == floor_speed:  # the lesser of the two at most the floor: r << 14 <= floor
        if top <= floor_speed:
            return True
        m: i64 = floor_speed >> 14
        return x < (m + 1) * (m + 1)
    if top < s:
        return False
    if top == s:  # r << 14 >= s: r at least s / 2^14, rounded up
        c: i64 = (s + 0x3FFF) >> 14
        return x >= c * c
    # below cruise: r << 14 is s itself
    if s & 0x3FFF:
        return False
    r: i64 = s >> 14
    return r * r <= x < (r + 1) * (r + 1)


class Motion:
    # the interrupt's integers: native ones when compiled (robox.native). Their values
    # are set at power-up (initialise); the defaults here only let the compiled code read
    # them without first asking whether they were ever set (an attribute assigned outside
    # __init__ and without a default costs that test at every read)
    speed_x4k: i64 = 0
    timer_period: i64 = 0
    max_period_for_ramping: i64 = 0
    max_speed_step: i64 = 0
    buffer_in: i64 = 0
    buffer_out: i64 = 0
    next_tick: i64 = 0
    last_tick: i64 = 0
    interrupts: i64 = 0
    switch_abandon_counter: i64 = 0
    queued_length: i64 = 0
    holdoff_since: float = 0.0
    switch_select: int = 0
    slip_select: bool = False
    switch_invert: int = 0
    filament_slip: bool = False
    what: int = NORMAL
    active: bool = False
    z_top_counter: int = 0
    acc: vec[i64]  # the step accumulators, per axis
    _slip_inputs: vec[float]
    _slip_thresholds: vec[i64]

    def __init__(self, firmware: Firmware):
        self.fw = firmware

    # ------------------------------------------------------------ set-up
    def initialise(self) -> None:
        fw = self.fw
        self.machine = fw.hw.machine
        self.parameters = fw.parameters
        self.pa: dict[str, Any] = fw.parameters.values
        self.set_acceleration(None)
        self.speed_x4k = MIN_SPEED << 12
        self.timer_period = IDLE_PERIOD
        self.switch_select = 0
        self.slip_select = False
        self.switch_abandon_counter = 0
        self.switch_invert = 0
        self.filament_slip = False
        self.what = NORMAL
        self.buffer_in = 0
        self.buffer_out = 0
        self.block = [Block() for _ in range(BUFFER_SIZE)]
        # the lengths of the queued blocks added up, kept as they are queued and counted
        # down (is_buffer_ready_for_more adds them up each time it asks)
        self.queued_length = 0
        # the steps (16.16, their sizes) the queued blocks after the one at buffer_out
        # make on each drive (E, D), kept as blocks are queued and begun: none of their
        # lengths changes before it is begun (passes_ahead adds the one under way)
        self._tail = vec[i64]([0, 0])
        self.acc = vec[i64]([0] * 6)
        self._block_steps = vec[i64]([0] * 6)  # queue_block's scratch: each axis's steps
        self.active = False
        # the interrupt's own copy of the wheels' levels; starts unknown (0)
        self.last_index = vec[i64]([0, 0])
        self.next_tick = self.tick_of(fw.clock.now + TIMER_START_S) + IDLE_PERIOD
        self.last_tick = self.next_tick - IDLE_PERIOD
        self.autoload_counter = vec[i64]([self.machine.index_wheel(E),
                                          self.machine.index_wheel(D)])
        self.slip_error = [False, False]
        self.index_moved = [False, False]
        self.holdoff_since = fw.clock.now
        self.z_top_counter = 0
        self.interrupts = 0
        # _slip_threshold's last inputs (threshold, steps per unit, multiplier) and
        # answer, per drive (NaN: none yet, equal to nothing)
        self._slip_inputs = vec[float]([math.nan] * 6)
        self._slip_thresholds = vec[i64]([0, 0])

    @staticmethod
    def tick_of(seconds: float) -> i64:
        """The timer tick nearest a moment of the simulated clock."""
        return int(seconds * TICKS_PER_S + 0.5)

    def set_acceleration(self, line) -> None:
        """M201 (and power-up): S acceleration, T allowable error (1..255); the ramp's
        period limit and the junction speed step are worked out again only here."""
        pa = self.pa
        if line is not None:
            if line.has("S"):
                pa["acceleration"] = max(1, min(255, line.uint("S")))
            if line.has("T"):
                pa["allowable_error"] = max(1, min(255, line.uint("T")))
            self.parameters.changed()
        a = pa["acceleration"]
        self.max_period_for_ramping = (0x10000 // math.isqrt(a << 3)) & 0xFFFF
        self.max_speed_step = _max_speed_step(a, pa["allowable_error"])

    # ----------------------------------------------------------- queries
    def empty(self) -> bool:
        return self.buffer_out == self.buffer_in

    def idle(self) -> bool:
        return self.buffer_out == self.buffer_in

    def queued(self) -> i64:
        return (self.buffer_in - self.buffer_out) & MASK

    def ready_for_more(self) -> bool:
        """is_buffer_ready_for_more: not full, and the steps queued are fewer than the
        newest block's speed needs to stop plus a 0.1 s margin."""
        return self._counts_until_ready(self.parameters.acceleration) == 0

    def aborting(self) -> bool:
        return self.fw.job.abort_flag

    # ------------------------------------------------------------ inputs
    def switch_actuated(self, axis: int) -> bool:
        # (the parameters' per-axis copy of M526's settings: a native index, where the
        # settings' dicts are two lookups)
        return self.machine.switch_pin(axis) != self.fw.parameters.invert_switch[axis]

    def z_top_actuated(self) -> bool:
        return self.z_top_counter >= Z_TOP_DEGLITCH

    def selected_nozzle(self) -> int:
        return int(not self.switch_actuated(B))

    def switch_states(self) -> bytes:
        """Status bytes 27..33 (axis switches, lid) and 35..37 (index wheels, Z-top)."""
        # (a character at a time into a buffer: compiled, no generator or list is made)
        out = bytearray(b"0000000")
        i: i64
        for i in range(6):
            if self.switch_actuated(i):
                out[i] = 0x31
        if self.machine.lid_pin():
            out[6] = 0x31
        return bytes(out)

    def index_and_z_top(self) -> bytes:
        m = self.machine
        out = bytearray(b"000")
        if m.index_wheel(E):
            out[0] = 0x31
        if m.index_wheel(D):
            out[1] = 0x31
        if self.z_top_actuated():
            out[2] = 0x31
        return bytes(out)

    def m119_text(self) -> bytes:
        s = [int(self.switch_actuated(i)) for i in range(6)]
        m = self.machine
        return (f"M119 X:{s[0]} Y:{s[1]} Z:{s[2]} Z+:{int(self.z_top_actuated())} "
                f"E:{s[3]} D:{s[4]} B:{s[5]} Eindex:{m.index_wheel(E)} "
                f"Dindex:{m.index_wheel(D)}\r\n").encode()

    # --------------------------------------------------------- foreground
    def maintain(self) -> None:
        self._monitor_index_wheels()
        self._monitor_z_top_switch()
        self._manage_motor_currents()

    def _monitor_index_wheels(self) -> None:
        m = self.machine
        now = self.fw.clock.now
        invert = self.fw.parameters.invert_switch
        acc = self.acc
        counters = self.autoload_counter
        pins: i64 = m.sensor_pins()  # (both sensors in one call)
        i: i64  # (native integers: compiled, the sums and indices below are native)
        for i in range(2):
            axis: i64 = E + i  # then D
            level: i64 = invert[axis]
            if (pins >> i) & 1 == level:  # no filament
                if now - self.holdoff_since < FILAMENT_HOLDOFF_S or not self.empty():
                    if counters[i]:
                        counters[i] = 0
                else:
                    counter: i64 = counters[i]
                    if m.index_wheel(axis) != (counter & 1):
                        counters[i] = counter + 1
                if counters[i] >= FILAMENT_AUTOLOAD_THRESHOLD:
                    self.fw.job.execute_gcode(b"M120 D\n" if i else b"M120 E\n")
                    counters[i] = 0
                held: i64 = acc[axis]
                if held > 0xFFFF:
                    acc[axis] = held & 0xFFFF
                continue
            if counters[i]:
                counters[i] = 0
            until_slip = self.what == UNTIL_SLIP
            threshold = self._slip_threshold(i)
            if until_slip and self.filament_slip:
                acc[axis] &= 0xFFFF
                continue
            if self._slip_count(axis) > threshold:
                acc[axis] &= 0xFFFF
                self.filament_slip = True
                if self.what == LOADING:
                    self.fw.errors.set(ErrorBit.D_LOAD_SLIP if i else ErrorBit.E_LOAD_SLIP)
                elif self.what == UNLOADING:
                    self.fw.errors.set(ErrorBit.D_UNLOAD_SLIP if i else ErrorBit.E_UNLOAD_SLIP)
                elif self.what == NORMAL:
                    self.slip_error[i] = True

    def _slip_threshold(self, i: i64) -> i64:
        """The count (16.16, steps since the wheel's last edge) past which drive i's
        filament has slipped. Every pass asks, and its inputs (M909's threshold, M92's
        steps, the reel's multiplier) hardly ever change: the last answer for each
        drive is kept with the inputs it came from."""
        pa = self.parameters
        threshold_mm = pa.until_slip_threshold_mm if self.what == UNTIL_SLIP \
            else pa.slip_threshold_mm
        spu: float = pa.steps_per_unit[E + i]
        multiplier = self.fw.position.filament_multiplier(i)
        memo = self._slip_inputs
        k: i64 = 3 * i
        if memo[k] == threshold_mm and memo[k + 1] == spu and memo[k + 2] == multiplier:
            return self._slip_thresholds[i]
        temp = float32(float32(float32(spu * threshold_mm) * multiplier) * 65536.0)
        answer: i64 = int(temp) if temp < 2147483648.0 else 0x7FFFFFFF
        memo[k] = threshold_mm
        memo[k + 1] = spu
        memo[k + 2] = multiplier
        self._slip_thresholds[i] = answer
        return answer

    def _slip_count(self, axis: i64) -> i64:
        """The drive's accumulator read as a signed long: its magnitude."""
        count: i64 = self.acc[axis]
        if count & 0x80000000:
            count -= 1 << 32
        return -count if count < 0 else count

    def _monitor_z_top_switch(self) -> None:
        if self.machine.z_top_pin():
            self.z_top_counter = 0
        else:
            self.z_top_counter = min(0xFF, self.z_top_counter + 1)
        if not self.empty() and self.block[self.buffer_out].check_z_top and \
                self.z_top_actuated():
            self.fw.errors.set(ErrorBit.Z_TOP_SWITCH)

    def _manage_motor_currents(self) -> None:
        n = self.buffer_out
        while n != self.buffer_in:  # (a loop, not any() over a generator: native)
            if self.block[n].inc[B]:
                return
            n = (n + 1) & MASK
        self.fw.heaters.force_nozzles_off(False)

    def motors_off(self) -> None:
        """M84: every driver disabled (positions are kept; nothing pushes the axes)."""
        self.machine.motors_on = False

    def is_filament_slip_error(self, i: int) -> bool:
        r = self.slip_error[i]
        self.slip_error[i] = False
        return r

    def has_index_wheel_moved(self, i: int) -> bool:
        r = self.index_moved[i]
        self.index_moved[i] = False
        return r

    # ------------------------------------------------------ queueing moves
    def add_block(self, feed_rate: float, speed_limit: float, check_z_top: bool,
                  moves: vec[float]) -> Waits:
        """add_block_to_buffer: queue `moves` (mm per axis, float32) and wait until the
        queue is ready for more; `moves` is rewritten with the distances the steps make
        (all 0 when the move is shorter than a step: it is absorbed into the next)."""
        if self.queue_block(feed_rate, speed_limit, check_z_top, moves):
            while not self.ready_for_more():
                yield READY_WAIT

    def queue_block(self, feed_rate: float, speed_limit: float, check_z_top: bool,
                    moves: vec[float]) -> bool:
        """add_block_to_buffer up to its wait for room (see add_block): whether a block
        was queued (if not, the move was shorter than a step and `moves` is all 0).
        A caller that queues blocks on every pass waits for room itself, sparing a
        generator per block."""
        parameters = self.fw.parameters
        spu = parameters.steps_per_unit
        steps = self._block_steps  # (every item written below: no vector made per block)
        length: i64 = 0
        # An axis that does not move costs nothing below: every float32() of a zero is
        # zero, and max() with a zero leaves the running value as it was. (Each list item
        # is read into a typed local once: compiled, one unboxing, native arithmetic.)
        for i in range(6):
            move: float = moves[i]
            n: i64 = 0
            if move:
                n = self._steps(i, move, spu[i])
            steps[i] = n
            if n < 0:
                n = -n
            if n > length:
                length = n
        if length < 1:
            for i in range(6):
                moves[i] = 0.0
            return False
        blk = self.block[self.buffer_in]
        blk.length = length
        blk.end_speed = 0
        blk.check_z_top = check_z_top
        if feed_rate > 0.0:
            max_speed = parameters.max_speed
            total = 0.0
            for i in range(6):  # (sum() and math.isfinite() are generic calls compiled)
                total += moves[i]
            if (speed_limit > 0.0 and total - total == 0.0
                    and all(m > 0.0 for m in max_speed)):
                min_duration = 0.0
                for i in range(6):
                    move = moves[i]
                    if move:
                        min_duration = float32(max(min_duration, abs(move) / max_speed[i]))
                v = 0.0
                for i in range(3):
                    move = moves[i]
                    if move:
                        v = float32(v + float32(move * move))
                v = float32(math.sqrt(v))
                min_duration = max(min_duration, float32(v / feed_rate))
                for i in range(3, 6):
                    move = moves[i]
                    if move:
                        min_duration = float32(max(min_duration, abs(move) / speed_limit))
                if min_duration > 0.0:
                    speed = min(float32(MAX_SPEED),
                                float32(float(length)) / (SPEED_UNITS * min_duration))
                else:
                    speed = float(MAX_SPEED)
            else:
                speed = self._speed_exactly(length, feed_rate, speed_limit, moves, max_speed)
            blk.speed = max(MIN_SPEED, to_ushort(speed))
        else:
            blk.speed = MIN_SPEED
        moving: i64 = 0  # the movers, bit i for axis i
        exact = length < 16777216  # whole numbers below 2**24 are floats as they are
        f32_length = float(length) if exact else float32(float(length))
        incs = blk.inc
        before = self.block[(self.buffer_in - 1) & MASK].inc
        turn: i64 = 0
        for i in range(6):
            count: i64 = steps[i]
            per_unit: float = spu[i]
            inc: i64 = 0
            if not count:
                # floor(0.5) / steps per unit: 0, unless M92 made that 0 or NaN
                moves[i] = 0.0 if per_unit > 0.0 else float32(div(0.0, per_unit))
            else:
                f32_steps = float(count) if exact else float32(float(count))
                inc = math.floor(65536.0 * f32_steps / f32_length)
                product = float32(float32(float(inc)) * f32_length)
                moves[i] = float32(div(math.floor((product + 32768.0) / 65536.0), per_unit))
                if inc:
                    moving |= 1 << i
            incs[i] = inc
            change: i64 = inc - before[i]
            if change < 0:
                change = -change
            if change > turn:
                turn = change
        blk.movers = MOVERS[moving]
        blk.turn = turn
        if moving:  # make_motor_active() for each axis that moves, once for them all
            self.machine.motors_on = True
        if incs[B]:
            self.fw.heaters.set_head_power(True)
            self.fw.heaters.force_nozzles_off(True)
        n = self.queued()
        b = self.buffer_in
        if n > 0:  # behind the block at buffer_out: in the tail
            tail = self._tail
            for i in range(2):
                tail[i] += _drive_steps(blk, E + i)
        self.buffer_in = (self.buffer_in + 1) & MASK
        self.queued_length += length
        a: i64 = self.parameters.acceleration  # (read once: nothing here changes it)
        while n > 0:
            prev = (b - 1) & MASK
            end_speed = self._end_speed(self.block[b], a)
            if end_speed == self.block[prev].end_speed:
                break  # so every block before it would come out as it is
            self.block[prev].end_speed = end_speed
            b = prev
            n -= 1
        return True

    def steps_for(self, axis: int, move: float) -> int:
        """The whole steps add_block gives `move` mm on `axis` (on B in chunks of 64
        while the nozzle heaters are forced off)."""
        return self._steps(axis, move, self.pa["steps_per_unit"][AXES[axis]])

    def _steps(self, axis: int, move: float, per_unit: float) -> int:
        """steps_for() with the axis's steps per unit given (a float, not an optional
        one: compiled, passed unboxed)."""
        v = float32(move * per_unit)  # (a float local: compiled, a native product)
        if axis == B and self.fw.heaters.nozzle_forcing:
            return wrap_long(64 * floor_long(v / 64.0 + 0.5))
        v += 0.5
        return math.floor(v) if -2147483648.0 < v < 2147483648.0 else floor_long(v)

    @staticmethod
    def _speed_exactly(length: int, feed_rate: float, speed_limit: float, moves: vec[float],
                       max_speed: vec[float]) -> float:
        """The block's speed before the cast, in add_block_to_buffer's own order, for
        when a number is zero, negative, infinite or NaN (a 0/0 or a NaN met by the
        firmware's max() can decide the result, and a zero's sign can)."""
        min_duration = 0.0
        for i in range(6):
            min_duration = cmax(min_duration, float32(div(abs(moves[i]), max_speed[i])))
        v = 0.0
        for i in range(3):
            v = float32(v + float32(moves[i] * moves[i]))
        v = float32(csqrt(v))
        min_duration = cmax(min_duration, float32(div(v, feed_rate)))
        for i in range(3, 6):
            min_duration = cmax(min_duration, float32(div(abs(moves[i]), speed_limit)))
        return cmin(float(float32(MAX_SPEED)),
                    div(float32(length), SPEED_UNITS * min_duration))

    def _end_speed(self, nxt: Block, a: i64) -> int:
        """The junction speed into `nxt` from the block queued before it (the
        acceleration `a`)."""
        v = (min(0x00800000, nxt.length) << 1) * a
        v += (nxt.end_speed * nxt.end_speed) >> 4
        end_speed = min(nxt.speed, isqrt32(v & U32) << 2)
        if nxt.turn > 0:
            end_speed = min(end_speed, self.max_speed_step // nxt.turn)
        return max(MIN_SPEED, min(MAX_SPEED, end_speed))

    def wait_until_empty(self) -> Waits:
        yield from wait_for(self.empty, EMPTY_WAIT)

    # ------------------------------------------------------- the interrupt
    def catch_up(self) -> None:
        """Run every step interrupt due by now."""
        limit = self.tick_of(self.fw.clock.now)
        # the acceleration read once for the interrupts taken here together (no G-code
        # runs between them to change it)
        a: i64 = self.parameters.acceleration
        while self.next_tick <= limit:
            self._advance(limit, NO_CAP, a)

    def passes_ahead(self, now: float, pass_s: float) -> i64:
        """How many passes (each `pass_s` long) from `now` the loop may skip while motion
        runs, the step interrupts run ahead over them (NO_CAP: any number; under 2:
        none), so that nothing the foreground watches pass by pass changes on the way.
        The Z-top switch is open and no hand is on a filament. For each drive with
        filament in it, no pass in between may see its sensor read otherwise; where the
        sensor finds no filament, each pass only puts the slip count back under a step
        (the automatic load waits for motion to end), as the pass that ends the run
        does; where it finds filament, no pass in between may find a slip: the slip
        count (the accumulator's size) stays within the threshold. Where the queued
        blocks' steps could change either, the passes are as many as the steps to
        spare allow (see `_passes_within`)."""
        m = self.machine
        if m.z_top_pin() != 1 or m.hand_busy():
            return 0
        invert = self.fw.parameters.invert_switch
        most: i64 = NO_CAP
        n: i64 = self.queued()
        i: i64
        k: i64
        for i in range(2):
            axis: i64 = E + i  # then D
            if m.filament[axis] is None:
                continue
            ahead: i64 = 0  # 16.16: the steps the queued blocks make on this drive
            if n:
                ahead = _drive_steps(self.block[self.buffer_out], axis) + self._tail[i]
            # the steps they make, at most (a block's carries out of a fraction that
            # starts under a step)
            steps: i64 = (ahead >> 16) + n
            margin: i64 = m.sensor_margin(axis, True, True)
            if margin <= steps:  # only the ways the blocks drive it count
                forward, back, biggest, fastest = self._queue_reach(axis)
                margin = m.sensor_margin(axis, forward, back)
                if margin <= steps:  # an interrupt makes a step at most
                    k = self._passes_within(margin - 1, fastest, now, pass_s)
                    if k < most:
                        most = k
            if m.switch_pin(axis) == invert[axis]:  # no filament at the sensor
                if self.autoload_counter[i]:
                    return 0
                continue
            if self.what == UNTIL_SLIP and self.filament_slip:
                return 0
            # the count after them, at most: a wheel's edge leaves under a step, and
            # each block that begins puts every fraction at a half step (up to half a
            # step more)
            count: i64 = self._slip_count(axis)
            if count < 0xFFFF:
                count = 0xFFFF
            count += n * 0x8000
            threshold: i64 = self._slip_threshold(i)
            if count + ahead > threshold:
                if count > threshold:
                    return 0
                # an interrupt adds at most the largest increment a queued block has
                forward, back, biggest, fastest = self._queue_reach(axis)
                k = self._passes_within((threshold - count) // biggest, fastest, now,
                                        pass_s)
                if k < most:
                    most = k
        return most

    def _queue_reach(self, axis: i64) -> tuple[bool, bool, i64, i64]:
        """What the queued blocks can do to drive `axis`: whether one feeds it, whether
        one draws it back, the largest increment (16.16, its size; at least 1) one has
        on it, and the highest speed (x 4096) the motion can reach: the speed now, or a
        block's."""
        forward = back = False
        biggest: i64 = 1
        fastest: i64 = self.speed_x4k
        b: i64 = self.buffer_out
        while b != self.buffer_in:
            blk = self.block[b]
            step: i64 = blk.inc[axis]
            if step > 0:
                forward = True
            elif step < 0:
                back = True
                step = -step
            if step > biggest:
                biggest = step
            top: i64 = blk.speed << 12
            if top > fastest:
                fastest = top
            b = (b + 1) & MASK
        return forward, back, biggest, fastest

    def _passes_within(self, interrupts: i64, fastest: i64, now: float,
                       pass_s: float) -> i64:
        """How many passes (each `pass_s` long) from `now` take no more than `interrupts`
        of the coming step interrupts: they come no closer together than the period of
        the speed `fastest` (x 4096), the highest the motion can reach, and a pass takes
        those up to its tick."""
        if interrupts < 1:
            return 0
        if interrupts > 1 << 40:  # (more than any horizon holds: the sums stay native)
            interrupts = 1 << 40
        period: i64 = 1
        if fastest > 0 and 0x10000000 // fastest > 1:
            period = 0x10000000 // fastest
        # the interrupt after the last of them is due at this tick at the soonest; a
        # pass's tick, worked out from the clock's sum, is within a tick of its count
        beyond: i64 = self.next_tick + interrupts * period
        passes: i64 = (beyond - self.tick_of(now) - 2) // self.tick_of(pass_s)
        return passes if passes > 0 else 0

    def run_ahead(self, until: float, kind: str) -> float | None:
        """Run the interrupts due by `until`, stopping after the one that leaves the queue
        ready for more (`kind` "ready") or empty ("empty"); returns when that was (now,
        if it already is), or None if it did not happen by `until`."""
        limit = self.tick_of(until)
        last = self.fw.clock.now
        a: i64 = self.parameters.acceleration  # (as catch_up() reads it)
        ready = kind == "ready"  # (compared once, not at every run of interrupts)
        while True:
            # (statements, not a conditional expression: compiled, one whose arms mix an
            # i64 and an int goes through a boxed number)
            cap: i64
            if ready:
                cap = self._counts_until_ready(a)
            elif self.empty():
                cap = 0
            else:
                cap = NO_CAP
            if cap == 0:
                return last
            if self.next_tick > limit or not self.machine.z_top_pin():
                return None
            self._advance(limit, cap, a)
            last = self.last_tick / TICKS_PER_S

    def _counts_until_ready(self, a: i64) -> i64:
        """How many more counted interrupts until ready_for_more() holds (0: it does);
        NO_CAP when it needs a block to end first (`a`: the acceleration)."""
        n = self.queued()
        if n >= BUFFER_SIZE - 1:
            return NO_CAP
        if n == 0:
            return 0
        length: i64 = self.queued_length
        speed = self.block[(self.buffer_in - 1) & MASK].speed
        v = (((speed // a + MARGIN_UNITS) * speed) & U32) >> 5
        # (statements, not a conditional expression with a literal arm: compiled, that
        # makes the i64 a boxed number on its way out)
        if length < v:
            return 0
        return length - v + 1

    def _advance(self, limit: i64, cap: i64, a: i64) -> None:
        """One interrupt, or a run of them, not past `limit` nor past `cap` counted
        interrupts (NO_CAP: no cap), with the acceleration `a`."""
        if not self.active:
            if self.buffer_in != self.buffer_out:
                if self.block[self.buffer_out].length:
                    self.active = True
                    acc = self.acc
                    for i in range(6):
                        acc[i] = (acc[i] & 0xFFFF0000) | 0x8000
                else:  # never queued by the firmware; skipped as it would be
                    self._next_block()
            if not self.active:  # idle: every interrupt until `limit` is the same
                self.speed_x4k = MIN_SPEED << 12
                self._check_index_wheels()
                self.timer_period = IDLE_PERIOD
                n = (limit - self.next_tick) // IDLE_PERIOD + 1
                self.last_tick = self.next_tick + (n - 1) * IDLE_PERIOD
                self.next_tick += n * IDLE_PERIOD
                self.interrupts += n
                return
        blk = self.block[self.buffer_out]
        m = self.machine
        k = self._run_length(blk, limit, m, cap, a)
        if k > 1:
            self._batch(blk, k, m)
        elif self.switch_abandon_counter == 0:
            wheels = self._wheel_cap(blk, m)
            if wheels < 2:
                self._interrupt(blk, m)
                return
            # the run's first interrupt looks at the wheels (one may have changed at the
            # last interrupt before, another block's); none changes again before its end
            self._check_index_wheels()
            if wheels < cap:
                cap = wheels
            self._singles(blk, limit, cap)
        else:
            self._watched(blk, limit, m, cap)

    def _watched(self, blk: Block, limit: i64, m: Machine, cap: i64) -> None:
        """Interrupts of a block that watches a switch while its speed ramps (a homing, a
        valve run to its switch): a run of them as `_singles` takes them, or with the
        length held while the switch has not tripped, as far as the switch and the
        index wheels cannot change and the abandon count lasts; else one."""
        counter: i64 = self.switch_abandon_counter
        most: i64 = cap if cap < counter else counter
        if self.fw.job.abort_flag or most < 2:  # (an abort counts every interrupt)
            self._interrupt(blk, m)
            return
        quiet = self._quiet_cap(blk, m, self.switch_select)
        if quiet < most:
            most = quiet
        wheels: i64 = self._wheel_cap(blk, m)
        if wheels < most:
            most = wheels
        if most < 2:
            self._interrupt(blk, m)
            return
        counting = (self.slip_select and self.filament_slip) or \
            m.switch_pin(self.switch_select) != self.switch_invert
        before = self.interrupts
        self._check_index_wheels()  # (the run's first interrupt's look)
        if counting:
            self._singles(blk, limit, most)
        else:
            self._held_ramp(blk, limit, most)
        self.switch_abandon_counter = counter - (self.interrupts - before)

    def _held_ramp(self, blk: Block, limit: i64, most: i64) -> None:
        """Up to `most` interrupts that do not count the block's length down (its switch
        has not tripped): the interrupt's arithmetic with the square root's speed fixed
        by the held length, in a tight loop; the steps made at the end, all at once.
        Stops once the speed holds (a run may follow), at `limit` or after `most`."""
        a: i64 = self.parameters.acceleration
        v: i64 = _braking_root(blk, a) << 14
        top: i64 = blk.speed << 12
        if v < top:
            top = v
        maxp: i64 = self.max_period_for_ramping
        floor_speed: i64 = MIN_SPEED << 12
        s: i64 = self.speed_x4k
        period: i64 = self.timer_period
        tick: i64 = self.next_tick
        last: i64 = tick
        end: i64 = limit
        count: i64 = 0
        while True:
            n: i64 = s + (period if period < maxp else maxp) * a
            if top < n:
                n = top
            if n < floor_speed:
                n = floor_speed
            settled = n == s
            s = n
            period = ((0x10000 << 12) // s) & 0xFFFF
            last = tick
            tick += period
            count += 1
            if settled or count >= most or tick > end:
                break
        self._ran(blk, count, s, period, last, tick)

    def _ran(self, blk: Block, count: i64, s: i64, period: i64, last: i64,
             tick: i64) -> None:
        """The end of a run of `count` interrupts worked out in a loop: each moving
        axis's steps made at once, the speed, period and ticks where the last left them."""
        self._step_movers(blk, count)
        self.speed_x4k = s
        self.timer_period = period
        self.last_tick = last
        self.next_tick = tick
        self.interrupts += count

    def _quiet_cap(self, blk: Block, m: Machine, select: int | None) -> i64:
        """How many interrupts of this block leave the switch `select` watches (None:
        none) reading as it does now after each: the fastest motor a microstep short of
        where it could change, whatever its accumulator holds. NO_CAP if none can."""
        quiet: i64 = m.quiet_steps(select)
        if quiet >= (1 << 59):
            return NO_CAP
        biggest: i64 = 0
        for i in blk.movers:
            inc: i64 = blk.inc[i]
            if inc < 0:
                inc = -inc
            if inc > biggest:
                biggest = inc
        if biggest == 0:
            return NO_CAP
        return ((quiet - 1) * 65536 - 65535) // biggest

    def _wheel_cap(self, blk: Block, m: Machine) -> i64:
        """How many interrupts of this block can be made with the index wheels read once,
        before the first: each turning drive's steps may reach its wheel's next edge that
        way only at the last of them (the interrupt after it sees the new level, as one
        interrupt at a time would). Worked out from the drive's accumulator: its
        fraction and increment give the interrupt whose carry is that step. NEVER if no
        wheel turns."""
        most: i64 = 1 << 60
        inc = blk.inc
        acc = self.acc
        for axis in blk.movers:
            if E <= axis <= D:
                step: i64 = inc[axis]
                if step == 0:
                    continue
                margin: i64 = m.wheel_steps(axis, step > 0)
                if margin < (1 << 59):
                    fraction: i64 = acc[axis] & 0xFFFF
                    # the steps after j interrupts: (fraction + j * step) >> 16, rounded
                    # down; the level holds while fewer than `margin` are made
                    if step > 0:
                        k: i64 = (margin * 65536 - 1 - fraction) // step + 1
                    else:
                        k = (fraction + (margin - 1) * 65536) // -step + 1
                    if k < most:
                        most = k
        return most

    def _check_index_wheels(self) -> None:
        levels: i64 = self.machine.index_levels()
        last = self.last_index
        if levels == last[0] | (last[1] << 1):  # (as nearly always: neither has changed)
            return
        i: i64
        for i in range(2):
            if (levels >> i) & 1 != last[i]:
                axis: i64 = E + i  # then D
                last[i] ^= 1
                self.acc[axis] &= 0xFFFF
                self.index_moved[i] = True

    def _counts(self) -> bool:
        """check_switches(): whether this interrupt counts the block's length down."""
        if self.fw.job.abort_flag or self.switch_abandon_counter == 0:
            return True
        self.switch_abandon_counter -= 1
        if self.slip_select and self.filament_slip:
            return True
        return self.machine.switch_pin(self.switch_select) != self.switch_invert

    def _interrupt(self, blk: Block, m: Machine) -> None:
        """One step interrupt, as TC0_IrqHandler does it with a block under way."""
        self._check_index_wheels()
        acc = self.acc
        inc = blk.inc
        for i in blk.movers:
            v: i64 = acc[i]
            w: i64 = (v + inc[i]) & U32
            acc[i] = w
            if (v ^ w) & 0xFFFF0000:
                m.step(i, 1 if inc[i] > 0 else -1)
        a: i64 = self.parameters.acceleration
        v = _braking_root(blk, a)
        # (two-way ifs, not min() of three: compiled, native integers, where a min() of
        # three calls the builtin on boxed ones)
        period: i64 = self.timer_period
        if period > self.max_period_for_ramping:
            period = self.max_period_for_ramping
        s: i64 = self.speed_x4k + period * a
        if v << 14 < s:
            s = v << 14
        top: i64 = blk.speed << 12
        if top < s:
            s = top
        self.speed_x4k = max(MIN_SPEED << 12, s)
        if self._counts():
            blk.length -= 1
            self.queued_length -= 1
        if blk.length == 0:
            self._next_block()
            self.active = False
        self.timer_period = ((0x10000 << 12) // self.speed_x4k) & 0xFFFF
        self.last_tick = self.next_tick
        self.next_tick += self.timer_period
        self.interrupts += 1

    def _singles(self, blk: Block, limit: i64, cap: i64) -> None:
        """Interrupts one at a time while the speed ramps, the same arithmetic as
        `_interrupt` in a tight loop, for a block that watches no switch (or one that
        cannot change meanwhile, and has tripped: see `_watched`), and no further than
        its index wheels can turn without changing level (`cap`). Nothing the
        interrupts read changes on the way, so each axis's steps are made at the end, all
        at once, from its accumulator (as `_batch` does).
        Stops once the speed holds at the block's cruise speed or the floor (a run may
        follow), at the block's end, at `limit` or after `cap` interrupts; a speed that
        holds while the block slows down (the square root's steps) runs on."""
        a: i64 = self.parameters.acceleration
        c: i64 = (blk.end_speed * blk.end_speed) >> 4
        top: i64 = blk.speed << 12
        maxp: i64 = self.max_period_for_ramping
        floor_speed: i64 = MIN_SPEED << 12
        s: i64 = self.speed_x4k
        period: i64 = self.timer_period
        tick: i64 = self.next_tick
        last: i64 = tick
        length: i64 = blk.length
        count: i64 = 0
        most: i64 = cap if cap < length else length
        end: i64 = limit
        n: i64
        v: i64
        # From this length up the square root's speed is at least the cruise speed, so it
        # cannot be the least of the three and need not be worked out: its radicand,
        # 2 * a * min(length, 2^23) + c, grows with the length (when it cannot wrap).
        need: i64 = -(-top >> 14)
        sure: i64 = NO_CAP
        # While the radicand cannot wrap it only falls as the length does, and its root
        # follows from the last one by stepping down (exact, and cheaper than a root).
        unwrapped = (0x00800000 << 1) * a + c <= U32
        if unwrapped:
            sure = max(0, -(-(need * need - c) // (2 * a)))
            if sure > 0x00800000:
                sure = NO_CAP
        x: i64
        root: i64 = 0
        rooted: i64 = -1  # the radicand `root` is the root of (-1: none yet)
        # While the square root holds the speed (below cruise, above the floor) it stays
        # where it is until the radicand falls below root^2, at the length `lowest`: the
        # interrupts up to there repeat one period, and are counted together.
        holding = False
        lowest: i64 = 0
        k: i64
        # (every interrupt speeds up where the speed is not capped: see the loop's own)
        speeding = a > 0 and maxp > 0
        while True:
            if holding:
                k = length - lowest
                if most - count < k:
                    k = most - count
                x = (end - tick) // period + 1  # the interrupt that passes `end`
                if x < k:
                    k = x
                if k > 1:
                    length -= k
                    count += k
                    last = tick + (k - 1) * period
                    tick += k * period
                    capped = length
                    if capped > 0x00800000:
                        capped = 0x00800000
                    rooted = (capped << 1) * a + c
                    if count >= most or tick > end:
                        break
            elif speeding and floor_speed <= s < top \
                    and (length > sure or (unwrapped and rooted >= 0)) \
                    and period * s <= 0x10000000 < (period + 1) * s:
                # Speeding up while neither the cruise speed nor the square root holds
                # the speed back, in a loop of its own: each interrupt adds to the speed,
                # so the period can only fall (the test for a rise is left out), and the
                # root, once the length is short of `sure`, is followed down as the
                # radicand falls. It ends before the interrupt the cruise speed or the
                # root would hold back, or one that needs a root taken afresh: the loop
                # below takes that one.
                ended = False
                while True:
                    n = s + (period if period < maxp else maxp) * a
                    if n >= top:
                        break
                    if length - 1 < sure:
                        if rooted < 0 or not unwrapped or length - 1 > 0x00800000:
                            break
                        x = ((length - 1) << 1) * a + c
                        while root * root > x:
                            root -= 1
                        rooted = x
                        if root << 14 < n:
                            break
                    length -= 1
                    s = n
                    if period * s > 0x10000000:
                        period -= 1
                        if period * s > 0x10000000:
                            period = 0x10000000 // s
                    last = tick
                    tick += period
                    count += 1
                    if count >= most or tick > end:
                        ended = True
                        break
                if ended:
                    break
            length -= 1
            n = s + (period if period < maxp else maxp) * a
            if length < sure:
                capped = length  # (an if, not min(): native compiled, and quick in Python)
                if capped > 0x00800000:
                    capped = 0x00800000
                x = ((capped << 1) * a + c) & U32
                if unwrapped and x <= rooted:
                    while root * root > x:
                        root -= 1
                else:
                    root = isqrt32(x)
                rooted = x
                v = root << 14
                if v < n:
                    n = v
                    holding = unwrapped and floor_speed < v < top
                    if holding:
                        lowest = -(-(root * root - c) // (2 * a))
                        if lowest < 0:
                            lowest = 0
                else:
                    holding = False
            if top < n:
                n = top
            if n < floor_speed:
                n = floor_speed
            settled = n == s and (n == top or n == floor_speed)  # noqa: SIM109 (no tuple)
            s = n
            # the period, (2^28 // s) & 0xFFFF (the mask is idle: s is at least the floor),
            # moves by a unit or two from the last one while the speed ramps: found by
            # checking its product with s, the quotient worked out only past that
            if period * s > 0x10000000:
                period -= 1
                if period * s > 0x10000000:
                    period = 0x10000000 // s
            elif (period + 1) * s <= 0x10000000:
                period += 1
                if (period + 1) * s <= 0x10000000:
                    period = 0x10000000 // s
            if period == 0:
                holding = False
            last = tick
            tick += period
            count += 1
            if settled or count >= most or tick > end:
                break
        self.queued_length -= blk.length - length
        blk.length = length
        self._ran(blk, count, s, period, last, tick)
        if length == 0:
            self._next_block()
            self.active = False

    def _next_block(self) -> None:
        """buffer_out moves on from a block that has ended: the block it comes to, if
        any, is under way and no longer in the tail."""
        out = (self.buffer_out + 1) & MASK
        self.buffer_out = out
        if out != self.buffer_in:
            blk = self.block[out]
            tail = self._tail
            i: i64
            for i in range(2):
                tail[i] -= _drive_steps(blk, E + i)

    def _step_movers(self, blk: Block, n: i64) -> None:
        """`n` interrupts' worth of each moving axis's accumulator at once: the carries
        out of its fraction are the steps it makes (native integers throughout)."""
        acc = self.acc
        inc = blk.inc
        m = self.machine
        for i in blk.movers:
            before: i64 = acc[i]
            moved: i64 = n * inc[i]
            acc[i] = (before + moved) & U32
            m.step(i, ((before & 0xFFFF) + moved) >> 16)

    def _run_length(self, blk: Block, limit: i64, m: Machine, cap: i64,
                    a: i64) -> i64:
        """How many interrupts from now can be done at once (1: one at a time): the speed
        must stay exactly where it is for every one of them, no input the interrupt
        reads may change, the block may not end and `cap` counted ones are the most."""
        s = self.speed_x4k
        c = (blk.end_speed * blk.end_speed) >> 4
        k: i64
        counting = (self.fw.job.abort_flag or self.switch_abandon_counter == 0
                    or (self.slip_select and self.filament_slip))
        watching = not counting
        if watching:
            counting = m.switch_pin(self.switch_select) != self.switch_invert
        length = blk.length
        if length <= 1:
            return 1
        if not _holds(blk, a, s):
            return 1
        if counting:
            if s == MIN_SPEED << 12:
                k = length - 1
            else:
                need = -(-s // 16384)  # v must stay at least this
                rem_min = max(0, -(-(need * need - c) // (2 * a)))
                k = min(length - 1, length - rem_min)
            if cap < k:
                k = cap
        else:
            k = 1 << 40  # the length is not counted down: the speed cannot change
        if k < 2:
            return 1
        if watching:
            k = min(k, self.switch_abandon_counter)
        k = min(k, (limit - self.next_tick) // self.timer_period + 1)
        quiet = self._quiet_cap(blk, m, self.switch_select if watching else None)
        if quiet < k:
            k = quiet
        wheels = self._wheel_cap(blk, m)
        if wheels < k:
            k = wheels
        return k

    def _batch(self, blk: Block, k: i64, m: Machine) -> None:
        """`k` interrupts at a constant speed, no input changing, the block not ending."""
        self._check_index_wheels()
        self._step_movers(blk, k)
        if self.fw.job.abort_flag or self.switch_abandon_counter == 0:
            blk.length -= k
            self.queued_length -= k
        else:
            self.switch_abandon_counter -= k
            if (self.slip_select and self.filament_slip) or \
                    m.switch_pin(self.switch_select) != self.switch_invert:
                blk.length -= k
                self.queued_length -= k
        self.last_tick = self.next_tick + (k - 1) * self.timer_period
        self.next_tick += k * self.timer_period
        self.interrupts += k

    # ------------------------------------------------- switch-bound moves
    def _single(self, axis: int, distance: float) -> vec[float]:
        moves = vec[float]([0.0] * 6)
        moves[axis] = float32(distance)
        return moves

    def home_axis(self, axis: int, home_distance: float, abandon: float) -> Waits:
        """Back off if the switch is already actuated, then run towards it until it trips
        plus the home distance (giving up after `abandon` mm). Returns the distance."""
        pa = self.pa
        spu = pa["steps_per_unit"][AXES[axis]]
        moved = 0.0
        yield from self.wait_until_empty()
        if self.aborting():
            return moved
        self.switch_select = axis
        self.slip_select = False
        self.switch_invert = pa["invert_switch"][AXES[axis]]
        if self.machine.switch_pin(axis) != self.switch_invert:
            moves = self._single(axis, float32(-1.5 * home_distance))
            moved = float32(moved + moves[axis])
            yield from self.add_block(FLT_MAX, FLT_MAX, False, moves)
            yield from self.wait_until_empty()
        if self.aborting():
            return moved
        moves = self._single(axis, home_distance)
        self.switch_abandon_counter = to_ulong(float32(float32(abandon) * spu))
        yield from self.add_block(FLT_MAX, FLT_MAX, False, moves)
        yield from self.wait_until_empty()
        v = float32(abandon - float32(div(float32(float(self.switch_abandon_counter)), spu)))
        moved = float32(moved + (v if home_distance >= 0.0 else -v))
        self.switch_abandon_counter = 0
        return moved

    def make_z_safe(self) -> Waits:
        yield from self.wait_until_empty()
        moves = self._single(Z, Z_SAFE_LOWER if self.z_top_actuated() else Z_SAFE_RAISE)
        yield from self.add_block(FLT_MAX, FLT_MAX, False, moves)
        yield from self.wait_until_empty()

    def rotate_gantry(self, distance: float) -> Waits:
        yield from self.wait_until_empty()
        moves = self._single(Z, float32(0.5 * distance))
        self.machine.gantry_rotation = True
        yield from self.add_block(FLT_MAX, FLT_MAX, False, moves)
        yield from self.wait_until_empty()
        self.machine.gantry_rotation = False

    def select_nozzle(self, distance: float, abandon: float) -> Waits:
        """Move the valve to the side of its switch `distance` asks for (+: nozzle 0),
        backing off first when already there; up to three retries at half speed each,
        then B_POSITION_LOST / B_STUCK. Returns the distance to the switch."""
        pa = self.pa
        spu = pa["steps_per_unit"]["B"]
        invert = pa["invert_switch"]["B"]
        moved = 0.0
        measured = False
        yield from self.wait_until_empty()
        if self.aborting():
            return moved
        self.switch_select = B
        self.slip_select = False
        tries = 4
        speed = pa["max_speed"]["B"]
        negative = distance < 0.0
        for back_off in (True, False):
            factor = -0.25 if back_off else 1.0
            while tries > 0 and ((self.machine.switch_pin(B) == invert) == negative) == back_off:
                self.switch_abandon_counter = to_ulong(float32(float32(abandon) * spu))
                moves = self._single(B, float32(factor * distance))
                self.switch_invert = int((negative == bool(invert)) if back_off
                                         else (negative != bool(invert)))
                yield from self.add_block(FLT_MAX, speed, False, moves)
                yield from self.wait_until_empty()
                if not measured:
                    moved = float32(abandon - float32(float32(float(self.switch_abandon_counter))
                                                      / spu))
                    moved = float32(moved - abs(moves[B]))
                    measured = True
                self.switch_abandon_counter = 0
                if ((self.machine.switch_pin(B) == invert) == negative) == back_off:
                    tries -= 1
                    speed = float32(speed * 0.5)
                    if tries <= 1:
                        self.fw.heaters.enable_nozzle_forcing()
                        self.fw.errors.set(ErrorBit.B_POSITION_LOST)
                if self.aborting():
                    return moved
        if tries == 0:
            self.fw.errors.set(ErrorBit.B_STUCK)
        return moved

    def _watched_move(self, axis: int, what: int, invert: int, slip: bool,
                      abandon_steps: int, distance: float,
                      speed_limit: float = FLT_MAX) -> Waits:
        """Move `axis` by `distance`, its length counted down only once the axis's
        switch reads other than `invert` (or, with `slip`, once the filament slips),
        abandoned after `abandon_steps` interrupts; returns the interrupts left."""
        self.what = what
        self.switch_select = axis
        self.filament_slip = False
        self.slip_select = slip
        self.switch_invert = invert
        self.switch_abandon_counter = abandon_steps
        yield from self.add_block(FLT_MAX, speed_limit, False, self._single(axis, distance))
        yield from self.wait_until_empty()
        left = self.switch_abandon_counter
        self.switch_abandon_counter = 0
        self.what = NORMAL
        return left

    def _abandon_steps(self, axis: int, distance: float) -> int:
        return to_ulong(float32(float32(distance) * self.pa["steps_per_unit"][AXES[axis]]))

    def grab_filament(self, axis: int, overtravel: float, abandon: float) -> Waits:
        invert = self.pa["invert_switch"][AXES[axis]]
        yield from self.wait_until_empty()
        if self.aborting():
            return False
        self.switch_select = axis
        self.filament_slip = False
        self.slip_select = False
        self.switch_invert = invert
        if self.machine.switch_pin(axis) == invert:
            yield from self._watched_move(axis, LOADING, invert, False,
                                          self._abandon_steps(axis, abandon), overtravel)
        return self.switch_actuated(axis)

    def load_filament(self, axis: int, overtravel: float, distance: float) -> Waits:
        spu = self.pa["steps_per_unit"][AXES[axis]]
        yield from self.wait_until_empty()
        if self.aborting():
            return False
        yield from self._watched_move(axis, LOADING,
                                      int(not self.pa["invert_switch"][AXES[axis]]), True,
                                      int((distance - 2.0 * overtravel) * spu), overtravel)
        return not self.filament_slip and self.switch_actuated(axis)

    def unload_filament(self, axis: int, overtravel: float, abandon: float) -> Waits:
        yield from self.wait_until_empty()
        if self.aborting():
            return
        yield from self._watched_move(axis, UNLOADING,
                                      int(not self.pa["invert_switch"][AXES[axis]]), True,
                                      self._abandon_steps(axis, abandon), -overtravel)
        self.holdoff_since = self.fw.clock.now

    def move_filament_until_slip(self, axis: int, overtravel: float, abandon: float,
                                 speed_limit: float) -> Waits:
        invert = self.pa["invert_switch"][AXES[axis]]
        spu = self.pa["steps_per_unit"][AXES[axis]]
        yield from self.wait_until_empty()
        if self.aborting() or self.machine.switch_pin(axis) == invert:
            return 0.0
        left = yield from self._watched_move(axis, UNTIL_SLIP, int(not invert), True,
                                             self._abandon_steps(axis, abandon), overtravel,
                                             speed_limit)
        moved = float32(abandon - float32(float32(left) / spu))
        return moved if overtravel >= 0.0 else -moved


__all__ = ["FLT_MAX", "SPEED_UNITS", "B", "Block", "D", "E", "Motion", "X", "Y", "Z"]
