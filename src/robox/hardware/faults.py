"""Fault injection: one plan per device, consulted by the simulated hardware only.

Firmware objects never special-case faults; they see what real hardware would
show them: a write that never returns (power cut), a block half written (torn),
a read that fails, a card that is gone.
"""

from __future__ import annotations

from typing import Any

try:  # mypyc's class options (robox.native: compiled, these classes are native)
    from mypy_extensions import mypyc_attr
except ImportError:  # (not installed: pure Python, where the options mean nothing)

    def mypyc_attr(*_args: Any, **_flags: Any) -> Any:  # type: ignore[misc]
        return lambda cls: cls


class Tear:
    """How a torn write lands: a prefix of the new bytes, a seeded byte mix, or, beyond
    the byte-mix model, a block left erased (every byte `fill`)."""

    def __init__(self, prefix: int | None = None, seed: int | None = None,
                 fill: int | None = None) -> None:
        self.prefix = prefix
        self.seed = seed
        self.fill = fill

    def apply(self, old: bytes, new: bytes) -> bytes:
        import numpy as np  # only here: keeps robox-cli start-up fast

        if self.fill is not None:
            return bytes([self.fill]) * len(new)
        if self.prefix is not None:
            return new[: self.prefix] + old[self.prefix :]
        rng = np.random.default_rng(self.seed)
        take_new = rng.integers(0, 2, len(new), dtype=np.uint8).astype(bool)
        mixed = np.where(take_new, np.frombuffer(new, np.uint8), np.frombuffer(old, np.uint8))
        return mixed.tobytes()

    def describe(self) -> str:
        if self.fill is not None:
            return f"fill={self.fill:#04x}"
        return f"prefix={self.prefix}" if self.prefix is not None else f"mix={self.seed}"


class FaultPlan:
    """Faults scheduled by ordinal (1-based) of the device's writes and reads.

    - `cut_after_write`: power fails right after that write has landed.
    - `tear_write` with `tear`: that write lands torn, then power fails.
    - `failing_reads`: reads (by ordinal) that fail; schedule two consecutive
      ordinals for a read that also fails its retry.
    - `remove_before_access`: the card is pulled out just before that access
      (reads and writes counted together).
    """

    def __init__(self, cut_after_write: int | None = None, tear_write: int | None = None,
                 tear: Tear | None = None, failing_reads: set[int] | None = None,
                 remove_before_access: int | None = None) -> None:
        self.cut_after_write = cut_after_write
        self.tear_write = tear_write
        self.tear = Tear() if tear is None else tear
        self.failing_reads: set[int] = set() if failing_reads is None else failing_reads
        self.remove_before_access = remove_before_access

    def describe(self) -> str:
        parts = []
        if self.cut_after_write is not None:
            parts.append(f"cut_after_write={self.cut_after_write}")
        if self.tear_write is not None:
            parts.append(f"tear_write={self.tear_write}:{self.tear.describe()}")
        if self.failing_reads:
            parts.append(f"failing_reads={sorted(self.failing_reads)}")
        if self.remove_before_access is not None:
            parts.append(f"remove_before_access={self.remove_before_access}")
        return ",".join(parts) or "none"


class EepromFaultPlan:
    """A hot-unplug scheduled by transaction ordinal (1-based) of one EEPROM chip.

    The chip is pulled out at transaction `unplug_at`. If that transaction is a
    write, `write_lands` says whether its byte reached the cells first; either
    way the transaction is not acknowledged.
    """

    def __init__(self, unplug_at: int | None = None, write_lands: bool = False) -> None:
        self.unplug_at = unplug_at
        self.write_lands = write_lands

    def describe(self) -> str:
        if self.unplug_at is None:
            return "none"
        return f"unplug_at={self.unplug_at},write_lands={self.write_lands}"


class Landing:
    """How the write that power fails during lands: "whole" (then power fails), or torn:
    on a card block "prefix"/"mix"/"erase" as a Tear; on an EEPROM byte "garble" (the
    cell left holding `param`); on a flash page "partial" (erased, its first `param`
    bytes programmed)."""

    def __init__(self, mode: str = "whole", param: int = 0) -> None:
        self.mode = mode
        self.param = param

    def tear(self) -> Tear | None:
        if self.mode == "prefix":
            return Tear(prefix=self.param)
        if self.mode == "mix":
            return Tear(seed=self.param)
        if self.mode == "erase":
            return Tear(fill=0)
        return None


@mypyc_attr(allow_interpreted_subclasses=True)  # a recorder of the writes extends it
class PowerPlan:
    """The printer's supply, shared by every nonvolatile medium (card, EEPROM chips,
    flash): their writes are counted in one sequence, in the order they happen, and
    power fails during write number `cut_at` (1-based), which lands as `landing` says.
    With `log`, every write is also recorded as (device, address, bytes)."""

    def __init__(self, cut_at: int | None = None, landing: Landing | None = None,
                 log: list | None = None) -> None:
        self.cut_at = cut_at
        self.landing = Landing() if landing is None else landing
        self.log = log
        self.writes = 0

    def write(self, device: object, address: int, data: bytes) -> Landing | None:
        """Called by a device as a write reaches its medium; a Landing means the device
        lands the write that way and raises PowerCut."""
        self.writes += 1
        if self.log is not None:
            self.log.append((device, address, bytes(data)))
        return self.landing if self.writes == self.cut_at else None
