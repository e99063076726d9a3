#!/usr/bin/env python3
"""Host-side upload to the in-process virtual printer through the pyusb backend.

Usage: python bench/send_job.py
Prints upload MB/s, chunks per second, and the host's CPU time per chunk
(client + transport, the printer's share measured apart). Asserts nothing.
"""

import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import usb.core

from robox.gcode import prepare_job
from robox.host.client import Printer
from robox.host.transport import UsbTransport
from robox.native import build
from robox.sim.printer import VirtualPrinter
from robox.sim.usb_backend import VirtualRoboxBackend
from tests.firmware.wire import circle_job

JOB_LINES = 120_000


def main() -> None:
    print(f"measuring {build()}")
    job = prepare_job(circle_job(JOB_LINES, heat=False))
    virtual = VirtualPrinter(card_blocks=4 * 65536)
    virtual.settle()
    model_cpu = [0.0]
    run_until = virtual.run_until

    def timed_run_until(*args, **kwargs):  # the printer's share of the time
        start = time.process_time()
        try:
            return run_until(*args, **kwargs)
        finally:
            model_cpu[0] += time.process_time() - start

    virtual.run_until = timed_run_until
    device = usb.core.find(idVendor=0x16D0, idProduct=0x081B,
                           backend=VirtualRoboxBackend(virtual))
    printer = Printer(UsbTransport(device))
    chunks = len(job) // 512 + 1
    wall, cpu = time.perf_counter(), time.process_time()
    printer.send_file(job, "bench", run=False)
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    host_cpu = cpu - model_cpu[0]
    print(f"upload of {len(job) / 1e6:.2f} MB ({chunks} chunks) to the in-process virtual "
          "printer over its pyusb backend:")
    print(f"  {len(job) / 1e6 / wall:.2f} MB/s, {chunks / wall:,.0f} chunks/s")
    print(f"  host CPU per chunk {host_cpu / chunks * 1e6:.0f} µs (client, pyusb, transport); "
          f"printer model {model_cpu[0] / chunks * 1e6:.0f} µs")


if __name__ == "__main__":
    main()
