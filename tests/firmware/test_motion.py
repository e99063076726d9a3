"""Motion and mechanics: each test pins a behaviour of the firmware's motion.c or
position.c (named in its docstring); the step counts, interrupt times and float32
results are worked out here, independently of the model's code."""

import math
import struct

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from robox.firmware import motion as motion_module
from robox.formats.protocol import ErrorBit
from robox.hardware.machine import D, E
from robox.native import compiled_modules
from robox.packed import vec
from tests.firmware.wire import MACROS, job_text

SPU = {"X": 133.7, "Y": 133.7, "Z": 6400.0, "E": 747.0, "B": 2500.0}


def f32(value: float) -> float:
    return struct.unpack("<f", struct.pack("<f", value))[0]


@pytest.fixture
def wire(wire):
    wire.clear()
    return wire


def settle(wire, timeout: float = 3000.0) -> None:
    job = wire.fw.job
    assert wire.printer.run_until(lambda: not job.execute_buffer and job.current is None
                                  and wire.fw.motion.empty(), timeout)


def run(wire, *lines: str, timeout: float = 3000.0) -> None:
    wire.gcode(job_text(list(lines)))
    settle(wire, timeout)


def naive_block(length: int, speed: int, acceleration: int, period: int = 32768,
                s: int = 2 << 12) -> list[int]:
    """The step interrupt's periods for one block from rest to rest, one interrupt at
    a time (TC0_IrqHandler's ramp with end speed 0)."""
    max_period = 0x10000 // math.isqrt(acceleration << 3)
    periods = []
    while length:
        v = math.isqrt(2 * (length - 1) * acceleration)
        s = max(2 << 12, min(v << 14, s + min(period, max_period) * acceleration,
                             speed << 12))
        length -= 1
        period = (0x10000 << 12) // s
        periods.append(period)
    return periods


@pytest.mark.parametrize("acceleration", [4, 9])
def test_a_block_takes_the_time_the_interrupts_ramp_gives(wire, acceleration):
    """add_block_to_buffer's length and speed, TC0_IrqHandler's ramp (M201 S)."""
    run(wire, f"M201 S{acceleration}")
    motion = wire.fw.motion
    moves = vec[float]([1.5, 0.0, 0.0, 0.0, 0.0, 0.0])  # a list in pure Python
    queued = motion.add_block(10.0, motion_module.FLT_MAX, False, moves)
    next(queued)  # queued; the foreground now waits for room
    length = math.floor(f32(1.5 * f32(133.7)) + 0.5)
    min_duration = max(f32(1.5 / f32(200.0)), f32(1.5 / 10.0))  # the feed rate rules
    speed = int(length / (96e6 / (65536 * 32) * min_duration))
    assert (length, motion.block[motion.buffer_out].speed) == (201, speed) == (201, 29)
    start = motion.next_tick  # the idle interrupt that picks the block up
    before = wire.printer.hw.machine.x
    assert wire.printer.run_until(motion.empty, 5)
    periods = naive_block(201, 29, acceleration)
    assert motion.last_tick == start + sum(periods[:-1])
    assert wire.printer.hw.machine.x - before == 201


def scripted_session(wire) -> list[bytes]:
    wire.ok(b"\xa0" + b"58" + b"08" + b"0.650000")
    wire.ok(b"\xa0" + b"88" + b"08" + b"-0.70000")
    out = []
    for text in ("G28 X Y Z", "G1 X50 Y20 F6000", "G1 X52 Y21 Z0.3 F1200", "T1",
                 "G0 B1", "G1 X10 Y30 B0.5 F3000", "G91", "G1 X-3 Y2 F600", "G90", "T0",
                 "G4 P120", "G1 X100 Y100 Z5 F12000", "M201 S7", "G1 X1 Y1 F9000"):
        wire.gcode(job_text([text]))
        for _ in range(3):
            wire.printer.run_until(lambda: False, 0.137)
            out.append(wire.gcode(b"M114\r"))
            out.append(wire.raw(b"\xb0"))
    settle(wire)
    m = wire.printer.hw.machine
    out.append(repr((m.x, m.y, m.za, m.zb, m.b, wire.fw.motion.interrupts,
                     wire.fw.motion.last_tick, wire.fw.clock.now)).encode())
    return out


def fresh_wire():
    from tests.firmware.wire import Wire
    w = Wire()
    w.printer.run_until(lambda: False, 2.0)
    w.clear()
    return w


@pytest.mark.skipif("robox.firmware.motion" in compiled_modules(),
                    reason="a compiled class's methods cannot be replaced; the same source "
                           "is checked by the pure-Python run")
def test_runs_of_interrupts_and_skipped_passes_change_nothing(monkeypatch):
    """The model's fast paths (runs of identical interrupts, the tight ramp loop, passes
    skipped while only motion is awaited) give what one interrupt per call and one
    pass per millisecond give: every reply, position, interrupt count and tick."""
    fast = scripted_session(fresh_wire())
    slow_wire = fresh_wire()
    motion = slow_wire.fw.motion
    monkeypatch.setattr(motion, "passes_ahead", lambda now, pass_s: 0)
    monkeypatch.setattr(motion, "_run_length", lambda *a: 1)
    monkeypatch.setattr(motion, "_singles", lambda blk, limit, cap: motion._interrupt(
        blk, motion.machine))
    monkeypatch.setattr(motion, "_watched", lambda blk, limit, m, cap: motion._interrupt(
        blk, m))
    slow = scripted_session(slow_wire)
    assert len(fast) == 85 and fast == slow


def filament_session(wire, moves: list[str], slip_from: int = -1) -> list[bytes]:
    """A hot nozzle with filament 2 mm short of it: moves that push, extrude and draw
    back, with every reply, the index wheels' reports and the machine at the end."""
    from robox.hardware.machine import NOZZLE_MM

    m = wire.printer.hw.machine
    m.insert_filament(E, tip_mm=NOZZLE_MM - 2.0)
    m.insert_filament(D, tip_mm=NOZZLE_MM - 2.0)
    for name in ("nozzle0", "nozzle1"):
        m.heaters[name].temperature = 210.0
    out = []
    motion = wire.fw.motion
    for n, text in enumerate(("M104 S210 T210", "G28 X Y", *moves)):
        if n == slip_from:  # the wheel stops turning: the slip count runs up to its limit
            m.wheel_slipping[E] = True
        wire.gcode(job_text([text]))
        for _ in range(2):
            wire.printer.run_until(lambda: False, 0.173)
            out.append(wire.gcode(b"M114\r"))
            out.append(wire.gcode(b"M119\r"))  # the index wheels' levels
            out.append(wire.raw(b"\xb0"))
            # the drives' accumulators count the steps since their wheel's last edge
            # (the slip detection's measure): a run that passed an edge unseen shows here
            # and a move that watches a switch counts its interrupts down to abandoning
            out.append(repr((list(motion.acc), list(motion.last_index),
                             list(motion.index_moved), motion.switch_abandon_counter,
                             motion.speed_x4k)).encode())
    settle(wire)
    out.append(repr((m.x, m.y, m.b, m.filament[E], m.filament[D], m.wheel_passed,
                     m.extruded, motion.interrupts, motion.last_tick, motion.slip_error,
                     wire.fw.clock.now)).encode())
    return out


