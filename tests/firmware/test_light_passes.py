"""Light passes run together (Firmware._run_light_passes): passes whose only work is an
EEPROM's step (Eeproms.run_inert_passes) or a packet from the host crossing the bus.
What the chips, the card, the EEPROM object and a host see must be what running each
such pass whole gives (`Firmware.light_passes = False`, the reference).

Each case runs two printers from the same media with the same host steps, one each
way, and compares every write reaching a chip or the card (address, bytes, simulated
moment), the moment each EEPROM became VALID, every reply and the moment it was
there, the moment every EEPROM fell quiet (what settle() waits for), and at that
moment the chips' bytes and the EEPROM object's state. (Once quiet, a settled
EEPROM's verify reads are taken at most every QUIET_STEP_S, in whichever passes run:
from there on the two printers' read counters may differ, by design.)"""

from dataclasses import replace

import pytest

from robox.errors import PowerCut
from robox.formats.eeprom import BANK_ADDRESSES, BANK_SIZE, EepromIndex
from robox.formats.sdcard import BLOCK_SIZE
from robox.hardware.faults import EepromFaultPlan, PowerPlan
from robox.sim.printer import Media, VirtualPrinter

HEAD, REEL0 = EepromIndex.HEAD, EepromIndex.REEL0
END_S = 2.5


def fresh() -> Media:
    return VirtualPrinter(card_blocks=64).media()


def altered(media: Media, index: int, changes: dict[int, int]) -> Media:
    chips = list(media.chips)
    data = bytearray(chips[index])
    for address, value in changes.items():
        data[address] = value
    chips[index] = bytes(data)
    return replace(media, chips=tuple(chips))


class Log(PowerPlan):
    """Every write to a nonvolatile medium, with its moment."""

    def __init__(self, printer: VirtualPrinter):
        super().__init__()
        self.printer = printer
        hw = printer.hw
        self.names = {id(c): f"chip{i}" for i, c in enumerate(hw.eeprom_bus.sockets) if c}
        self.names[id(hw.card)] = "card"
        self.events = []
        self.ordinals = []  # (chip, its transaction count) at each EEPROM write

    def write(self, device, address, data):
        self.events.append(("write", self.names.get(id(device)), address, bytes(data),
                            round(self.printer.firmware.clock.now, 9)))
        name = self.names.get(id(device))
        if name is not None and name.startswith("chip"):
            self.ordinals.append((name, device.transactions))
        return super().write(device, address, data)


def outcome(printer: VirtualPrinter) -> tuple:
    fw = printer.firmware
    states = [(s.status, s.counter, s.working_bank, s.verified_banks, s.writing,
               bytes(s.buffer)) for s in fw.eeproms.states]
    chips = [None if c is None else (bytes(c.data), c.writes, c.plugged)
             for c in printer.hw.eeprom_bus.sockets]
    return states, chips, fw.errors.bits


def run(media: Media, light: bool, faults=None, frames=()) -> tuple:
    p = VirtualPrinter(media=media)
    fw = p.firmware
    fw.light_passes = light
    if faults:
        faults(p)
    log = Log(p)
    p.supply(log)
    fw.eeproms.on_valid.append(lambda i: log.events.append(
        ("valid", int(i), round(fw.clock.now, 9))))
    usb = p.usb
    for frame in frames:  # a host's commands, each as soon as the last was answered
        if frame is None:  # (or once the EEPROMs are quiet)
            p.run_until(lambda: fw.eeproms.all_quiet(), END_S)
            continue
        usb.host_write(frame)
        p.run_until(lambda: usb.reply_waiting > 0, 1.0)
        log.events.append(("reply", usb.host_read(4096), round(fw.clock.now, 9)))
    p.run_until(lambda: fw.eeproms.all_quiet(), END_S)
    quiet_at, state = round(fw.clock.now, 9), outcome(p)
    p.run_until(lambda: False, END_S - fw.clock.now)
    return log.events, quiet_at, state


def unplug_reel_after(n: int):
    def fault(p: VirtualPrinter) -> None:
        p.hw.eeprom_bus.sockets[REEL0].faults = EepromFaultPlan(unplug_at=n)
    return fault


