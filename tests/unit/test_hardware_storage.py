"""MemoryStorage: copy on write over bytes (by chunks), a copy of a bytearray, adopt
without a copy."""

from hypothesis import given, settings
from hypothesis import strategies as st

from robox.hardware.storage import MemoryStorage


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
