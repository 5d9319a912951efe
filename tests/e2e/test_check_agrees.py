"""check-program and the machine agree (issue 31): every program in tests/programs, with
the options its shop would give (a material library, its own codes), is checked, then run
through the stack (mosquitto, the daemon and the mock as processes, the reference sender)
with the same options and the dialect detection an owner gets by default. A program the
check calls runnable runs every cut it listed to completion, one row per cut; a program it
refuses stops at the line it refused first. (Whether a cut is good is the program's and
the scenario's: a fixed voltage the sheet does not give makes the THC follow it.)"""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import pytest

from dthc_bridge.config import ControllerSettings
from dthc_bridge.controller.dialect import Dialect
from dthc_bridge.materials import MaterialStore
from dthc_bridge.program.check import check_program
from dthc_tools.demo import Stack, StackOptions
from dthc_tools.demo.summary import summarize

pytestmark = [pytest.mark.slow, pytest.mark.timeout(180)]

PROGRAMS = Path(__file__).parents[1] / "programs"
NAMES = sorted(p.name for p in PROGRAMS.iterdir() if p.suffix in (".nc", ".ngc"))
METRIC, INCH = "shop_material.cfg", "shop_material_inch.cfg"
# What the shop gives with each program: its library (and whether it is in inches), the
# codes its post writes for the torch.
SHOP: dict[str, dict[str, Any]] = {
    "firecontrol_relay.nc": {"codes": {"M10": "M3", "M11": "M5"}},
    "sheetcam_shop_m13_m15.nc": {"codes": {"M13": "M3", "M15": "M5"}},
    "linuxcnc_material_change.ngc": {"library": METRIC},
    "plasmac_material_overcut.ngc": {"library": METRIC},
    "plasmac_pierce_only.ngc": {"library": INCH, "inch": True},
    "sheetcam_plasmac_inch.ngc": {"library": INCH, "inch": True},
}


@pytest.mark.parametrize("name", NAMES)
async def test_what_check_program_calls_runnable_runs_on_the_machine(
    name: str, tmp_path: Path
) -> None:
    shop = SHOP.get(name, {})
    lines = (PROGRAMS / name).read_text(encoding="utf-8").splitlines()
    library = None
    if "library" in shop:
        library = tmp_path / "materials.cfg"
        shutil.copyfile(PROGRAMS / shop["library"], library)
    inch = bool(shop.get("inch"))
    codes: dict[str, str] = shop.get("codes", {})
    check = check_program(  # as `dthc-bridge check-program` runs it, with the same options
        lines, codes=codes, inch_materials=inch,
        materials=MaterialStore(library).load() if library else None,
        fallback_dialect=Dialect(ControllerSettings().dialect),
    )  # fmt: skip
    options = StackOptions(tmp_path, broker="mosquitto", materials_file=library,
                           controller={"materials_in_inches": inch})  # fmt: skip
    async with Stack(options) as stack:
        report = await stack.send(lines, codes=codes)
        result = await stack.finish(report)
    summary = summarize(result, options.telemetry_hz)
    print(json.dumps({name: {"check": "ok" if check.ok else "refused", "cuts": len(check.cuts),
                             "dialect": check.dialect, "ran": report.ok,
                             "completed": summary["completed_cuts"],
                             "height_rms_mm": summary["height_rms_mm"],
                             "violations": summary["safety_violations"]}}))  # fmt: skip
    assert report.dialect == check.dialect
    assert summary["safety_violations"] == 0
    if not check.ok:
        assert not report.ok
        assert report.error_line == check.refused[0]["line"], (report.error, check.refused)
        return
    assert check.cuts, "runnable with no cut is not OK (check-program refuses it)"
    assert report.ok, report.error
    assert summary["errors"] == [], summary["errors"]
    cuts = summary["cuts"]
    assert isinstance(cuts, list)
    assert len(cuts) == len(check.cuts)  # each cut it listed burned, one row each
    assert all(cut["arc_on_s"] > 0 for cut in cuts)
    assert summary["torch_on_at_exit"] is False
