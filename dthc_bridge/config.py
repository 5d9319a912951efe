"""The daemon's configuration: one closed, typed model read from TOML, env overrides on top.

Unknown keys are refused with the exact key named; bounds sit beside each field.
Environment variables override the file: ``DTHC_MQTT__HOST=broker`` sets ``[mqtt] host``.
An integer field takes an integer: ``port = 1883.0`` (or ``true``) is refused, not
converted as pydantic's lax mode would, while the environment's text ``"1883"`` is read as
the integer.

One source of truth for defaults: the pure objects the daemon builds (:class:`ThcConfig`,
:class:`SequenceConfig`, :class:`LinkTiming`, the protocol's constants) define every
default once; a field here that sets one of their values reads its default from a default
instance (``default=_THC.deadband_v``) and keeps only its bounds. The pure objects are the
source because they are what the controller, the tests and the benchmarks run without a
configuration file; the model only narrows what a user may set. Attribute access (not a
name in a string) lets mypy catch a misspelt field. ``tests/daemon/test_defaults.py``
fails when the two drift. :func:`default_controller_configs` gives tools the controller
objects the daemon runs with no configuration.
"""

from __future__ import annotations

import re
import tomllib
import types
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Literal, NamedTuple, Union, get_args, get_origin

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    field_validator,
    model_validator,
)
from pydantic_core import PydanticCustomError
from pydantic_settings import BaseSettings, PydanticBaseSettingsSource, SettingsConfigDict

import firmware_protocol as fp

from .board import HomingMode, HomingPlan
from .code_map import parse_code_map
from .controller.commands import ThcMode
from .controller.sequence import SequenceConfig
from .controller.thc import ThcConfig
from .link import LinkTiming
from .mqtt.settings import MqttSettings

__all__ = [
    "ConfigError",
    "ControllerConfigs",
    "DaemonConfig",
    "default_controller_configs",
    "load_config",
]

# The pure objects' defaults, read by the fields below (never repeated as literals).
_LINK = LinkTiming()
_SEQ = SequenceConfig()
_THC = ThcConfig()
_HOMING = HomingPlan()


