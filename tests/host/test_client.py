"""robox-cli and the client API against the virtual printer, through the pyusb backend
(the hardware's code path) and through a real pty."""

import json

import pytest
import usb.core
from click.testing import CliRunner

from robox.cli import cli
from robox.formats.protocol import FIXED_REPLY_LENGTH, reply_length
from robox.gcode import prepare_job
from robox.host.client import Printer, PrinterError, ProtocolError
from robox.host.transport import Disconnected, NoReply, UsbTransport
from robox.sim import images
from robox.sim.printer import VirtualPrinter
from robox.sim.usb_backend import VirtualRoboxBackend
from tests.cli.test_sdcard_cli import one_line_error
from tests.firmware.wire import circle_job
from tests.installed import EXAMPLE
from tests.sim import serving


def run(*args):
    return CliRunner().invoke(cli, list(args), catch_exceptions=False)


@pytest.fixture
def state(tmp_path):
    return tmp_path / "printer"


def sim(state, *args):
    return run("--device", f"sim-once:{state}", *args)


def test_send_job_wait_prints_the_example_to_the_end(state):
    result = sim(state, "send-job", str(EXAMPLE), "--wait", "--json")
    assert result.exit_code == 0, result.output
    summary = json.loads(result.output)
    assert summary["lines"] == prepare_job(EXAMPLE.read_bytes()).count(b"\r")
    assert summary["errors"] == [] and summary["simulated_print_time_s"] > 60
    assert 0 < summary["filament_used_mm"]["reel0"] < 1000
    files = json.loads(sim(state, "files", "--json").output)
    assert files[-1]["id"] == summary["id"] and files[-1]["size"] == summary["bytes"]
    human = sim(state, "send-job", str(EXAMPLE), "--wait")
    assert "printed in" in human.output and "errors: none" in human.output


def test_status_files_gcode_errors(state):
    status = json.loads(sim(state, "status", "--json").output)
    assert status["eeproms"]["head"] == "valid" and status["sd_card"]
    assert status["job"] is None and status["errors"] == []
    assert "square_tower" in sim(state, "files").output  # from the bundled card
    out = sim(state, "gcode", "M115", "G28", "M114").output
    assert out.startswith("FIRMWARE_NAME: robox r776sim\nok\n")
    assert sim(state, "errors").output.strip() == "no errors"


@pytest.fixture
def served(tmp_path):
    """A virtual printer that keeps running between commands: sim serve on a pty."""
    with serving.served(tmp_path / "served") as path:
        yield f"serial:{path}"


def test_pause_resume_abort_and_run_job(served):
    def on(*args):
        return run("--device", served, *args)

    assert on("run-job", "spiral_vase").exit_code == 0
    assert json.loads(on("status", "--json").output)["job"] == "spiral_vase"
    assert on("pause").exit_code == 0
    assert json.loads(on("status", "--json").output)["pause"] in ("pausing", "paused")
    for _ in range(200):  # the line under way (a heat-up) ends, then the head parks
        if json.loads(on("status", "--json").output)["pause"] == "paused":
            break
    assert json.loads(on("status", "--json").output)["pause"] == "paused"
    assert on("resume").exit_code == 0
    assert json.loads(on("status", "--json").output)["pause"] in ("resuming", "running")
    assert on("abort").exit_code == 0
    assert json.loads(on("status", "--json").output)["job"] is None
    assert on("run-job").exit_code == 0  # the last job again
    assert json.loads(on("status", "--json").output)["job"] == "spiral_vase"
    one_line_error(on("run-job", "nothing_here"), 1, "no job")


def test_eeprom_round_trips(state):
    assert sim(state, "write-eeprom", "reel0", "remaining_filament=1234.5",
               "friendly_name=Test reel").exit_code == 0
    fields = json.loads(sim(state, "read-eeprom", "reel0", "--json").output)
    assert fields["remaining_filament"] == 1234.5 and fields["friendly_name"] == "Test reel"
    dump = json.loads(run("eeprom", "show", str(state / "reel0.eeprom"), "--json").output)
    assert dump["fields"]["remaining_filament"]["value"] == 1234.5  # banks written, saved
    assert sim(state, "format-eeprom", "head", "--yes").exit_code == 0
    assert json.loads(sim(state, "read-eeprom", "head", "--json").output)["type_code"] == ""
    one_line_error(sim(state, "write-eeprom", "reel0", "nope=1"), 2, "no reel EEPROM field")


