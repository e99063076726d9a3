#!/usr/bin/env python3
"""Anti-checksum insert + verify throughput: the library's word sum beside a plain byte loop.

Usage: python bench/firmware_image.py [--quick]
On a 128 KiB image (the whole flash: summed through struct) and a
64 MiB buffer (the word-sum core, since insertion refuses anything larger than
the flash: past robox.formats.firmware.NUMPY_SUM_BYTES numpy sums it). Prints
figures.
"""

import struct
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from robox.formats import firmware as fw
from robox.native import build

OFFSET = 0xBC


def byte_loop_sum(data: bytes) -> int:
    total = 0
    for i, byte in enumerate(data):
        total += byte << (8 * (i % 4))
    return total & 0xFFFFFFFF


def insert_and_verify(data: bytes, summer) -> float:
    start = time.perf_counter()
    image = bytearray(data)
    value = fw.anti_checksum(summer(bytes(image)))
    image[OFFSET : OFFSET + 4] = struct.pack("<I", value)
    assert summer(bytes(image)) == 0
    return time.perf_counter() - start


def best(runs: int, data: bytes, summer) -> float:
    return min(insert_and_verify(data, summer) for _ in range(runs))


def main() -> None:
    print(f"measuring {build()}")
    quick = "--quick" in sys.argv
    rng = np.random.default_rng(776)
    cases = [("128 KiB image", 128 * 1024, 20, 3), ("64 MiB buffer", 64 * 1024 * 1024, 3, 1)]
    if quick:
        cases[1] = ("4 MiB buffer", 4 * 1024 * 1024, 3, 1)
    print("anti-checksum insert + verify (two word sums), best of N:")
    for name, size, runs_numpy, runs_loop in cases:
        data = bytearray(rng.integers(0, 256, size, dtype=np.uint8).tobytes())
        data[OFFSET : OFFSET + 4] = bytes(4)
        data = bytes(data)
        mb = size / 1e6
        t_numpy = best(runs_numpy, data, fw.word_sum)
        t_loop = best(runs_loop, data, byte_loop_sum)
        how = "numpy" if size > fw.NUMPY_SUM_BYTES else "struct"
        print(f"  {name:<14} {how} {mb / t_numpy:9.1f} MB/s   byte loop {mb / t_loop:6.2f} MB/s"
              f"   ({t_loop / t_numpy:,.0f}x)")
    library = fw.insert_anti_checksum
    image = bytearray(rng.integers(0, 256, 128 * 1024, dtype=np.uint8).tobytes())
    image[OFFSET : OFFSET + 4] = bytes(4)
    start = time.perf_counter()
    for _ in range(50):
        result = library(bytes(image))
        assert fw.check_binary(result.image).accepted
    elapsed = (time.perf_counter() - start) / 50
    print(f"  library insert_anti_checksum + check_binary on 128 KiB: "
          f"{0.131072 / elapsed:.1f} MB/s ({elapsed * 1000:.2f} ms)")


if __name__ == "__main__":
    main()
