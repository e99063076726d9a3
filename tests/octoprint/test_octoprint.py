"""OctoPrint itself, from PyPI, driving a served virtual printer through the plugin.

OctoPrint is started headless on 127.0.0.1 with its own base directory and driven
through its REST API only, as a user's browser does. The printer is a virtual one
served in the background (`robox-cli sim serve --detach`), reached through the
plugin's `robox:sim:DIR` port. Checked, each through what OctoPrint reports:

- the Robox's heaters under OctoPrint's names (tool0, bed, chamber; no tool1 on the
  virtual printer's single-material head), and a target set on tool 0 reaching
  nozzle 0 alone;
- an upload to the card with print: OctoPrint is printing from the card before the
  upload has ended (print while uploading), progress advances, and pause, resume and
  cancel reach the printer; the stored file is the job `robox-cli send-job` would
  store, byte for byte;
- "Printed" counted in bytes of the file;
- a printer error shown as an OctoPrint notification, and the job the printer paused
  for it shown as Paused, then cancelled with its heaters off.

OctoPrint is taken from this environment when installed (`.[test]` installs it),
else installed into a scratch environment; the test is skipped, saying why, only
when that installation fails.
"""

from __future__ import annotations

import contextlib
import http.client
import importlib.util
import json
import os
import signal
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request
from pathlib import Path

import pytest

from robox.formats.sdcard import default_id
from robox.gcode import job_file
from robox.locks import read_record

REPO = Path(__file__).resolve().parents[2]
KEY = "0123456789ABCDEF0123456789ABCDEF"
DISABLED = ["announcements", "tracking", "discovery", "errortracking", "softwareupdate",
            "pluginmanager", "firmware_check", "healthcheck", "achievements",
            "virtual_printer", "gcodeviewer", "backup"]


@pytest.fixture(scope="module")
def octoprint_python(tmp_path_factory) -> str:
    if importlib.util.find_spec("octoprint") is not None:
        return sys.executable
    venv = tmp_path_factory.mktemp("octoprint-venv")
    try:
        subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True,
                       capture_output=True, timeout=300)
        subprocess.run([str(venv / "bin" / "pip"), "install", "-q", "OctoPrint>=1.10",
                        "-e", str(REPO)], check=True, capture_output=True, timeout=900)
    except (subprocess.CalledProcessError, subprocess.TimeoutExpired, OSError) as exc:
        detail = getattr(exc, "stderr", b"") or b""
        pytest.skip(f"OctoPrint could not be installed: {exc} "
                    f"{detail.decode(errors='replace')[-300:]}")
    return str(venv / "bin" / "python")


