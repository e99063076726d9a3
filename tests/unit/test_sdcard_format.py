"""The directory block against bytes built independently from the spec's table."""

import struct

import pytest
from hypothesis import given
from hypothesis import strategies as st

from robox.errors import UsageError
from robox.formats import sdcard as f


def spec_block(capacity, nwb, first, nxt, last, nonvolatile=b"\0\0", padding=bytes(51),
               slots=()):
    """Block 0 assembled byte by byte at the spec's offsets."""
    block = bytearray(512)
    block[0:4] = capacity.to_bytes(4, "little")
    block[4:8] = nwb.to_bytes(4, "little")
    block[8] = first
    block[9] = nxt
    block[10] = last
    block[11:13] = nonvolatile
    block[13:64] = padding
    for index, (file_id, is_job, unused, start, length) in slots:
        base = 64 + 28 * index
        block[base : base + 16] = file_id.ljust(16, b"\0")
        block[base + 16] = is_job
        block[base + 17 : base + 20] = unused
        block[base + 20 : base + 24] = start.to_bytes(4, "little")
        block[base + 24 : base + 28] = length.to_bytes(4, "little")
    return bytes(block)


def test_decode_reads_every_field_at_its_offset():
    raw = spec_block(16384, 777, 3, 5, 4, b"\x01\x02", bytes(range(51)),
                     [(3, (b"cube", 1, b"xyz", 1, 700)), (4, (b"vase.gcode", 0, b"\0\0\0", 3, 99))])
    d = f.Directory.decode(raw)
    assert (d.capacity, d.next_write_block, d.first_file, d.next_file, d.last_job) == \
        (16384, 777, 3, 5, 4)
    assert d.nonvolatile == b"\x01\x02"
    assert d.padding == bytes(range(51))
    assert d.slots[3] == f.FileSlot(b"cube".ljust(16, b"\0"), 1, b"xyz", 1, 700)
    assert d.slots[4].id == b"vase.gcode".ljust(16, b"\0") and not d.slots[4].job
    assert d.ring() == [3, 4]


def test_encode_is_the_exact_inverse_including_uninterpreted_bytes():
    raw = bytes((i * 7 + 3) & 0xFF for i in range(512))
    assert f.Directory.decode(raw).encode() == raw


@given(st.binary(min_size=512, max_size=512))
def test_any_block_round_trips(raw):
    assert f.Directory.decode(raw).encode() == raw


def test_fresh_directory_is_the_printers_format():
    assert f.Directory.fresh(4096).encode() == spec_block(4096, 1, 0, 0, 0xFF)


def test_ring_wraps_round_sixteen_slots():
    d = f.Directory(capacity=4096, first_file=14, next_file=2)
    assert d.ring() == [14, 15, 0, 1]
    assert f.Directory(capacity=4096, first_file=5, next_file=5).ring() == []
    assert len(f.Directory(capacity=4096, first_file=3, next_file=2).ring()) == 15


def test_capacity_of_an_image_is_whole_kib_times_two():
    assert f.card_blocks(8 * 1024 * 1024) == 16384
    assert f.card_blocks(1024 * 1024 + 512) == 2048  # a trailing half KiB is not card


def test_blocks_wrap_from_the_last_block_to_block_one():
    assert f.following_block(2998, 1, 3000) == 2999
    assert f.following_block(2999, 1, 3000) == 1
    assert f.following_block(101, 2950, 3000) == 52  # the spec's example


def test_new_files_do_not_start_in_the_last_1024_blocks():
    assert f.start_for(3000 - 1024, 3000) == 1976  # exactly 1024 remain: start there
    assert f.start_for(3000 - 1023, 3000) == 1
    assert f.start_for(5, 3000) == 5


def test_make_id_stores_up_to_the_first_nul():
    assert f.make_id("abc") == b"abc" + bytes(13)
    assert f.make_id(b"ab\0cd") == b"ab" + bytes(14)
    assert f.make_id("x" * 16) == b"x" * 16
    with pytest.raises(UsageError, match="17 bytes"):
        f.make_id("x" * 17)
    with pytest.raises(UsageError, match="ASCII"):
        f.make_id("caf\u00e9")
    with pytest.raises(UsageError, match="ASCII"):
        f.make_id(b"\xff")


def test_id_text_escapes_untrusted_bytes():
    assert f.id_text(b"../../etc\npass\0rest") == "../../etc\\x0apass"
    assert f.id_text(b"a\\b") == "a\\x5cb"


