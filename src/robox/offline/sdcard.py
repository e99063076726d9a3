"""Card images on the host: create, format, list, store, fetch and check.

Everything goes through the firmware's own file-system object or its
read-only mount plan, so an image is handled exactly as a printer (or the
virtual printer) would handle the card. Inspection opens the image read-only:
`ls`, `get` and `fsck` cannot write to it.
"""

from __future__ import annotations

import contextlib
import io
import os
import re
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import BinaryIO

from robox.errors import ImageError, NotFoundError, RoboxError, UsageError
from robox.fileio import replacing, require_regular_file
from robox.firmware.error_flags import ErrorFlags
from robox.firmware.file_system import FileSystem, MountPlan, plan_mount, scan_copies
from robox.formats.sdcard import (
    BLOCK_SIZE,
    ID_SIZE,
    MIN_CARD_BLOCKS,
    NO_JOB,
    Directory,
    card_blocks,
    default_id,
    file_blocks,
    following_block,
    id_text,
    make_id,
    newest_with_id,
    trailer_generation,
)
from robox.hardware.sdcard import SdCard
from robox.hardware.storage import FileStorage

_SIZE = re.compile(r"^\s*(\d+)\s*(b|kib|mib|gib)\s*$", re.IGNORECASE)
_UNITS = {"kib": 1024, "mib": 1024**2, "gib": 1024**3}
#: The capacity field is 32 bits wide.
MAX_CARD_BLOCKS = 0xFFFFFFFE


def parse_size(text: str) -> int:
    """Card size in blocks from `8MiB`, `512KiB`, `1GiB` or a block count `16384b`."""
    match = _SIZE.match(text)
    if not match:
        raise UsageError(f"size {text!r} is not like 8MiB, 512KiB or 16384b")
    number, unit = int(match.group(1)), match.group(2).lower()
    if unit == "b":
        blocks = number
    else:
        size = number * _UNITS[unit]
        if size % 1024:
            raise UsageError(f"size {text!r} is not a whole number of KiB")
        blocks = card_blocks(size)
    if blocks % 2:
        raise UsageError(f"size {text!r} is an odd number of blocks; a card holds whole KiB")
    if blocks < MIN_CARD_BLOCKS:
        raise UsageError(f"size {text!r} is {blocks} blocks; a card has at least "
                         f"{MIN_CARD_BLOCKS} (1 MiB)")
    if blocks > MAX_CARD_BLOCKS:
        raise UsageError(f"size {text!r} is too large for the 32-bit capacity field")
    return blocks


def check_image_size(path: str | os.PathLike, size: int) -> int:
    """Capacity of an image of `size` bytes, or ImageError saying why it is not one."""
    if size % BLOCK_SIZE:
        raise ImageError(f"{path}: {size} bytes is not a whole number of 512-byte blocks")
    capacity = card_blocks(size)
    if capacity < MIN_CARD_BLOCKS:
        raise ImageError(f"{path}: {size // BLOCK_SIZE} blocks is too small for a card image "
                         f"(at least {MIN_CARD_BLOCKS})")
    return capacity


@contextlib.contextmanager
def open_card(path: str | os.PathLike, writable: bool = False) -> Iterator[SdCard]:
    """An SdCard over an image file, after checking the file can be one."""
    require_regular_file(path, "a card image")
    try:
        storage = FileStorage(path, writable=writable)
    except FileNotFoundError:
        raise NotFoundError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise ImageError(f"{path}: is a directory, not a card image") from None
    except OSError as exc:
        raise ImageError(f"{path}: {exc.strerror}") from None
    try:
        check_image_size(path, storage.size)
        yield SdCard(storage)
        storage.flush()
    finally:
        storage.close()


def _fs_errors(errors: ErrorFlags, what: str) -> RoboxError:
    return RoboxError(f"{what}: {errors.describe() or 'failed'}")


# ------------------------------------------------------------------ format
def _looks_like_card(card: SdCard) -> bool:
    """An existing file may be reformatted only if it already looks like a card image."""
    block0 = card.read_block(0)
    directory = Directory.decode(block0)
    return directory.capacity == card.capacity or not any(block0)


