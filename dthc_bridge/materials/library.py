"""Plasma materials: one cut recipe per number, in QtPlasmaC's material-file format.

A shop keeps its cut recipes (pierce height and delay, cut height, feed, amps, volts, ...)
in a material library and programs select one by number (``M190 P<n>``). QtPlasmaC, the
largest open plasma community, defines the file format, so a library written here can be
read by QtPlasmaC and the other way round:

* one ``[MATERIAL_NUMBER_<n>]`` section per material; numbers need not be consecutive;
* ``KEY = value`` lines, keys ``NAME``, ``KERF_WIDTH``, ``THC`` (0/1), ``PIERCE_HEIGHT``,
  ``PIERCE_DELAY`` (s), ``PUDDLE_JUMP_HEIGHT`` (% of pierce height), ``PUDDLE_JUMP_DELAY``
  (s), ``CUT_HEIGHT``, ``CUT_SPEED`` (units/min), ``CUT_AMPS``, ``CUT_VOLTS``,
  ``PAUSE_AT_END`` (s), ``GAS_PRESSURE``, ``CUT_MODE``;
* ``PIERCE_HEIGHT``, ``PIERCE_DELAY``, ``CUT_HEIGHT`` and ``CUT_SPEED`` are mandatory, the
  rest default to 0 (an empty value counts as absent, as QtPlasmaC writes them);
* lines starting with ``#`` are comments (whole lines only: a ``#`` after a value is part
  of the value, as in QtPlasmaC).

Lengths are in the machine's units (mm or inch) and are kept as written;
:meth:`Material.as_cut_params` converts to the controller's millimetres.

Numbering: material 0 is the default material, which lives in the daemon's settings (as
QtPlasmaC keeps it in its own settings), never in the file; numbers from
:data:`TEMPORARY_BASE` (1 000 000) up are temporary materials a program defines for itself
(magic comments with ``o=0``): they are never written and refused when read.

The file parser is hand-written rather than :mod:`configparser`, which lower-cases keys,
accepts inline comments and continuation lines QtPlasmaC does not, and reports errors
without the line and section the user wrote.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import KW_ONLY, dataclass, fields

from dthc_bridge.cut_params import CommandError, CutParams
from dthc_bridge.units import MM_PER_INCH

__all__ = [
    "MATERIAL_KEYS",
    "TEMPORARY_BASE",
    "Material",
    "MaterialError",
    "format_material_file",
    "material_from_dict",
    "material_to_dict",
    "parse_material_file",
]

TEMPORARY_BASE = 1_000_000  # numbers from here up are temporary (program-defined, o=0)


class MaterialError(ValueError):
    """A material, a material file or a magic comment is invalid.

    ``where`` names the place as the user wrote it (``"line 12 [MATERIAL_NUMBER_3]
    CUT_HEIGHT"``, ``"ph"``, ``"pierce_delay"``, ``"M190 P7"``); ``reason`` says what is wrong.
    """

    def __init__(self, where: str, reason: str) -> None:
        super().__init__(f"{where}: {reason}")
        self.where = where
        self.reason = reason


@dataclass(frozen=True, slots=True)
class Material:
    """One cut recipe. Lengths in the machine's units, feeds in units/min, times in s.

    Validated on construction; a :class:`MaterialError` names the attribute. Numbers are
    turned into ``float`` (``int`` for ``cut_mode``) and ``name`` is stripped, so equal
    recipes compare equal however they were written.

    ``thc`` follows the file format: an absent ``THC`` key is 0, so a material that does not
    say otherwise has THC *off*; write ``THC = 1`` (``th=1``, ``"thc": true``) to enable it.
    ``thickness`` comes from a magic comment's ``mt`` and is kept in memory only: neither the
    file format nor the MQTT dict carries it.
    """

    number: int
    _: KW_ONLY
    name: str = ""
    kerf_width: float = 0.0
    thc: bool = False
    pierce_height: float
    pierce_delay_s: float
    puddle_jump_height_percent: float = 0.0  # 0 = no puddle jump
    puddle_jump_delay_s: float = 0.0
    cut_height: float
    cut_speed: float  # units/min
    cut_amps: float = 0.0
    cut_volts: float = 0.0  # 0 = auto voltage (sampled after the cut starts)
    pause_at_end_s: float = 0.0
    gas_pressure: float = 0.0
    cut_mode: int = 0  # 1..3 for plasma sources that have modes; 0 = not set
    thickness: float = 0.0

    def __post_init__(self) -> None:
        if not _is_int(self.number) or self.number < 0:
            raise MaterialError("number", f"must be a whole number 0 or more, got {self.number!r}")
        if not isinstance(self.name, str):
            raise MaterialError("name", f"must be text, got {self.name!r}")
        name = self.name.strip()
        if name and not name.isprintable():
            raise MaterialError("name", f"must be one line of printable text, got {name!r}")
        object.__setattr__(self, "name", name)
        if not isinstance(self.thc, bool):
            raise MaterialError("thc", f"must be true or false, got {self.thc!r}")
        if not _is_int(self.cut_mode) or not 0 <= self.cut_mode <= 3:
            raise MaterialError(
                "cut_mode", f"must be 0 (not set), 1, 2 or 3, got {self.cut_mode!r}"
            )
        for attr in _POSITIVE:
            # A temporary tube material may leave them 0 (the program positions the torch).
            self._check_number(attr, positive=not self.positions_nothing)
        for attr in _NON_NEGATIVE:
            self._check_number(attr, positive=False)

    def _check_number(self, attr: str, *, positive: bool) -> None:
        value = getattr(self, attr)
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise MaterialError(attr, f"must be a number, got {value!r}")
        if not math.isfinite(value):
            raise MaterialError(attr, f"must be a finite number, got {value!r}")
        if positive and value <= 0:
            raise MaterialError(attr, f"must be more than 0, got {value:g}")
        if value < 0:
            raise MaterialError(attr, f"must be 0 or more, got {value:g}")
        object.__setattr__(self, attr, float(value))

    @property
    def positions_nothing(self) -> bool:
        """QtPlasmaC's tube-cutting material (``o=0`` with only ``pd`` while ``#<tube-cut> =
        1``): a temporary material whose pierce height, cut height and feed are all 0, so
        the program's own probe, Z moves and feeds position the torch."""
        return self.temporary and not (self.pierce_height or self.cut_height or self.cut_speed)

    @property
    def temporary(self) -> bool:
        """A program-defined material (``o=0``): never written to the library file."""
        return self.number >= TEMPORARY_BASE

    def cut_speed_mm_min(self, *, inch: bool = False) -> float:
        """The cut feed in mm/min (``CUT_SPEED`` is in the machine's units per minute)."""
        return self.cut_speed * (MM_PER_INCH if inch else 1.0)

    def as_cut_params(
        self,
        *,
        touch_feed_mm_min: float,
        ohmic: bool,
        anti_dive_percent: float,
        inch: bool = False,
    ) -> CutParams:
        """The controller's (MASSO G200-style) parameter set for this material.

        Lengths are converted to mm when the machine works in inches (``inch``). Touch-off
        feed, ohmic sensing and anti-dive are machine settings a material does not set, so
        the caller supplies them. ``cut_volts`` 0 becomes auto voltage. A value outside the
        controller's ranges raises :class:`MaterialError` naming this material's attribute.
        """
        scale = MM_PER_INCH if inch else 1.0
        try:
            return CutParams(
                touch_feed_mm_min=touch_feed_mm_min,
                pierce_height_mm=self.pierce_height * scale,
                pierce_delay_ms=self.pierce_delay_s * 1000.0,
                cut_height_mm=self.cut_height * scale,
                cut_voltage_v=self.cut_volts or None,
                anti_dive_percent=anti_dive_percent,
                ohmic=ohmic,
            )
        except CommandError as e:
            attr, controller_unit = _CUT_PARAM_ATTRS.get(e.word, (e.word, ""))
            if not hasattr(self, attr):  # the caller's machine setting, not the material
                raise MaterialError(attr, f"{e.reason} {controller_unit}") from e
            unit = _ATTR_UNITS.get(attr, "in" if inch else "mm")
            raise MaterialError(
                f"material {self.number} {attr}",
                f"{getattr(self, attr):g} {unit} is outside the controller's range "
                f"({e.reason} {controller_unit})",
            ) from e


