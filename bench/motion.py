#!/usr/bin/env python3
"""Simulated duration of a set of jobs on the firmware model, and the wall time it took.

Usage: python bench/motion.py [--quick]

Each job runs on a fresh virtual printer, stored on its card and printed from there as a
host would: the shapes of AutoMaker's macros (homing, gantry and bed levelling, purge,
ejecting stuck filament, tool changes) and a slicer's print (bench/model.py's tower; with
`--quick` its 20 mm version). The simulated time is what the printer's own motion and
heater code take (the 16-block queue, acceleration, homing against the switches, the
thermal plants); the wall time is what it cost to simulate. Asserts nothing.
"""

import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from model import host_text, sliced_gcode  # noqa: E402

from robox.hardware.machine import E  # noqa: E402
from robox.native import build  # noqa: E402
from robox.sim.printer import VirtualPrinter  # noqa: E402
from tests.firmware.wire import MACROS, Wire, job_text  # noqa: E402


def run_job(name: str, text: bytes) -> tuple[int, float, float, bool]:
    """(lines, simulated s, wall s, finished) for one job on a fresh printer."""
    printer = VirtualPrinter(card_blocks=4 * 65536)
    wire = Wire(printer)
    printer.settle()
    wire.clear()
    printer.hw.machine.insert_filament(E, tip_mm=380.0)  # loaded up to the nozzle
    # the head's valve offsets, as a calibrated head has them (the simulated head's are 0,
    # on which T0/T1 cannot find the valve's switch side and latch B_STUCK)
    wire.ok(b"\xa0" + b"58" + b"08" + b"0.650000")
    wire.ok(b"\xa0" + b"88" + b"08" + b"-0.70000")
    file_id = name.replace(" ", "")[:16]
    wire.upload(file_id, text)
    fw = printer.firmware
    wall = time.perf_counter()
    began = fw.clock.now
    wire.ok(b"\x94" + file_id.encode().ljust(16, b"\0"))
    printer.run_until(lambda: not fw.job.running, 10 * 24 * 3600)
    wall = time.perf_counter() - wall
    finished = ("job finished", file_id.encode().ljust(16, b"\0")) in fw.events
    return text.count(b"\r"), fw.clock.now - began, wall, finished


def main() -> None:
    print(f"measuring {build()}")
    quick = "--quick" in sys.argv
    jobs = [(name, job_text(lines)) for name, lines in MACROS.items()]
    tower = sliced_gcode(quick)
    jobs.append((f"print {tower.stem}", host_text(tower.read_bytes())))
    print(f"{'job':24} {'lines':>7} {'simulated':>12} {'wall':>9} {'sim/wall':>9}  end")
    total_sim = total_wall = 0.0
    for name, text in jobs:
        lines, simulated, wall, finished = run_job(name, text)
        total_sim += simulated
        total_wall += wall
        end = "finished" if finished else "NOT FINISHED"
        print(f"{name:24} {lines:7,} {simulated:11.1f}s {wall:8.2f}s "
              f"{simulated / wall:8,.0f}x  {end}", flush=True)
    print(f"{'all':24} {'':7} {total_sim:11.1f}s {total_wall:8.2f}s "
          f"{total_sim / total_wall:8,.0f}x")


if __name__ == "__main__":
    main()
