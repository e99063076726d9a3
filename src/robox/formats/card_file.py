"""A file on the SD card as a host names and sizes it (spec/sdcard.md): its id, 16 bytes
NUL padded, by which the printer's commands name it, and the 512-byte blocks it takes.
Apart from the card's layout (robox.formats.sdcard, which gives these too), so that a
command talking to a printer need not load that."""

from __future__ import annotations

from robox.errors import UsageError

BLOCK_SIZE = 512
ID_SIZE = 16


def default_id(name: str, sha1_hex: str) -> str:
    """The id robox gives a file stored without one (send-job, sdcard put): the first
    alphanumerics of its name, then the start of its content's SHA-1, 16 characters in
    all, so the same content under the same name always gets the same id (an upload
    resumes under it) and different contents get different ids."""
    stem = "".join(c for c in name if c.isascii() and c.isalnum())[:7] or "file"
    return f"{stem}_{sha1_hex[:ID_SIZE - len(stem) - 1]}"


def make_id(value: str | bytes) -> bytes:
    """The 16-byte id stored for `value`: up to its first NUL, NUL padded.

    Raises UsageError for an id that is empty (no printer command can name it), longer
    than 16 bytes or not ASCII.
    """
    if isinstance(value, str):
        if not value.isascii():
            raise UsageError(f"file id {value!r} is not ASCII")
        value = value.encode("ascii")
    raw = bytes(value)
    raw = raw.split(b"\0", 1)[0]
    if len(raw) > ID_SIZE:
        raise UsageError(f"file id is {len(raw)} bytes long; at most {ID_SIZE} are allowed")
    if not raw:
        raise UsageError("file id is empty; a printer opens files by a non-empty id")
    if any(b >= 0x80 for b in raw):
        raise UsageError("file id must be ASCII")
    return raw.ljust(ID_SIZE, b"\0")


def id_text(file_id: bytes) -> str:
    """Printable form of an untrusted id: up to the first NUL, non-printables escaped."""
    raw = file_id.split(b"\0", 1)[0]
    return "".join(chr(b) if 0x20 <= b < 0x7F and b != 0x5C else f"\\x{b:02x}" for b in raw)
