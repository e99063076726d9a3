"""Calibrating a head: the Z heights, needle openings and X/Y alignment of its nozzles,
measured on the printer and written to the head's EEPROM (AutoMaker's calibration
wizards as guided sequences, on robox.maintenance's `Sequence`).

Each calibration reads the head's EEPROM first and keeps it. It writes the head whole,
in one command and read back: while it measures (offsets cleared, trial B offsets), and
with what it found as its last step. Ctrl-C or an error at any step puts the kept data
back (the hours the firmware counted meanwhile stay counted) after the printer's abort
has switched the heaters off.

- `nozzle-height` (AutoMaker's nozzle height calibration): the nozzles' Z offsets
  cleared, the nozzles heated, the gantry levelled, then the bed probed in the middle
  with each nozzle in turn, eleven times (G28 Z? and M113: how far from where the last
  home put the bed), nozzle 1 minus nozzle 0 averaged over its six pairs: the Z
  difference. Then nozzle 0 is raised in 0.05 mm steps until a sheet of paper just
  drags under it (the person says when; `--paper-z` answers for a script). Written:
  nozzle 0's Z offset -(paper Z) - difference/2, nozzle 1's -(paper Z) + difference/2
  (AutoMaker's split). The probe's resolution is the Z motor's microstep, 1/6400 mm.
- `nozzle-opening` (AutoMaker's nozzle opening calibration, with a finer step): needs
  filament at the nozzle. For each nozzle the head is told its needle shuts at
  `B_START` (nozzle 1: -`B_START`), the feed is pressurised against the shut needle
  (G36) and the valve is opened in `B_STEP` steps; the person says when plastic first
  comes out (`--opens-at B0,B1` answers with the B values shown). The needle's seat
  lies between that B and the step before; the step before is written as the nozzle's
  B offset, so a job's B 0 keeps the needle shut (as AutoMaker wrote it). AutoMaker
  started at 0.75 in 0.05 steps, so a seat below 0.75 read as 0.7; this starts lower
  and steps finer.
- `xy` (AutoMaker's X and Y alignment): a pattern printed on the bed, eleven pairs of
  lines across X (A to K) and eleven along Y (1 to 11), each pair one line from each
  nozzle with nozzle 1's shifted by `XY_STEP` times (pair - middle); the person says
  which pair lines up (`--x-pair`, `--y-pair`). Written as AutoMaker wrote it: each
  nozzle's offset moved half the step per pair, the two in opposite directions.
"""

from __future__ import annotations

import contextlib
import math

from robox.errors import RoboxError, UsageError
from robox.formats import eeprom as fmt
from robox.formats.heads import head_kind, head_valves, max_temperature
from robox.maintenance import LEVEL_GANTRY, SENSOR_AT, Sequence, head_type_of, write_head, z_delta

#: probes of AutoMaker's Z difference measurement (alternately nozzle 1 and nozzle 0)
Z_PROBES = 11
PAPER_STEP_MM = 0.05
PAPER_MAX_MM = 2.0
#: where the needle-opening search starts, and its step (B units)
B_START = 0.3
B_STEP = 0.02
B_LAST = 1.5
#: the alignment pattern: pairs, their spacing, and nozzle 1's shift per pair
XY_PAIRS = 11
XY_STEP = 0.05
X_LETTERS = "ABCDEFGHIJK"
PROBE_AT = (105.0, 75.0)
PATTERN_LINE_MM = 12.0
PATTERN_LAYER_MM = 0.3


def number(value: float) -> str:
    """A G-code number: at most four decimals, no trailing zeros."""
    text = f"{value:.4f}".rstrip("0").rstrip(".")
    return "0" if text in ("-0", "") else text


