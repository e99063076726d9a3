"""G-code as text: lines, comments, words, and the form a Robox job takes on the wire.

A job on the printer's card is ASCII, one command per line ended with CR, with no
comments or blank lines (protocol.md). Slicers' files carry comments in UTF-8 (names,
degree signs), LF or CRLF line ends, and words in either case; the firmware reads
only the command part, so everything after `;` or inside `( )` is dropped, and bytes
>= 0x80 may appear only in comments.
"""

from __future__ import annotations

import itertools
import re
from collections.abc import Iterable, Iterator
from typing import Final

from robox.packed import BytesWriter, i64, u8

SNIFF_BYTES = 65536

_WORD = re.compile(r"(\S)([^\sA-Z]*)")  # (str.isspace() is \s, ASCII letters upper-cased)
# the same, with a number spelled out ("Xnan", "E-inf") kept as its word's: strtod, which
# the firmware reads a word's number with, takes it as one (NaN, infinite)
_SPELLED_WORD = re.compile(r"(\S)([+-]?(?:NAN|INF(?:INITY)?)(?![^\s;])|[^\sA-Z]*)")


BOM = b"\xef\xbb\xbf"  # UTF-8's byte order mark, which Windows editors put first


def code_part(raw: bytes) -> bytes:
    """A line without its comment (`;` to the end, or from `(`) and outer blanks. A
    `Macro:NAME` line keeps its whole name, parentheses included (AutoMaker's
    `Macro:Level_Gantry_(2-points)`)."""
    line = raw.split(b";", 1)[0]
    paren = line.find(b"(")
    if paren >= 0 and line.lstrip()[:6].lower() != b"macro:":
        line = line[:paren]
    return line.strip()


def split_lines(chunks: Iterable[bytes]) -> Iterator[bytes]:
    """Lines (without their ends) from a stream of byte chunks; CR, LF or CRLF. (The
    lines of each chunk are handed on by itertools.chain: a line costs a step of its
    list, not a generator's resumption.)"""
    return itertools.chain.from_iterable(_chunk_lines(chunks))


def _chunk_lines(chunks: Iterable[bytes]) -> Iterator[list[bytes]]:
    """split_lines's lines, a list of them for each chunk."""
    pending = b""
    for chunk in chunks:
        pending += chunk
        held = pending[-1:] == b"\r"  # its LF may start the next chunk
        text = pending[:-1] if held else pending
        complete = text.splitlines()  # (bytes: at LF, CR and CRLF alone)
        rest = b""
        if complete and text[-1] != 10 and text[-1] != 13:  # its end is still to come
            rest = complete.pop()
        pending = rest + (b"\r" if held else b"")
        yield complete
    pending = pending.rstrip(b"\r")
    if pending:
        yield [pending]


def prepare_job(text: bytes) -> bytes:
    """Comments and blank lines stripped, each line ended with CR (protocol.md)."""
    return b"".join(line + b"\r" for line in (code_part(raw) for raw in split_lines([text]))
                    if line)


def looks_like_gcode(text: bytes) -> bool:
    """Text whose command lines start with G, M or T codes (comments may hold any
    bytes, UTF-8 included; the commands must be ASCII)."""
    head = text[:SNIFF_BYTES]
    if not head or b"\0" in head[:4096]:
        return False
    lines = [code_part(raw) for raw in split_lines([head])]
    if len(head) == SNIFF_BYTES and lines:
        lines.pop()  # cut at the sniff limit
    words = [line.split()[0] for line in lines if line]
    if not words or not all(line.isascii() for line in lines):
        return False
    return all(w[:1].upper() in (b"G", b"M", b"T") for w in words[:50])


# ASCII letters upper-cased and the four separators str.split() knows beyond bytes.split()
# (\x1c-\x1f) made blanks, in one pass: the bytes then split as their text would
_UPPER_BLANKS = bytes(range(256)).replace(
    bytes(range(0x61, 0x7B)), bytes(range(0x41, 0x5B))).replace(b"\x1c\x1d\x1e\x1f", b"    ")


