"""Power cuts during firmware reprogramming, at every page write, whole or torn.

The printer writes the new image page by page with nothing else running; there
is no second copy. Legal end state: at power-up the boot check sets
FLASH_CHECKSUM unless flash holds a whole image (old or new); the printer still
answers; and updating again from the firmware file on the card, which the cut
left committed, writes the new image whole and clears the error at the next boot.
"""

import random
import struct

import pytest

from robox.errors import PowerCut
from robox.formats.firmware import PAGE_SIZE, to_sd_text
from robox.formats.protocol import ErrorBit
from robox.formats.sdcard import make_id
from robox.hardware.faults import Landing, PowerPlan
from robox.sim import images
from robox.sim.printer import VirtualPrinter
from tests.faults.printer_campaign import connect

FILE_ID = "robox_firmware"
OLD = images.firmware_image()  # 24 KiB, what the printer runs


def boot_sum_is_zero(flash: bytes) -> bool:
    """The boot check, computed here independently: 32-bit little-endian words of the
    pages up to the last page of 0..506 that is not erased, summed mod 2^32."""
    pages = 0
    for page in range(507):
        if flash[page * PAGE_SIZE : (page + 1) * PAGE_SIZE] != b"\xff" * PAGE_SIZE:
            pages = page + 1
    if pages == 0:
        return False
    image = flash[: pages * PAGE_SIZE]
    return sum(struct.unpack(f"<{len(image) // 4}I", image)) % (1 << 32) == 0


def prepared(new: bytes):
    """Media of a printer running OLD with `new` stored on its card as an SD firmware file."""
    virtual = VirtualPrinter(card_blocks=2048)
    virtual.settle()
    connect(virtual).send_file(to_sd_text(new), FILE_ID, job=False)
    virtual.settle()
    return virtual.media()


def update(virtual: VirtualPrinter) -> None:
    resets = virtual.firmware.resets
    reply = virtual.transact(b"\x8f" + make_id(FILE_ID))
    assert reply[:1] == b"\xe3" and set(reply[1:]) == {ord("0")}, reply
    assert virtual.run_until(lambda: virtual.firmware.resets > resets, 5)


def page_writes(media) -> list[int]:
    virtual = VirtualPrinter(media=media)
    virtual.settle()
    log: list = []
    virtual.supply(PowerPlan(log=log))
    update(virtual)
    assert {device for device, _, _ in log} == {virtual.hw.flash}
    return [page for _, page, _ in log]


@pytest.mark.parametrize("size,revision", [(32 * 1024, "r900big"), (12 * 1024, "r901sml")])
def test_a_cut_at_every_page_of_an_update_boots_flagged_and_updating_again_recovers(
        size, revision):
    new = images.firmware_image(revision, size=size, seed=size)
    media = prepared(new)
    pages = page_writes(media)
    # every page of the new image differs from the old one; a smaller image also erases
    # the old image's pages beyond its end
    assert pages == list(range(max(len(new), len(OLD)) // PAGE_SIZE))
    rng = random.Random(size)
    problems = []
    for n in range(1, len(pages) + 1):
        for landing in (Landing("whole"), Landing("partial", 0),
                        Landing("partial", rng.randrange(1, PAGE_SIZE))):
            label = f"page write {n} ({landing.mode} {landing.param})"
            virtual = VirtualPrinter(media=media)
            virtual.settle()
            virtual.supply(PowerPlan(cut_at=n, landing=landing))
            with pytest.raises(PowerCut):
                update(virtual)
            survivor = virtual.media()
            image = survivor.flash[: len(new)]
            whole = image == new and survivor.flash[len(new) : len(OLD)] == \
                b"\xff" * max(0, len(OLD) - len(new))
            printer = VirtualPrinter(media=survivor)
            printer.settle()
            flagged = printer.firmware.errors.is_set(ErrorBit.FLASH_CHECKSUM)
            if flagged == boot_sum_is_zero(survivor.flash) or (not whole and not flagged):
                problems.append(f"{label}: FLASH_CHECKSUM {flagged}, image whole {whole}")
            status = printer.transact(b"\xb0")
            if status[:1] != b"\xe1":
                problems.append(f"{label}: the printer does not answer a status request")
            printer.transact(b"\xc0")
            update(printer)
            again = printer.media().flash
            if again[: len(new)] != new or printer.firmware.errors.is_set(
                    ErrorBit.FLASH_CHECKSUM) or printer.firmware.revision != revision:
                problems.append(f"{label}: updating again did not recover")
            if again[len(new) : 507 * PAGE_SIZE] != b"\xff" * (507 * PAGE_SIZE - len(new)):
                problems.append(f"{label}: pages past the new image are not erased")
    assert not problems, f"{len(problems)} problem(s)\n" + "\n".join(problems[:10])
