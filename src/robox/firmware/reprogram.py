"""Reprogramming: check a firmware file on the card, write it to flash, reset."""

from __future__ import annotations

from robox.formats.firmware import (
    IMAGE_PAGES,
    PAGE_SIZE,
    check_sd_text,
    flashed_image_pages,
    from_sd_text,
)
from robox.formats.protocol import ErrorBit

ERASED = b"\xff" * PAGE_SIZE


class Reprogram:
    def __init__(self, firmware):
        self.fw = firmware

    def initialise(self) -> None:
        self.last_check = None

    def check(self, file_id: bytes) -> bytes | None:
        """The image if the newest committed file with this id passes every rule; else
        BAD_FIRMWARE_FILE is set and flash is left alone."""
        text = self.fw.file_system.read_committed(file_id)
        result = check_sd_text(text) if text is not None else None
        self.last_check = result
        if result is None or not result.accepted:
            self.fw.errors.set(ErrorBit.BAD_FIRMWARE_FILE)
            return None
        return from_sd_text(text)

    def flash(self, image: bytes) -> None:
        """Page by page from the start of flash (interrupts off: nothing else runs), the
        rest of the image area erased, then reset. A power cut here leaves a partial image."""
        flash = self.fw.hw.flash
        pages = len(image) // PAGE_SIZE
        old_pages = flashed_image_pages(flash.read(0, len(IMAGE_PAGES) * PAGE_SIZE))
        for page in range(pages):
            data = image[page * PAGE_SIZE : (page + 1) * PAGE_SIZE]
            if flash.page(page) != data:
                flash.write_page(page, data)
        for page in range(pages, max(pages, old_pages)):
            if flash.page(page) != ERASED:
                flash.write_page(page, ERASED)
        self.fw.request_reset()