def upload(file_id: bytes, data: bytes) -> list[bytes]:
    """The frames of a whole upload: start, 512-byte chunks, and the end."""
    frames = [b"\x90" + file_id]
    chunks = [data[i : i + BLOCK_SIZE] for i in range(0, len(data), BLOCK_SIZE)]
    for n, chunk in enumerate(chunks[:-1]):
        frames.append(b"\x91" + f"{n:08x}".encode() + chunk.ljust(BLOCK_SIZE, b"\0"))
    last = chunks[-1]
    frames.append(b"\x92" + f"{len(chunks) - 1:08x}{len(last):04x}".encode() + last)
    return frames


def printing_while_uploading(file_id: bytes, data: bytes) -> list[bytes]:
    """An upload that is a job (0x97), the job run after its first chunk (0x94)."""
    frames = upload(file_id, data)
    return [b"\x97" + file_id, frames[1], b"\x94" + file_id, *frames[2:]]


HOST = [b"\xb0", *upload(b"MACRO0000000003\0", bytes(range(256)) * 9), b"\xb6",
        b"\x95" + b"0005M105\n", b"\x93", b"\xb0"]

CASES = {
    "both chips good": (lambda m: m, None, ()),
    # bank 1 of the head differs in one byte: found while verifying, rewritten, read back
    "head bank 1 differs": (lambda m: altered(m, HEAD, {BANK_ADDRESSES[1] + 40: 0x21}),
                            None, ()),
    # reel bank 0 fails its CRC: bank 1 is loaded, then bank 0 is rewritten whole
    "reel bank 0 torn": (lambda m: altered(m, REEL0, {BANK_ADDRESSES[0] + 7: 0x7E,
                                                      BANK_ADDRESSES[0] + 8: 0x01}), None, ()),
    # a blank reel: no bank passes, it stays PRESENT and keeps reading
    "reel blank": (lambda m: altered(m, REEL0, dict.fromkeys(range(512), 0xFF)), None, ()),
    # the reel stops answering in the middle of its first bank, and again while verifying
    "reel unplugged mid-load": (lambda m: m, unplug_reel_after(90), ()),
    "reel unplugged mid-verify": (lambda m: m, unplug_reel_after(BANK_SIZE + 50), ()),
    # a host uploading and asking while the chips load (packets crossing the bus, with
    # EEPROM steps in the same passes), and the same once they have settled
    "host while loading": (lambda m: m, None, HOST),
    "host while rewriting": (lambda m: altered(m, HEAD, {BANK_ADDRESSES[1] + 40: 0x21}),
                             None, HOST),
    "host after settling": (lambda m: m, None, [None, *HOST]),
    # a queued M109 S0 waits on the nozzle: the line looks again at the very next pass,
    # the one in which the status request is still crossing (mixed session 231's bytes)
    "a line waiting": (lambda m: m, None, [None, b"\x950012M109 S0 ; comment\r", b"\xb0"]),
    # a job's M109 waits while the nozzle heats, the rest of the job's own upload
    # crosses in and the chips load: the line looks at its heater at the first pass and
    # then at each sample, as the passes that carry the packets would find it still short
    "a job heating": (lambda m: m, None, [
        *printing_while_uploading(b"JOBAAAA000000002",
                                  b"M104 S60\nM109\n" + b"G4 P10\n" * 400), b"\xb0"]),
    # a job started and ended: the hours counter counts its passes from the one that
    # started it (the run-job frame crossed in light passes), and writes them to flash
    "a job's hours": (lambda m: m, None, [None, *upload(b"JOBAAAA000000001",
                                                        b"G4 P200\n" * 3),
                                          b"\x94JOBAAAA000000001", None, b"\xb6"]),
}
# reel bank 1 differs in one byte: verifying it, transaction 237 is the read that finds
# it, 238 its write, then reads the chip ignores in its write cycle and the read back;
# the reel is pulled out at each of those transactions in turn
for _n in range(236, 246):
    CASES[f"reel rewrite unplugged at {_n}"] = (
        lambda m: altered(m, REEL0, {BANK_ADDRESSES[1] + 40: 0x21}), unplug_reel_after(_n), ())


