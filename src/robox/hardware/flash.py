"""The microcontroller's flash: 512 pages of 256 bytes; a page write is erase-and-write."""

from __future__ import annotations

from robox.errors import PowerCut
from robox.formats.firmware import FLASH_SIZE, PAGE_SIZE
from robox.hardware.storage import MemoryStorage, Storage


class Flash:
    def __init__(self, storage: Storage | None = None):
        self.storage = storage or MemoryStorage(b"\xff" * FLASH_SIZE)
        if self.storage.size != FLASH_SIZE:
            raise ValueError(f"flash is {FLASH_SIZE} bytes, not {self.storage.size}")
        self.page_writes = 0
        #: The printer's supply (a PowerPlan shared with the other media), if watched.
        self.power = None

    def read(self, offset: int, length: int) -> bytes:
        return self.storage.read(offset, length)

    def page(self, number: int) -> bytes:
        return self.storage.read(number * PAGE_SIZE, PAGE_SIZE)

    def write_page(self, number: int, data: bytes) -> None:
        data = bytes(data).ljust(PAGE_SIZE, b"\xff")[:PAGE_SIZE]
        self.page_writes += 1
        landing = self.power.write(self, number, data) if self.power is not None else None
        if landing is not None:
            landed = PAGE_SIZE if landing.mode == "whole" else landing.param
            self.storage.write(number * PAGE_SIZE, data[:landed] + b"\xff" * (PAGE_SIZE - landed))
            raise PowerCut(f"power cut while writing flash page {number}")
        self.storage.write(number * PAGE_SIZE, data)

    def flush(self) -> None:
        self.storage.flush()
