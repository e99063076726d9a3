"""Shared test helpers: cards, file systems, and a printer-style uploader."""

from __future__ import annotations

import importlib

# Loaded before any test activates pyfakefs: robox imports numpy lazily, and numpy
# cannot be first imported from inside a fake file system.
import numpy as np

from robox.cli import LAZY_COMMANDS
from robox.firmware.file_system import FileSystem

# robox-cli imports a command's module when the command runs: here, before any test
# runs one inside pyfakefs, which cannot patch a module first imported under it
for _module, _attribute, _help in LAZY_COMMANDS.values():
    importlib.import_module(_module)


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


import pytest  # noqa: E402


@pytest.fixture(autouse=True)
def _own_state_home(tmp_path_factory, monkeypatch):
    """What the host records of printers' cards (robox.host.catalogue) stays in the test's
    own directory, never the user's."""
    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path_factory.mktemp("state-home")))
