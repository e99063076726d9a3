"""Looking after the printer: jobs AutoMaker's wizards did that are not prints, as
guided sequences any printer robox-cli drives can run.

A sequence is a list of steps: G-code sent line by line through the execute buffer
(0x95) and waited out by watching the status report, questions for the person at the
printer, readings, and EEPROM writes. Every question has a key an option answers, so a
script or a test can drive a sequence; a question nobody answers away from a terminal
is refused rather than waited on. `--dry-run` lists the steps and sends nothing.

Ctrl-C or an error at any step runs the sequence's restore before it ends: the printer
is told to abort (which empties its queues and switches every heater off, 0xff) and the
heaters are switched off by G-code too; an EEPROM is only ever written whole, in one
command, as a sequence's last step, so it holds the old data or the new.

Where AutoMaker's behaviour is followed and where not, per sequence:

- `purge`: the purge temperature is AutoMaker's, halfway from the material the head
  last melted (its EEPROM) to the reel's, at least 180 °C and at most the head's
  maximum; the head is homed and the gantry levelled, the nozzles heated and waited
  for here (within 5 °C, as AutoMaker waited), each nozzle's feed pressurised
  against its shut needle (G36) and purge lines laid along the front of the bed,
  and the reel's temperature written to the head as the material it last melted
  (what makes the printer stop asking for a purge). Unlike AutoMaker the bed is not
  heated to 90 °C first: the lines are scrap, and a cold bed saves minutes.
- `level-gantry`: AutoMaker's two-point levelling (Z homed at each leadscrew, G38,
  Z homed in the middle) and the Z difference the printer measured (M113).
- `unload`: the firmware's own unload (M122: it heats for it, moves the carriage to the
  right and pulls the filament back).
- `load`: the printer's own automatic load (the index wheel turning with nothing at the
  sensor starts it); the sequence asks while the person pushes the filament in, waits
  while the printer loads it to the nozzle and checks the sensor sees it.
- `eject-stuck`: AutoMaker's Eject stuck material: a dual-material head's nozzles each
  freed in turn with its own heater and feed (its macros' 160 °C neck and 120 mm3 push).
- `head-change`: AutoMaker's Remove head (home, T0 with the valve shut, park at the
  front, unload every feed the head has, unlock the door), then a question while the
  head is changed and the new head's EEPROM read. Like AutoMaker it leaves the head's
  power on.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from robox.errors import RoboxError, UsageError
from robox.formats.heads import head_kind, head_valves, max_temperature
from robox.formats.protocol import error_names
from robox.host.client import Status

#: how close a nozzle must come to its target before the sequence goes on (AutoMaker's)
TEMPERATURE_MARGIN_C = 5.0
#: AutoMaker's floor for a purge temperature
PURGE_MIN_C = 180.0
PURGE_LINES_PER_NOZZLE = 3
PURGE_MM3_PER_LINE = 20.0
POLL_S = 0.5
HEAT_TIMEOUT_S = 900.0
MOVE_TIMEOUT_S = 600.0

LEVEL_GANTRY = ("G90", "G28 X Y", "G0 X20 Y75", "G28 Z", "G0 X200 Y75", "G28 Z", "G38",
                "G0 X113 Y75", "G28 Z")


class Declined(RoboxError):
    """The person at the printer said no: nothing more is done."""


Ask = Callable[[str, str], bool]
#: a question with several answers (key, text, choices): the one chosen
Choose = Callable[[str, str, tuple[str, ...]], str]


@dataclass
class Report:
    """What a sequence did: its steps, what it measured and what it wrote."""

    sequence: str
    dry_run: bool
    steps: list[str] = field(default_factory=list)
    measured: dict = field(default_factory=dict)
    written: dict = field(default_factory=dict)


class Sequence:
    """One run of a guided sequence on `printer` (None with `dry_run`)."""

    name = ""
    #: the options that answer its questions (away from a terminal, all must be given)
    questions: tuple[str, ...] = ("yes",)

    def __init__(self, printer, answers: dict, ask: Ask | None,
                 say: Callable[[str], None], dry_run: bool = False,
                 choose: Choose | None = None):
        self.printer = printer
        self.answers = answers
        self.ask = ask
        self.choose = choose
        self.say = say
        self.dry_run = dry_run
        self.report = Report(self.name, dry_run)
        self.heating = False

    # ------------------------------------------------------------ running
    def run(self) -> Report:
        if self.ask is None and not self.dry_run:
            missing = [k for k in self.questions if self.answers.get(k) is None]
            if missing:
                raise UsageError(f"{self.name} asks questions; not at a terminal: answer "
                                 f"them with {' '.join('--' + k for k in missing)}")
        try:
            self.steps()
        except BaseException:
            if not self.dry_run:
                self.restore()
            raise
        return self.report

    def steps(self) -> None:  # pragma: no cover - each sequence has its own
        raise NotImplementedError

    def restore(self) -> None:
        """After Ctrl-C or an error: nothing left moving or hot. Best effort: a printer
        that has gone cannot be told."""
        try:
            self.printer.abort()
            if self.heating:
                for line in ("M104 S0 T0", "M140 S0"):
                    self.printer.gcode(line + "\r")
        except (RoboxError, OSError):
            pass

    # ------------------------------------------------------------ steps
    def step(self, text: str) -> None:
        self.report.steps.append(text)
        self.say(("would: " if self.dry_run else "") + text)

    def question(self, key: str, text: str) -> None:
        """A yes-or-no question for the person at the printer; `key` is the option that
        answers it. No: Declined."""
        if self.dry_run:
            self.step(f"ask: {text} (--{key})")
            return
        answer = self.answers.get(key)
        if answer is None:
            if self.ask is None:
                raise UsageError(f"{text} Not at a terminal: answer with --{key}")
            answer = self.ask(key, text)
        if not answer:
            raise Declined(f"{self.name}: stopped at the question: {text}")

    def send(self, text: str, lines: tuple[str, ...] | list[str]) -> None:
        """G-code lines through the execute buffer, then wait until the printer has
        run them (its status idle)."""
        self.step(text)
        if self.dry_run:
            for line in lines:
                self.say(f"    {line}")
            return
        self.run_lines(lines)

    def run_lines(self, lines: tuple[str, ...] | list[str]) -> None:
        """G-code lines through the execute buffer, each waited out (no step said)."""
        known = self.printer.errors()
        for line in lines:
            self.printer.gcode(line + "\r")
            self.wait_idle(known, MOVE_TIMEOUT_S)

    def send_groups(self, text: str, groups: list[list[str]]) -> None:
        """Each group of G-code lines as one command (the execute buffer runs them in
        turn, so the head does not stop between them), then wait until the printer has
        run them."""
        self.step(text)
        if self.dry_run:
            for group in groups:
                self.say("    " + " | ".join(group))
            return
        known = self.printer.errors()
        for group in groups:
            self.printer.gcode("".join(line + "\r" for line in group))
            self.wait_idle(known, MOVE_TIMEOUT_S)

    def watch(self, known_errors: int, until: Callable[[Status], bool], timeout_s: float,
              failure: str) -> None:
        """Look at the status every POLL_S until `until(status)` holds; a fresh error, or
        `timeout_s` gone by (RoboxError `failure`), ends the wait."""
        start = time.monotonic()
        while True:
            status = self.printer.status()
            self.check_errors(known_errors)
            if until(status):
                return
            if time.monotonic() - start > timeout_s:
                raise RoboxError(f"{self.name}: {failure}")
            self.printer.idle(POLL_S)

    def wait_idle(self, known_errors: int, timeout_s: float) -> None:
        """Until two looks POLL_S apart find the printer idle (a line between two of
        its moves, homing say, can show idle for a moment)."""
        idle = [0]

        def twice_idle(status: Status) -> bool:
            idle[0] = idle[0] + 1 if not status.busy else 0
            return idle[0] >= 2

        self.watch(known_errors, twice_idle, timeout_s,
                   f"the printer was still busy after {timeout_s:g} s")

    def check_errors(self, known: int) -> None:
        fresh = self.printer.errors() & ~known
        if fresh:
            raise RoboxError(f"{self.name}: the printer reported "
                             f"{', '.join(error_names(fresh))}")

    def heat(self, targets: dict[int, float]) -> None:
        """Nozzle targets set, then waited for (within TEMPERATURE_MARGIN_C)."""
        words = " ".join(("S" if n == 0 else "T") + f"{t:g}" for n, t in sorted(targets.items()))
        self.step(f"heat nozzle{'s' if len(targets) > 1 else ''} "
                  + ", ".join(f"{n} to {t:g} °C" for n, t in sorted(targets.items())))
        if self.dry_run:
            self.say(f"    M104 {words}")
            return
        self.heating = True
        known = self.printer.errors()
        self.printer.gcode(f"M104 {words}\r")

        def hot(status: Status) -> bool:
            if not status.head_power:
                raise RoboxError(f"{self.name}: the head's power is off (errors: "
                                 f"{', '.join(error_names(self.printer.errors())) or 'none'})")
            return all(status.temperatures[f"nozzle{n}"]["measured"] >= t - TEMPERATURE_MARGIN_C
                       for n, t in targets.items())

        self.watch(known, hot, HEAT_TIMEOUT_S, "the nozzle did not reach its temperature")

    def cool(self, nozzle: int, target: float) -> None:
        """Set a nozzle's target below where it is and wait until it has come down to it
        (within TEMPERATURE_MARGIN_C)."""
        word = "S" if nozzle == 0 else "T"
        self.step(f"let nozzle {nozzle} cool to {target:g} °C")
        if self.dry_run:
            self.say(f"    M104 {word}{target:g}")
            return
        known = self.printer.errors()
        self.printer.gcode(f"M104 {word}{target:g}\r")
        self.watch(known, lambda status: status.temperatures[f"nozzle{nozzle}"]["measured"]
                   <= target + TEMPERATURE_MARGIN_C, HEAT_TIMEOUT_S,
                   f"the nozzle did not cool to {target:g} °C")


def write_head(printer, data: bytes, assignments: dict, who: str,
               hours: bytes | None = None) -> None:
    """The head's data (`data`, with `assignments` and, where given, `hours` in place of
    its hours field) written whole in one command and read back. The hours are left out
    of the comparison: the firmware counts a hot head's hours on, and writes them, in
    between."""
    from robox.formats import eeprom as fmt

    hours_field = fmt.field("head", "head_hours")
    where = slice(hours_field.offset, hours_field.offset + hours_field.size)
    out = bytearray(data)
    if hours is not None:
        out[where] = hours
    for name, value in assignments.items():
        fmt.set_field(out, "head", name, value)
    printer.write_eeprom("head", 0, bytes(out))
    back = bytearray(printer.read_eeprom("head"))
    back[where] = fmt.mask7(bytes(out[where]))
    if bytes(back) != fmt.mask7(bytes(out)):
        raise RoboxError(f"{who}: the head EEPROM reads back other than was written")


def head_type_of(head: dict, who: str) -> str:
    """The type code of the head's EEPROM fields (RoboxError where it gives none)."""
    head_type = str(head.get("type_code", "") or "")
    if not head_type:
        raise RoboxError(f"{who}: the head's EEPROM gives no head type (is the head in "
                         "place? a formatted head needs its data written back)")
    return head_type


