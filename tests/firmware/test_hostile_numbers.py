"""Absurd numbers in G-code: the model does what the printer's C does with them.

get_float is strtod, so `1e39`, `inf` and `nan` arrive as such; the firmware never
checks them. What follows is the ARM's soft-float arithmetic: conversions to integers
saturate (NaN gives 0), float division by zero gives an infinity, and the firmware's
min/max macros let a NaN through or not depending on the side it is on. Each test pins
one consequence, with the figures worked out here from the C source, and a table test
sends every code the firmware knows with every letter set to hostile values.
"""

import math
import random
import struct

import pytest

from robox.firmware import carith
from robox.sim.printer import VirtualPrinter
from tests.firmware.test_motion import naive_block, run, settle, x_after_g1
from tests.firmware.wire import Wire, job_text


def f32(value: float) -> float:
    try:
        return struct.unpack("<f", struct.pack("<f", value))[0]
    except OverflowError:
        return math.copysign(math.inf, value)


@pytest.fixture
def wire(wire):
    wire.clear()
    return wire


def m114_x(wire) -> float:
    text = wire.gcode(b"M114\r").decode()
    return float(text.split("X:")[1].split()[0])


def follow_clamped_x(dest: float, pos: float, target: float, travel: float = 226.0,
                     spu: float = 133.7) -> tuple[float, float]:
    """do_g0_g1 and do_move one segment at a time, as position.c runs them: 2 mm
    segments counted with (unsigned long), the destination summed in float, each
    segment's target clamped to 0..travel and queued as whole steps."""
    distance = f32(abs(f32(target - dest)))
    segments = (1 + int(distance / 2.0)) & 0xFFFFFFFF
    part = f32(f32(target - dest) / f32(segments))
    for _ in range(segments):
        dest = f32(dest + part)
        goal = max(0.0, min(travel, dest))
        steps = math.floor(f32(f32(goal - pos) * f32(spu)) + 0.5)
        pos = f32(pos + f32(steps / f32(spu)))
    return dest, pos


def test_float_sums_taken_in_bulk_equal_one_addition_at_a_time():
    """Many segments add the same float to a destination: the bulk sum the model uses
    for segments that queue nothing is the float sum, ties to even included."""
    rng = random.Random(2)
    for _ in range(400):
        step = f32(rng.choice([1.5, 3.0, 0.1, 1.9999, -2.0, -0.75, 7.0])
                   * 2.0 ** rng.randint(-20, 6))
        x = f32(rng.choice([0.0, rng.uniform(-500, 500), 3e-39, rng.uniform(-1, 1) * 1e7]))
        count = rng.randint(0, 3000)
        expected = x
        for _ in range(count):
            expected = f32(expected + step)
        assert carith.f32_accumulate(x, step, count) == expected, (x, step, count)
    assert carith.f32_accumulate(0.0, 2.0, 4_000_000_000) == 2.0 ** 25  # 2 + 2**25 is 2**25
    # a sum that does not move still takes the sum's sign: -0.0 + 0.0 is 0.0
    assert math.copysign(1.0, carith.f32_accumulate(-0.0, 0.0, 3)) == 1.0


def test_arm_conversions_saturate_and_take_nan_as_zero():
    """__aeabi_f2iz / __aeabi_f2uiz: no trap, whatever the value."""
    assert [carith.to_long(v) for v in (math.nan, math.inf, -math.inf, 3e9, -3e9, -7.9)] == \
        [0, 0x7FFFFFFF, -0x80000000, 0x7FFFFFFF, -0x80000000, -7]
    assert [carith.to_ulong(v) for v in (math.nan, math.inf, -math.inf, 5e9, -1.0, 7.9)] == \
        [0, 0xFFFFFFFF, 0, 0xFFFFFFFF, 0, 7]
    assert carith.cmax(0.0, math.nan) != carith.cmax(0.0, math.nan)  # NaN comes through
    assert carith.cmax(math.nan, 0.0) == 0.0


def test_a_move_too_long_to_count_in_segments_is_dropped(wire):
    """do_g0_g1: 1 + (unsigned long)(distance / 2) wraps to 0 segments when the quotient
    saturates, so G1 X1e10 queues nothing and leaves the destination alone."""
    run(wire, "G28 X", "G1 X20 F6000")
    before = wire.gcode(b"M114\r")
    run(wire, "G1 X1e10")
    assert wire.gcode(b"M114\r") == before
    run(wire, "G1 X30")  # still measured from X20
    _, pos = follow_clamped_x(20.0, x_after_g1(0.0, 20.0), 30.0)
    assert m114_x(wire) == pytest.approx(pos, abs=1e-6)