def test_eeprom_floats_read_back_as_written_online_and_offline(state):
    """2.85 is stored as "2.850000", which the printer reads as the float32
    2.8499999046325684: a user reads back 2.85, in text and in JSON."""
    assert sim(state, "write-eeprom", "reel0", "filament_diameter=2.85",
               "filament_multiplier=0.1").exit_code == 0
    fields = json.loads(sim(state, "read-eeprom", "reel0", "--json").output)
    assert (fields["filament_diameter"], fields["filament_multiplier"]) == (2.85, 0.1)
    text = sim(state, "read-eeprom", "reel0").output.splitlines()
    assert [line.split() for line in text if line.startswith("filament_d")] == \
        [["filament_diameter", "2.85"]]
    dump = json.loads(run("eeprom", "show", str(state / "reel0.eeprom"), "--json").output)
    assert dump["fields"]["filament_diameter"] == {"value": 2.85, "raw": "2.850000"}
    shown = run("eeprom", "show", str(state / "reel0.eeprom")).output.splitlines()
    assert ["filament_diameter", "2.85"] in [line.split() for line in shown]


def test_update_firmware_good_and_bad(state, tmp_path):
    good = tmp_path / "good.bin"
    good.write_bytes(images.firmware_image("r800new", size=16384, seed=8))
    result = sim(state, "update-firmware", str(good))
    assert result.exit_code == 0, result.output
    assert "r776sim -> r800new" in result.output
    assert json.loads(sim(state, "status", "--json").output)["errors"] == []
    bad = tmp_path / "bad.bin"
    data = bytearray(good.read_bytes())
    data[1000] ^= 1
    bad.write_bytes(bytes(data))
    one_line_error(sim(state, "update-firmware", str(bad)), 1, "would be refused")
    assert "r800new" in sim(state, "gcode", "M115").output


def released_image(revision: bytes, size: int = 20480) -> bytes:
    """An image laid out as a released one is: code (here, bytes), the M115 reply as a
    C string literal among its constants, and the word at 0xBC that brings the 32-bit
    word sum to zero (computed here, not by the package)."""
    import random
    import struct

    body = bytearray(random.Random(779).randbytes(size))
    literal = b"FIRMWARE_NAME: robox " + revision + b"\r\n\0"
    body[0x3100 : 0x3100 + len(literal)] = literal
    body[0xBC:0xC0] = bytes(4)
    total = sum(struct.unpack(f"<{size // 4}I", bytes(body))) & 0xFFFFFFFF
    body[0xBC:0xC0] = struct.pack("<I", (-total) & 0xFFFFFFFF)
    return bytes(body)


def test_after_an_update_the_printer_reports_the_revision_the_image_declares(state,
                                                                              tmp_path):
    image = tmp_path / "robox_r779.bin"
    image.write_bytes(released_image(b"r779"))
    result = sim(state, "update-firmware", str(image), "--json")
    assert result.exit_code == 0, result.output
    assert json.loads(result.output) == {"before": "r776sim", "after": "r779"}
    assert sim(state, "gcode", "M115").output.splitlines()[0] == "FIRMWARE_NAME: robox r779"
    # 0xb4, as the printer sends it: the revision NUL padded to 8 bytes
    from robox.host.devices import open_printer

    with open_printer(f"sim-once:{state}") as printer:
        assert printer.transact(b"\xb4") == b"\xe4r779\0\0\0\0"


@pytest.mark.parametrize("args,status,words", [
    (["--device", "bogus", "status"], 2, "unknown device"),
    (["--device", "serial:/dev/nonexistent-robox", "status"], 1, "cannot open"),
    (["--device", "serial:", "status"], 2, "needs a path"),
])
def test_device_selection_errors(args, status, words):
    one_line_error(run(*args), status, words)


def test_usb_without_a_printer_says_so():
    result = run("--device", "usb", "status")
    assert result.exit_code == 1
    assert "no Robox is attached" in result.stderr or "no USB backend" in result.stderr


def test_send_job_bad_input(state, tmp_path):
    one_line_error(sim(state, "send-job", str(tmp_path / "missing.gcode")), 1, "no such file")
    binary = tmp_path / "photo.jpg"
    binary.write_bytes(b"\xff\xd8\xff\xe0" + bytes(100))
    one_line_error(sim(state, "send-job", str(binary)), 1, "not a G-code file")
    one_line_error(sim(state, "send-job", str(EXAMPLE), "--id", "x" * 17), 2, "at most 16")


