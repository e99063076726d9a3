"""One small exception hierarchy for every layer of robox."""


class RoboxError(Exception):
    """A problem the user can act on; the message says what and, where possible, how."""


class UsageError(RoboxError):
    """The request itself is malformed (a bad size, id or value)."""


class NotFoundError(RoboxError):
    """What was asked for does not exist (a file on a card, a field)."""


class ImageError(RoboxError):
    """An image or dump file cannot be used (wrong size, not what it claims to be)."""


class CardError(RoboxError):
    """The simulated SD card did not complete an access."""


class CardAbsent(CardError):
    """No card is in the slot (the card-detect switch is open)."""


class CardReadError(CardError):
    """A block read failed."""


class PowerCut(BaseException):
    """Power failed. Derived from BaseException so firmware code cannot swallow it."""
