"""Physics behind the simulated DTHC board: pure, deterministic, simulated time.

No I/O, no asyncio, no threads, no wall clock. The board (mock_device.board_logic, the
firmware's C board logic) owns a :class:`Plant` and calls ``Plant.step(dt_s)`` once per
sample period.
"""

from .arc import Arc, ArcEnd, ArcState
from .gantry import Gantry, GcodeError, Segment
from .inputs import InputBit
from .noise import NoiseGenerator
from .plant import DEFAULT_DT_S, Plant
from .scenario import (
    SCENARIO_DIR,
    Scenario,
    ScenarioError,
    list_scenarios,
    load_scenario,
    scenario_from_dict,
)
from .surface import GAP_KERF, GAP_METAL, GAP_WIDE, PlateSurface
from .thc_box import ThcBox
from .torch import TorchHead
from .truth import (
    TRUTH_FIELDS,
    VIOLATION_LEASE,
    VIOLATION_TOUCH,
    CutStats,
    TruthRecorder,
    TruthRow,
    TruthSummary,
)
from .zaxis import ZAxis, ZState

__all__ = [
    "DEFAULT_DT_S",
    "GAP_KERF",
    "GAP_METAL",
    "GAP_WIDE",
    "SCENARIO_DIR",
    "TRUTH_FIELDS",
    "VIOLATION_LEASE",
    "VIOLATION_TOUCH",
    "Arc",
    "ArcEnd",
    "ArcState",
    "CutStats",
    "Gantry",
    "GcodeError",
    "InputBit",
    "NoiseGenerator",
    "Plant",
    "PlateSurface",
    "Scenario",
    "ScenarioError",
    "Segment",
    "ThcBox",
    "TorchHead",
    "TruthRecorder",
    "TruthRow",
    "TruthSummary",
    "ZAxis",
    "ZState",
    "list_scenarios",
    "load_scenario",
    "scenario_from_dict",
]
