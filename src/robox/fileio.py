"""Host file helpers: outputs written whole or not at all, through links, never over an
input, and inputs read with a plain one-line refusal.

`replacing(path)` yields a temporary file to write; once it is written whole, the file
`path` names gets its content:

- a regular file (or none yet) is replaced by a rename of the temporary file, which is
  fsynced first; the directory is fsynced after, so what a command reports as saved
  survives a power cut;
- through a symbolic link, the file it points to is replaced and the link stays;
- a regular file with other names (hard links) is rewritten in place, so that every
  name sees the new content (a rename would leave the other names on the old one);
- a device node or FIFO is written to as a stream, never replaced;
- `-` is standard output, written once the whole output is made (a command that
  fails writes nothing there either).

An error while writing names the user's path, never the temporary one.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import stat
import sys
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


def fsync_directory(directory: str | os.PathLike) -> None:
    """Make a rename or a new name in `directory` durable (best effort where the file
    system cannot)."""
    try:
        fd = os.open(directory, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
    except OSError:
        return
    try:
        with contextlib.suppress(OSError):
            os.fsync(fd)
    finally:
        os.close(fd)


def _fsync_file(path: str | os.PathLike) -> None:
    fd = os.open(path, os.O_RDONLY | os.O_CLOEXEC)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


STDOUT = "-"  # an output path that means standard output


def is_stdout(path: str | os.PathLike) -> bool:
    return os.fspath(path) == STDOUT


@contextlib.contextmanager
def _to_stdout() -> Iterator[str]:
    """A temporary file whose content goes to standard output once it is written."""
    fd, temp = tempfile.mkstemp(prefix=".robox-stdout.", suffix=".tmp")
    os.close(fd)
    try:
        yield temp
        with open(temp, "rb") as source:
            shutil.copyfileobj(source, sys.stdout.buffer, 1 << 20)
        sys.stdout.buffer.flush()
    finally:
        with contextlib.suppress(OSError):
            os.unlink(temp)


@contextlib.contextmanager
def replacing(path: str | os.PathLike) -> Iterator[str]:
    """Yield a temporary path; once the block has written it, the file `path` names
    gets its content (see the module's docstring). On any exception the temporary
    file is removed and that file is untouched. A new file gets the umask's mode, a
    replaced one keeps its own."""
    from robox.errors import ImageError

    if is_stdout(path):
        with _to_stdout() as temp:
            yield temp
        return
    target = Path(os.path.realpath(path))
    try:
        info = os.stat(target)
    except OSError:
        info = None
    stream = info is not None and not stat.S_ISREG(info.st_mode)
    in_place = info is not None and not stream and info.st_nlink > 1
    directory = tempfile.gettempdir() if stream or in_place else str(target.parent)
    try:
        fd, temp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=directory)
    except OSError as exc:
        raise ImageError(f"{path}: cannot write: {exc.strerror}") from None
    os.close(fd)
    try:
        yield temp
        if stream or in_place:
            with open(temp, "rb") as source, open(target, "r+b" if in_place else "wb") as out:
                shutil.copyfileobj(source, out, 1 << 20)
                if in_place:
                    out.truncate()
                    out.flush()
                    os.fsync(out.fileno())
            os.unlink(temp)
        else:
            os.chmod(temp, _mode_for(target))
            _fsync_file(temp)
            os.replace(temp, target)
            fsync_directory(target.parent)
    except OSError as exc:
        with contextlib.suppress(OSError):
            os.unlink(temp)
        raise ImageError(f"{path}: cannot write: {exc.strerror or exc}") from None
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(temp)
        raise


def refuse_overwriting(output: str | os.PathLike, *inputs: str | os.PathLike) -> None:
    """Refuse (a usage error, one line) an output that is one of the inputs, by name or
    through a link: the command would destroy what it reads."""
    from robox.errors import UsageError

    if is_stdout(output):
        return  # (a shell redirection onto an input has emptied it before we start)
    try:
        out = os.stat(output)
    except OSError:
        return
    for source in inputs:
        try:
            info = os.stat(source)
        except OSError:
            continue
        if (info.st_dev, info.st_ino) == (out.st_dev, out.st_ino):
            raise UsageError(f"{output}: that is the input {source}; write the output to "
                             "another file")


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