def format_image(path: str | os.PathLike, blocks: int | None,
                 confirm: Callable[[], None] | None = None) -> dict:
    """Create a formatted image of `blocks` blocks, or reformat an existing image (once
    every check has passed, `confirm()` is called before its files are dropped; it raises
    to stop)."""
    target = Path(path)
    if target.exists():
        if target.is_dir():
            raise ImageError(f"{path}: is a directory, not a card image")
        with open_card(target, writable=True) as card:
            if blocks is not None and blocks != card.capacity:
                raise ImageError(f"{path}: the image holds {card.capacity} blocks, not {blocks}; "
                                 "an image is not resized (remove it to make a new one)")
            if not _looks_like_card(card):
                found = Directory.decode(card.read_block(0)).capacity
                raise ImageError(f"{path}: block 0 is not a card directory (its capacity field "
                                 f"says {found} blocks, the image holds {card.capacity}); "
                                 "refusing to overwrite a file that is not a card image")
            if confirm is not None:
                confirm()
            errors = ErrorFlags()
            if not FileSystem(card, errors).format():
                raise _fs_errors(errors, f"{path}: format failed")
            return {"image": str(path), "capacity_blocks": card.capacity, "created": False}
    if blocks is None:
        raise UsageError(f"{path} does not exist: give --size to create it")
    check_image_size(path, blocks * BLOCK_SIZE)  # (said of the user's path, not the temporary)
    with replacing(target) as temp:
        with open(temp, "r+b") as handle:
            handle.truncate(blocks * BLOCK_SIZE)
        with open_card(temp, writable=True) as card:
            errors = ErrorFlags()
            if not FileSystem(card, errors).format():
                raise _fs_errors(errors, f"{path}: format failed")
    return {"image": str(path), "capacity_blocks": blocks, "created": True}


# ------------------------------------------------------------- inspection
def _mounted(path: str | os.PathLike, card: SdCard) -> tuple[MountPlan, Directory]:
    plan = plan_mount(card)
    if plan.directory is None:
        reason = plan.project.reason
        raise ImageError(f"{path}: the directory is not valid ({reason}); "
                         "a printer would format this card")
    return plan, plan.directory


def _file_entry(d: Directory, index: int, capacity: int) -> dict:
    slot = d.slots[index]
    end = following_block(slot.start_block, slot.blocks - 1, capacity) if slot.blocks else None
    return {
        "slot": index,
        "id": id_text(slot.id),
        "id_hex": slot.id.hex(),
        "job": slot.job,
        "start_block": slot.start_block,
        "length": slot.length,
        "blocks": slot.blocks,
        "end_block": end,
        "wraps": slot.blocks > 0 and slot.start_block + slot.blocks > capacity,
        "last_job": d.last_job == index,
    }


def list_image(path: str | os.PathLike) -> dict:
    """Committed files, oldest first, as a printer mounting the card would see them."""
    with open_card(path) as card:
        plan, d = _mounted(path, card)
        return {
            "image": str(path),
            "capacity_blocks": card.capacity,
            "mount": plan.action,
            "files": [_file_entry(d, i, card.capacity) for i in d.ring()],
            "last_job": None if d.last_job == NO_JOB else d.last_job,
        }


def resolve_id(path: str | os.PathLike, wanted: str) -> str:
    """The id on the card that `wanted` names: itself, or the file name a file was put
    or sent under without --id (part.gcode: the one id on the card made from that name,
    robox.formats.sdcard.default_id). NotFoundError lists the ids there are."""
    if not wanted or not wanted.isascii() or (len(wanted) > ID_SIZE and
                                              not Path(wanted).suffix):
        make_id(wanted)  # refuses it: neither an id nor a file's name
    ids = [entry["id"] for entry in list_image(path)["files"]]
    if wanted in ids:
        return wanted
    stem = default_id(Path(wanted).stem, "")  # the name's part of the id, and "_"
    made = sorted({i for i in ids if i.startswith(stem) and len(i) == ID_SIZE and
                   all(c in "0123456789abcdef" for c in i[len(stem):])})
    if len(made) == 1:
        return made[0]
    if made:
        raise UsageError(f"{path}: {wanted!r} could be any of {', '.join(made)}: give the id")
    listed = ", ".join(dict.fromkeys(ids)) or "none"
    raise NotFoundError(f"{path}: no file with id {wanted!r} (ids on the card: {listed})")


