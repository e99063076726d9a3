"""Card helpers the tests and bench/ share: a printer-style uploader, a read-back, and
deterministic content. Nothing here needs pytest."""

from __future__ import annotations

import numpy as np

from robox.firmware.file_system import FileSystem


def upload(fs: FileSystem, file_id: bytes | str, data: bytes, job: bool = True) -> bool:
    """Send a file as a host does: start, 512-byte chunks, end."""
    if not fs.start_write_file(file_id, job):
        return False
    chunks = len(data) // 512
    for sequence in range(chunks):
        if not fs.write_chunk(sequence, data[sequence * 512 : (sequence + 1) * 512]):
            return False
    return fs.end_write_file(chunks, data[chunks * 512 :])


def read_back(fs: FileSystem, file_id: bytes | str) -> bytes | None:
    if not fs.start_read_file(file_id):
        return None
    parts = []
    while not fs.eof():
        chunk = fs.read()
        if not chunk:
            return None
        parts.append(chunk)
    return b"".join(parts)


def pattern(size: int, seed: int) -> bytes:
    """Deterministic content that differs per seed and per block."""
    return np.random.default_rng(seed).integers(0, 256, size, dtype=np.uint8).tobytes()