def chosen_nozzles(head_type: str, nozzle: int | None, who: str) -> list[int]:
    """The head's nozzles, or the one `nozzle` names (UsageError where it has none)."""
    nozzles = [0] if head_kind(head_type) == "plain" else [0, 1]
    if nozzle is None:
        return nozzles
    if nozzle not in nozzles:
        raise UsageError(f"{who}: a {head_type} head has no nozzle {nozzle}")
    return [nozzle]


def z_delta(printer, who: str) -> float:
    """M113: how far the last Z home found the bed from where the one before put it."""
    reply = printer.gcode("M113\r")
    for part in reply.replace("\r", "\n").split("\n"):
        if part.startswith("Zdelta:"):
            return float(part.split(":", 1)[1])
    raise RoboxError(f"{who}: the printer's M113 reply has no Z delta: {reply!r}")


def purge_temperature(last_c: float, reel_c: float, head_max_c: float) -> float:
    """AutoMaker's purge temperature: halfway from the material the head last melted to
    the reel's, at least 180 °C, at most the head's maximum (whole degrees)."""
    if not math.isfinite(last_c) or last_c <= 0:
        last_c = reel_c
    return float(int(min(head_max_c, max(PURGE_MIN_C, last_c + (reel_c - last_c) / 2))))


class Purge(Sequence):
    """Purge the nozzle(s) of the old material after a material change."""

    name = "purge"

    def __init__(self, *args, nozzle: int | None = None, temperature: float | None = None,
                 head: dict | None = None, reels: dict | None = None, **kwargs):
        super().__init__(*args, **kwargs)
        self.nozzle = nozzle
        self.temperature = temperature
        self.head = head or {}
        self.reels = reels or {}

    def plan(self) -> tuple[dict[int, dict], dict[int, float]]:
        """The nozzles purged, each with its feed; and the heaters, each with its reel's
        temperature, the material the head last melted and the purge temperature. A
        single-material head has one heater for both nozzles and both are purged (as
        AutoMaker did); a dual-material head a heater per nozzle."""
        head_type = head_type_of(self.head, self.name)
        kind = head_kind(head_type)
        valves = head_valves(head_type)
        nozzles = chosen_nozzles(head_type, self.nozzle, self.name)
        limit = max_temperature(head_type)
        purged: dict[int, dict] = {}
        heaters: dict[int, dict] = {}
        for n in nozzles:
            feed = valves.feeds[n] if n < len(valves.feeds) else "E"
            heater = n if kind == "dual" else 0
            purged[n] = {"feed": feed, "heater": heater}
            if heater in heaters:
                continue
            which = "reel0" if feed == "E" else "reel1"
            reel = self.reels.get(which)
            if reel is None:
                raise RoboxError(f"purge: nozzle {n} is fed from {which}, which has no "
                                 "valid EEPROM (is the reel in place?)")
            reel_c = float(reel["nozzle_temperature"])
            last_c = float(self.head.get(f"nozzle{heater}_last_filament_temperature", 0.0)
                           or 0.0)
            target = self.temperature if self.temperature is not None else \
                purge_temperature(last_c, reel_c, limit)
            if target > limit:
                raise UsageError(f"purge: {target:g} °C is above the {limit:g} °C the head "
                                 "reaches")
            heaters[heater] = {"reel_c": reel_c, "last_c": last_c, "purge_c": target}
        return purged, heaters

    def steps(self) -> None:
        purged, heaters = self.plan()
        self.report.measured = {f"heater{h}": p for h, p in heaters.items()}
        self.report.measured["nozzles"] = sorted(purged)
        at = ", ".join(f"{p['purge_c']:g} °C (last material {p['last_c']:g} °C, this "
                       f"reel {p['reel_c']:g} °C)" for p in heaters.values())
        self.question("yes", f"Purge nozzle{'s' if len(purged) > 1 else ''} "
                             f"{' and '.join(str(n) for n in purged)} at {at}? The head "
                             "homes and lays purge lines along the front of the bed.")
        self.send("home and level the gantry", LEVEL_GANTRY)
        self.heat({h: p["purge_c"] for h, p in heaters.items()})
        for i in range(PURGE_LINES_PER_NOZZLE):
            for k, n in enumerate(purged):
                y = 15 + 10 * (i * len(purged) + k)
                feed = purged[n]["feed"]
                self.send(f"purge line {i + 1} of nozzle {n}",
                          [f"G0 X20 Y{y} Z0.3", f"T{n}", f"G36 {feed}500 F400", "G0 B1",
                           f"G1 X180 {feed}{PURGE_MM3_PER_LINE:g} F400", "G0 B0", "G0 Z1"])
        self.send("heaters off, the head up and away",
                  ["M104 S0 T0", "G0 Z10", "G0 X113 Y140"])
        self.heating = False
        self.record_materials(heaters)

    def record_materials(self, heaters: dict[int, dict]) -> None:
        """The head's EEPROM told the material each purged heater's nozzle now holds
        (its reel's temperature), in one write of its whole data."""
        assignments = {f"nozzle{h}_last_filament_temperature": p["reel_c"]
                       for h, p in heaters.items()}
        self.step("record in the head: " + ", ".join(
            f"nozzle {h} last melted {p['reel_c']:g} °C" for h, p in heaters.items()))
        if self.dry_run:
            return
        write_head(self.printer, self.printer.read_eeprom("head"), assignments, self.name)
        self.report.written = {"head": assignments}


