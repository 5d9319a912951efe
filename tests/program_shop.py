"""The programs in tests/programs as a shop runs them: what it gives with each (its
material library, whether that is in inches, the codes its post writes for the torch),
check-program run with those options, and what "check-program and the machine agree" means
(issue 31). Shared by the agreement tests: on the real stack (tests/e2e/test_check_agrees*)
and in simulated time in every dialect (tests/sim/test_every_dialect.py)."""

from __future__ import annotations

import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from dthc_bridge.config import ControllerSettings
from dthc_bridge.controller.dialect import Dialect
from dthc_bridge.materials import MaterialStore
from dthc_bridge.program.check import CheckReport, check_program
from dthc_tools.sender import SendReport

PROGRAMS = Path(__file__).parent / "programs"
NC_NAMES = sorted(p.name for p in PROGRAMS.iterdir() if p.suffix == ".nc")
NGC_NAMES = sorted(p.name for p in PROGRAMS.iterdir() if p.suffix == ".ngc")
METRIC, INCH = "shop_material.cfg", "shop_material_inch.cfg"
SHOP: dict[str, dict[str, Any]] = {
    "firecontrol_relay.nc": {"codes": {"M10": "M3", "M11": "M5"}},
    "sheetcam_shop_m13_m15.nc": {"codes": {"M13": "M3", "M15": "M5"}},
    "linuxcnc_material_change.ngc": {"library": METRIC},
    "plasmac_material_overcut.ngc": {"library": METRIC},
    "plasmac_pierce_only.ngc": {"library": INCH, "inch": True},
    "sheetcam_plasmac_inch.ngc": {"library": INCH, "inch": True},
}


@dataclass(frozen=True)
class ShopRun:
    """One program with its shop's options, as both check-program and the daemon get them."""

    name: str
    lines: list[str]
    library: Path | None = None  # a copy in the test's own directory
    inch: bool = False
    codes: dict[str, str] = field(default_factory=dict)

    def check(self, dialect: Dialect | None = None) -> CheckReport:
        """As ``dthc-bridge check-program`` runs it, with the same options."""
        return check_program(
            self.lines, dialect=dialect, codes=self.codes, inch_materials=self.inch,
            materials=MaterialStore(self.library).load() if self.library else None,
            fallback_dialect=Dialect(ControllerSettings().dialect),
        )  # fmt: skip

    def settings(self) -> ControllerSettings:
        """The daemon's [controller] section with the same options."""
        return ControllerSettings(materials_file=self.library, materials_in_inches=self.inch)


def shop_run(name: str, workdir: Path) -> ShopRun:
    shop = SHOP.get(name, {})
    library = None
    if "library" in shop:
        library = workdir / "materials.cfg"
        shutil.copyfile(PROGRAMS / shop["library"], library)
    lines = (PROGRAMS / name).read_text(encoding="utf-8").splitlines()
    return ShopRun(name, lines, library, bool(shop.get("inch")), dict(shop.get("codes", {})))


def assert_agree(check: CheckReport, report: SendReport, summary: dict[str, Any]) -> None:
    """The machine did what the check said: a refused program stops at the line refused
    first; a runnable one runs every cut listed to its end, one row per cut, no fault."""
    assert report.dialect == check.dialect
    assert summary["safety_violations"] == 0, summary["violations"]
    assert summary["torch_on_at_exit"] is False
    if not check.ok:
        assert not report.ok
        assert report.error_line == check.refused[0]["line"], (report.error, check.refused)
        return
    assert check.cuts, "runnable with no cut is not OK (check-program refuses it)"
    assert report.ok, report.error
    assert summary["errors"] == [], summary["errors"]
    cuts = summary["cuts"]
    assert len(cuts) == len(check.cuts)  # each cut it listed burned, one row each
    assert all(cut["arc_on_s"] > 0 for cut in cuts)