class OctoPrint:
    def __init__(self, url: str, logs: Path | None = None):
        self.url = url
        self.logs = logs  # OctoPrint's log directory: its serial log is shown on a failure

    def serial_log_tail(self, lines: int = 40) -> str:
        log = self.logs / "serial.log" if self.logs else None
        if log is None or not log.exists():
            return ""
        return "\n".join(log.read_text(errors="replace").splitlines()[-lines:])

    def call(self, method: str, path: str, body=None, raw: bytes | None = None,
             content_type: str = "application/json"):
        data = raw if raw is not None else (json.dumps(body).encode() if body is not None
                                            else None)
        request = urllib.request.Request(self.url + path, data=data, method=method,
                                         headers={"X-Api-Key": KEY,
                                                  "Content-Type": content_type})
        with urllib.request.urlopen(request, timeout=60) as reply:
            text = reply.read()
        return json.loads(text) if text else None

    def upload_to_card(self, name: str, data: bytes, print_it: bool) -> dict:
        boundary = "robox-test-boundary"
        body = (f"--{boundary}\r\nContent-Disposition: form-data; name=\"file\"; "
                f"filename=\"{name}\"\r\nContent-Type: application/octet-stream\r\n\r\n"
                ).encode() + data + (
                f"\r\n--{boundary}\r\nContent-Disposition: form-data; name=\"print\"\r\n\r\n"
                f"{'true' if print_it else 'false'}\r\n--{boundary}--\r\n").encode()
        return self.call("POST", "/api/files/sdcard", raw=body,
                         content_type=f"multipart/form-data; boundary={boundary}")

    def until(self, what: str, check, timeout: float = 60.0, every: float = 0.05):
        deadline = time.monotonic() + timeout
        last = None
        while time.monotonic() < deadline:
            last = check()
            if last:
                return last
            time.sleep(every)
        raise AssertionError(f"OctoPrint never showed {what} (last: {last!r}); its serial "
                             f"log ends:\n{self.serial_log_tail()}")

    def state(self) -> str:
        return self.call("GET", "/api/job")["state"]

    def connect(self, port: str, tools: int = 1) -> None:
        """Connect to `port`, wait until Operational, and show `tools` tools and the
        chamber (the Robox's ambient)."""
        self.call("POST", "/api/connection", {"command": "connect", "port": port,
                                              "baudrate": 115200})
        self.until(f"Operational on {port}", lambda: self.state() == "Operational")
        self.call("PATCH", "/api/printerprofiles/_default",
                  {"profile": {"heatedChamber": True, "extruder": {"count": tools}}})

    def disconnect(self) -> None:
        self.call("POST", "/api/connection", {"command": "disconnect"})
        self.until("Offline", lambda: self.state().startswith("Offline"), timeout=30)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def rig(octoprint_python, tmp_path_factory):
    base = tmp_path_factory.mktemp("octoprint-rig")
    env = dict(os.environ, HOME=str(base / "home"), XDG_RUNTIME_DIR=str(base / "run"),
               XDG_STATE_HOME=str(base / "state"), XDG_DATA_HOME=str(base / "data"))
    for d in ("home", "run"):
        (base / d).mkdir()
    state = base / "printer"
    cli = [sys.executable, "-m", "robox.cli"]
    subprocess.run([*cli, "sim", "serve", "--detach", "--speed", "10", "--state", str(state)],
                   env=env, check=True, capture_output=True, timeout=60)
    home = base / "octoprint"
    home.mkdir()
    (home / "config.yaml").write_text(
        f"api:\n  key: {KEY}\nserver:\n  firstRun: false\n  onlineCheck:\n    enabled: false\n"
        f"  pluginBlacklist:\n    enabled: false\nserial:\n  autoconnect: false\n  log: true\n"
        f"plugins:\n  _disabled: [{', '.join(DISABLED)}]\n")
    port = _free_port()
    with open(base / "octoprint.log", "wb") as log:
        server = subprocess.Popen([octoprint_python, "-m", "octoprint", "serve",
                                   "--iknowwhatimdoing", "--basedir", str(home),
                                   "--host", "127.0.0.1", "--port", str(port)],
                                  env=env, stdout=log, stderr=subprocess.STDOUT)
        op = OctoPrint(f"http://127.0.0.1:{port}", home / "logs")
        try:
            def up():
                if server.poll() is not None:
                    log_text = (base / "octoprint.log").read_text()
                    raise AssertionError(f"OctoPrint exited: {log_text}")
                # while it starts, the port may refuse, or answer before OctoPrint does
                with contextlib.suppress(OSError, urllib.error.URLError,
                                         http.client.HTTPException, ValueError):
                    return op.call("GET", "/api/version")
                return None
            op.until("its API", up, timeout=120, every=0.5)
            yield op, state, env, base
        finally:
            server.terminate()
            try:
                server.wait(30)
            except subprocess.TimeoutExpired:
                server.kill()
            _stop(cli, state, env)


def _job(lines: int) -> bytes:
    """A job long enough to print while it uploads (a few hundred chunks)."""
    out = ["G28", "G90"]
    for i in range(lines):
        out.append(f"G1 X{10 + (i % 50)} Y{10 + (i * 7) % 50} F6000")
    return ("\n".join(out) + "\n").encode()


def _catalogue(base: Path) -> dict:
    entries = {}
    for path in (base / "state" / "robox" / "cards").glob("*.json"):
        entries.update(json.loads(path.read_text())["files"])
    return entries


