"""What a head's type code says about it: its kind, its nozzles and their valves.

The kind follows the firmware's reading of the head EEPROM's type code (eeprom.c). The
valve figures are AutoMaker's, from its head definitions and print profiles:

| type code        | kind   | nozzle 0      | nozzle 1      | ejection mm3 (0 / 1) |
|------------------|--------|---------------|---------------|----------------------|
| RBX01-SM, -S2    | single | 0.3 mm, feed E| 0.8 mm, feed E| 0.3 / 0.6            |
| RBX01-DM, -DF    | dual   | 0.4 mm, feed D| 0.4 mm, feed E| 0.3 / 0.3            |
| RBXDV-S1, others | plain  | one nozzle, E | (none)        | no valve             |

A nozzle's ejection volume is the plastic its needle pushes out going from open (B 1)
to shut (B 0), and the void it leaves behind opening; a partial open never goes below
`PARTIAL_B_MINIMUM`. Newer type codes (RX...) are read as eeprom.c reads them: digit 7
the material count, digit 6 odd where a valve is fitted; they take the figures of the
RBX01 head of their kind.
"""

from __future__ import annotations

from dataclasses import dataclass

from robox.errors import UsageError

#: The head a job is translated for when the printer's cannot be read, and the filament
#: diameter when its reel's cannot.
HEAD_DEFAULT = "RBX01-SM"
DEFAULT_DIAMETER = 1.75
#: AutoMaker's partialBMinimum (50%): the least a short path's valve is opened.
PARTIAL_B_MINIMUM = 0.5
#: AutoMaker's maxClosesBeforeNozzleReselect: the nozzle is selected again (the firmware
#: measures the valve against its switch on a T) after this many opens.
OPENS_BEFORE_RESELECT = 10
E_FEED = "E"
D_FEED = "D"


@dataclass(frozen=True)
class HeadValves:
    kind: str  # 'single', 'dual' or 'plain'
    diameters_mm: tuple[float, ...]
    ejection_mm3: tuple[float, ...]  # per nozzle; empty for a head without a valve
    feeds: tuple[str, ...]  # the extruder that feeds each nozzle

    @property
    def has_valve(self) -> bool:
        return bool(self.ejection_mm3)


SINGLE = HeadValves("single", (0.3, 0.8), (0.3, 0.6), (E_FEED, E_FEED))
DUAL = HeadValves("dual", (0.4, 0.4), (0.3, 0.3), (D_FEED, E_FEED))
PLAIN = HeadValves("plain", (0.4,), (), (E_FEED,))
_BY_KIND = {"single": SINGLE, "dual": DUAL, "plain": PLAIN}


def max_temperature(type_code: bytes | str) -> float:
    """The highest nozzle temperature the firmware lets a head of this type reach (°C):
    eeprom.c's reading of the type code's first eight characters, to which it clamps
    every nozzle target. An unknown type (RBX01-SM among them) gets 260."""
    name = (type_code.encode("ascii", "replace") if isinstance(type_code, str)
            else bytes(type_code))[:8]
    if name in (b"RBX01-S2", b"RBX01-DM"):
        return 280.0
    if name == b"RBXDV-S1":
        return 300.0
    if name == b"RBXDV-S2":
        return 500.0
    if name[:2] == b"RX" and len(name) > 4:
        t = name[4]
        if 0x31 <= t <= 0x39:
            return float(200 + 5 * (t - 0x31))
        if 0x41 <= t <= 0x5A:
            return float(245 + 5 * (t - 0x41))
        if 0x61 <= t <= 0x7A:
            return float(375 + 5 * (t - 0x61))
    return 260.0


def head_kind(type_code: str) -> str:
    """'dual' (two materials, E and D), 'single' (one material, two nozzles behind a
    valve) or 'plain' (no valve): from the head EEPROM's type code as eeprom.c reads
    it (old names RBX01-SM/-S2/-DM; new names RX..., digit 7 the material count, digit
    6 odd when there is a valve)."""
    code = type_code.strip().upper()
    if code.startswith("RBX01-DM"):
        return "dual"
    if code.startswith(("RBX01-SM", "RBX01-S2")):
        return "single"
    if code.startswith("RX") and len(code) >= 8:
        if (ord(code[7]) - ord("0")) & 3 == 2:
            return "dual"
        return "single" if (ord(code[6]) - ord("0")) & 1 else "plain"
    if code.startswith("RBX"):
        return "plain"
    raise UsageError(f"unknown head type {type_code!r} (e.g. RBX01-SM, RBX01-DM)")


def head_valves(type_code: str, ejection: tuple[float, ...] | None = None) -> HeadValves:
    """The valve figures of a head type; `ejection` overrides the ejection volumes."""
    valves = _BY_KIND[head_kind(type_code)]
    if ejection is None or not valves.has_valve:
        return valves
    if len(ejection) == 1:
        ejection = ejection * len(valves.ejection_mm3)
    if len(ejection) != len(valves.ejection_mm3) or any(not 0.01 <= v <= 50.0
                                                        for v in ejection):
        raise UsageError("an ejection volume is given once (every nozzle) or per nozzle, "
                         "0.01 to 50 mm3 each")
    return HeadValves(valves.kind, valves.diameters_mm, tuple(ejection), valves.feeds)
