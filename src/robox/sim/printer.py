"""The virtual printer: the firmware model on simulated hardware, with a state directory.

State directory (it survives between runs; each file is readable by the
offline tools):
    sdcard.img      the SD card, written through as the firmware writes it
    head.eeprom     512-byte chip dumps of the head and reel EEPROMs
    reel0.eeprom
    reel1.eeprom    only with a dual-reel adaptor (its presence fits the mux)
    flash.bin       the 128 KiB flash, written through
    filament.json   the filament in the feeds, where there is any (`robox-cli sim
                    load`): {"E": {"length_mm": .., "tip_mm": ..}, "D": ...}, tip_mm
                    along the path from the drive (380: at the nozzle); saved as the
                    printer switches off. Without it the feeds are empty, as at power-up.
    flaws.json      the head's true build, where it differs from a perfect head (`sim
                    serve --nozzle-z-difference MM --b-open B0,B1 --xy-offset DX,DY`):
                    {"nozzle_z_difference_mm": .., "b_open": [..], "xy_offset_mm": [..]}.
                    The machine's probing and valve follow it; the calibrations measure it.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass
from pathlib import Path

from robox.errors import ImageError, RoboxError
from robox.fileio import write_atomically
from robox.firmware.main import Firmware, Hardware
from robox.formats.eeprom import CHIP_SIZE, EepromIndex, fields_of, loaded_bank, read_bank
from robox.formats.firmware import FLASH_SIZE
from robox.formats.heads import HeadValves, head_valves
from robox.formats.protocol import reply_length
from robox.hardware.deposition import Deposition
from robox.hardware.eeprom import EepromChip
from robox.hardware.eeprom_bus import EepromBus
from robox.hardware.flash import Flash
from robox.hardware.machine import NOZZLE_MM, STEPS_PER_MM, D, E, Z
from robox.hardware.sdcard import SdCard
from robox.hardware.storage import FileStorage, MemoryStorage
from robox.hardware.usb import PACKET_SIZE, ReplyWaiting
from robox.locks import DirectoryLock
from robox.offline import sdcard as card_images
from robox.sim import images

CARD_SIZE = "64MiB"
BUNDLED_CARD = Path(__file__).resolve().parent.parent / "data" / "sdcard.img"
CHIP_FILES = {EepromIndex.HEAD: "head.eeprom", EepromIndex.REEL0: "reel0.eeprom",
              EepromIndex.REEL1: "reel1.eeprom"}
FILAMENT_FILE = "filament.json"
FEEDS = {"E": E, "D": D}
FLAWS_FILE = "flaws.json"
#: how far a virtual head may be from perfect: beyond this no calibration could help
FLAW_LIMITS = {"nozzle_z_difference_mm": 2.0, "b_open": 2.0, "xy_offset_mm": 1.0}


def read_flaws(directory: Path) -> dict:
    """The head's true build a state directory records (an empty dict: perfect, the
    head exactly as its EEPROM says)."""
    path = directory / FLAWS_FILE
    if not path.exists():
        return {}
    try:
        data = json.loads(path.read_text())
        return check_flaws(data)
    except (OSError, ValueError, TypeError, AttributeError) as e:
        raise ImageError(f"{path}: not a head flaws record ({e})") from None


def check_flaws(data: dict) -> dict:
    """`data` with its values checked (ValueError names the one out of bounds)."""
    out: dict = {}
    for key, value in data.items():
        if key not in FLAW_LIMITS:
            raise ValueError(f"unknown flaw {key!r}")
        values = [float(v) for v in value] if isinstance(value, list) else [float(value)]
        if len(values) != (1 if key == "nozzle_z_difference_mm" else 2):
            raise ValueError(f"{key}: {value!r}")
        for v in values:
            if not (math.isfinite(v) and abs(v) <= FLAW_LIMITS[key]):
                raise ValueError(f"{key}: {v:g} is beyond ±{FLAW_LIMITS[key]:g}")
        if key == "b_open" and not (values[0] > 0.0 > values[1]):
            raise ValueError("b_open: nozzle 0's needle opens at a positive B, nozzle 1's "
                             f"at a negative one ({values[0]:g}, {values[1]:g})")
        out[key] = values[0] if key == "nozzle_z_difference_mm" else values
    return out


def write_flaws(directory: Path, flaws: dict) -> None:
    """Record the head's true build (the file goes when the head is perfect)."""
    path = directory / FLAWS_FILE
    if not flaws:
        path.unlink(missing_ok=True)
        return
    write_atomically(path, (json.dumps(check_flaws(flaws), indent=1, sort_keys=True)
                            + "\n").encode())


