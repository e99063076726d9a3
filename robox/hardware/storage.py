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

    @classmethod
    def adopt(cls, data: bytearray) -> MemoryStorage:
        """A store over `data` itself, not a copy (the caller hands it over)."""
        storage = cls(b"")
        storage.data, storage.size = data, len(data)
        return storage

    def read(self, offset: int, length: int) -> bytes:
        return bytes(self.data[offset : offset + length])

    def write(self, offset: int, data: bytes) -> None:
        self.data[offset : offset + len(data)] = data

    def flush(self) -> None:
        pass

    def close(self) -> None:
        pass


class FileStorage:
    """A file read and written in place, unbuffered. Opened read-only unless `writable`."""

    def __init__(self, path: str | os.PathLike, writable: bool = False):
        self.path = os.fspath(path)
        self.writable = writable
        self._file = open(self.path, "r+b" if writable else "rb", buffering=0)  # noqa: SIM115
        self.size = os.fstat(self._file.fileno()).st_size

    def read(self, offset: int, length: int) -> bytes:
        self._file.seek(offset)
        return self._file.read(length)

    def write(self, offset: int, data: bytes) -> None:
        if not self.writable:
            raise PermissionError(f"{self.path} is open read-only")
        self._file.seek(offset)
        self._file.write(data)

    def flush(self) -> None:
        if self.writable:
            os.fsync(self._file.fileno())

    def close(self) -> None:
        self._file.close()

    def __enter__(self) -> FileStorage:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
