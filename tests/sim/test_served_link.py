"""The served printer's Unix socket (robox.sim.serve, `link.sock`): the pty's byte stream
without the tty layer, for robox-cli's own `--device sim`. One host at a time, the pty's
lock shared with the pty's hosts, the pty alone where no socket can be made."""

import os
import select
import socket
import subprocess
import sys
import time

import pytest

from robox.formats.protocol import reply_length
from robox.host.devices import _served_transport, open_printer
from robox.host.transport import (
    Disconnected,
    NoReply,
    SerialTransport,
    SocketTransport,
)
from robox.locks import InUse, describe_pid
from robox.sim.printer import VirtualPrinter
from robox.sim.serve import LINK_NAME, PtyServer
from tests.sim import serving

CLI = [sys.executable, "-m", "robox.cli"]


@pytest.fixture
def linked(tmp_path):
    """A printer served in process with its socket in `tmp_path`."""
    server = PtyServer(VirtualPrinter(), None, link=str(tmp_path / LINK_NAME))
    server.printer.settle()
    yield server
    server.close()
    server.printer.close()


def connect(server: PtyServer) -> socket.socket:
    before = server.host
    host = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    host.connect(server.link)
    host.setblocking(False)
    for _ in range(100):  # until the server has taken it
        server.serve_once(timeout=0.01)
        if server.host is not None and server.host is not before:
            return host
    raise AssertionError("the server did not take the connection")


def ask_socket(server: PtyServer, host: socket.socket, frame: bytes) -> bytes:
    """`frame` written at the socket, served until its whole reply came back there."""
    host.sendall(frame)
    out, start = b"", time.monotonic()
    while reply_length(out) is None or len(out) < reply_length(out):
        assert time.monotonic() - start < 10, f"no reply to {frame[:1]!r}"
        server.serve_once(timeout=0.01)
        if select.select([host], [], [], 0)[0]:
            got = host.recv(4096)
            assert got, "the printer hung up"
            out += got
    return out


def test_the_socket_carries_the_ptys_bytes(linked):
    """The same command asked at the pty and at the socket: the same report, byte for
    byte (the error report: 0xE3 and its flags, all clear)."""
    over_pty, _ = serving.ask(linked, b"\xb3")
    host = connect(linked)
    try:
        over_socket = ask_socket(linked, host, b"\xb3")
    finally:
        host.close()
    assert over_pty[0] == 0xE3 and len(over_pty) == reply_length(over_pty)
    assert over_socket == over_pty
    assert not select.select([linked.slave], [], [], 0)[0]  # nothing went to the pty


def test_a_host_that_connects_takes_the_link_over(linked):
    first = connect(linked)
    second = connect(linked)
    try:
        assert first.recv(64) == b""  # hung up on: the new host has the printer
        assert ask_socket(linked, second, b"\xb3")[0] == 0xE3
    finally:
        first.close()
        second.close()


def test_a_host_gone_leaves_the_printer_to_the_pty(linked):
    host = connect(linked)
    host.close()
    for _ in range(100):
        linked.serve_once(timeout=0.01)
        if linked.host is None:
            break
    assert linked.host is None
    reply, _ = serving.ask(linked, b"\xb3")  # answered at the pty again
    assert reply[0] == 0xE3 and len(reply) == reply_length(reply)


def test_a_socket_host_holds_the_ptys_lock(linked):
    """A host at the socket locks the pty as one on the pty would: robox-cli on the pty is
    refused in one line naming the holder, and the reverse."""
    holder = SocketTransport(linked.link, linked.path)
    try:
        other = subprocess.run([*CLI, "--device", f"serial:{linked.path}", "status"],
                               capture_output=True, timeout=120)
        assert other.returncode == 1 and other.stdout == b""
        assert other.stderr.decode().splitlines() == [
            f"robox-cli: error: {linked.path} is in use by {describe_pid(os.getpid())}"]
    finally:
        holder.close()
    on_pty = SerialTransport(linked.path)
    try:
        with pytest.raises(InUse):
            SocketTransport(linked.link, linked.path)
    finally:
        on_pty.close()


def test_a_socket_read_waits_out_its_timeout_then_says_the_printer_went(linked):
    holder = SocketTransport(linked.link, linked.path)
    try:
        for _ in range(100):
            linked.serve_once(timeout=0.01)
            if linked.host is not None:
                break
        started = time.monotonic()
        with pytest.raises(NoReply):
            holder.read(64, 200)  # nothing asked, nothing said
        assert 0.19 <= time.monotonic() - started < 5
        linked._hang_up()
        with pytest.raises(Disconnected):
            holder.read(64, 2000)
    finally:
        holder.close()


def test_a_directory_too_long_for_a_socket_is_served_on_the_pty_alone(tmp_path):
    deep = tmp_path / ("d" * 60) / ("e" * 60)
    deep.mkdir(parents=True)
    path = str(deep / LINK_NAME)
    assert len(path.encode()) > 108  # beyond any socket address's room
    server = PtyServer(VirtualPrinter(), None, link=path)
    try:
        assert server.link is None and server.listener is None
        transport = _served_transport({"pty": server.path, "link": server.link})
        try:
            assert isinstance(transport, SerialTransport)
        finally:
            transport.close()
    finally:
        server.close()
        server.printer.close()


