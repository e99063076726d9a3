"""Firmware images (spec/firmware-image.md): word sums, anti-checksums, SD firmware text.

An image is valid when the sum of its little-endian 32-bit words is zero
(mod 2^32). The build reserves a zero word (at 0xBC) and writes there the
"anti-checksum" that makes it so. The printer is sent the image as text, two
hex digits per byte, and checks that text before it touches flash.
Checks return results (an enum per failed rule, with details); they raise
nothing, so that tools and the firmware model decide what to do.
"""

from __future__ import annotations

import binascii
import struct
from dataclasses import dataclass
from enum import Enum

# ------------------------------------------------------------ flash layout
FLASH_BASE = 0x00080000
PAGE_SIZE = 256
FLASH_PAGES = 512
FLASH_SIZE = PAGE_SIZE * FLASH_PAGES  # 128 KiB
IMAGE_PAGES = range(0, 507)
PARAMETER_PAGES = (507, 508)
HOURS_PAGE = 509
UNUSED_PAGE = 510
UNIQUE_ID_PAGE = 511

DEFAULT_OFFSET = 0xBC
#: The M115 reply every released image carries compiled in: this, its revision, CR LF.
REVISION_LITERAL = b"FIRMWARE_NAME: robox "
#: Where this project's stand-in images said their revision before they carried the
#: literal (the marker, then 8 characters NUL padded): still read, never written.
LEGACY_REVISION_MARKER = b"ROBOX-REVISION:"
#: Bounds the printer puts on the SD firmware text, in characters.
TEXT_MULTIPLE = 2 * PAGE_SIZE  # 512
TEXT_MIN = 8192  # a binary under 4 KiB is not a credible firmware
TEXT_MAX = 2 * FLASH_SIZE  # 262144

_U32 = 0xFFFFFFFF


#: Above this many bytes numpy sums the words (its import, about 0.15 s, pays off only
#: for buffers far larger than the flash; the firmware model sums its 128 KiB at every
#: power-up, robox-cli's start-up included).
NUMPY_SUM_BYTES = 4 << 20


def word_sum(data: bytes | bytearray | memoryview) -> int:
    """Sum mod 2^32 of the data as little-endian 32-bit words (a short tail padded with 0)."""
    raw = memoryview(data).cast("B")
    whole = len(raw) - len(raw) % 4
    if whole > NUMPY_SUM_BYTES:
        import numpy as np

        total = int(np.frombuffer(raw[:whole], dtype="<u4").sum(dtype=np.uint64))
    else:
        total = sum(struct.unpack_from(f"<{whole // 4}I", raw))
    for i in range(whole, len(raw)):
        total += raw[i] << (8 * (i % 4))
    return total & _U32


def image_revision(image: bytes) -> str | None:
    """The revision an image declares (spec: firmware-image.md), if it declares one:
    what follows its M115 literal up to the line end (r779 in a released robox_r779.bin)."""
    data = bytes(image)
    at = data.find(REVISION_LITERAL)
    while at >= 0:
        start = at + len(REVISION_LITERAL)
        end = data.find(b"\r\n", start, start + 33)
        text = data[start:end].strip() if end > start else b""
        if text and all(0x21 <= c < 0x7F for c in text):
            return text.decode("ascii")
        at = data.find(REVISION_LITERAL, start)
    at = data.find(LEGACY_REVISION_MARKER)
    if at < 0:
        return None
    raw = data[at + len(LEGACY_REVISION_MARKER) : at + len(LEGACY_REVISION_MARKER) + 8]
    return raw.split(b"\0", 1)[0].decode("ascii", "replace").strip() or None


def flash_identity(flash: bytes) -> tuple[str, str | None]:
    """A flash dump's unique ID (its last page, as 0xb2 reports it) and the revision
    its image declares (None: it declares none)."""
    raw = bytes(b & 0x7F for b in flash[UNIQUE_ID_PAGE * PAGE_SIZE :
                                        (UNIQUE_ID_PAGE + 1) * PAGE_SIZE])
    unique = raw.split(b"\0", 1)[0].decode("ascii", "replace").strip()
    image = bytes(flash[IMAGE_PAGES.start * PAGE_SIZE : IMAGE_PAGES.stop * PAGE_SIZE])
    return unique, image_revision(image[: flashed_image_pages(image) * PAGE_SIZE])


def flashed_image_pages(flash: bytes) -> int:
    """Pages of the image in a flash dump: up to the last page in 0..506 not erased."""
    image = memoryview(flash)[IMAGE_PAGES.start * PAGE_SIZE : IMAGE_PAGES.stop * PAGE_SIZE]
    if len(image) < len(IMAGE_PAGES) * PAGE_SIZE:  # a short dump: its missing pages count
        return IMAGE_PAGES.stop
    # the last 8-byte word not erased is the one that holds the last byte not erased
    programmed = len(bytes(image).rstrip(b"\xff"))
    if programmed == 0:
        return 0
    return IMAGE_PAGES.start + (programmed - 1) // PAGE_SIZE + 1


def anti_checksum(total: int) -> int:
    """The word that brings a sum to zero: (~sum + 1) mod 2^32."""
    return (~total + 1) & _U32


