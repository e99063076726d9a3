"""What a new virtual printer starts with: a flashed image, a head, a reel of PLA."""

from __future__ import annotations

import os
import random

from robox.formats import eeprom as fmt
from robox.formats.firmware import (
    DEFAULT_OFFSET,
    FLASH_SIZE,
    HOURS_PAGE,
    PAGE_SIZE,
    REVISION_LITERAL,
    UNIQUE_ID_PAGE,
    insert_anti_checksum,
)

DEFAULT_REVISION = "r776sim"
IMAGE_BYTES = 24 * 1024


def firmware_image(revision: str = DEFAULT_REVISION, size: int = IMAGE_BYTES,
                   seed: int = 776) -> bytes:
    """A stand-in firmware image: deterministic content, the revision marker, a valid
    anti-checksum at 0xBC. The model runs its own code; the image gives the flash the
    bytes a real one would (size, word sum, version, revision)."""
    body = bytearray(random.Random(seed).randbytes(size))  # (not numpy: start-up time)
    body[DEFAULT_OFFSET : DEFAULT_OFFSET + 4] = bytes(4)
    marker = REVISION_LITERAL + revision.encode("ascii") + b"\r\n\0"  # as a C literal
    body[0x200 : 0x200 + len(marker)] = marker
    body[-PAGE_SIZE:] = body[-PAGE_SIZE:].replace(b"\xff", b"\xfe")  # last page not erased
    result = insert_anti_checksum(bytes(body))
    assert result.inserted, result.detail
    return result.image


def flash_contents(image: bytes, unique_id: bytes) -> bytes:
    flash = bytearray(b"\xff" * FLASH_SIZE)
    flash[: len(image)] = image
    flash[HOURS_PAGE * PAGE_SIZE : HOURS_PAGE * PAGE_SIZE + 8] = b"0.000000"
    uid = bytes(b & 0x7F for b in unique_id)[:PAGE_SIZE].ljust(PAGE_SIZE, b"\0")
    flash[UNIQUE_ID_PAGE * PAGE_SIZE : (UNIQUE_ID_PAGE + 1) * PAGE_SIZE] = uid
    return bytes(flash)


def new_unique_id() -> bytes:
    return b"RBXSIM" + os.urandom(5).hex().upper().encode()


#: The B offsets a calibrated head carries: where its needles shut (robox.hardware.deposition).
CALIBRATED_B_OFFSETS = (0.65, -0.70)


def head_eeprom(calibrated: bool = False, type_code: str = "RBX01-SM") -> bytes:
    """A head of `type_code` (by default a single-material one).

    `calibrated`: as a head leaves calibration, with the valve's B offsets measured
    (nozzle 0 opens at +0.65, nozzle 1 at -0.70 past the B switch) and the reel's PLA
    as the material it last melted, so that T0/T1 find their needle and a job away
    from a host asks for no nozzle flush. Uncalibrated (offsets 0: T0/T1 raise
    B_STUCK) is the head the conformance recordings start with."""
    data = bytearray(fmt.DATA_SIZE)
    fields = [("type_code", type_code), ("unique_id", "RBXSIMHEAD0001"),
              ("max_temperature", "300"), ("thermistor_beta", "3960"),
              ("thermistor_tcal", "1.0"), ("head_hours", "0")]
    if calibrated:
        fields += [("nozzle0_b_offset", f"{CALIBRATED_B_OFFSETS[0]:.2f}"),
                   ("nozzle1_b_offset", f"{CALIBRATED_B_OFFSETS[1]:.2f}"),
                   ("nozzle0_last_filament_temperature", "210"),
                   ("nozzle1_last_filament_temperature", "210")]
    for name, value in fields:
        fmt.set_field(data, "head", name, value)
    return fmt.chip_image(bytes(data))


def reel_eeprom(remaining_mm: float = 240000.0, diameter_mm: float = 1.75) -> bytes:
    """A reel of PLA (by default 1.75 mm, with 240 m of filament)."""
    data = bytearray(fmt.DATA_SIZE)
    for name, value in (("filament_id", "RBX-PLA-SIM"), ("display_colour", "FFFFFF"),
                        ("first_layer_nozzle_temperature", "210"),
                        ("nozzle_temperature", "210"), ("first_layer_bed_temperature", "60"),
                        ("bed_temperature", "55"), ("ambient_temperature", "35"),
                        ("filament_diameter", repr(diameter_mm)), ("filament_multiplier", "1.0"),
                        ("feed_rate_multiplier", "1.0"), ("friendly_name", "Robox PLA White"),
                        ("material_type", "P"), ("remaining_filament", repr(remaining_mm))):
        fmt.set_field(data, "reel", name, value)
    return fmt.chip_image(bytes(data))
