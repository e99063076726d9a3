#!/usr/bin/env python3
"""EEPROM benchmarks: cost of propagating one changed byte, and maintain steps per second.

Usage: python bench/eeprom.py
One loop pass is taken as 1 ms of simulated time; the chips have a 5 ms
internal write cycle. Prints figures; asserts nothing.
"""

import time

from robox.firmware.eeprom import Eeproms, Status
from robox.firmware.error_flags import ErrorFlags
from robox.formats import eeprom as fmt
from robox.formats.eeprom import EepromIndex
from robox.hardware.clock import SimClock
from robox.hardware.eeprom import EepromChip
from robox.hardware.eeprom_bus import EepromBus
from robox.native import build

PASS_S = 0.001


def rig(with_all_three: bool):
    clock = SimClock()
    data = bytearray(192)
    fmt.set_field(data, "reel", "remaining_filament", "240000")
    image = fmt.chip_image(bytes(data))
    if with_all_three:
        chips = [EepromChip(image, clock) for _ in range(3)]
        bus = EepromBus(*chips, mux_present=True)
    else:
        chips = [EepromChip(image, clock)]
        bus = EepromBus(reel0=chips[0])
    eeproms = Eeproms(bus, clock, ErrorFlags())
    return clock, chips, eeproms


def settle(clock, eeproms, index) -> int:
    passes = 0
    while not (eeproms.status(index) == Status.VALID and eeproms.settled(index)):
        eeproms.maintain()
        clock.advance(PASS_S)
        passes += 1
    return passes


def propagate_one_byte() -> None:
    clock, chips, eeproms = rig(False)
    reel = EepromIndex.REEL0
    settle(clock, eeproms, reel)
    for _ in range(150):  # mid-way through verifying a bank, as in normal running
        eeproms.maintain()
        clock.advance(PASS_S)
    chip = chips[0]
    before = (chip.transactions, chip.writes, clock.now)
    eeproms.host_write(reel, 0x20, b"Z")
    passes = settle(clock, eeproms, reel)
    transactions = chip.transactions - before[0]
    print("propagate one changed byte to both banks (reel 0):")
    print(f"  {transactions} transactions ({chip.writes - before[1]} byte writes, "
          f"{chip.nacks} refused during write cycles), {passes} loop passes")
    print(f"  {(clock.now - before[2]) * 1000:.1f} ms of simulated time at "
          f"{PASS_S * 1000:.0f} ms per pass")


def steps_per_second() -> None:
    clock, chips, eeproms = rig(True)
    for index in EepromIndex:
        settle(clock, eeproms, index)
    passes = 200_000
    before = sum(chip.transactions for chip in chips)
    start = time.perf_counter()
    for _ in range(passes):
        eeproms.maintain()
        clock.advance(PASS_S)
    elapsed = time.perf_counter() - start
    transactions = sum(chip.transactions for chip in chips) - before
    print("maintain() with three settled EEPROMs (their verify reads every 10 ms of "
          "simulated time):")
    print(f"  {passes / elapsed:,.0f} maintain calls/s of wall time, "
          f"{transactions / elapsed:,.0f} chip transactions/s")
    eeproms.set_float(EepromIndex.REEL0, "remaining_filament", 1.0)
    start, passes = time.perf_counter(), 0
    before = sum(chip.transactions for chip in chips)
    while not eeproms.settled(EepromIndex.REEL0):
        eeproms.maintain()
        clock.advance(PASS_S)
        passes += 1
    elapsed = time.perf_counter() - start
    transactions = sum(chip.transactions for chip in chips) - before
    print("maintain() while a reel is rewritten (one transaction per pass for it):")
    print(f"  {passes / elapsed:,.0f} maintain calls/s, {transactions / elapsed:,.0f} "
          "chip transactions/s")


if __name__ == "__main__":
    print(f"measuring {build()}")
    propagate_one_byte()
    steps_per_second()