def test_a_move_far_past_the_travel_stops_there_and_its_destination_stays_far(wire):
    """do_move clamps each segment's target to the travel, but the destination keeps
    its float sum: coming back, the move is measured from where the sum ended."""
    run(wire, "G28 X", "G92 X0")
    pos = m114_x(wire)
    assert pos == 0.0
    dest, pos = follow_clamped_x(0.0, 0.0, 100000.0)
    run(wire, "G1 X100000 F6000")
    assert m114_x(wire) == pytest.approx(pos, abs=1e-6) == pytest.approx(226.0, abs=0.01)
    dest, pos = follow_clamped_x(dest, pos, 10.0)
    run(wire, "G1 X10")
    assert m114_x(wire) == pytest.approx(pos, abs=1e-6)
    assert abs(pos - 10.0) > 1e-3  # the float sums do not land on 10 exactly


def test_a_nan_destination_holds_an_axis_until_g92(wire):
    """max(0, min(travel, NaN)) is NaN, (signed long)floor(NaN) is 0 steps: after G1
    Xnan no absolute X move moves X; G92 gives the destination a number again."""
    run(wire, "G28 X", "G92 X0", "G1 X5 F6000")
    at = m114_x(wire)
    run(wire, "G1 Xnan", "G1 X20", "G1 X40")
    assert m114_x(wire) == at
    run(wire, "G92 X0", "G1 X20")
    assert m114_x(wire) == pytest.approx(x_after_g1(0.0, 20.0), abs=1e-6)


def test_an_extrusion_at_feed_rate_zero_crawls_at_the_minimum_speed(wire):
    """An E-only move takes F as a speed limit: |E| / 0 is infinite, the block's speed
    (unsigned short)(length / inf) = 0 becomes MIN_SPEED, 2 units (91.6 steps/s)."""
    motion = wire.fw.motion
    length = math.floor(f32(f32(f32(1.0) / f32(f32(1.75 * 1.75) * math.pi / 4.0))
                            * 747.0) + 0.5)
    wire.gcode(job_text(["G1 E1 F0"]))
    assert wire.printer.run_until(lambda: not motion.empty(), 1)
    start = motion.next_tick
    assert motion.block[motion.buffer_out].speed == 2
    settle(wire)
    assert motion.last_tick == start + sum(naive_block(length, 2, 4)[:-1])


@pytest.mark.parametrize("value", ["nan", "-5", "-inf"])
def test_a_dwell_of_no_number_is_no_dwell(wire, value):
    """G4 S: delay_aborting((unsigned long)(S * 1000)) is 0 ticks for NaN and negatives."""
    start = wire.fw.clock.now
    run(wire, f"G4 S{value}")
    assert wire.fw.clock.now - start < 0.05


def test_an_endless_dwell_waits_the_longest_count_and_an_abort_ends_it(wire):
    """G4 S1e30: (unsigned long) saturates at 2**32 - 1 ticks (49.7 days)."""
    wire.gcode(job_text(["G4 S1e30"]))
    job = wire.fw.job
    assert wire.printer.run_until(lambda: job.waiting is not None and
                                  job.waiting.until is not None, 1)
    assert job.waiting.until - wire.fw.clock.now == pytest.approx(0xFFFFFFFF / 1000, abs=0.01)
    wire.printer.run_until(lambda: False, 100)
    assert wire.raw(b"\xb0")[26:27] == b"1"  # still busy
    wire.ack(b"\xff")
    assert wire.printer.run_until(lambda: job.current is None and not job.abort_flag, 1)


G_CODES = [0, 1, 4, 28, 36, 37, 38, 39, 90, 91, 92]
M_CODES = [1, 84, 92, 103, 104, 106, 107, 109, 111, 112, 113, 114, 115, 119, 120, 121, 122,
           126, 127, 128, 129, 139, 140, 150, 154, 157, 170, 190, 201, 202, 301, 302, 303,
           304, 400, 500, 501, 502, 503, 510, 520, 526, 527, 530, 531, 532, 533, 534, 906,
           907, 908, 909, 997, 998]
HOSTILE = ["nan", "-inf", "1e39", "-3e38", "1e10", "0", "-1", "4294967296"]


@pytest.mark.parametrize("homed", [False, True])
def test_every_code_with_every_letter_hostile_raises_nothing(homed):
    """Every G and M code of gcode.c, each parameter letter, absurd values, one after
    another on one printer (so earlier damage, M92 X0 say, meets later moves); each
    line gets a second of the printer's time, then an abort."""
    wire = Wire(VirtualPrinter())
    wire.printer.settle()
    if homed:
        run(wire, "G28 X Y Z")
    usb = wire.usb
    for code in [f"G{g}" for g in G_CODES] + [f"M{m}" for m in M_CODES]:
        for letter in "XYZEDBFSPT":
            for value in HOSTILE:
                line = f"{code} {letter}{value}\n".encode()
                usb.host_write(b"\x95%04x" % len(line) + line)
                wire.printer.run_until(lambda: False, 1.0)
                usb.host_write(b"\xff")
                wire.printer.run_until(lambda: False, 0.2)
                while usb.reply_waiting:
                    usb.host_read(4096)
    assert wire.raw(b"\xb0")[:1] == b"\xe1"  # and it still answers