class _Closed(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class HomingSettings(_Closed):
    """Z homing on the board's home switch (protocol 1.3, HOMING): ``at_start`` homes each
    time the board comes online unhomed (power-on, a reset); ``required`` does the same and
    refuses cuts while Z is unhomed. Off by default: the firmware cannot tell whether a
    switch is wired, and a seek with none runs Z into its hard stop for ``max_travel_mm``."""

    mode: HomingMode = _HOMING.mode
    seek_mm_s: float = Field(_HOMING.seek_mm_s, gt=0.0, le=200.0, description="up to the switch")
    locate_mm_s: float = Field(_HOMING.locate_mm_s, gt=0.0, le=50.0, description="the slow re-seek")
    backoff_mm: float = Field(
        _HOMING.backoff_mm, gt=0.0, le=20.0, description="off the switch, and parked"
    )
    max_travel_mm: float = Field(
        _HOMING.max_travel_mm, gt=0.0, le=2000.0, description="the seek's limit"
    )
    timeout_s: float = Field(_HOMING.timeout_s, gt=0.0, le=65.0)

    def plan(self) -> HomingPlan:
        return HomingPlan(**self.model_dump())


class BoardSettings(_Closed):
    link: str = Field("/dev/dthc0", description="/dev/..., socket://HOST:PORT or usb://VID:PID")
    baudrate: int = Field(921_600, ge=9600, le=12_000_000)
    lease_ms: int = Field(_LINK.lease_ms, ge=fp.LEASE_MIN_MS, le=fp.LEASE_MAX_MS)
    ack_timeout_ms: float = Field(_LINK.ack_timeout_s * 1000.0, ge=2.0, le=2000.0)
    max_attempts: int = Field(_LINK.max_attempts, ge=1, le=20)
    sample_rate_hz: int = Field(fp.DEFAULT_SAMPLE_RATE_HZ, ge=100, le=20_000)
    batch_size: int = Field(fp.DEFAULT_BATCH_SIZE, ge=1, le=fp.MAX_BATCH_SIZE)
    filter: Literal["none", "moving_average", "low_pass", "median3"] = "median3"
    filter_param: int = Field(0, ge=0, le=500)
    arc_lost_ms: int = Field(0, ge=0, le=1000, description="board-side arc-lost latch; 0 = off")
    cal_offset: int = 0
    cal_scale: float = Field(0.01, gt=0.0, description="volts per raw count")
    homing: HomingSettings = HomingSettings()

    def timing(self) -> LinkTiming:
        return LinkTiming(
            ack_timeout_s=self.ack_timeout_ms / 1000.0,
            max_attempts=self.max_attempts,
            lease_ms=self.lease_ms,
        )


class ThcSettings(_Closed):
    kp_per_s: float = Field(_THC.kp_per_s, gt=0.0, le=100.0)
    ki_per_s2: float = Field(_THC.ki_per_s2, ge=0.0, le=1000.0)
    deadband_v: float = Field(_THC.deadband_v, ge=0.0, le=5.0)
    lowpass_hz: float = Field(_THC.lowpass_hz, gt=0.0, le=500.0)
    slope_v_per_mm: float = Field(_THC.slope_v_per_mm, gt=1.0, le=20.0)
    max_speed_mm_s: float = Field(_THC.max_speed_mm_s, gt=0.0, le=100.0)
    max_accel_mm_s2: float = Field(_THC.max_accel_mm_s2, gt=0.0, le=5000.0)
    void_slope_v_s: float = Field(_THC.void_slope_v_s, gt=0.0)
    # Follow a steady slow-down once its voltage rise has settled (False: hold Z through it).
    slow_follow: bool = _THC.slow_follow
    slow_follow_max_mm: float = Field(_THC.slow_follow_max_mm, ge=0.0, le=10.0)

    def build(self) -> ThcConfig:
        return ThcConfig(**self.model_dump())


_NOT_SEQUENCE = frozenset(
    {"dialect", "plasma_mode_at_start", "materials_file", "materials_in_inches",
     "default_cut_feed_mm_min", "codes", "consumables_file"}
)  # fmt: skip


class ControllerSettings(_Closed):
    # CutSequence.__init__ starts in this mode (ARC_OK_AND_VOLTAGE), not a SequenceConfig
    # field, so it cannot be read from one; tests/daemon/test_defaults.py holds them equal.
    # int with bounds, not Literal[0, 1, 2]: an environment override arrives as text ("0").
    mode: int = Field(1, ge=0, le=2)
    probe_height_mm: float = Field(_SEQ.probe_height_mm, gt=0.0, le=200.0)
    float_travel_mm: float = Field(_SEQ.float_travel_mm, ge=0.0, le=10.0)
    ohmic_offset_mm: float = Field(_SEQ.ohmic_offset_mm, ge=-5.0, le=5.0)
    ohmic_retries: int = Field(_SEQ.ohmic_retries, ge=0, le=5)
    arc_ok_timeout_s: float = Field(_SEQ.arc_ok_timeout_s, gt=0.0, le=10.0)
    arc_start_attempts: int = Field(_SEQ.arc_start_attempts, ge=1, le=10)
    arc_retry_delay_s: float = Field(_SEQ.arc_retry_delay_s, ge=0.0, le=10.0)
    arc_lost_delay_s: float = Field(_SEQ.arc_lost_delay_s, ge=0.0, le=1.0)
    thc_delay_s: float = Field(_SEQ.thc_delay_s, ge=0.0, le=9.0)
    # The THC's height window (1 mm below cut height, 4 mm above, by the arc voltage):
    # reaching an edge ends the cut with an error. Below is kept under 10 mm and above
    # 0.5 mm, so that it always stops something.
    thc_window_below_mm: float = Field(_SEQ.thc_window_below_mm, ge=0.2, le=10.0)
    thc_window_above_mm: float = Field(_SEQ.thc_window_above_mm, ge=0.5, le=20.0)
    safe_height_mm: float = Field(_SEQ.safe_height_mm, gt=0.0, le=100.0)
    pause_at_end_s: float = Field(_SEQ.pause_at_end_s, ge=0.0, le=5.0)
    puddle_height_percent: float = Field(_SEQ.puddle_height_percent, ge=50.0, le=300.0)
    puddle_delay_s: float = Field(_SEQ.puddle_delay_s, ge=0.0, le=5.0)
    ihs_skip_distance_mm: float = Field(_SEQ.ihs_skip_distance_mm, ge=0.0, le=1000.0)
    # SequenceConfig types it int; the model narrows it to 0 or 1.
    ihs_skip_type: int = Field(_SEQ.ihs_skip_type, ge=0, le=1)
    dry_run: bool = _SEQ.dry_run
    thc: ThcSettings = ThcSettings()
    # The dialect of G-code lines whose request names none (dthc_bridge.controller.dialect).
    dialect: Literal["masso", "plasmac", "rosetta", "relay"] = "masso"
    # A plasma-only table: M3 lights the torch with no tool change first (most posts send
    # none), and a tool change is a note that never leaves plasma mode. False: a table whose
    # sender drives other tools too (a MASSO router with a plasma head): T112 M6 (PlasmaC
    # T0 M6) enters plasma mode and any other tool leaves it.
    plasma_mode_at_start: bool = True
    # The material library (QtPlasmaC format), written crash-safe on every change; None:
    # no library (material 0, the default, only; material_set is refused).
    materials_file: Path | None = None
    materials_in_inches: bool = False  # the library's lengths and feeds are inches
    # Pierce count and arc-on time (consumable life), kept across restarts. None: in the
    # service's StateDirectory under systemd, else ~/.local/state/dthc-bridge/.
    consumables_file: Path | None = None
    # Material 0 (the default): the default cut parameters with this cut feed.
    default_cut_feed_mm_min: float = Field(3000.0, gt=0.0, le=50_000.0)
    # A shop's own codes mapped to the daemon's ({"H1" = "M667"}): the sender and
    # check-program rewrite them before parsing (the sender asks at program_start).
    codes: dict[str, str] = {}

    @field_validator("codes")
    @classmethod
    def _check_codes(cls, codes: dict[str, str]) -> dict[str, str]:
        return parse_code_map([f"{code}={line}" for code, line in codes.items()])

    def sequence(self) -> SequenceConfig:
        fields = self.model_dump(exclude={"mode", "thc", *_NOT_SEQUENCE})
        return SequenceConfig(**fields)

    @property
    def thc_mode(self) -> ThcMode:
        return ThcMode(self.mode)

    def configs(self) -> ControllerConfigs:
        """What the daemon's controller is built from (see ``daemon.build_controller``)."""
        return ControllerConfigs(self.sequence(), self.thc.build(), self.thc_mode)


class ControllerConfigs(NamedTuple):
    """The pure objects a :class:`CutSequence` is built from, and the mode it runs in."""

    sequence: SequenceConfig
    thc: ThcConfig
    mode: ThcMode


def default_controller_configs() -> ControllerConfigs:
    """The controller configuration the daemon runs without a file or environment override.

    Built the way ``daemon.build_service`` builds it, from the ``[controller]`` section's
    defaults (the environment is not read), so a simulation or benchmark runs exactly the
    daemon's values.
    """
    return ControllerSettings().configs()


class LoggingSettings(_Closed):
    level: Literal["debug", "info", "warning", "error"] = "info"
    json_logs: bool | None = Field(None, description="None: JSON when stderr is not a TTY")
    trace_frames: bool = Field(
        False, description="keep each session's last frames; log them when a corrupt one arrives"
    )


class DaemonConfig(BaseSettings):
    model_config = SettingsConfigDict(
        env_prefix="DTHC_", env_nested_delimiter="__", extra="forbid", frozen=True
    )

    board: BoardSettings = BoardSettings()
    mqtt: MqttSettings = MqttSettings()
    controller: ControllerSettings = ControllerSettings()
    logging: LoggingSettings = LoggingSettings()

    @classmethod
    def settings_customise_sources(
        cls,
        settings_cls: type[BaseSettings],
        init_settings: PydanticBaseSettingsSource,
        env_settings: PydanticBaseSettingsSource,
        dotenv_settings: PydanticBaseSettingsSource,
        file_secret_settings: PydanticBaseSettingsSource,
    ) -> tuple[PydanticBaseSettingsSource, ...]:
        # The environment overrides the file (the file's values arrive as init arguments).
        return (env_settings, init_settings)

    @model_validator(mode="before")
    @classmethod
    def _integers_are_integers(cls, data: object) -> object:
        if isinstance(data, Mapping):
            problems = _non_integers(cls, data, ())
            if problems:
                raise PydanticCustomError("int_not_integral", "; ".join(problems))
        return data


_INTEGER_TEXT = re.compile(r"\s*[+-]?[0-9][0-9_]*\s*")


def _non_integers(
    model: type[BaseModel], data: Mapping[str, object], where: tuple[str, ...]
) -> list[str]:
    """``key: must be an integer, not 1883.0`` for each integer field given a float or a
    boolean (from TOML) or a number with a fraction or exponent (the environment's text)."""
    problems: list[str] = []
    for name, value in data.items():
        field = model.model_fields.get(name) if isinstance(name, str) else None
        if field is None:
            continue  # an unknown key: pydantic names it
        key = (*where, name)
        kinds = _annotation_kinds(field.annotation)
        if isinstance(value, Mapping):
            for nested in kinds:
                if isinstance(nested, type) and issubclass(nested, BaseModel):
                    problems += _non_integers(nested, value, key)
        elif int in kinds and float not in kinds and _not_an_integer(value, kinds):
            problems.append(f"{'.'.join(key)}: must be an integer, not {value!r}")
    return problems


def _annotation_kinds(annotation: object) -> tuple[object, ...]:
    """``int | None`` -> (int, NoneType); ``int`` -> (int,)."""
    if get_origin(annotation) in (Union, types.UnionType):
        return get_args(annotation)
    return (annotation,)


def _not_an_integer(value: object, kinds: tuple[object, ...]) -> bool:
    if isinstance(value, bool):
        return bool not in kinds
    if isinstance(value, float):
        return True
    if isinstance(value, str) and not _INTEGER_TEXT.fullmatch(value):
        try:
            float(value)
        except ValueError:
            return False  # not a number at all: pydantic says so
        return True
    return False


class ConfigError(Exception):
    """The configuration cannot be used; the message names the file and the exact key."""


def load_config(path: Path | None) -> DaemonConfig:
    data: dict[str, Any] = {}
    if path is not None:
        try:
            data = tomllib.loads(path.read_text())
        except OSError as exc:
            raise ConfigError(f"{path}: {exc.strerror or exc}") from None
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError(f"{path}: not valid TOML: {exc}") from None
    try:
        return DaemonConfig(**data)
    except ValidationError as exc:
        problems = []
        for error in exc.errors():
            key = ".".join(str(part) for part in error["loc"])
            problems.append(f"{key}: {error['msg']}" if key else error["msg"])
        where = str(path) if path else "environment"
        raise ConfigError(f"{where}: " + "; ".join(problems)) from None
