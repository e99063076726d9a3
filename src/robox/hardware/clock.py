"""Simulated time: a clock the firmware loop advances; nothing here reads the wall clock."""


class SimClock:
    """Seconds since power-up, advanced explicitly."""

    def __init__(self, start: float = 0.0):
        self.now = start

    def advance(self, seconds: float, times: int = 1) -> None:
        """Move on `times` steps of `seconds`, added one by one (so n passes of 1 ms land
        exactly where n single passes would)."""
        if seconds < 0:
            raise ValueError("time does not run backwards")
        now = self.now
        left = times
        while left > 0:  # (a float and a countdown: compiled, neither is boxed)
            now += seconds
            left -= 1
        self.now = now