def get_file(path: str | os.PathLike, file_id: str) -> bytes:
    """The newest committed file with that id, byte-exact. Never writes the image."""
    wanted = make_id(file_id)
    with open_card(path) as card:
        _, d = _mounted(path, card)
        index = newest_with_id(d, wanted)
        if index is not None:
            return b"".join(card.read_block(block)[:size]
                            for block, size in file_blocks(d.slots[index], card.capacity))
    raise NotFoundError(f"{path}: no file with id {id_text(wanted)!r}")


def put_file(path: str | os.PathLike, data: bytes, file_id: str, job: bool) -> dict:
    """Store `data` as a printer receives a file: start, 512-byte chunks, end."""
    return put_stream(path, io.BytesIO(data), file_id, job)


def largest_file(path: str | os.PathLike) -> int:
    """The most bytes a file stored on the image can have (read from its size alone)."""
    with open_card(path) as card:
        return (card.capacity - 2) * BLOCK_SIZE


def put_stream(path: str | os.PathLike, source: BinaryIO, file_id: str, job: bool) -> dict:
    """Store what `source` (a seekable binary file) holds, read a chunk at a time, as a
    printer receives a file."""
    stored = make_id(file_id)
    length = source.seek(0, io.SEEK_END)
    source.seek(0)
    if not length:
        raise RoboxError("the file is empty; a printer does not keep zero-length files")
    with open_card(path, writable=True) as card:
        largest = (card.capacity - 2) * BLOCK_SIZE
        if length > largest:
            raise ImageError(f"the file is {length} bytes; the largest file this card "
                             f"holds is {largest} bytes")
        _mounted(path, card)  # refuse a card a printer would format
        errors = ErrorFlags()
        fs = FileSystem(card, errors)
        before = fs.file_list()
        chunks = length // BLOCK_SIZE
        ok = fs.start_write_file(stored, job)
        for sequence in range(chunks):
            if not ok:
                break
            ok = fs.write_chunk(sequence, source.read(BLOCK_SIZE))
        if ok:
            ok = fs.end_write_file(chunks, source.read())
        if not ok or errors.bits:
            raise _fs_errors(errors, f"{path}: storing the file failed")
        after = fs.file_list()
        dropped = [id_text(i) for i in before if i not in after]
        return {"image": str(path), "id": id_text(stored), "job": job, "length": length,
                "dropped": dropped}


def fsck_image(path: str | os.PathLike, deep: bool = False) -> dict:
    """Everything a person needs to judge a card image; never writes it. It reads what
    a mount reads: the whole card only when block 0 is not a valid directory (a mount
    then looks for a recovery copy), or with `deep`."""
    with open_card(path) as card:
        plan = plan_mount(card)
        d = plan.on_card
        copies = list(plan.copies) if plan.copies is not None else \
            scan_copies(card) if deep else None
        in_use = plan.directory
        newest = copies[0] if copies else None
        report = {
            "image": str(path),
            "capacity_blocks": card.capacity,
            "directory": {
                "capacity": d.capacity,
                "next_write_block": d.next_write_block,
                "first_file": d.first_file,
                "next_file": d.next_file,
                "last_job": None if d.last_job == NO_JOB else d.last_job,
                "nonvolatile": list(d.nonvolatile),
                "generation": trailer_generation(d),
            },
            "printer": {
                "valid": plan.printer.valid,
                "action": "keep" if plan.printer.valid else "format",
                "reason": plan.printer.reason or None,
            },
            "project": {
                "valid": plan.project.valid,
                "action": plan.action,
                "reason": plan.project.reason or None,
                "repairs": list(plan.repairs),
            },
            # the files in use after mount; for a card the project would format,
            # the extents block 0 claims, so a person can see what is wrong
            "files_from": {"keep": "directory", "recover": "recovery copy",
                           "format": "invalid directory"}[plan.action],
            "files": [_file_entry(in_use or d, i, card.capacity)
                      for i in (in_use or d).ring()],
            "recovery_copy": None if newest is None else {
                "block": newest.block,
                "generation": newest.generation,
                "usable": True,
                "files": len(newest.directory.ring()),
                "matches_directory": in_use is not None
                and newest.directory.ring() == in_use.ring()
                and all(newest.directory.slots[i] == in_use.slots[i] for i in in_use.ring()),
            },
            "recovery_copies": None if copies is None else len(copies),
        }
        return report
