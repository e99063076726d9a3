"""Serve a virtual printer on a pseudo-terminal, as a real printer's /dev/ttyACM* appears.

The simulated clock either runs as fast as the work needs (jumping over waits,
standing still while nothing is pending), or is paced to the wall clock
(`speed` 1 = real time, 10 = ten times faster). Real time lives here only.

Running fast, the clock still waits for a connected host: the printer counts a
host as connected only if it asked for the error report within the last 5 s of
the printer's time, so while one is, the clock stops `FAST_SLICE_S` short of
that lapse until the host speaks again (or has said nothing for
`HOST_QUIET_S` of wall time, when it is taken to have gone). A command that
arrives while the clock is held is still answered: the clock may then run on
to `REPLY_MARGIN_S` short of the lapse, enough for any command that does not
itself wait on the printer. A host polling twice a second stays connected, as
with a real printer. Nothing holds the clock while bytes the host wrote are still
on their way in (crossing the bus, or landed and not yet taken): the host has
spoken, and what it said (its next poll, say) can only arrive by the clock
running on. A printer that does not take them (a deaf receiver) then runs on
and, 5 s later, counts the host as gone, as the real one would.

Running fast, the clock also waits for a live host's next chunk when a job printing
that very upload comes within `UPLOAD_MARGIN` bytes of its end (see _reader_margin):
a real host stores far faster than the printer prints, so a real print does not
meet the end of an upload still coming in.

Beside the pty the printer listens on a Unix socket in its state directory (`LINK_NAME`,
its path in the lock record as "link"): the same byte stream as the pty's, one host
at a time, for robox-cli's own commands (`--device sim`), without the tty layer's
work on every round trip (a kernel work item for each write's buffer, and the flush
of pending ones on each look).
While a host is connected there the printer's replies go to it, and what arrives on
the pty is still taken in, as from a second program on one serial port: the port's
lock (robox.locks.port_lock on the pty), which that host holds, keeps robox-cli's
programs from doing that. A host that connects takes the link over from one before
it (gone, whose lock it now holds): bytes still owed to the old one are dropped, as
a tty drops what an earlier holder left unread. Running fast, for `HOST_SPIN_S` after
handing that host a whole reply the server looks for its next command without
sleeping (see _look), as the host looks for its replies (SocketTransport): a round
trip then wakes neither.
"""

from __future__ import annotations

import contextlib
import os
import select
import signal
import socket
import sys
import time
import traceback
import tty

from robox.errors import RoboxError
from robox.firmware.command import HOST_CONNECTED_S
from robox.firmware.main import PASS_S
from robox.sim import served
from robox.sim.printer import VirtualPrinter

READ_SIZE = 4096
FAST_SLICE_S = 1.0
HOST_QUIET_S = 2.0
REPLY_MARGIN_S = 0.1
UPLOAD_MARGIN = 2 * 512  # bytes: two of an upload's chunks
HOST_SPIN_S = 0.0005
LINK_NAME = "link.sock"


def listen(path: str) -> socket.socket | None:
    """A listening Unix socket at `path` (a stale one there is replaced), or None where
    none can be made (a path too long for a socket's address, a file system without
    sockets): the pty alone then serves."""
    with contextlib.suppress(FileNotFoundError):
        os.unlink(path)
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        listener.bind(path)
        os.chmod(path, 0o600)
        listener.listen(2)
    except OSError:
        listener.close()
        return None
    listener.setblocking(False)
    return listener