def slots_chain(capacity, *files):
    """Directory whose ring holds (start, length) files in slots 0.."""
    d = f.Directory(capacity=capacity, next_write_block=1, first_file=0, next_file=len(files))
    for index, (start, length) in enumerate(files):
        file_id = (b"f%d" % index).ljust(16, b"\0")
        d = d.with_slot(index, f.FileSlot(file_id, 1, bytes(3), start, length))
    return d


def test_spec_example_printer_rejects_a_wrapped_file_the_project_keeps():
    # B: 2950 blocks at 101, wrapping to end at block 51; C right after at 52.
    d = slots_chain(3000, (101, 2950 * 512), (52, 10 * 512))
    assert not f.printer_walk(d, 3000).valid
    verdict = f.project_walk(d, 3000)
    assert verdict.valid
    assert verdict.extents[0].wraps and verdict.extents[0].end_block == 51
    assert verdict.chain_next_block == 62


def test_printer_and_project_agree_on_a_plain_chain():
    d = slots_chain(4096, (1, 1000), (3, 512 * 10), (13, 1))
    assert f.printer_walk(d, 4096).valid and f.project_walk(d, 4096).valid
    assert f.project_walk(d, 4096).chain_next_block == 14


def test_restart_at_block_one_when_fewer_than_1024_blocks_remain():
    # first file ends at block 3100 of 4096: 996 blocks remain, the next starts at 1
    d = slots_chain(4096, (2000, 1100 * 512), (1, 512))
    assert f.printer_walk(d, 4096).valid and f.project_walk(d, 4096).valid
    bad = slots_chain(4096, (2000, 1100 * 512), (3100, 512))
    assert not f.printer_walk(bad, 4096).valid and not f.project_walk(bad, 4096).valid


@pytest.mark.parametrize("start", [0, 4096, 0xFFFFFFF0])
def test_project_rejects_starts_outside_the_card(start):
    d = slots_chain(4096, (start, 512))
    assert not f.project_walk(d, 4096).valid
    assert "outside the card" in f.project_walk(d, 4096).reason


def test_printer_accepts_starts_outside_the_card_its_32_bit_walk_misses():
    # 5000 + 1 block = 5001, past the end, so the printer expects the next at 1
    d = slots_chain(4096, (5000, 512), (1, 512))
    assert f.printer_walk(d, 4096).valid
    assert not f.project_walk(d, 4096).valid
    # 0xFFFFFFFF + 1 block wraps to 0 in 32 bits: the printer then expects block 0
    wrapped = slots_chain(4096, (0xFFFFFFFF, 512), (0, 512))
    assert f.printer_walk(wrapped, 4096).valid
    assert not f.project_walk(wrapped, 4096).valid


def test_overlapping_files_are_invalid_for_the_project():
    d = slots_chain(3000, (1, 2000 * 512), (2001, 998 * 512), (1, 512))
    assert not f.project_walk(d, 3000).valid


@pytest.mark.parametrize("field,value,why", [
    ("capacity", 4094, "capacity"), ("first_file", 16, "first_file"),
    ("next_file", 200, "next_file"),
])
def test_header_checks(field, value, why):
    from dataclasses import replace
    d = replace(f.Directory.fresh(4096), **{field: value})
    assert why in f.project_walk(d, 4096).reason
    assert not f.printer_walk(d, 4096).valid


def test_next_write_block_out_of_range_fails_only_the_printer_walk():
    from dataclasses import replace
    d = replace(f.Directory.fresh(4096), next_write_block=4096)
    assert not f.printer_walk(d, 4096).valid
    assert f.project_walk(d, 4096).valid  # derived state: recomputed at mount


def test_recovery_copy_round_trip_and_crc():
    d = f.stamp_generation(slots_chain(4096, (1, 700)), 41)
    copy = f.encode_copy(d, 9)
    assert copy[44:48] == b"RBXc" and struct.unpack_from("<I", copy, 48)[0] == 9
    generation, back = f.decode_copy(copy, 9)
    assert generation == 41 and back == d
    assert f.decode_copy(copy, 10) is None  # a copy read elsewhere is not one
    damaged = bytearray(copy)
    damaged[100] ^= 1
    assert f.decode_copy(bytes(damaged), 9) is None


def test_generation_trailer_lives_in_the_padding_only():
    d = slots_chain(4096, (1, 700))
    stamped = f.stamp_generation(d, 7)
    a, b = d.encode(), stamped.encode()
    assert [i for i in range(512) if a[i] != b[i]] and \
        all(44 <= i < 64 for i in range(512) if a[i] != b[i])
    assert f.trailer_generation(stamped) == 7 and f.trailer_generation(d) is None
