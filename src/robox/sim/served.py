"""Virtual printers that stay on: served in the background, found again by later commands.

A served printer is a `robox-cli sim serve` process. It holds its state directory's
lock (`robox.locks`) for as long as it runs, and its lock record names the
pseudo-terminal it serves on: that record is how a later command finds it, and the
kernel's lock is how that command knows the record is live. So a printer killed
with -9 is simply no longer served; the next `--device sim` starts a new one on
the same state, which powers up from what the files hold, as a real printer would.

Each server also leaves a note in a per-user runtime directory
(`$XDG_RUNTIME_DIR/robox/served`, else under the temporary directory) naming its
state directory, so that `robox-cli printers` can list the printers being served
without knowing where their state lives; a note whose printer is gone is removed
by the next reader.

A background server is started detached (a double fork and a new session): it
outlives the command that started it and leaves it no child to reap. Its console
(the printer's own notices, faults) goes to `serve.log` in the state directory,
begun afresh at each start.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import time
from pathlib import Path

from robox.errors import RoboxError
from robox.locks import InUse, describe_holder, read_record

START_TIMEOUT_S = 30.0
STOP_TIMEOUT_S = 30.0
LOG_NAME = "serve.log"


def default_state_dir() -> Path:
    """The per-user virtual printer's state directory (here, not with the printer, so a
    command naming it does not load the firmware model)."""
    base = os.environ.get("XDG_DATA_HOME") or os.path.join(os.path.expanduser("~"), ".local",
                                                           "share")
    return Path(base) / "robox" / "sim"


def runtime_dir() -> Path:
    base = os.environ.get("XDG_RUNTIME_DIR")
    if base:
        return Path(base) / "robox" / "served"
    import tempfile

    return Path(tempfile.gettempdir()) / f"robox-{os.getuid()}" / "served"


def _note_path(directory: Path) -> Path:
    import hashlib

    key = hashlib.sha1(str(directory).encode()).hexdigest()[:16]
    return runtime_dir() / key


def add_note(directory: Path) -> None:
    """Tell `printers` that this state directory is being served (best effort)."""
    path = _note_path(directory)
    with contextlib.suppress(OSError):
        path.parent.mkdir(parents=True, exist_ok=True, mode=0o700)
        path.write_text(str(directory) + "\n")


def remove_note(directory: Path) -> None:
    with contextlib.suppress(OSError):
        _note_path(directory).unlink()


def served_record(directory: Path) -> dict | None:
    """The serving process's record, or None when this state directory is not served
    (raises InUse when a command is running the printer in its own process)."""
    record = read_record(directory)
    if record is None:
        return None
    if record.get("role") != "serve":
        raise InUse(f"{directory}: the virtual printer is in use by "
                    f"{describe_holder(record)}")
    return record


def list_served() -> list[dict]:
    """Every printer served now: {"state", "pid", "pty", "started", "unique_id",
    "revision"}."""
    found = []
    try:
        notes = sorted(runtime_dir().iterdir())
    except OSError:
        return found
    for note in notes:
        try:
            directory = Path(note.read_text().strip())
            record = read_record(directory)
        except (OSError, RoboxError):
            record = None
        if record is None or record.get("role") != "serve":
            with contextlib.suppress(OSError):
                note.unlink()
            continue
        if record.get("pty"):
            found.append({"state": str(directory), "pid": record.get("pid"),
                          "pty": record["pty"], "started": record.get("started"),
                          **_identity(directory)})
    return found


def stop_hint(directory: Path) -> str:
    """The command that switches the printer of `directory` off, as a user types it."""
    import shlex

    where = "" if directory == default_state_dir() else f" --state {shlex.quote(str(directory))}"
    return f"`robox-cli sim stop{where}`"


def _identity(directory: Path) -> dict:
    """The served printer's unique ID and firmware revision, from its flash dump (read
    without its port, which another program may hold): what 0xb2 and 0xb4 answer."""
    from robox.firmware.main import DEFAULT_REVISION
    from robox.formats.firmware import flash_identity

    try:
        unique, revision = flash_identity((directory / "flash.bin").read_bytes())
    except OSError:
        return {"unique_id": None, "revision": None}
    return {"unique_id": unique or None, "revision": revision or DEFAULT_REVISION}


def _spawn_detached(argv: list[str], log: Path) -> int:
    """Start `argv` in a new session, detached from this process; its PID."""
    ready, report = os.pipe()
    child = os.fork()
    if child == 0:  # pragma: no cover - runs only in the forked child
        try:
            os.close(ready)
            os.setsid()
            grandchild = os.fork()
            if grandchild:
                os.write(report, str(grandchild).encode())
                os._exit(0)
            out = os.open(log, os.O_WRONLY | os.O_TRUNC | os.O_CREAT, 0o644)
            null = os.open(os.devnull, os.O_RDONLY)
            os.dup2(null, 0)
            os.dup2(out, 1)
            os.dup2(out, 2)
            os.chdir("/")
            os.execv(argv[0], argv)
        finally:
            os._exit(127)
    os.close(report)
    try:
        text = b""
        while chunk := os.read(ready, 64):
            text += chunk
    finally:
        os.close(ready)
        os.waitpid(child, 0)
    if not text.isdigit():
        raise RoboxError("could not start the virtual printer in the background")
    return int(text)


def _alive(pid: int) -> bool:
    """Whether `pid` runs (a zombie, dead and not yet reaped, does not)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    try:
        with open(f"/proc/{pid}/stat") as stat:
            return stat.read().rpartition(") ")[2][:1] != "Z"
    except OSError:
        return True


