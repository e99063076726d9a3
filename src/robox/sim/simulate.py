"""A job printed offline on a fresh virtual printer, and what the printing did.

The job (a slicer's file is translated first, as send-job would) is stored on
a card sized to it, as a printer stores an upload, and run with the run-job
command on a printer with the chosen head and full reels. A host asks for the
error report every few simulated seconds, as send-job --wait does, so the
printer counts a host as connected. While it prints:

- every move the position object queues is watched (Position.watcher): the
  job-frame coordinates of extruding moves (the extent, and moves outside the
  build plate), moves whose X or Y the firmware clamps to the axes' travel,
  and filament pushed while the valve of a head that has one is shut;
- the thermistors' readings give the peak temperatures;
- a pause the job makes itself (M1) is resumed and noted; a pause an error
  makes ends the simulation, as it would stop the print.

The reels' filament is loaded up to the nozzle in the feeds the job uses, and the
machine's deposition model (robox.hardware.deposition) records where the plastic
lands; robox.sim.quality judges the record (blobs, starved stretches) and draws it.

Volumes are the filament the position object queued (signed: retractions
count back), in cubic millimetres of the reel's diameter and multiplier.
"""

from __future__ import annotations

import contextlib
import math
import os
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path

from robox.errors import UsageError
from robox.fileio import write_atomically
from robox.formats.heads import head_valves
from robox.formats.protocol import PAUSE_MASK_CONNECTED, error_bits, error_names
from robox.formats.sdcard import BLOCK_SIZE, make_id
from robox.gcode import JobFile, Options, head_kind, job_file
from robox.gcode.files import inspect
from robox.gcode.translate import DEFAULT_DIAMETER, HEAD_DEFAULT
from robox.hardware.deposition import Deposition
from robox.hardware.machine import NOZZLE_MM, D, E
from robox.offline import sdcard as card_images
from robox.sim import images
from robox.sim.printer import CARD_SIZE, VirtualPrinter, create_state
from robox.sim.quality import Quality, find_lines
from robox.sim.watch import BED_X_MM, BED_Y_MM, Watch

#: The build plate, in the job's frame (its origin at the plate's front left corner).
BED_MM = (BED_X_MM, BED_Y_MM)
#: Simulated seconds between the host's error reports.
POLL_S = 2.0
#: A job still printing after this much simulated time is given up.
MAX_PRINT_S = 7 * 24 * 3600.0
JOB_ID = "simulated"
HEATERS = ("nozzle0", "nozzle1", "bed", "ambient")


class Setup:
    """The virtual printer and the translation a simulation uses."""

    def __init__(self, head: str = HEAD_DEFAULT, filament_diameter: float = DEFAULT_DIAMETER,
                 remaining_m: tuple[float, float] = (240.0, 240.0), nozzle: int | None = None,
                 macros: Path | None = None, raw: bool = False,
                 ejection: tuple[float, ...] | None = None, valve: str = "automaker") -> None:
        self.head = head
        self.filament_diameter = filament_diameter
        self.remaining_m = remaining_m  # on reel 0, reel 1
        self.nozzle = nozzle
        self.macros = macros
        self.raw = raw  # run the file as it is, even a slicer's
        self.ejection = ejection  # mm3 per nozzle (None: the head's own)
        # how a slicer's file drives the valve: "automaker", "simple"
        self.valve = valve


class Report:
    def __init__(self, file: str, head: str, translation: dict | None, lines: int) -> None:
        self.file = file
        self.head = head
        self.translation = translation
        self.lines = lines
        self.lines_run = 0
        self.completed = False
        self.print_time_s = 0.0
        self.extruders: dict = {}
        self.peak_c: dict = {}
        self.extent_mm: dict | None = None
        self.warnings: list[str] = []
        self.errors: list[str] = []
        self.deposition: dict | None = None
        self.quality: Quality | None = None  # the record, for a picture (not in the dict)
        self.quality_worst: list = []

    def as_dict(self) -> dict:
        return {"file": self.file, "head": self.head, "translation": self.translation,
                "lines": self.lines, "lines_run": self.lines_run,
                "completed": self.completed, "print_time_s": round(self.print_time_s, 1),
                "extruders": self.extruders, "peak_temperatures_c": self.peak_c,
                "extent_mm": self.extent_mm, "deposition": self.deposition,
                "warnings": self.warnings, "errors": self.errors}


def _area(diameter: float) -> float:
    return math.pi * diameter * diameter / 4.0


def _lines_text(lines: list[int]) -> str:
    shown = ", ".join(str(n) for n in lines[:5])
    return f"line{'s' if len(lines) > 1 else ''} {shown}" + \
        (f" and {len(lines) - 5} more" if len(lines) > 5 else "")


