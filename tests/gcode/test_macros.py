"""AutoMaker's macros as its installer ships them: names with parentheses, blanks and
`#HEAD#N` variants, files made only of includes, and a Windows editor's byte order
mark; through `roboxise` and `send-job` as a user runs them."""

import json

import pytest
from click.testing import CliRunner

from robox.cli import cli
from robox.errors import UsageError
from robox.gcode import code_part
from robox.gcode.macros import directive, find
from robox.gcode.translate import ROBOXISED

# AutoMaker's start macro for a dual-material head, as its macros directory holds it:
# only includes and codes, CRLF line ends, a byte order mark first
START_DM = (b"\xef\xbb\xbfM83\t\t\t;Set Extruder to Relative moves\r\n"
            b"Macro:Home_all_Axis_in_sequence\r\n\r\n"
            b"Macro:Short_Purge#RBX01-DM#N0\r\n\r\n"
            b"Macro:Short_Purge#RBX01-DM#N1\r\n\r\n"
            b"Macro:Level_Gantry_(2-points)\r\n")
FILES = {
    "Home_all_Axis_in_sequence.gcode": b"G28 Y\r\nG28 X\r\nG28 Z\r\n",
    "Level_Gantry_(2-points).gcode": b"G0 Z5\r\nG28 Z\r\nG0 X190\r\nG28 Z\r\n",
    "Short_Purge#RBX01-DM#N0.gcode": b"T0\r\nG1 D2 F400\r\n",
    "Short_Purge#RBX01-DM#N1.gcode": b"T1\r\nG1 E2 F400\r\n",
    "Short_Purge.gcode": b"G1 E9 F400\r\n",
    "Short_Purge#N1.gcode": b"T1\r\nG1 E8 F400\r\n",
    "Short_Purge#RBX01-SM#U.gcode": b"G1 E7 F400\r\n",
    "Purge Material.gcode": b"G4 P100\r\n",
    "Before_Print.gcode": START_DM,
    "Only_Includes.gcode": b"Macro:Home_all_Axis_in_sequence\r\nMacro:Purge Material\r\n",
}


@pytest.fixture
def macros(tmp_path):
    directory = tmp_path / "Macros"
    directory.mkdir()
    for name, data in FILES.items():
        (directory / name).write_bytes(data)
    return directory


def run(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def test_a_macro_line_keeps_its_whole_name():
    assert code_part(b"Macro:Level_Gantry_(2-points)") == b"Macro:Level_Gantry_(2-points)"
    assert directive(b"Macro:Level_Gantry_(2-points)") == "Level_Gantry_(2-points)"
    assert directive(b"  Macro: Purge Material  ; after a change") == "Purge Material"
    assert directive(b"Macro:Short_Purge#RBX01-DM#N0") == "Short_Purge#RBX01-DM#N0"
    assert directive(b"M109 ; Macro:x") is None
    assert code_part(b"G1 X5 (a comment) Y6") == b"G1 X5"  # elsewhere ( still opens one


@pytest.mark.parametrize("name, head, nozzle, chosen", [
    ("Short_Purge", "RBX01-DM", 0, "Short_Purge#RBX01-DM#N0.gcode"),
    ("Short_Purge", "RBX01-DM", 1, "Short_Purge#RBX01-DM#N1.gcode"),
    ("Short_Purge#RBX01-DM#N1", "RBX01-SM", 0, "Short_Purge#RBX01-DM#N1.gcode"),
    ("Short_Purge", "RBX01-SM", 0, "Short_Purge.gcode"),  # the safety-off one loses
    ("Short_Purge", "RBX01-SM", 1, "Short_Purge#N1.gcode"),
    ("Short_Purge", "RBXDV-S1", 0, "Short_Purge.gcode"),
    ("short_purge", "RBX01-SM", 0, "Short_Purge.gcode"),
])
def test_the_file_is_chosen_as_automaker_scored_them(macros, name, head, nozzle, chosen):
    if name.islower():  # a base name matched without case, but the file name starts
        with pytest.raises(UsageError):  # with it as written (on a case-sensitive disk)
            find(macros, name, head, nozzle)
        return
    assert find(macros, name, head, nozzle).name == chosen


def test_an_automaker_start_macro_expands_through_roboxise(macros, tmp_path):
    job = tmp_path / "start.gcode"
    job.write_bytes(START_DM)
    out = tmp_path / "start.robox"
    result = run("roboxise", job, "-o", out, "--macros", macros, "--head", "RBX01-DM",
                 "--json")
    assert result.exit_code == 0, result.output
    assert json.loads(result.output)["macros"] == 4
    assert out.read_bytes() == ROBOXISED + (
        b"\nM83\nG28 Y\nG28 X\nG28 Z\nT0\nG1 D2 F400\nT1\nG1 E2 F400\n"
        b"G0 Z5\nG28 Z\nG0 X190\nG28 Z\n")


def test_a_file_made_only_of_includes_is_a_job(macros, tmp_path):
    job = tmp_path / "only.gcode"
    job.write_bytes(b"\xef\xbb\xbfMacro:Home_all_Axis_in_sequence\r\n"
                    b"Macro:Level_Gantry_(2-points)\r\nMacro:Purge Material\r\n")
    out = tmp_path / "only.robox"
    assert run("roboxise", job, "-o", out, "--macros", macros).exit_code == 0
    assert out.read_bytes() == ROBOXISED + (b"\nG28 Y\nG28 X\nG28 Z\nG0 Z5\nG28 Z\nG0 X190\n"
                                            b"G28 Z\nG4 P100\n")


def test_send_job_expands_macros_and_never_sends_a_macro_line(macros, tmp_path):
    state = tmp_path / "printer"
    job = tmp_path / "only.gcode"
    job.write_bytes(b"Macro:Only_Includes\r\nG0 X10\r\n")
    device = ("--device", f"sim-once:{state}")
    refused = run(*device, "send-job", job, "--id", "inc")
    assert refused.exit_code == 2  # a usage error: it needs an option
    assert refused.output.splitlines()[-1] == (
        f"robox-cli: error: {job}: line 1: Macro:Only_Includes: the printer does not "
        "expand macros (send it with --macros DIR, without --raw)")
    sent = run(*device, "send-job", job, "--id", "inc", "--macros", macros, "--wait",
               "--json")
    assert sent.exit_code == 0, sent.output
    assert json.loads(sent.output)["lines"] == 5  # G28 Y, G28 X, G28 Z, G4 P100, G0 X10
    got = tmp_path / "inc.gcode"
    assert run("sdcard", "get", state / "sdcard.img", "inc", "-o", got).exit_code == 0
    assert got.read_bytes() == b"G28 Y\rG28 X\rG28 Z\rG4 P100\rG0 X10\r"


def test_a_macro_that_includes_itself_is_refused_by_its_chain(macros, tmp_path):
    (macros / "A.gcode").write_bytes(b"Macro:B\n")
    (macros / "B.gcode").write_bytes(b"G4 P1\nMacro:A\n")
    job = tmp_path / "loop.gcode"
    job.write_bytes(b"Macro:A\n")
    result = run("roboxise", job, "-o", tmp_path / "loop.robox", "--macros", macros)
    assert result.exit_code == 2
    assert result.output.splitlines()[-1] == (
        "robox-cli: error: line 1: macro 'A' includes itself (A -> B -> A)")
    assert not (tmp_path / "loop.robox").exists()
