"""Fixtures for firmware-object tests: a card, error flags, a file system."""

import pytest

from robox.firmware.error_flags import ErrorFlags
from robox.firmware.file_system import FileSystem
from robox.hardware.sdcard import SdCard


@pytest.fixture
def card() -> SdCard:
    return SdCard.blank(3000)


@pytest.fixture
def errors() -> ErrorFlags:
    return ErrorFlags()


@pytest.fixture
def fs(card: SdCard, errors: ErrorFlags) -> FileSystem:
    return FileSystem(card, errors)


@pytest.fixture
def wire():
    """A settled in-memory virtual printer spoken to in raw frames."""
    from tests.firmware.wire import Wire

    w = Wire()
    w.printer.settle()
    return w