class Calibration(Sequence):
    """A sequence that changes the head's EEPROM: what it held is kept and put back after
    Ctrl-C or an error."""

    def __init__(self, *args, head: dict | None = None, reels: dict | None = None,
                 **kwargs):
        super().__init__(*args, **kwargs)
        self.head = head or {}
        self.reels = reels or {}
        self.saved: bytes | None = None

    def head_type(self) -> str:
        return head_type_of(self.head, self.name)

    def nozzles(self) -> list[int]:
        if head_kind(self.head_type()) == "plain":
            raise UsageError(f"{self.name}: a {self.head_type()} head has one nozzle: "
                             "there is nothing to calibrate between nozzles")
        return [0, 1]

    def heaters(self) -> dict[int, float]:
        """Each heater of the head at its reel's nozzle temperature (a single-material
        head: one heater, reel 0's)."""
        head_type = self.head_type()
        limit = max_temperature(head_type)
        valves = head_valves(head_type)
        heaters: dict[int, float] = {}
        for n in ([0, 1] if head_kind(head_type) == "dual" else [0]):
            which = "reel0" if valves.feeds[n] == "E" else "reel1"
            reel = self.reels.get(which)
            if reel is None:
                raise RoboxError(f"{self.name}: nozzle {n} is fed from {which}, which has "
                                 "no valid EEPROM (is the reel in place?)")
            reel_c = float(reel["nozzle_temperature"])
            if not (math.isfinite(reel_c) and reel_c > 0):
                raise RoboxError(f"{self.name}: {which} gives no nozzle temperature (a "
                                 "blank reel: robox-cli reel program writes one)")
            heaters[n] = min(limit, reel_c)
        return heaters

    def keep_head(self) -> None:
        self.step("read and keep the head's EEPROM")
        if not self.dry_run:
            self.saved = self.printer.read_eeprom("head")

    def write_head(self, text: str, assignments: dict[str, float]) -> None:
        """The kept head data with `assignments`, written whole and read back."""
        self.step(text + "".join((": " if i == 0 else ", ") + f"{k} {number(v)}"
                                 for i, (k, v) in enumerate(assignments.items())))
        if self.dry_run:
            return
        assert self.saved is not None
        hours_field = fmt.field("head", "head_hours")
        now = self.printer.read_eeprom("head")  # the hours as the firmware has counted them
        write_head(self.printer, self.saved, assignments, self.name,
                   hours=now[hours_field.offset:hours_field.offset + hours_field.size])

    def report_written(self, *names: str) -> None:
        """The fields written, as the head's EEPROM now reads them."""
        if self.dry_run:
            return
        data = self.printer.read_eeprom("head")
        self.report.written = {"head": {name: fmt.shown_fields("head", data)[name]
                                        for name in names}}

    def restore(self) -> None:
        super().restore()
        if self.saved is None:
            return
        with contextlib.suppress(RoboxError, OSError):
            self.write_head("put the head's data back", {})

    def heat_all(self) -> None:
        self.heat(self.heaters())

    def finish(self) -> None:
        self.send("heaters off, the head up and the bed to the front",
                  ["M104 S0 T0", "M140 S0", "G90", "G0 Z25", "G0 X105 Y150"])
        self.heating = False



