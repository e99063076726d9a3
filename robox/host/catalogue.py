"""What this host knows of the files on each printer's card.

The printer's file list (report 0xe0) carries ids only: no size, no job flag,
and a repeated id is listed once per copy. The host that uploads a file knows
the rest, as AutoMaker did with the jobs it kept; a job's default id is made
from its name and content's SHA-1 (`robox.formats.sdcard.default_id`), so an
id seen again means the same content.

The catalogue is one JSON file per printer, named by its unique ID, under
`$XDG_STATE_HOME/robox/cards` (else `~/.local/state/robox/cards`):

    {"files": {"<id>": {"size": 12345, "lines": 678, "job": true,
                        "sha1": "<hex>", "stored": "<ISO time>"}}}

An upload is recorded once its last chunk is acknowledged (`robox-cli send-job`,
the OctoPrint plugin). `describe()` joins the
printer's list with it: each copy, which copy is the newest (the last listed,
the one a run by id starts), and size, lines and job flag where known. A
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


def load(unique_id: str) -> dict[str, dict]:
    try:
        data = json.loads(path_for(unique_id).read_text("utf-8"))
        files = data["files"]
        return {str(k): dict(v) for k, v in files.items() if isinstance(v, dict)}
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return {}


def record(unique_id: str, file_id: str, size: int, lines: int | None, job: bool,
           sha1: str | None = None) -> None:
    """Remember that `file_id` on this printer's card holds `size` bytes."""
    target = path_for(unique_id)
    target.parent.mkdir(parents=True, exist_ok=True)
    # read, changed and replaced with no other host between (two send-jobs at once)
    with lock_file(target.with_suffix(".lock"), f"the catalogue {target}"):
        files = load(unique_id)
        files[file_id] = {"size": size, "lines": lines, "job": job, "sha1": sha1,
                          "stored": time.strftime("%Y-%m-%dT%H:%M:%S%z")}
        write_atomically(target, json.dumps({"files": files}, indent=1, sort_keys=True)
                         .encode("utf-8"))


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
