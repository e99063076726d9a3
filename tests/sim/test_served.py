"""A virtual printer that stays on: `--device sim:DIR` starts `sim serve` in the background
once and every later command talks to that same printer through its pseudo-terminal, so
jobs, uploads and resumes carry on across commands as on a real printer. Real processes,
real ptys, real locks; each test switches its printers off again."""

import hashlib
import io
import json
import os
import signal
import subprocess
import sys
import time

import pytest
from click.testing import CliRunner

from robox.cli import cli
from robox.host import devices
from robox.host.devices import open_printer
from robox.host.transport import SerialTransport
from robox.locks import LOCK_NAME
from robox.offline import sdcard as card_images
from tests.cli.test_sdcard_cli import one_line_error

# a job as send-job stores it (one CR per line): 30 chunks of moves, nothing heated
JOB = b"G28 X Y\r" + b"".join(b"G1 X%d Y%d F3000\r" % (10 + i % 50, 10 + (i * 7) % 50)
                             for i in range(900))


def run(*args):
    return CliRunner().invoke(cli, [str(a) for a in args], catch_exceptions=False)


def alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    with open(f"/proc/{pid}/stat") as stat:  # a zombie is no longer serving
        return stat.read().rpartition(") ")[2][:1] != "Z"


@pytest.fixture
def state(tmp_path, monkeypatch):
    """A state directory; whatever serves it is switched off afterwards."""
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path / "runtime"))
    monkeypatch.setattr(devices, "_usb_devices", lambda: [])  # no USB printers here
    directory = tmp_path / "printer"
    yield directory
    record = _record(directory)
    if record and record.get("pid"):
        os.kill(record["pid"], signal.SIGKILL)


def _record(directory):
    from robox.locks import read_record

    return read_record(directory)


def test_sim_starts_a_printer_that_stays_on_across_commands(state, tmp_path):
    job = tmp_path / "part.gcode"
    job.write_bytes(JOB.replace(b"\r", b"\n"))
    sent = run("--device", f"sim:{state}", "send-job", job, "--raw", "--id", "part", "--json")
    assert sent.exit_code == 0, sent.output
    assert json.loads(sent.stdout)["printing"] is True
    assert "started the virtual printer in the background" in sent.stderr
    # the hint names this printer's state directory, so following it stops this one
    assert sent.stderr.rstrip().endswith(f"`robox-cli sim stop --state {state}` switches "
                                         "it off")
    record = _record(state)
    assert record["role"] == "serve" and alive(record["pid"])

    # the next command reaches the same printer, the job still printing on it
    status = run("--device", f"sim:{state}", "status", "--json")
    assert status.exit_code == 0 and status.stderr == ""
    assert json.loads(status.stdout)["job"] == "part"
    assert _record(state)["pid"] == record["pid"]

    shown = run("sim", "status", "--state", state, "--json")
    assert shown.exit_code == 0
    assert json.loads(shown.stdout) | {"started": None} == {
        "state": str(state), "served": True, "pid": record["pid"], "pty": record["pty"],
        "link": str(state / "link.sock"), "started": None, "speed": None}
    # listed with the unique ID and firmware the printer itself answers (0xb2, 0xb4)
    with open_printer(f"sim:{state}") as printer:
        unique, revision = printer.unique_id(), printer.revision()
    listed = json.loads(run("printers", "--json").stdout)
    assert listed == [{"kind": "sim", "device": f"sim:{state}", "state": str(state),
                       "pid": record["pid"], "pty": record["pty"],
                       "started": record["started"], "unique_id": unique,
                       "revision": revision}]
    assert unique.startswith("RBXSIM") and revision == "r776sim"
    assert run("printers").stdout.splitlines()[-1] == (
        f"{unique}  firmware {revision}  (sim:{state}: virtual, served on {record['pty']} "
        f"by PID {record['pid']})")

    # the job runs to its end on the served printer between commands
    deadline = time.monotonic() + 60
    while json.loads(run("--device", f"sim:{state}", "status", "--json").stdout)["job"]:
        assert time.monotonic() < deadline, "the job never ended"
        time.sleep(0.1)

    stopped = run("sim", "stop", "--state", state)
    assert stopped.exit_code == 0 and f"PID {record['pid']}" in stopped.stdout
    assert not alive(record["pid"])
    assert run("sim", "status", "--state", state).exit_code == 3
    assert json.loads(run("printers", "--json").stdout) == []
    assert run("sim", "stop", "--state", state).stdout.startswith("not served")
    # switched off cleanly: the card holds the job, byte for byte
    card = state / "sdcard.img"
    assert run("sdcard", "fsck", card).exit_code == 0
    assert card_images.get_file(card, "part") == JOB


def test_an_upload_cut_off_resumes_on_the_served_printer(state, tmp_path):
    class Cut(Exception):
        pass

    def cut_after_chunk_4(done, total):
        if done >= 5 * 512:
            raise Cut

    with open_printer(f"sim:{state}") as printer, pytest.raises(Cut):
        printer.send_file(io.BytesIO(JOB), "part", progress=cut_after_chunk_4)
    job = tmp_path / "part.gcode"
    job.write_bytes(JOB)
    again = run("--device", f"sim:{state}", "send-job", job, "--raw", "--id", "part",
                "--resume", "--json")
    assert again.exit_code == 0, again.output
    summary = json.loads(again.stdout)
    assert summary["resumed_from_byte"] == 5 * 512 and summary["restarted"] is False
    assert run("sim", "stop", "--state", state).exit_code == 0
    stored = card_images.get_file(state / "sdcard.img", "part")
    assert hashlib.sha256(stored).hexdigest() == hashlib.sha256(JOB).hexdigest()