def one_interrupt_at_a_time(monkeypatch, wire) -> None:
    motion = wire.fw.motion
    monkeypatch.setattr(motion, "passes_ahead", lambda now, pass_s: 0)
    monkeypatch.setattr(motion, "_run_length", lambda *a: 1)
    monkeypatch.setattr(motion, "_singles", lambda blk, limit, cap: motion._interrupt(
        blk, motion.machine))
    monkeypatch.setattr(motion, "_watched", lambda blk, limit, m, cap: motion._interrupt(
        blk, m))


_move = st.builds(
    lambda x, y, e, d, f: (f"G1 X{x} Y{y}" if x is not None else "G1") +
    (f" E{e}" if e is not None else "") + (f" D{d}" if d is not None else "") + f" F{f}",
    st.one_of(st.none(), st.integers(5, 200)), st.integers(5, 140),
    st.one_of(st.none(), st.floats(-3.0, 12.0).map(lambda v: round(v, 2))),
    st.one_of(st.none(), st.floats(-1.0, 4.0).map(lambda v: round(v, 2))),
    st.sampled_from([120, 600, 3000, 12000]))


@pytest.mark.skipif("robox.firmware.motion" in compiled_modules(),
                    reason="a compiled class's methods cannot be replaced; the same source "
                           "is checked by the pure-Python run")
@settings(max_examples=25, deadline=None)
@given(st.lists(st.one_of(_move, _move, st.sampled_from(["T0", "T1", "G28 X", "G28 Y"])),
                min_size=1, max_size=6), st.integers(-1, 7))
def test_filament_runs_are_batched_as_one_interrupt_at_a_time_would_run_them(moves,
                                                                              slip_from):
    """With filament in the drives, runs of interrupts (cruise batches and the ramp
    loop, bounded by each drive's own steps to its index wheel's next edge) and the
    passes skipped while only motion is awaited (where no slip count can reach its
    threshold) give what one interrupt per call and one pass per millisecond give:
    every reply, wheel level, slip count, position and tick; also when a wheel stops
    turning part-way and the slip is found, and through the ramps of moves that watch
    a switch (homing, the valve run to its switch on a nozzle change)."""
    fast = filament_session(fresh_wire(), moves, slip_from)
    slow_wire = fresh_wire()
    with pytest.MonkeyPatch.context() as monkeypatch:
        one_interrupt_at_a_time(monkeypatch, slow_wire)
        slow = filament_session(slow_wire, moves, slip_from)
    assert fast == slow


def slipping_job_session(wire, slip_at_line: int) -> list[bytes]:
    """A printing job whose filament stops turning its wheel at a line: the slips the
    job's boss finds, its retries and the pause, sampled every half second."""
    m = wire.printer.hw.machine
    m.insert_filament(E, tip_mm=379.0)
    m.heaters["nozzle0"].temperature = 210.0
    lines = ["M104 S210", "G92 X0 Y0 Z0"] + [
        f"G1 X{10 + i % 5 * 3} Y{i % 7} E{1 + i % 3} F{600 + 300 * (i % 4)}"
        for i in range(60)]
    wire.upload("slips", job_text(lines))
    wire.ok(b"\x94" + b"slips".ljust(16, b"\0"))
    motion = wire.fw.motion
    out = []
    for _ in range(80):
        wire.printer.run_until(lambda: False, 0.5)
        if wire.fw.job.line_number >= slip_at_line:
            m.wheel_slipping[E] = True
        out.append(wire.raw(b"\xb0"))
        out.append(repr((wire.fw.job.line_number, wire.fw.job.pause, list(motion.acc),
                         list(wire.fw.job.slip_count), wire.fw.errors.bits,
                         motion.interrupts, wire.fw.clock.now)).encode())
    return out


@pytest.mark.skipif("robox.firmware.motion" in compiled_modules(),
                    reason="a compiled class's methods cannot be replaced; the same source "
                           "is checked by the pure-Python run")
@pytest.mark.parametrize("slip_at_line", [4, 25, 1000])
def test_passes_skipped_with_filament_in_find_a_slip_at_the_same_pass(slip_at_line):
    """A print with filament in: the loop skips passes while only motion is awaited
    and no slip count can reach its threshold; when the wheel stops, the slip is found,
    retried and the job paused at the very pass one pass at a time finds them."""
    fast = slipping_job_session(fresh_wire(), slip_at_line)
    slow_wire = fresh_wire()
    with pytest.MonkeyPatch.context() as monkeypatch:
        one_interrupt_at_a_time(monkeypatch, slow_wire)
        slow = slipping_job_session(slow_wire, slip_at_line)
    assert fast == slow


def drive_session(wire, tip_mm: float, moves: list[str], slipping: bool,
                  sample_s: float = 0.1,
                  length_mm: float = 240_000.0) -> tuple[list[bytes], int]:
    """Moves of drive E alone, the pass's view of it sampled every `sample_s` while each
    runs and after it (the sensor's reading, the slip count, the automatic load's
    count, slips found, errors, the filament and the interrupts' tick); and the count
    of whole passes the loop ran."""
    from robox.hardware.machine import NOZZLE_MM

    m = wire.printer.hw.machine
    m.insert_filament(E, length_mm=length_mm, tip_mm=tip_mm)
    if tip_mm > NOZZLE_MM - 10.0:
        m.heaters["nozzle0"].temperature = 210.0
        wire.gcode(b"M104 S210\r")
    m.wheel_slipping[E] = slipping
    motion = wire.fw.motion
    out = []
    for text in moves:
        wire.gcode(job_text([text]))
        for _ in range(round(6.0 / sample_s)):
            wire.printer.run_until(lambda: False, sample_s)
            f = m.filament[E]
            out.append(repr((m.switch_pin(E), list(motion.acc), list(motion.autoload_counter),
                             motion.filament_slip, motion.slip_error, wire.fw.errors.bits,
                             f.tip, f.tail, m.extruded[E], motion.interrupts,
                             motion.last_tick, wire.fw.clock.now)).encode())
        out.append(wire.gcode(b"M114\r"))
    return out, wire.fw.whole_passes


@pytest.mark.skipif("robox.firmware.motion" in compiled_modules(),
                    reason="a compiled class's methods cannot be replaced; the same source "
                           "is checked by the pure-Python run")
def test_a_long_push_on_a_wheel_that_stops_skips_passes_and_finds_each_slip_on_time():
    """A push far longer than the slip threshold (10 mm of E) on a wheel that does not
    turn: the loop skips passes as far as the slip count has steps to spare, and finds
    each slip (the count put back, the slip recorded) at the very pass one pass and one
    interrupt at a time finds it."""
    from robox.hardware.machine import NOZZLE_MM

    moves = ["G1 E60 F150", "G1 E90 F400"]
    fast, fast_passes = drive_session(fresh_wire(), NOZZLE_MM - 2.0, moves, True)
    slow_wire = fresh_wire()
    with pytest.MonkeyPatch.context() as monkeypatch:
        one_interrupt_at_a_time(monkeypatch, slow_wire)
        slow, slow_passes = drive_session(slow_wire, NOZZLE_MM - 2.0, moves, True)
    assert fast == slow
    assert b"True" in fast[-2]  # (slips were found)
    assert fast_passes * 4 < slow_passes


@pytest.mark.skipif("robox.firmware.motion" in compiled_modules(),
                    reason="a compiled class's methods cannot be replaced; the same source "
                           "is checked by the pure-Python run")
