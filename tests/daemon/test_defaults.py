"""One source of truth for defaults: the configuration model and the pure objects agree.

The pure objects (``ThcConfig``, ``SequenceConfig``, ``LinkTiming``, the protocol's
constants) define each default once; ``dthc_bridge.config`` reads its field defaults from
them. These tests fail when the two drift: a default repeated as a literal and changed on
one side, a config field added without saying which pure field it sets, or a field that
no longer reaches the object the daemon builds.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import inspect
import os
import sys
from collections.abc import Callable
from dataclasses import dataclass
from types import ModuleType
from typing import Any

import pytest
from pydantic import BaseModel

import firmware_protocol as fp
from dthc_bridge import config as config_module
from dthc_bridge.config import (
    BoardSettings,
    ControllerConfigs,
    ControllerSettings,
    DaemonConfig,
    ThcSettings,
    default_controller_configs,
)
from dthc_bridge.controller.commands import ThcMode
from dthc_bridge.controller.sequence import CutSequence, SequenceConfig
from dthc_bridge.controller.thc import ThcConfig
from dthc_bridge.daemon import build_service
from dthc_bridge.link import LinkSupervisor, LinkTiming
from dthc_bridge.transport import open_transport


@dataclass(frozen=True)
class Section:
    """A config section and the pure object it builds."""

    model: type[BaseModel]
    pure: type[Any]  # a dataclass
    build: Callable[[Any], object]  # section -> pure object, as the daemon calls it
    of: Callable[[DaemonConfig], BaseModel]  # the section inside a DaemonConfig
    # Config fields named differently from the pure field they set: name -> (pure, to_pure).
    renamed: dict[str, tuple[str, Callable[[Any], Any]]]
    # Config fields that set no field of the pure object, each with the reason.
    config_only: dict[str, str]
    # Pure fields whose daemon default deliberately differs from the pure default, each
    # with the reason. None today: the daemon runs the pure objects' defaults.
    overrides: dict[str, str]

    def mapping(self) -> dict[str, tuple[str, Callable[[Any], Any]]]:
        """Every config field that sets a pure field: name -> (pure field, to_pure)."""
        pure_names = {f.name for f in dataclasses.fields(self.pure)}
        same = {
            name: (name, _same)
            for name in self.model.model_fields
            if name in pure_names and name not in self.config_only
        }
        return same | self.renamed


def _same(value: Any) -> Any:
    return value


SECTIONS = {
    "controller.thc": Section(
        model=ThcSettings,
        pure=ThcConfig,
        build=ThcSettings.build,
        of=lambda config: config.controller.thc,
        renamed={},
        config_only={},
        overrides={},
    ),
    "controller": Section(
        model=ControllerSettings,
        pure=SequenceConfig,
        build=ControllerSettings.sequence,
        of=lambda config: config.controller,
        renamed={},
        config_only={
            "mode": "CutSequence.mode, not a SequenceConfig field (checked below)",
            "thc": "the [controller.thc] section (its own entry)",
            "dialect": "the ControllerService's default dialect, not the sequence's",
            "plasma_mode_at_start": "CutSequence.plasma_mode at start (daemon.build_service)",
            "materials_file": "the MaterialStore the service writes",
            "consumables_file": "the ConsumableLog the service counts pierces and arc time in",
            "materials_in_inches": "PlasmaController.inch_materials",
            "default_cut_feed_mm_min": "PlasmaController.default_material (material 0)",
            "codes": "the sender's code table, given at program_start",
        },
        overrides={},
    ),
    "board": Section(
        model=BoardSettings,
        pure=LinkTiming,
        build=BoardSettings.timing,
        of=lambda config: config.board,
        renamed={"ack_timeout_ms": ("ack_timeout_s", lambda ms: ms / 1000.0)},
        config_only={
            "link": "the installation's board URL; no pure default",
            "homing": "the [board.homing] section: the service's HomingPlan (checked below)",
            "baudrate": "a LinkSupervisor argument (checked below)",
            "sample_rate_hz": "BoardClient.configure, protocol default (checked below)",
            "batch_size": "BoardClient.configure, protocol default (checked below)",
            "filter": "BoardClient.configure argument; the daemon passes it",
            "filter_param": "BoardClient.configure argument; the daemon passes it",
            "arc_lost_ms": "BoardClient.configure argument; the daemon passes it",
            "cal_offset": "BoardClient.configure argument; the daemon passes it",
            "cal_scale": "BoardClient.configure argument; the daemon passes it",
        },
        overrides={},
    ),
}


@pytest.fixture(autouse=True)
def _no_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    """DaemonConfig() reads DTHC_* variables: these tests see the model's own defaults."""
    for name in list(os.environ):
        if name.upper().startswith("DTHC_"):
            monkeypatch.delenv(name)


def _pure_default(section: Section, name: str) -> Any:
    return getattr(section.pure(), name)


@pytest.mark.parametrize("name", SECTIONS)
def test_every_config_field_sets_a_pure_field_or_says_why_not(name: str) -> None:
    """A config field added without a pure counterpart (or a reason) fails here."""
    section = SECTIONS[name]
    classified = set(section.mapping()) | set(section.config_only)
    assert set(section.model.model_fields) == classified
    pure_names = {f.name for f in dataclasses.fields(section.pure)}
    assert {pure for pure, _ in section.mapping().values()} <= pure_names
    assert set(section.overrides) <= pure_names


@pytest.mark.parametrize("name", SECTIONS)
def test_config_field_defaults_equal_the_pure_defaults(name: str) -> None:
    """Each config default, converted to the pure field's unit, is the pure default."""
    section = SECTIONS[name]
    for field, (pure, to_pure) in section.mapping().items():
        default = section.model.model_fields[field].default
        assert to_pure(default) == _pure_default(section, pure), f"{name}.{field}"


