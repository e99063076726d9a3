"""Device selection and USB faults, with virtual printers standing in for attached ones."""

import errno
import os
import termios

import pytest
import usb.core
from click.testing import CliRunner

from robox.cli import cli
from robox.host import devices
from robox.host.transport import (
    Disconnected,
    NoReply,
    PermissionDenied,
    SerialTransport,
    UsbTransport,
)
from robox.sim.printer import VirtualPrinter
from robox.sim.usb_backend import VirtualRoboxBackend
from tests.cli.test_sdcard_cli import one_line_error


def attached(unique_id: bytes):
    virtual = VirtualPrinter()
    virtual.hw.flash.write_page(511, unique_id.ljust(256, b"\0"))
    virtual.firmware.power_up()
    virtual.settle()
    backend = VirtualRoboxBackend(virtual)
    return usb.core.find(idVendor=0x16D0, idProduct=0x081B, backend=backend), virtual


@pytest.fixture
def two(monkeypatch):
    found = [attached(b"RBX-AAA-0001"), attached(b"RBX-BBB-0002")]
    monkeypatch.setattr(devices, "_usb_devices", lambda: [d for d, _ in found])
    return found


def run(*args):
    return CliRunner().invoke(cli, list(args), catch_exceptions=False)


def test_printers_lists_unique_ids_and_revisions(two):
    out = run("printers").output
    assert "RBX-AAA-0001  firmware r776sim" in out and "RBX-BBB-0002" in out


def test_several_printers_need_a_choice(two):
    one_line_error(run("--device", "usb", "status"), 1, "2 printers are attached")
    assert run("--device", "usb:RBX-BBB", "files").exit_code == 0
    one_line_error(run("--device", "usb:RBX-CCC", "status"), 1, "no attached printer")
    one_line_error(run("--device", "usb:RBX", "status"), 1, "matches 2 printers")


def test_one_printer_needs_no_choice(monkeypatch):
    device, _ = attached(b"RBX-ONLY")
    monkeypatch.setattr(devices, "_usb_devices", lambda: [device])
    assert "FIRMWARE_NAME" in run("--device", "usb", "gcode", "M115").output


def test_the_environment_chooses_the_device(two, monkeypatch):
    monkeypatch.setenv("ROBOX_DEVICE", "usb:RBX-AAA")
    assert run("files").exit_code == 0


def test_no_printer_attached(monkeypatch):
    monkeypatch.setattr(devices, "_usb_devices", lambda: [])
    one_line_error(run("status"), 1, "no Robox is attached")


class Locked(VirtualRoboxBackend):
    def claim_interface(self, dev_handle, intf):
        raise usb.core.USBError("Access denied (insufficient permissions)", -3, errno.EACCES)


def test_permission_denied_names_the_udev_rule():
    backend = Locked(VirtualPrinter())
    device = usb.core.find(idVendor=0x16D0, idProduct=0x081B, backend=backend)
    with pytest.raises(PermissionDenied, match=r"60-robox\.rules"):
        UsbTransport(device)


def test_unplugged_mid_upload_says_how_to_resume(monkeypatch, tmp_path):
    device, virtual = attached(b"RBX-PULL")
    monkeypatch.setattr(devices, "_usb_devices", lambda: [device])
    writes = [0]
    original = VirtualRoboxBackend.bulk_write

    def pull_the_cable(self, *args):
        writes[0] += 1
        if writes[0] == 6:  # errors query, start, chunks 0..2, then chunk 3
            self.printer.usb.disconnect()
        return original(self, *args)

    monkeypatch.setattr(VirtualRoboxBackend, "bulk_write", pull_the_cable)
    job = tmp_path / "big.gcode"
    job.write_text("G1 X1 E0.1 F600\n" * 400)
    one_line_error(run("--device", "usb", "send-job", str(job)), 1, "--resume")
    virtual.usb.connect()
    monkeypatch.setattr(VirtualRoboxBackend, "bulk_write", original)
    result = run("--device", "usb", "send-job", str(job), "--resume")
    assert result.exit_code == 0, result.output
    files = virtual.firmware.file_system.file_list()
    assert files[-1].startswith(b"big_")


