"""The virtual printer as hosts meet it: state directory, pseudo-terminal, pyusb device."""

import json
import os
import select
import time

import pytest
import serial
import usb.core
import usb.util
from click.testing import CliRunner

from robox.cli import cli
from robox.formats.protocol import reply_length
from robox.locks import describe_pid
from robox.sim.printer import VirtualPrinter
from robox.sim.usb_backend import VirtualRoboxBackend
from tests.firmware.wire import Wire, circle_job, hexn, ident
from tests.sim import serving


def run_cli(*args):
    return CliRunner().invoke(cli, list(args), catch_exceptions=False)


def test_a_new_state_directory_is_a_printer_the_offline_tools_can_read(tmp_path):
    state = tmp_path / "printer"
    with VirtualPrinter(state) as printer:
        printer.settle()
        assert printer.firmware.revision == "r776sim"
        assert printer.firmware.errors.bits == 0
    names = sorted(p.name for p in state.iterdir())
    assert names == ["flash.bin", "head.eeprom", "printer.lock", "reel0.eeprom", "sdcard.img"]
    assert run_cli("sdcard", "fsck", str(state / "sdcard.img")).exit_code == 0
    reel = json.loads(run_cli("eeprom", "show", str(state / "reel0.eeprom"), "--json").output)
    assert reel["fields"]["filament_diameter"]["value"] == 1.75
    assert reel["fields"]["remaining_filament"]["value"] == 240000.0
    head = json.loads(run_cli("eeprom", "show", str(state / "head.eeprom"), "--json").output)
    assert head["kind"] == "head" and head["fields"]["type_code"]["value"] == "RBX01-SM"


def test_state_persists_between_runs_and_the_card_is_written_through(tmp_path):
    state = tmp_path / "printer"
    with VirtualPrinter(state) as printer:
        wire = Wire(printer)
        printer.settle()
        wire.upload("persist", circle_job(100, heat=False))
        wire.ok(b"\x94" + ident("persist"))
        wire.wait_job_done()
        printer.run_until(lambda: False, 7.5)  # the 7.2 s filament bookkeeping
        printer.settle()
        # the printer, switched on, may write its card at any pass: nobody else reads
        # it meanwhile, and is told who has it
        refused = run_cli("sdcard", "ls", str(state / "sdcard.img"), "--json")
        assert refused.exit_code == 1
        assert refused.output.strip().splitlines() == [
            f"robox-cli: error: {state / 'sdcard.img'} is in use by PID {os.getpid()} "
            f"({describe_pid(os.getpid()).split(' (', 1)[1]}"]
        remaining = printer.firmware.eeproms.get_float(1, "remaining_filament")
    assert remaining < 240000.0
    listing = json.loads(run_cli("sdcard", "ls", str(state / "sdcard.img"), "--json").output)
    bundled = ["square_tower", "spiral_vase", "home_macro"]  # the bundled card's files
    assert [f["id"] for f in listing["files"]] == [*bundled[:2], "persist"]
    dumped = json.loads(run_cli("eeprom", "show", str(state / "reel0.eeprom"), "--json").output)
    assert dumped["fields"]["remaining_filament"]["value"] == remaining
    with VirtualPrinter(state) as again:
        assert again.firmware.file_system.file_list()[-1] == ident("persist")


def test_a_second_reel_needs_a_dual_reel_adaptor_file(tmp_path):
    state = tmp_path / "printer"
    with VirtualPrinter(state):
        pass
    (state / "reel1.eeprom").write_bytes((state / "reel0.eeprom").read_bytes())
    with VirtualPrinter(state) as printer:
        printer.settle()
        assert printer.firmware.eeproms.status_characters() == b"2221"


