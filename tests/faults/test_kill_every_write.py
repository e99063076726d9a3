"""kill -9 of `sim serve` at every write it makes to its state directory.

A killed process stops between two system calls (or inside one), and what it
wrote before stays in the kernel's page cache: the state directory holds
exactly the writes made before the kill. The virtual printer writes its state
in two ways only: a card block, a flash page or a chip dump in place
(`FileStorage.write`, one unbuffered write call each), and a chip dump that did
not exist created whole (`write_atomically`: a temporary file written, then
renamed into place).

So the served session runs once, in this process, with the printer's own
`PtyServer` (as `sim serve` runs it) and a real `robox-cli send-job` process as
its host, while those writes are recorded. A kill at any moment then leaves
the pristine directory plus the first K recorded writes, for some K; a kill
between a dump's temporary file and its rename leaves that file behind as well,
empty, torn or whole. Every such directory, for every K, must: pass the offline
checks (`sdcard fsck`, `eeprom fsck`); open as a printer whose chips load
VALID; keep the job committed before the
session; hold the new job absent or whole; and take the upload again with
resume, storing it byte-identical.

That the recording missed no write is checked too: replaying every recorded
write over the pristine directory gives the directory the session left,
file for file.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import usb.core

from robox.fileio import write_atomically
from robox.firmware.eeprom import Status
from robox.formats.eeprom import EepromIndex
from robox.formats.sdcard import make_id
from robox.hardware.storage import FileStorage
from robox.host.client import Printer
from robox.host.transport import UsbTransport
from robox.offline.eeprom import fsck_dump
from robox.offline.sdcard import format_image, fsck_image
from robox.sim import printer as sim_printer
from robox.sim.printer import VirtualPrinter
from robox.sim.serve import PtyServer
from robox.sim.usb_backend import VirtualRoboxBackend
from tests.faults.printer_campaign import job_bytes

CARD_BLOCKS = 4096  # a 2 MiB card: small enough to write out at every kill point
CHIP_FILES = {"head.eeprom": EepromIndex.HEAD, "reel0.eeprom": EepromIndex.REEL0}
JOB = job_bytes(600)  # heated, extruding: it books filament and hours as it prints
FIRST = b"G28 X Y\r" * 200


def connect(virtual: VirtualPrinter) -> Printer:
    device = usb.core.find(idVendor=0x16D0, idProduct=0x081B,
                           backend=VirtualRoboxBackend(virtual))
    return Printer(UsbTransport(device), idle=lambda s: virtual.run_until(
        lambda: False, s))


def read_dir(state: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(state.iterdir())}


def pristine(state: Path) -> dict[str, bytes]:
    """A printer with a small card holding one committed job, switched off."""
    state.mkdir()
    format_image(state / "sdcard.img", CARD_BLOCKS)
    with VirtualPrinter(state) as virtual:
        virtual.settle()
        connect(virtual).send_file(FIRST, "first", run=False)
        virtual.settle()
    return read_dir(state)


def record_session(state: Path, job_file: Path, monkeypatch) -> list[tuple]:
    """Serve the printer while a real host uploads the job and it prints to its end;
    returns every write to the state directory, in order."""
    ops: list[tuple] = []
    write_in_place = FileStorage.write

    def recorded_write(storage, offset, data):
        ops.append(("write", Path(storage.path).name, offset, bytes(data)))
        write_in_place(storage, offset, data)

    def recorded_replace(path, data):
        ops.append(("replace", Path(path).name, bytes(data)))
        write_atomically(path, data)

    monkeypatch.setattr(FileStorage, "write", recorded_write)
    monkeypatch.setattr(sim_printer, "write_atomically", recorded_replace)
    printer = VirtualPrinter(state)
    server = PtyServer(printer)
    host = subprocess.Popen([sys.executable, "-m", "robox.cli", "--device",
                             f"serial:{server.path}", "send-job", str(job_file), "--raw",
                             "--id", "part"], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        while host.poll() is None:
            server.serve_once()
        fw = printer.firmware
        until = fw.clock.now + 3600
        while (fw.job.running or fw.heaters.any_on()) and fw.clock.now < until:
            server.serve_once(timeout=0)
        printer.settle()  # as sim serve stops
    finally:
        printer.close()
        server.close()
    _, err = host.communicate()
    assert host.returncode == 0, err.decode()
    assert not fw.job.running, "the job did not print to its end"
    monkeypatch.undo()
    return ops


def apply(files: dict[str, bytearray], op: tuple) -> None:
    if op[0] == "write":
        _, name, offset, data = op
        files[name][offset : offset + len(data)] = data
    else:
        _, name, data = op
        files[name] = bytearray(data)


def judge(state: Path, expected: bytes) -> list[str]:
    problems = []
    card = fsck_image(state / "sdcard.img")
    if card["project"]["action"] == "format":
        problems.append(f"sdcard fsck: the card would be formatted ({card['project']})")
    for name in CHIP_FILES:
        verdict = fsck_dump(state / name)
        if not verdict["valid"]:
            problems.append(f"eeprom fsck {name}: {verdict['reason']}")
    with VirtualPrinter(state) as virtual:
        virtual.settle()
        fw = virtual.firmware
        for name, index in CHIP_FILES.items():
            if fw.eeproms.status(index) != Status.VALID:
                problems.append(f"{name} loads {fw.eeproms.status(index).name}")
        if fw.file_system.read_committed(make_id("first")) != FIRST:
            problems.append("the job committed before the session was lost")
        part = fw.file_system.read_committed(make_id("part"))
        if part is not None and part != expected:
            problems.append("'part' is stored but not whole")
        connect(virtual).send_file(expected, "part", run=False, resume=True)
        if fw.file_system.read_committed(make_id("part")) != expected:
            problems.append("after the upload again with resume, 'part' is not "
                            "byte-identical")
    stale = [p.name for p in state.iterdir() if p.name.endswith(".tmp")]
    if stale:
        problems.append(f"opening left temporary files: {stale}")
    return problems


def test_kill_9_at_every_write_of_a_served_print_leaves_a_state_that_reopens(
        tmp_path, monkeypatch):
    start = pristine(tmp_path / "pristine")
    job_file = tmp_path / "part.gcode"
    job_file.write_bytes(JOB)
    session = tmp_path / "session"
    session.mkdir()
    for name, data in start.items():
        (session / name).write_bytes(data)
    ops = record_session(session, job_file, monkeypatch)
    end = read_dir(session)

    # the recording holds every write: replayed over the pristine files, it gives the end
    files = {name: bytearray(data) for name, data in start.items()}
    for op in ops:
        apply(files, op)
    assert {name: bytes(data) for name, data in files.items()} == end
    kinds = {(op[0], op[1]) for op in ops}
    assert {("write", "sdcard.img"), ("write", "flash.bin"), ("write", "head.eeprom"),
            ("write", "reel0.eeprom")} <= kinds, kinds
    with VirtualPrinter(session) as virtual:
        expected = virtual.firmware.file_system.read_committed(make_id("part"))
    assert expected == JOB

    files = {name: bytearray(data) for name, data in start.items()}
    problems = []
    points = 0
    for k in range(len(ops) + 1):
        if k:
            apply(files, ops[k - 1])
        # killed after write k; and, before a dump's rename, with its temporary file
        # left behind, empty, half written or whole
        leftovers = [None]
        if k < len(ops) and ops[k][0] == "replace":
            data = ops[k][2]
            leftovers += [(ops[k][1], b""), (ops[k][1], data[: len(data) // 2]),
                          (ops[k][1], data)]
        for leftover in leftovers:
            state = tmp_path / f"kill{k}"
            state.mkdir()
            for name, data in files.items():
                (state / name).write_bytes(data)
            if leftover is not None:
                (state / f".{leftover[0]}.killed.tmp").write_bytes(leftover[1])
            label = f"killed after write {k} of {len(ops)}" + (
                "" if leftover is None else f" with {len(leftover[1])} bytes of a temporary "
                f"{leftover[0]}")
            problems += [f"{label}: {p}" for p in judge(state, expected)]
            points += 1
            for p in state.iterdir():
                p.unlink()
            state.rmdir()
    assert not problems, "\n".join(problems[:20])
    assert points > len(ops) > 50