@pytest.mark.parametrize("tip_mm, length_mm, moves", [
    (13.0, 240_000.0, ["G1 E-8 F60", "G1 E6 F60", "G1 E-8 F60", "G1 E-40 F300"]),
    (30.0, 34.0, ["G1 E20 F300", "G1 E-4 F300"]),
], ids=["drawn-back-past-the-sensor-and-fed-again-then-off-the-drive",
        "fed-until-the-tail-leaves-the-drive"])
def test_filament_at_its_sensors_edge_or_leaving_the_drive_runs_as_step_by_step(
        tip_mm, length_mm, moves):
    """The tip drawn back past the sensor (each pass then puts the slip count back
    under a step, and with motion over the automatic load counts the wheel), fed in
    again, then drawn back off the drive; a reel's end fed until its tail leaves the
    drive (nothing moves it after that): the passes skipped while the sensor cannot
    change, and the runs of steps, give what one pass and one interrupt at a time
    give, the filament stopping where single steps stop it."""
    fast, fast_passes = drive_session(fresh_wire(), tip_mm, moves, False,
                                      length_mm=length_mm)
    slow_wire = fresh_wire()
    with pytest.MonkeyPatch.context() as monkeypatch:
        one_interrupt_at_a_time(monkeypatch, slow_wire)
        slow, slow_passes = drive_session(slow_wire, tip_mm, moves, False,
                                          length_mm=length_mm)
    assert fast == slow
    assert fast_passes * 4 < slow_passes


@settings(max_examples=60, deadline=None)
@given(st.integers(-3, 40), st.integers(1, 40), st.integers(-60, 60))
def test_a_run_of_drive_steps_moves_the_filament_as_the_steps_one_by_one(tip, length, n):
    """Machine.step: a run of n microsteps of drive E leaves the filament, its index
    wheel and what it extruded where n single steps leave them, also when the filament
    leaves the drive part-way (its tail fed past it, its tip drawn back behind it)."""
    from robox.hardware.machine import Filament, Machine

    machines = []
    for steps in ([n], [1 if n > 0 else -1] * abs(n)):
        m = Machine()
        m.filament[E] = Filament(tip=tip, tail=tip - length)
        for step in steps:
            m.step(E, step)
        f = m.filament[E]
        machines.append((f.tip, f.tail, m.wheel_passed[E], m.extruded[E]))
    assert machines[0] == machines[1]


@settings(max_examples=60, deadline=None)
@given(st.booleans(), st.integers(-30, 30), st.integers(-30, 30), st.booleans(),
       st.booleans())
def test_the_sensor_margin_is_the_fewest_steps_that_change_the_sensors_reading(
        near_sensor, tip, tail, forward, back):
    """Machine.sensor_margin: stepping drive E one microstep at a time each way allowed,
    the reading holds for one step fewer than the margin and changes at the margin one
    way or the other; where nothing can change it (no filament under the drive, only a
    way that leads from the sensor) it is NEVER. Tips by the sensor and by the drive,
    tails by the drive (in front of it, the filament has left the drive)."""
    from robox.hardware.machine import NEVER, Filament, Machine

    sensor = Machine()._sensor_steps[E]
    tip_at = sensor + tip if near_sensor else tip
    tail_at = min(tail, tip_at)

    def machine():
        m = Machine()
        m.filament[E] = Filament(tip=tip_at, tail=tail_at)
        return m

    changed_at = []
    for way, allowed in ((1, forward), (-1, back)):
        m = machine()
        before = m.switch_pin(E)
        for n in range(1, sensor + 100 if allowed else 0):
            m.step(E, way)
            if m.switch_pin(E) != before:
                changed_at.append(n)
                break
    margin = machine().sensor_margin(E, forward, back)
    assert margin == (min(changed_at) if changed_at else NEVER)


@pytest.mark.skipif("robox.firmware.main" in compiled_modules(),
                    reason="a compiled class's methods cannot be replaced; the same source "
                           "is checked by the pure-Python run")
def test_the_queued_length_kept_is_the_queued_blocks_lengths_added_up():
    """The running total ready_for_more() reads is, after every pass of a session with
    homing (switch-watched moves), tool changes, dwells and a new acceleration, what
    adding up the queued blocks' lengths gives."""
    w = fresh_wire()
    fw, motion = w.fw, w.fw.motion
    run_passes = fw.run_passes  # (what run_until and run_pass take every pass with)
    seen = []

    def checked(step, passes):
        run_passes(step, passes)
        n, b, total = motion.queued(), motion.buffer_out, 0
        for _ in range(n):
            total += motion.block[b].length
            b = (b + 1) & motion_module.MASK
        seen.append((motion.queued_length, total))

    fw.run_passes = checked
    scripted_session(w)
    assert len(seen) > 300 and any(total for _, total in seen)
    assert all(kept == total for kept, total in seen)


@pytest.mark.skipif("robox.firmware.main" in compiled_modules(),
                    reason="a compiled class's methods cannot be replaced; the same source "
                           "is checked by the pure-Python run")
def test_the_drives_steps_kept_behind_the_block_under_way_are_the_queues():
    """The running totals passes_ahead() reads, each drive's steps in the blocks queued
    behind the one at buffer_out, are after every pass of a job of extruding moves (E
    forwards, then, from an empty queue, back) what walking the queue gives."""
    from tests.firmware.wire import circle_job, ident

    w = fresh_wire()
    fw, motion = w.fw, w.fw.motion
    run_passes = fw.run_passes
    seen = []

    def walked(axis: int) -> int:
        total, n = 0, (motion.buffer_out + 1) & motion_module.MASK
        while motion.buffer_out != motion.buffer_in and n != motion.buffer_in:
            total += abs(motion.block[n].inc[axis]) * motion.block[n].length
            n = (n + 1) & motion_module.MASK
        return total

    def checked(step, passes):
        run_passes(step, passes)
        seen.append((list(motion._tail), [walked(E), walked(D)]))

    fw.run_passes = checked
    # (after M400 the queue fills again from empty: a block queued behind a lone one)
    back = job_text(["M400"] + [f"G1 X{60 + i} Y{40 + i % 7} E-0.6 F4000"
                                for i in range(40)])
    w.upload("tail", circle_job(80, heat=False) + back)
    w.ok(b"\x94" + ident("tail"))
    w.wait_job_done()
    assert len(seen) > 300 and sum(1 for _, walk in seen if walk[0]) > 100
    assert all(kept == walk for kept, walk in seen)


AXIS_SPU = [SPU["X"], SPU["Y"], SPU["Z"], SPU["E"], SPU["E"]]  # X, Y, Z, E, D


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.lists(st.one_of(st.just(0.0), st.floats(-30.0, 30.0, width=32)),
                         min_size=5, max_size=5), min_size=2, max_size=12))
def test_each_block_has_the_steps_increments_and_movers_of_its_own_move(moves):
    """add_block_to_buffer: a block's length is its largest axis's whole steps, each
    axis's increment is floor(65536 * steps / length) (16.16), and the axes the
    interrupt steps are those whose increment is not 0, in axis order. Moves one after
    another, with axes idle in one and moving in the next: nothing of a block carries
    into the one after it."""
    motion = fresh_wire().fw.motion
    for move in moves:
        steps = [math.floor(f32(f32(m) * f32(spu)) + 0.5)
                 for m, spu in zip(move, AXIS_SPU, strict=True)]
        length = max(abs(n) for n in steps)
        at = motion.buffer_in
        queued = motion.queue_block(50.0, 0.0, False, vec[float]([*move, 0.0]))
        assert queued == (length > 0)
        if not queued:
            continue
        incs = [math.floor(65536.0 * n / length) for n in steps] + [0]
        blk = motion.block[at]
        assert blk.length == length
        assert list(blk.inc) == incs
        assert list(blk.movers) == [i for i, inc in enumerate(incs) if inc]


