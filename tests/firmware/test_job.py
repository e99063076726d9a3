"""The job engine over the wire: printing while uploading, resume, pause, abort, errors."""

import pytest

from robox.firmware.gcode import IDLE_ABORT_S, IDLE_PAUSE_S, PauseState
from robox.formats.protocol import ErrorBit
from tests.firmware.test_protocol import status_fields
from tests.firmware.wire import circle_job, hexn, ident, job_text


def test_a_job_prints_while_it_uploads_and_completes(wire):
    job = circle_job(400)
    seen_waiting = []

    def between(n):
        if n >= 2:
            wire.printer.run_until(lambda: wire.fw.job.waiting_for_data, 600)
            seen_waiting.append(wire.fw.job.waiting_for_data)
            status = status_fields(wire.raw(b"\xb0"))
            assert status["job"] == ident("circle") and status["pause"] == b"0"

    wire.upload("circle", job, run_after=1, between=between)
    assert seen_waiting and all(seen_waiting)  # it caught up with the upload and waited
    assert wire.raw(b"\x96") == b"\xe001" + ident("circle")  # listed once complete
    wire.wait_job_done()
    assert ("job finished", ident("circle")) in wire.fw.events
    assert wire.fw.job.line_number == job.count(b"\r")
    assert not wire.fw.heaters.any_on()
    status = status_fields(wire.raw(b"\xb0"))
    assert status["job"] == bytes(16)


def test_the_line_number_in_the_status_report_counts_job_lines(wire):
    wire.upload("count", job_text(["G4 S30"] + ["G1 X1"] * 5 + ["G4 S1000"]), run_after=None)
    wire.ok(b"\x94" + ident("count"))
    wire.printer.run_until(lambda: wire.fw.job.line_number == 7, 200)
    assert status_fields(wire.raw(b"\xb0"))["line"] == b"00000007"


def test_run_job_with_an_empty_id_runs_the_last_job(wire):
    wire.upload("again", job_text(["G1 X5 F600"]))
    wire.ok(b"\x94" + ident("again"))
    wire.wait_job_done()
    wire.ok(b"\x94" + bytes(16))
    assert wire.fw.job.running and wire.fw.job.job_id == ident("again")


def test_an_interrupted_upload_resumes_from_the_send_file_report(wire):
    data = circle_job(300, heat=False)
    wire.ok(b"\x97" + ident("resume"))
    for n in range(5):
        wire.ok(b"\x91" + hexn(n, 8) + data[n * 512 : (n + 1) * 512])
    wire.usb.disconnect()
    wire.usb.connect()
    report = wire.raw(b"\x93")
    assert report == b"\xe9" + ident("resume") + b"00000005"
    nxt = int(report[17:], 16)
    wire.ok(b"\x91" + hexn(3, 8) + b"x" * 512)  # a resent earlier chunk is ignored
    chunks = len(data) // 512
    for n in range(nxt, chunks):
        wire.ok(b"\x91" + hexn(n, 8) + data[n * 512 : (n + 1) * 512])
    tail = data[chunks * 512 :]
    wire.ok(b"\x92" + hexn(chunks, 8) + hexn(len(tail), 4) + tail)
    assert wire.fw.file_system.read_committed(ident("resume")) == data


def test_pause_parks_resume_returns_and_the_job_finishes(wire):
    wire.upload("pausing", circle_job(200, heat=False))
    wire.ok(b"\x94" + ident("pausing"))
    wire.printer.run_until(lambda: wire.fw.job.line_number > 50, 100)
    wire.ok(b"\x981")
    states = {status_fields(wire.raw(b"\xb0"))["pause"]}
    wire.printer.run_until(lambda: wire.fw.job.pause_state == PauseState.PAUSED, 100)
    states.add(status_fields(wire.raw(b"\xb0"))["pause"])
    assert states == {b"1", b"2"}
    line = wire.fw.job.line_number
    wire.printer.run_until(lambda: False, 60)
    assert wire.fw.job.line_number == line  # nothing runs while paused
    x = wire.fw.position.reported_position("X")
    assert abs(x - 5.0) < 0.01  # parked
    wire.gcode(b"G91\rG1 Z1\rG90\r")  # jogging while paused runs from the execute buffer
    wire.ok(b"\x980")
    assert status_fields(wire.raw(b"\xb0"))["pause"] in (b"3", b"0")
    wire.wait_job_done()
    assert ("job finished", ident("pausing")) in wire.fw.events


