"""Byte transports to a printer: USB through pyusb (a real Robox, or the virtual one through
its pyusb backend), serial through pyserial (/dev/ttyACM*, or a virtual printer's pty),
and a served virtual printer's Unix socket (robox.sim.serve).

Both read and write raw bytes; framing and stop-and-wait live in the client.
Failures become robox.errors types a user can act on.
"""

from __future__ import annotations

import errno
import os
import select
import time
from array import array
from pathlib import Path

from robox.errors import RoboxError
from robox.locks import lock_port, port_lock

try:
    from termios import error as _termios_error
    from termios import tcdrain as _tcdrain

    _TTY_ERRORS: tuple[type[Exception], ...] = (_termios_error,)
except ImportError:  # pragma: no cover - a system without termios (Windows)
    _TTY_ERRORS = ()
    _tcdrain = None

try:  # the C module: `socket` itself makes enums of every constant, some 4 ms of each
    # command's start, for the one socket a served printer's host opens
    import _socket as sockets
except ImportError:  # pragma: no cover - an interpreter without it
    import socket as sockets  # type: ignore[no-redef]

VENDOR_ID = 0x16D0
PRODUCT_ID = 0x081B
DATA_INTERFACE = 1


class TransportError(RoboxError):
    """The link to the printer failed."""


class Disconnected(TransportError):
    """The printer went away (unplugged, powered off)."""


class NoReply(TransportError):
    """The printer did not answer in time."""


class PermissionDenied(TransportError):
    """The operating system refused access to the printer."""


def permission_hint() -> str:
    rule = Path(__file__).resolve().parent.parent / "data" / "60-robox.rules"
    return ("permission denied opening the printer: install the udev rule shipped as "
            f"{rule} (see README, 'Using a printer without root')")


class _PortLock:
    """The port's lock, taken before the port is opened (robox.locks.port_lock)."""

    _lock: int | None = None

    def _unlock(self) -> None:
        if self._lock is not None:
            os.close(self._lock)
            self._lock = None


def _bulk_calls(device):
    """The backend's own bulk transfers and the device's open handle, where this pyusb
    keeps them where its Device.read and Device.write find them (None otherwise).

    Those two methods do the same bookkeeping at every transfer: six calls that take
    the device's lock, the endpoint's interface looked up, the interface claimed if it
    is not, the data copied into an array. For a Robox that is the same interface and
    the same two endpoints every time, claimed once when the transport opens: what is
    left is the backend's call, which the transport makes itself. Measured on an
    in-process printer, the bookkeeping was a sixth of the CPU time of a whole print
    (`send-job --wait`)."""
    ctx = getattr(device, "_ctx", None)
    backend = getattr(ctx, "backend", None)
    handle = getattr(ctx, "handle", None)
    write = getattr(backend, "bulk_write", None)
    read = getattr(backend, "bulk_read", None)
    if handle is None or not callable(write) or not callable(read):
        return None
    return write, read, handle


