"""Firmware images: sums, anti-checksum insertion, SD text, the printer's acceptance rules."""

import struct

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from robox.formats import firmware as fw


def struct_sum(data: bytes) -> int:
    """The word sum computed independently: little-endian words, a short tail zero padded."""
    padded = data + bytes(-len(data) % 4)
    return sum(struct.unpack(f"<{len(padded) // 4}I", padded)) & 0xFFFFFFFF


def images(min_pages=1, max_pages=512):
    """Page-multiple images (content from a seed) and a 4-aligned offset inside them."""
    def build(pages, seed, word):
        rng = np.random.default_rng(seed)
        data = rng.integers(0, 256, pages * 256, dtype=np.uint8).tobytes()
        return data, 4 * (word % (pages * 64))
    return st.builds(build, st.integers(min_pages, max_pages), st.integers(0, 2**32 - 1),
                     st.integers(0, 2**16))


@given(st.binary(max_size=2000))
def test_word_sum_matches_struct(data):
    assert fw.word_sum(data) == struct_sum(data)


@pytest.mark.parametrize("extra", [0, 3, 4, 7])
def test_word_sum_either_side_of_the_numpy_threshold_matches_struct(extra):
    data = np.random.default_rng(extra).integers(
        0, 256, fw.NUMPY_SUM_BYTES + extra, dtype=np.uint8).tobytes()
    assert fw.word_sum(data) == struct_sum(data)


def test_word_sum_is_byte_shifted_by_position():
    assert fw.word_sum(b"\x01\x02\x03\x04\x05") == 0x04030201 + 0x05


@settings(max_examples=60)
@given(images())
def test_any_image_with_a_zero_slot_sums_to_zero_after_insertion(case):
    data, offset = case
    image = bytearray(data)
    image[offset : offset + 4] = bytes(4)
    result = fw.insert_anti_checksum(bytes(image), offset)
    assert result.inserted
    assert struct_sum(result.image) == 0
    assert result.image[:offset] == image[:offset]
    assert result.image[offset + 4 :] == image[offset + 4 :]
    assert struct.unpack_from("<I", result.image, offset)[0] == result.value


@pytest.mark.parametrize("image,offset,refusal", [
    (b"", 0xBC, fw.Refusal.EMPTY),
    (bytes(131072 + 256), 0xBC, fw.Refusal.TOO_LARGE),
    (bytes(4096 + 1), 0xBC, fw.Refusal.NOT_PAGE_MULTIPLE),
    (bytes(256), 0xFD, fw.Refusal.OFFSET_OUTSIDE),
    (bytes(256), 0x100, fw.Refusal.OFFSET_OUTSIDE),
    (bytes(0xBC) + b"\0\0\1\0" + bytes(256 - 0xC0), 0xBC, fw.Refusal.OFFSET_NOT_ZERO),
])
def test_each_refusal(image, offset, refusal):
    result = fw.insert_anti_checksum(image, offset)
    assert result.refusal == refusal and result.image is None and result.detail


def test_a_full_flash_image_is_allowed_and_offset_at_the_very_end():
    image = bytes(131072)
    assert fw.insert_anti_checksum(image, 131068).inserted


@given(st.binary(max_size=3000))
def test_sd_text_round_trips_and_is_upper_case(data):
    text = fw.to_sd_text(data)
    assert text == data.hex().upper().encode()
    assert fw.from_sd_text(text) == data
    assert fw.from_sd_text(text.lower()) == data


@pytest.mark.parametrize("text,words", [(b"ABC", "odd"), (b"AG", "not a hex"),
                                        (b"00\n", "not a hex"), (b" 00", "not a hex")])
def test_bad_sd_text(text, words):
    with pytest.raises(ValueError, match=words):
        fw.from_sd_text(text)


def printer_accepts(text: bytes) -> bool:
    """The acceptance rules of spec/firmware-image.md, written out independently."""
    if len(text) % 512 or not 8192 <= len(text) <= 262144:
        return False
    if len(text) % 2 or any(c not in b"0123456789abcdefABCDEF" for c in text):
        return False
    return struct_sum(bytes.fromhex(text.decode())) == 0


