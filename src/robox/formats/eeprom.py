"""Head and reel EEPROMs (spec/eeprom.md): two CRC-protected banks, named fields.

A 512-byte chip holds bank 0 at 0x000 and bank 1 at 0x100; each bank is 192
data bytes (the "virtual EEPROM" a host sees) and a 4-byte CRC, little-endian.
Data bytes are 7-bit ASCII. Fields are fixed slices of the 192 data bytes.
"""

from __future__ import annotations

import re
import struct
import zlib
from dataclasses import dataclass
from enum import IntEnum
from typing import Final

from robox.errors import NotFoundError, UsageError
from robox.formats import float8

# (Final: the compiled firmware model takes them as constants, not module lookups)
CHIP_SIZE: Final = 512
DATA_SIZE: Final = 192
BANK_SIZE: Final = 196  # the data and its CRC-32
BANK_ADDRESSES = (0x000, 0x100)
CRC_INIT = 0x535E01FE


def eeprom_crc(data: bytes) -> int:
    """Reflected CRC-32 (0x04C11DB7), initial register 0x535E01FE, no final XOR.
    zlib's CRC-32 is the same polynomial, reflected, with the register and the result
    inverted: its running value for this register is the register inverted, and the
    result is inverted back."""
    return zlib.crc32(data, CRC_INIT ^ 0xFFFFFFFF) ^ 0xFFFFFFFF


class EepromIndex(IntEnum):
    HEAD = 0
    REEL0 = 1
    REEL1 = 2


def mask7(data: bytes) -> bytes:
    """Every byte masked to 7 bits, as the printer writes and reports them."""
    return bytes(b & 0x7F for b in data)


def bank_image(data: bytes) -> bytes:
    """196 bytes of a bank: the 192 data bytes and their CRC."""
    if len(data) != DATA_SIZE:
        raise ValueError(f"a bank holds {DATA_SIZE} data bytes, not {len(data)}")
    return bytes(data) + struct.pack("<I", eeprom_crc(bytes(data)))


def bank_good(bank: bytes) -> bool:
    """True when a 196-byte bank's CRC matches its data."""
    return len(bank) == BANK_SIZE and eeprom_crc(bytes(bank)) == 0


def read_bank(chip: bytes, bank: int) -> bytes:
    start = BANK_ADDRESSES[bank]
    return bytes(chip[start : start + BANK_SIZE])


def chip_image(data: bytes, fill: int = 0xFF) -> bytes:
    """A whole chip with both banks holding `data` (masked), the rest `fill`."""
    bank = bank_image(mask7(data))
    chip = bytearray([fill]) * CHIP_SIZE
    for start in BANK_ADDRESSES:
        chip[start : start + BANK_SIZE] = bank
    return bytes(chip)


def loaded_bank(chip: bytes) -> int | None:
    """The bank a printer loads at power-up: bank 0 if good, else bank 1 if good."""
    for bank in (0, 1):
        if bank_good(read_bank(chip, bank)):
            return bank
    return None


# ------------------------------------------------------------------ fields
_HEX6 = re.compile(r"^#?[0-9A-Fa-f]{6}$")


@dataclass(frozen=True)
class Field:
    name: str
    offset: int
    size: int
    kind: str  # "text", "float", "colour" or "char"
    description: str

    def read(self, data: bytes):
        raw = bytes(data[self.offset : self.offset + self.size])
        if self.kind == "float":
            return float8.parse(raw)
        return raw.split(b"\0", 1)[0].decode("ascii", "replace")

    def raw(self, data: bytes) -> bytes:
        return bytes(data[self.offset : self.offset + self.size])

    def encode(self, value: str | float) -> bytes:
        """The field's bytes for a value given as text (from a user) or a number."""
        if self.kind == "float":
            if isinstance(value, str):
                try:
                    number = float(value)
                except ValueError:
                    raise UsageError(f"{self.name}: {value!r} is not a number") from None
            else:
                number = float(value)
            try:
                return float8.encode_checked(number)
            except UsageError:
                raise UsageError(f"{self.name}: {value!r} does not fit in 8 characters") from None
        text = str(value)
        if not all(0x20 <= ord(c) < 0x7F for c in text):
            raise UsageError(f"{self.name}: {text!r} is not printable ASCII")
        if self.kind == "colour":
            if not _HEX6.match(text):
                raise UsageError(f"{self.name}: {text!r} is not a colour like FF8000")
            return text.lstrip("#").upper().encode("ascii")
        if self.kind == "char" and len(text) != 1:
            raise UsageError(f"{self.name}: {text!r} is not one character")
        if len(text) > self.size:
            raise UsageError(f"{self.name}: {text!r} is {len(text)} characters; "
                             f"the field holds {self.size}")
        return text.encode("ascii").ljust(self.size, b"\0")


