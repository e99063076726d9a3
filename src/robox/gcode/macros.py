"""AutoMaker's macros: `Macro:NAME` lines and the file each one names.

A job or a macro includes another macro with a line `Macro:NAME`; NAME is the rest of
the line, blanks trimmed, and may hold anything a file name can: parentheses
(`Macro:Level_Gantry_(2-points)`), blanks, and `#` parts that pick a variant
(`Macro:Short_Purge#RBX01-DM#N0`). Only a `;` comment is taken off it.

Macro files are named `BASE[#PART...].gcode`, each PART one of: a nozzle (`N0`, `N1`,
`NB` both), safety features (`S` on, `U` off), or else a head type code (`RBX01-DM`).
For `Macro:NAME` the files whose names start with NAME are candidates, their BASE
equal to NAME's first part (case aside), and the best fit wins, scored per part as
AutoMaker scored them: the job's head equal to the file's, or a file with no head for
the standard head (RBX01-SM), 2; a file for any head, 1; another head's, -2. The nozzle
the job uses now, the same way (N0/N1). Safety: a printed job leaves them as they are,
so a file that names none scores 2 and one that does, -2. Ties go to the first name in
sorted order.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

from robox.errors import UsageError

DEFAULT_HEAD = "RBX01-SM"
NOZZLE_PARTS = ("N0", "N1", "NB")
SAFETY_PARTS = ("S", "U")
EXTENSION = ".gcode"
_DIRECTIVE = re.compile(rb"\s*macro:", re.IGNORECASE)


def directive(line: bytes) -> str | None:
    """The macro NAME of a `Macro:NAME` line (None: not such a line)."""
    found = _DIRECTIVE.match(line)
    if found is None:
        return None
    name = line[found.end():].split(b";", 1)[0].strip()
    if not name.isascii():
        raise UsageError("a macro name is ASCII")
    return name.decode("ascii")


def _score(stem: str, base: str, head: str, nozzle: int) -> int | None:
    """How well a macro file named `stem` fits; None: another macro's file."""
    parts = stem.split("#")
    if parts[0].lower() != base.lower():
        return None
    file_head = file_nozzle = file_safety = None
    for part in parts[1:]:
        if part in NOZZLE_PARTS:
            file_nozzle = part
        elif part in SAFETY_PARTS:
            file_safety = part
        else:
            file_head = part
    score = 0
    if file_head == head or (file_head is None and head == DEFAULT_HEAD):
        score += 2
    elif file_head is None:
        score += 1
    else:
        score -= 2
    if file_nozzle == f"N{nozzle}":
        score += 2
    elif file_nozzle is None:
        score += 1
    else:
        score -= 2
    score += 2 if file_safety is None else -2
    return score


def find(directory: Path, name: str, head: str, nozzle: int) -> Path:
    """The file of macro `name` for `head` with `nozzle` in use (UsageError: none)."""
    base = name.split("#", 1)[0]
    try:
        listed = sorted(os.listdir(directory))
    except OSError as exc:
        raise UsageError(f"macros directory {directory}: {exc.strerror}") from None
    best: tuple[int, str] | None = None
    for entry in listed:
        if not entry.startswith(name) or not entry.lower().endswith(EXTENSION):
            continue
        stem = entry[: -len(EXTENSION)]
        if "." in stem or not (directory / entry).is_file():
            continue
        score = _score(stem, base, head, nozzle)
        if score is not None and (best is None or score > best[0]):
            best = (score, entry)
    if best is None:
        raise UsageError(f"no macro {name!r} in {directory} (a file {name}[#...].gcode)")
    return directory / best[1]