class UsbTransport(_PortLock):
    """Bulk endpoints of the Robox's CDC data interface, through pyusb. Once the interface
    is claimed, each transfer is the backend's bulk transfer on its open handle (see
    _bulk_calls), or Endpoint.write and Endpoint.read where this pyusb keeps those
    elsewhere."""

    #: the backend's bulk calls and handle (_bulk_calls); None: through the endpoints
    _direct: tuple | None = None

    def __init__(self, device, lock: bool = False):
        """`lock`: take the device's port lock first (a real printer; a virtual one is
        locked by its state directory)."""
        import usb.core
        import usb.util

        self._usb = usb
        self.device = device
        self._lock = None
        if lock:
            self._lock = port_lock(f"the printer on USB bus {device.bus} address "
                                   f"{device.address}",
                                   key=f"usb-{device.bus}-{device.address}")
        try:
            self._claim(device)
        except BaseException:
            self._unlock()
            raise

    def _claim(self, device) -> None:
        usb = self._usb
        try:
            for interface in (0, DATA_INTERFACE):
                if device.is_kernel_driver_active(interface):
                    device.detach_kernel_driver(interface)
            try:
                device.set_configuration()
            except usb.core.USBError as exc:
                if exc.errno != errno.EBUSY:
                    raise
            usb.util.claim_interface(device, DATA_INTERFACE)
            setting = device.get_active_configuration()[(DATA_INTERFACE, 0)]
            self.ep_out = usb.util.find_descriptor(setting, custom_match=lambda e:
                                                   usb.util.endpoint_direction(
                                                       e.bEndpointAddress) ==
                                                   usb.util.ENDPOINT_OUT)
            self.ep_in = usb.util.find_descriptor(setting, custom_match=lambda e:
                                                  usb.util.endpoint_direction(
                                                      e.bEndpointAddress) ==
                                                  usb.util.ENDPOINT_IN)
        except usb.core.USBError as exc:
            raise self._translate(exc) from None
        if self.ep_out is None or self.ep_in is None:
            raise TransportError("the USB device has no bulk endpoints: not a Robox?")
        self._out_address = self.ep_out.bEndpointAddress
        self._in_address = self.ep_in.bEndpointAddress
        self._direct = _bulk_calls(device)
        #: the arrays the backend reads into, one per size (a transfer copies out what
        #: it got, so the next one may fill the same array)
        self._buffers: dict[int, array] = {}

    def _translate(self, exc) -> TransportError:
        code = getattr(exc, "errno", None)
        if code in (errno.EACCES, errno.EPERM):
            return PermissionDenied(permission_hint())
        if code in (errno.ENODEV, errno.EIO, errno.EPIPE) or \
                getattr(exc, "backend_error_code", None) == -4:
            return Disconnected("the printer was disconnected")
        if isinstance(exc, self._usb.core.USBTimeoutError) or code == errno.ETIMEDOUT:
            return NoReply("the printer did not answer")
        return TransportError(f"USB error: {exc}")

    def write(self, data: bytes, timeout_ms: int = 5000) -> None:
        try:
            if self._direct is None:
                self.ep_out.write(data, timeout_ms)
            else:
                write, _, handle = self._direct
                write(handle, self._out_address, DATA_INTERFACE, array("B", data),
                      timeout_ms)
        except self._usb.core.USBError as exc:
            raise self._translate(exc) from None

    def read(self, limit: int, timeout_ms: int = 5000) -> bytes:
        try:
            if self._direct is None:
                return bytes(self.ep_in.read(max(limit, 64), timeout_ms))
            _, read, handle = self._direct
            size = max(limit, 64)
            buffer = self._buffers.get(size)
            if buffer is None:
                buffer = self._buffers[size] = array("B", bytes(size))
            count = read(handle, self._in_address, DATA_INTERFACE, buffer, timeout_ms)
            data = buffer.tobytes()
            return data if count == size else data[:count]
        except self._usb.core.USBError as exc:
            raise self._translate(exc) from None

    def close(self) -> None:
        self._direct = None  # (the handle goes with the device's resources)
        try:
            self._usb.util.release_interface(self.device, DATA_INTERFACE)
            self._usb.util.dispose_resources(self.device)
        except self._usb.core.USBError:
            pass
        finally:
            self._unlock()


class SerialTransport(_PortLock):
    """A serial port: a printer's /dev/ttyACM*, or a virtual printer's pty.

    pyserial opens, configures and closes the port. Where the port is a POSIX tty, the
    bytes go through its descriptor (Serial.fileno(), there for select()): a write is
    os.write then tcdrain, what pyserial's write and flush() do; a read is select then
    os.read, what pyserial's read does, without the timeout objects and the
    in_waiting ioctl it adds to every call (a third of the host's time with a
    printer served in the background, 28k transactions for the 427k-line plate)."""

    #: how long a write may wait for the port to take its bytes (pyserial's write_timeout)
    WRITE_TIMEOUT_S = 5.0

    def __init__(self, path: str):
        import serial

        self._serial = serial
        # locked before it is opened: opening a tty flushes what it has received, which
        # may be the reply the port's holder is waiting for
        self._lock = port_lock(path)
        try:
            self.port = serial.Serial(path, 115200, timeout=0.05,
                                      write_timeout=self.WRITE_TIMEOUT_S)
        except serial.SerialException as exc:
            self._unlock()
            if isinstance(exc.__context__, PermissionError) or "ermission" in str(exc):
                raise PermissionDenied(f"{path}: {permission_hint()}") from None
            raise TransportError(f"{path}: cannot open: {exc.strerror or exc}") from None
        except BaseException:
            self._unlock()
            raise
        try:
            lock_port(self.port.fileno(), path)  # for other programs that lock the device
        except BaseException:
            self.port.close()
            self._unlock()
            raise
        #: the tty's descriptor (pyserial opened it non-blocking); None: through pyserial
        self._fd: int | None = self.port.fileno() if _tcdrain is not None else None

    def write(self, data: bytes, timeout_ms: int = 5000) -> None:
        try:
            if self._fd is None:
                self.port.write(data)
                self.port.flush()
                return
            _write_all(self._fd, memoryview(data), self.WRITE_TIMEOUT_S)
            _tcdrain(self._fd)
        except (self._serial.SerialException, OSError, *_TTY_ERRORS):
            # (the drain is termios.tcdrain, whose error is no OSError: a port gone
            # between the write and the drain, an unplugged printer's or a killed
            # server's pty, fails there with EIO)
            raise Disconnected("the printer was disconnected") from None

    def read(self, limit: int, timeout_ms: int = 5000) -> bytes:
        if self._fd is not None:
            return _read_some(self._fd, limit, timeout_ms)
        end = time.monotonic() + timeout_ms / 1000.0
        while True:
            try:
                data = self.port.read(min(limit, max(1, self.port.in_waiting)))
            except (self._serial.SerialException, OSError):
                raise Disconnected("the printer was disconnected") from None
            if data:
                return data
            if time.monotonic() >= end:
                raise NoReply("the printer did not answer")

    def close(self) -> None:
        try:
            self.port.close()
        finally:
            self._unlock()