def _log_tail(log: Path) -> str:
    try:
        lines = [line for line in log.read_text(errors="replace").splitlines() if line]
    except OSError:
        return ""
    return lines[-1] if lines else ""


def start(directory: Path, speed: float | None = None) -> dict:
    """Serve the printer of `directory` in the background; its record once it serves.
    An already served printer is refused (InUse)."""
    directory = Path(os.path.abspath(directory))
    record = served_record(directory)
    if record is not None:
        raise InUse(f"{directory}: the virtual printer is already served by "
                    f"{describe_holder(record)}")
    directory.mkdir(parents=True, exist_ok=True)
    argv = [sys.executable, "-m", "robox.cli", "sim", "serve", "--state", str(directory)]
    if speed is not None:
        argv += ["--speed", repr(speed)]
    log = directory / LOG_NAME
    pid = _spawn_detached(argv, log)
    return _wait_for_server(directory, pid, log)


def _wait_for_server(directory: Path, pid: int, log: Path) -> dict:
    deadline = time.monotonic() + START_TIMEOUT_S
    while True:
        record = served_record(directory)
        if record is not None and record.get("pty"):
            return record  # ours, or one started at the same moment by another command
        if not _alive(pid) and read_record(directory) is None:
            reason = _log_tail(log) or "it exited"
            raise RoboxError(f"the virtual printer did not start: {reason} (see {log})")
        if time.monotonic() > deadline:
            with contextlib.suppress(OSError):
                os.kill(pid, signal.SIGTERM)
            raise RoboxError(f"the virtual printer did not start within "
                             f"{START_TIMEOUT_S:.0f} s (see {log})")
        time.sleep(0.02)


def ensure(directory: Path, announce=None) -> dict:
    """The record of the printer served for `directory`, starting one if none is."""
    directory = Path(os.path.abspath(directory))
    record = served_record(directory)
    if record is not None and record.get("pty"):
        return record
    if record is not None:  # being started by someone else this very moment
        return _wait_for_server(directory, record.get("pid") or 0, directory / LOG_NAME)
    try:
        record = start(directory)
    except InUse:  # another command started it first
        record = _wait_for_server(directory, 0, directory / LOG_NAME)
    else:
        if announce is not None:
            announce(record)
    return record


def stop(directory: Path, timeout: float = STOP_TIMEOUT_S) -> dict | None:
    """Switch the served printer off (SIGTERM: it settles and saves its state first);
    its record, or None when it was not served."""
    directory = Path(os.path.abspath(directory))
    record = served_record(directory)
    if record is None:
        return None
    pid = record.get("pid")
    if not isinstance(pid, int) or pid <= 0:
        raise RoboxError(f"{directory}: the lock record names no process")
    with contextlib.suppress(ProcessLookupError):
        os.kill(pid, signal.SIGTERM)
    deadline = time.monotonic() + timeout
    while read_record(directory) is not None or _alive(pid):
        if time.monotonic() > deadline:
            raise RoboxError(f"the virtual printer (PID {pid}) did not stop within "
                             f"{timeout:.0f} s")
        time.sleep(0.02)
    remove_note(directory)
    return record
