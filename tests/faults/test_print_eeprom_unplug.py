"""The head or the reel pulled out at every EEPROM transaction of a print's bookkeeping.

A printing job extrudes with the head hot; at the bookkeeping tick the firmware
books the reel's remaining filament and the head's hours, and rewrites both banks
of each chip. The chip is pulled out at transaction k of that rewrite (a write
with its byte landed or not), for every k, on the whole printer.

Legal end state: the printer keeps answering; within the EEPROM timeout it sees
the chip gone (and, for the head, switches head power off, as the firmware does);
the chip, put back, loads VALID holding the image from before the tick or the one
after it; and the chip taken to another printer loads the same way.
"""

from dataclasses import dataclass

import pytest

from robox.firmware.eeprom import TIMEOUT_S, Status
from robox.formats.eeprom import DATA_SIZE, EepromIndex
from robox.hardware.faults import EepromFaultPlan
from robox.sim.printer import VirtualPrinter
from tests.faults.printer_campaign import connect

JOB = b"M104 S210\r" + b"".join(f"G1 E{0.5 * i:.1f} F60\r".encode() for i in range(1, 71))
# 35 s of feeding; the head is hot from about 15 s
TICK = 3 * 7.2  # the first bookkeeping tick with the head hot and the reel feeding


@pytest.fixture(scope="module")
def media():
    virtual = VirtualPrinter(card_blocks=2048)
    virtual.settle()
    connect(virtual).send_file(JOB, "feed", run=False)
    virtual.settle()
    return virtual.media()


def start(media, index: EepromIndex, faults: EepromFaultPlan | None = None) -> VirtualPrinter:
    """Power up, run the job, and stop just before the tick."""
    virtual = VirtualPrinter(media=media)
    virtual.settle()
    if faults is not None:
        virtual.hw.eeprom_bus.sockets[index].faults = faults
    virtual.transact(b"\x94" + b"feed".ljust(16, b"\0"))
    virtual.run_until(lambda: virtual.firmware.clock.now >= TICK - 0.05, TICK)
    return virtual


@dataclass
class Clean:
    base: int  # the chip's transactions before the tick
    kinds: list[str]  # "read" or "write", per transaction from the tick until settled
    before: bytes
    after: bytes


def clean_run(media, index: EepromIndex) -> Clean:
    virtual = start(media, index)
    fw = virtual.firmware
    chip = virtual.hw.eeprom_bus.sockets[index]
    before = bytes(fw.eeproms.states[index].data[:DATA_SIZE])
    base = chip.transactions
    kinds: list[str] = []
    chip.journal = kinds
    virtual.run_until(lambda: fw.clock.now >= TICK + 0.01, 1)
    virtual.run_until(lambda: fw.eeproms.settled(index), 5)
    after = bytes(fw.eeproms.states[index].data[:DATA_SIZE])
    assert fw.job.running, "the job must still be printing at the tick"
    return Clean(base, kinds, before, after)


def load_elsewhere(chip_data: bytes, index: EepromIndex, media) -> tuple[Status, bytes]:
    chips = list(media.chips)
    chips[index] = chip_data
    virtual = VirtualPrinter(media=type(media)(media.card, tuple(chips), media.flash))
    virtual.settle()
    fw = virtual.firmware
    return fw.eeproms.status(index), bytes(fw.eeproms.states[index].data[:DATA_SIZE])


@pytest.mark.parametrize("index", [EepromIndex.HEAD, EepromIndex.REEL0])
def test_unplug_at_every_transaction_of_the_bookkeeping(media, index):
    clean = clean_run(media, index)
    assert clean.before != clean.after  # the tick changed this chip
    assert clean.kinds.count("write") >= 10
    legal = (clean.before, clean.after)
    problems = []
    for k, kind in enumerate(clean.kinds, 1):
        for lands in (False, True) if kind == "write" else (False,):
            label = f"{index.name} pulled at transaction {k} ({kind}, lands={lands})"
            virtual = start(media, index, EepromFaultPlan(unplug_at=clean.base + k,
                                                          write_lands=lands))
            fw = virtual.firmware
            chip = virtual.hw.eeprom_bus.sockets[index]
            virtual.run_until(lambda chip=chip: not chip.plugged, 2)
            if chip.plugged:
                problems.append(f"{label}: the transaction never came")
                continue
            virtual.run_until(lambda: False, TIMEOUT_S + 0.05)
            if virtual.transact(b"\xb0")[:1] != b"\xe1":
                problems.append(f"{label}: no status report")
            if fw.eeproms.status(index) != Status.NOT_PRESENT:
                problems.append(f"{label}: still {fw.eeproms.status(index).name}")
            if index == EepromIndex.HEAD and fw.heaters.head_power_on():
                problems.append(f"{label}: head power left on without its EEPROM")
            pulled = bytes(chip.data)
            chip.plug()
            virtual.run_until(lambda fw=fw: fw.eeproms.status(index) == Status.VALID, 2)
            data = bytes(fw.eeproms.states[index].data[:DATA_SIZE])
            if fw.eeproms.status(index) != Status.VALID or data not in legal:
                problems.append(f"{label}: put back, it loads {fw.eeproms.status(index).name}"
                                f"{'' if data in legal else ', neither old nor new'}")
            status, data = load_elsewhere(pulled, index, media)
            if status != Status.VALID or data not in legal:
                problems.append(f"{label}: in another printer it loads {status.name}"
                                f"{'' if data in legal else ', neither old nor new'}")
    assert not problems, f"{len(problems)} problem(s)\n" + "\n".join(problems[:10])
