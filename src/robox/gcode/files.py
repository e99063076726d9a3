"""Translating files: detection from the head and tail, the stream to a temporary
file renamed into place (a failed translation leaves nothing behind)."""

from __future__ import annotations

import contextlib
import hashlib
import itertools
import os
import tempfile
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import BinaryIO

from robox.errors import ImageError, UsageError
from robox.fileio import open_input, read_chunks, refuse_overwriting, replacing
from robox.formats.protocol import JOB_LINE_LIMIT
from robox.gcode.text import BOM, code_part, looks_like_gcode, split_lines
from robox.gcode.translate import ROBOXISED, Detected, Options, Summary, detect, translate

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
    """What `path` holds (the slicer, the E mode), from its head and tail."""
    with _lines(path) as (_, detected):
        return detected


@contextlib.contextmanager
def _lines(source: str | os.PathLike, detected: Detected | None = None
           ) -> Iterator[tuple[Iterator[bytes], Detected]]:
    """The lines of `source`, and what it is. With `detected`, what inspect() found in it
    a moment before: its head and tail are not read and judged again."""
    with open_input(source, "a G-code file") as handle:
        if detected is not None:
            if handle.read(len(BOM)) != BOM:
                handle.seek(0)
            yield split_lines(read_chunks(handle)), detected
            return
        head, tail = _sniff(handle)
        if head.startswith(BOM):  # a file a Windows editor saved: the mark is not G-code
            head = head[len(BOM):]
            handle.seek(len(BOM))
        if not looks_like_gcode(head):
            raise ImageError(f"{source}: not a G-code file")
        yield split_lines(read_chunks(handle)), detect(head, tail)


CARD_LINE_END = b"\r"  # a job's lines as they go to the card (protocol.md)
FILE_LINE_END = b"\n"  # and in a file a person keeps


class Written:
    """What `_write_job` wrote, as the printer will read it: its lines (each ended by a
    CR), its longest line and its SHA-1."""

    def __init__(self) -> None:
        self.lines = 0
        self.longest = 0
        self.digest = hashlib.sha1()

    def write(self, out: BinaryIO, batch: list[bytes], end: bytes) -> None:
        """The lines of `batch`, each ended with `end`, to `out`, and counted."""
        data = end.join(batch) + end
        out.write(data)
        self.digest.update(data)
        ends = data.count(b"\r")
        if not ends:
            return  # (LF ends: a person's file, not the card's lines)
        self.lines += ends
        # each line is one of the card's unless a line holds a CR of its own
        parts = batch if ends == len(batch) and data[-1:] == b"\r" else data.split(b"\r")
        self.longest = max(self.longest, max(map(len, parts)))


def _write_job(lines: Iterable[bytes], target: str | os.PathLike,
               end: bytes = CARD_LINE_END) -> Written:
    """Lines ended with `end` to a temporary file renamed into place once all are
    written."""
    written = Written()
    with replacing(target) as temp, open(temp, "wb") as out:
        source = iter(lines)
        # (batches taken by islice: the per-line loop runs in C, not in this frame)
        while batch := list(itertools.islice(source, 4096)):
            written.write(out, batch, end)
    return written


def _roboxise(source: str | os.PathLike, target: str | os.PathLike, options: Options,
              end: bytes, detected: Detected | None = None) -> tuple[Summary, Written]:
    with _lines(source, detected) as (lines, detected):
        refuse_overwriting(target, source)
        translated, summary = translate(lines, options, detected)
        if end == FILE_LINE_END:  # a file a person keeps: marked a Robox job
            translated = itertools.chain([ROBOXISED], translated)
        return summary, _write_job(translated, target, end)


def roboxise_file(source: str | os.PathLike, target: str | os.PathLike,
                  options: Options, end: bytes = FILE_LINE_END) -> Summary:
    """Translate `source` into the Robox job `target`, its lines ended with `end` (LF
    for a person's file; send-job's copy for the card, CR). Streams; `target` appears
    only when the whole file translated."""
    return _roboxise(source, target, options, end)[0]


def _strip(source: str | os.PathLike, target: str | os.PathLike,
           detected: Detected | None = None) -> Written:
    with _lines(source, detected) as (lines, _):
        refuse_overwriting(target, source)
        return _write_job(_no_macros(source, map(code_part, lines)), target)


def strip_file(source: str | os.PathLike, target: str | os.PathLike) -> None:
    """`source` as a job as it is: comments and blank lines dropped, CR line ends. A
    `Macro:NAME` line is refused: the printer does not expand macros, a host does."""
    _strip(source, target)


def _no_macros(source: str | os.PathLike, codes: Iterable[bytes]) -> Iterator[bytes]:
    for number, code in enumerate(codes, 1):
        if code:
            if code[:6].lower() == b"macro:":
                raise UsageError(f"{source}: line {number}: {code.decode('ascii', 'replace')}"
                                 ": the printer does not expand macros (send it with "
                                 "--macros DIR, without --raw)")
            yield code


class JobFile:
    """A job ready to upload, in a temporary file."""

    def __init__(self, path: Path, size: int, lines: int, sha1: str,
                 translation: Summary | None, long_line: tuple[int, int] | None = None,
                 source: str = "") -> None:
        self.path = path
        self.size = size
        self.lines = lines
        self.sha1 = sha1
        self.translation = translation  # None: sent as it is
        self.long_line = long_line  # (number, bytes) of the first line too long
        self.source = source

    def refuse_long_lines(self) -> None:
        """Refuse to upload a job with a line the printer would abort it on (ImageError);
        `simulate` prints it instead, and shows the abort."""
        if self.long_line is not None:
            number, length = self.long_line
            raise ImageError(f"{self.source}: job line {number} is {length} bytes; the "
                             f"printer reads lines of at most {JOB_LINE_LIMIT - 1} (it would "
                             "abort the job there)")


def _first_long_line(job: Path) -> tuple[int, int]:
    """The number and length of the job's first line too long for the printer."""
    number, run = 1, 0
    with open(job, "rb") as handle:
        for chunk in read_chunks(handle):
            for k, part in enumerate(chunk.split(b"\r")):
                if k:  # the line before this part ended
                    if run >= JOB_LINE_LIMIT:
                        return number, run
                    number, run = number + 1, 0
                run += len(part)
    return number, run


@contextlib.contextmanager
def job_file(source: str | os.PathLike, options: Options | None,
             detected: Detected | None = None) -> Iterator[JobFile]:
    """The Robox job for `source` in a temporary file, removed afterwards: translated
    with `options`, or with None as it is (comments stripped). Memory stays flat.
    `detected`: what inspect() found in `source` (the caller chose `options` by it), so
    that the file's head and tail are not read and judged a second time."""
    with tempfile.TemporaryDirectory(prefix="robox-job-") as directory:
        target = Path(directory) / "job.gcode"
        summary = None
        if options is None:
            written = _strip(source, target, detected)
        else:
            summary, written = _roboxise(source, target, options, CARD_LINE_END, detected)
        # (counted as it was written: the file is not read again)
        lines, longest = written.lines, written.longest
        if not lines:
            raise ImageError(f"{source}: no G-code commands in the file")
        long_line = _first_long_line(target) if longest >= JOB_LINE_LIMIT else None
        yield JobFile(target, target.stat().st_size, lines, written.digest.hexdigest(), summary,
                      long_line, str(source))
