"""Filament reels: what a reel EEPROM says, in a person's terms, and a catalogue of
common materials to program a third-party reel's chip with.

A reel EEPROM holds the filament's name and colour, its temperatures (nozzle, bed and
ambient, each with a first-layer value where the printer has one), its diameter, the
extrusion and feed-rate multipliers, the material type and the length left
(`../spec/eeprom.md`). The printer loads the temperatures and the filament figures when
the reel becomes valid and takes the length used off the remaining length as it prints.

`Definition` is one reel's worth in the terms `robox-cli reel` speaks: the keys of a
definition file (TOML or JSON) and of `reel show --json`. `MATERIALS` is the catalogue.
The figures are common starting points for each material on a Robox (1.75 mm filament,
an enclosed heated chamber), not any maker's; a definition file carries a reel's own.

What the printer would clamp is refused before anything is written (`Definition.check`,
`check_for_head`): bed targets above 160 °C, an ambient target above 60 °C and nozzle
targets above the head's maximum (260 °C for a standard RBX01-SM head, 280 °C for the
RBX01-S2 and RBX01-DM); and what an EEPROM field cannot hold (a number that does not fit
in 8 characters, text that is too long or not ASCII).

The material type is stored as AutoMaker stored it, one character: 'A' plus the
material's place in its list (`MATERIAL_TYPES`), so a reel programmed here reads in
AutoMaker as that material and an AutoMaker reel reads here by name.
"""

from __future__ import annotations

import json
import math
import tomllib
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path

from robox.errors import UsageError
from robox.formats import eeprom as fmt
from robox.formats import float8
from robox.formats.heads import max_temperature

#: What the firmware clamps targets to (heaters.c): bed, ambient.
MAX_BED_C = 160.0
MAX_AMBIENT_C = 60.0

#: AutoMaker's material list, in its order: the stored character is 'A' + the index.
MATERIAL_TYPES = (
    "ABS", "ASA", "mABS", "PLA", "PA12", "PA6", "PA6/66", "HIPS", "Special", "CO-PET",
    "BVOH", "TPU", "PC", "PC-ABS", "PVB", "PCL", "PETG", "PVOH", "PLA/PHA", "PP", "PEEK",
    "PEKK", "PPSU", "PPS", "PSU", "PEI", "PVDF", "TPC",
)


def type_char(material_type: str) -> str:
    for i, name in enumerate(MATERIAL_TYPES):
        if name.lower() == material_type.lower():
            return chr(ord("A") + i)
    raise UsageError(f"unknown material type {material_type!r} "
                     f"(known: {', '.join(MATERIAL_TYPES)})")


def type_name(char: str) -> str:
    """The material type a stored character names ('' for none, the character itself
    for one outside the list)."""
    if not char:
        return ""
    i = ord(char[0]) - ord("A")
    return MATERIAL_TYPES[i] if 0 <= i < len(MATERIAL_TYPES) else char