class NozzleHeight(Calibration):
    """The nozzles' Z offsets: the Z difference between them, probed, and nozzle 0's
    height over the bed, judged with a sheet of paper."""

    name = "calibrate nozzle-height"
    questions = ("yes", "paper_z")

    def steps(self) -> None:
        self.nozzles()
        self.heaters()
        self.question("yes", "Calibrate the nozzle heights? The head homes, heats and probes "
                             "the bed with each nozzle; the bed must be clean. Have a sheet "
                             "of paper ready.")
        self.keep_head()
        self.write_head("clear the nozzles' Z offsets while measuring",
                        {"nozzle0_z_offset": 0.0, "nozzle1_z_offset": 0.0})
        self.send("home", ["G90", "T0", "G28 X Y", "G28 Z"])
        self.heat_all()
        x, y = PROBE_AT
        self.send("level the gantry",
                  ["G0 Z5", "G0 X30 Y75", "G28 Z", "G0 Z5", "G0 X190 Y75", "G28 Z", "G0 Z5",
                   "G38", f"G0 X{number(x)} Y{number(y)}", "G28 Z", "G0 Z5"])
        deltas: dict[int, list[float]] = {0: [0.0], 1: []}
        self.step(f"probe the bed {Z_PROBES} times, nozzle 1 and nozzle 0 in turn "
                  "(G28 Z?, M113)")
        if not self.dry_run:
            for k in range(Z_PROBES):
                nozzle = 1 if k % 2 == 0 else 0
                self.run_lines([f"T{nozzle}", "G28 Z?"])
                deltas[nozzle].append(z_delta(self.printer, self.name))
        else:
            self.say("    T1, G28 Z?, M113, T0, G28 Z?, M113, ...")
        pairs = (Z_PROBES + 1) // 2
        difference = 0.0
        if not self.dry_run:
            difference = sum(deltas[1][i] - deltas[0][i] for i in range(pairs)) / pairs
            self.report.measured["z_difference_mm"] = round(difference, 6)
            self.report.measured["z_deltas_mm"] = {f"nozzle{n}": v for n, v in deltas.items()}
            self.say(f"nozzle 1's tip is {difference:.4f} mm below nozzle 0's")
        self.send("nozzle 0 over the middle of the bed, 5 mm up",
                  ["T0", f"G0 X{number(x)} Y{number(y)}", "G28 Z", "G0 Z5"])
        paper = self.paper_height()
        self.report.measured["paper_z_mm"] = paper
        self.write_head("write the nozzles' Z offsets",
                        {"nozzle0_z_offset": -paper - 0.5 * difference,
                         "nozzle1_z_offset": -paper + 0.5 * difference})
        self.report_written("nozzle0_z_offset", "nozzle1_z_offset")
        self.saved = None  # (what is written stays)
        self.finish()

    def paper_height(self) -> float:
        """Nozzle 0 raised from the bed in PAPER_STEP_MM steps until the person says a
        sheet of paper just drags under it; the height (or --paper-z's)."""
        given = self.answers.get("paper_z")
        if self.dry_run:
            self.step("ask: slide a sheet of paper under nozzle 0 and raise or lower it "
                      "until the paper just drags (--paper-z)")
            return 0.0 if given is None else float(given)
        if given is not None:
            z = float(given)
            self.send(f"nozzle 0 to Z {number(z)} (--paper-z)", [f"G0 Z{number(z)}"])
            return z
        if self.choose is None:
            raise UsageError("Not at a terminal: answer the paper question with --paper-z")
        z = 0.0
        self.send("nozzle 0 down to the bed", ["G0 Z0"])
        while True:
            answer = self.choose(
                "paper_z", f"Nozzle 0 is at Z {z:.2f} mm. Slide the paper under it: does it "
                           "just drag? (y: yes; u: up 0.05 mm; d: down 0.05 mm)",
                ("y", "u", "d"))
            if answer == "y":
                return round(z, 2)
            z = min(PAPER_MAX_MM, z + PAPER_STEP_MM) if answer == "u" else \
                max(0.0, z - PAPER_STEP_MM)
            self.run_lines([f"G0 Z{number(z)}"])


