"""Materials a program brings along: QtPlasmaC's magic comments, and the program-time table.

A CAM post can put the recipes a program needs into the program itself, one comment per
material, so the program cuts right on a machine whose library lacks them::

    (o=2, nu=12, na=Mild steel 1.5 mm 45 A, ph=3.8, pd=0.4, ch=1.5, fr=3000, cv=121)

The comment starts with ``o=``; ``key=value`` pairs are separated by commas (blanks around
them are tolerated), the name runs to the next comma. ``o`` is the option:

* 0: a temporary material for this program only, numbered from 1 000 000 up;
* 1: add material ``nu`` unless the library already has it (the library's recipe wins);
* 2: add material ``nu``, or overwrite it.

``ph``, ``pd``, ``ch`` and ``fr`` are mandatory, ``nu`` for options 1 and 2 (and ignored
for 0, whose number is assigned). The other keys are ``na`` name, ``mt`` thickness, ``kw``
kerf, ``th`` THC 0/1, ``jh``/``jd`` puddle jump height (%) and delay (s), ``ca`` amps,
``cv`` volts, ``pe`` pause at end (s), ``gp`` gas pressure and ``cm`` cut mode. An empty
value counts as absent.

:class:`MaterialTable` is what a running program sees: the library, the default material
0 from the daemon's settings, the materials the program's comments defined, and which one
is in force (``M190 P<n>``, ``M190 P-1`` back to the one before the program).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType

from dthc_bridge.materials.library import (
    FIELDS,
    TEMPORARY_BASE,
    Material,
    MaterialError,
    parse_number,
    renamed,
)

__all__ = ["MAGIC_KEYS", "MagicMaterial", "MaterialTable", "parse_magic_comment"]

_BY_MAGIC_KEY = {f.magic_key: f for f in FIELDS}
MAGIC_KEYS = ("o", "nu", *_BY_MAGIC_KEY, "mt")
_MAGIC_NAMES = {f.attr: f.magic_key for f in FIELDS} | {"thickness": "mt", "number": "nu"}


@dataclass(frozen=True, slots=True)
class MagicMaterial:
    """A parsed magic comment: its option (0, 1, 2) and the material it defines.

    For option 0 the material's number is :data:`TEMPORARY_BASE`, a placeholder:
    :meth:`MaterialTable.apply` gives it the next free temporary number.
    """

    option: int
    material: Material

    def __post_init__(self) -> None:
        if self.option not in (0, 1, 2):
            raise MaterialError(f"o={self.option}", "option must be 0, 1 or 2")
        if self.option != 0 and not 1 <= self.material.number < TEMPORARY_BASE:
            raise MaterialError("nu", f"must be 1 to {TEMPORARY_BASE - 1} for option {self.option}")


TUBE_DEFAULTS = {"ph": "0", "ch": "0", "fr": "0"}
"""What QtPlasmaC's filter gives a tube-cutting temporary material for the keys it left out
(#<tube-cut> = 1, o=0 with pd only): the plan fills them in (dthc_bridge/program/plan.py)."""


def parse_magic_comment(text: str) -> MagicMaterial | None:
    """The material a comment defines, or None when the comment is not a magic comment.

    ``text`` is the comment's inside, without the parentheses. A comment that starts with
    ``o=`` (after blanks) but is malformed raises :class:`MaterialError` naming the key:
    ``"ph: required for a material"``, ``"xx: unknown key"``, ``"o=3: option must be ..."``.
    """
    text = text.strip()
    if not text.startswith("o="):
        return None
    given: dict[str, str] = {}
    for raw in text.split(","):
        part = raw.strip()
        if not part:
            continue
        key, equals, value = part.partition("=")
        key = key.strip()
        if not equals:
            raise MaterialError(part, "expected key=value")
        if key not in MAGIC_KEYS:
            raise MaterialError(key, f"unknown key; the keys are {', '.join(MAGIC_KEYS)}")
        if key in given:
            raise MaterialError(key, "given twice")
        given[key] = value.strip()

    option_text = given["o"]
    if option_text not in ("0", "1", "2"):
        raise MaterialError(f"o={option_text}", "option must be 0, 1 or 2")
    option = int(option_text)
    number = TEMPORARY_BASE
    if option != 0:
        if not given.get("nu"):
            raise MaterialError("nu", f"required for option {option}")
        number = int(parse_number(given["nu"], int, "nu"))
        if not 1 <= number < TEMPORARY_BASE:
            raise MaterialError(
                "nu",
                f"must be 1 to {TEMPORARY_BASE - 1}, got {number} "
                "(0 is the default material, higher numbers are temporary)",
            )

    kwargs: dict[str, object] = {}
    for f in FIELDS:
        value = given.get(f.magic_key, "")
        if not value:
            if f.required:
                raise MaterialError(f.magic_key, "required for a material")
            continue
        kwargs[f.attr] = value if f.kind is str else parse_number(value, f.kind, f.magic_key)
    if given.get("mt"):
        kwargs["thickness"] = parse_number(given["mt"], float, "mt")
    try:
        material = Material(number, **kwargs)  # type: ignore[arg-type]
    except MaterialError as e:
        raise renamed(e, _MAGIC_NAMES) from None
    return MagicMaterial(option, material)


class MaterialTable:
    """The materials a running program can select, and the one in force.

    Built from the library (``materials``), the default material 0 from the daemon's
    settings (``default``; a material 0 in ``materials`` takes its place) and the number in
    force before the program (``initial``).

    :meth:`apply` takes a magic comment. Choice: an option 0 material becomes the material
    in force at once (QtPlasmaC's "temporary default": a program that defines one means to
    cut with it, usually without an ``M190``); options 1 and 2 only define, and the
    program selects with ``M190 P<n>``. Each option 0 comment gets the next temporary
    number (1 000 000, 1 000 001, ...). Nothing here touches the library file: what options
    1 and 2 defined is in :attr:`changes` for the caller to store, as QtPlasmaC does.
    """

    def __init__(
        self,
        materials: Mapping[int, Material],
        default: Material | None = None,
        *,
        initial: int = 0,
    ) -> None:
        for number, material in materials.items():
            if material.number != number:
                raise MaterialError(f"material {number}", f"is numbered {material.number}")
        if default is not None and default.number != 0:
            raise MaterialError("default material", f"must be number 0, not {default.number}")
        self._materials = dict(materials)
        self._default = default
        self._changes: dict[int, Material] = {}
        self._next_temporary = max((n + 1 for n in materials if n >= TEMPORARY_BASE), default=0)
        self._next_temporary = max(self._next_temporary, TEMPORARY_BASE)
        self.get(initial, where=f"initial material {initial}")
        self.initial = initial
        self._selected = initial

    @property
    def materials(self) -> Mapping[int, Material]:
        """Every material the program may select but the default (a read-only view)."""
        return MappingProxyType(self._materials)

    @property
    def changes(self) -> Mapping[int, Material]:
        """What option 1 and 2 comments added or overwrote, for the library (read-only)."""
        return MappingProxyType(self._changes)

    @property
    def selected_number(self) -> int:
        return self._selected

    @property
    def selected(self) -> Material:
        """The material in force (re-read: an overwrite by ``o=2`` shows at once)."""
        return self.get(self._selected)

    def get(self, number: int, *, where: str | None = None) -> Material:
        """Material ``number``: the table's, else the default for 0; else MaterialError."""
        material = self._materials.get(number)
        if material is None and number == 0:
            material = self._default
        if material is None:
            raise MaterialError(where or f"material {number}", f"no material {number}")
        return material

    def select(self, number: int) -> Material:
        """``M190 P<number>``: put material ``number`` in force; -1 is :meth:`revert`."""
        if number == -1:
            return self.revert()
        material = self.get(number, where=f"M190 P{number}")
        self._selected = number
        return material

    def revert(self) -> Material:
        """``M190 P-1``: back to the material in force before the program."""
        self._selected = self.initial
        return self.selected

    def apply(self, magic: MagicMaterial) -> Material:
        """Define the comment's material; returns the material now under its number."""
        material = magic.material
        if magic.option == 0:
            material = dataclasses.replace(material, number=self._next_temporary)
            self._next_temporary += 1
            self._materials[material.number] = material
            self._selected = material.number
            return material
        existing = self._materials.get(material.number)
        if magic.option == 1 and existing is not None:
            return existing
        self._materials[material.number] = material
        self._changes[material.number] = material
        return material