@pytest.mark.parametrize("name", list(CASES))
def test_light_passes_run_together_as_whole_passes(name):
    make, faults, frames = CASES[name]
    media = make(fresh())
    together = run(media, True, faults, frames)
    whole = run(media, False, faults, frames)
    assert together[0] == whole[0]  # writes, VALID moments, replies and their moments
    assert together[1] == whole[1]  # when every EEPROM fell quiet
    assert together[2] == whole[2]  # chips, EEPROM object, error flags when quiet
    if frames:
        replies = [e for e in whole[0] if e[0] == "reply"]
        assert len(replies) == len([f for f in frames if f]) and all(r[1] for r in replies)
        if any(f and f[0] == 0x90 for f in frames):  # an upload: its blocks reached the card
            assert any(e[0] == "write" and e[1] == "card" for e in whole[0])


def test_light_passes_make_power_up_and_uploads_cheap():
    """The point of it: loading and verifying both chips takes about 400 steps each, and
    a 521-byte chunk crosses the bus in 9 frames; they now cost a few whole passes."""
    counts = {}
    for light in (True, False):
        p = VirtualPrinter(media=fresh())
        fw = p.firmware
        fw.light_passes = light
        before = fw.whole_passes
        usb = p.usb
        for frame in HOST:
            usb.host_write(frame)
            p.run_until(lambda usb=usb: usb.reply_waiting > 0, 1.0)
            usb.host_read(4096)
        p.settle()
        assert all(fw.eeproms.states[i].status.name == "VALID" for i in (HEAD, REEL0))
        counts[light] = fw.whole_passes - before
    assert counts[False] >= 2 * BANK_SIZE  # a bank loaded and one verified, pass by pass
    assert counts[True] * 8 < counts[False], counts


# A job that prints: both axes homed, then moves that extrude (2.4 mm^3 is 1 mm of 1.75 mm
# filament), long enough that the 7.2 s bookkeeping rewrites the reel's remaining
# length twice while the head is moving; every seventh line waits for motion to end.
# 58 chunks: it is printed while it is still being uploaded, the rest of it from 1 s on.
PRINT_ID = b"JOBAAAA000000002"
PRINT = b"G28 X Y\n" + b"".join(
    b"G1 X%d Y%d E1.5 F%d\n" % (20 + 40 * (i % 2), 20 + (i * 13) % 50, 2400 + 600 * (i % 3))
    + (b"M400\n" if i % 7 == 6 else b"") for i in range(1300))


def printing(light: bool, cut_at: int | None = None, unplug_at: int | None = None) -> tuple:
    """The print above from power-up (uploaded while the chips load and the head moves),
    then to 17 s a status request every 0.5 s; after some of them a new head serial
    written with the rest of the head's first 160 bytes as they are (a transfer crossing
    the bus in three packets while the head moves, and an EEPROM rewrite), and a pause
    and a resume. Every write to a chip or the card, every reply, each with its moment;
    then the machine, the interrupts, the hours counter and the EEPROM object as they
    end. With `cut_at`, the supply fails during that write (in the order they reach a
    medium): then the moment, the machine, the interrupts and every chip and the card
    as the power goes. With `unplug_at`, reel 0 is pulled out at that transaction."""
    media = fresh()
    p = VirtualPrinter(media=media)
    if unplug_at is not None:
        unplug_reel_after(unplug_at)(p)
    fw = p.firmware
    fw.light_passes = light
    log = Log(p)
    log.cut_at = cut_at
    p.supply(log)
    usb = p.usb

    def ask(frame: bytes) -> None:
        usb.host_write(frame)
        p.run_until(lambda: usb.reply_waiting > 0, 1.0)
        log.events.append(("reply", usb.host_read(4096), round(fw.clock.now, 9)))

    def session() -> None:
        frames = upload(PRINT_ID, PRINT)
        assert len(frames) > 55
        for frame in [*frames[:3], b"\x94" + PRINT_ID]:  # run from chunk 1 on
            ask(frame)
        p.run_until(lambda: False, 1.0 - fw.clock.now)  # homed and printing: the rest
        for frame in frames[3:]:
            ask(frame)
        for n in range(1, 35):
            p.run_until(lambda: False, n * 0.5 - fw.clock.now)
            ask(b"\xb0")
            if n % 3 == 0:
                head = bytearray(media.chips[HEAD][BANK_ADDRESSES[0] :
                                                   BANK_ADDRESSES[0] + 0xA0])
                head[0x10:0x28] = b"SIMHEAD%06d" % n + bytes(11)
                ask(b"\xa0" + b"10" + b"90" + bytes(head[0x10:]))
            if n in (11, 13):
                ask(b"\x98" + (b"1" if n == 11 else b"0"))  # pause, then resume

    m = p.hw.machine
    try:
        session()
    except PowerCut:
        hw = p.hw
        return (round(fw.clock.now, 9), m.x, m.y, m.za, m.zb, fw.motion.interrupts,
                [bytes(c.data) for c in hw.eeprom_bus.sockets if c is not None],
                hw.card.writes, log.events)
    assert cut_at is None
    ends = (round(fw.clock.now, 9), m.x, m.y, list(fw.position.position),
            list(fw.position.extruded_mm), fw.motion.interrupts, fw.job.line_number,
            fw.job.running, [s.last_ack for s in fw.eeproms.states], fw.hours.run_ticks)
    # (a settled EEPROM's place in its banks follows the passes that ran: see above)
    states, chips, errors = outcome(p)
    states = [s if s[3] < 2 else (s[0], None, None, 2, s[4], s[5]) for s in states]
    return (log.events, ends, (states, chips, errors), fw.whole_passes, log.ordinals,
            fw.step_passes)