class NozzleOpening(Calibration):
    """The B offsets: where each nozzle's needle just opens, watched with filament in."""

    name = "calibrate nozzle-opening"
    questions = ("yes", "opens_at")

    def steps(self) -> None:
        head_type = self.head_type()
        valves = head_valves(head_type)
        if not valves.has_valve:
            raise UsageError(f"{self.name}: a {head_type} head has no valve")
        self.heaters()
        if not self.dry_run:
            raw = self.printer.status().raw
            for feed in sorted(set(valves.feeds)):
                if raw[SENSOR_AT[feed]:SENSOR_AT[feed] + 1] != b"1":
                    raise RoboxError(f"{self.name}: feed {feed} has no filament at its "
                                     "sensor: load it first (robox-cli load)")
        given = self.answers.get("opens_at")
        self.question("yes", "Calibrate the nozzle openings? The head heats and pushes "
                             "filament against each shut needle, then opens it a little "
                             "at a time: watch for plastic at the nozzle.")
        self.keep_head()
        self.send("home", ["G90", "T0", "G28 X Y", "G28 Z"])
        self.heat_all()
        self.send("the head up over the middle of the bed",
                  [f"G0 X{number(PROBE_AT[0])} Y{number(PROBE_AT[1])}", "G0 Z50"])
        found: dict[int, float] = {}
        for n in (0, 1):
            sign = 1.0 if n == 0 else -1.0
            feed = valves.feeds[n]
            self.write_head(f"tell the head nozzle {n}'s needle shuts at B "
                            f"{number(sign * B_START)}",
                            {f"nozzle{n}_b_offset": sign * B_START,
                             **{f"nozzle{m}_b_offset": v for m, v in found.items()}})
            self.send(f"pressurise feed {feed} against nozzle {n}'s shut needle",
                      [f"T{n}", "G0 B0", f"G36 {feed}100 F800"])
            found[n] = self.search(n, sign, None if given is None else given[n])
            self.send(f"shut nozzle {n}", ["G0 B0"])
        self.report.measured = {f"nozzle{n}_opens_at": number(v + sign_of(n) * B_STEP)
                                for n, v in found.items()}
        self.write_head("write the needles' B offsets (the last B each stayed shut)",
                        {f"nozzle{n}_b_offset": v for n, v in found.items()})
        self.report_written(*(f"nozzle{n}_b_offset" for n in found))
        self.saved = None
        self.finish()

    def search(self, n: int, sign: float, given: float | None) -> float:
        """Open nozzle n's needle a step at a time until plastic comes out; the last B it
        stayed shut at."""
        if self.dry_run:
            self.step(f"ask at each B from {number(sign * B_START)} in steps of "
                      f"{number(B_STEP)}: is plastic coming out of nozzle {n}? (--opens-at)")
            return sign * B_START
        if given is None and self.choose is None:
            raise UsageError("Not at a terminal: answer the opening question with --opens-at")
        k = 0
        while True:
            b = B_START + k * B_STEP
            if b > B_LAST + 1e-9:
                raise RoboxError(f"{self.name}: no plastic from nozzle {n} up to B "
                                 f"{number(sign * B_LAST)} (is the filament at the nozzle?)")
            self.send(f"nozzle {n}'s valve to B {number(sign * b)}",
                      [f"G0 B{number(b - B_START)}"])
            if given is not None:  # (the B shown: nozzle 1's negative)
                out = b >= sign * given - 1e-9
            else:
                out = self.choose("opens_at", f"B {sign * b:.2f}: is plastic coming out of "
                                              f"nozzle {n}? (y/n)", ("y", "n")) == "y"
            if out:
                if k == 0:
                    raise RoboxError(f"{self.name}: nozzle {n} was already open at B "
                                     f"{number(sign * B_START)}: its needle does not shut")
                return sign * (b - B_STEP)
            k += 1


def sign_of(n: int) -> float:
    return 1.0 if n == 0 else -1.0


