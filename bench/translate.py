#!/usr/bin/env python3
"""The translator's throughput on a real slicer's file, beside a plain read of it.

Usage: python bench/translate.py [--quick] [--memory]
Slices the bench's star tower with slic3r as a user would (absolute E in mm,
no volumetric E; cached in bench/.cache/), then times, in one run: a plain
line-by-line read of the file (`for line in f: line.split()`) and
`roboxise_file` writing the Robox job, with AutoMaker's valve (the default) and with
`--valve simple`. Prints lines/s, MB/s and the ratios.
With --memory, also the peak resident memory of `robox-cli roboxise` and of
`robox-cli --device sim-once:DIR send-job` (upload only) on that file and on a
file about 50 MB long (the same layers over and over), each in its own process.
Asserts nothing.
"""

import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from model import plain_loop_rate, robox_cli, sliced_gcode  # noqa: E402

from robox.gcode import Options, roboxise_file  # noqa: E402
from robox.native import build  # noqa: E402


def main() -> None:
    print(f"measuring {build()}")
    path = sliced_gcode("--quick" in sys.argv, "tower-user", ())  # E in mm, absolute
    size = path.stat().st_size
    rate = plain_loop_rate(path)
    took = {}
    with tempfile.TemporaryDirectory() as tmp:
        for valve in ("automaker", "simple"):
            start = time.perf_counter()
            summary = roboxise_file(path, Path(tmp) / "job.robox", Options(valve=valve))
            took[valve] = time.perf_counter() - start
    lines = summary.lines_in
    plain = lines / rate
    print(f"slic3r G-code {path.name}: {size / 1e6:.2f} MB, {lines} lines "
          f"({summary.e_mode} E, {summary.volume_mm3['E']:.0f} mm3, "
          f"{summary.valve_cycles} valve openings)")
    print(f"  plain read:  {lines / plain:,.0f} lines/s, {size / 1e6 / plain:.1f} MB/s")
    for valve, seconds in took.items():
        print(f"  roboxise --valve {valve + ':':10} {lines / seconds:,.0f} lines/s, "
              f"{size / 1e6 / seconds:.2f} MB/s; ratio to the plain read {plain / seconds:.4f}")
    if "--memory" in sys.argv:
        memory(path)


def memory(path: Path) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        big = Path(tmp) / "big.gcode"
        body = path.read_bytes()
        head, _, rest = body.partition(b"\nG1 Z")
        layers = b"\nG1 Z" + rest.split(b"\n; filament used")[0]
        with open(big, "wb") as out:
            out.write(head)
            while out.tell() < 50_000_000:
                out.write(layers)
        for name in (path, big):
            size = name.stat().st_size / 1e6
            _, roboxise = robox_cli("roboxise", str(name), "-o", f"{tmp}/out.robox")
            _, send = robox_cli("--device", f"sim-once:{tmp}/printer", "send-job", str(name))
            print(f"  peak RSS on {size:.1f} MB: roboxise {roboxise:.0f} MB, "
                  f"send-job {send:.0f} MB")


if __name__ == "__main__":
    main()