def test_motion_runs_ahead_while_an_eeprom_rewrites_as_pass_by_pass():
    """While the reel's remaining length is rewritten (about 400 steps, one a pass) and
    the job waits for room in the motion queue, the interrupts run ahead over the passes
    whose only other work is an inert EEPROM step (Eeproms.inert_passes): the same
    writes at the same moments, the same replies, the same machine, as every pass run
    whole, in a fraction of the passes."""
    together, whole = printing(True), printing(False)
    writes = [e for e in whole[0] if e[0] == "write" and e[1] == "chip1"]
    assert any(e[4] > 7.2 for e in writes) and any(e[4] > 14.4 for e in writes)
    assert len({e[4] // 1.5 for e in whole[0] if e[0] == "write" and e[1] == "chip0"}) > 5
    status = [e[1] for e in whole[0] if e[0] == "reply" and e[1][:1] == b"\xe1"]
    assert len(status) == 34
    assert len(set(status)) > 30  # the job moved on between them
    assert together[0] == whole[0]
    assert together[1] == whole[1] and together[1][7]  # still printing at the end
    assert together[2] == whole[2]
    assert together[3] * 2 < whole[3], (together[3], whole[3])
    # the rewrites' reads that find a byte and their writes took passes of their own
    assert together[5] > 100 and whole[5] == 0


def test_a_power_cut_at_any_eeprom_write_while_motion_runs_ahead_is_as_pass_by_pass():
    """An EEPROM's write is never taken in a light pass (motion run ahead over it would
    be ahead of a cut there): at every EEPROM write of the print, a power cut comes at
    the same moment, with the machine, the interrupts, the chips and the card where
    running each pass whole leaves them."""
    events = printing(False)[0]
    writes = [e for e in events if e[0] == "write"]
    cuts = [n for n, e in enumerate(writes, 1) if e[1] != "card"]
    assert len(cuts) > 60 and any(writes[n - 1][4] > 7.2 for n in cuts)
    for cut_at in cuts:
        together, whole = printing(True, cut_at), printing(False, cut_at)
        assert together[0] == writes[cut_at - 1][4]  # the moment of that write
        assert together == whole, cut_at


def test_a_reel_pulled_out_around_a_rewrite_while_motion_runs_ahead_is_as_pass_by_pass():
    """Reel 0 pulled out at the read that finds a byte to rewrite, at the write, and at the
    read back, for the first bytes of the 14.4 s bookkeeping rewrite while the head moves:
    the passes that take only the EEPROMs' steps (Firmware._step_pass) leave the same
    writes, replies, machine and chips as every pass run whole, the chip's loss and the
    0.2 s timeout after it included. (A settled EEPROM's reads are counted as the passes
    ran, so each run's own transaction numbers locate those writes.)"""
    located = {}
    for light in (True, False):
        events, ordinals = (lambda r: (r[0], r[4]))(printing(light))
        moments = [e[4] for e in events if e[0] == "write" and str(e[1]).startswith("chip")]
        located[light] = [n for (chip, n), t in zip(ordinals, moments, strict=True)
                          if chip == "chip1" and t > 14.4][:3]
    assert len(located[True]) == 3
    for k in range(3):
        for offset in (-1, 0, 1):
            together = printing(True, unplug_at=located[True][k] + offset)
            whole = printing(False, unplug_at=located[False][k] + offset)
            assert together[:3] == whole[:3], (k, offset)
            assert together[2][0][REEL0][0] == 0  # NOT_PRESENT at the end


@pytest.mark.parametrize("name", [n for n in CASES if not CASES[n][2]])
def test_inert_passes_says_how_many_passes_run_inert_passes_runs(name):
    """At every stage of loading, verifying and rewriting (each case's chips), the count
    predicted without running anything is the count then run, and a shorter run is
    predicted as far as it goes (a verifying EEPROM's bytes are compared only that far);
    between runs, a whole pass takes the step that ended the last one."""
    make, faults, _ = CASES[name]
    p = VirtualPrinter(media=make(fresh()))
    if faults:
        faults(p)
    fw = p.firmware
    eeproms = fw.eeproms
    runs = []
    while not eeproms.all_quiet() and fw.clock.now < END_S:
        whole = eeproms.inert_passes(0.001, 10_000)
        for most in (1, 2, 7, 60, 10_000):
            before = (fw.clock.now, [(s.counter, s.working_bank, s.last_step)
                                     for s in eeproms.states])
            predicted = eeproms.inert_passes(0.001, most)
            assert (fw.clock.now, [(s.counter, s.working_bank, s.last_step)
                                   for s in eeproms.states]) == before  # nothing ran
            assert predicted == min(most, whole)
            if most == 10_000:
                runs.append(predicted)
                assert eeproms.run_inert_passes(0.001, most) == predicted
        p.firmware.run_pass(0.001)
    assert eeproms.all_quiet() or name == "reel blank"
    assert max(runs) > 50  # long runs of reads were predicted, not only single steps


@pytest.mark.parametrize("left", [1, 2, 9, 60, 150])
def test_a_settled_eeproms_bank_end_ends_a_long_run(left):
    """A settled EEPROM steps every 10 ms; the step that ends its bank is not inert, so a
    run predicted over many passes stops short of it, however few of its steps are left
    before it: the count predicted is the count run, and the step comes next."""
    p = VirtualPrinter(media=fresh())
    fw = p.firmware
    eeproms = fw.eeproms
    p.settle()
    head = eeproms.states[HEAD]
    while head.counter != BANK_SIZE - left or not eeproms.all_quiet():
        fw.run_pass(0.001)
    predicted = eeproms.inert_passes(0.001, 5000)
    assert predicted < 12 * left + 12  # the bank's end (10 or 11 passes a step), not 5000
    for most in range(1, predicted + 30, 1 if left < 10 else 7):  # shorter runs: as far
        assert eeproms.inert_passes(0.001, most) == min(most, predicted)
    assert eeproms.run_inert_passes(0.001, 5000) == predicted
    banks = head.verified_banks
    while head.verified_banks == banks:  # the passes before it would have stepped inertly
        fw.run_pass(0.001)
        assert head.counter in (BANK_SIZE - 1, 0)


def test_run_until_with_no_condition_runs_the_whole_timeout():
    """No condition (a host idling beside a virtual printer) runs the timeout through and
    ends where a condition that never holds ends, pass for pass."""
    ends = []
    for condition in (None, lambda: False):
        printer = VirtualPrinter(media=fresh())
        fw = printer.firmware
        start = fw.clock.now
        assert printer.run_until(condition, 3.0) is False
        assert fw.clock.now >= start + 3.0
        ends.append((fw.clock.now, fw.whole_passes, outcome(printer)))
    assert ends[0] == ends[1]
