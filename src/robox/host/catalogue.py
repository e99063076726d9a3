"""What this host knows of the files on each printer's card.

The printer's file list (report 0xe0) carries ids only: no size, no job flag,
and a repeated id is listed once per copy. The host that uploads a file knows
the rest, as AutoMaker did with the jobs it kept; a job's default id is made
from its name and content's SHA-1 (`robox.formats.sdcard.default_id`), so an
id seen again means the same content.

The catalogue is one JSON file per printer, named by its unique ID, under
`$XDG_STATE_HOME/robox/cards` (else `~/.local/state/robox/cards`):

    {"files": {"<id>": {"size": 12345, "lines": 678, "job": true,
                        "sha1": "<hex>", "stored": "<ISO time>"}},
     "card": {"largest_file": 2147482624}}

An upload is recorded once its last chunk is acknowledged (`robox-cli send-job`,
the OctoPrint plugin). `describe()` joins the
printer's list with it: each copy, which copy is the newest (the last listed,
the one a run by id starts), and size, lines and job flag where known.

The printer does not report its card's size. An upload it refuses as too large
for the card tells the host (`robox.host.client.FileTooLarge`); the largest file
the card holds is then kept under "card", and a larger job is refused before its
first chunk from then on. A
catalogue that cannot be read counts as empty; it is written by temporary file
and rename, so a crash leaves the old one or the new one.
"""

from __future__ import annotations

import json
import os
import re
import time
from collections import Counter
from pathlib import Path

from robox.fileio import write_atomically
from robox.locks import lock_file

SAFE = re.compile(r"[^A-Za-z0-9_.-]")


def directory() -> Path:
    base = os.environ.get("XDG_STATE_HOME") or os.path.join(os.path.expanduser("~"), ".local",
                                                            "state")
    return Path(base) / "robox" / "cards"


def path_for(unique_id: str) -> Path:
    return directory() / f"{SAFE.sub('_', unique_id) or 'unknown'}.json"


def _read(unique_id: str) -> dict:
    try:
        data = json.loads(path_for(unique_id).read_text("utf-8"))
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


def load(unique_id: str) -> dict[str, dict]:
    files = _read(unique_id).get("files")
    if not isinstance(files, dict):
        return {}
    return {str(k): dict(v) for k, v in files.items() if isinstance(v, dict)}


def largest_file(unique_id: str) -> int | None:
    """The most bytes a file on this printer's card can have, if an upload found out."""
    card = _read(unique_id).get("card")
    value = card.get("largest_file") if isinstance(card, dict) else None
    return value if isinstance(value, int) and not isinstance(value, bool) and value > 0 \
        else None


def _update(unique_id: str, change) -> None:
    """Read, change and replace the printer's catalogue with no other host between
    (two send-jobs at once)."""
    target = path_for(unique_id)
    target.parent.mkdir(parents=True, exist_ok=True)
    with lock_file(target.with_suffix(".lock"), f"the catalogue {target}"):
        data = {"files": load(unique_id)}
        card = _read(unique_id).get("card")
        if isinstance(card, dict):
            data["card"] = card
        change(data)
        write_atomically(target, json.dumps(data, indent=1, sort_keys=True).encode("utf-8"))


def record(unique_id: str, file_id: str, size: int, lines: int | None, job: bool,
           sha1: str | None = None) -> None:
    """Remember that `file_id` on this printer's card holds `size` bytes."""
    entry = {"size": size, "lines": lines, "job": job, "sha1": sha1,
             "stored": time.strftime("%Y-%m-%dT%H:%M:%S%z")}
    _update(unique_id, lambda data: data["files"].__setitem__(file_id, entry))


def record_largest_file(unique_id: str, largest: int) -> None:
    """Remember the most bytes a file on this printer's card can have."""
    _update(unique_id, lambda data: data.setdefault("card", {})
            .__setitem__("largest_file", largest))


def describe(listed: list[str], known: dict[str, dict]) -> list[dict]:
    """The printer's list (oldest first), each copy with what is known of it."""
    last = {name: i for i, name in enumerate(listed)}
    copies = Counter(listed)
    out = []
    for i, name in enumerate(listed):
        entry = known.get(name, {})
        out.append({"id": name, "newest": last[name] == i,
                    "copies": copies[name],
                    "size": entry.get("size"), "lines": entry.get("lines"),
                    "job": entry.get("job")})
    return out
