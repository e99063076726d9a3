"""Who is using what: a lock per virtual printer state directory and per serial port.

Both are advisory `flock` locks, so the kernel drops them the moment their holder
exits, however it exits (kill -9 included): no stale lock survives its process.

- A state directory's lock is the file `printer.lock` in it, held for as long as a
  process has the printer's files open. Its text is a JSON record of the holder:
  its PID, its role (`serve`: `robox-cli sim serve`; `command`: one CLI command
  running the printer in its own process) and, once serving, the pseudo-terminal
  it serves on. A reader that cannot take the lock knows the record is live.
- A serial port (a real printer's /dev/ttyACM*, or a served printer's pty) is
  locked on the open port itself, so that two hosts cannot interleave their frames;
  the holder's PID comes from the kernel's table of locks (/proc/locks).
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import time
from pathlib import Path

from robox.errors import RoboxError

LOCK_NAME = "printer.lock"
RECORD_WAIT_S = 1.0  # how long a reader waits for a new holder to write its record


class InUse(RoboxError):
    """Another process holds the printer or the port."""


def describe_pid(pid: int | None) -> str:
    if pid is None:
        return "another process"
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as handle:
            words = [w.decode(errors="replace") for w in handle.read().split(b"\0") if w]
    except OSError:
        return f"PID {pid}"
    if not words:
        return f"PID {pid}"
    shown = " ".join(Path(w).name if i == 0 else w for i, w in enumerate(words))
    return f"PID {pid} ({shown if len(shown) <= 100 else shown[:99] + '…'})"


def lock_holder(path: str | os.PathLike) -> int | None:
    """The PID holding a flock on `path` (by its device and inode), if the kernel says."""
    try:
        info = os.stat(path)
        with open("/proc/locks") as table:
            rows = table.read().splitlines()
    except OSError:
        return None
    wanted = f"{os.major(info.st_dev):02x}:{os.minor(info.st_dev):02x}:{info.st_ino}"
    for row in rows:
        fields = row.split()
        if len(fields) >= 6 and fields[1] == "FLOCK" and fields[5] == wanted \
                and fields[4].isdigit():
            return int(fields[4])
    return None


class DirectoryLock:
    """The lock on a state directory, held until `release()`."""

    def __init__(self, directory: str | os.PathLike, role: str):
        self.path = Path(directory) / LOCK_NAME
        self.record = {"pid": os.getpid(), "role": role}
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            holder = read_record(Path(directory))
            hint = ""
            if holder and holder.get("role") == "serve":
                hint = (f"; reach it with --device sim:{directory}, or switch it off with "
                        f"`robox-cli sim stop --state {directory}`")
            raise InUse(f"{directory}: the virtual printer is in use by "
                        f"{describe_holder(holder)}{hint}") from None
        except OSError as exc:
            os.close(fd)
            raise RoboxError(f"{self.path}: cannot lock: {exc.strerror}") from None
        self.fd = fd
        self._write()

    def update(self, **fields) -> None:
        self.record.update(fields)
        self._write()

    def _write(self) -> None:
        # written over the old record, then cut to length: the file is never empty
        # while held, so a reader sees the old record, the new one, or (for the
        # moment between the two calls, if the new one is shorter) neither whole
        data = json.dumps(self.record).encode() + b"\n"
        os.pwrite(self.fd, data, 0)
        os.ftruncate(self.fd, len(data))

    def release(self) -> None:
        if self.fd is not None:
            with contextlib.suppress(OSError):
                os.ftruncate(self.fd, 0)
            os.close(self.fd)  # closing the only descriptor drops the lock
            self.fd = None


def describe_holder(record: dict | None) -> str:
    if not record:
        return "another process"
    what = describe_pid(record.get("pid"))
    if record.get("role") == "serve":
        return f"{what}, serving it on {record.get('pty') or 'a pseudo-terminal'}"
    return what


def read_record(directory: Path) -> dict | None:
    """The live holder's record of a state directory, or None when nobody holds it.

    A lock taken a moment ago has no record yet, and a record being rewritten can be
    caught half-way: both are read again, briefly, before the holder is reported
    as one whose record is unknown ({})."""
    path = Path(directory) / LOCK_NAME
    try:
        fd = os.open(path, os.O_RDONLY | os.O_CLOEXEC)
    except FileNotFoundError:
        return None
    except OSError as exc:
        raise RoboxError(f"{path}: cannot read: {exc.strerror}") from None
    try:
        deadline = time.monotonic() + RECORD_WAIT_S
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
            except BlockingIOError:
                pass
            else:
                return None  # nobody holds it
            try:
                record = json.loads(os.pread(fd, 4096, 0))
            except ValueError:
                record = None
            if isinstance(record, dict) and "pid" in record:
                return record
            if time.monotonic() > deadline:
                return {}
            time.sleep(0.002)
    finally:
        os.close(fd)


def lock_port(fd: int, path: str) -> None:
    """Take the lock on an open serial port, or say who has it."""
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        raise InUse(f"{path} is in use by {describe_pid(lock_holder(path))}") from None
    except OSError:
        pass  # a port that cannot be locked is used unlocked, as by other hosts