@pytest.mark.parametrize("moment", ["after the ack", "before the ack"])
def test_a_cable_pulled_at_every_chunk_of_a_printing_upload_then_resume(monkeypatch, tmp_path,
                                                                        moment):
    """send-job prints while it uploads; the cable goes at chunk c (once its ack has been
    read, or while the host waits for it), for every c; `send-job --resume` then finishes
    the upload and the card holds what an uninterrupted upload stores."""
    job = tmp_path / "part.gcode"
    job.write_bytes(b"".join(f"G1 X{i % 50 + 10} Y{i % 37 + 10} F6000\n".encode()
                             for i in range(400)))
    args = ("--device", "usb", "send-job", str(job), "--raw", "--id", "part")
    original_write, original_read = VirtualRoboxBackend.bulk_write, VirtualRoboxBackend.bulk_read
    device, virtual = attached(b"RBX-CLEAN")
    monkeypatch.setattr(devices, "_usb_devices", lambda: [device])
    assert run(*args).exit_code == 0
    expected = virtual.firmware.file_system.read_committed(b"part".ljust(16, b"\0"))
    assert expected == job.read_bytes().replace(b"\n", b"\r")
    chunks = len(expected) // 512
    assert chunks >= 10
    for cut in range(chunks):
        device, virtual = attached(b"RBX-PULL")
        monkeypatch.setattr(devices, "_usb_devices", lambda device=device: [device])
        state = {"armed": False}

        def pull_write(self, dev_handle, ep, intf, data, timeout, cut=cut, state=state):
            frame = bytes(data)
            if frame[:1] == b"\x91" and int(frame[1:9], 16) == cut:
                state["armed"] = True
            elif state["armed"] and moment == "after the ack":
                self.printer.usb.disconnect()
            return original_write(self, dev_handle, ep, intf, data, timeout)

        def pull_read(self, dev_handle, ep, intf, buff, timeout, state=state):
            if state["armed"] and moment == "before the ack":
                self.printer.usb.disconnect()
            return original_read(self, dev_handle, ep, intf, buff, timeout)

        monkeypatch.setattr(VirtualRoboxBackend, "bulk_write", pull_write)
        monkeypatch.setattr(VirtualRoboxBackend, "bulk_read", pull_read)
        first = run(*args)
        assert first.exit_code == 1 and "--resume" in first.output, (cut, first.output)
        monkeypatch.setattr(VirtualRoboxBackend, "bulk_write", original_write)
        monkeypatch.setattr(VirtualRoboxBackend, "bulk_read", original_read)
        virtual.usb.connect()
        second = run(*args, "--resume")
        assert second.exit_code == 0, (cut, second.output)
        stored = virtual.firmware.file_system.read_committed(b"part".ljust(16, b"\0"))
        assert stored == expected, f"cable pulled at chunk {cut} ({moment})"
        assert virtual.run_until(lambda v=virtual: v.firmware.job.jobs_completed == 1, 600), \
            f"the job did not print to its end after the cable was pulled at chunk {cut}"


def test_a_printer_another_program_uses_is_listed_as_in_use_and_refused(monkeypatch):
    """A USB printer's port is locked before its interface is claimed: `printers` lists
    one in use by whom, and a command on it is refused in one line."""
    import os

    from robox.locks import describe_pid, port_lock

    monkeypatch.setattr(VirtualRoboxBackend, "virtual", False)  # locked as a real one
    device, _ = attached(b"RBX-BUSY-0001")
    monkeypatch.setattr(devices, "_usb_devices", lambda: [device])
    held = port_lock("held", key=f"usb-{device.bus}-{device.address}")
    try:
        listed = run("printers").output.splitlines()
        busy = (f"the printer on USB bus {device.bus} address {device.address} is in use by "
                f"{describe_pid(os.getpid())}")
        assert listed == [f"(bus {device.bus}, address {device.address}): {busy}"]
        result = CliRunner().invoke(cli, ["--device", "usb", "status"])
        assert result.exit_code == 1 and result.output.splitlines() == [
            f"robox-cli: error: {busy}"]
    finally:
        os.close(held)
    assert "RBX-BUSY-0001  firmware" in run("printers").output


