"""Byte stores behind simulated media: memory, or a file read and written in place."""

from __future__ import annotations

import os
from typing import Protocol


class Storage(Protocol):
    size: int

    def read(self, offset: int, length: int) -> bytes: ...

    def write(self, offset: int, data: bytes) -> None: ...

    def flush(self) -> None: ...

    def close(self) -> None: ...


class MemoryStorage:
    """A bytearray; `data` is the live content."""

    def __init__(self, data: bytes | bytearray):
        self.data = bytearray(data)
        self.size = len(self.data)

    def read(self, offset: int, length: int) -> bytes:
        return bytes(self.data[offset : offset + length])

    def write(self, offset: int, data: bytes) -> None:
        self.data[offset : offset + len(data)] = data

    def flush(self) -> None:
        pass

    def close(self) -> None:
        pass


class FileStorage:
    """A file accessed with pread/pwrite. Opened read-only unless `writable`."""

    def __init__(self, path: str | os.PathLike, writable: bool = False):
        self.path = os.fspath(path)
        self.writable = writable
        self._fd = os.open(self.path, os.O_RDWR if writable else os.O_RDONLY)
        self.size = os.fstat(self._fd).st_size

    def read(self, offset: int, length: int) -> bytes:
        return os.pread(self._fd, length, offset)

    def write(self, offset: int, data: bytes) -> None:
        if not self.writable:
            raise PermissionError(f"{self.path} is open read-only")
        os.pwrite(self._fd, data, offset)

    def flush(self) -> None:
        if self.writable:
            os.fsync(self._fd)

    def close(self) -> None:
        if self._fd >= 0:
            os.close(self._fd)
            self._fd = -1

    def __enter__(self) -> FileStorage:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
