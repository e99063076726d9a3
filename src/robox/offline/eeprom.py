"""EEPROM dumps (512-byte chip images) on the host: create, show, change, check.

`set` runs the firmware's own EEPROM object over a simulated chip holding the
dump: the printer's load, masked host writes, then maintenance until both
banks are verified; so a changed dump is exactly what a printer leaves on the
chip. `show` and `fsck` only read the file.
"""

from __future__ import annotations

import os

from robox.errors import ImageError, NotFoundError, RoboxError, UsageError
from robox.fileio import read_input, write_atomically
from robox.firmware.eeprom import Eeproms, Status
from robox.firmware.error_flags import ErrorFlags
from robox.formats import eeprom as fmt
from robox.formats import float8
from robox.formats.eeprom import CHIP_SIZE, DATA_SIZE, EepromIndex
from robox.hardware.clock import SimClock
from robox.hardware.eeprom import EepromChip
from robox.hardware.eeprom_bus import EepromBus
from robox.locks import locked_path

#: Loop passes allowed for a load or a rewrite of both banks (generous).
MAX_PASSES = 100_000
PASS_S = 0.001


def read_dump(path: str | os.PathLike) -> bytes:
    data = read_input(path, "an EEPROM dump", limit=CHIP_SIZE, allow_empty=True)
    if len(data) != CHIP_SIZE:
        raise ImageError(f"{path}: {len(data)} bytes; an EEPROM dump is {CHIP_SIZE} bytes")
    return data


def parse_assignments(assignments: list[str]) -> list[tuple[str, str]]:
    pairs = []
    for text in assignments:
        name, sep, value = text.partition("=")
        if not sep or not name:
            raise UsageError(f"{text!r} is not FIELD=VALUE")
        pairs.append((name.strip(), value))
    return pairs


def _field(kind: str, name: str) -> fmt.Field:
    try:
        return fmt.field(kind, name)
    except NotFoundError as exc:
        raise UsageError(str(exc)) from None


def _encode_all(kind: str, pairs: list[tuple[str, str]]) -> list[tuple[fmt.Field, bytes]]:
    """Every assignment checked and encoded before anything is changed."""
    encoded = []
    for name, value in pairs:
        f = _field(kind, name)
        encoded.append((f, fmt.mask7(f.encode(value))))
    return encoded


#: Fields a new dump holds unless set: a multiplier of 0 would make a reel extrude nothing.
NEW_DEFAULTS = {"reel": ["filament_multiplier=1.0", "feed_rate_multiplier=1.0"], "head": []}


def new_dump(kind: str, assignments: list[str]) -> bytes:
    """A chip image with both banks valid: zeroed data, a reel's multipliers 1.0, and
    the given fields set."""
    data = bytearray(DATA_SIZE)
    for f, raw in _encode_all(kind, parse_assignments(NEW_DEFAULTS[kind] + assignments)):
        data[f.offset : f.offset + f.size] = raw
    return fmt.chip_image(bytes(data))


def _bank_report(chip: bytes, bank: int) -> dict:
    raw = fmt.read_bank(chip, bank)
    stored = int.from_bytes(raw[DATA_SIZE:], "little")
    return {"bank": bank, "address": fmt.BANK_ADDRESSES[bank], "crc_good": fmt.bank_good(raw),
            "crc_stored": f"{stored:08x}", "crc_computed": f"{fmt.eeprom_crc(raw[:DATA_SIZE]):08x}"}


def _field_report(kind: str, data: bytes) -> dict:
    report = {}
    for f in fmt.FIELDS[kind].values():
        value = f.read(data)
        report[f.name] = {"value": float8.shortest(value) if isinstance(value, float) else value,
                          "raw": f.raw(data).decode("ascii", "backslashreplace")}
    return report


def inspect(chip: bytes, kind: str | None = None) -> dict:
    """Both banks, what a printer would load, and every field of the loaded copy."""
    loaded = fmt.loaded_bank(chip)
    # what a host reads: the loaded copy's data, masked to 7 bits
    data = fmt.mask7(fmt.read_bank(chip, loaded)[:DATA_SIZE]) if loaded is not None else None
    if kind is None:
        kind = fmt.guess_kind(data if data is not None else fmt.read_bank(chip, 0))
    reasons = []
    for bank in (0, 1):
        if not fmt.bank_good(fmt.read_bank(chip, bank)):
            reasons.append(f"bank {bank} CRC is bad")
    identical = fmt.read_bank(chip, 0) == fmt.read_bank(chip, 1)
    return {
        "kind": kind,
        "banks": [_bank_report(chip, 0), _bank_report(chip, 1)],
        "loaded_bank": loaded,
        "status": "VALID" if loaded is not None else "PRESENT",
        "banks_identical": identical,
        "problems": reasons,
        "fields": _field_report(kind, data) if data is not None else None,
    }


def show_dump(path: str | os.PathLike, kind: str | None = None) -> dict:
    return {"dump": str(path), **inspect(read_dump(path), kind)}


def fsck_dump(path: str | os.PathLike) -> dict:
    report = inspect(read_dump(path))
    verdict = {
        "dump": str(path),
        "valid": report["loaded_bank"] is not None,
        "loaded_bank": report["loaded_bank"],
        "banks": report["banks"],
        "banks_identical": report["banks_identical"],
    }
    if report["loaded_bank"] is None:
        verdict["reason"] = ("both banks have a bad CRC: a printer reports it present but "
                             "not valid, and a host must format it")
    elif report["problems"] or not report["banks_identical"]:
        verdict["reason"] = (f"loads bank {report['loaded_bank']}; a printer rewrites the "
                             "other bank from it")
    else:
        verdict["reason"] = "both banks good and identical"
    return verdict


def run_until(eeproms: Eeproms, clock: SimClock, done) -> None:
    for _ in range(MAX_PASSES):
        if done():
            return
        eeproms.maintain()
        clock.advance(PASS_S)
    raise RoboxError("the EEPROM did not settle")  # pragma: no cover - a model bug


def set_dump(path: str | os.PathLike, assignments: list[str], kind: str | None = None) -> dict:
    """Change fields as a printer would (load, masked writes, both banks rewritten)."""
    with locked_path(path):  # read, changed and replaced with no other writer between
        return _set_dump(path, assignments, kind)


def _set_dump(path: str | os.PathLike, assignments: list[str], kind: str | None) -> dict:
    chip_bytes = read_dump(path)
    pairs = parse_assignments(assignments)
    loaded = fmt.loaded_bank(chip_bytes)
    if loaded is None:
        raise RoboxError(f"{path}: both banks have a bad CRC; a printer would not load it "
                         "(make a new one with `robox-cli eeprom new`)")
    if kind is None:
        kind = fmt.guess_kind(fmt.read_bank(chip_bytes, loaded))
    changes = _encode_all(kind, pairs)
    clock = SimClock()
    chip = EepromChip(chip_bytes, clock)
    index = EepromIndex.HEAD if kind == "head" else EepromIndex.REEL0
    bus = EepromBus(**{"head" if kind == "head" else "reel0": chip})
    eeproms = Eeproms(bus, clock, ErrorFlags())
    run_until(eeproms, clock, lambda: eeproms.status(index) != Status.NOT_PRESENT)
    for f, raw in changes:
        eeproms.host_write(index, f.offset, raw)
    run_until(eeproms, clock, lambda: eeproms.settled(index))
    write_atomically(path, bytes(chip.data))
    return {"dump": str(path), "kind": kind, "changed": [name for name, _ in pairs],
            "transactions": chip.transactions, "writes": chip.writes}