class LevelGantry(Sequence):
    """Level the gantry from the Z switch at each leadscrew."""

    name = "level-gantry"

    def steps(self) -> None:
        self.question("yes", "Level the gantry? The head homes and probes the bed at "
                             "both sides.")
        self.send("home, probe Z at each leadscrew, level the gantry (G38)", LEVEL_GANTRY)
        if self.dry_run:
            return
        self.report.measured = {"z_delta_mm": z_delta(self.printer, self.name)}


def check_feed(name: str, feed: str, head: dict) -> None:
    """A feed the head in place has (D: a dual-material head's); an unknown head is let
    be (the printer reports what it cannot do)."""
    head_type = str(head.get("type_code", "") or "")
    if head_type and feed not in (*head_valves(head_type).feeds, "E"):
        raise UsageError(f"{name}: a {head_type} head has no feed {feed} (feed D is a "
                         "dual-material head's)")


class Unload(Sequence):
    """Unload a feed's filament: the printer heats the nozzle, moves the carriage right
    and pulls the filament back out of the Bowden tube (M122)."""

    name = "unload"

    def __init__(self, *args, feed: str = "E", head: dict | None = None, **kwargs):
        super().__init__(*args, **kwargs)
        self.feed = feed
        self.head = head or {}

    def steps(self) -> None:
        check_feed(self.name, self.feed, self.head)
        self.question("yes", f"Unload the filament from feed {self.feed}? The nozzle heats "
                             "and the drive pulls the filament back: hold the reel.")
        self.heating = True  # (the printer heats for the unload itself)
        self.send(f"unload feed {self.feed} (the printer heats, moves right and pulls back)",
                  [f"M122 {self.feed}"])
        self.heating = False
        self.report.measured = {"unloaded": self.feed}