class PtyServer:
    def __init__(self, printer: VirtualPrinter, speed: float | None = None,
                 console=None, link: str | None = None):
        self.printer = printer
        self.console = console  # where the printer's own notices go (sim serve: stderr)
        self._events_seen = 0
        self.speed = speed
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        os.set_blocking(self.master, False)
        self.path = os.ttyname(self.slave)
        #: the Unix socket hosts may connect to instead (None: the pty alone)
        self.listener = listen(link) if link else None
        self.link = link if self.listener is not None else None
        self.host: socket.socket | None = None  # the host connected there
        self.stopping = False
        self._pending_out = bytearray()
        self._last_input = 0.0
        self._reply_owed = False  # the host wrote and has had nothing back yet
        self._answered = 0.0  # when (wall) the host last had a whole reply
        self._upload_length = -1  # of an upload that a job prints as it comes
        self._upload_grew = 0.0  # when (wall) that upload last grew
        self.start_pacing()

    def stop(self, *_args) -> None:
        self.stopping = True

    def _pump_input(self, fd: int) -> None:
        try:
            data = os.read(fd, READ_SIZE)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            data = b""
        if not data:
            if self.host is not None and fd == self.host.fileno():
                self._hang_up()  # the host at the socket went
            return
        self.printer.usb.host_write(data)
        self._last_input = time.monotonic()
        self._reply_owed = True

    def _accept(self) -> None:
        """A host connects at the socket: it takes the link over (see the docstring)."""
        if self.listener is None:
            return
        try:
            host, _ = self.listener.accept()
        except OSError:  # (gone again before it was taken, or nothing there after all)
            return
        host.setblocking(False)
        self._hang_up()
        self.host = host

    def _hang_up(self) -> None:
        if self.host is not None:
            self.host.close()
            self.host = None
            self._pending_out.clear()

    def _pump_output(self) -> bool:
        """Hand the host what the printer sent; True when a reply went out whole."""
        usb = self.printer.usb
        replied = False
        while usb.reply_waiting:
            self._pending_out += usb.host_read(READ_SIZE)
            self._reply_owed = False
            replied = True
        fd = self.master if self.host is None else self.host.fileno()
        while self._pending_out:
            try:
                written = os.write(fd, self._pending_out)
            except (BlockingIOError, InterruptedError):
                return False
            except OSError:
                self._pending_out.clear()  # nobody is listening
                if fd != self.master:
                    self._hang_up()
                return False
            del self._pending_out[:written]
        if replied:
            self._answered = time.monotonic()
        return replied

    def _run_fast(self) -> None:
        """Fast: run the firmware on, at most FAST_SLICE_S, never past the host's turn
        and not into the end of an upload its host is still sending (see _reader_margin)."""
        fw = self.printer.firmware
        margin = self._reader_margin()
        if margin and fw.reader_near_upload_end(margin):
            return
        turn = self._host_turn()
        until = fw.clock.now + FAST_SLICE_S if turn is None else min(
            fw.clock.now + FAST_SLICE_S, turn)
        self.printer.run_for_host(until - fw.clock.now, margin)

    def _reader_margin(self) -> int:
        """Fast: how close a job printing its own upload may come to the upload's end
        while the host sending it is live (0: no limit). A real host stores a chunk far
        sooner than the printer prints one, so the print never meets the end of what is
        stored; a clock that runs free between the host's commands would meet it, and
        pause the job, again and again. So the clock waits for the host's next chunk
        instead, for as long as the upload grew within the last `HOST_QUIET_S` of wall
        time (then the host is taken to have stopped, and the job catches up and pauses
        as on the real printer)."""
        written = self.printer.firmware.file_system.upload_length()
        if written < 0:
            self._upload_length = -1
            return 0
        now = time.monotonic()
        if written != self._upload_length:
            self._upload_length, self._upload_grew = written, now
        return UPLOAD_MARGIN if now - self._upload_grew <= HOST_QUIET_S else 0

    def _host_turn(self) -> float | None:
        """Fast mode: the printer time at which a connected host must be heard from
        again (None when no host is connected, it has gone quiet, or what it wrote
        is still on its way in)."""
        command = self.printer.firmware.command
        usb = self.printer.usb
        if not command.host_connected() or usb.arriving or usb.received or \
                time.monotonic() - self._last_input > HOST_QUIET_S:
            return None
        margin = REPLY_MARGIN_S if self._reply_owed else FAST_SLICE_S
        return command.last_ack_report + HOST_CONNECTED_S - margin

    def serve_once(self, timeout: float = 0.05) -> None:
        """Wait for the host (at most `timeout` s), then run the firmware."""
        fw = self.printer.firmware
        watched: list = [self.master]
        if self.listener is not None:
            watched.append(self.listener)
            if self.host is not None:
                watched.append(self.host)
        readable = self._look(watched, self._wait(timeout))
        for source in readable:
            if source is self.listener:
                self._accept()
            else:
                self._pump_input(source if isinstance(source, int) else source.fileno())
        if self.speed is None:
            self._run_fast()
            if self._pump_output() and fw.working():
                # the host has its reply and is writing its next command: run on
                # meanwhile, rather than look at once for what it cannot have sent yet
                self._run_fast()
        else:
            # whole passes only, the clock less than one behind the wall's: each pass
            # lets one packet of the host's across the bus, whatever its length
            target = self._paced_now()
            while fw.clock.now + PASS_S <= target:
                self.printer.run_pass(*fw.plan(target - fw.clock.now))
                if self.printer.usb.reply_waiting:
                    self._pump_output()
        self._pump_output()
        self._tell_console()

    def _look(self, watched: list, wait: float) -> list:
        """select() on `watched` for up to `wait` s. Fast, with a host at the socket that
        had a whole reply less than HOST_SPIN_S ago, it looks again and again first, up
        to then: that host's next command is likely on its way, and sleeping until it
        comes costs a wakeup (see SocketTransport, which looks for its replies so)."""
        if wait > 0.0 and self.host is not None and self.speed is None:
            end = self._answered + HOST_SPIN_S
            if end > time.monotonic():
                end = min(end, time.monotonic() + wait)
                while True:
                    readable = select.select(watched, [], [], 0)[0]
                    if readable or time.monotonic() >= end:
                        return readable
        return select.select(watched, [], [], wait)[0]

    def start_pacing(self) -> None:
        """Paced: the printer's time and the wall's run on together from now."""
        self._sim_start = self.printer.firmware.clock.now
        self._wall_start = time.monotonic()

    def _paced_now(self) -> float:
        """Paced: the printer time that the wall clock says it is."""
        return self._sim_start + (time.monotonic() - self._wall_start) * self.speed

    def _wait(self, timeout: float) -> float:
        """How long to wait for the host before running the firmware again: not at all
        while it works with its clock free (fast), until its next pass is due (paced,
        working: a transfer crossing the bus takes a pass a packet), else `timeout`."""
        fw = self.printer.firmware
        if not fw.working():
            return timeout
        if self.speed is None:
            margin = self._reader_margin()
            if margin and fw.reader_near_upload_end(margin):
                return timeout  # the clock waits for the host's next chunk
            turn = self._host_turn()
            return timeout if turn is not None and fw.clock.now >= turn else 0.0
        due = (fw.clock.now + PASS_S - self._paced_now()) / self.speed
        return min(timeout, max(0.0, due))

    def _tell_console(self) -> None:
        """Say what a person at the printer should know (a deaf receiver, say)."""
        fw = self.printer.firmware
        events = fw.events
        if fw.events is not getattr(self, "_events_list", None):  # a reset starts afresh
            self._events_list, self._events_seen = events, 0
        for kind, detail in events[self._events_seen :]:
            if kind == "deaf" and self.console is not None:
                self.console(f"robox sim: {detail}")
        self._events_seen = len(events)

    def serve(self) -> None:
        self.start_pacing()
        while not self.stopping:
            self.serve_once()

    def close(self) -> None:
        self._hang_up()
        if self.listener is not None:
            self.listener.close()
            if self.link is not None:
                with contextlib.suppress(OSError):
                    os.unlink(self.link)
        os.close(self.master)
        os.close(self.slave)


