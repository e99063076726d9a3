"""Host file helpers: replace a file atomically (temporary sibling, then rename)."""

from __future__ import annotations

import contextlib
import os
import stat
import tempfile
from collections.abc import Iterator
from pathlib import Path


def _mode_for(target: Path) -> int:
    try:
        return stat.S_IMODE(target.stat().st_mode)
    except FileNotFoundError:
        umask = os.umask(0)
        os.umask(umask)
        return 0o666 & ~umask


@contextlib.contextmanager
def replacing(path: str | os.PathLike) -> Iterator[str]:
    """Yield a temporary path beside `path`; on success it replaces `path`.

    On any exception the temporary file is removed and `path` is untouched.
    The new file gets the old file's mode, or the umask's for a new file.
    """
    target = Path(path)
    fd, temp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp",
                                dir=target.parent if str(target.parent) else ".")
    os.close(fd)
    try:
        yield temp
        os.chmod(temp, _mode_for(target))
        os.replace(temp, target)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(temp)
        raise


def read_input(path: str | os.PathLike, what: str = "file", limit: int | None = None,
               allow_empty: bool = False) -> bytes:
    """The bytes of an input file, or a robox error saying plainly why not: missing,
    unreadable, not a regular file, empty (unless `allow_empty`), or (with `limit`)
    larger than any `what`."""
    from robox.errors import ImageError

    with open_input(path, what) as handle:
        data = handle.read() if limit is None else handle.read(limit + 1)
    if not data and not allow_empty:
        raise ImageError(f"{path}: the file is empty")
    if limit is not None and len(data) > limit:
        raise ImageError(f"{path}: larger than {what} can be ({limit} bytes)")
    return data


def write_atomically(path: str | os.PathLike, data: bytes) -> None:
    with replacing(path) as temp, open(temp, "wb") as handle:
        handle.write(data)


def require_regular_file(path: str | os.PathLike, what: str = "file") -> None:
    """Refuse at once (a robox error, one line) a path that is missing, unreadable, or
    not a regular file (a FIFO would block, a device never ends)."""
    from robox.errors import ImageError, NotFoundError

    try:
        info = os.stat(path)
    except FileNotFoundError:
        raise NotFoundError(f"{path}: no such file") from None
    except PermissionError:
        raise ImageError(f"{path}: not readable (permission denied)") from None
    if stat.S_ISDIR(info.st_mode):
        raise ImageError(f"{path}: is a directory, not {what}")
    if not stat.S_ISREG(info.st_mode):
        raise ImageError(f"{path}: not a regular file, not {what}")


def open_input(path: str | os.PathLike, what: str = "file"):
    """An input file opened for reading in binary, after `require_regular_file`."""
    from robox.errors import ImageError

    require_regular_file(path, what)
    try:
        return open(path, "rb")
    except PermissionError:
        raise ImageError(f"{path}: not readable (permission denied)") from None


def read_chunks(handle, size: int = 1 << 20) -> Iterator[bytes]:
    while chunk := handle.read(size):
        yield chunk
