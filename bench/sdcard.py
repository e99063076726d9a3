#!/usr/bin/env python3
"""SD card benchmarks: `put` throughput beside cp, and the power-cut campaign rate.

Usage: python bench/sdcard.py [--quick]
Prints figures; asserts nothing.
"""

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from robox.native import build  # noqa: E402
from robox.offline import sdcard as images  # noqa: E402
from tests.faults import campaign  # noqa: E402

FILE_BYTES = 20 * 1000 * 1000
IMAGE_SIZE = "64MiB"


def best_of(runs: int, action) -> float:
    times = []
    for _ in range(runs):
        start = time.perf_counter()
        action()
        times.append(time.perf_counter() - start)
    return min(times)


def bench_put(work: Path, runs: int) -> None:
    source = work / "data.bin"  # any bytes: put without --job stores them as they are
    source.write_bytes(os.urandom(FILE_BYTES))
    image = work / "card.img"
    images.format_image(image, images.parse_size(IMAGE_SIZE))
    data = source.read_bytes()
    put = best_of(runs, lambda: images.put_file(image, data, "job", True))
    cli = best_of(runs, lambda: subprocess.run(
        [sys.executable, "-m", "robox.cli", "sdcard", "put", str(image), str(source)],
        check=True, capture_output=True))
    cp = best_of(runs, lambda: subprocess.run(["cp", str(source), str(work / "copy")],
                                              check=True))
    mb = FILE_BYTES / 1e6
    print(f"put 20 MB, byte for byte, into a {IMAGE_SIZE} image (best of {runs}):")
    print(f"  library put_file      {mb / put:8.1f} MB/s  ({put * 1000:7.1f} ms)")
    print(f"  robox-cli sdcard put  {mb / cli:8.1f} MB/s  ({cli * 1000:7.1f} ms, process included)")
    print(f"  cp                    {mb / cp:8.1f} MB/s  ({cp * 1000:7.1f} ms, process included)")
    print(f"  ratio cp / robox-cli  {cli / cp:8.1f} x")


def bench_campaign(limit: int | None) -> None:
    start = time.perf_counter()
    rec = campaign.record()
    recorded = time.perf_counter() - start
    media = campaign.Media(rec)
    all_cases = list(campaign.cases(rec))[:limit]
    start = time.perf_counter()
    problems = 0
    for case in all_cases:
        problems += bool(campaign.check(rec, media, case))
    elapsed = time.perf_counter() - start
    print(f"power-cut campaign: {len(rec.writes)} block writes in the scenario "
          f"(recorded in {recorded * 1000:.0f} ms)")
    print(f"  {len(all_cases)} cut points checked in {elapsed:.1f} s: "
          f"{len(all_cases) / elapsed:.0f} cut points/s, {problems} illegal end states")


def main() -> None:
    print(f"measuring {build()}")
    quick = "--quick" in sys.argv
    with tempfile.TemporaryDirectory() as work:
        bench_put(Path(work), 1 if quick else 3)
    bench_campaign(500 if quick else None)


if __name__ == "__main__":
    main()