# --------------------------------------------------------------- insertion
class Refusal(Enum):
    """Why an anti-checksum is not inserted (the image is left untouched)."""

    EMPTY = "the image is empty"
    TOO_LARGE = "the image is larger than the flash"
    NOT_PAGE_MULTIPLE = "the image size is not a multiple of 256 bytes"
    OFFSET_OUTSIDE = "the offset's 4 bytes lie outside the image"
    OFFSET_NOT_ZERO = "the 4 bytes at the offset are not zero"


@dataclass(frozen=True)
class Insertion:
    refusal: Refusal | None
    detail: str
    image: bytes | None = None  # the image with the anti-checksum, when inserted
    value: int | None = None  # the anti-checksum inserted

    @property
    def inserted(self) -> bool:
        return self.refusal is None


def insert_anti_checksum(image: bytes, offset: int = DEFAULT_OFFSET) -> Insertion:
    """The image with its anti-checksum at `offset`, or the first rule it breaks."""
    size = len(image)
    if size == 0:
        return Insertion(Refusal.EMPTY, "the image is empty")
    if size > FLASH_SIZE:
        return Insertion(Refusal.TOO_LARGE,
                         f"{size} bytes is larger than the {FLASH_SIZE}-byte flash")
    if size % PAGE_SIZE:
        return Insertion(Refusal.NOT_PAGE_MULTIPLE,
                         f"{size} bytes is not a multiple of {PAGE_SIZE}")
    if offset < 0 or offset + 4 > size:
        return Insertion(Refusal.OFFSET_OUTSIDE,
                         f"offset {offset:#x} + 4 is outside the {size}-byte image")
    word = bytes(image[offset : offset + 4])
    if word != bytes(4):
        value = struct.unpack("<I", word)[0]
        return Insertion(Refusal.OFFSET_NOT_ZERO,
                         f"the word at {offset:#x} is {value:#010x}, not zero (code, or an "
                         "anti-checksum already inserted)")
    value = anti_checksum(word_sum(image))
    out = bytearray(image)
    out[offset : offset + 4] = struct.pack("<I", value)
    return Insertion(None, f"anti-checksum {value:#010x} inserted at {offset:#x}",
                     bytes(out), value)


# ---------------------------------------------------------- SD firmware text
_HEX = frozenset(b"0123456789abcdefABCDEF")


def to_sd_text(image: bytes) -> bytes:
    """The SD firmware file: two upper-case hex digits per byte."""
    return binascii.hexlify(image).upper()


def first_non_hex(text: bytes) -> int | None:
    for i, b in enumerate(text):
        if b not in _HEX:
            return i
    return None


def from_sd_text(text: bytes) -> bytes:
    """The binary in an SD firmware file (either case); ValueError saying what is wrong."""
    bad = first_non_hex(text)
    if bad is not None:
        raise ValueError(f"character {bad} ({text[bad:bad + 1]!r}) is not a hex digit")
    if len(text) % 2:
        raise ValueError(f"{len(text)} characters is an odd number; two per byte")
    return binascii.unhexlify(text)


def looks_like_sd_text(data: bytes) -> bool:
    """SD text is hex digits only (white space tolerated for detection, not acceptance)."""
    stripped = bytes(data).strip()
    return bool(stripped) and all(b in _HEX or b in b" \t\r\n" for b in stripped)


# ----------------------------------------------------------- printer checks
class Check(Enum):
    """A rule the printer applies to a firmware file before flashing."""

    NOT_HEX = "the text is not two hex digits per byte"
    LENGTH_NOT_MULTIPLE = "the length is not a multiple of 512 characters"
    TOO_SHORT = "shorter than 8192 characters (4 KiB)"
    TOO_LONG = "longer than 262144 characters (128 KiB)"
    CHECKSUM = "the image does not sum to zero"


class Verification:
    """The printer's verdict on a firmware file, with the figures behind it."""

    def __init__(self, characters: int, size: int | None, checksum: int | None,
                 failures: list[tuple[Check, str]]) -> None:
        self.characters = characters
        self.size = size  # bytes of binary, when the text decodes
        self.checksum = checksum
        self.failures = failures

    @property
    def accepted(self) -> bool:
        return not self.failures


def _length_failures(characters: int) -> list[tuple[Check, str]]:
    what = f"{characters} characters ({characters / 2:g} bytes)"
    failures = []
    if characters % TEXT_MULTIPLE:
        failures.append((Check.LENGTH_NOT_MULTIPLE, what))
    if characters < TEXT_MIN:
        failures.append((Check.TOO_SHORT, what))
    if characters > TEXT_MAX:
        failures.append((Check.TOO_LONG, what))
    return failures


def _checksum_failure(result: Verification) -> None:
    if result.checksum:
        result.failures.append((Check.CHECKSUM, f"the word sum is {result.checksum:#010x}"))


def check_sd_text(text: bytes) -> Verification:
    """Every rule the printer checks on an SD firmware file's text."""
    result = Verification(len(text), None, None, _length_failures(len(text)))
    try:
        image = from_sd_text(text)
    except ValueError as exc:
        result.failures.append((Check.NOT_HEX, str(exc)))
        return result
    result.size = len(image)
    result.checksum = word_sum(image)
    _checksum_failure(result)
    return result


def check_binary(image: bytes) -> Verification:
    """The same rules for a .bin, as they apply to its SD text (two characters a byte)."""
    result = Verification(2 * len(image), len(image), word_sum(image),
                          _length_failures(2 * len(image)))
    _checksum_failure(result)
    return result