LENGTHS = [7680, 8190, 8192, 8704, 9000, 131072, 262144 - 512, 262144, 262144 + 512, 262146]


@settings(max_examples=80, deadline=None)
@given(st.sampled_from(LENGTHS), st.booleans(), st.booleans(), st.integers(0, 2**32 - 1))
def test_verify_accepts_exactly_what_the_printer_accepts(characters, balanced, lower, seed):
    data = bytearray(np.random.default_rng(seed).integers(0, 256, characters // 2,
                                                           dtype=np.uint8).tobytes())
    if balanced and len(data) >= 4:
        data[0:4] = bytes(4)
        data[0:4] = struct.pack("<I", fw.anti_checksum(fw.word_sum(bytes(data))))
    text = fw.to_sd_text(bytes(data)) + (b"0" if characters % 2 else b"")
    if lower:
        text = text.lower()
    result = fw.check_sd_text(text)
    assert result.accepted == printer_accepts(text)
    assert fw.check_binary(bytes(data)).accepted == printer_accepts(fw.to_sd_text(bytes(data)))


def test_each_failed_rule_is_named():
    rules = {check for check, _ in fw.check_sd_text(b"1" * 8193).failures}
    assert rules == {fw.Check.LENGTH_NOT_MULTIPLE, fw.Check.NOT_HEX}
    rules = {check for check, _ in fw.check_sd_text(b"11" * 256).failures}
    assert rules == {fw.Check.TOO_SHORT, fw.Check.CHECKSUM}
    rules = {check for check, _ in fw.check_sd_text(b"00" * (131072 + 256)).failures}
    assert rules == {fw.Check.TOO_LONG}


def test_flash_layout_constants():
    assert fw.FLASH_SIZE == 128 * 1024 and fw.FLASH_PAGES * fw.PAGE_SIZE == fw.FLASH_SIZE
    assert (fw.PARAMETER_PAGES, fw.HOURS_PAGE, fw.UNUSED_PAGE, fw.UNIQUE_ID_PAGE) == \
        ((507, 508), 509, 510, 511)
    assert list(fw.IMAGE_PAGES) == list(range(507))
    assert fw.FLASH_BASE == 0x00080000


def test_detection_of_sd_text():
    assert fw.looks_like_sd_text(b"0A1b\r\n")
    assert not fw.looks_like_sd_text(b"\x00\x01") and not fw.looks_like_sd_text(b"  ")


def pages_by_bytes(flash: bytes) -> int:
    """Flashed pages worked out byte by byte: the last byte of pages 0..506 not 0xff."""
    image = flash[: 507 * 256]
    if len(image) < 507 * 256:
        return 507
    last = max((i for i, b in enumerate(image) if b != 0xFF), default=-1)
    return last // 256 + 1


@given(st.integers(0, 507 * 256), st.integers(0, 255), st.booleans(), st.integers(0, 2**16))
@settings(max_examples=300)
def test_flashed_image_pages_finds_the_last_programmed_byte(length, last, tail, seed):
    # a dump programmed up to `length` bytes, ending in `last` (0xff when the image's
    # own last byte happens to be erased), then erased flash, sometimes with the hours
    # and other pages past the image programmed
    rng = np.random.default_rng(seed)
    flash = bytearray(b"\xff" * (512 * 256))
    flash[:length] = rng.integers(0, 256, length, dtype=np.uint8).tobytes()
    if length:
        flash[length - 1] = last
    if tail:
        flash[507 * 256 :] = rng.integers(0, 256, 5 * 256, dtype=np.uint8).tobytes()
    assert fw.flashed_image_pages(bytes(flash)) == pages_by_bytes(bytes(flash))


def test_flashed_image_pages_of_a_short_dump_counts_its_missing_pages():
    assert fw.flashed_image_pages(b"\x00" * 256) == 507
    assert fw.flashed_image_pages(b"\xff" * (507 * 256)) == 0
    assert fw.flashed_image_pages(b"\xff" * (300 * 256) + b"\x00" + b"\xff" * (207 * 256 - 1)) \
        == 301