BACK_OFF = math.floor(f32(0.75 * f32(133.7)) + 0.5)  # 100 steps off a closed switch


def expected_x_home(start_steps: int, travel: float = 226.0) -> tuple[int, float]:
    """G28 X with the switch open: run until it trips, then 0.5 mm (67 steps) counted
    from the step that trips it (so it ends 66 steps past); the distance is the
    abandon distance less what is left of it (home_axis)."""
    length = math.floor(f32(-0.5 * f32(133.7)) + 0.5)  # -67
    interrupts = start_steps + (-length - 1)
    counter = int(f32(f32(1.5 * travel) * f32(133.7))) - interrupts
    v = f32(f32(1.5 * travel) - f32(f32(counter) / f32(133.7)))
    return length + 1, v


def x_after_g1(start: float, x: float, spu: float = 133.7) -> float:
    """Where position.c books X after `G1 X` from `start` with no tool offset: the move
    goes in 2 mm segments, each queues whole steps, and add_block_to_buffer rewrites
    each segment as the distance its steps make, which the position adds up in float."""
    distance = f32(abs(x - start))
    segments = 1 + int(distance / 2.0)
    part = f32(f32(x - start) / f32(segments))
    dest = pos = start
    for _ in range(segments):
        dest = f32(dest + part)
        steps = math.floor(f32(f32(dest - pos) * f32(spu)) + 0.5)
        pos = f32(pos + f32(steps / f32(spu)))
    return pos


def test_homing_runs_to_the_switch_and_past_it_by_the_home_distance(wire):
    """home_axis: back off 1.5 x 0.5 mm when the switch is already closed, then run
    towards it until it trips and 0.5 mm more; M111 shows the distance to the switch."""
    run(wire, "G28 X")
    m = wire.printer.hw.machine
    end, v = expected_x_home(BACK_OFF)
    assert (BACK_OFF, m.x, m.za, m.zb) == (100, end, 3 * 6400, 3 * 6400)  # Z made safe
    moved = f32(0.75 - v)
    assert wire.gcode(b"M111\r") == f"Xdelta:{moved:f}\r\nok\r\n".encode()
    assert wire.gcode(b"M119\r").startswith(b"M119 X:1 Y:1 Z:0 Z+:0")
    run(wire, "G1 X20 F6000")
    start = m.x
    assert start == -66 + round(20 * 133.7)
    run(wire, "G28 X")
    end, v = expected_x_home(start)
    assert m.x == end
    position = f32(x_after_g1(0.0, 20.0) - v)  # home_delta: where it was, less the run
    assert wire.gcode(b"M111\r") == f"Xdelta:{position:f}\r\nok\r\n".encode()


def test_tool_changes_run_the_valve_to_its_switch_and_past_by_the_heads_offset(wire):
    """select_nozzle and do_tool_change: back off a quarter of the offset when the wanted
    side is already selected, run to the switch and on by the offset (0xa0 writes the
    head's B offsets at 0x58 and 0x88, as AutoMaker does)."""
    wire.ok(b"\xa0" + b"58" + b"08" + b"0.650000")
    wire.ok(b"\xa0" + b"88" + b"08" + b"-0.70000")
    wire.printer.settle()
    m = wire.printer.hw.machine
    run(wire, "T0")
    back = math.floor(f32(f32(-0.25 * f32(0.65)) * 2500.0) + 0.5)  # -406
    on = math.floor(f32(f32(0.65) * 2500.0) + 0.5)  # 1625, counted from the trip step
    assert m.b == back + (-back) + on - 1 == 1624
    run(wire, "G0 B1")
    assert m.b == 1624 + 2500
    assert wire.gcode(b"M114\r") == b"X:0.000000 Y:0.000000 Z:0.000000 B:1.000000 T:0\r\nok\r\n"
    run(wire, "T1")
    distance = f32(-1.0 + f32(-0.7))
    steps = math.floor(f32(distance * 2500.0) + 0.5)  # -4250
    interrupts = (1624 + 2500 + 1) + (-steps - 1)
    assert m.b == 1624 + 2500 - interrupts == -4250
    assert wire.gcode(b"M114\r").endswith(b"B:1.000000 T:1\r\nok\r\n")
    counter = int(f32(7.0 * 2500.0)) - interrupts
    measured = f32(f32(7.0 - f32(f32(counter) / 2500.0)) - f32(-steps / 2500.0))
    delta = f32(measured - f32(1.0 + f32(0.65)))
    assert wire.gcode(b"M999\r") == f"Bdelta:{delta:f}\r\nok\r\n".encode()
    assert set(wire.ack(b"\xb3")) == {"0"}  # within B_POSITION_WARNING_TOLERANCE


def test_a_valve_switch_that_never_opens_is_b_position_lost_then_b_stuck(wire):
    """select_nozzle's retries at half speed each; the last one enables the nozzle
    forcing work-around and B_POSITION_LOST, running out of them B_STUCK."""
    wire.printer.hw.machine.stuck["B"] = True
    run(wire, "T1", timeout=600)
    errors = wire.ack(b"\xb3")
    assert errors[ErrorBit.B_POSITION_LOST] == "1" and errors[ErrorBit.B_STUCK] == "1"
    assert wire.fw.heaters.nozzle_forcing


def test_a_z_top_switch_closing_below_its_height_is_an_error(wire):
    """monitor_z_top_switch: ten passes of the Z-top input closed while a block that stays
    below M533's height runs."""
    run(wire, "G92 X0 Y0 Z0")
    wire.printer.hw.machine.stuck["Z+"] = True
    run(wire, "G1 Z5 F600")
    assert wire.ack(b"\xb3")[ErrorBit.Z_TOP_SWITCH] == "1"
    assert b"Z+:1" in wire.gcode(b"M119\r")


def test_a_block_that_reaches_m533s_height_does_not_watch_the_z_top_switch(wire):
    """The same closed switch under blocks that each end above M533's height as it
    stands now (lowered from the factory's 79 mm): not watched, no error. (G1 Z5 is
    three segments, the first ending at 1.67 mm.)"""
    run(wire, "G92 X0 Y0 Z0", "M533 Z1.5")
    wire.printer.hw.machine.stuck["Z+"] = True
    run(wire, "G1 Z5 F600")
    assert wire.ack(b"\xb3")[ErrorBit.Z_TOP_SWITCH] == "0"
    run(wire, "M533 Z5.5", "G1 Z0 F600", "G1 Z5 F600")  # below the height again: watched
    assert wire.ack(b"\xb3")[ErrorBit.Z_TOP_SWITCH] == "1"


def level_after_homes(wire, tilt_mm: float) -> None:
    m = wire.printer.hw.machine
    m.zb = round(tilt_mm * 6400)
    run(wire, "G28 X Y", "G1 X20 F6000", "G28 Z", "G1 X200 F6000", "G28 Z", "G38")


def test_g38_levels_a_tilted_gantry_from_two_z_homes(wire):
    """level_gantry: the Z difference of the last two homes, scaled to the leadscrews,
    turns the gantry (ZA against ZB)."""
    level_after_homes(wire, 2.0)
    m = wire.printer.hw.machine
    assert abs(m.za - m.zb) <= 0.02 * 6400
    assert wire.ack(b"\xb3")[ErrorBit.MAX_GANTRY_ADJUSTMENT] == "0"


