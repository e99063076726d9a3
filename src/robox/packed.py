"""Fixed-size vectors of native numbers for the compiled core; plain lists in pure Python.
(And librt's BytesWriter, which compiled appends a byte natively; a bytearray in pure
Python. And a vector of floats to and from bytes: `floats_to_bytes`, `floats_from_bytes`.)

The firmware keeps its per-axis numbers (accumulators, increments, positions) in C
arrays. Compiled (robox.native), `vec[i64]` and `vec[float]` are mypyc's packed
vectors (librt.vecs): reading or writing an item is a native load or store, where a
list item is a boxed int or float that is made, checked and freed on every access.
In pure Python a packed vector is only slower than a list, so there `vec[T](items)`
makes a list; the code that uses them is the same either way.

setup.py has mypyc take `COMPILED` as always true, so the compiled modules are typed
for librt's vectors; at run time the test below tells the two builds apart (a compiled
module's functions are not Python function objects).
"""

from __future__ import annotations

import sys
import types
from array import array
from typing import Any


def _probe() -> None:
    """A function whose type says whether this module runs compiled."""


COMPILED = not isinstance(_probe, types.FunctionType)

if COMPILED:
    from librt.strings import BytesWriter, read_f64_le, write_f64_le
    from librt.vecs import append, vec
else:

    class _Lists:
        """`vec[T](items)` in pure Python: a list of the items."""

        def __getitem__(self, kind: Any) -> type[list]:
            return list

    vec: Any = _Lists()

    def append(v: list, item: Any) -> list:  # type: ignore[misc]
        """librt.vecs.append(v, item) (which returns the vector, perhaps a new one)."""
        v.append(item)
        return v

    class BytesWriter(bytearray):  # type: ignore[no-redef]
        """librt.strings.BytesWriter in pure Python, as far as the project uses it:
        bytes appended one by one, then getvalue()."""

        def getvalue(self) -> bytes:
            return bytes(self)

try:  # native 64-bit and 8-bit integers where the compiled core is built; otherwise int
    from mypy_extensions import i64, u8
except ImportError:  # pragma: no cover - mypy_extensions comes with the build's tools
    i64 = u8 = int  # type: ignore[misc,assignment]


def floats_to_bytes(values: vec[float]) -> bytes:
    """The floats as little-endian doubles, 8 bytes each (compiled, each written natively
    where an array made of a vector boxes every item and parses it back)."""
    if COMPILED:
        out = BytesWriter()
        for value in values:
            write_f64_le(out, value)
        return out.getvalue()
    doubles = array("d", values)
    if sys.byteorder == "big":  # pragma: no cover - the machines built for are little-endian
        doubles.byteswap()
    return doubles.tobytes()


def floats_from_bytes(data: bytes) -> vec[float]:
    """`floats_to_bytes`' floats back (its length a multiple of 8)."""
    if COMPILED:
        out = vec[float]()
        at: i64 = 0
        end: i64 = len(data) - 7
        while at < end:
            out = append(out, read_f64_le(data, at))
            at += 8
        return out
    doubles = array("d")
    doubles.frombytes(data)
    if sys.byteorder == "big":  # pragma: no cover
        doubles.byteswap()
    return vec[float](doubles.tolist())


__all__ = ["COMPILED", "BytesWriter", "append", "floats_from_bytes", "floats_to_bytes", "i64",
           "u8", "vec"]