@dataclass(frozen=True)
class Definition:
    """One reel, in `robox-cli reel`'s terms (°C, mm, metres)."""

    id: str
    name: str
    material_type: str
    colour: str = "FFFFFF"
    nozzle_c: float = 0.0
    first_layer_nozzle_c: float = 0.0
    bed_c: float = 0.0
    first_layer_bed_c: float = 0.0
    ambient_c: float = 0.0
    diameter_mm: float = 1.75
    filament_multiplier: float = 1.0
    feed_rate_multiplier: float = 1.0
    remaining_m: float | None = None  # None: leave the reel's own length as it is

    # ------------------------------------------------------------ reading
    @classmethod
    def from_mapping(cls, values: dict, where: str) -> Definition:
        """A definition from a file's table; `material` names a catalogue entry to start
        from, and the other keys replace its values."""
        values = dict(values)
        base = values.pop("material", None)
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(values) - known)
        if unknown:
            raise UsageError(f"{where}: unknown key {unknown[0]!r} "
                             f"(keys: material, {', '.join(sorted(known))})")
        if base is not None:
            start = asdict(material(str(base)))
        else:
            missing = [k for k in ("id", "name", "material_type") if k not in values]
            if missing:
                raise UsageError(f"{where}: {missing[0]!r} is missing (or name a catalogue "
                                 f"'material' to start from)")
            start = {}
        start.update(values)
        for f in fields(cls):
            value = start.get(f.name)
            if f.name in ("id", "name", "material_type", "colour"):
                if value is not None and not isinstance(value, str):
                    raise UsageError(f"{where}: {f.name} must be text, not {value!r}")
            elif value is not None and (isinstance(value, bool)
                                        or not isinstance(value, (int, float))):
                raise UsageError(f"{where}: {f.name} must be a number, not {value!r}")
            elif value is not None:
                start[f.name] = float(value)
        return cls(**start).check()

    @classmethod
    def from_file(cls, path: Path) -> Definition:
        try:
            text = path.read_bytes()
        except OSError as exc:
            raise UsageError(f"{path}: {exc.strerror or exc}") from None
        try:
            if path.suffix.lower() == ".json":
                values = json.loads(text)
            else:
                values = tomllib.loads(text.decode("utf-8"))
        except (ValueError, UnicodeDecodeError) as exc:
            kind = "JSON" if path.suffix.lower() == ".json" else "TOML"
            raise UsageError(f"{path}: not a {kind} reel definition ({exc})") from None
        if not isinstance(values, dict):
            raise UsageError(f"{path}: a reel definition is a table of keys and values")
        return cls.from_mapping(values, str(path))

    @classmethod
    def from_fields(cls, values: dict) -> Definition:
        """What a reel EEPROM's fields (formats.eeprom.fields_of) say, unchecked."""
        given = {key: values[name] for key, name in FIELD_OF.items()}
        given["material_type"] = type_name(given["material_type"])
        given["colour"] = given["colour"][:6]
        given["remaining_m"] /= 1000.0
        return cls(**given)

    # ------------------------------------------------------------ checking
    def check(self) -> Definition:
        """Itself, once every value is one the EEPROM holds and the printer would use
        as it is; else UsageError naming the first that is not."""
        for name in ("nozzle_c", "first_layer_nozzle_c", "bed_c", "first_layer_bed_c",
                     "ambient_c"):
            value = getattr(self, name)
            if not math.isfinite(value) or value < 0:
                raise UsageError(f"{name}: {value:g} is not a temperature")
        for name, limit in (("bed_c", MAX_BED_C), ("first_layer_bed_c", MAX_BED_C),
                            ("ambient_c", MAX_AMBIENT_C)):
            if getattr(self, name) > limit:
                raise UsageError(f"{name}: {getattr(self, name):g} °C is above the "
                                 f"{limit:g} °C the printer clamps it to")
        if not 0.1 <= self.diameter_mm <= 4.0:
            raise UsageError(f"diameter_mm: {self.diameter_mm:g} is not a filament diameter "
                             "(0.1 to 4 mm)")
        for name in ("filament_multiplier", "feed_rate_multiplier"):
            value = getattr(self, name)
            if not 0.0 < value <= 10.0:
                raise UsageError(f"{name}: {value:g} is not a multiplier (above 0, up to 10)")
        if self.remaining_m is not None and not 0.0 <= self.remaining_m < 99_999.0:
            raise UsageError(f"remaining_m: {self.remaining_m:g} is not a length in metres")
        if not self.id:
            raise UsageError("id: a reel needs a filament ID")
        self.assignments()  # the fields' own checks: lengths, ASCII, 8 characters
        return self

    def check_for_head(self, head_type: str) -> None:
        """Refuse nozzle temperatures above what the head (by its type code) may reach:
        the printer would clamp them."""
        limit = max_temperature(head_type)
        for name in ("nozzle_c", "first_layer_nozzle_c"):
            value = getattr(self, name)
            if value > limit:
                raise UsageError(f"{name}: {value:g} °C is above the {limit:g} °C a "
                                 f"{head_type or 'standard'} head reaches (the printer "
                                 "would clamp it)")

    # ------------------------------------------------------------ writing
    def assignments(self) -> dict[str, str]:
        """The reel EEPROM's fields for this definition (remaining length only when
        given), each checked against its field."""
        out = {name: getattr(self, key) for key, name in FIELD_OF.items()}
        out["material_type"] = type_char(self.material_type)
        out["display_colour"] = self.colour.lstrip("#").upper()
        if self.remaining_m is None:
            del out["remaining_filament"]
        else:
            out["remaining_filament"] = self.remaining_m * 1000.0
        shown: dict[str, str] = {}
        for name, value in out.items():
            f = fmt.field("reel", name)
            if f.kind == "float":
                try:
                    float8.encode_checked(float(value))
                except UsageError:
                    raise UsageError(f"{KEY_OF[name]}: {value:g} does not fit in the "
                                     "EEPROM's 8 characters") from None
                shown[name] = float8.shortest(float(value))
            else:
                try:
                    f.encode(str(value))
                except UsageError as exc:
                    raise UsageError(f"{KEY_OF[name]}: {exc}") from None
                shown[name] = str(value)
        return shown

    def apply(self, data: bytes) -> bytes:
        """The reel's 192 data bytes with this definition written into them."""
        out = bytearray(data)
        for name, value in self.assignments().items():
            fmt.set_field(out, "reel", name, value)
        return bytes(out)

    def shown(self) -> dict:
        """The definition as `reel show --json` and a definition file spell it."""
        out = asdict(self)
        for name, value in out.items():
            if isinstance(value, float):
                out[name] = float8.shortest(float(value))
        return out