def test_after_g38_the_bed_correction_weighs_the_levelled_points(wire):
    """level_gantry keeps the last two homes' points, the second's height now 0: the
    correction that follows weighs those, not the points it weighed before."""
    m = wire.printer.hw.machine
    m.zb = round(2.0 * 6400)
    run(wire, "G28 X Y", "G1 X20 F6000", "G28 Z", "G1 X200 F6000", "G28 Z")
    position = wire.fw.position
    position.z_washout = 0.5
    before = list(position.levelling)
    assert len(before) >= 2 and before[1][2] != 0.0
    at_x = f32(f32(position.position[0] + 10.0) - position.tool_offset[0])
    at_y = f32(f32(position.position[1] + 20.0) - position.tool_offset[1])
    assert position.z_correction(10.0, 20.0, 0.2) == weighted_z(before, at_x, at_y, 0.2, 0.5)
    run(wire, "G38")
    (x0, y0, z0), (x1, y1, _) = before[:2]
    after = [(x0, y0, z0), (x1, y1, 0.0)]
    assert position.levelling == after
    at_x = f32(f32(position.position[0] + 10.0) - position.tool_offset[0])
    at_y = f32(f32(position.position[1] + 20.0) - position.tool_offset[1])
    assert position.z_correction(10.0, 20.0, 0.2) == weighted_z(after, at_x, at_y, 0.2, 0.5)


def test_g38_clamps_the_adjustment_at_ten_millimetres(wire):
    level_after_homes(wire, 15.0)
    m = wire.printer.hw.machine
    assert wire.ack(b"\xb3")[ErrorBit.MAX_GANTRY_ADJUSTMENT] == "1"
    assert abs(m.za - m.zb) == pytest.approx(5.0 * 6400, abs=0.05 * 6400)


def test_g37_homes_y_and_drives_past_its_travel_to_unlock_the_door(wire):
    """unlock_cover with S: Y homed first, then to M532's 161.5 mm."""
    m = wire.printer.hw.machine
    assert not m.door_unlocked()
    run(wire, "G37 S")
    home_end, _ = expected_x_home(BACK_OFF, 155.0)  # Y homes as X does
    unlock = math.floor(f32(f32(161.5) * f32(133.7)) + 0.5)
    assert (home_end, m.y) == (-66, home_end + unlock)
    assert m.door_unlocked()


def test_g36_pushes_against_a_cold_nozzle_until_the_filament_slips(wire):
    """move_filament_until_slip: the wheel stops turning at the nozzle and the upper bits
    of the step accumulator pass M909 T (4 mm) of steps: the run ends 5 mm later."""
    m = wire.printer.hw.machine
    m.insert_filament(E, tip_mm=370.0)
    run(wire, "G36 E40 F600")
    assert m.filament[E].tip == m.nozzle_steps(E)
    assert wire.fw.motion.filament_slip
    assert set(wire.ack(b"\xb3")) == {"0"}  # slip was expected: no error


def test_slip_thresholds_follow_m909_m92_and_the_mode(wire):
    """The slip threshold (16.16 steps) is f32(f32(f32(steps/mm * M909's mm) * the
    reel's multiplier) * 65536), worked out afresh whenever one of them changes: M909's
    S (normal moves) and T (G36), M92's E or D."""
    motion = wire.fw.motion

    def expected(spu: float, mm: float) -> int:
        return int(f32(f32(f32(f32(spu) * f32(mm)) * 1.0) * 65536.0))

    assert motion._slip_threshold(0) == expected(747.0, 10.0)
    assert motion._slip_threshold(1) == expected(747.0, 10.0)
    run(wire, "M909 S2.5")
    assert motion._slip_threshold(0) == expected(747.0, 2.5)
    run(wire, "M92 E500")
    assert motion._slip_threshold(0) == expected(500.0, 2.5)
    assert motion._slip_threshold(1) == expected(747.0, 2.5)
    run(wire, "M909 T1.5")
    motion.what = motion_module.UNTIL_SLIP
    try:
        assert motion._slip_threshold(0) == expected(500.0, 1.5)
    finally:
        motion.what = motion_module.NORMAL
    assert motion._slip_threshold(0) == expected(500.0, 2.5)


def test_g36_through_a_hot_nozzle_runs_its_whole_distance(wire):
    m = wire.printer.hw.machine
    m.heaters["nozzle0"].temperature = 200.0
    m.insert_filament(E, tip_mm=370.0)
    run(wire, "G36 E20 F600")
    assert not wire.fw.motion.filament_slip
    extruded = 20 * 747 + 5 * 747 - 10 * 747  # abandon 20 mm, 5 mm over, 10 mm to go
    assert m.extruded[E] == pytest.approx(extruded, abs=3)


def poll_busy(wire, done) -> set[bytes]:
    seen = set()
    while not done():
        seen.add(wire.raw(b"\xb0")[26:27])
        wire.printer.run_until(lambda: False, 0.5)
    return seen


def test_m120_loads_in_stages_and_reports_loading(wire):
    """do_filament_load: grab to the sensor and 5 mm on, carriage to M531's X, load 340 mm
    plus 5, then on until the filament slips at the nozzle; status byte 26 is '2'."""
    m = wire.printer.hw.machine
    m.insert_filament(E)
    wire.gcode(b"M120 E\r")
    seen = poll_busy(wire, lambda: wire.fw.motion.empty() and wire.fw.job.current is None
                     and not wire.fw.job.execute_buffer)
    assert b"2" in seen
    assert m.filament[E].tip == m.nozzle_steps(E)
    assert m.x == pytest.approx(190 * 133.7 - 66, abs=2)
    assert wire.raw(b"\xb0")[26:27] == b"0"


def test_m121_brings_the_nozzle_to_unload_temperature_then_retracts(wire):
    """do_filament_unload: carriage to the load X, the nozzle held at 140 C for 5 s, then
    the filament out until the sensor opens and 35 mm more; status byte 26 is '3'."""
    m = wire.printer.hw.machine
    m.insert_filament(E, tip_mm=380.0)
    start = wire.fw.clock.now
    wire.gcode(b"M121 E\r")
    seen = poll_busy(wire, lambda: wire.fw.motion.empty() and wire.fw.job.current is None
                     and not wire.fw.job.execute_buffer)
    assert b"3" in seen
    assert wire.fw.clock.now - start > 5
    assert not m.filament_present(E)
    assert m.filament[E].tip < 0  # out past the drive, which lets go of it
    assert wire.fw.heaters.nozzle[0].mode == 0


def test_filament_fed_by_hand_starts_a_load(wire):
    """monitor_index_wheels: eight index-wheel edges with no filament at the sensor and
    the motion queue empty queue M120."""
    m = wire.printer.hw.machine
    wire.printer.run_until(lambda: False, 4.5)  # not within 4 s of an unload (or power-up)
    m.insert_filament(E, tip_mm=-5.0)
    m.feed_by_hand(E, 8.0)
    wire.printer.run_until(lambda: wire.fw.position.what != 0, 10)
    assert wire.raw(b"\xb0")[26:27] == b"2"
    settle(wire)
    assert m.filament[E].tip == m.nozzle_steps(E)


