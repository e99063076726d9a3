"""Choosing a printer: `usb`, `usb:ID`, `serial:PATH`, `sim[:DIR]` and `sim-once[:DIR]`.

`sim` is the virtual printer that stays on: the one served for that state
directory (`robox-cli sim serve`), started in the background when none is, and
reached through its pseudo-terminal as a real printer's /dev/ttyACM* is. Jobs,
uploads and resumes carry on across commands, as on a real printer.

`sim-once` runs the virtual printer in this process for the duration of the
command (tests and benchmarks), reached through its pyusb backend (the same code
path as a real printer); it lets the printer finish its background work and
switches it off before the command exits.
"""

from __future__ import annotations

import contextlib
import errno
import os
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

from robox.errors import RoboxError, UsageError
from robox.formats.card_file import BLOCK_SIZE
from robox.host.client import DEFAULT_TIMEOUT_MS, Printer
from robox.host.transport import (
    PRODUCT_ID,
    VENDOR_ID,
    NoReply,
    PermissionDenied,
    SerialTransport,
    SocketTransport,
    TransportError,
    UsbTransport,
    permission_hint,
)
from robox.locks import InUse

ENVIRONMENT = "ROBOX_DEVICE"
SIM_STEP_S = 5.0  # simulated seconds a sim-once printer runs while the host waits


class NoPrinter(RoboxError):
    """No printer matches the selection."""


@dataclass
class Attached:
    unique_id: str | None  # None: another program is using it (`in_use` says which)
    revision: str | None
    bus: int | None
    address: int | None
    in_use: str | None = None


# libusb's shared libraries by the names their packages install them under: loaded by
# name, as the dynamic linker finds them, instead of pyusb's search (ctypes'
# find_library runs ldconfig and a compiler, a tenth of a second of every command)
LIBUSB1_NAMES = ("libusb-1.0.so.0", "libusb-1.0.so", "libusb-1.0.0.dylib", "libusb-1.0.dll")
LIBUSB0_NAMES = ("libusb-0.1.so.4", "libusb.so")


def _usb_backend():
    """pyusb's backend over the libusb found by name (None: none installed)."""
    import ctypes

    for names, module in ((LIBUSB1_NAMES, "libusb1"), (LIBUSB0_NAMES, "libusb0")):
        for name in names:
            try:
                ctypes.CDLL(name)
            except OSError:
                continue
            import importlib

            backend = importlib.import_module(f"usb.backend.{module}")
            found = backend.get_backend(find_library=lambda _name, lib=name: lib)
            if found is not None:
                return found
    return None


def _usb_devices():
    import usb.core

    backend = _usb_backend()
    if backend is None:
        raise NoPrinter("no USB backend: install libusb (Debian: libusb-1.0-0)")
    return list(usb.core.find(find_all=True, idVendor=VENDOR_ID, idProduct=PRODUCT_ID,
                              backend=backend))


def _connect(transport, timeout_ms: int, idle=None, take_over: bool = False) -> Printer:
    """A `Printer` on `transport` (closed again if the printer cannot be reached).
    `take_over`: a text host's unfinished line is ended first (`robox.host.textmode`)."""
    try:
        if take_over:
            from robox.host.textmode import take_over as taking_over

            return taking_over(transport, timeout_ms, idle)
        return Printer(transport, timeout_ms, idle=idle)
    except BaseException:
        transport.close()
        raise


def _open_usb(device, timeout_ms: int = DEFAULT_TIMEOUT_MS, take_over: bool = False
              ) -> Printer:
    import usb.core

    try:
        backend = getattr(getattr(device, "_ctx", None), "backend", None)
        lock = not getattr(backend, "virtual", False)
        return _connect(UsbTransport(device, lock=lock), timeout_ms, take_over=take_over)
    except usb.core.USBError as exc:
        if exc.errno in (errno.EACCES, errno.EPERM):
            raise PermissionDenied(permission_hint()) from None
        raise TransportError(f"USB error: {exc}") from None


def list_printers() -> list[Attached]:
    found = []
    for device in _usb_devices():
        try:
            printer = _open_usb(device)
        except InUse as exc:  # its port is locked: listed, not asked
            found.append(Attached(None, None, device.bus, device.address, str(exc)))
            continue
        try:
            found.append(Attached(printer.unique_id(), printer.revision(), device.bus,
                                  device.address))
        finally:
            printer.transport.close()
    return found


def _select_usb(prefix: str | None, timeout_ms: int = DEFAULT_TIMEOUT_MS,
                take_over: bool = False) -> Printer:
    devices = _usb_devices()
    if not devices:
        raise NoPrinter("no Robox is attached over USB (VID 16D0, PID 081B)")
    if prefix is None and len(devices) == 1:
        return _open_usb(devices[0], timeout_ms, take_over)
    matches, ids = [], []
    for device in devices:
        printer = _open_usb(device, timeout_ms, take_over)
        unique = printer.unique_id()
        ids.append(unique)
        if prefix is not None and unique.startswith(prefix):
            matches.append(printer)
        else:
            printer.transport.close()
    if prefix is None:
        raise NoPrinter(f"{len(devices)} printers are attached ({', '.join(ids)}); choose "
                        "one with --device usb:ID")
    if not matches:
        raise NoPrinter(f"no attached printer's unique ID starts with {prefix!r} "
                        f"(attached: {', '.join(ids) or 'none'})")
    if len(matches) > 1:
        raise NoPrinter(f"{prefix!r} matches {len(matches)} printers; give more of the ID")
    return matches[0]