def test_a_serial_port_gone_between_the_write_and_its_drain_is_a_disconnect(tmp_path):
    """pyserial's flush() is termios.tcdrain, whose failure is a termios.error, not an
    OSError: a printer's tty (or a served printer's pty) that goes between the write and
    the drain is a disconnect like any other, never a traceback. Here the port's
    descriptor is turned into a plain file's after it opened: the write lands, the drain
    fails as it does on a dead tty."""
    master, slave = os.openpty()
    port = SerialTransport(os.ttyname(slave))
    try:
        sink = os.open(tmp_path / "sink", os.O_WRONLY | os.O_CREAT)
        os.dup2(sink, port.port.fileno())
        os.close(sink)
        with pytest.raises(termios.error):  # what the drain itself raises
            termios.tcdrain(port.port.fileno())
        with pytest.raises(Disconnected):
            port.write(b"\xb0")
        assert (tmp_path / "sink").read_bytes() == b"\xb0"
    finally:
        port.close()
        os.close(master)
        os.close(slave)


@pytest.fixture
def pty_port():
    """A SerialTransport on a pty's slave, and the master: the other end."""
    master, slave = os.openpty()
    port = SerialTransport(os.ttyname(slave))
    os.set_blocking(master, False)
    ends = {"master": master}
    yield port, ends
    port.close()
    if ends["master"] is not None:
        os.close(ends["master"])
    os.close(slave)


@pytest.mark.parametrize("descriptor", [True, False])
def test_a_serial_port_s_bytes_go_through_its_descriptor(pty_port, descriptor):
    """On a tty the transport reads and writes the port's descriptor (elsewhere, through
    pyserial's read and write, alike): what it writes is at the other end whole, and a
    read returns what has come, up to its limit, the rest left for the next ones."""
    port, ends = pty_port
    master = ends["master"]
    assert port._fd == port.port.fileno()
    if not descriptor:
        port._fd = None
    frame = bytes(range(256)) * 4
    port.write(frame)
    assert os.read(master, 4096) == frame
    os.write(master, b"\xe3" + b"0" * 99)
    got = []
    while sum(map(len, got)) < 100:
        got.append(port.read(64, timeout_ms=1000))
    assert b"".join(got) == b"\xe3" + b"0" * 99 and max(map(len, got)) <= 64


def test_a_serial_read_with_nothing_coming_times_out_as_no_reply(pty_port):
    import time

    port, _ = pty_port
    start = time.monotonic()
    with pytest.raises(NoReply):
        port.read(64, timeout_ms=150)
    assert 0.14 <= time.monotonic() - start < 2.0


def test_a_serial_port_whose_other_end_went_is_a_disconnect(pty_port):
    """The other end closed (a served printer killed): a read finds the port hung up, a
    write cannot land; each is a disconnect, never a traceback."""
    port, ends = pty_port
    os.close(ends["master"])
    ends["master"] = None
    with pytest.raises(Disconnected):
        port.read(64, timeout_ms=1000)
    with pytest.raises(Disconnected):
        port.write(b"\xb0")


def test_a_serial_write_nobody_takes_gives_up_as_a_disconnect(pty_port, monkeypatch):
    """A port that takes no more (its buffer full, nobody reading the other end) is given
    up after the write timeout, as pyserial's write_timeout did."""
    port, _ = pty_port
    monkeypatch.setattr(SerialTransport, "WRITE_TIMEOUT_S", 0.2)
    with pytest.raises(Disconnected):
        for _ in range(64):  # (a pty's buffer holds some kilobytes)
            port.write(b"G" * 65536)