def test_a_wheel_that_stops_turning_while_printing_parks_and_reports_no_filament(wire):
    """the_boss's slip handling: park, back off 8.3 mm; the wheel still does not turn,
    so the filament has run out: paused, E_NO_FILAMENT, M121 E queued."""
    m = wire.printer.hw.machine
    m.insert_filament(E, tip_mm=380.0)
    m.heaters["nozzle0"].temperature = 210.0
    m.wheel_slipping[E] = True
    lines = ["G92 X0 Y0 Z0"] + [f"G1 X{10 + i % 2} E2 F600" for i in range(80)]
    wire.upload("slips", job_text(lines))
    wire.ok(b"\x94" + b"slips".ljust(16, b"\0"))
    assert wire.printer.run_until(lambda: wire.fw.errors.is_set(ErrorBit.E_NO_FILAMENT), 300)
    assert wire.fw.job.pause == 1 and wire.fw.job.parked


def test_the_reel_is_charged_the_whole_millimetres_the_job_extruded(wire):
    """update_reel_filament_length every 7.2 s: floor of the E destination, per reel."""
    from robox.formats.eeprom import EepromIndex
    eeproms = wire.fw.eeproms
    before = eeproms.get_float(EepromIndex.REEL0, "remaining_filament")
    volumes = [0.37 + 0.011 * i for i in range(300)]
    lines = ["G92 X0 Y0 Z0"] + [f"G1 X{(i % 10) * 2} E{v:.4f} F3000"
                               for i, v in enumerate(volumes)]
    wire.upload("charged", job_text(lines))
    wire.ok(b"\x94" + b"charged".ljust(16, b"\0"))
    wire.wait_job_done()
    wire.printer.run_until(lambda: False, 8.0)
    area = f32(f32(1.75 * 1.75) * math.pi / 4.0)
    total = sum(volumes) / area
    after = eeproms.get_float(EepromIndex.REEL0, "remaining_filament")
    assert before - after == pytest.approx(math.floor(total), abs=1)
    assert 0 <= wire.fw.position.destination[3] < 1




@pytest.mark.parametrize("name", list(MACROS))
def test_automaker_macro_shapes_run_as_jobs(wire, name):
    """Each shape of AutoMaker's macros, as a job file on the card, runs to its end."""
    m = wire.printer.hw.machine
    m.insert_filament(E, tip_mm=380.0)
    wire.ok(b"\xa0" + b"58" + b"08" + b"0.650000")
    wire.ok(b"\xa0" + b"88" + b"08" + b"-0.70000")
    file_id = name.replace(" ", "")[:16]
    wire.upload(file_id, job_text(MACROS[name]))
    wire.ok(b"\x94" + file_id.encode().ljust(16, b"\0"))
    wire.wait_job_done(3000)
    assert ("job finished", file_id.encode().ljust(16, b"\0")) in wire.fw.events
    assert not wire.fw.errors.is_set(ErrorBit.B_STUCK)
    if name == "level gantry":
        assert abs(m.za - m.zb) <= 0.02 * 6400
    if name == "eject stuck material":
        assert not m.filament_present(E)
    if name == "home all":
        assert m.x == m.y == -66


def automaker_shaped_job(volumes: list[float]) -> str:
    """A job as AutoMaker's post-processor lays one out (our own words): its header, the
    pre-print macro, layers of volumetric E moves between valve opens and closes, the
    post-print macro, and the trailer stating each extruder's volume (the sum of the
    extrusions' E and D, in mm3)."""
    lines = ["; File post-processed by the CEL Tech Roboxiser on Mon 2 Jan 2017 10:00:00",
             ";", "; Pre print gcode", "M104 S210", "G28 X Y Z", "M109", "T0",
             "; End of Pre print gcode", ";LAYER:0", "G0 Z0.3"]
    for i, v in enumerate(volumes):
        if i % 20 == 0:
            lines += ["G1 B0 F150 ; close", f"G0 X{20 + i // 20 * 10} Y20", "G1 B1 F150 ; open"]
        lines.append(f"G1 X{20 + i // 20 * 10 + (i % 2) * 4} Y{20 + i % 20 * 2} E{v:.5f} F1800")
    lines += ["G1 B0 F150", ";", "; Post print gcode", "M104 S0", "G0 Z20",
              "; End of Post print gcode", ";", "; Extruder E", "; ----------",
              f"; Volume of material - {sum(volumes)!r}", "; Extruder D", "; ----------",
              "; Volume of material - 0.0", ";"]
    return "\r".join(lines) + "\r"


def trailer_volumes(text: str) -> dict[str, float]:
    """{'E': mm3, 'D': mm3} from an AutoMaker job's trailer."""
    found, extruder = {}, None
    for line in text.split("\r"):
        if line.startswith("; Extruder "):
            extruder = line.split()[-1]
        elif line.startswith("; Volume of material - ") and extruder:
            found[extruder] = float(line.rsplit(" ", 1)[1])
    return found


def test_an_automaker_job_extrudes_and_books_the_volume_its_trailer_states(wire):
    """position.c converts each E (mm3) through the reel's diameter into steps, carrying
    the rounding into the next move; update_reel_filament_length books whole mm every
    7.2 s. The hot nozzle passes exactly the filament the steps drive."""
    from robox.formats.eeprom import EepromIndex
    m = wire.printer.hw.machine
    m.insert_filament(E, tip_mm=380.0)
    wire.ok(b"\xa0" + b"58" + b"08" + b"0.650000")
    wire.ok(b"\xa0" + b"88" + b"08" + b"-0.70000")
    eeproms = wire.fw.eeproms
    before = eeproms.get_float(EepromIndex.REEL0, "remaining_filament")
    text = automaker_shaped_job([0.21 + 0.0037 * (i % 17) for i in range(60)])
    stated = trailer_volumes(text)
    wire.upload("automaker", text.encode())
    wire.ok(b"\x94" + b"automaker".ljust(16, b"\0"))
    wire.wait_job_done(3000)
    assert ("job finished", b"automaker".ljust(16, b"\0")) in wire.fw.events
    wire.printer.run_until(lambda: False, 8.0)  # one more bookkeeping tick
    area = f32(f32(1.75 * 1.75) * math.pi / 4.0)
    filament_mm = stated["E"] / area
    assert abs(m.extruded[E] - filament_mm * SPU["E"]) <= 1  # whole steps, rounding carried
    assert m.extruded[D] == 0 and stated["D"] == 0.0
    after = eeproms.get_float(EepromIndex.REEL0, "remaining_filament")
    assert before - after == math.floor(filament_mm)
    # the only error: with no host connected, the reel's 210 C against the melt temperature
    # the head recorded (none) asks for a nozzle flush (get_nozzle_targets_from_reel)
    assert wire.fw.errors.bits == 1 << ErrorBit.NOZZLE_FLUSH_NEEDED