class HeadChange(Sequence):
    """Get the printer ready for a head to be taken off, wait while it is changed, and
    read the new head (AutoMaker's Remove head: home, shut the valve, park at the
    front, unload the filament, unlock the door)."""

    name = "head-change"
    questions = ("yes", "swapped")

    def __init__(self, *args, head: dict | None = None, **kwargs):
        super().__init__(*args, **kwargs)
        self.head = head or {}

    def steps(self) -> None:
        head_type = str(self.head.get("type_code", "") or "")
        feeds = ["E", "D"] if head_type and head_kind(head_type) == "dual" else ["E"]
        self.question("yes", "Change the head? The filament is unloaded, the head parks at "
                             "the front and the door unlocks.")
        self.send("home", ["G90", "G28 X Y", "G28 Z"])
        self.send("shut the valve and park the head at the front",
                  ["T0", "G0 B0", "G0 X210 Y120 Z20"])
        self.heating = True
        self.send("unload the filament (" + " and ".join(f"feed {f}" for f in feeds) + ")",
                  [f"M122 {f}" for f in feeds])
        self.heating = False
        self.send("unlock the door", ["G37"])
        self.question("swapped", "Take the head off and fit the new one. Is the new head "
                                 "in place?")
        self.step("read the new head")
        if self.dry_run:
            return
        status = None
        for _ in range(20):  # its EEPROM is read within moments of being plugged in
            status = self.printer.status()
            if status.eeproms["head"] == "valid":
                break
            self.printer.idle(POLL_S)
        if status is None or status.eeproms["head"] != "valid":
            raise RoboxError("head-change: the new head's EEPROM cannot be read (is it "
                             "seated?)")
        fields = self.printer.read_eeprom_fields("head")
        self.report.measured = {"old_head": {"type_code": head_type,
                                             "unique_id": self.head.get("unique_id", "")},
                                "new_head": {"type_code": fields["type_code"],
                                             "unique_id": fields["unique_id"]}}


