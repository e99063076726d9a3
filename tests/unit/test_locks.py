"""The state directory's lock record as a reader meets it while its holder writes it.

A reader that finds the lock held reads the holder's record from the lock file. The
holder takes the lock before it writes the record, and rewrites the record when it
starts serving, so a reader can come between: it must read again, not report a
holder of unknown role (which `sim serve --detach`, waiting for its own server,
took for another process holding the printer)."""

import fcntl
import json
import os

import pytest

from robox import locks
from robox.locks import LOCK_NAME, DirectoryLock, read_record
from robox.sim import served


def test_a_lock_taken_but_not_yet_written_is_read_again(tmp_path, monkeypatch):
    path = tmp_path / LOCK_NAME
    holder = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    fcntl.flock(holder, fcntl.LOCK_EX)  # taken, nothing written yet
    real = os.pread
    seen = []

    def pread(fd, size, offset):
        data = real(fd, size, offset)
        seen.append(data)
        if len(seen) == 2:  # the holder writes its record between two reads
            os.pwrite(holder, b'{"pid": 4242, "role": "serve"}\n', 0)
        return data
    monkeypatch.setattr(locks.os, "pread", pread)
    try:
        assert read_record(tmp_path) == {"pid": 4242, "role": "serve"}
        assert seen[:2] == [b"", b""] and len(seen) == 3
        assert served.served_record(tmp_path) == {"pid": 4242, "role": "serve"}
    finally:
        os.close(holder)


def test_a_record_torn_mid_write_is_read_again(tmp_path, monkeypatch):
    whole = b'{"pid": 4242, "role": "serve", "pty": "/dev/pts/7"}\n'
    path = tmp_path / LOCK_NAME
    holder = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    fcntl.flock(holder, fcntl.LOCK_EX)
    os.pwrite(holder, whole[:20], 0)  # a record caught half-written
    real = os.pread
    seen = []

    def pread(fd, size, offset):
        data = real(fd, size, offset)
        seen.append(data)
        os.pwrite(holder, whole, 0)
        return data
    monkeypatch.setattr(locks.os, "pread", pread)
    try:
        assert read_record(tmp_path) == json.loads(whole)
        assert seen == [whole[:20], whole]
    finally:
        os.close(holder)


def test_a_holder_that_never_writes_is_reported_as_unknown(tmp_path, monkeypatch):
    monkeypatch.setattr(locks, "RECORD_WAIT_S", 0.05)
    holder = os.open(tmp_path / LOCK_NAME, os.O_RDWR | os.O_CREAT, 0o644)
    fcntl.flock(holder, fcntl.LOCK_EX)
    try:
        assert read_record(tmp_path) == {}
        with pytest.raises(locks.InUse, match="in use by another process"):
            served.served_record(tmp_path)
    finally:
        os.close(holder)
    assert read_record(tmp_path) is None  # released: nobody holds it


def test_the_holder_never_leaves_its_record_empty(tmp_path, monkeypatch):
    """Each write of the record, seen from another descriptor after every system call
    that makes it, leaves a non-empty file; the last leaves exactly the new record."""
    lock = DirectoryLock(tmp_path, "serve")
    path = tmp_path / LOCK_NAME
    contents = []
    real_pwrite, real_ftruncate = os.pwrite, os.ftruncate

    def pwrite(fd, data, offset):
        done = real_pwrite(fd, data, offset)
        contents.append(path.read_bytes())
        return done

    def ftruncate(fd, length):
        real_ftruncate(fd, length)
        contents.append(path.read_bytes())
    monkeypatch.setattr(locks.os, "pwrite", pwrite)
    monkeypatch.setattr(locks.os, "ftruncate", ftruncate)
    try:
        lock.update(pty="/dev/pts/12", started=1.5)
        lock.record = {"pid": os.getpid(), "role": "serve"}  # a shorter record
        lock.update()
        assert contents and all(contents)
        assert path.read_bytes() == json.dumps(
            {"pid": os.getpid(), "role": "serve"}).encode() + b"\n"
        assert read_record(tmp_path) == {"pid": os.getpid(), "role": "serve"}
    finally:
        monkeypatch.undo()
        lock.release()
    assert path.read_bytes() == b"" and read_record(tmp_path) is None