def words(line: bytes) -> tuple[str, dict[str, str]]:
    """('G1', {'X': '10', 'E': '.5'}) from b'G1 X10 E.5'; letters upper-cased. Words may
    be run together (b'G1X10E.5'), as some slicers write them: a word is any character
    but a blank, then everything up to the next letter or blank."""
    parts = line.translate(_UPPER_BLANKS).split()
    # one word per blank-separated part, as nearly every slicer writes them, unless a
    # letter follows a part's first character (words run together); bytes, whose
    # isupper() looks at ASCII alone
    if parts and not parts[0][1:].isupper():
        params: dict[str, str] = {}
        for part in parts[1:]:
            value = part[1:]
            if value.isupper():
                break
            params[part[:1].decode("ascii")] = value.decode("ascii")
        else:
            return parts[0].decode("ascii"), params
    out = _WORD.findall(line.decode("ascii").upper())
    if not out:
        return "", {}
    (letter, number), rest = out[0], out[1:]
    return letter + number, {k: v for k, v in rest}


def words_as_read(line: bytes) -> tuple[str, dict[str, str]]:
    """words(), with a number spelled out kept as its word's, as the printer reads it,
    where words() sees its letters run together, each a word with no number."""
    code, p = words(line)
    if "" not in p.values():  # (nearly every line: only letters with no number need it)
        return code, p
    found = _SPELLED_WORD.findall(line.decode("ascii").upper())
    (letter, digits), rest = found[0], found[1:]
    return letter + digits, {k: v for k, v in rest}


def number(value: float) -> bytes:
    """`value` as a job writes it: printf's "%.5f" without trailing zeros or a bare
    point ("-0" is "0"). Worked out in native arithmetic, not by a formatter: the value
    in hundred-thousandths, |value| * 1e5, is rounded to a whole number as printf
    rounds the exact product (to the nearest, a tie to the even one), its error found
    exactly by Dekker's product (1e5 has 17 bits, so only `value` is split); then its
    digits are written, the point 5 places from the right. Beyond 2**52
    hundred-thousandths (4.5e10), or infinite or NaN: printf's own text."""
    a = -value if value < 0.0 else value
    p = a * 100000.0
    if not p < _EXACT_BELOW:  # (NaN too)
        return _printf_number(value)
    n: i64 = int(p)  # below 2**52 its fraction, p - n, is exact, and so is 0.5
    fraction = p - float(n)
    if fraction >= 0.5:
        # the product's error, exact: p's rounding moved it by less than half its unit,
        # so only at a fraction of exactly 0.5 can the error's sign decide
        c = a * _SPLIT
        high = c - (c - a)
        error = (high * 100000.0 - p) + (a - high) * 100000.0
        if fraction > 0.5 or error > 0.0 or (error == 0.0 and n & 1 == 1):
            n += 1
    if n == 0:
        return b"0"
    # the digits from the left, written natively (compiled): the whole part's, then
    # the fraction's up to its last one that is not 0
    out = BytesWriter()
    if value < 0.0:
        out.append(45)  # -
    whole: i64 = n // 100000
    part: i64 = n - whole * 100000
    unit: i64 = 1
    while unit * 10 <= whole:
        unit *= 10
    while True:
        digit: i64 = whole // unit
        out.append(u8(48 + digit))
        whole -= digit * unit
        if unit == 1:
            break
        unit = unit // 10
    if part != 0:
        out.append(46)  # .
        unit = 10000
        while part != 0:
            digit = part // unit
            out.append(u8(48 + digit))
            part -= digit * unit
            unit = unit // 10
    return out.getvalue()


_SPLIT: Final = 134217729.0  # 2**27 + 1: Veltkamp's split into two 26-bit halves
_EXACT_BELOW: Final = 4503599627370496.0  # 2**52


def _printf_number(value: float) -> bytes:
    text = b"%.5f" % value
    end = len(text)
    while end > 1 and text[end - 1] == 0x30:
        end -= 1
    if text[end - 1] == 0x2E:
        end -= 1
    text = text[:end]
    return b"0" if text == b"-0" or not text else text


native_number = number  # the body above, whichever runs (for the tests)
if __file__.endswith(".py"):  # interpreted, the formatter is the quicker
    number = _printf_number  # type: ignore[assignment]
