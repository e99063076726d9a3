"""Hot-unplug of a reel EEPROM at every transaction of a multi-field update.

A change of remaining filament and diameter is propagated to the chip; the
reel is pulled out at transaction k (for a write: with its byte landed or
not), for every k. Whatever the moment, the copy a printer then loads is
exactly the old data or exactly the new data, and the EEPROM reaches VALID.
"""

from dataclasses import dataclass

import pytest

from robox.firmware.eeprom import TIMEOUT_S, Eeproms, Status
from robox.firmware.error_flags import ErrorFlags
from robox.formats import eeprom as fmt
from robox.formats.eeprom import DATA_SIZE, EepromIndex
from robox.hardware.clock import SimClock
from robox.hardware.eeprom import EepromChip
from robox.hardware.eeprom_bus import EepromBus
from robox.hardware.faults import EepromFaultPlan

REEL = EepromIndex.REEL0
PASS_S = 0.001


def old_data() -> bytes:
    data = bytearray(192)
    for name, value in (("filament_id", "PLA"), ("filament_diameter", "1.75"),
                        ("filament_multiplier", "1"), ("remaining_filament", "240000")):
        fmt.set_field(data, "reel", name, value)
    return bytes(data)


def change(eeproms: Eeproms) -> None:
    eeproms.set_float(REEL, "remaining_filament", 238766.5)
    eeproms.set_float(REEL, "filament_diameter", 2.85)


@dataclass
class Run:
    clock: SimClock
    chip: EepromChip
    eeproms: Eeproms
    base: int  # chip transactions spent loading, before the change

    def passes(self, count: int) -> None:
        for _ in range(count):
            self.eeproms.maintain()
            self.clock.advance(PASS_S)


def start(faults: EepromFaultPlan | None = None) -> Run:
    clock = SimClock()
    chip = EepromChip(fmt.chip_image(old_data()), clock, faults)
    eeproms = Eeproms(EepromBus(reel0=chip), clock, ErrorFlags())
    run = Run(clock, chip, eeproms, 0)
    while not (eeproms.status(REEL) == Status.VALID and eeproms.settled(REEL)):
        run.passes(1)
    while eeproms.states[REEL].counter <= 100:  # the change arrives mid-way through a bank
        run.passes(1)
    run.base = chip.transactions
    change(eeproms)
    return run


@pytest.fixture(scope="module")
def clean():
    run = start()
    new = run.eeproms.states[REEL].data
    kinds = []  # per transaction after the change: "write" or "read"
    while not run.eeproms.settled(REEL):
        writes = run.chip.writes + run.chip.nacks
        was_writing = run.eeproms.states[REEL].writing
        run.passes(1)
        kinds.append("write" if was_writing and run.chip.writes + run.chip.nacks > writes
                     else "read")
    assert fmt.read_bank(bytes(run.chip.data), 0)[:DATA_SIZE] == new
    return new, kinds


def load_as_printer(chip: EepromChip) -> tuple[Status, bytes]:
    """Power up a printer with this chip in the reel socket and let it load."""
    clock = SimClock()
    chip.clock, chip.plugged, chip.faults = clock, True, EepromFaultPlan()
    chip._busy_until = 0.0
    eeproms = Eeproms(EepromBus(reel0=chip), clock, ErrorFlags())
    for _ in range(2 * 196 + 10):
        eeproms.maintain()
        clock.advance(PASS_S)
    return eeproms.status(REEL), eeproms.states[REEL].data


def unplugged(k: int, lands: bool) -> Run:
    """The run, stopped just after the chip was pulled out at change transaction k."""
    run = start(EepromFaultPlan(unplug_at=start().base + k, write_lands=lands))
    while run.chip.plugged:
        run.passes(1)
    return run


def cases(kinds):
    for k, kind in enumerate(kinds, 1):
        yield k, False
        if kind == "write":
            yield k, True


def test_the_change_needs_both_banks_rewritten(clean):
    new, kinds = clean
    assert new != old_data()
    assert kinds.count("write") >= 2 * 10  # several bytes, in each bank


def test_unplug_at_every_transaction_then_power_up_loads_old_or_new(clean):
    new, kinds = clean
    problems = []
    for k, lands in cases(kinds):
        run = unplugged(k, lands)
        status, data = load_as_printer(run.chip)
        if status != Status.VALID or data not in (old_data(), new):
            problems.append(f"unplug at transaction {k} (lands={lands}): {status.name}, "
                            f"{'a mix' if status == Status.VALID else 'not loaded'}")
    assert not problems, "\n".join(problems[:10])


def test_unplug_at_every_transaction_then_timeout_and_reinsert(clean):
    new, kinds = clean
    problems = []
    for k, lands in cases(kinds):
        run = unplugged(k, lands)
        run.passes(int(TIMEOUT_S / PASS_S) + 2)
        if run.eeproms.status(REEL) != Status.NOT_PRESENT:
            problems.append(f"{k}: still {run.eeproms.status(REEL).name} after the timeout")
            continue
        run.chip.plug()
        run.passes(2 * 196 + 10)
        data = run.eeproms.states[REEL].data
        mixed = data not in (old_data(), new)
        if run.eeproms.status(REEL) != Status.VALID or mixed:
            problems.append(f"unplug at {k} (lands={lands}): reloaded "
                            f"{run.eeproms.status(REEL).name}, mixed={mixed}")
    assert not problems, "\n".join(problems[:10])


def test_a_quick_reinsert_at_every_transaction_completes_the_change(clean):
    new, kinds = clean
    problems = []
    for k, lands in cases(kinds):
        run = unplugged(k, lands)
        run.passes(20)  # 20 ms out of the socket: less than the timeout
        run.chip.plug()
        while not run.eeproms.settled(REEL):
            run.passes(1)
        chip = bytes(run.chip.data)
        banks = [fmt.read_bank(chip, b) for b in (0, 1)]
        if not all(fmt.bank_good(b) and b[:DATA_SIZE] == new for b in banks):
            problems.append(f"reinsert after unplug at {k} (lands={lands}): banks not both new")
    assert not problems, "\n".join(problems[:10])