@contextlib.contextmanager
def _sim(directory: Path, timeout_ms: int = DEFAULT_TIMEOUT_MS) -> Iterator[Printer]:
    import usb.core

    from robox.sim.printer import VirtualPrinter
    from robox.sim.usb_backend import VirtualRoboxBackend

    virtual = VirtualPrinter(directory)
    try:
        virtual.settle()  # power-up: the EEPROMs load, as on a printer switched on a moment ago
        backend = VirtualRoboxBackend(virtual)
        device = usb.core.find(idVendor=VENDOR_ID, idProduct=PRODUCT_ID, backend=backend)

        def idle(seconds: float) -> None:
            virtual.run_until(None, max(seconds, SIM_STEP_S))

        printer = Printer(UsbTransport(device), timeout_ms, idle=idle)
        printer.virtual = virtual
        printer.largest_file = largest_file(virtual.hw.card.capacity)
        yield printer
    finally:
        # the in-process printer is switched off after each command: a cooled head is
        # one that a printer left on would have by the next command
        virtual.cool_down()
        virtual.settle()
        virtual.close()


def _served(directory: Path, timeout_ms: int, announce=None, take_over: bool = False
            ) -> Printer:
    """The printer served for `directory` (started in the background if need be)."""
    from robox.sim import served

    record = served.ensure(directory, announce)
    printer = _connect(_served_transport(record), timeout_ms,
                       served_idle(record.get("speed")), take_over)
    printer.served = record
    with contextlib.suppress(OSError):  # its card's size, from its image's
        printer.largest_file = largest_file(
            (directory / "sdcard.img").stat().st_size // 1024 * 2)
    return printer


def _served_transport(record: dict):
    """The way in to a served printer: its Unix socket where it has one, else its pty
    (a printer served by an older robox, or in a directory whose path is too long for a
    socket's address)."""
    link = record.get("link")
    if link:
        try:
            return SocketTransport(link, record["pty"], spin=record.get("speed") is None)
        except TransportError:
            pass  # (the lock is not the trouble: that refusal is InUse, and stands)
    return SerialTransport(record["pty"])


def largest_file(capacity_blocks: int) -> int:
    """The most bytes a file on a card of `capacity_blocks` can have: a file may take
    every block but the directory's and one (the write that would reach its own first
    block is refused as too large)."""
    return max(0, capacity_blocks - 2) * BLOCK_SIZE


def served_idle(speed: float | None) -> Callable[[float], None]:
    """How a host lets a served printer's time pass. Paced (`speed` times the wall
    clock), the wait is the wall time that takes. Running fast, the printer's clock
    stops a little short of the moment it would count the host as gone, until the host
    asks again (`robox.sim.serve`): there the host's poll is what lets the time pass,
    so it asks again at once."""
    if speed is None:
        return lambda seconds: time.sleep(0)
    return lambda seconds: time.sleep(seconds / speed)


def _started(directory: Path) -> Callable[[dict], None]:
    def say(record: dict) -> None:
        from robox.sim.served import stop_hint

        print(f"robox-cli: started the virtual printer in the background (PID "
              f"{record['pid']}, {record['pty']}); {stop_hint(directory)} switches it off",
              file=sys.stderr)
    return say


def _half_command(exc: NoReply, printer: str, clear: str) -> NoReply:
    """`exc` (a printer that did not answer as it was opened), with the likeliest cause
    and its cure: the firmware keeps a command's first bytes until the rest come, or
    until the USB link goes down."""
    return NoReply(f"{exc}. If a program was cut off while it sent the printer a command, "
                   f"{printer} waits for the rest of it: {clear}")


@contextlib.contextmanager
def open_printer(spec: str | None, timeout_s: float = DEFAULT_TIMEOUT_MS / 1000,
                 take_over: bool = False) -> Iterator[Printer]:
    """The printer chosen by `spec` (default: $ROBOX_DEVICE, else `usb`); a reply not
    begun within `timeout_s` is an error (NoReply). With `take_over`, a printer a text
    host left in the middle of a line is taken over (`robox.host.textmode.take_over`)
    instead of refused."""
    timeout_ms = max(1, round(timeout_s * 1000))
    spec = spec or os.environ.get(ENVIRONMENT) or "usb"
    kind, _, rest = spec.partition(":")
    if kind in ("sim", "sim-once"):
        from robox.sim.served import default_state_dir

        directory = Path(os.path.abspath(rest)) if rest else default_state_dir()
        if kind == "sim-once":
            with _sim(directory, timeout_ms) as printer:
                yield printer
            return
        try:
            printer = _served(directory, timeout_ms, _started(directory), take_over)
        except NoReply as exc:
            from robox.sim.served import stop_hint

            raise _half_command(exc, "the virtual printer", f"{stop_hint(directory)} "
                                "switches it off, and the next command serves it afresh"
                                ) from None
    elif kind in ("usb", "serial"):
        if kind == "serial" and not rest:
            raise UsageError("serial needs a path: --device serial:/dev/ttyACM0")
        try:
            printer = _select_usb(rest or None, timeout_ms, take_over) if kind == "usb" \
                else _connect(SerialTransport(rest), timeout_ms, take_over=take_over)
        except NoReply as exc:
            raise _half_command(exc, "the printer", "unplug its USB cable and plug it back "
                                "in (or switch it off and on)") from None
    else:
        raise UsageError(f"unknown device {spec!r}: use usb, usb:ID, serial:PATH, sim, "
                         "sim:DIR, sim-once or sim-once:DIR")
    try:
        yield printer
    finally:
        printer.transport.close()
