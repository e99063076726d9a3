"""Passes in which only the EEPROM object works are run together (Firmware.run_pass,
Eeproms.run_inert_passes): what the chips, the EEPROM object and a host see must be
what running every pass one by one gives.

Each case powers up two printers on the same media. One runs as run_until() runs
(batched); the other one pass of 1 ms at a time, with no pass skipped. Compared: every
write reaching a chip (address, byte, simulated moment), the moment each EEPROM became
VALID and the moment every EEPROM fell quiet (what settle() waits for), and at that
moment the chips' bytes and the EEPROM object's state. (Once quiet, a settled EEPROM's
verify reads are taken at most every QUIET_STEP_S, in whichever passes run: from there
on the two printers' read counters may differ, by design.)"""

from dataclasses import replace

import pytest

from robox.firmware.main import PASS_S
from robox.formats.eeprom import BANK_ADDRESSES, BANK_SIZE, EepromIndex
from robox.hardware.faults import EepromFaultPlan, PowerPlan
from robox.sim.printer import Media, VirtualPrinter

HEAD, REEL0 = EepromIndex.HEAD, EepromIndex.REEL0
END_S = 2.5


def fresh() -> Media:
    p = VirtualPrinter(card_blocks=64)
    return p.media()


def altered(media: Media, index: int, changes: dict[int, int]) -> Media:
    chips = list(media.chips)
    data = bytearray(chips[index])
    for address, value in changes.items():
        data[address] = value
    chips[index] = bytes(data)
    return replace(media, chips=tuple(chips))


class Log(PowerPlan):
    def __init__(self, printer: VirtualPrinter):
        super().__init__()
        self.printer = printer
        self.names = {id(c): i for i, c in enumerate(printer.hw.eeprom_bus.sockets) if c}
        self.events = []

    def write(self, device, address, data):
        self.events.append(("write", self.names.get(id(device)), address, bytes(data),
                            round(self.printer.firmware.clock.now, 9)))
        return super().write(device, address, data)


def watch(printer: VirtualPrinter) -> Log:
    log = Log(printer)
    printer.supply(log)
    fw = printer.firmware
    fw.eeproms.on_valid.append(lambda i: log.events.append(
        ("valid", int(i), round(fw.clock.now, 9))))
    return log


def outcome(printer: VirtualPrinter) -> tuple:
    fw = printer.firmware
    states = [(s.status, s.counter, s.working_bank, s.verified_banks, s.writing,
               bytes(s.buffer)) for s in fw.eeproms.states]
    chips = [None if c is None else (bytes(c.data), c.writes, c.plugged)
             for c in printer.hw.eeprom_bus.sockets]
    return states, chips, fw.errors.bits


def run_batched(media: Media, faults=None) -> tuple:
    p = VirtualPrinter(media=media)
    if faults:
        faults(p)
    log = watch(p)
    p.run_until(lambda: p.firmware.eeproms.all_quiet(), END_S)
    quiet_at, state = round(p.firmware.clock.now, 9), outcome(p)
    p.run_until(lambda: False, END_S - p.firmware.clock.now)
    return log.events, quiet_at, state


def run_pass_by_pass(media: Media, faults=None) -> tuple:
    p = VirtualPrinter(media=media)
    if faults:
        faults(p)
    log = watch(p)
    fw = p.firmware
    quiet_at = state = None
    while fw.clock.now < END_S - PASS_S / 2:
        if quiet_at is None and fw.eeproms.all_quiet():
            quiet_at, state = round(fw.clock.now, 9), outcome(p)
        fw.run_pass(PASS_S)
    return log.events, quiet_at, state


def unplug_reel_after(n: int):
    def fault(p: VirtualPrinter) -> None:
        p.hw.eeprom_bus.sockets[REEL0].faults = EepromFaultPlan(unplug_at=n)
    return fault


CASES = {
    "both chips good": (lambda m: m, None),
    # bank 1 of the head differs in one byte: found while verifying, rewritten, read back
    "head bank 1 differs": (lambda m: altered(m, HEAD, {BANK_ADDRESSES[1] + 40: 0x21}), None),
    # reel bank 0 fails its CRC: bank 1 is loaded, then bank 0 is rewritten whole
    "reel bank 0 torn": (lambda m: altered(m, REEL0, {BANK_ADDRESSES[0] + 7: 0x7e,
                                                      BANK_ADDRESSES[0] + 8: 0x01}), None),
    # a blank reel: no bank passes, it stays PRESENT and keeps reading
    "reel blank": (lambda m: altered(m, REEL0, dict.fromkeys(range(512), 0xFF)), None),
    # the reel stops answering in the middle of its first bank, and again while verifying
    "reel unplugged mid-load": (lambda m: m, unplug_reel_after(90)),
    "reel unplugged mid-verify": (lambda m: m, unplug_reel_after(BANK_SIZE + 50)),
}


@pytest.mark.parametrize("name", list(CASES))
def test_eeprom_only_passes_run_together_as_one_by_one(name):
    make, faults = CASES[name]
    media = make(fresh())
    batched = run_batched(media, faults)
    single = run_pass_by_pass(media, faults)
    assert batched[0] == single[0]  # writes and VALID moments
    assert batched[1] == single[1]  # when every EEPROM fell quiet
    assert batched[2] == single[2]  # chips, EEPROM object, error flags when quiet
    assert single[1] is not None


def test_a_power_up_load_is_run_in_few_passes():
    """The point of it: loading and verifying both chips takes about 400 steps each,
    which now cost a handful of whole passes."""
    p = VirtualPrinter(media=fresh())
    fw = p.firmware
    passes = 0
    real = fw.do_everything_else

    def counted():
        nonlocal passes
        passes += 1
        real()
    fw.do_everything_else = counted
    p.settle()
    assert all(fw.eeproms.states[i].status.name == "VALID" for i in (HEAD, REEL0))
    assert fw.clock.now > 2 * BANK_SIZE * PASS_S  # a bank loaded and one verified
    assert passes < 20
