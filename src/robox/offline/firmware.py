"""Firmware image files on the host: inject an anti-checksum, verify, convert for the SD card."""

from __future__ import annotations

import os
import re
import stat

from robox import fileio
from robox.errors import ImageError, RoboxError, UsageError
from robox.fileio import write_atomically
from robox.formats import firmware as fw
from robox.locks import locked_path

_HEX_OFFSET = re.compile(r"^\s*(0[xX])?([0-9A-Fa-f]+)\s*$")


def parse_offset(text: str) -> int:
    """An offset in hexadecimal, with or without 0x (as strtoul(s, NULL, 16) reads it)."""
    match = _HEX_OFFSET.match(text)
    if not match:
        raise UsageError(f"offset {text!r} is not hexadecimal")
    return int(match.group(2), 16)


def read_input(path: str | os.PathLike) -> bytes:
    """A firmware file: a .bin image or its SD text form, at most TEXT_MAX bytes."""
    return fileio.read_input(path, "a firmware file", limit=fw.TEXT_MAX)


def _check_writable(path: str | os.PathLike) -> None:
    mode = os.stat(path).st_mode
    if not os.access(path, os.W_OK) or not mode & (stat.S_IWUSR | stat.S_IWGRP | stat.S_IWOTH):
        raise ImageError(f"{path}: the file is read-only")


def inject(path: str | os.PathLike, offset: int = fw.DEFAULT_OFFSET) -> dict:
    """Insert the anti-checksum in place, atomically, only once every check has passed."""
    with locked_path(path):  # read, changed and replaced with no other writer between
        return _inject(path, offset)


def _inject(path: str | os.PathLike, offset: int) -> dict:
    image = read_input(path)
    result = fw.insert_anti_checksum(image, offset)
    if not result.inserted:
        raise RoboxError(f"{path}: {result.refusal.value}: {result.detail}")
    _check_writable(path)
    write_atomically(path, result.image)
    return {"file": str(path), "offset": offset, "anti_checksum": f"{result.value:08x}",
            "size": len(image)}


def _failures(result: fw.Verification) -> list[dict]:
    return [{"rule": check.name, "message": check.value, "detail": detail}
            for check, detail in result.failures]


def verify(path: str | os.PathLike, offset: int = fw.DEFAULT_OFFSET) -> dict:
    """What a printer would make of FILE (a .bin or an SD firmware text file). Never writes."""
    data = read_input(path)
    if fw.looks_like_sd_text(data):
        kind = "sd-text"
        result = fw.check_sd_text(data)
        image = fw.from_sd_text(data) if result.size is not None else None
    else:
        kind = "binary"
        result = fw.check_binary(data)
        image = data
    word = None
    if image is not None and offset >= 0 and offset + 4 <= len(image):
        word = f"{int.from_bytes(image[offset : offset + 4], 'little'):08x}"
    return {
        "file": str(path),
        "kind": kind,
        "characters": result.characters,
        "size": result.size,
        "pages": None if result.size is None else result.size / fw.PAGE_SIZE,
        "page_aligned": result.size is not None and result.size % fw.PAGE_SIZE == 0,
        "checksum": None if result.checksum is None else f"{result.checksum:08x}",
        "offset": offset,
        "word_at_offset": word,
        "overlaps_parameter_pages": result.size is not None
        and result.size > fw.PARAMETER_PAGES[0] * fw.PAGE_SIZE,
        "accepted": result.accepted,
        "failures": _failures(result),
    }


def to_sd(path: str | os.PathLike, out: str | os.PathLike) -> dict:
    image = read_input(path)
    text = fw.to_sd_text(image)
    write_atomically(out, text)
    return {"input": str(path), "output": str(out), "bytes": len(image), "characters": len(text)}


def from_sd(path: str | os.PathLike, out: str | os.PathLike) -> dict:
    text = read_input(path)
    try:
        image = fw.from_sd_text(text)
    except ValueError as exc:
        raise ImageError(f"{path}: not an SD firmware file: {exc}") from None
    short = [detail for check, detail in fw.check_sd_text(text).failures
             if check in (fw.Check.LENGTH_NOT_MULTIPLE, fw.Check.TOO_SHORT)]
    if short:
        raise ImageError(f"{path}: not a whole SD firmware file ({short[0]}: a printer "
                         f"takes a multiple of {fw.TEXT_MULTIPLE} characters, at least "
                         f"{fw.TEXT_MIN}); was it cut short?")
    write_atomically(out, image)
    return {"input": str(path), "output": str(out), "bytes": len(image), "characters": len(text)}