def read_filament(directory: Path) -> dict[str, dict[str, float] | None]:
    """The filament a state directory says is in each feed (None: empty)."""
    path = directory / FILAMENT_FILE
    if not path.exists():
        return dict.fromkeys(FEEDS)
    try:
        data = json.loads(path.read_text())
        out: dict[str, dict[str, float] | None] = {}
        for name in FEEDS:
            feed = data.get(name)
            if feed is None:
                out[name] = None
                continue
            length, tip = float(feed["length_mm"]), float(feed["tip_mm"])
            if not (0.0 < length < 1e7 and -1e6 < tip <= NOZZLE_MM and math.isfinite(tip)):
                raise ValueError(f"{name}: length_mm {length}, tip_mm {tip}")
            out[name] = {"length_mm": length, "tip_mm": tip}
        return out
    except (OSError, ValueError, TypeError, KeyError, AttributeError) as e:
        raise ImageError(f"{path}: not a filament record ({e})") from None


def _chip_fields(chip: EepromChip | None, kind: str = "head") -> dict:
    if chip is None:
        return {}
    data = bytes(chip.data)
    bank = loaded_bank(data)
    return {} if bank is None else fields_of(kind, read_bank(data, bank))


def reel_diameter_of(chip: EepromChip | None) -> float:
    """The reel's filament diameter (1.75 mm where it cannot be read)."""
    try:
        value = float(_chip_fields(chip, "reel").get("filament_diameter", 1.75))
    except (TypeError, ValueError):
        return 1.75
    return value if 0.5 <= value <= 5.0 else 1.75


def head_valves_of(chip: EepromChip | None) -> HeadValves:
    """The valves of the head in the socket (by its type code; a single-material head
    where it cannot be read)."""
    code = str(_chip_fields(chip).get("type_code", "")).strip()
    try:
        return head_valves(code or "RBX01-SM")
    except RoboxError:
        return head_valves("RBX01-SM")


def head_seats_of(chip: EepromChip | None) -> tuple[float, float]:
    """Where the head's needles shut: its EEPROM's B offsets (calibration measures them
    there)."""
    f = _chip_fields(chip)
    seats = []
    for name in ("nozzle0_b_offset", "nozzle1_b_offset"):
        try:
            value = float(f.get(name, 0.0))
        except (TypeError, ValueError):
            value = 0.0
        seats.append(value if math.isfinite(value) else 0.0)
    return seats[0], seats[1]


def write_filament(directory: Path, feeds: dict[str, dict[str, float] | None]) -> None:
    """Record the filament in each feed (the file goes when every feed is empty)."""
    path = directory / FILAMENT_FILE
    if all(feed is None for feed in feeds.values()):
        path.unlink(missing_ok=True)
        return
    write_atomically(path, (json.dumps(feeds, indent=1, sort_keys=True) + "\n").encode())


def create_state(directory: Path) -> None:
    """Fill a state directory with a new printer (files already there are kept)."""
    directory.mkdir(parents=True, exist_ok=True)
    # a process killed while it wrote one of these left its temporary file behind; a new
    # card is built in a temporary file that is itself replaced, so temporaries nest
    names = ("sdcard.img", "flash.bin", *CHIP_FILES.values())
    for stale in directory.glob(".*.tmp"):
        if stale.name.lstrip(".").startswith(tuple(f"{name}." for name in names)):
            stale.unlink(missing_ok=True)
    card = directory / "sdcard.img"
    if not card.exists():
        _new_card(card)
    for name, content in (("head.eeprom", lambda: images.head_eeprom(calibrated=True)),
                          ("reel0.eeprom", images.reel_eeprom)):
        if not (directory / name).exists():
            write_atomically(directory / name, content())
    if not (directory / "flash.bin").exists():
        write_atomically(directory / "flash.bin",
                         images.flash_contents(images.firmware_image(), images.new_unique_id()))


def _new_card(card: Path) -> None:
    """A 64 MiB card holding the bundled card image's files, in their order."""
    from robox.fileio import replacing

    with replacing(card) as temp:
        Path(temp).unlink()
        card_images.format_image(temp, card_images.parse_size(CARD_SIZE))
        if BUNDLED_CARD.exists():
            for entry in card_images.list_image(BUNDLED_CARD)["files"]:
                data = card_images.get_file(BUNDLED_CARD, entry["id"])
                card_images.put_file(temp, data, entry["id"], entry["job"])


@dataclass(frozen=True)
class Media:
    """What a printer keeps with its power off: the card's bytes, each EEPROM socket's chip
    (None: empty socket), and the flash."""

    card: bytes
    chips: tuple[bytes | None, bytes | None, bytes | None]
    flash: bytes