#: each definition key's reel EEPROM field (spec/eeprom.md)
FIELD_OF = {"id": "filament_id", "name": "friendly_name", "material_type": "material_type",
            "colour": "display_colour", "nozzle_c": "nozzle_temperature",
            "first_layer_nozzle_c": "first_layer_nozzle_temperature",
            "bed_c": "bed_temperature", "first_layer_bed_c": "first_layer_bed_temperature",
            "ambient_c": "ambient_temperature", "diameter_mm": "filament_diameter",
            "filament_multiplier": "filament_multiplier",
            "feed_rate_multiplier": "feed_rate_multiplier",
            "remaining_m": "remaining_filament"}
KEY_OF = {name: key for key, name in FIELD_OF.items()}


def _entry(key: str, type_: str, nozzle: float, bed: float, ambient: float, colour: str,
           first_nozzle: float | None = None, first_bed: float | None = None,
           feed: float = 1.0, multiplier: float = 1.0) -> Definition:
    return Definition(id=f"RBX-GEN-{key}"[:16], name=f"Generic {type_}",
                      material_type=type_, colour=colour, nozzle_c=nozzle,
                      first_layer_nozzle_c=first_nozzle if first_nozzle is not None
                      else nozzle + 5, bed_c=bed,
                      first_layer_bed_c=first_bed if first_bed is not None else bed,
                      ambient_c=ambient, feed_rate_multiplier=feed,
                      filament_multiplier=multiplier)


#: The catalogue: name -> definition (no remaining length: the reel's own is kept
#: unless one is given).
MATERIALS: dict[str, Definition] = {
    "PLA": _entry("PLA", "PLA", 210, 50, 30, "FFFFFF", first_bed=55),
    "PETG": _entry("PETG", "PETG", 240, 80, 35, "1E90FF"),
    "ABS": _entry("ABS", "ABS", 250, 100, 50, "F0F0F0", first_bed=105),
    "ASA": _entry("ASA", "ASA", 255, 100, 50, "202020", first_bed=105),
    "TPU": _entry("TPU", "TPU", 225, 45, 30, "FF4500", feed=0.5),
    "NYLON": Definition(id="RBX-GEN-NYLON", name="Generic nylon (PA6)",
                        material_type="PA6", colour="F5F5DC", nozzle_c=255,
                        first_layer_nozzle_c=260, bed_c=90, first_layer_bed_c=90,
                        ambient_c=45),
    "PVA": Definition(id="RBX-GEN-PVA", name="Generic PVA (support)",
                      material_type="PVOH", colour="FFFFE0", nozzle_c=200,
                      first_layer_nozzle_c=205, bed_c=55, first_layer_bed_c=55,
                      ambient_c=30, feed_rate_multiplier=0.8),
    "HIPS": _entry("HIPS", "HIPS", 240, 100, 45, "FFFAF0"),
    "PC": _entry("PC", "PC", 275, 120, 55, "E0FFFF", first_nozzle=280, first_bed=125),
}


def material(name: str) -> Definition:
    entry = MATERIALS.get(name.upper())
    if entry is None:
        raise UsageError(f"no material {name!r} in the catalogue "
                         f"(materials: {', '.join(MATERIALS)}; or --from FILE)")
    return entry


def with_overrides(base: Definition, **values) -> Definition:
    """`base` with the given values (None: keep), checked."""
    given = {k: v for k, v in values.items() if v is not None}
    return replace(base, **given).check()