def test_chip_dumps_follow_their_chips_in_place_and_a_new_one_is_created(tmp_path):
    """A dump is written over in place (the same file, so the same inode) as soon as
    run_until() returns after the chip was written; a reel plugged in behind a
    dual-reel adaptor while the printer runs gets its dump once the firmware first
    writes it, created whole."""
    from robox.hardware.eeprom import EepromChip
    from robox.sim import images

    state = tmp_path / "printer"
    with VirtualPrinter(state) as printer:
        printer.settle()
        wire = Wire(printer)
        inode = os.stat(state / "reel0.eeprom").st_ino
        name = b"ROBOX TEST REEL".ljust(40, b"\0")
        wire.ok(b"\xa2" + b"68" + b"28" + name)  # reel 0's friendly name, 40 bytes at 0x68
        printer.settle()
        chip = printer.hw.eeprom_bus.sockets[1]
        assert chip.writes > 0
        assert (state / "reel0.eeprom").read_bytes() == bytes(chip.data)
        assert os.stat(state / "reel0.eeprom").st_ino == inode
        assert chip.data[0x68 : 0x68 + 15] == b"ROBOX TEST REEL"

        second = EepromChip(images.reel_eeprom(), clock=printer.hw.clock)
        printer.hw.eeprom_bus.mux_present = True
        printer.hw.eeprom_bus.insert(2, second)
        printer.run_until(lambda: False, 1.0)  # found, loaded and verified
        printer.settle()
        assert printer.firmware.eeproms.status_characters()[:3] == b"222"
        assert not (state / "reel1.eeprom").exists()  # nothing written to it yet
        wire.ok(b"\xa4" + b"68" + b"28" + name)
        printer.settle()
        assert second.writes > 0
        assert (state / "reel1.eeprom").read_bytes() == bytes(second.data)
    assert sorted(p.name for p in state.iterdir()) == [
        "flash.bin", "head.eeprom", "printer.lock", "reel0.eeprom", "reel1.eeprom",
        "sdcard.img"]
    with VirtualPrinter(state) as again:  # and the next power-up reads both reels
        again.settle()
        assert again.firmware.eeproms.status_characters() == b"2221"


def test_the_pyusb_backend_presents_the_real_device():
    printer = VirtualPrinter()
    backend = VirtualRoboxBackend(printer)
    dev = usb.core.find(idVendor=0x16D0, idProduct=0x081B, backend=backend)
    assert dev is not None and dev.bDeviceClass == 0x02
    assert usb.util.get_string(dev, dev.iProduct) == "Robox"
    assert usb.util.get_string(dev, dev.iSerialNumber) == "RBXSIM0000000001"
    dev.set_configuration()
    with pytest.raises(usb.core.USBError):
        usb.util.claim_interface(dev, 1)  # the kernel's cdc_acm driver holds it
    dev.detach_kernel_driver(1)
    usb.util.claim_interface(dev, 1)
    intf = dev.get_active_configuration()[(1, 0)]
    kinds = sorted((e.bEndpointAddress, usb.util.endpoint_type(e.bmAttributes)) for e in intf)
    assert kinds == [(0x02, usb.util.ENDPOINT_TYPE_BULK), (0x81, usb.util.ENDPOINT_TYPE_BULK)]
    dev.write(0x02, b"\xb4")
    assert bytes(dev.read(0x81, 64, 1000)) == b"\xe4r776sim\0"
    dev.write(0x02, b"\xb0")
    status = b""
    while len(status) < 222:
        status += bytes(dev.read(0x81, 64, 1000))
    assert status[0] == 0xE1 and len(status) == 222
    with pytest.raises(usb.core.USBTimeoutError):
        dev.read(0x81, 64, 200)
    printer.usb.disconnect()
    with pytest.raises(usb.core.USBError):
        dev.write(0x02, b"\xb4")


def read_ok(port: serial.Serial, deadline: float = 10.0) -> bytes:
    out = b""
    end = time.monotonic() + deadline
    while not out.endswith(b"ok\r\n") and time.monotonic() < end:
        out += port.read(port.in_waiting or 1)
    return out


def test_robox_cli_sim_serve_on_a_pty_for_a_pronterface_host(tmp_path):
    state = tmp_path / "printer"
    with serving.served(state) as path, serial.Serial(path, 115200, timeout=0.2) as port:
        port.write(b"N1 M110 N0*125\n")
        assert read_ok(port) == b"ok\r\n"
        port.write(b"M115\n")
        assert read_ok(port) == b"FIRMWARE_NAME: robox r776sim\r\nok\r\n"
        for line in (b"G28 X Y\n", b"G1 X20 Y20 F6000\n", b"M400\n"):
            port.write(line)
            assert read_ok(port) == b"ok\r\n"
        port.write(b"M114\n")
        x, y = (float(word[2:]) for word in read_ok(port).split(b" ")[:2])
        assert abs(x - 20) < 1 / 133.7 and abs(y - 20) < 1 / 133.7  # within a step
    assert run_cli("sdcard", "fsck", str(state / "sdcard.img")).exit_code == 0
    assert run_cli("eeprom", "fsck", str(state / "reel0.eeprom")).exit_code == 0
    assert os.path.getsize(state / "flash.bin") == 131072


