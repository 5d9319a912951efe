"""probe_away_release on a board that predates it: SKIP, not FAIL (protocol 1.2)."""

from __future__ import annotations

import pytest

import firmware_protocol as fp
from dthc_bridge.conformance import CHECK_NAMES, ConformanceOptions
from dthc_bridge.conformance.checks_probe_away import PROBE_AWAY_MINOR, check_probe_away_release
from dthc_bridge.conformance.context import SuiteContext
from dthc_bridge.conformance.rawlink import RawBoardLink


def _info(minor: int) -> fp.HelloInfo:
    return fp.HelloInfo(
        1, fp.PROTOCOL_MAJOR, minor, 0, 3, 1, fp.ResetReason.POWER_ON, 0x5EED1234, "OLD-BOARD",
        1000, 5, int(fp.Capability.OHMIC | fp.Capability.FLOAT), 0, 100_000, 256, 250,
    )  # fmt: skip


@pytest.mark.parametrize("minor", [0, 1])
async def test_a_board_announcing_less_than_1_2_is_skipped_without_moving(minor: int) -> None:
    """A 1.0 or 1.1 board never heard of Z_PROBE_AWAY: the check is skipped with the
    versions named (as lease_idle_lapse skips a 1.0 board), and sends nothing: the link
    was never opened."""
    link = RawBoardLink("sim://never-opened", ack_timeout_s=0.02)
    ctx = SuiteContext(link, ConformanceOptions(link="sim://never-opened"))
    ctx.info = _info(minor)
    (result,) = await check_probe_away_release(ctx)
    assert result.name == "probe_away_release"
    assert result.passed is None
    assert f"1.{minor}" in result.figure
    assert f"1.{PROBE_AWAY_MINOR}" in result.figure
    assert ctx.link.mark() == 0


def test_the_check_runs_after_the_touch_off_check() -> None:
    """It follows probe_contact, whose setup (a plate within reach) it shares."""
    names = list(CHECK_NAMES)
    assert names.index("probe_away_release") == names.index("probe_contact") + 1