#: AutoMaker's eject temperatures: soft enough to draw a neck (a dual-material head's
#: macros: 160 °C), then cool enough to snap; and what its macros push through a nozzle
NECK_C = 140.0
NECK_DUAL_C = 160.0
SNAP_C = 125.0
PUSH_MM3 = 70.0
PUSH_DUAL_MM3 = 120.0


class EjectStuck(Sequence):
    """Free filament stuck in the head (AutoMaker's Eject stuck material): heat to the
    reel's first-layer temperature, push a short purge through each nozzle, then let
    the nozzle cool while drawing the filament back: a neck at 140 °C (a dual-material
    head: 160 °C), snapped at 125 °C, and the drive pulls it out until it slips. A
    dual-material head's nozzles each have a heater and a feed of their own, and each is
    freed in turn (or the one `nozzle` names)."""

    name = "eject-stuck"

    def __init__(self, *args, head: dict | None = None, reels: dict | None = None,
                 nozzle: int | None = None, **kwargs):
        super().__init__(*args, **kwargs)
        self.head = head or {}
        self.reels = reels or {}
        self.nozzle = nozzle

    def plan(self) -> list[dict]:
        """Each heater freed: its nozzles, feed, reel temperature and neck temperature."""
        head_type = head_type_of(self.head, self.name)
        kind = head_kind(head_type)
        valves = head_valves(head_type)
        nozzles = chosen_nozzles(head_type, self.nozzle, self.name)
        if self.nozzle is not None:
            if kind != "dual":  # one heater and one feed: both nozzles are freed together
                raise UsageError(f"eject-stuck: a {head_type} head's nozzles share one feed; "
                                 "they are freed together (no --nozzle)")
            nozzles = [self.nozzle]
        limit = max_temperature(head_type)
        plans = []
        for heater in (nozzles if kind == "dual" else [0]):
            feed = valves.feeds[heater] if valves.feeds else "E"
            which = "reel0" if feed == "E" else "reel1"
            reel = self.reels.get(which)
            if reel is None:
                raise RoboxError(f"eject-stuck: {which} has no valid EEPROM (is the reel in "
                                 "place?): its temperature is needed")
            plans.append({"heater": heater, "feed": feed,
                          "nozzles": [heater] if kind == "dual" else nozzles,
                          "heat_c": min(float(reel["first_layer_nozzle_temperature"]), limit),
                          "neck_c": NECK_DUAL_C if kind == "dual" else NECK_C,
                          "push_mm3": PUSH_DUAL_MM3 if kind == "dual" else PUSH_MM3})
        return plans

    def steps(self) -> None:
        plans = self.plan()
        self.report.measured = {"heat_c": plans[0]["heat_c"], "neck_c": plans[0]["neck_c"],
                                "snap_c": SNAP_C} if len(plans) == 1 else \
            {f"heater{p['heater']}": {"heat_c": p["heat_c"], "neck_c": p["neck_c"],
                                      "snap_c": SNAP_C} for p in plans}
        which = " and ".join(f"{p['heat_c']:g} °C" for p in plans)
        self.question("yes", f"Eject the stuck filament? The nozzle heats to {which}, "
                             "pushes a little through, then cools while the drive pulls "
                             "the filament out: hold the reel.")
        self.send("home", ["G90", "G28 X Y", "G28 Z"])
        for p in plans:
            heater, feed, word = p["heater"], p["feed"], "S" if p["heater"] == 0 else "T"
            self.heat({heater: p["heat_c"]})
            for n in p["nozzles"]:
                x = 20 + 40 * n
                self.send(f"push through nozzle {n}",
                          [f"G0 X{x} Y0 Z8", f"T{n}", "G0 Z4", f"G36 {feed}1200 F400",
                           "G0 B1", f"G1 X{x + 12} {feed}{p['push_mm3']:g} F50", "G0 B0",
                           "G0 Z8"])
            self.cool(heater, p["neck_c"])
            self.send("draw a neck in the filament", [f"G1 {feed}-50 F2100"])
            self.cool(heater, SNAP_C)
            self.send(f"snap it and pull feed {feed}'s filament out",
                      [f"G36 {feed}-1200 F2100", f"G1 {feed}-20 F2100"])
            self.send(f"heater {heater} off", [f"M104 {word}0"])
        self.send("heaters off, the head up and away", ["M104 S0 T0", "G0 Z20", "G0 X113 Y140"])
        self.heating = False