def test_robox_cli_reaches_a_served_printer_through_its_socket(tmp_path):
    state = tmp_path / "printer"
    with serving.served(state):
        assert (state / LINK_NAME).exists()
        with open_printer(f"sim:{state}") as printer:
            assert isinstance(printer.transport, SocketTransport)
            assert printer.transport._fd is not None
            assert printer.status().eeproms["head"] == "valid"
        status = subprocess.run([*CLI, "--device", f"sim:{state}", "status", "--json"],
                                capture_output=True, timeout=120)
        assert status.returncode == 0, status.stderr.decode()
    assert not (state / LINK_NAME).exists()  # switched off: gone with the server


def test_a_host_looks_for_its_reply_before_it_sleeps_only_where_that_pays(linked,
                                                                          monkeypatch):
    """The host's read looks again and again (SPIN_S) on a printer that runs as fast as
    its work needs, with another processor to run it on; not on a paced printer, whose
    replies take its own time, nor with one processor, which the printer needs."""
    from robox.host import transport

    def spin_of(record: dict) -> float:
        made = _served_transport(record)
        try:
            assert isinstance(made, SocketTransport)
            return made._spin
        finally:
            made.close()

    fast = {"pty": linked.path, "link": linked.link, "speed": None}
    monkeypatch.setattr(transport, "_processors", lambda: 2)
    assert spin_of(fast) == SocketTransport.SPIN_S > 0
    assert spin_of({**fast, "speed": 10.0}) == 0
    monkeypatch.setattr(transport, "_processors", lambda: 1)
    assert spin_of(fast) == 0


def test_a_fast_server_looks_for_its_socket_hosts_next_command_before_it_sleeps(
        linked, monkeypatch):
    """For HOST_SPIN_S after handing a host at the socket a whole reply, the server looks
    for its next command without sleeping; otherwise (no reply lately, a host on the pty,
    a paced printer) it sleeps in one select() for as long as it may wait."""
    from robox.sim import serve

    host = connect(linked)
    try:
        ask_socket(linked, host, b"\xb3")
        sleeps: list[float] = []
        real_select = select.select

        def counted(r, w, x, timeout):
            sleeps.append(timeout)
            return real_select(r, w, x, timeout)

        monkeypatch.setattr(serve.select, "select", counted)
        watched = [linked.master, linked.listener, linked.host]
        linked._answered = time.monotonic()
        assert linked._look(watched, 0.05) == []
        assert len(sleeps) > 1 and set(sleeps) == {0}  # looked, never slept
        sleeps.clear()
        linked._answered = time.monotonic() - 2 * serve.HOST_SPIN_S
        assert linked._look(watched, 0.05) == []
        assert sleeps == [0.05]  # no reply lately: one sleep
        sleeps.clear()
        linked._answered = time.monotonic()
        host.sendall(b"\xb3")
        assert linked._look(watched, 0.05) == [linked.host]  # found while looking
        assert set(sleeps) == {0}
        sleeps.clear()
        linked.speed = 1.0
        linked._answered = time.monotonic()
        linked._look(watched, 0.01)
        assert sleeps == [0.01]  # paced: the reply's host waits on the printer's time
    finally:
        host.close()


def test_a_host_cut_off_inside_a_command_leaves_the_printer_waiting_and_the_cli_says_so(
        tmp_path):
    """A host gone with half a command sent (killed inside its write) leaves the printer
    waiting for the rest, as the real one does (tests/firmware/test_usb_down.py). The
    next robox-cli says, in one line, what clears it; a printer served afresh answers."""
    state = tmp_path / "printer"
    with serving.served(state) as pty:
        host = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        host.connect(str(state / LINK_NAME))
        host.sendall(b"\x91" + b"00000000" + b"x" * 100)  # 109 of a chunk's 521 bytes
        host.close()
        said = {}
        for device in (f"sim:{state}", f"serial:{pty}"):
            stuck = subprocess.run([*CLI, "--timeout", "1", "--device", device, "status"],
                                   capture_output=True, text=True, timeout=120)
            assert stuck.returncode == 1
            said[device.split(":")[0]] = stuck.stderr.strip()
        assert all(len(text.splitlines()) == 1 for text in said.values())
        assert said["sim"] == (
            "robox-cli: error: the printer did not answer. If a program was cut off while "
            "it sent the printer a command, the virtual printer waits for the rest of it: "
            f"`robox-cli sim stop --state {state}` switches it off, and the next command "
            "serves it afresh")
        assert said["serial"].endswith(
            "the printer waits for the rest of it: unplug its USB cable and plug it back in "
            "(or switch it off and on)")
    try:
        again = subprocess.run([*CLI, "--device", f"sim:{state}", "status", "--json"],
                               capture_output=True, text=True, timeout=120)
        assert again.returncode == 0, again.stderr
    finally:
        subprocess.run([*CLI, "sim", "stop", "--state", str(state)], capture_output=True,
                       timeout=120)