# --------------------------------------------------------- the client API
def connect(virtual: VirtualPrinter) -> Printer:
    backend = VirtualRoboxBackend(virtual)
    device = usb.core.find(idVendor=0x16D0, idProduct=0x081B, backend=backend)
    return Printer(UsbTransport(device), idle=lambda s: virtual.run_until(lambda: False, 5))


@pytest.fixture
def virtual():
    v = VirtualPrinter()
    v.settle()
    return v


def test_resume_after_a_disconnect_at_every_chunk(virtual, tmp_path):
    """Interrupted while sending bytes, resumed from the job's file on disk (read a chunk
    at a time from where the printer says the upload stopped): the card holds the job."""
    job = prepare_job(circle_job(150, heat=False))
    on_disk = tmp_path / "job.gcode"
    on_disk.write_bytes(job + b"G4 P1\r")
    chunks = len(job) // 512
    assert chunks >= 5
    clean = VirtualPrinter()
    clean.settle()
    with open(on_disk, "rb") as source:
        connect(clean).send_file(source, "resume", run=False)
    expected = clean.firmware.file_system.read_committed(b"resume".ljust(16, b"\0"))
    assert expected == job + b"G4 P1\r"
    for cut in range(chunks):
        v = VirtualPrinter()
        v.settle()
        printer = connect(v)

        def progress(done, total, v=v, cut=cut):
            if done >= (cut + 1) * 512:
                v.usb.disconnect()

        with pytest.raises(Disconnected):
            printer.send_file(on_disk.read_bytes(), "resume", run=False, progress=progress)
        v.usb.connect()
        with open(on_disk, "rb") as source:
            connect(v).send_file(source, "resume", run=False, resume=True)
        stored = v.firmware.file_system.read_committed(b"resume".ljust(16, b"\0"))
        assert stored == expected, f"cut after chunk {cut}"


def test_an_error_in_an_ack_is_named_in_words(virtual):
    printer = connect(virtual)
    virtual.hw.card.remove()
    with pytest.raises(PrinterError, match="SD card error"):
        printer.send_file(b"G28\r", "nocard")


class Spy:
    """A transport that records the traffic and checks stop-and-wait."""

    def __init__(self, inner):
        self.inner = inner
        self.pending = b""
        self.writes = 0

    def write(self, data, timeout_ms=5000):
        assert self.pending == b"", "a command was sent before the last reply was read"
        self.pending = b"?"
        self.writes += 1
        self.inner.write(data, timeout_ms)
        self.reply = b""

    def read(self, limit, timeout_ms=5000):
        data = self.inner.read(limit, timeout_ms)
        self.reply += data
        if reply_length(self.reply) == len(self.reply):
            self.pending = b""
        return data

    def close(self):
        self.inner.close()


def test_the_host_never_has_two_commands_in_flight(virtual):
    printer = connect(virtual)
    spy = Spy(printer.transport)
    printer.transport = spy
    printer.send_file(prepare_job(circle_job(40, heat=False)), "spy")
    printer.status()
    printer.read_eeprom_fields("reel0")
    printer.gcode("M105\r")
    assert spy.writes > 5 and spy.pending == b""
    assert virtual.firmware.errors.bits == 0  # no USB_TX: nothing was clobbered


def test_over_a_real_pty(served):
    status = json.loads(run("--device", served, "status", "--json").output)
    assert status["eeproms"]["reel0"] == "valid"
    result = run("--device", served, "send-job", str(EXAMPLE), "--wait", "--json")
    assert result.exit_code == 0, result.output
    summary = json.loads(result.output)
    assert summary["errors"] == []
    assert summary["id"] in [f["id"] for f in
                             json.loads(run("--device", served, "files", "--json").output)]


class LineEnds:
    """A transport that ends every frame with a line end, as a text terminal would."""

    def __init__(self, inner):
        self.inner = inner

    def write(self, data, timeout_ms=5000):
        self.inner.write(data + b"\n", timeout_ms)

    def read(self, limit, timeout_ms=5000):
        return self.inner.read(limit, timeout_ms)