def test_octoprint_drives_a_robox(rig, tmp_path):
    op, state, env, base = rig

    # --- connect through the plugin's port for this virtual printer
    ports = op.call("GET", "/api/connection")["options"]["ports"]
    port = f"robox:sim:{state}"
    assert port in ports, ports
    op.connect(port)

    # --- temperatures under OctoPrint's names; tool 0's target reaches nozzle 0 (the
    # virtual head is single-material: its nozzle 1 has no heater to set)
    op.call("POST", "/api/printer/tool", {"command": "target", "targets": {"tool0": 150}})

    def targets():
        t = op.call("GET", "/api/printer").get("temperature", {})
        if {"tool0", "bed", "chamber"} <= t.keys() and t["tool0"]["target"] == 150:
            return t
        return None
    t = op.until("tool 0 heating to 150", targets, timeout=30)
    assert "tool1" not in t  # a single-material head has one nozzle heater
    assert t["bed"]["target"] == 0
    assert 0 < t["tool0"]["actual"] < 300 and 0 < t["chamber"]["actual"] < 100
    op.call("POST", "/api/printer/tool", {"command": "target", "targets": {"tool0": 0}})
    op.until("tool 0 off", lambda: op.call("GET", "/api/printer")["temperature"]["tool0"]
             ["target"] == 0, timeout=30)

    # --- upload with print: printing from the card while the upload goes on
    source = tmp_path / "long_part.gcode"
    source.write_bytes(_job(12000))
    with job_file(str(source), None) as prepared:
        expected = Path(prepared.path).read_bytes()
        card_id = default_id("long_part", prepared.sha1)
    reply = op.upload_to_card("long_part.gcode", source.read_bytes(), print_it=True)
    assert reply["files"]["sdcard"]["name"] == f"{card_id}.gco"
    op.until("printing from SD", lambda: op.state().startswith("Printing"), timeout=60,
             every=0.02)
    assert card_id not in _catalogue(base), "the upload had ended before the print began"
    op.until("progress", lambda: (op.call("GET", "/api/job")["progress"]["completion"] or 0)
             > 0, timeout=60)
    # "Printed" in bytes of the job OctoPrint uploaded, not in its lines
    job = op.call("GET", "/api/job")
    assert job["job"]["file"]["size"] == len(expected)
    assert 0 < job["progress"]["filepos"] <= len(expected)

    # --- pause (the upload carries on), resume, cancel
    op.call("POST", "/api/job", {"command": "pause", "action": "pause"})
    op.until("Paused", lambda: op.state() == "Paused", timeout=60)
    op.until("the upload's end", lambda: card_id in _catalogue(base), timeout=120)
    entry = _catalogue(base)[card_id]
    assert entry["size"] == len(expected) and entry["job"] is True
    assert entry["lines"] == expected.count(b"\r")
    assert op.state() == "Paused"
    op.call("POST", "/api/job", {"command": "pause", "action": "resume"})
    op.until("printing again", lambda: op.state().startswith("Printing"), timeout=60)
    op.call("POST", "/api/job", {"command": "cancel"})
    op.until("Operational after cancel", lambda: op.state() == "Operational", timeout=60)

    # --- a printer error becomes an OctoPrint notification: a dual head's nozzle 1
    # heated on a single-material head, whose thermistor input reads open
    bad = b"M104 T200\n" + b"G4 S2\n" * 30
    op.upload_to_card("bad_heat.gcode", bad, print_it=True)

    def notified():
        notes = op.call("GET", "/api/plugin/action_command_notification")["notifications"]
        return [n for n in notes if "nozzle 1 thermistor" in n["message"]]
    op.until("the error as a notification", notified, timeout=90, every=0.2)
    # the printer paused the job for it: OctoPrint shows it paused, offering Cancel
    op.until("Paused for the error", lambda: op.state() == "Paused", timeout=60)
    op.call("POST", "/api/job", {"command": "cancel"})
    op.until("Operational after cancel", lambda: op.state() == "Operational", timeout=60)

    # --- a cancelled job's heaters are off, and OctoPrint shows them off
    heats = b"M104 S160\n" + b"G4 S2\n" * 60
    op.upload_to_card("heats.gcode", heats, print_it=True)
    op.until("the job heating tool 0", lambda: op.call("GET", "/api/printer")
             ["temperature"]["tool0"]["target"] == 160, timeout=60, every=0.2)
    op.call("POST", "/api/job", {"command": "cancel"})
    op.until("Operational after cancel", lambda: op.state() == "Operational", timeout=60)
    op.until("tool 0's target gone with the job", lambda: op.call("GET", "/api/printer")
             ["temperature"]["tool0"]["target"] == 0, timeout=30, every=0.2)

    # --- the card holds the job as robox-cli would have stored it
    op.disconnect()
    subprocess.run([sys.executable, "-m", "robox.cli", "sim", "stop", "--state", str(state)],
                   env=env, check=True, capture_output=True, timeout=60)
    stored = tmp_path / "stored.gcode"
    subprocess.run([sys.executable, "-m", "robox.cli", "sdcard", "get",
                    str(state / "sdcard.img"), card_id, "-o", str(stored)],
                   env=env, check=True, capture_output=True, timeout=60)
    assert stored.read_bytes() == expected


