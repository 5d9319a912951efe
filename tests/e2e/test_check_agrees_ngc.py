"""check-program and the machine agree on the .ngc programs in tests/programs (PlasmaC and
RosettaCNC forms) chosen for the processes: see test_check_agrees.py, which runs the .nc
ones."""

from __future__ import annotations

from pathlib import Path

import pytest

from ..program_shop import NGC_NAMES
from .test_check_agrees import ON_THE_STACK, agrees

pytestmark = [pytest.mark.slow, pytest.mark.timeout(180)]


@pytest.mark.parametrize("name", [name for name in NGC_NAMES if name in ON_THE_STACK])
async def test_what_check_program_calls_runnable_runs_on_the_machine(
    name: str, tmp_path: Path
) -> None:
    await agrees(name, tmp_path)