def test_abort_stops_everything(wire):
    wire.upload("abort", circle_job(300))
    wire.ok(b"\x94" + ident("abort"))
    wire.printer.run_until(lambda: wire.fw.job.line_number > 20, 600)
    wire.ok(b"\xff")
    job = wire.fw.job
    assert not job.running and job.job_id is None and not job.execute_buffer
    assert not wire.fw.heaters.any_on()
    wire.printer.run_until(wire.fw.motion.idle, 10)
    assert status_fields(wire.raw(b"\xb0"))["job"] == bytes(16)


def test_a_latched_error_pauses_a_running_job_once(wire):
    wire.upload("err", circle_job(300, heat=False))
    wire.ok(b"\x94" + ident("err"))
    wire.printer.run_until(lambda: wire.fw.job.line_number > 10, 100)
    wire.fw.errors.set(ErrorBit.B_STUCK)
    wire.printer.run_until(lambda: wire.fw.job.pause_state == PauseState.PAUSED, 60)
    assert wire.fw.job.pause_state == PauseState.PAUSED
    wire.ack(b"\x980")
    wire.printer.run_until(lambda: False, 5)
    assert wire.fw.job.pause_state == PauseState.RUNNING  # the same error does not re-pause


@pytest.mark.parametrize("bit", [ErrorBit.B_POSITION_WARNING, ErrorBit.E_NO_FILAMENT,
                                 ErrorBit.POWEROFF_WHILST_HOT])
def test_some_errors_never_pause(wire, bit):
    wire.upload("np", circle_job(300, heat=False))
    wire.ok(b"\x94" + ident("np"))
    wire.printer.run_until(lambda: wire.fw.job.line_number > 10, 100)
    wire.fw.errors.set(bit)
    wire.printer.run_until(lambda: False, 5)
    assert wire.fw.job.pause_state == PauseState.RUNNING


def test_filament_slip_pauses_only_without_a_connected_host(wire):
    wire.upload("slip", circle_job(2000, heat=False))
    wire.ok(b"\x94" + ident("slip"))
    wire.printer.run_until(lambda: wire.fw.job.line_number > 10, 100)
    wire.ack(b"\xb3")  # an ack report: the host is connected for 5 s
    wire.fw.errors.set(ErrorBit.E_FILAMENT_SLIP)
    wire.printer.run_until(lambda: False, 2)
    assert wire.fw.job.pause_state == PauseState.RUNNING
    wire.printer.run_until(lambda: wire.fw.job.pause_state != PauseState.RUNNING, 10)
    assert wire.fw.job.pause_state in (PauseState.PAUSING, PauseState.PAUSED)


def test_a_line_longer_than_512_bytes_aborts_the_job(wire):
    wire.upload("long", job_text(["G1 X1", "G1 X2 " + ";" * 600, "G1 X3"]))
    wire.ok(b"\x94" + ident("long"))
    wire.printer.run_until(lambda: not wire.fw.job.running, 30)
    assert wire.ack(b"\xb3")[ErrorBit.GCODE_LINE_TOO_LONG] == "1"
    assert wire.fw.job.line_number == 1


def test_idle_pause_then_idle_abort(wire):
    wire.ok(b"\x97" + ident("stall"))
    wire.ok(b"\x91" + hexn(0, 8) + job_text(["M104 S200"] + ["G1 X1"] * 100)[:512])
    wire.ok(b"\x94" + ident("stall"))
    wire.printer.run_until(lambda: wire.fw.job.waiting_for_data, 60)
    start = wire.fw.clock.now
    wire.printer.run_until(lambda: wire.fw.job.pause_state == PauseState.PAUSED,
                           IDLE_PAUSE_S + 120)
    assert IDLE_PAUSE_S <= wire.fw.clock.now - start < IDLE_PAUSE_S + 120
    wire.printer.run_until(lambda: not wire.fw.job.running, IDLE_ABORT_S)
    assert not wire.fw.job.running and not wire.fw.heaters.any_on()
    assert wire.fw.clock.now - start >= IDLE_ABORT_S - 1


def test_a_selfie_pause_from_the_job(wire):
    wire.upload("selfie", job_text(["G1 X10 F3000", "M1 C", "G1 X20"]))
    wire.ok(b"\x94" + ident("selfie"))
    wire.printer.run_until(lambda: wire.fw.job.pause_state == PauseState.SELFIE, 60)
    assert status_fields(wire.raw(b"\xb0"))["pause"] == b"4"
    wire.ok(b"\x980")
    wire.wait_job_done()