def test_sim_serve_says_on_its_console_when_the_printer_goes_deaf():
    from robox.sim.serve import PtyServer

    messages = []
    server = PtyServer(VirtualPrinter(), None, console=messages.append)
    try:
        server.printer.usb.host_write(b"M115" + b" " * 1020)  # 1024 bytes, no line end
        for _ in range(30):
            server.serve_once(timeout=0)
        assert server.printer.firmware.command.deaf
        assert len(messages) == 1 and "no more input until reset" in messages[0]
    finally:
        server.close()


def test_a_served_printer_held_for_its_host_still_answers_it():
    """Running fast, the served clock stops short of the moment the printer would stop
    counting its host as connected. A command the host sends then is answered at once:
    the host is not left waiting until it is taken to have gone (after which the printer
    would run on without it and raise the errors a host handles, nozzle flush needed)."""

    from robox.sim.serve import FAST_SLICE_S, HOST_QUIET_S, PtyServer

    server = PtyServer(VirtualPrinter(), None)
    fw = server.printer.firmware

    def ask(frame: bytes) -> tuple[bytes, float]:
        return serving.ask(server, frame)

    try:
        assert ask(b"\xb3")[0][0] == 0xE3
        text = b"M104 S200\r"
        assert ask(b"\x95" + f"{len(text):04x}".encode() + text)[0][0] == 0xE7
        held_at = fw.command.last_ack_report + 5 - FAST_SLICE_S
        for _ in range(10_000):
            server.serve_once(timeout=0)
            if fw.clock.now >= held_at:
                break
        assert fw.clock.now >= held_at and fw.heaters.any_on()
        server.serve_once(timeout=0)
        assert fw.clock.now < held_at + 0.01  # held: the heater's work waits for the host
        status, took = ask(b"\xb0")
        assert status[0] == 0xE1 and took < HOST_QUIET_S / 2
        assert fw.command.host_connected()
        errors, _ = ask(b"\xb3")
        assert set(errors[1:]) == {ord("0")}  # nothing a connected host would see latched
    finally:
        server.close()


def test_a_fast_served_printer_runs_on_once_its_host_has_a_whole_reply():
    """The look at the pty that answers a command also runs the printer on past the
    reply (a slice of its time, while it has work), rather than looking again at once
    for the next command, which the host cannot have written yet."""
    import select

    from robox.formats.protocol import reply_length
    from robox.sim.serve import FAST_SLICE_S, PtyServer

    server = PtyServer(VirtualPrinter(), None)
    fw = server.printer.firmware
    server.printer.settle()
    try:
        Wire(server.printer).gcode(b"M104 S200\r")  # a heater on: the printer works
        began = fw.clock.now
        os.write(server.slave, b"\xb3")
        server.serve_once(timeout=1.0)
        assert select.select([server.slave], [], [], 1.0)[0]
        reply = os.read(server.slave, 4096)
        assert reply[0] == 0xE3 and len(reply) == reply_length(reply)
        assert fw.clock.now - began >= FAST_SLICE_S  # and on, in the same look
    finally:
        server.close()
        server.printer.close()


def test_sim_serve_reports_a_fault_in_the_model_on_its_console(tmp_path, monkeypatch):
    """No catch-all hides a bug: the exception's type, message and traceback go to the
    console (stderr for `sim serve`), and serving ends with a clear error."""
    import pytest

    from robox.sim import serve as serve_module

    def broken(self, *args, **kwargs):
        raise ValueError("cannot convert float NaN to integer")

    monkeypatch.setattr(serve_module.VirtualPrinter, "run_pass", broken)
    monkeypatch.setattr(serve_module.VirtualPrinter, "run_for_host", broken)
    said: list[str] = []
    with pytest.raises(serve_module.ModelFault, match="ValueError"):
        serve_module.serve_forever(tmp_path / "state", None, lambda path: None, said.append)
    assert said[0].startswith("robox sim: fault in the firmware model at t=")
    assert said[0].endswith("ValueError: cannot convert float NaN to integer")
    assert any("in broken" in line for line in said[1:])


