"""The latched error flags that the ack/errors report 0xe3 carries."""

from __future__ import annotations

from robox.formats.protocol import ERROR_REPORT_BITS, ERROR_TEXT, ErrorBit


class ErrorFlags:
    """Error bits latch when set and stay set until cleared."""

    def __init__(self) -> None:
        self.bits = 0
        # the last report and the bits it was made from (asked with every ack, and the
        # bits seldom change between two)
        self._reported = -1
        self._report = b""

    def set(self, bit: ErrorBit) -> None:
        self.bits |= 1 << bit

    def is_set(self, bit: ErrorBit) -> bool:
        return bool(self.bits >> bit & 1)

    def clear(self) -> None:
        self.bits = 0

    def active(self) -> list[ErrorBit]:
        return [bit for bit in ErrorBit if self.is_set(bit)]

    def describe(self) -> str:
        return ", ".join(ERROR_TEXT[bit] for bit in self.active())

    def report(self) -> bytes:
        """The 64 characters of the 0xe3 report: character i is bit i."""
        low = self.bits & ((1 << ERROR_REPORT_BITS) - 1)
        if low != self._reported:
            self._report = format(low, f"0{ERROR_REPORT_BITS}b")[::-1].encode("ascii")
            self._reported = low
        return self._report