def _errors(virtual: VirtualPrinter) -> int:
    """The error report, asked for as a host does (it keeps the host counted)."""
    return error_bits(virtual.transact(b"\xb3"))


def _card_blocks(job: JobFile) -> int:
    """A card as big as a printer's usual one, or big enough for the job."""
    least = card_images.parse_size(CARD_SIZE) // BLOCK_SIZE
    return max(least, job.size // BLOCK_SIZE + 4096)


def _make_printer(state: Path, setup: Setup, kind: str, job: JobFile) -> VirtualPrinter:
    write_atomically(state / "head.eeprom",
                     images.head_eeprom(calibrated=True, type_code=setup.head))
    for n in range(2 if kind == "dual" else 1):
        write_atomically(state / f"reel{n}.eeprom",
                         images.reel_eeprom(setup.remaining_m[n] * 1000.0,
                                            setup.filament_diameter))
    card = state / "sdcard.img"
    card_images.format_image(card, _card_blocks(job))
    with open(job.path, "rb") as source:
        card_images.put_stream(card, source, JOB_ID, job=True)
    create_state(state)  # the flash
    virtual = VirtualPrinter(state)
    machine = virtual.hw.machine
    for n, axis in enumerate((E, D)):
        if n in _feeds_used(job, kind):
            machine.insert_filament(axis, setup.remaining_m[n] * 1000.0, tip_mm=NOZZLE_MM)
    Deposition(head_valves(setup.head, setup.ejection), (setup.filament_diameter,) * 2,
               images.CALIBRATED_B_OFFSETS, spill=str(state / "deposition.rows")).attach(machine)
    virtual.settle()
    return virtual


def _feeds_used(job: JobFile, kind: str) -> set[int]:
    """The extruders a job feeds (0: E, 1: D): from its translation, or its text."""
    if kind != "dual":
        return {0}
    if job.translation is not None:
        volume = job.translation.volume_mm3
        used = {n for n, name in enumerate("ED") if volume.get(name, 0.0) > 0.0}
        return used or {0}
    used = set()
    with open(job.path, "rb") as f:
        for raw in f:
            line = raw.split(b";", 1)[0].upper()
            if line.startswith((b"G0", b"G1")):
                if b"E" in line[2:]:
                    used.add(0)
                if b"D" in line[2:]:
                    used.add(1)
                if len(used) == 2:
                    break
    return used or {0}


@contextlib.contextmanager
def _prepared(source: str | os.PathLike, setup: Setup, kind: str
              ) -> Iterator[tuple[JobFile, VirtualPrinter]]:
    detected = inspect(source)
    options = None
    if not setup.raw and (detected.from_slicer or setup.macros is not None):
        options = Options(filament_diameter=(setup.filament_diameter,) * 2, head=setup.head,
                          nozzle=setup.nozzle, macros=setup.macros, valve=setup.valve,
                          ejection=setup.ejection)
    with job_file(source, options, detected) as job, \
            tempfile.TemporaryDirectory(prefix="robox-simulate-") as state:
        virtual = _make_printer(Path(state), setup, kind, job)
        try:
            yield job, virtual
        finally:
            virtual.close()


def simulate(source: str | os.PathLike, setup: Setup,
             progress: Callable[[int, int], None] | None = None,
             judged: Callable[[Report], None] | None = None) -> Report:
    """Print `source` on a fresh virtual printer; what it did. `progress(lines, total)`
    hears of the job's line number as it goes; `judged(report)` is called while the
    deposition record (`report.quality`) can still be read (it is gone afterwards)."""
    if any(m < 0 for m in setup.remaining_m):
        raise UsageError("the filament remaining on a reel cannot be negative")
    kind = head_kind(setup.head)
    with _prepared(source, setup, kind) as (job, virtual):
        fw = virtual.firmware
        report = Report(str(source), setup.head.strip().upper(),
                        job.translation.as_dict() if job.translation else None, job.lines)
        watch = Watch(fw, kind != "plain")
        dep = virtual.hw.machine.deposition
        if job.translation is not None and job.translation.start_lines and dep is not None:
            watch.start_lines = job.translation.start_lines
            watch.deposition = dep
            dep.judging = False
        _print(virtual, watch, report, progress, setup, kind)
        _judge(virtual, report, job)
        if judged is not None:
            judged(report)
        report.quality = None
    return report


def _judge(virtual: VirtualPrinter, report: Report, job: JobFile) -> None:
    """The deposition figures, and the worst places with their job lines."""
    machine = virtual.hw.machine
    dep = machine.deposition
    if dep is None:
        return
    dep.finish()
    p = virtual.firmware.position
    offsets = [(p._tool_float(n, 0) + p.pa["x_offset"], p._tool_float(n, 8) + p.pa["y_offset"],
                p._tool_float(n, 16)) for n in range(2)]
    quality = Quality(dep, offsets, BED_MM)
    figures, worst = quality.figures()
    find_lines(job.path, worst)
    figures["pushed_into_shut_head_mm3"] = round(dep.shut_fed_mm3, 3)
    figures["worst"] = [place.as_dict() for place in worst]
    report.deposition = figures
    report.quality = quality
    report.quality_worst = worst


def _print(virtual: VirtualPrinter, watch: Watch, report: Report,
           progress: Callable[[int, int], None] | None, setup: Setup, kind: str) -> None:
    fw = virtual.firmware
    heaters = fw.hw.machine.heaters
    watch.watch_heaters([heaters[name] for name in HEATERS])
    latched = _errors(virtual)
    watch.attach()
    extruded = list(fw.position.extruded_mm)
    started = fw.clock.now
    finished = fw.job.jobs_completed
    virtual.transact(b"\x94" + make_id(JOB_ID))
    pauses: list[int] = []
    passes = watch.passes()
    while True:
        virtual.run_until(passes, POLL_S)
        if fw.position.watcher is None:  # the printer was reset: a new position object
            watch.attach()
        bits = _errors(virtual)
        job = fw.job
        if progress:
            progress(job.line_number if job.running else report.lines, report.lines)
        if not job.running:
            report.completed = job.jobs_completed > finished
            if not report.completed:
                report.errors.append(f"the job was aborted at line {watch.reached}")
            break
        if fw.clock.now - started > MAX_PRINT_S:
            report.errors.append(f"still printing after {MAX_PRINT_S / 3600:.0f} hours "
                                 f"(line {job.line_number}); given up")
            break
        if job.pause and not job.aborting():  # (an abort under way ends the job)
            stopping = bits & PAUSE_MASK_CONNECTED & ~latched
            if stopping:
                report.errors.append(f"the printer paused the job at line {job.line_number}"
                                     f": {', '.join(error_names(stopping))}")
                break
            pauses.append(job.line_number)
            virtual.transact(b"\x980")
    report.print_time_s = fw.clock.now - started
    report.lines_run = report.lines if report.completed else watch.reached
    report.peak_c = {name: round(value, 1) for name, value in zip(HEATERS, watch.peak,
                                                                   strict=True)}
    bits = _errors(virtual) & ~latched
    report.errors += [f"the printer reports {name}" for name in error_names(bits)]
    _volumes(fw, watch, report, extruded, setup, kind)
    _warnings(watch, report, pauses)


def _volumes(fw, watch: Watch, report: Report, extruded: list[float], setup: Setup,
             kind: str) -> None:
    p = fw.position
    for n, (name, reel) in enumerate((("E", "reel0"), ("D", "reel1"))):
        mm = p.extruded_mm[n] - extruded[n]
        if kind != "dual" and n == 1 and not mm:
            continue
        area = _area(p.diameter[n]) / (p.multiplier[n] or 1.0)
        report.extruders[name] = {
            "reel": reel, "filament_m": round(mm / 1000.0, 3), "mm3": round(mm * area, 1),
            "diameter_mm": round(p.diameter[n], 3),
            "reel_remaining_m": setup.remaining_m[n] if kind == "dual" or n == 0 else None}
        if watch.shut_mm[n] > 0.0:
            report.warnings.append(
                f"{watch.shut_mm[n] * area:.1f} mm3 pushed into the nozzle from extruder {name} "
                f"with the valve shut ({_lines_text(watch.shut_lines)})")
        remaining = report.extruders[name]["reel_remaining_m"]
        if remaining is not None and mm / 1000.0 > remaining:
            report.warnings.append(
                f"extruder {name} needs {mm / 1000.0:.2f} m of filament; {reel} holds "
                f"{remaining:.2f} m: it runs out")
    if watch.low[0] <= watch.high[0]:
        report.extent_mm = {axis: [round(watch.low[i], 3), round(watch.high[i], 3)]
                            for i, axis in enumerate("XYZ")}


def _warnings(watch: Watch, report: Report, pauses: list[int]) -> None:
    if watch.outside_lines:
        ext = report.extent_mm or {}
        report.warnings.append(
            f"extrusion outside the {BED_MM[0]:.0f} x {BED_MM[1]:.0f} mm build plate (X "
            f"{ext['X'][0]:.1f}..{ext['X'][1]:.1f}, Y {ext['Y'][0]:.1f}..{ext['Y'][1]:.1f}; "
            f"{_lines_text(watch.outside_lines)})")
    if watch.clamped_lines:
        report.warnings.append(
            "moves beyond the axes' travel, stopped at its end "
            f"({_lines_text(watch.clamped_lines)})")
    if pauses:
        report.warnings.append(f"the job pauses itself ({_lines_text(pauses)}); resumed")