def test_a_new_start_removes_the_temporary_file_of_a_killed_one(tmp_path):
    from robox.sim.printer import create_state

    state = tmp_path / "printer"
    state.mkdir()
    stale = state / ".sdcard.img.k1ll3d.tmp"
    stale.write_bytes(bytes(4096))
    # the new card's own temporary file, replaced while it was built
    nested = state / "..sdcard.img.5nwflh5f.tmp.6c_8s3v5.tmp"
    nested.write_bytes(bytes(4096))
    other = state / "notes.txt"
    other.write_text("mine")
    kept = state / ".mine.tmp"
    kept.write_text("mine")
    create_state(state)
    assert not stale.exists() and not nested.exists()
    assert other.read_text() == "mine" and kept.read_text() == "mine"
    assert (state / "sdcard.img").stat().st_size == 64 * 1024 * 1024


def test_a_paced_printer_lets_one_packet_across_a_pass_however_often_it_runs(monkeypatch):
    """Paced to the wall clock, the served printer runs whole passes only. Woken every
    quarter of a pass, as it is while a transfer crosses, it still takes a pass for each
    64-byte packet of a 521-byte chunk, and answers it as a printer in this process
    does (a pass more or less: where in a pass the chunk arrived)."""
    from robox.firmware.main import PASS_S
    from robox.sim import serve

    chunk = b"\x91" + hexn(0, 8) + bytes(range(256)) * 2
    packets = -(-len(chunk) // 64)
    alone = VirtualPrinter()
    alone.settle()
    assert alone.transact(b"\x90" + ident("paced"))[0] == 0xE3
    began = alone.firmware.clock.now
    assert alone.transact(chunk)[0] == 0xE3
    in_process = alone.firmware.clock.now - began
    assert in_process >= packets * PASS_S

    wall = [1000.0]
    monkeypatch.setattr(serve.time, "monotonic", lambda: wall[0])
    printer = VirtualPrinter()
    printer.settle()
    server = serve.PtyServer(printer, speed=1.0)
    clock, usb = printer.firmware.clock, printer.usb
    paced_from = clock.now

    def exchange(frame: bytes) -> tuple[bytes, float]:
        os.write(server.slave, frame)
        taken = None
        out = b""
        for _ in range(20 * packets * 4):
            before, arrived = clock.now, usb.bytes_in
            wall[0] += PASS_S / 4
            server.serve_once(timeout=0)
            if taken is None and usb.bytes_in > arrived:
                taken = before
            if select.select([server.slave], [], [], 0)[0]:
                out += os.read(server.slave, 4096)
                if reply_length(out) is not None and len(out) >= reply_length(out):
                    return out, clock.now - taken
            assert clock.now - paced_from <= wall[0] - 1000.0  # never ahead of the wall
        raise AssertionError(f"no reply to {frame[:1]!r}")

    try:
        assert exchange(b"\x90" + ident("paced"))[0][0] == 0xE3
        reply, took = exchange(chunk)
        assert reply[0] == 0xE3 and set(reply[1:]) == {ord("0")}
        assert took >= packets * PASS_S
        assert abs(took - in_process) <= PASS_S + 1e-9
    finally:
        server.close()
        printer.close()
        alone.close()


def test_run_for_host_stops_for_a_reply_and_runs_on_while_the_printer_works():
    printer = VirtualPrinter()
    printer.settle()
    fw, usb = printer.firmware, printer.usb
    assert printer.run_for_host(0.0) == 0
    assert printer.run_for_host(5.0) == 1 and not fw.working()  # nothing to do: a pass
    began = fw.clock.now
    usb.host_write(b"\xb3")
    printer.run_for_host(5.0)
    assert usb.reply_waiting and fw.clock.now - began < 0.01  # the reply, at once
    assert usb.host_read(4096)[0] == 0xE3
    Wire(printer).gcode(b"M104 S200\r")  # a heater on: the printer works without a host
    began = fw.clock.now
    printer.run_for_host(0.5)
    assert fw.working() and not usb.reply_waiting
    assert 0.5 <= fw.clock.now - began < 0.5 + 0.01
    printer.close()


def test_a_host_lets_a_served_printers_time_pass_by_its_pace(monkeypatch):
    """Fast, the served clock waits for the host's next poll: the host asks at once.
    Paced, the host sleeps the wall time that the printer's time takes."""
    from robox.host import devices

    slept = []
    monkeypatch.setattr(devices.time, "sleep", slept.append)
    devices.served_idle(None)(0.5)
    devices.served_idle(1.0)(0.5)
    devices.served_idle(10.0)(0.5)
    devices.served_idle(0.5)(0.5)
    assert slept == [0, 0.5, 0.05, 1.0]