def test_octoprint_on_the_plain_port_of_a_robox_left_in_robox_mode(rig, tmp_path):
    """A Robox a host left in Robox mode answers no text: OctoPrint connecting to its
    own serial port gets it back in text (an idle printer is reset), or, while a job
    keeps it in Robox mode, is connected through the Robox link and follows the job."""
    op, _, env, base = rig
    state = base / "plain-printer"
    cli = [sys.executable, "-m", "robox.cli"]
    try:
        subprocess.run([*cli, "sim", "serve", "--detach", "--speed", "10", "--state",
                        str(state)], env=env, check=True, capture_output=True, timeout=60)
        pty = json.loads(subprocess.run([*cli, "sim", "status", "--json", "--state",
                                         str(state)], env=env, check=True,
                                        capture_output=True, timeout=60).stdout)["pty"]
        device = ["--device", f"sim:{state}"]
        subprocess.run([*cli, *device, "status"], env=env, check=True, capture_output=True,
                       timeout=60)  # frames: Robox mode from now until a reset
        assert pty in op.call("GET", "/api/connection")["options"]["ports"]

        # --- idle: OctoPrint talks text to it, with the Robox's temperatures renamed
        op.connect(pty)
        op.call("POST", "/api/printer/tool", {"command": "target", "targets": {"tool0": 150}})

        def heating():
            t = op.call("GET", "/api/printer").get("temperature", {})
            if {"tool0", "bed", "chamber"} <= t.keys() and t["tool0"]["actual"] > 60:
                return t
            return None
        t = op.until("nozzle 0 heating as tool 0", heating, timeout=60, every=0.2)
        assert t.get("tool1", {}).get("actual", 0) < 40 and t["bed"]["actual"] < 40
        op.call("POST", "/api/printer/tool", {"command": "target", "targets": {"tool0": 0}})
        op.disconnect()

        # --- a job in Robox mode: not reset, followed through the Robox link
        source = tmp_path / "followed.gcode"
        source.write_text("G28 X Y\nG90\n" + "".join(  # slow moves: minutes of printing
            f"G1 X{10 + i % 50} Y{10 + (i * 7) % 50} F300\n" for i in range(2000)))
        subprocess.run([*cli, *device, "send-job", str(source), "--id", "followed"],
                       env=env, check=True, capture_output=True, timeout=120)
        op.call("POST", "/api/connection", {"command": "connect", "port": pty,
                                            "baudrate": 115200})
        op.until("printing the job it found", lambda: op.state().startswith("Printing"),
                 timeout=60, every=0.1)
        assert op.call("GET", "/api/job")["job"]["file"]["name"] == "followed.gco"

        def told():
            notes = op.call("GET", "/api/plugin/action_command_notification")["notifications"]
            return [n for n in notes if "under way in Robox mode" in n["message"]]
        op.until("why it stays in Robox mode", told, timeout=30, every=0.2)
        op.call("POST", "/api/job", {"command": "cancel"})
        op.until("Operational after cancel", lambda: op.state() == "Operational", timeout=60)
        op.disconnect()
    finally:
        _stop(cli, state, env)


def _stop(cli: list[str], state: Path, env: dict) -> None:
    """Switch the served printer off; one that does not stop is killed, so that no test
    leaves a printer running."""
    with contextlib.suppress(subprocess.SubprocessError):
        subprocess.run([*cli, "sim", "stop", "--state", str(state)], env=env,
                       capture_output=True, timeout=60)
    record = read_record(state) if state.exists() else None
    if record and record.get("pid"):
        with contextlib.suppress(OSError):
            os.kill(record["pid"], signal.SIGKILL)
