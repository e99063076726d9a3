"""Byte stores behind simulated media: memory, or a file read and written in place."""

from __future__ import annotations

import io
import os
from typing import Protocol

from robox.locks import lock_storage


class Storage(Protocol):
    size: int

    def read(self, offset: int, length: int) -> bytes: ...

    def write(self, offset: int, data: bytes) -> None: ...

    def flush(self) -> None: ...

    def close(self) -> None: ...


class MemoryStorage:
    """Bytes in memory; `data` is the live content, a bytearray.

    Copy on write: built from `bytes`, the store reads those bytes themselves, and a
    write copies only the CHUNK-byte pieces it touches (kept apart until `data` is asked
    for, which joins everything into one bytearray). A medium powered up to be read and
    written in a few places, as each survivor of a fault campaign is, never copies whole.
    """

    CHUNK = 4096

    def __init__(self, data: bytes | bytearray):
        # bytes are immutable, so shared; a bytearray is the caller's, so copied
        self._base: bytes | None = data if type(data) is bytes else None
        self._data: bytearray | None = None if self._base is not None else bytearray(data)
        self._chunks: dict[int, bytearray] = {}  # chunk index -> its bytes as written
        self.size = len(data)

    @classmethod
    def adopt(cls, data: bytearray) -> MemoryStorage:
        """A store over `data` itself, not a copy (the caller hands it over)."""
        storage = cls(b"")
        storage._base, storage._data, storage.size = None, data, len(data)
        return storage

    @property
    def data(self) -> bytearray:
        if self._data is None:
            data = bytearray(self._base)
            for index, chunk in self._chunks.items():
                data[index * self.CHUNK : index * self.CHUNK + len(chunk)] = chunk
            self._data, self._base, self._chunks = data, None, {}
        return self._data

    def read(self, offset: int, length: int) -> bytes:
        if self._data is not None:
            return bytes(self._data[offset : offset + length])
        end = min(offset + length, self.size)
        if not self._chunks or offset >= end:
            return self._base[offset:end]
        size = self.CHUNK
        first, last = offset // size, (end - 1) // size
        if first == last:
            chunk = self._chunks.get(first)
            if chunk is None:
                return self._base[offset:end]
            return bytes(chunk[offset - first * size : end - first * size])
        pieces = []
        for index in range(first, last + 1):
            start, stop = max(offset, index * size), min(end, (index + 1) * size)
            chunk = self._chunks.get(index)
            pieces.append(self._base[start:stop] if chunk is None
                          else chunk[start - index * size : stop - index * size])
        return b"".join(pieces)

    def write(self, offset: int, data: bytes) -> None:
        end = offset + len(data)
        if self._data is not None or end > self.size:  # growing: as a bytearray would
            self.data[offset:end] = data
            return
        size, view = self.CHUNK, memoryview(data)
        for index in range(offset // size, (end - 1) // size + 1):
            chunk = self._chunks.get(index)
            if chunk is None:
                chunk = self._chunks[index] = bytearray(
                    self._base[index * size : (index + 1) * size])
            start, stop = max(offset, index * size), min(end, (index + 1) * size)
            chunk[start - index * size : stop - index * size] = view[start - offset :
                                                                      stop - offset]

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
        try:
            # shared to read, exclusive to write, for as long as it is open
            lock_storage(self._file.fileno(), self.path, exclusive=writable)
        except BaseException:
            self._file.close()
            raise
        self.size = os.fstat(self._file.fileno()).st_size
        # An operating system's file is read and written at an offset in one system call
        # (the card's model goes a block at a time: a seek and a read were two). Any
        # other file object (an emulated file system's, in tests), or a system without
        # pread (Windows), seeks first.
        self._fd = self._file.fileno() \
            if type(self._file) is io.FileIO and hasattr(os, "pread") else -1

    def read(self, offset: int, length: int) -> bytes:
        if self._fd >= 0:
            return os.pread(self._fd, length, offset)
        self._file.seek(offset)
        return self._file.read(length)

    def write(self, offset: int, data: bytes) -> None:
        if not self.writable:
            raise PermissionError(f"{self.path} is open read-only")
        if self._fd < 0:
            self._file.seek(offset)
            self._file.write(data)
            return
        view = memoryview(data)
        while view:  # (a write may take less than it is given)
            done = os.pwrite(self._fd, view, offset)
            view, offset = view[done:], offset + done

    def flush(self) -> None:
        if self.writable:
            os.fsync(self._file.fileno())

    def close(self) -> None:
        self._fd = -1  # (a use after this is the closed file object's error, as before)
        self._file.close()

    def __enter__(self) -> FileStorage:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