def reference_ramp(length, speed, end_speed, a, s, period, maxp, tick, limit, cap):
    """TC0_IrqHandler's speed update one interrupt at a time, the square root taken at
    every interrupt (its 23-bit cap and 32-bit wrap included), stopping where the tight
    loop stops: the speed held at cruise or floor, the block's end, the limit, the cap."""
    count, c, top, floor_speed = 0, (end_speed * end_speed) >> 4, speed << 12, 2 << 12
    cap = length if cap is None else min(cap, length)
    while True:
        length -= 1
        v = math.isqrt(((min(length, 0x00800000) << 1) * a + c) & 0xFFFFFFFF) << 14
        n = max(floor_speed, min(v, s + min(period, maxp) * a, top))
        settled = n == s and n in (top, floor_speed)
        s, period = n, ((0x10000 << 12) // n) & 0xFFFF
        last = tick
        tick += period
        count += 1
        if settled or count >= cap or tick > limit:
            return count, length, s, period, last, tick


@settings(max_examples=400, deadline=None)
@given(length=st.one_of(st.integers(1, 3000), st.integers(0x007FFF00, 1 << 24)),
       speed=st.integers(2, 0xFFFF), end_speed=st.one_of(st.integers(0, 300),
                                                          st.integers(0, 0xFFFF)),
       a=st.one_of(st.integers(1, 255), st.just(255)), start=st.integers(2, 0xFFFF),
       cap=st.one_of(st.none(), st.integers(1, 5000)),
       limit=st.one_of(st.just(3 << 32), st.integers(0, 1 << 22)))
# cruising at 5 << 12, the root's 1 << 14 (one step left) is below it: the bound on the
# root rounds the cruise speed up, not down
@example(length=2, speed=5, end_speed=0, a=1, start=5, cap=None, limit=3 << 32)
# slowing down at a held root, the interrupt that passes the limit ends a run part-way
@example(length=3000, speed=0xFFFF, end_speed=0, a=40, start=200, cap=None, limit=60_000)
# speeding up from the floor in the loop that leaves the root out, to the cruise speed,
# then slowing down by the root to the block's end
@example(length=3000, speed=300, end_speed=0, a=4, start=2, cap=None, limit=3 << 32)
def test_the_ramp_loop_gives_the_interrupts_speeds_one_by_one(length, speed, end_speed, a,
                                                              start, cap, limit):
    """The tight ramp loop (the model leaves out the square root while it cannot be the
    least speed, and counts together the interrupts at which it holds the speed) against
    the interrupt's arithmetic taken literally: short blocks, where the square root
    brings the speed down, and blocks past 2^23 steps, where its radicand wraps at 32
    bits when the end speed is high; stopped by the cap, the block's end or the limit."""
    from tests.firmware.wire import Wire
    motion = _ramp_motion.setdefault("m", Wire().fw.motion)
    motion.pa["acceleration"] = a
    motion.parameters.changed()  # as M201 would
    maxp = (0x10000 // math.isqrt(a << 3)) & 0xFFFF
    motion.max_period_for_ramping = maxp
    blk = motion_module.Block()
    blk.length, blk.speed, blk.end_speed = length, speed, end_speed  # (no axis moves)
    s = min(start, speed) << 12
    motion.speed_x4k, motion.timer_period = s, ((0x10000 << 12) // s) & 0xFFFF
    motion.next_tick, motion.active = 0, True
    if cap is None and length > 3000:
        cap = 20_000  # a speed the square root holds below cruise runs to the block's end
    expected = reference_ramp(length, speed, end_speed, a, s, motion.timer_period, maxp, 0,
                              limit, cap)
    before = motion.interrupts
    motion._singles(blk, limit, motion_module.NO_CAP if cap is None else cap)
    count, left, s, period, last, tick = expected
    assert (motion.interrupts - before, blk.length, motion.speed_x4k, motion.timer_period,
            motion.last_tick, motion.next_tick) == (count, left, s, period, last, tick)


_ramp_motion: dict = {}


_HEIGHTS = st.one_of(st.integers(-(1 << 22), 1 << 22), st.integers(607990, 608010))
_CARRIAGE = st.one_of(st.integers(-40000, 70000), st.integers(-5025, -5010),
                      st.integers(33615, 33635))


@settings(max_examples=1000, deadline=None)
@given(za=_HEIGHTS, zb=_HEIGHTS, x=_CARRIAGE)
@example(za=607998, zb=607998, x=-5018)  # the quick answer's corners, a step in
@example(za=607998, zb=607999, x=33624)
@example(za=-(1 << 22), zb=607998, x=-5019)  # just outside the span: worked out
def test_the_z_top_pin_reads_as_the_gantry_lines_height_says(za, zb, x):
    """z_top_pin() (which answers at once where both leadscrews are below the switch
    and the carriage between them) reads 0 exactly where the gantry line's height at
    the carriage is at or above the switch, a tilted gantry and the span's edges
    included."""
    from robox.hardware import machine
    from robox.hardware.machine import Z_TOP_STEPS, Machine

    # its quick answer's bounds: a step inside the span and a step below the switch
    bounds = (machine.SPAN_X_LO, machine.SPAN_X_HI, machine.BELOW_TOP)
    assert bounds == (math.ceil(machine.ZA_X_MM * machine.X_STEPS_PER_MM) + 1,
                      math.floor(machine.ZB_X_MM * machine.X_STEPS_PER_MM) - 1,
                      math.floor(Z_TOP_STEPS) - 1)
    m = Machine()
    m.za, m.zb, m.x = za, zb, x
    assert m.z_top_pin() == int(m.nozzle_height() < Z_TOP_STEPS)
    za_mm, zb_mm, x_mm = za / 6400.0, zb / 6400.0, x / 133.7
    height_mm = za_mm + (zb_mm - za_mm) * (x_mm + 37.546) / (251.5 + 37.546)
    if abs(height_mm - 95.0) > 1e-6:  # away from the switch, by the geometry itself
        assert m.z_top_pin() == int(height_mm < 95.0)


@settings(max_examples=300, deadline=None)
@given(passed=st.tuples(st.integers(-(1 << 40), 1 << 40), st.integers(-(1 << 40), 1 << 40)),
       base=st.tuples(st.booleans(), st.booleans()))
def test_both_index_wheels_read_at_once_read_as_each_does(passed, base):
    """The levels the step interrupt reads in one call are index_wheel()'s for E (bit 0)
    and D (bit 1), whichever way each wheel's base level and count of steps lie."""
    from robox.hardware.machine import Machine

    m = Machine()
    m.wheel_passed[E], m.wheel_passed[D] = passed
    m.wheel_base[E], m.wheel_base[D] = base
    assert m.index_levels() == m.index_wheel(E) | (m.index_wheel(D) << 1)
    # and by the wheels' own rule: the level toggles every 256 microsteps, from the base
    expected = [((n >> 8) & 1) ^ int(b) for n, b in zip(passed, base, strict=True)]
    assert m.index_levels() == expected[0] | (expected[1] << 1)


_FEED = st.one_of(st.none(), st.tuples(st.integers(-3000, 3000), st.integers(0, 6000)))


@settings(max_examples=300, deadline=None)
@given(feeds=st.tuples(_FEED, _FEED),
       stuck=st.sampled_from([{}, {"E": True}, {"D": False}, {"X": True},
                              {"E": False, "D": True}]))
# a tip at the sensor, a tail at it, and a step past each
@example(feeds=((0, 10), (-1, 10)), stuck={})
@example(feeds=((10, 10), (11, 10)), stuck={})
def test_both_filament_sensors_read_at_once_read_as_each_does(feeds, stuck):
    """The sensors the foreground reads in one call on every pass are switch_pin()'s
    for E (bit 0) and D (bit 1): 0 where filament lies across the sensor, 1 where none
    does (its tip short of it, its tail past it, or no filament), an input stuck at a
    level by fault injection read as stuck."""
    from robox.hardware.machine import SENSOR_STEPS, Filament, Machine

    m = Machine()
    for axis, feed in zip((E, D), feeds, strict=True):
        if feed is not None:  # its tip that far past the sensor, that length behind it
            tip = SENSOR_STEPS[axis] + feed[0]
            m.filament[axis] = Filament(tip=tip, tail=tip - feed[1])
    m.stuck = dict(stuck)
    assert m.sensor_pins() == m.switch_pin(E) | (m.switch_pin(D) << 1)
    # and by the sensor's own rule, where nothing is stuck
    if not stuck:
        expected = [int(not (f is not None and f.tail <= SENSOR_STEPS[axis] <= f.tip))
                    for axis, f in ((E, m.filament[E]), (D, m.filament[D]))]
        assert m.sensor_pins() == expected[0] | (expected[1] << 1)


@settings(max_examples=2000, deadline=None)
@given(length=st.one_of(st.integers(0, 3000), st.integers(0x007FFF00, 1 << 31)),
       speed=st.integers(0, 0xFFFFF), end_speed=st.one_of(st.integers(0, 300),
                                                          st.integers(0, 0x3FFFF)),
       a=st.integers(1, 255), offset=st.integers(-2, 2),
       near=st.sampled_from(["speed", "root", "cruise", "floor", "any"]),
       anywhere=st.integers(0, 1 << 34))
# at the floor with cruise below it, and with the root at zero (x = 0) and at one (x = 1)
@example(length=1, speed=1, end_speed=0, a=1, offset=0, near="floor", anywhere=0)
@example(length=1, speed=9, end_speed=0, a=1, offset=0, near="floor", anywhere=0)
@example(length=1, speed=9, end_speed=4, a=1, offset=0, near="floor", anywhere=0)
# the radicand a square at each bound: at cruise with x = 400 = 20^2 and cruise 20 << 14;
# below cruise at 20 << 14 with x = 20^2, with x = 21^2 - 1, and with x = 21^2
@example(length=101, speed=80, end_speed=0, a=2, offset=0, near="cruise", anywhere=0)
@example(length=101, speed=100, end_speed=0, a=2, offset=0, near="root", anywhere=0)
@example(length=111, speed=100, end_speed=0, a=2, offset=0, near="root", anywhere=0)
@example(length=1, speed=100, end_speed=84, a=1, offset=0, near="any", anywhere=20 << 14)
def test_a_run_of_steady_interrupts_is_found_without_the_square_root(
        length, speed, end_speed, a, offset, near, anywhere):
    """Whether the interrupt leaves the speed where it is, worked out from the radicand
    against squares, agrees with the interrupt's arithmetic taken literally (the root
    taken, shifted, capped by cruise, floored) for speeds at, beside and far from each
    of the values it can settle on."""
    blk = motion_module.Block()
    blk.length, blk.speed, blk.end_speed = length, speed, end_speed
    radicand = ((min(max(length - 1, -1), 0x00800000) << 1) * a
                + ((end_speed * end_speed) >> 4)) & 0xFFFFFFFF
    root = math.isqrt(radicand)
    floor_speed = 2 << 12
    settles = max(floor_speed, min(root << 14, speed << 12))
    s = {"speed": settles, "root": root << 14, "cruise": speed << 12,
         "floor": floor_speed, "any": anywhere}[near] + offset
    assert motion_module._holds(blk, a, s) == (settles == s)


def test_the_interrupts_acceleration_follows_every_change_of_the_parameter(wire):
    """The step interrupt reads pa.acceleration at every run of interrupts; the model
    keeps it as a native integer, which must follow each way the parameter changes:
    M201 (through motion), M502 (factory settings), M501 (the saved ones)."""
    motion = wire.fw.motion

    def seen() -> tuple[int, int]:
        return motion.parameters.acceleration, motion.pa["acceleration"]

    factory = seen()[1]
    run(wire, "M201 S7")
    assert seen() == (7, 7)
    run(wire, "M500", "M201 S3")
    assert seen() == (3, 3)
    run(wire, "M501")  # the saved 7
    assert seen() == (7, 7)
    run(wire, "M502")
    assert seen() == (factory, factory) and factory != 7


def test_the_per_axis_copies_follow_every_change_of_the_parameters(wire):
    """Blocks and passes read steps per unit, speed and travel limits and the switch levels
    from copies in axis order (packed vectors compiled): each must follow a G-code that
    changes the parameter, M501 (the saved ones) and M502 (factory settings)."""
    parameters = wire.fw.parameters
    names = ("steps_per_unit", "max_speed", "travel", "invert_switch")

    def seen() -> list[tuple[list, list]]:
        return [([getattr(parameters, name)[i] for i in range(6)],
                 [parameters.values[name][axis] for axis in "XYZEDB"]) for name in names]

    factory = seen()
    run(wire, "M92 X100 D700", "M202 Y50", "M520 Z90", "M526 E0 X1")
    changed = seen()
    assert [copy for copy, _ in changed] == [values for _, values in changed]
    assert changed[0][0][0] == 100.0 and changed[0][0][4] == 700.0
    assert changed[1][0][1] == 50.0 and changed[2][0][2] == 90.0
    assert changed[3][0][3] == 0 and changed[3][0][0] == 1
    run(wire, "M500", "M502")
    assert seen() == factory and factory != changed
    run(wire, "M501")  # what M500 saved (steps per unit among it)
    saved = seen()
    assert [copy for copy, _ in saved] == [values for _, values in saved]
    assert saved[0] == changed[0]


def weighted_z(points, x: float, y: float, z_dest: float, washout: float) -> float:
    """position.c's bed correction at (x, y), worked out in numpy's float32 (each
    operation rounded as C's float arithmetic rounds it): the points' heights weighed
    by their inverse squared distance (at a point, that point's height), faded out by
    the washout over Z."""
    f = np.float32
    p = np.array(points, dtype=np.float32).reshape(-1, 3)
    off = p[:, :2] - np.array([x, y], dtype=np.float32)
    near = off[:, 0] * off[:, 0] + off[:, 1] * off[:, 1]
    on = np.flatnonzero(near < 1.0e-10)
    if len(on):
        return float(p[on[0], 2])
    weights = f(1.0) / near
    total, mean = f(0.0), f(0.0)
    for w, h in zip(weights, p[:, 2], strict=True):  # in order, as the C sums them
        total, mean = total + w, mean + w * h
    fade = f(max(0.0, min(1.0, 1.0 - float(f(z_dest * washout)))))
    return float((mean / total) * fade)


@settings(max_examples=200, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])  # (all set here)
@given(st.lists(st.tuples(st.floats(0, 210), st.floats(0, 150),
                          st.sampled_from([0.0, 0.0, -0.0, 0.05, -0.1])), min_size=1,
                max_size=3),
       st.floats(-50, 250), st.floats(-50, 200), st.floats(0, 5))
@example([(10.0, 20.0, -0.0), (50.0, 20.0, 0.0)], 10.0, 20.0, 0.2)  # at a -0.0 point
def test_the_bed_correction_weighs_the_levelling_points(wire, points, x, y, z):
    """The correction is the weighted mean of the points' heights in C float arithmetic
    (at a point: that point's height, its sign too), faded by the washout."""
    position = wire.fw.position
    points = [(f32(px), f32(py), f32(pz)) for px, py, pz in points]  # (C floats)
    position.levelling = points
    position.z_washout = 0.5
    at_x = f32(f32(position.position[0] + x) - position.tool_offset[0])
    at_y = f32(f32(position.position[1] + y) - position.tool_offset[1])
    got = position.z_correction(x, y, z)
    expected = weighted_z(points, at_x, at_y, z, 0.5)
    assert got == expected and math.copysign(1.0, got) == math.copysign(1.0, expected)
