"""kill -9 of `robox-cli sim serve` while a host uploads a job that prints.

The state directory's files are written as the printer writes its media: the card,
the flash and each chip dump in place, one block, page or dump per write (a new
dump is created whole, by a rename). A process killed at any moment therefore
leaves the card and flash as a power cut right after some write would, and each
chip as it was at some moment: test_kill_every_write.py judges every such state of
a served print.
Here real processes are killed at moments spread over a session, from the state
directory's creation to the end of the upload; after each the directory must open
as a printer, pass the offline checks, keep every committed file, and take
`send-job --resume`.
"""

import hashlib
import shutil
import signal
import subprocess
import sys
import time

from click.testing import CliRunner

from robox.cli import cli
from robox.firmware.eeprom import Status
from robox.formats.eeprom import EepromIndex
from robox.formats.sdcard import make_id
from robox.sim.printer import VirtualPrinter

#: When `sim serve` is killed: at its start (0), or this fraction of an unbroken
#: upload's wall time after the host starts (measured first, on the same machine, so
#: that the kills spread over the upload however fast the model runs).
MOMENTS = (0.0, 0.02, 0.06, 0.12, 0.2, 0.3, 0.4, 0.5, 0.62, 0.75, 0.9, 1.2)


def run(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def serve(state):
    return subprocess.Popen([sys.executable, "-m", "robox.cli", "sim", "serve", "--state",
                             str(state)], stdout=subprocess.PIPE, stderr=subprocess.PIPE)


def send(path: str, job) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "robox.cli", "--device", f"serial:{path}",
                             "send-job", str(job), "--raw", "--id", "part"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)


def unbroken_upload_seconds(pristine, state, job) -> float:
    """Wall seconds from the host's start to its end, nothing killed."""
    shutil.copytree(pristine, state)
    server = serve(state)
    try:
        path = server.stdout.readline().decode().strip()
        start = time.monotonic()
        host = send(path, job)
        _, err = host.communicate(timeout=120)
        assert host.returncode == 0, err.decode()
        return time.monotonic() - start
    finally:
        server.send_signal(signal.SIGTERM)
        server.wait(timeout=30)


def test_kill_9_at_moments_through_a_served_upload_leaves_a_state_that_reopens(tmp_path):
    pristine = tmp_path / "pristine"
    job = tmp_path / "part.gcode"
    job.write_bytes(b"".join(f"G1 X{i % 50 + 10} Y{i % 37 + 10} F6000\n".encode()
                             for i in range(16000)))
    expected = job.read_bytes().replace(b"\n", b"\r")
    first = tmp_path / "first.gcode"
    first.write_bytes(b"G28 X Y\n" * 200)
    assert run("--device", f"sim-once:{pristine}", "send-job", first, "--raw", "--id", "first",
               "--wait").exit_code == 0
    with VirtualPrinter(pristine) as virtual:
        stored_first = virtual.firmware.file_system.read_committed(make_id("first"))
    upload_s = unbroken_upload_seconds(pristine, tmp_path / "unbroken", job)
    problems = []
    killed_mid_upload = 0
    for number, fraction in enumerate(MOMENTS):
        moment = fraction * upload_s
        state = tmp_path / f"printer{number}"  # each kill starts from the same printer
        shutil.copytree(pristine, state)
        server = serve(state)
        host = None
        if moment > 0:
            path = server.stdout.readline().decode().strip()
            host = send(path, job)
            time.sleep(moment)
        server.send_signal(signal.SIGKILL)
        server.wait(timeout=30)
        if host is not None:
            _, err = host.communicate(timeout=60)
            killed_mid_upload += host.returncode != 0
        label = f"killed {moment:.2f} s after the start"
        if host is not None and host.returncode != 0:
            lines = err.decode().strip().splitlines()
            if "Traceback" in err.decode() or not lines[-1].startswith("robox-cli: error"):
                problems.append(f"{label}: the host's error is not one line: {lines[-3:]}")
        for name in ("sdcard.img",):
            result = run("sdcard", "fsck", state / name)
            if result.exit_code != 0:
                problems.append(f"{label}: sdcard fsck: {result.output.strip()}")
        for name in ("head.eeprom", "reel0.eeprom"):
            result = run("eeprom", "fsck", state / name)
            if result.exit_code != 0:
                problems.append(f"{label}: eeprom fsck {name}: {result.output.strip()}")
        with VirtualPrinter(state) as virtual:
            virtual.settle()
            fw = virtual.firmware
            for index in (EepromIndex.HEAD, EepromIndex.REEL0):
                if fw.eeproms.status(index) != Status.VALID:
                    problems.append(f"{label}: {index.name} is {fw.eeproms.status(index).name}")
            if fw.file_system.read_committed(make_id("first")) != stored_first:
                problems.append(f"{label}: the committed job 'first' was lost")
            part = fw.file_system.read_committed(make_id("part"))
            if part is not None and part != expected:
                problems.append(f"{label}: 'part' is stored but not whole")
        result = run("--device", f"sim-once:{state}", "send-job", job, "--raw", "--id", "part",
                     "--resume")
        if result.exit_code != 0:
            problems.append(f"{label}: send-job --resume: {result.output.strip()}")
        with VirtualPrinter(state) as virtual:
            stored = virtual.firmware.file_system.read_committed(make_id("part"))
            if hashlib.sha1(stored or b"").digest() != hashlib.sha1(expected).digest():
                problems.append(f"{label}: after --resume 'part' is not byte-identical")
    assert not problems, "\n".join(problems)
    assert killed_mid_upload >= 3  # several kills did land during the upload


def test_kill_9_while_sim_serve_creates_a_new_state_directory(tmp_path):
    """A new directory is filled file by file, each written whole under a temporary name
    and renamed: a kill leaves some files or none (and perhaps a temporary file), and the
    next start removes what a killed one left and fills in the rest."""
    problems = []
    for number, moment in enumerate((0.0, 0.1, 0.15, 0.2, 0.25, 0.3, 0.5)):
        state = tmp_path / f"new{number}"
        server = serve(state)
        time.sleep(moment)
        server.send_signal(signal.SIGKILL)
        server.wait(timeout=30)
        result = run("--device", f"sim-once:{state}", "status")
        if result.exit_code != 0:
            problems.append(f"killed at {moment} s: status: {result.output.strip()}")
        leftovers = [p.name for p in state.iterdir()]
        if any(name.startswith(".") or name.endswith(".tmp") for name in leftovers):
            problems.append(f"killed at {moment} s: the next start left {leftovers}")
        for name, command in (("sdcard.img", "sdcard"), ("head.eeprom", "eeprom"),
                              ("reel0.eeprom", "eeprom")):
            result = run(command, "fsck", state / name)
            if result.exit_code != 0:
                problems.append(f"killed at {moment} s: {name}: {result.output.strip()}")
    assert not problems, "\n".join(problems)