@pytest.mark.parametrize("name", SECTIONS)
def test_the_daemon_builds_the_pure_defaults_except_listed_overrides(name: str) -> None:
    """The object built from DaemonConfig() is the pure default but for listed overrides."""
    section = SECTIONS[name]
    built = section.build(section.of(DaemonConfig()))
    kept = {field: getattr(built, field) for field in section.overrides}
    assert built == dataclasses.replace(section.pure(), **kept)
    for field in section.overrides:  # a stale entry: the override no longer differs
        assert kept[field] != _pure_default(section, field), f"{name}: {field}"


def _changed(value: Any) -> Any:
    if isinstance(value, bool):
        return not value
    if isinstance(value, int):
        return value + 1
    if isinstance(value, float):
        return value + 0.125
    raise AssertionError(f"no changed value for {value!r}")


@pytest.mark.parametrize("name", SECTIONS)
def test_every_config_field_reaches_the_built_object(name: str) -> None:
    """A changed value in each config field arrives in its pure field (the build maps it)."""
    section = SECTIONS[name]
    defaults = section.model()
    for field, (pure, to_pure) in section.mapping().items():
        value = _changed(getattr(defaults, field))
        built = section.build(defaults.model_copy(update={field: value}))
        assert getattr(built, pure) == to_pure(value), f"{name}.{field}"


@pytest.fixture
def config_with_changed_pure_defaults(monkeypatch: pytest.MonkeyPatch) -> ModuleType:
    """``dthc_bridge.config`` executed afresh after every pure default was changed."""
    for pure in {section.pure for section in SECTIONS.values()}:
        defaults = pure.__init__.__defaults__
        assert defaults is not None  # every field of a pure config object has a default
        monkeypatch.setattr(pure.__init__, "__defaults__", tuple(map(_changed, defaults)))
    name = "dthc_bridge._config_with_changed_defaults"
    spec = importlib.util.spec_from_file_location(name, config_module.__file__)
    assert spec is not None
    assert spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, name, module)  # pydantic resolves annotations here
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize("name", SECTIONS)
def test_config_defaults_are_read_from_the_pure_objects(
    name: str, config_with_changed_pure_defaults: ModuleType
) -> None:
    """Change the pure defaults and the model's defaults follow: none is a copied literal."""
    section = SECTIONS[name]
    model = getattr(config_with_changed_pure_defaults, section.model.__name__)
    for field, (pure, to_pure) in section.mapping().items():
        changed = _pure_default(section, pure)
        assert changed != getattr(section.pure, pure)  # the class attribute: the original
        assert to_pure(model.model_fields[field].default) == changed, f"{name}.{field}"


def test_controller_mode_default_is_the_mode_a_cut_sequence_starts_in() -> None:
    """``controller.mode`` cannot read CutSequence's starting mode; it must equal it."""
    assert DaemonConfig().controller.thc_mode is CutSequence().mode


def test_protocol_defaults_come_from_firmware_protocol() -> None:
    """Sampling, lease, window and velocity expiry defaults are the protocol's constants."""
    board = DaemonConfig().board
    assert (board.sample_rate_hz, board.batch_size) == (
        fp.DEFAULT_SAMPLE_RATE_HZ,
        fp.DEFAULT_BATCH_SIZE,
    )
    timing = LinkTiming()
    assert timing.lease_ms == fp.DEFAULT_LEASE_MS
    assert timing.window == fp.HOST_WINDOW
    assert timing.velocity_expiry_ms == fp.DEFAULT_ZVEL_EXPIRY_MS


def test_baudrate_default_is_the_link_supervisors() -> None:
    """The baud rate is still written in several signatures: they must agree."""
    baudrate = DaemonConfig().board.baudrate
    for function in (LinkSupervisor, open_transport):
        assert inspect.signature(function).parameters["baudrate"].default == baudrate


def test_default_controller_configs_are_the_sections_defaults() -> None:
    """The tools' defaults are built from DaemonConfig() the way build_service does."""
    controller = DaemonConfig().controller
    assert default_controller_configs() == ControllerConfigs(
        controller.sequence(), controller.thc.build(), controller.thc_mode
    )
    assert default_controller_configs().mode is ThcMode.ARC_OK_AND_VOLTAGE


def test_default_controller_configs_ignore_the_environment(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A DTHC_* variable changes the daemon's config, never the tools' defaults."""
    monkeypatch.setenv("DTHC_CONTROLLER__THC__KP_PER_S", "20")
    monkeypatch.setenv("DTHC_CONTROLLER__SAFE_HEIGHT_MM", "30")
    assert DaemonConfig().controller.thc.kp_per_s == 20.0
    assert DaemonConfig().controller.safe_height_mm == 30.0
    configs = default_controller_configs()
    assert configs.thc.kp_per_s == ThcConfig().kp_per_s
    assert configs.sequence.safe_height_mm == SequenceConfig().safe_height_mm


async def test_default_controller_configs_are_what_the_daemon_runs() -> None:
    """build_service(DaemonConfig()) drives a CutSequence with exactly these objects."""
    supervisor, service = build_service(DaemonConfig())
    sequence, thc, mode = default_controller_configs()
    assert service.sequence.config == sequence
    assert service.sequence.thc.config == thc
    assert service.sequence.mode is mode
    assert supervisor.timing == DaemonConfig().board.timing() == LinkTiming()


def test_the_homing_section_defaults_are_the_services() -> None:
    """[board.homing] as shipped is the HomingPlan the service runs without one: off."""
    from dthc_bridge.board import HomingPlan
    from dthc_bridge.config import HomingSettings

    assert HomingSettings().plan() == HomingPlan()
    assert HomingPlan().mode == "off"
