"""MemoryStorage: copy on write over bytes (by chunks), a copy of a bytearray, adopt
without a copy. FileStorage: reads and writes at an offset, through the descriptor or
through the file object, as a bytearray takes them."""

import os
import tempfile

from hypothesis import given, settings
from hypothesis import strategies as st

from robox.hardware import storage as storage_module
from robox.hardware.storage import FileStorage, MemoryStorage


def test_stores_built_from_the_same_bytes_are_independent():
    original = bytes(range(256)) * 4
    a, b = MemoryStorage(original), MemoryStorage(original)
    assert a.read(0, 1024) == original and a.size == 1024
    a.write(10, b"\xaa\xbb")
    assert a.read(8, 6) == bytes([8, 9, 0xAA, 0xBB, 12, 13])
    assert b.read(8, 6) == bytes(range(8, 14))
    assert bytes(a.data) == original[:10] + b"\xaa\xbb" + original[12:]
    assert bytes(b.data) == original


def test_data_is_the_live_content_before_and_after_a_write():
    store = MemoryStorage(b"\x00" * 16)
    live = store.data
    live[3] = 7  # written through `data` before any write()
    assert store.read(0, 4) == b"\x00\x00\x00\x07"
    store.write(4, b"\x09")
    assert store.data is live and live[4] == 9


def test_a_bytearray_is_copied_and_an_adopted_one_is_not():
    source = bytearray(8)
    copied, adopted = MemoryStorage(source), MemoryStorage.adopt(source)
    source[0] = 1
    assert copied.read(0, 1) == b"\x00"
    assert adopted.read(0, 1) == b"\x01"
    adopted.write(1, b"\x02")
    assert source[1] == 2


def test_reads_past_the_end_are_short_as_with_a_file():
    store = MemoryStorage(b"abc")
    assert store.read(2, 10) == b"c" and store.read(5, 1) == b""
    store.write(0, b"x")
    assert store.read(2, 10) == b"c"


ops = st.lists(st.tuples(st.sampled_from(["write", "read", "data"]),
                         st.integers(0, 3 * 4096 + 100), st.integers(0, 9000),
                         st.integers(0, 255)), max_size=30)


@given(st.integers(0, 3 * 4096 + 100), ops)
@settings(max_examples=300)
def test_copy_on_write_reads_as_a_plain_bytearray(size, steps):
    # the same writes and reads on a store and on a bytearray give the same bytes,
    # reads spanning written and unwritten chunks included, before and after `data`
    base = bytes((i * 7 + 3) & 0xFF for i in range(size))
    store, model = MemoryStorage(base), bytearray(base)
    for op, offset, length, value in steps:
        offset = offset % (size + 1)
        length = min(length, size - offset)
        if op == "write":
            store.write(offset, bytes([value]) * length)
            model[offset : offset + length] = bytes([value]) * length
        elif op == "read":
            assert store.read(offset, length + value) == bytes(model[offset : offset + length
                                                                      + value])
        else:
            assert bytes(store.data) == bytes(model)
    assert store.read(0, size) == bytes(model) and store.size == len(model)
    assert base == bytes((i * 7 + 3) & 0xFF for i in range(size))  # the source untouched


file_ops = st.lists(st.tuples(st.sampled_from(["write", "read"]), st.integers(0, 5000),
                              st.integers(0, 1500), st.integers(0, 255)), max_size=25)


@given(st.integers(0, 4096), file_ops, st.booleans())
@settings(max_examples=150, deadline=None)
def test_a_file_store_reads_and_writes_at_offsets_as_a_bytearray(size, steps, descriptor):
    """Each read and write lands at its own offset whatever came before it (a read
    after a write elsewhere, a write past the end growing the file), through the
    descriptor (pread, pwrite) and through the file object (seek, then read or write),
    as an emulated file system's file is taken."""
    base = bytes((i * 11 + 5) & 0xFF for i in range(size))
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "image")
        with open(path, "wb") as f:
            f.write(base)
        model = bytearray(base)
        with FileStorage(path, writable=True) as store:
            assert (store._fd >= 0) is True  # an operating system's file: its descriptor
            if not descriptor:
                store._fd = -1
            for op, offset, length, value in steps:
                if op == "write":
                    data = bytes([value]) * length
                    store.write(offset, data)
                    if offset > len(model) and length:  # (an empty write grows nothing)
                        model.extend(bytes(offset - len(model)))
                    model[offset : offset + length] = data
                else:
                    assert store.read(offset, length) == bytes(model[offset : offset + length])
        with open(path, "rb") as f:
            assert f.read() == bytes(model)


def test_a_write_the_system_takes_in_parts_lands_whole(monkeypatch):
    """pwrite may take less than it is given: the rest follows at its own offset."""
    real = os.pwrite
    calls = []

    def partial(fd, data, offset):
        calls.append(offset)
        return real(fd, bytes(data[:100]), offset)

    monkeypatch.setattr(storage_module.os, "pwrite", partial)
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "image")
        with open(path, "wb") as f:
            f.write(bytes(1024))
        data = bytes(range(256)) * 2
        with FileStorage(path, writable=True) as store:
            store.write(300, data)
            assert store.read(300, 512) == data and store.read(0, 300) == bytes(300)
        assert calls == [300, 400, 500, 600, 700, 800]


def test_a_read_only_file_store_refuses_a_write():
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "image")
        with open(path, "wb") as f:
            f.write(b"abc")
        with FileStorage(path) as store:
            try:
                store.write(0, b"x")
            except PermissionError:
                pass
            else:
                raise AssertionError("a read-only store took a write")
            assert store.read(0, 3) == b"abc"


def test_a_closed_file_store_fails_as_its_closed_file_does():
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "image")
        with open(path, "wb") as f:
            f.write(b"abc")
        store = FileStorage(path, writable=True)
        store.close()
        for use in (lambda: store.read(0, 1), lambda: store.write(0, b"x")):
            try:
                use()
            except ValueError as exc:  # io's "I/O operation on closed file"
                assert "closed file" in str(exc)
            else:
                raise AssertionError("a closed store was used")
