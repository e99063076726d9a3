"""Two programs at once: a port, an image, a dump or a catalogue is used by one at a
time; a second is refused in one line naming the holder, or waits with --wait-lock,
and never disturbs the first."""

import json
import os
import subprocess
import sys
import time

import pytest
from click.testing import CliRunner

from robox.cli import cli
from robox.formats.protocol import reply_length
from robox.hardware.storage import FileStorage
from robox.host.transport import SerialTransport
from robox.locks import describe_pid
from robox.offline.sdcard import format_image, list_image
from robox.sim.printer import VirtualPrinter
from robox.sim.serve import PtyServer

CLI = [sys.executable, "-m", "robox.cli"]


def refusal(path, pid: int = 0) -> str:
    """The one line a command refused `path` says."""
    return f"robox-cli: error: {path} is in use by {describe_pid(pid or os.getpid())}"


def pumped(server: PtyServer, replies: int) -> None:
    """Serve until the printer has sent `replies` replies and they are in the pty."""
    for _ in range(10_000):
        server.serve_once(timeout=0)
        if server.printer.usb.replies >= replies and not server.printer.usb.reply_waiting \
                and not server._pending_out:
            return
    raise AssertionError("the printer did not answer")


def read_report(port: SerialTransport) -> bytes:
    reply = b""
    while reply_length(reply) is None or len(reply) < reply_length(reply):
        reply += port.read(64, 2000)
    return reply


@pytest.fixture
def served():
    server = PtyServer(VirtualPrinter(), None)
    server.printer.settle()
    yield server
    server.close()
    server.printer.close()


def test_a_refused_client_leaves_the_reply_its_holder_awaits(served):
    """Opening a tty flushes what it has received: a second client that opened the port
    before finding it locked threw away the reply the first was waiting for."""
    holder = SerialTransport(served.path)
    try:
        holder.write(b"\xb3")
        pumped(served, served.printer.usb.replies + 1)  # the reply waits in the port
        second = subprocess.run([*CLI, "--device", f"serial:{served.path}", "status"],
                                capture_output=True, timeout=120)
        assert second.returncode == 1 and second.stdout == b""
        assert second.stderr.decode().splitlines() == [refusal(served.path)]
        reply = read_report(holder)
        assert reply[0] == 0xE3 and len(reply) == reply_length(reply)
    finally:
        holder.close()


def test_wait_lock_waits_for_the_port_and_then_runs(served):
    holder = SerialTransport(served.path)
    second = subprocess.Popen([*CLI, "--device", f"serial:{served.path}", "--wait-lock", "60",
                               "status", "--json"], stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE)
    try:
        end = time.monotonic() + 1.0
        while time.monotonic() < end:  # it waits: the port is ours
            served.serve_once(timeout=0.01)
        assert second.poll() is None
        holder.close()
        end = time.monotonic() + 120
        while second.poll() is None and time.monotonic() < end:
            served.serve_once(timeout=0.01)
        out, err = second.communicate(timeout=10)
        assert second.returncode == 0, err.decode()
        assert "sd_card" in json.loads(out) or json.loads(out)
    finally:
        if second.poll() is None:
            second.kill()
        holder.close()


@pytest.fixture
def card(tmp_path):
    image = tmp_path / "card.img"
    format_image(image, 16384)  # room for both parts below, with none dropped
    return image


def test_a_put_on_an_image_another_program_writes_is_refused(card, tmp_path):
    part = tmp_path / "part.gcode"
    part.write_bytes(b"G1 X10\n" * 1000)
    before = card.read_bytes()
    with FileStorage(card, writable=True):  # another program writes the image
        result = subprocess.run([*CLI, "sdcard", "put", str(card), str(part)],
                                capture_output=True, timeout=120)
    assert result.returncode == 1
    assert result.stderr.decode().splitlines() == [refusal(card)]
    assert card.read_bytes() == before
    with FileStorage(card):  # another program reads it: so may we
        assert list_image(card)["files"] == []


def test_two_puts_at_once_with_wait_lock_both_land(card, tmp_path):
    parts = []
    for n in range(2):
        part = tmp_path / f"part{n}.gcode"
        part.write_bytes(f"G1 X{n + 1}0\r".encode() * 20_000)  # a job stored as it is
        parts.append(part)
    # (jobs: a file that is not a job is dropped when the next file is stored)
    runs = [subprocess.Popen([*CLI, "--wait-lock", "120", "sdcard", "put", str(card), str(p),
                              "--id", p.stem, "--job"], stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE)
            for p in parts]
    for run in runs:
        _, err = run.communicate(timeout=300)
        assert run.returncode == 0, err.decode()
    assert sorted(f["id"] for f in list_image(card)["files"]) == ["part0", "part1"]
    fsck = CliRunner().invoke(cli, ["sdcard", "fsck", str(card)])
    assert fsck.exit_code == 0, fsck.output