def test_a_text_reply_is_named_not_misread():
    """A printer in the middle of another host's text (Pronterface) line takes a frame as
    more text and answers "ok" once the line ends: the client says so instead of reading
    the text as a report."""
    v = VirtualPrinter()
    v.settle()
    v.usb.host_write(b"G1 X1")  # a text host's unfinished line
    device = usb.core.find(idVendor=0x16D0, idProduct=0x081B, backend=VirtualRoboxBackend(v))
    with pytest.raises(ProtocolError, match=r"answered in text \(b'ok\\r\\n'\)"):
        Printer(LineEnds(UsbTransport(device)))


class BulkPackets:
    """A transport that hands out the printer's replies as a USB bulk IN endpoint does:
    in packets of 64 bytes, a read ending at a short packet or when its buffer is full.
    A buffer that is not whole packets could overflow on a real bus, and a read left
    waiting after the reply's last full packet would time out: both fail the test."""

    def __init__(self, inner):
        self.inner = inner
        self.pending = b""
        self.replies: list[list[int]] = []  # each reply's code and length, and its reads

    def write(self, data, timeout_ms=5000):
        self.inner.write(data, timeout_ms)
        reply = b""  # the whole reply, as the printer sends it
        while reply_length(reply) is None or len(reply) < reply_length(reply):
            reply += self.inner.read(64, timeout_ms)
        self.pending = reply
        self.replies.append([reply[0], len(reply), 0])

    def read(self, limit, timeout_ms=5000):
        assert limit % 64 == 0, f"a {limit}-byte buffer is not whole packets"
        self.replies[-1][2] += 1
        out = b""
        while len(out) < limit:
            if not self.pending:
                raise NoReply("the read waits for a packet that never comes")
            packet, self.pending = self.pending[:64], self.pending[64:]
            out += packet
            if len(packet) < 64:
                break
        return out


def test_a_reply_is_read_in_at_most_two_reads_of_whole_packets(virtual):
    """A report of fixed length comes in one read whose buffer is whole packets, ended by
    the reply's short packet or by filling up exactly. Any other reply's first packet says
    its length, and the rest comes in one more such read."""
    printer = connect(virtual)
    bulk = BulkPackets(printer.transport)
    printer.transport = bulk
    printer.status()  # 0xE1, 222 bytes: four packets
    printer.errors()  # 0xE3, 65 bytes: a full packet and one byte
    printer.read_eeprom("reel0")  # 0xE6, 193 bytes
    printer.files()  # 0xE0, its length in its first packet: one
    for n in range(4):  # acks, 0xE3
        printer.send_file(prepare_job(circle_job(4, heat=False)), f"bulk{n}", run=False)
    printer.files()  # four files: 67 bytes
    printer.gcode("M105\r")  # 0xE7, its length in its first packet
    printer.gcode("M119\r")
    assert {0xE0, 0xE1, 0xE3, 0xE6, 0xE7} <= {code for code, _, _ in bulk.replies}
    assert len(bulk.replies) > 8
    for code, length, reads in bulk.replies:
        assert reads == (1 if code in FIXED_REPLY_LENGTH or length <= 64 else 2), hex(code)
    assert any(code not in FIXED_REPLY_LENGTH and reads == 2 for code, _, reads in bulk.replies)


@pytest.mark.parametrize("size", [100, 512 * 6, 512 * 6 + 300])
def test_an_upload_takes_a_pass_per_packet_and_one_to_answer_each_frame(virtual, size):
    """The recording rig's timing: a frame of n bytes arrives in ceil(n/64) passes and is
    answered in the pass after; the host reads that answer before it sends the next
    frame (the firmware has one transmit buffer), so no pass carries two frames' bytes.
    Start (0x90 and a 16-byte name), 512-byte chunks (0x91, 8 hex digits of sequence),
    end (0x92, 8 hex digits of chunks, 4 of the tail's length, the tail)."""
    data = b"".join(b"G1 X%d Y%d F3000\r" % (n % 200, n % 150) for n in range(size))[:size]
    chunks, tail = divmod(size, 512)
    frames = [1 + 16] + [1 + 8 + 512] * chunks + [1 + 8 + 4 + tail]
    printer = connect(virtual)
    clock = virtual.firmware.clock
    began = clock.now
    printer.send_file(data, "timing", job=False)
    assert round((clock.now - began) * 1000) == sum(-(-n // 64) + 1 for n in frames)
    assert virtual.firmware.file_system.read_committed(b"timing".ljust(16, b"\0")) == data
