"""Who is using what: one lock discipline for everything two programs can share.

Every lock is an advisory `flock`, so the kernel drops it the moment its holder
exits, however it exits (kill -9 included): no stale lock survives its process. A
process refused a lock says who holds it ("... is in use by PID 4242 (robox-cli
send-job part.gcode)") and stops, touching nothing; with `--wait-lock SECONDS`
(`set_wait`) it waits that long for the holder to finish first.

- A state directory's lock is the file `printer.lock` in it, held for as long as a
  process has the printer's files open. Its text is a JSON record of the holder:
  its PID, its role (`serve`: `robox-cli sim serve`; `command`: one CLI command
  running the printer in its own process) and, once serving, the pseudo-terminal
  it serves on. A reader that cannot take the lock knows the record is live.
- A port (a real printer's /dev/ttyACM* or USB device, or a served printer's pty) is
  locked before it is opened, on a lock file named after the device in a directory
  every user shares (/run/lock, else the temporary directory): opening a tty flushes
  what it has received, so a client that opened the port first and was refused
  afterwards would have thrown away the reply its holder was waiting for. The open
  port itself is locked too, for other programs that lock the device.
- A card image or flash file is locked by the descriptor that reads or writes it
  (`robox.hardware.storage.FileStorage`): shared to read, exclusive to write. A
  file replaced whole by rename (an EEPROM dump, a firmware image, a host
  catalogue) is locked with `locked_path`, which follows the name to the file it
  names now. A virtual printer holds its card, flash and dumps exclusively while it
  is switched on, so an offline command is refused them meanwhile.

The holder's PID comes from the kernel's table of locks (/proc/locks).
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import stat
import time
from collections.abc import Callable, Iterator
from pathlib import Path

from robox.errors import RoboxError

LOCK_NAME = "printer.lock"
RECORD_WAIT_S = 1.0  # how long a reader waits for a new holder to write its record
RETRY_S = 0.05  # how often a waiting process tries a lock again
HOLDER_LOOKS = 5  # how often a refused process looks for a holder that keeps changing
UNKNOWN_HOLDER = "another process"
BRIEF_WAIT_S = 10.0  # how long a lock held only for a moment (a catalogue's) is waited for
SHARED_LOCK_DIRS = ("/run/lock", "/var/lock")

_wait_s = 0.0  # how long to wait for a lock another process holds (--wait-lock)


def set_wait(seconds: float) -> None:
    """Wait up to `seconds` for a lock another process holds before refusing."""
    global _wait_s
    _wait_s = max(0.0, seconds)


def take(fd: int, exclusive: bool, refusal: Callable[[], str],
         wait_s: float | None = None) -> None:
    """flock `fd`, waiting `wait_s` (default: as `set_wait` says) while another process
    holds it; InUse(refusal()) when it stays held."""
    flags = (fcntl.LOCK_EX if exclusive else fcntl.LOCK_SH) | fcntl.LOCK_NB
    deadline = time.monotonic() + (_wait_s if wait_s is None else wait_s)
    while True:
        try:
            fcntl.flock(fd, flags)
            return
        except BlockingIOError:
            if time.monotonic() >= deadline:
                break
            time.sleep(RETRY_S)
    # refused: a holder that left while it was looked up is not "another process" but
    # nobody, so the lock is tried again (a few times, for holders that come and go)
    for _ in range(HOLDER_LOOKS):
        message = refusal()
        if UNKNOWN_HOLDER not in message:
            raise InUse(message)
        try:
            fcntl.flock(fd, flags)
            return
        except BlockingIOError:
            time.sleep(RETRY_S / 10)
    raise InUse(message)


class InUse(RoboxError):
    """Another process holds the printer or the port."""


def describe_pid(pid: int | None) -> str:
    if pid is None:
        return UNKNOWN_HOLDER
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

        def refusal() -> str:
            holder = read_record(Path(directory))
            hint = ""
            if holder and holder.get("role") == "serve":
                hint = (f"; reach it with --device sim:{directory}, or switch it off with "
                        f"`robox-cli sim stop --state {directory}`")
            return (f"{directory}: the virtual printer is in use by "
                    f"{describe_holder(holder)}{hint}")

        try:
            take(fd, True, refusal)
        except InUse:
            os.close(fd)
            raise
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
        return UNKNOWN_HOLDER
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
    """Take the lock on an open serial port, or say who has it (a port that cannot be
    locked is used unlocked, as by other hosts)."""
    lock_storage(fd, path, exclusive=True)


def _shared_lock_dir() -> str:
    for directory in SHARED_LOCK_DIRS:
        if os.access(directory, os.W_OK | os.X_OK):
            return directory
    import tempfile

    return tempfile.gettempdir()


def port_lock(path: str, key: str | None = None) -> int | None:
    """Lock the port at `path` (or the device named by `key`, for a USB device) before
    it is opened; the lock file's descriptor, to close when done with the port. None
    when the port does not exist (opening it says so) or no lock file can be made."""
    if key is None:
        try:
            info = os.stat(path)
        except OSError:
            return None
        rdev = info.st_rdev if stat.S_ISCHR(info.st_mode) else None
        key = (f"tty-{os.major(rdev)}-{os.minor(rdev)}" if rdev is not None
               else f"file-{info.st_dev}-{info.st_ino}")
    lock_path = os.path.join(_shared_lock_dir(), f"robox-{key}.lock")
    try:
        fd = os.open(lock_path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o666)
    except OSError:
        return None
    with contextlib.suppress(OSError):
        os.fchmod(fd, 0o666)  # another user's client locks the same port through it
    try:
        take(fd, True, lambda: f"{path} is in use by {describe_pid(lock_holder(lock_path))}")
    except BaseException:
        os.close(fd)
        raise
    return fd


def lock_storage(fd: int, path: str, exclusive: bool) -> None:
    """Lock an open image or dump: shared to read it, exclusive to write it."""
    # (a file system without locks: the file is used unlocked)
    with contextlib.suppress(OSError):
        take(fd, exclusive, lambda: f"{path} is in use by {describe_pid(lock_holder(path))}")


@contextlib.contextmanager
def locked_path(path: str | os.PathLike, exclusive: bool = True) -> Iterator[None]:
    """Hold a lock on the file `path` names (through links) for the block, for a
    read-modify-replace. A writer that replaced the file by a rename leaves its lock on
    the file it replaced, so once the lock is granted the name is looked at again, and
    the lock taken anew when it names another file. A path with no file yet is not
    locked (it is created by rename, whole)."""
    while True:
        try:
            if not stat.S_ISREG(os.stat(path).st_mode):
                yield  # a device or FIFO is written as a stream, not replaced
                return
            handle = open(path, "rb")  # noqa: SIM115 - held open across the block
        except OSError:
            yield  # no file yet, or unreadable: the command itself says so
            return
        try:
            info = os.fstat(handle.fileno())
            lock_storage(handle.fileno(), os.fspath(path), exclusive)
            try:
                now = os.stat(path)
            except FileNotFoundError:
                now = None
            if now is not None and (now.st_dev, now.st_ino) == (info.st_dev, info.st_ino):
                yield
                return
        finally:
            handle.close()


@contextlib.contextmanager
def lock_file(path: str | os.PathLike, what: str, wait_s: float = BRIEF_WAIT_S
              ) -> Iterator[None]:
    """Hold the lock file `path` (made if need be) for the block: for state kept in
    files that are replaced whole and may not exist yet (`what` names it). Such a lock
    is held for a moment only, so it is waited for (`wait_s`)."""
    fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
    try:
        take(fd, True, lambda: f"{what} is in use by {describe_pid(lock_holder(path))}",
             max(wait_s, _wait_s))
        yield
    finally:
        os.close(fd)