def test_a_switched_on_printers_files_are_refused_to_offline_writers(tmp_path):
    state = tmp_path / "printer"
    part = tmp_path / "part.gcode"
    part.write_bytes(b"G1 X10\n" * 100)
    with VirtualPrinter(state) as printer:
        printer.settle()
        before = {p.name: p.read_bytes() for p in state.iterdir()}
        runner = CliRunner()
        for args, path in ((["sdcard", "put", str(state / "sdcard.img"), str(part)],
                            state / "sdcard.img"),
                           (["eeprom", "set", str(state / "reel0.eeprom"),
                             "filament_diameter=2.85"], state / "reel0.eeprom"),
                           (["eeprom", "set", str(state / "head.eeprom"),
                             "nozzle1_z_offset=0.1"], state / "head.eeprom")):
            result = runner.invoke(cli, args)
            assert result.exit_code == 1, result.output
            assert result.output.splitlines() == [refusal(path)]
        assert {p.name: p.read_bytes() for p in state.iterdir()} == before


def test_catalogue_records_from_many_hosts_at_once_are_all_kept(tmp_path):
    """Each host reads the catalogue, adds its file and replaces it: under the lock, no
    host's entry is lost to another's replacement."""
    script = ("import sys\nfrom robox.host import catalogue\n"
              "for n in range(25):\n"
              "    catalogue.record('RBX01-0001', f'{sys.argv[1]}-{n}', n, n, True)\n")
    env = {**os.environ, "XDG_STATE_HOME": str(tmp_path)}
    hosts = [subprocess.Popen([sys.executable, "-c", script, f"host{k}"], env=env)
             for k in range(6)]
    for host in hosts:
        assert host.wait(timeout=300) == 0
    kept = json.loads((tmp_path / "robox" / "cards" / "RBX01-0001.json").read_text())
    assert sorted(kept["files"]) == sorted(f"host{k}-{n}" for k in range(6) for n in range(25))


def serve_while(server: PtyServer, child: subprocess.Popen, wall_s: float = 300) -> None:
    end = time.monotonic() + wall_s
    while child.poll() is None and time.monotonic() < end:
        server.serve_once(timeout=0.01)


def send_job_wait(served: PtyServer, job, job_id: str) -> subprocess.Popen:
    return subprocess.Popen([*CLI, "--device", f"serial:{served.path}", "send-job",
                             str(job), "--raw", "--id", job_id, "--wait"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)


def test_send_job_wait_ends_on_a_pause_for_an_error_and_frees_the_port(served, tmp_path):
    """The printer pauses the job for an open nozzle thermistor: the wait ends with the
    error's name, what the user can do, and status 1, leaving the port to `abort`. (The
    thermistor breaks once the upload is complete: an error during the upload ends the
    upload instead.)"""
    fw = served.printer.firmware
    job = tmp_path / "heat.gcode"
    job.write_bytes(b"M104 S200\nG28 X Y\n" + b"G1 X20 Y20 F600\nG1 X100 Y100\n" * 200)
    send = send_job_wait(served, job, "heat")
    end = time.monotonic() + 120
    while not (fw.job.running and fw.file_system.send_file_report()[0] == bytes(16)) and \
            send.poll() is None and time.monotonic() < end:
        served.serve_once(timeout=0.01)
    served.printer.hw.machine.heaters["nozzle0"].thermistor_ok = False
    serve_while(served, send)
    _, err = send.communicate(timeout=10)
    assert send.returncode == 1, err.decode()
    last = err.decode().strip().splitlines()[-1]
    assert last.startswith("robox-cli: error: heat is paused at line ")
    assert last.endswith("for an error: nozzle 0 thermistor fault; once its cause is dealt "
                         "with, `robox-cli resume` continues it, or `robox-cli abort` ends it")
    abort = subprocess.Popen([*CLI, "--device", f"serial:{served.path}", "abort"],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    serve_while(served, abort)
    assert abort.wait(timeout=10) == 0, abort.stderr.read().decode()
    assert served.printer.run_until(lambda: not fw.job.running, 30.0)  # motion stops first


def test_send_job_wait_says_once_that_a_user_pause_is_waited_out(served, tmp_path):
    fw = served.printer.firmware
    job = tmp_path / "moves.gcode"
    # (a host on a serial port polls twice a second, and the served clock waits for
    # it: a few seconds of wall time)
    job.write_bytes(b"G28 X Y\n" + b"G1 X20 Y20 F3000\nG1 X100 Y100\n" * 12)
    send = send_job_wait(served, job, "moves")
    end = time.monotonic() + 120
    while fw.job.line_number < 4 and time.monotonic() < end:
        served.serve_once(timeout=0.01)
    fw.job.pause_resume(b"1")  # paused by another party (a pause the host did not make)
    end = time.monotonic() + 2.0
    while time.monotonic() < end:
        served.serve_once(timeout=0.01)
    assert send.poll() is None and fw.job.paused()
    fw.job.pause_resume(b"0")
    serve_while(served, send)
    out, err = send.communicate(timeout=10)
    assert send.returncode == 0, err.decode()
    said = [line for line in err.decode().splitlines() if "is paused" in line]
    assert len(said) == 1 and said[0].startswith("moves is paused at line ")
    assert said[0].endswith("(by the user or the job): waiting for it to be resumed (Ctrl-C "
                            "stops waiting and leaves it paused; `robox-cli resume` then "
                            "continues it)")
    assert out.decode().startswith("sent moves:")