def test_resume_of_an_upload_that_had_finished_sends_nothing(state, tmp_path):
    """The link went after the last chunk was acknowledged: the file is on the card and
    printing, so --resume says so, sends nothing and leaves one copy."""
    job = tmp_path / "part.gcode"
    job.write_bytes(JOB)
    first = run("--device", f"sim:{state}", "send-job", job, "--raw", "--id", "part")
    assert first.exit_code == 0, first.output
    again = run("--device", f"sim:{state}", "send-job", job, "--raw", "--id", "part",
                "--resume")
    assert again.exit_code == 0, again.output
    assert again.stdout.splitlines() == [
        "part is already on the card (its upload had finished): nothing sent; it is printing"]
    as_json = json.loads(run("--device", f"sim:{state}", "send-job", job, "--raw", "--id",
                             "part", "--resume", "--json").stdout)
    assert as_json["already_stored"] is True and as_json["printing"] is True
    assert json.loads(run("--device", f"sim:{state}", "status", "--json").stdout)["job"] \
        == "part"
    listed = json.loads(run("--device", f"sim:{state}", "files", "--json").stdout)
    assert [f["id"] for f in listed].count("part") == 1
    assert run("sim", "stop", "--state", state).exit_code == 0


def test_one_host_at_a_time_on_a_served_printers_port(state):
    started = run("sim", "serve", "--detach", "--state", state)
    assert started.exit_code == 0, started.output
    pty = started.stdout.strip()
    assert pty == _record(state)["pty"]
    holder = SerialTransport(pty)  # a host connected to the port
    try:
        one_line_error(run("--device", f"sim:{state}", "status"), 1,
                       f"{pty} is in use by PID {os.getpid()}")
        one_line_error(run("--device", f"serial:{pty}", "status"), 1,
                       f"{pty} is in use by PID {os.getpid()}")
    finally:
        holder.close()
    assert run("--device", f"serial:{pty}", "status").exit_code == 0


def test_a_served_directory_is_not_opened_twice(state):
    assert run("sim", "serve", "--detach", "--state", state).exit_code == 0
    pid = _record(state)["pid"]
    one_line_error(run("--device", f"sim-once:{state}", "status"), 1,
                   f"in use by PID {pid}")
    one_line_error(run("sim", "serve", "--detach", "--state", state), 1,
                   f"already served by PID {pid}")
    foreground = subprocess.run([sys.executable, "-m", "robox.cli", "sim", "serve", "--state",
                                 str(state)], capture_output=True, text=True, timeout=60)
    assert foreground.returncode == 1 and foreground.stdout == ""
    assert foreground.stderr.startswith("robox-cli: error: ")
    assert f"in use by PID {pid}" in foreground.stderr
    assert "Traceback" not in foreground.stderr


def test_a_command_running_the_printer_itself_holds_it_too(state):
    from robox.sim.printer import VirtualPrinter

    with VirtualPrinter(state):  # as `--device sim-once:DIR` does, in this process
        one_line_error(run("--device", f"sim:{state}", "status"), 1,
                       f"in use by PID {os.getpid()}")
        one_line_error(run("sim", "stop", "--state", state), 1,
                       f"in use by PID {os.getpid()}")
    assert (state / LOCK_NAME).read_bytes() == b""  # released, nothing stale left in it


def test_a_killed_server_is_replaced_by_the_next_command(state):
    assert run("sim", "serve", "--detach", "--state", state).exit_code == 0
    first = _record(state)["pid"]
    os.kill(first, signal.SIGKILL)
    deadline = time.monotonic() + 10
    while _record(state) is not None:  # the kernel drops a dead process's lock
        assert time.monotonic() < deadline
        time.sleep(0.01)
    assert json.loads(run("printers", "--json").stdout) == []  # its note is cleared
    status = run("--device", f"sim:{state}", "status", "--json")
    assert status.exit_code == 0, status.output
    second = _record(state)["pid"]
    assert second != first and alive(second)
    assert json.loads(run("sim", "stop", "--state", state, "--json").stdout) == {
        "state": str(state), "stopped": True, "pid": second}


def test_sim_commands_take_the_printer_device_names(state, tmp_path):
    """`--device sim:DIR sim stop` stops the printer of DIR (it used to stop the
    per-user one); a --state naming another printer is refused."""
    assert run("--device", f"sim:{state}", "status").exit_code == 0
    pid = _record(state)["pid"]
    shown = run("--device", f"sim:{state}", "sim", "status", "--json")
    assert json.loads(shown.stdout)["state"] == str(state)
    other = tmp_path / "other"
    clash = CliRunner().invoke(cli, ["--device", f"sim:{state}", "sim", "stop", "--state",
                                     str(other)])
    one_line_error(clash, 2, "name two printers")
    assert alive(pid)
    stopped = run("--device", f"sim:{state}", "sim", "stop", "--json")
    assert json.loads(stopped.stdout) == {"state": str(state), "stopped": True, "pid": pid}
    assert not alive(pid)