class ModelFault(RoboxError):
    """The firmware model raised while serving (a bug; its traceback went to the console)."""


def serve_forever(state_dir, speed: float | None, announce, console=None) -> None:
    """Serve until SIGINT or SIGTERM, then leave every state file consistent."""
    state_dir = os.path.abspath(state_dir)
    printer = VirtualPrinter(state_dir, role="serve")
    try:
        server = PtyServer(printer, speed, console, os.path.join(state_dir, LINK_NAME))
    except BaseException:
        printer.close()
        raise
    previous = {sig: signal.signal(sig, server.stop) for sig in (signal.SIGINT, signal.SIGTERM)}
    faulted = False
    try:
        # power-up: the EEPROMs load before a host is told where to connect, as for a
        # printer in this process (sim-once); a host asking at once sees them read
        printer.settle()
        printer.lock.update(pty=server.path, link=server.link,
                            started=round(time.time(), 3), speed=speed)
        served.add_note(printer.state_dir)
        announce(server.path)
        server.serve()
    except Exception as exc:  # a bug in the model: say so, keep what was committed
        faulted = True
        report = console or (lambda message: print(message, file=sys.stderr))
        report(f"robox sim: fault in the firmware model at t={printer.firmware.clock.now:.3f}s: "
               f"{type(exc).__name__}: {exc}")
        for line in traceback.format_exc().rstrip().splitlines():
            report(f"robox sim:   {line}")
        raise ModelFault(f"the firmware model failed ({type(exc).__name__}: {exc}); "
                         "the state files hold what was committed before it") from None
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        if not faulted:
            printer.settle()
        served.remove_note(printer.state_dir)
        server.close()
        printer.close()  # last: it releases the state directory's lock