class SocketTransport(_PortLock):
    """A served virtual printer through its Unix socket (robox.sim.serve): the bytes its
    pty carries, without the tty layer. The pty `port` is locked as SerialTransport
    locks it (the lock file first, then the open port's own lock, for programs that
    lock the device), so the printer has one host whichever way in it uses.

    A read first looks for the reply again and again for up to SPIN_S, and only then
    sleeps in select(), where another processor can run the printer meanwhile: a served
    printer answers most commands within that, and waking a sleeping reader costs more
    than the wait (the kernel's wakeup, and on a virtual machine an interrupt between
    processors). On one processor the printer needs this one's time, so it sleeps at
    once; so it does with `spin` False (a printer paced to the wall clock, whose replies
    take the printer's own time)."""

    WRITE_TIMEOUT_S = SerialTransport.WRITE_TIMEOUT_S
    SPIN_S = 0.0005

    def __init__(self, path: str, port: str, spin: bool = True):
        self._lock = port_lock(port)
        self._port_fd: int | None = None
        self._socket: sockets.socket | None = None
        try:
            try:
                self._port_fd = os.open(port, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK
                                        | os.O_CLOEXEC)
            except OSError as exc:
                raise TransportError(f"{port}: cannot open: {exc.strerror}") from None
            lock_port(self._port_fd, port)
            self._socket = sockets.socket(sockets.AF_UNIX, sockets.SOCK_STREAM)
            self._socket.settimeout(self.WRITE_TIMEOUT_S)  # (a server that never takes it)
            try:
                self._socket.connect(path)
            except OSError as exc:
                raise TransportError(f"{path}: cannot connect: {exc.strerror}") from None
            self._socket.setblocking(False)
            self._fd = self._socket.fileno()
        except BaseException:
            self.close()
            raise
        self._spin = self.SPIN_S if spin and _processors() > 1 else 0.0

    def write(self, data: bytes, timeout_ms: int = 5000) -> None:
        try:
            _write_all(self._fd, memoryview(data), self.WRITE_TIMEOUT_S)
        except OSError:
            raise Disconnected("the printer was disconnected") from None

    def read(self, limit: int, timeout_ms: int = 5000) -> bytes:
        if self._spin:
            fd = self._fd
            end = time.perf_counter() + self._spin
            while True:
                try:
                    data = os.read(fd, limit)
                except BlockingIOError:
                    if time.perf_counter() < end:
                        continue
                    break
                except OSError:
                    raise Disconnected("the printer was disconnected") from None
                if not data:
                    raise Disconnected("the printer was disconnected")
                return data
        return _read_some(self._fd, limit, timeout_ms)

    def close(self) -> None:
        try:
            if self._socket is not None:
                self._socket.close()
                self._socket = None
            if self._port_fd is not None:
                os.close(self._port_fd)
                self._port_fd = None
        finally:
            self._unlock()


def _processors() -> int:
    """How many processors this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # (a system without affinities)
        return os.cpu_count() or 1


def _write_all(fd: int, view: memoryview, timeout_s: float) -> None:
    """Write all of `view` to the non-blocking `fd`, waiting at most `timeout_s` in all
    while it takes nothing (then OSError ETIMEDOUT)."""
    end = time.monotonic() + timeout_s
    while view:
        try:
            done = os.write(fd, view)
        except BlockingIOError:
            done = 0
        if done:
            view = view[done:]
            continue
        left = end - time.monotonic()
        if left <= 0.0 or not select.select([], [fd], [], left)[1]:
            raise OSError(errno.ETIMEDOUT, "the port took nothing")


def _read_some(fd: int, limit: int, timeout_ms: int) -> bytes:
    """What the non-blocking `fd` has, once it has something (at most `limit` bytes);
    NoReply when nothing came within `timeout_ms`, Disconnected when its other end went."""
    end = time.monotonic() + timeout_ms / 1000.0
    while True:
        try:
            if select.select([fd], [], [], max(0.0, end - time.monotonic()))[0]:
                data = os.read(fd, limit)
                if not data:  # readable, and nothing to read: the other end hung up
                    raise OSError(errno.EIO, "the port hung up")
                return data
        except OSError:
            raise Disconnected("the printer was disconnected") from None
        if time.monotonic() >= end:
            raise NoReply("the printer did not answer")