class VirtualPrinter:
    """Firmware plus hardware; `state_dir=None` keeps everything in memory (starting from
    `media` when given)."""

    def __init__(self, state_dir: str | os.PathLike | None = None, card_blocks: int = 16384,
                 media: Media | None = None, role: str = "command"):
        self.state_dir = Path(state_dir) if state_dir is not None else None
        self._files = []
        self.lock = None
        if self.state_dir is not None:
            self.state_dir.mkdir(parents=True, exist_ok=True)
            # held until close(): no other process opens these files meanwhile
            self.lock = DirectoryLock(self.state_dir, role)
        try:
            self._power_up(card_blocks, media)
        except BaseException:
            self.close()
            raise

    def _power_up(self, card_blocks: int, media: Media | None) -> None:
        chips: dict[EepromIndex, EepromChip | None] = {}
        self._dumps_at_power_up: dict[int, FileStorage] = {}
        if media is not None:
            if self.state_dir is not None:
                raise ValueError("media are for an in-memory printer")
            card = SdCard(MemoryStorage(media.card))
            flash = Flash(MemoryStorage(media.flash))
            chips = {index: None if content is None else EepromChip(content)
                     for index, content in zip(EepromIndex, media.chips, strict=True)}
        elif self.state_dir is None:
            card = SdCard.blank(card_blocks)
            flash = Flash(MemoryStorage(images.flash_contents(images.firmware_image(),
                                                              b"RBXSIM0000000001")))
            chips = {EepromIndex.HEAD: EepromChip(images.head_eeprom()),
                     EepromIndex.REEL0: EepromChip(images.reel_eeprom()),
                     EepromIndex.REEL1: None}
        else:
            create_state(self.state_dir)
            card_storage = self._open(self.state_dir / "sdcard.img")
            card_images.check_image_size(self.state_dir / "sdcard.img", card_storage.size)
            card = SdCard(card_storage)
            flash_storage = self._open(self.state_dir / "flash.bin")
            if flash_storage.size != FLASH_SIZE:
                raise ImageError(f"{self.state_dir / 'flash.bin'}: not {FLASH_SIZE} bytes")
            flash = Flash(flash_storage)
            for index, name in CHIP_FILES.items():
                path = self.state_dir / name
                if path.exists():
                    # open (and locked) while the printer is on: written in place
                    dump = self._dumps_at_power_up[index] = self._open(path)
                    if dump.size != CHIP_SIZE:
                        raise ImageError(f"{path}: {dump.size} bytes; a chip dump is 512")
                    chips[index] = EepromChip(dump.read(0, CHIP_SIZE))
                else:
                    chips[index] = None
        bus = EepromBus(chips.get(EepromIndex.HEAD), chips.get(EepromIndex.REEL0),
                        chips.get(EepromIndex.REEL1),
                        mux_present=chips.get(EepromIndex.REEL1) is not None)
        self.hw = Hardware(card, bus, flash)
        for chip in bus.sockets:
            if chip is not None:
                chip.clock = self.hw.clock
        self._saved_writes = [c.writes if c else 0 for c in bus.sockets]
        self._saved_mark = (bus.writes(), bus.inserts)
        # dumps open to write in place
        self._chip_dumps: dict[int, FileStorage] = dict(self._dumps_at_power_up)
        self._filament_loaded = False
        self.flaws = read_flaws(self.state_dir) if self.state_dir is not None else {}
        self.hw.machine.nozzle1_drop = round(self.flaws.get("nozzle_z_difference_mm", 0.0)
                                             * STEPS_PER_MM[Z])
        seats = self.flaws.get("b_open")
        if self.state_dir is not None:
            for name, feed in read_filament(self.state_dir).items():
                if feed is not None:
                    self.hw.machine.insert_filament(FEEDS[name], feed["length_mm"],
                                                    feed["tip_mm"])
                    self._filament_loaded = True
        if self._filament_loaded:
            # with filament in, the needle's physics (a shut head fills, then the drive
            # slips: what G36 waits for) without the record simulate keeps
            Deposition(head_valves_of(chips.get(EepromIndex.HEAD)),
                       (reel_diameter_of(chips.get(EepromIndex.REEL0)),
                        reel_diameter_of(chips.get(EepromIndex.REEL1))),
                       (seats[0], seats[1]) if seats else
                       head_seats_of(chips.get(EepromIndex.HEAD)),
                       recording=False).attach(self.hw.machine)
        self.firmware = Firmware(self.hw)

    def _open(self, path: Path) -> FileStorage:
        storage = FileStorage(path, writable=True)
        self._files.append(storage)
        return storage

    @property
    def usb(self):
        return self.hw.usb

    def media(self) -> Media:
        """A copy of everything nonvolatile, as it stands."""
        hw = self.hw
        return Media(bytes(hw.card.storage.read(0, hw.card.storage.size)),
                     tuple(None if chip is None else bytes(chip.data)
                           for chip in hw.eeprom_bus.sockets),
                     bytes(hw.flash.read(0, FLASH_SIZE)))

    def supply(self, plan) -> None:
        """Power every nonvolatile medium from `plan` (a PowerPlan), or from the mains
        (None)."""
        hw = self.hw
        for device in (hw.card, hw.flash, *hw.eeprom_bus.sockets):
            if device is not None:
                device.power = plan

    # ------------------------------------------------------------ running
    def run_pass(self, step: float | None = None, passes: int = 1) -> None:
        self.firmware.run_pass(step, passes)
        self.save_chips()

    def run_for_host(self, timeout: float, reader_margin: int = 0) -> int:
        """Firmware.run_for_host, then the chips' files brought up to date: before the
        host can have anything the run sent, its reply included."""
        passes = self.firmware.run_for_host(timeout, reader_margin=reader_margin)
        self.save_chips()
        return passes

    def run_until(self, condition, timeout: float = 3600.0) -> bool:
        """Firmware.run_until, then the chips' files brought up to date (condition None:
        run the whole timeout)."""
        done = self.firmware.run_until(condition, timeout)
        self.save_chips()
        return done

    def transact(self, frame: bytes, timeout: float = 10.0) -> bytes:
        """A host's command frame in at the USB link, and the printer's one whole report
        out, read as a USB host reads (as soon as it is sent, after any pass)."""
        usb = self.usb
        usb.host_write(frame)
        reply = b""
        while True:
            self.run_until(ReplyWaiting(usb), timeout)
            if not usb.reply_waiting:
                raise RoboxError(f"the virtual printer did not answer {frame[:1].hex()} "
                                 f"(got {reply!r})")
            length = reply_length(reply)
            reply += usb.host_read(PACKET_SIZE if length is None else length - len(reply))
            length = reply_length(reply)
            if length is not None and len(reply) >= length:
                return reply

    def settle(self, timeout: float = 10.0) -> bool:
        """Let background work finish: EEPROM banks rewritten, replies sent."""
        fw = self.firmware
        return self.run_until(lambda: all(fw.eeproms.quiet(i) for i in range(3))
                              and fw.command.pending_after_reply is None, timeout)

    def cool_down(self, timeout: float = 3600.0) -> bool:
        """With every heater off, let the head cool below the "hot" mark (and the card
        record it), as a printer left switched on would before someone turns it off."""
        heaters = self.firmware.heaters
        if heaters.any_on():
            return False
        return self.run_until(lambda: not heaters.head_hot_now() and
                              not self.firmware.file_system.nonvolatile(0), timeout)

    # ---------------------------------------------------------- persistence
    def save_chips(self) -> None:
        """Bring each chip's dump up to date with the chip, if it was written since. A
        dump is written over in place, one unbuffered 512-byte write, as the card image
        and the flash are written through; a dump that did not exist is created whole,
        by a rename."""
        if self.state_dir is None:
            return
        # (called after every run: nothing written and no chip swapped, nothing to look at)
        bus = self.hw.eeprom_bus
        mark = (bus.writes(), bus.inserts)
        if mark == self._saved_mark:
            return
        for index, chip in enumerate(bus.sockets):
            if chip is not None and chip.writes != self._saved_writes[index]:
                data = bytes(chip.data)
                dump = self._chip_dumps.get(index)
                if dump is None:
                    path = self.state_dir / CHIP_FILES[EepromIndex(index)]
                    if not path.exists():
                        write_atomically(path, data)
                    dump = self._chip_dumps[index] = self._open(path)
                dump.write(0, data)
                self._saved_writes[index] = chip.writes
        self._saved_mark = mark

    def save_filament(self) -> None:
        """Record where the filament in the feeds now is (a state directory's printer
        that had some: what a print used, drew back or ran out of)."""
        if self.state_dir is None or not self._filament_loaded:
            return
        machine = self.hw.machine
        feeds: dict[str, dict[str, float] | None] = {}
        for name, axis in FEEDS.items():
            f = machine.filament[axis]
            steps = STEPS_PER_MM[axis]
            feeds[name] = None if f is None or f.tip <= f.tail else {
                "length_mm": round(int(f.tip - f.tail) / steps, 3),
                "tip_mm": round(int(f.tip) / steps, 3)}
        write_filament(self.state_dir, feeds)

    def close(self) -> None:
        if getattr(self, "hw", None) is not None:
            self.save_chips()
            self.save_filament()
        self._chip_dumps = {}
        for storage in self._files:
            storage.flush()
            storage.close()
        self._files = []
        if self.lock is not None:
            self.lock.release()
            self.lock = None

    def __enter__(self) -> VirtualPrinter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
