"""What an existing file is, as far as this project's formats can tell: asked before an
output is written over it, so that a card image or an EEPROM dump is not lost to a
mistyped `-o` without the user saying so."""

from __future__ import annotations

import os
import stat

from robox.formats import eeprom as eeprom_format
from robox.formats.sdcard import BLOCK_SIZE, Directory

CARD_IMAGE = "a card image"
EEPROM_DUMP = "an EEPROM dump"


def identify(path: str | os.PathLike) -> str | None:
    """CARD_IMAGE, EEPROM_DUMP, or None (no such file, not a regular file, or neither)."""
    try:
        info = os.stat(path)
        if not stat.S_ISREG(info.st_mode) or info.st_size == 0:
            return None
        with open(path, "rb") as handle:
            head = handle.read(BLOCK_SIZE)
    except OSError:
        return None
    if info.st_size == eeprom_format.CHIP_SIZE and \
            eeprom_format.loaded_bank(head) is not None:
        return EEPROM_DUMP
    if info.st_size % BLOCK_SIZE == 0 and len(head) == BLOCK_SIZE and \
            Directory.decode(head).capacity == info.st_size // BLOCK_SIZE:
        return CARD_IMAGE
    return None