REEL_FIELDS = (
    Field("filament_id", 0x00, 16, "text", "material / filament ID"),
    Field("display_colour", 0x10, 6, "colour", "display colour RRGGBB"),
    Field("first_layer_nozzle_temperature", 0x28, 8, "float", "°C"),
    Field("nozzle_temperature", 0x30, 8, "float", "°C"),
    Field("first_layer_bed_temperature", 0x38, 8, "float", "°C"),
    Field("bed_temperature", 0x40, 8, "float", "°C"),
    Field("ambient_temperature", 0x48, 8, "float", "°C"),
    Field("filament_diameter", 0x50, 8, "float", "mm"),
    Field("filament_multiplier", 0x58, 8, "float", ""),
    Field("feed_rate_multiplier", 0x60, 8, "float", ""),
    Field("friendly_name", 0x68, 40, "text", "name"),
    Field("material_type", 0x90, 1, "char", "one character"),
    Field("remaining_filament", 0xB8, 8, "float", "mm of filament left on the reel"),
)

HEAD_FIELDS = (
    Field("type_code", 0x00, 16, "text", "e.g. RBX01-SM, RBX01-DM"),
    Field("unique_id", 0x10, 24, "text", "head serial"),
    Field("max_temperature", 0x28, 8, "float", "°C"),
    Field("thermistor_beta", 0x30, 8, "float", ""),
    Field("thermistor_tcal", 0x38, 8, "float", ""),
    *(Field(f"nozzle{n}_{axis}_offset", base + 8 * i, 8, "float", "mm")
      for n, base in ((0, 0x40), (1, 0x70)) for i, axis in enumerate("xyzb")),
    Field("nozzle1_last_filament_temperature", 0xA8, 8, "float", "°C"),
    Field("nozzle0_last_filament_temperature", 0xB0, 8, "float", "°C"),
    Field("head_hours", 0xB8, 8, "float", "hours of heating"),
)

FIELDS = {"reel": {f.name: f for f in REEL_FIELDS}, "head": {f.name: f for f in HEAD_FIELDS}}
KIND_OF = {EepromIndex.HEAD: "head", EepromIndex.REEL0: "reel", EepromIndex.REEL1: "reel"}


def field(kind: str, name: str) -> Field:
    try:
        return FIELDS[kind][name]
    except KeyError:
        names = ", ".join(FIELDS[kind])
        raise NotFoundError(f"no {kind} EEPROM field {name!r} (fields: {names})") from None


def set_field(data: bytearray, kind: str, name: str, value: str | float) -> None:
    """Write a field into 192 data bytes (masked to 7 bits)."""
    f = field(kind, name)
    data[f.offset : f.offset + f.size] = mask7(f.encode(value))


def fields_of(kind: str, data: bytes) -> dict:
    """Every field's value as the printer reads it (floats at float32 precision)."""
    return {f.name: f.read(data) for f in FIELDS[kind].values()}


def shown_fields(kind: str, data: bytes) -> dict:
    """Every field's value as a person wrote it: floats as the shortest decimal that
    is the same float32 (float8.shortest: 2.85, not 2.8499999046325684)."""
    return {name: float8.shortest(value) if isinstance(value, float) else value
            for name, value in fields_of(kind, data).items()}


_HEAD_CODE = re.compile(rb"^(RBX\d\d-|RX\d)")


def guess_kind(data: bytes) -> str:
    """A head's type code is RBXnn-... or RXn... (reel filament IDs read RBX-...)."""
    return "head" if _HEAD_CODE.match(bytes(data[:16])) else "reel"