_POSITIVE = ("pierce_height", "cut_height", "cut_speed")
_NON_NEGATIVE = (
    "kerf_width",
    "pierce_delay_s",
    "puddle_jump_height_percent",
    "puddle_jump_delay_s",
    "cut_amps",
    "cut_volts",
    "pause_at_end_s",
    "gas_pressure",
    "thickness",
)
# CutParams' words back to the attribute (or the caller's argument) and the word's unit.
_CUT_PARAM_ATTRS = {
    "G200 F": ("touch_feed_mm_min", "mm/min"),
    "G200 P": ("pierce_height", "mm"),
    "G200 D": ("pierce_delay_s", "ms"),
    "G200 C": ("cut_height", "mm"),
    "G200 V": ("cut_volts", "V"),
    "G200 A": ("anti_dive_percent", "%"),
}
_ATTR_UNITS = {"pierce_delay_s": "s", "cut_volts": "V"}


def _is_int(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


@dataclass(frozen=True, slots=True)
class _Field:
    """One material attribute under its three outside names."""

    attr: str
    file_key: str  # QtPlasmaC material file
    dict_key: str  # MQTT / JSON
    magic_key: str  # program magic comment
    kind: type  # str, float, int or bool
    required: bool = False


# Every attribute but number and thickness; magic.py shares this table and the two helpers
# below, so the three formats cannot drift apart.
FIELDS = (
    _Field("name", "NAME", "name", "na", str),
    _Field("kerf_width", "KERF_WIDTH", "kerf_width", "kw", float),
    _Field("thc", "THC", "thc", "th", bool),
    _Field("pierce_height", "PIERCE_HEIGHT", "pierce_height", "ph", float, required=True),
    _Field("pierce_delay_s", "PIERCE_DELAY", "pierce_delay", "pd", float, required=True),
    _Field("puddle_jump_height_percent", "PUDDLE_JUMP_HEIGHT", "puddle_jump_height", "jh", float),
    _Field("puddle_jump_delay_s", "PUDDLE_JUMP_DELAY", "puddle_jump_delay", "jd", float),
    _Field("cut_height", "CUT_HEIGHT", "cut_height", "ch", float, required=True),
    _Field("cut_speed", "CUT_SPEED", "cut_speed", "fr", float, required=True),
    _Field("cut_amps", "CUT_AMPS", "cut_amps", "ca", float),
    _Field("cut_volts", "CUT_VOLTS", "cut_volts", "cv", float),
    _Field("pause_at_end_s", "PAUSE_AT_END", "pause_at_end", "pe", float),
    _Field("gas_pressure", "GAS_PRESSURE", "gas_pressure", "gp", float),
    _Field("cut_mode", "CUT_MODE", "cut_mode", "cm", int),
)
assert {f.attr for f in FIELDS} | {"number", "thickness"} == {f.name for f in fields(Material)}
MATERIAL_KEYS = tuple(f.file_key for f in FIELDS)  # the file's keys, in the order written
_BY_FILE_KEY = {f.file_key: f for f in FIELDS}
_BY_DICT_KEY = {f.dict_key: f for f in FIELDS}

# A decimal number as people and repr() write it: no inf/nan, no underscores, no hex.
_NUMBER = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?")
_SECTION = re.compile(r"\[\s*MATERIAL_NUMBER_(\d+)\s*\]")


def parse_number(text: str, kind: type, where: str) -> float | int | bool:
    """``text`` as ``kind`` (float, int, or bool written 0/1); errors name ``where``."""
    if not _NUMBER.fullmatch(text):
        raise MaterialError(where, f"{text!r} is not a number")
    value = float(text)
    if kind is float:
        return value
    if not value.is_integer():
        raise MaterialError(where, f"{text!r} is not a whole number")
    if kind is bool:
        if value not in (0, 1):
            raise MaterialError(where, f"must be 0 (off) or 1 (on), got {text!r}")
        return value == 1
    return int(value)


def renamed(error: MaterialError, names: Mapping[str, str]) -> MaterialError:
    """``error`` (from :class:`Material`) with its attribute replaced by the outside name."""
    return MaterialError(names.get(error.where, error.where), error.reason)


def parse_material_file(text: str) -> dict[int, Material]:
    """The materials of a QtPlasmaC material file, by number.

    Strict, so a typo does not silently cut with a default: unknown sections and keys,
    duplicate sections and keys, numbers that do not parse, a missing mandatory key,
    material 0 and temporary numbers all raise :class:`MaterialError` naming the line,
    the section and the key as written.
    """
    materials: dict[int, Material] = {}
    section_lines: dict[int, int] = {}
    # The section being read: its header as written, number, line, and key -> (value, line).
    header = ""
    number = -1
    header_line = 0
    values: dict[str, tuple[str, int]] = {}

    def finish() -> None:
        if number < 0:
            return
        kwargs: dict[str, object] = {}
        for key, (value, line) in values.items():  # in line order
            f = _BY_FILE_KEY[key]
            if value:
                where = f"line {line} {header} {key}"
                kwargs[f.attr] = value if f.kind is str else parse_number(value, f.kind, where)
        for f in FIELDS:
            if f.required and f.attr not in kwargs:
                line = values.get(f.file_key, ("", header_line))[1]
                raise MaterialError(f"line {line} {header} {f.file_key}", "required, missing")
        try:
            materials[number] = Material(number, **kwargs)  # type: ignore[arg-type]
        except MaterialError as e:
            key = next((f.file_key for f in FIELDS if f.attr == e.where), e.where)
            line = values.get(key, ("", header_line))[1]
            raise MaterialError(f"line {line} {header} {key}", e.reason) from None

    for line_number, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        if line.startswith("["):
            finish()
            match = _SECTION.fullmatch(line)
            if match is None:
                raise MaterialError(
                    f"line {line_number} {line}", "unknown section; expected [MATERIAL_NUMBER_<n>]"
                )
            header, number, header_line, values = line, int(match[1]), line_number, {}
            if number in section_lines:
                raise MaterialError(
                    f"line {line_number} {header}",
                    f"material {number} is already defined at line {section_lines[number]}",
                )
            if number == 0:
                raise MaterialError(
                    f"line {line_number} {header}",
                    "material 0 is the default material; it is set in the daemon's settings",
                )
            if number >= TEMPORARY_BASE:
                raise MaterialError(
                    f"line {line_number} {header}",
                    f"numbers from {TEMPORARY_BASE} up are reserved for temporary materials",
                )
            section_lines[number] = line_number
            continue
        key, equals, value = line.partition("=")
        key = key.strip()
        if not equals:
            raise MaterialError(f"line {line_number}", f"expected KEY = value, got {line!r}")
        if number < 0:
            raise MaterialError(
                f"line {line_number} {key}", "comes before the first [MATERIAL_NUMBER_<n>]"
            )
        if key not in _BY_FILE_KEY:
            raise MaterialError(
                f"line {line_number} {header} {key}",
                f"unknown key; QtPlasmaC's keys are {', '.join(MATERIAL_KEYS)}",
            )
        if key in values:
            raise MaterialError(
                f"line {line_number} {header} {key}",
                f"already given at line {values[key][1]}",
            )
        values[key] = (value.strip(), line_number)
    finish()
    return materials


def _format_value(value: object) -> str:
    if isinstance(value, bool):
        return "1" if value else "0"
    if isinstance(value, float):
        text = repr(value)  # repr() round-trips exactly
        return text.removesuffix(".0")
    return str(value)


_HEADER = """\
# Plasma material library, QtPlasmaC material-file format, written by dthc-bridge.
# Lengths in the machine's units, CUT_SPEED in units/min, PIERCE_DELAY, PUDDLE_JUMP_DELAY
# and PAUSE_AT_END in seconds, PUDDLE_JUMP_HEIGHT in % of PIERCE_HEIGHT, THC 0 off / 1 on,
# CUT_VOLTS 0 = auto voltage. Comments are not kept when the daemon rewrites this file.
"""


def format_material_file(materials: Mapping[int, Material]) -> str:
    """``materials`` as a QtPlasmaC material file, by number; temporaries are left out.

    Every key is written, defaults included, as QtPlasmaC does. Material 0 (the default,
    kept in the settings) or a key that differs from its material's number raises
    :class:`MaterialError`.
    """
    width = max(len(k) for k in MATERIAL_KEYS)
    parts = [_HEADER]
    for number in sorted(materials):
        material = materials[number]
        if material.number != number:
            raise MaterialError(f"material {number}", f"is numbered {material.number}")
        if material.temporary:
            continue
        if number == 0:
            raise MaterialError(
                "material 0", "is the default material; it is set in the daemon's settings"
            )
        lines = [f"\n[MATERIAL_NUMBER_{number}]"]
        for f in FIELDS:
            value = _format_value(getattr(material, f.attr))
            lines.append(f"{f.file_key:<{width}} = {value}".rstrip())
        parts.append("\n".join(lines) + "\n")
    return "".join(parts)


def material_from_dict(number: int, data: Mapping[str, object]) -> Material:
    """A material from its JSON form (MQTT): the snake_case keys of :func:`material_to_dict`.

    Unknown keys, missing mandatory keys and values of the wrong type raise
    :class:`MaterialError` naming the key. ``thc`` takes true/false (or 0/1), ``cut_mode``
    a whole number; the rest numbers.
    """
    kwargs: dict[str, object] = {}
    for key, raw in data.items():
        f = _BY_DICT_KEY.get(key)
        if f is None:
            raise MaterialError(key, f"unknown key; the keys are {', '.join(_BY_DICT_KEY)}")
        value = raw
        if f.kind is bool and _is_int(raw) and raw in (0, 1):
            value = raw == 1  # JSON from some clients has no booleans
        elif f.kind is int and isinstance(raw, float) and raw.is_integer():
            value = int(raw)  # 2.0 from a client that has only floats
        kwargs[f.attr] = value
    for f in FIELDS:
        if f.required and f.attr not in kwargs:
            raise MaterialError(f.dict_key, "required, missing")
    try:
        return Material(number, **kwargs)  # type: ignore[arg-type]
    except MaterialError as e:
        raise renamed(e, {f.attr: f.dict_key for f in FIELDS}) from None


def material_to_dict(material: Material) -> dict[str, str | float | bool]:
    """The JSON form of ``material`` (number and thickness left out):
    ``material_from_dict(m.number, material_to_dict(m))`` gives ``m`` back (bar thickness)."""
    return {f.dict_key: getattr(material, f.attr) for f in FIELDS}