#: where the status report's switch flags give each feed's filament sensor
SENSOR_AT = {"E": 30, "D": 31}


class Load(Sequence):
    """Load a feed: the person pushes the filament into the inlet until the drive takes
    it, and the printer loads it to the nozzle by itself (its automatic load, as on
    AutoMaker's printers: the index wheel turning with no filament at the sensor)."""

    name = "load"
    questions = ("inserted",)

    def __init__(self, *args, feed: str = "E", head: dict | None = None, **kwargs):
        super().__init__(*args, **kwargs)
        self.feed = feed
        self.head = head or {}

    def at_sensor(self) -> bool:
        return self.printer.status().raw[SENSOR_AT[self.feed]:SENSOR_AT[self.feed] + 1] == b"1"

    def steps(self) -> None:
        check_feed(self.name, self.feed, self.head)
        if not self.dry_run and self.at_sensor():
            raise RoboxError(f"load: feed {self.feed} already has filament at its sensor "
                             "(robox-cli unload takes it out)")
        self.question("inserted", f"Push the filament into feed {self.feed}'s inlet until "
                                  "the drive takes it; the printer then loads it to the "
                                  "nozzle. Has the drive taken it?")
        self.step(f"wait while the printer loads feed {self.feed} to the nozzle")
        if self.dry_run:
            return
        self.wait_idle(self.printer.errors(), MOVE_TIMEOUT_S)
        if not self.at_sensor():
            raise RoboxError(f"load: no filament reached feed {self.feed}'s sensor")
        self.report.measured = {"loaded": self.feed}