class XYAlignment(Calibration):
    """The nozzles' X and Y offsets, from a printed pattern the person reads."""

    name = "calibrate xy"
    questions = ("yes", "x_pair", "y_pair")

    def pattern(self, valves) -> list[list[str]]:
        """Eleven pairs of lines across X, eleven along Y; nozzle 1's line of pair k
        shifted by (k - 5) x XY_STEP. A group of lines per printed line, each run as one
        command so that the head does not stop on it: the valve opened at the line's
        start with the plastic that fills the void the needle leaves, the line laid at
        the nozzle's width, and the valve closed on the move over its last part, the
        needle pushing out what that part needs (as jobs are translated)."""
        groups: list[list[str]] = []
        middle = XY_PAIRS // 2
        for n in (0, 1):
            feed = valves.feeds[n]
            flow = valves.diameters_mm[n] * PATTERN_LAYER_MM  # mm3 per mm of line
            ejection = valves.ejection_mm3[n]
            closing = min(PATTERN_LINE_MM / 2, ejection / flow)
            laid = PATTERN_LINE_MM - closing
            # pressurised against the shut needle, then a prime line in front of the
            # pattern takes what the head held (its first opening lets it all out)
            prime = 40.0 + 25.0 * n
            groups.append(["G0 Z1", f"T{n}", "G0 B0", f"G0 X{number(prime)} Y30",
                           f"G0 Z{PATTERN_LAYER_MM:g}", f"G36 {feed}100 F800",
                           f"G1 B1 {feed}{number(ejection)} F300",
                           f"G1 X{number(prime + 15)} {feed}{number(flow * 15)} F600",
                           f"G1 X{number(prime + 20)} B0 F600", "G0 Z1"])
            for k in range(XY_PAIRS):
                shift = (k - middle) * XY_STEP if n == 1 else 0.0
                # across X: lines along Y at X 40 + 5k (nozzle 1's beyond nozzle 0's in
                # Y); along Y: lines along X at Y 80 + 5k (nozzle 1's beyond in X)
                for along, at, start in (("Y", 40.0 + 5.0 * k + shift, 40.0),
                                         ("X", 80.0 + 5.0 * k + shift, 40.0)):
                    start += 0.0 if n == 0 else PATTERN_LINE_MM + 1.0
                    across = "X" if along == "Y" else "Y"
                    groups.append([
                        f"G0 {across}{number(at)} {along}{number(start)}",
                        f"G0 Z{PATTERN_LAYER_MM:g}",
                        f"G1 B1 {feed}{number(ejection)} F300",
                        f"G1 {along}{number(start + laid)} {feed}{number(flow * laid)} F600",
                        f"G1 {along}{number(start + PATTERN_LINE_MM)} B0 F600", "G0 Z1"])
        return groups

    def steps(self) -> None:
        head_type = self.head_type()
        self.nozzles()
        valves = head_valves(head_type)
        heaters = self.heaters()
        reel = self.reels.get("reel0") or {}
        bed = float(reel.get("first_layer_bed_temperature", 0.0) or 0.0)
        x_pair = self.answers.get("x_pair")
        y_pair = self.answers.get("y_pair")
        self.question("yes", "Calibrate the nozzles' X and Y alignment? The printer prints a "
                             "pattern of lines from both nozzles on the bed; have the bed "
                             "clean.")
        self.keep_head()
        self.send("home and level the gantry", LEVEL_GANTRY)
        if bed > 0 and math.isfinite(bed):
            self.send(f"heat the bed to {bed:g} °C", [f"M140 S{bed:g}"])
        self.heat(heaters)
        self.send_groups("print the alignment pattern (X pairs A to K, Y pairs 1 to 11)",
                         self.pattern(valves))
        self.send("heaters off, the head up and the bed to the front",
                  ["M104 S0 T0", "M140 S0", "G0 Z25", "G0 X105 Y150"])
        self.heating = False
        middle = XY_PAIRS // 2
        letter = self.pick("x_pair", x_pair, "Look at the lines across X (pairs A to K, left "
                           "to right): which pair lines up best?", tuple(X_LETTERS))
        digit = self.pick("y_pair", y_pair, "Look at the lines along Y (pairs 1 to 11, front "
                          "to back): which pair lines up best?",
                          tuple(str(k + 1) for k in range(XY_PAIRS)))
        kx = X_LETTERS.index(letter) - middle
        ky = int(digit) - 1 - middle
        self.report.measured = {"x_pair": letter, "y_pair": digit,
                                "nozzle1_off_by_mm": [round(-kx * XY_STEP, 4),
                                                      round(-ky * XY_STEP, 4)]}
        half = XY_STEP / 2.0
        saved = self.head
        self.write_head("write the nozzles' X and Y offsets",
                        {"nozzle0_x_offset": float(saved["nozzle0_x_offset"]) - kx * half,
                         "nozzle1_x_offset": float(saved["nozzle1_x_offset"]) + kx * half,
                         "nozzle0_y_offset": float(saved["nozzle0_y_offset"]) - ky * half,
                         "nozzle1_y_offset": float(saved["nozzle1_y_offset"]) + ky * half})
        self.report_written("nozzle0_x_offset", "nozzle1_x_offset", "nozzle0_y_offset",
                            "nozzle1_y_offset")
        self.saved = None

    def pick(self, key: str, given: str | None, text: str, choices: tuple[str, ...]) -> str:
        if self.dry_run:
            self.step(f"ask: {text} (--{key.replace('_', '-')})")
            return choices[len(choices) // 2]
        if given is not None:
            return given
        if self.choose is None:
            raise UsageError(f"{text} Not at a terminal: answer with --{key.replace('_', '-')}")
        return self.choose(key, text, choices)
