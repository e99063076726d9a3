"""Translating files: detection from the head and tail, the stream to a temporary
file renamed into place (a failed translation leaves nothing behind)."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from pathlib import Path

from robox.errors import ImageError
from robox.fileio import open_input, read_chunks, replacing
from robox.gcode.text import looks_like_gcode, split_lines
from robox.gcode.translate import Detected, Options, Summary, detect, translate

HEAD_BYTES = 1 << 16
TAIL_BYTES = 1 << 16


def _sniff(handle) -> tuple[bytes, bytes]:
    head = handle.read(HEAD_BYTES)
    size = os.fstat(handle.fileno()).st_size
    tail = b""
    if size > HEAD_BYTES:
        handle.seek(max(HEAD_BYTES, size - TAIL_BYTES))
        tail = handle.read(TAIL_BYTES)
    handle.seek(0)
    return head, tail


def inspect(path: str | os.PathLike) -> Detected:
    with open_input(path, "a G-code file") as handle:
        head, tail = _sniff(handle)
    if not looks_like_gcode(head):
        raise ImageError(f"{path}: not a G-code file")
    return detect(head, tail)


@contextlib.contextmanager
def _translation(source: str | os.PathLike, options: Options
                 ) -> Iterator[tuple[Iterator[bytes], Summary]]:
    with open_input(source, "a G-code file") as handle:
        head, tail = _sniff(handle)
        if not looks_like_gcode(head):
            raise ImageError(f"{source}: not a G-code file")
        yield translate(split_lines(read_chunks(handle)), options, detect(head, tail))


def roboxise_file(source: str | os.PathLike, target: str | os.PathLike,
                  options: Options) -> Summary:
    """Translate `source` into the Robox job `target` (lines ended with CR, as they go
    to the card). Streams; `target` appears only when the whole file translated."""
    with _translation(source, options) as (lines, summary):
        if Path(target).resolve() == Path(source).resolve():
            raise ImageError(f"{target}: the output would overwrite the input")
        with replacing(target) as temp, open(temp, "wb") as out:
            batch = []
            for line in lines:
                batch.append(line)
                if len(batch) >= 4096:
                    out.write(b"\r".join(batch) + b"\r")
                    batch.clear()
            if batch:
                out.write(b"\r".join(batch) + b"\r")
    return summary


def translated_job(source: str | os.PathLike, options: Options) -> tuple[bytes, Summary]:
    """The Robox job for `source` in memory (what send-job uploads)."""
    with _translation(source, options) as (lines, summary):
        parts = [line + b"\r" for line in lines]
    return b"".join(parts), summary
