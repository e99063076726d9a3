"""What simulate watches from outside the firmware (robox.sim.watch, compiled)."""

import tracemalloc

from robox.hardware.machine import X, Y
from robox.packed import vec
from robox.sim.printer import VirtualPrinter
from robox.sim.watch import BED_X_MM, Watch


def test_each_queued_move_is_seen_and_no_reference_to_it_is_kept(tmp_path):
    """The position object hands each queued move's distances (a new packed vector
    each time) to on_move. A compiled method taking a packed vector kept every one it
    was given (simulate's memory grew with the job, a vector per queued move): after
    thousands of calls, each with a vector of its own, the memory they took is back."""
    printer = VirtualPrinter()
    fw = printer.firmware
    watch = Watch(fw, has_valve=True)
    p = fw.position
    for axis in (X, Y):
        p.homing_done[axis] = True
    beyond = p.pa["travel"]["X"] + 5.0  # off the plate, and past X's travel
    p.destination[X] = beyond
    p.destination[Y] = 20.0
    pushed = [0.0, 0.0, 0.0, 0.5, 0.0, 0.0]
    watch.on_move(vec[float](pushed))  # (the notes' lists made before the count)
    tracemalloc.start()
    try:
        before = tracemalloc.get_traced_memory()[0]
        for _ in range(5000):
            watch.on_move(vec[float](pushed))
        kept = tracemalloc.get_traced_memory()[0] - before
    finally:
        tracemalloc.stop()
    assert kept < 16_000, f"{kept} bytes kept after 5000 moves"
    line = fw.job.line_number
    assert watch.outside_lines == [line] and watch.clamped_lines == [line]
    assert watch.low[X] == watch.high[X] == beyond > BED_X_MM
    assert watch.shut_lines == [line] and watch.shut_mm[0] == 5001 * 0.5


def test_the_firmware_tells_an_attached_watch_of_each_queued_move():
    """Attached, the watch is the position object's watcher: the moves a G-code line
    queues reach it from inside the firmware (natively, compiled), each with its
    distances and the destination it went to; its passes() condition holds while no
    job runs. A reset's new position object has no watcher."""
    import pytest

    from robox.hardware.clock import PassCondition

    printer = VirtualPrinter()
    printer.settle()
    fw = printer.firmware
    watch = Watch(fw, has_valve=False)
    watch.attach()
    assert fw.position.watcher is watch
    passes = watch.passes()
    assert isinstance(passes, PassCondition) and passes() and passes.holds()
    seen = []
    # the extent of the moves that push plastic, as only the watcher sees it
    for line in (b"G28 X Y\n", b"G1 X12 Y20 F3000\n", b"G1 E0.4\n", b"G1 X30 E0.4\n"):
        printer.transact(b"\x95" + b"%04x" % len(line) + line)
        assert printer.run_until(fw.motion.empty, 60.0)
        seen.append((watch.low[X], watch.high[X]))
    assert seen[0] == seen[1] == (float("inf"), float("-inf"))  # no plastic yet
    assert seen[2] == (12.0, 12.0)
    assert seen[3][0] == 12.0 and seen[3][1] == pytest.approx(30.0, abs=1e-4)
    fw.request_reset()
    printer.run_pass()
    assert printer.firmware.position.watcher is None
