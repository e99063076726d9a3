"""Simulated time: a clock the firmware loop advances; nothing here reads the wall clock."""


class SimClock:
    """Seconds since power-up, advanced explicitly."""

    def __init__(self, start: float = 0.0):
        self.now = start

    def advance(self, seconds: float) -> None:
        if seconds < 0:
            raise ValueError("time does not run backwards")
        self.now += seconds
