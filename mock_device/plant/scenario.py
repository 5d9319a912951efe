"""Scenario description of a simulated table: material, plate, noise, arc, faults, machine.

A scenario is a TOML file in ``mock_device/scenarios/`` read into frozen dataclasses.
Every table and key is optional except where noted; unknown keys are rejected with an
error naming the exact key (``material.cut_hieght_mm``), and values are checked against
the bounds declared beside each field.
"""

import dataclasses
import math
import tomllib
import types
import typing
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, TypeVar

__all__ = [
    "SCENARIO_DIR",
    "ArcSpec",
    "FaultSpec",
    "GantrySpec",
    "KerfSpec",
    "MaterialSpec",
    "NoiseSpec",
    "PlateSpec",
    "Scenario",
    "ScenarioError",
    "SurfaceCondition",
    "SurfaceSpec",
    "ThcBoxSpec",
    "TorchSpec",
    "VoidSpec",
    "WaveSpec",
    "ZAxisSpec",
    "list_scenarios",
    "load_scenario",
    "scenario_from_dict",
]

SCENARIO_DIR = Path(__file__).resolve().parent.parent / "scenarios"

SurfaceCondition = Literal["clean", "rusty", "painted", "wet"]

_T = TypeVar("_T")


class ScenarioError(ValueError):
    """A scenario file or table is invalid; ``key`` is the dotted path of the culprit."""

    def __init__(self, source: str, key: str, reason: str) -> None:
        self.source = source
        self.key = key
        self.reason = reason
        where = f"{source}: {key}: " if key else f"{source}: "
        super().__init__(where + reason)


class _FieldError(ValueError):
    """Raised inside ``__post_init__`` checks; names the field relative to its table."""

    def __init__(self, key: str, reason: str) -> None:
        self.key = key
        self.reason = reason
        super().__init__(f"{key}: {reason}")


def _num(
    default: float | None,
    *,
    ge: float | None = None,
    gt: float | None = None,
    le: float | None = None,
) -> Any:
    """A numeric field with bounds checked by the loader (``Any``: see ``dataclasses.field``)."""
    return field(default=default, metadata={"ge": ge, "gt": gt, "le": le})


def _range(lo: float, hi: float, *, ge: float = 0.0) -> Any:
    """A ``(low, high)`` pair, both ``>= ge`` and ``low <= high``."""
    return field(default=(lo, hi), metadata={"ge": ge, "ordered": True})


@dataclass(frozen=True, slots=True)
class MaterialSpec:
    """The material being cut and its cut-chart values."""

    name: str = "mild steel 2 mm, 45 A"
    thickness_mm: float = _num(2.0, gt=0.0)
    cut_height_mm: float = _num(1.5, gt=0.0)
    cut_voltage_v: float = _num(125.0, gt=0.0)
    slope_v_per_mm: float = _num(7.5, gt=0.0)
    pierce_height_mm: float = _num(3.8, gt=0.0)
    cut_feed_mm_min: float = _num(5500.0, gt=0.0)
    kerf_width_mm: float = _num(1.5, gt=0.0)
    # The cut voltage the operator enters (G200 V, plasmac's cut volts) when it is not the
    # arc's voltage at cut height (``cut_voltage_v``): a wrong chart or a typo. None: the same.
    entered_voltage_v: float | None = _num(None, gt=0.0)

    @property
    def programmed_voltage_v(self) -> float:
        """What a controller is given as the cut voltage."""
        return self.cut_voltage_v if self.entered_voltage_v is None else self.entered_voltage_v


@dataclass(frozen=True, slots=True)
class WaveSpec:
    """One sinusoidal warp of the plate: ``amplitude * sin(2π·d/wavelength + phase)``.

    ``d`` is the distance along ``direction_deg`` (0° = +X, 90° = +Y).
    """

    amplitude_mm: float = _num(0.0, ge=0.0)
    wavelength_mm: float = _num(500.0, gt=0.0)
    direction_deg: float = 0.0
    phase_deg: float = 0.0


@dataclass(frozen=True, slots=True)
class PlateSpec:
    """The plate: nominal top in machine Z, size from the origin, tilt about the origin.

    A thin sheet flexes under the heat of the cut: ``flex_start_s`` after the first arc
    transfer (the heat has built up), the whole sheet lifts by
    ``flex_amplitude_mm * (1 - cos(2π·t/flex_period_s)) / 2`` (up to the amplitude and
    back, again and again), however the torch moves.
    """

    top_mm: float = 20.0
    size_x_mm: float = _num(1250.0, gt=0.0)
    size_y_mm: float = _num(1250.0, gt=0.0)
    tilt_x_mm_per_m: float = 0.0
    tilt_y_mm_per_m: float = 0.0
    waves: tuple[WaveSpec, ...] = ()
    flex_amplitude_mm: float = _num(0.0, ge=0.0)
    flex_period_s: float = _num(3.0, gt=0.0)
    flex_start_s: float = _num(0.0, ge=0.0)


@dataclass(frozen=True, slots=True)
class SurfaceSpec:
    """Surface condition and its ohmic-contact behaviour (probabilities per 1 ms sample).

    - ``clean``: contact whenever the tip touches the plate.
    - ``rusty``: while touching, contact is seen on a sample with probability
      ``rusty_contact_probability`` (chatter).
    - ``painted``: never any contact; only the float switch works.
    - ``wet``: a water film conducts: from ``wet_film_mm`` above the plate down to touch the
      contact chatters with probability ``wet_contact_probability`` per sample (a premature,
      unreliable contact); at touch it is solid.
    """

    condition: SurfaceCondition = "clean"
    rusty_contact_probability: float = _num(0.3, ge=0.0, le=1.0)
    wet_film_mm: float = _num(2.0, ge=0.0)
    wet_contact_probability: float = _num(0.5, ge=0.0, le=1.0)


@dataclass(frozen=True, slots=True)
class KerfSpec:
    """An earlier cut line; ``width_mm`` defaults to the material's kerf width."""

    x0_mm: float
    y0_mm: float
    x1_mm: float
    y1_mm: float
    width_mm: float | None = _num(None, gt=0.0)


@dataclass(frozen=True, slots=True)
class VoidSpec:
    """A rectangle with no metal (a dropped part, a gap between slats)."""

    x_min_mm: float
    y_min_mm: float
    x_max_mm: float
    y_max_mm: float

    def __post_init__(self) -> None:
        if self.x_max_mm <= self.x_min_mm:
            raise _FieldError("x_max_mm", "must be greater than x_min_mm")
        if self.y_max_mm <= self.y_min_mm:
            raise _FieldError("y_max_mm", "must be greater than y_min_mm")


@dataclass(frozen=True, slots=True)
class NoiseSpec:
    """Measurement noise on the arc-voltage sample the board's ADC sees."""

    sigma_v: float = _num(0.4, ge=0.0)
    burst_rate_per_s: float = _num(0.0, ge=0.0)
    burst_amplitude_v: float = _num(1.75, ge=0.0)
    burst_duration_s: tuple[float, float] = _range(0.5, 2.0)
    spike_rate_per_s: float = _num(0.0, ge=0.0)
    spike_amplitude_v: tuple[float, float] = _range(20.0, 100.0)
    spike_length_samples: tuple[int, int] = _range(1, 2, ge=1)
    hf_start_spike_rate_per_s: float = _num(0.0, ge=0.0)
    hf_start_window_s: float = _num(0.5, ge=0.0)
    ripple_amplitude_v: float = _num(0.0, ge=0.0)
    ripple_hz: float = _num(100.0, gt=0.0)


@dataclass(frozen=True, slots=True)
class ArcSpec:
    """Arc start, arc-OK timing, voltage model and arc-loss limits."""

    pilot_to_transfer_s: tuple[float, float] = _range(0.15, 0.5)
    pilot_timeout_s: float = _num(3.0, gt=0.0)
    transfer_max_height_mm: float = _num(8.0, gt=0.0)
    arc_ok_delay_ms: tuple[float, float] = _range(5.0, 15.0)
    arc_ok_bounce_ms: tuple[float, float] = _range(0.0, 3.0)
    overshoot_v: float = _num(15.0, ge=0.0)
    settle_s: float = _num(0.3, gt=0.0)
    lose_above_height_mm: float = _num(7.0, gt=0.0)
    void_lose_width_mm: float = _num(6.0, gt=0.0)
    void_lose_ms: float = _num(5.0, ge=0.0)
    rise_v: float = _num(10.0, ge=0.0)
    speed_filter_s: float = _num(0.05, gt=0.0)
    kerf_spike_v: float = _num(20.0, ge=0.0)
    kerf_rise_v_per_s: float = _num(800.0, gt=0.0)
    kerf_fall_v_per_s: float = _num(400.0, gt=0.0)
    open_circuit_v: float = _num(280.0, gt=0.0)
    nominal_current_a: float = _num(45.0, gt=0.0)
    current_v_per_a: float = 0.0


@dataclass(frozen=True, slots=True)
class FaultSpec:
    """Injected faults, in seconds after the first arc transfer of the run (one-shot)."""

    arc_lost_at_s: float | None = _num(None, ge=0.0)
    breakaway_at_s: float | None = _num(None, ge=0.0)


@dataclass(frozen=True, slots=True)
class ThcBoxSpec:
    """External THC box (PlasmaC mode 2); ``set_voltage_v`` defaults to the cut voltage."""

    set_voltage_v: float | None = _num(None, gt=0.0)
    deadband_v: float = _num(1.0, ge=0.0)
    filter_ms: float = _num(10.0, ge=0.0)


@dataclass(frozen=True, slots=True)
class ZAxisSpec:
    """The Z stepper axis: soft limits, kinematic limits, start position."""

    min_mm: float = 0.0
    max_mm: float = 100.0
    max_velocity_mm_s: float = _num(60.0, gt=0.0)
    accel_mm_s2: float = _num(650.0, gt=0.0)
    step_mm: float = _num(0.005, gt=0.0)
    start_mm: float = 60.0
    home_switch_mm: float | None = None  # the home switch; None: 2 mm above max_mm

    def __post_init__(self) -> None:
        if self.max_mm <= self.min_mm:
            raise _FieldError("max_mm", "must be greater than min_mm")
        if self.home_switch_mm is not None and self.home_switch_mm <= self.max_mm:
            raise _FieldError("home_switch_mm", "must lie above max_mm (beyond the soft limits)")
        if not self.min_mm <= self.start_mm <= self.max_mm:
            raise _FieldError("start_mm", "must lie within min_mm..max_mm")


@dataclass(frozen=True, slots=True)
class GantrySpec:
    """XY motion planner limits."""

    accel_mm_s2: float = _num(1500.0, gt=0.0)
    rapid_mm_min: float = _num(10000.0, gt=0.0)
    junction_deviation_mm: float = _num(0.05, gt=0.0)
    arc_chord_mm: float = _num(0.5, gt=0.0)
    start_x_mm: float = 0.0
    start_y_mm: float = 0.0


@dataclass(frozen=True, slots=True)
class TorchSpec:
    """Floating head: float switch travel, hysteresis and bounce; breakaway travel."""

    float_travel_mm: float = _num(1.5, gt=0.0)
    float_hysteresis_mm: float = _num(0.1, ge=0.0)
    float_bounce_ms: float = _num(2.0, ge=0.0)
    max_float_mm: float = _num(6.0, gt=0.0)

    def __post_init__(self) -> None:
        if self.max_float_mm <= self.float_travel_mm:
            raise _FieldError("max_float_mm", "must be greater than float_travel_mm")
        if self.float_hysteresis_mm >= self.float_travel_mm:
            raise _FieldError("float_hysteresis_mm", "must be less than float_travel_mm")


@dataclass(frozen=True, slots=True)
class Scenario:
    """Everything the plant needs to simulate one table set-up."""

    name: str
    description: str = ""
    material: MaterialSpec = field(default_factory=MaterialSpec)
    plate: PlateSpec = field(default_factory=PlateSpec)
    surface: SurfaceSpec = field(default_factory=SurfaceSpec)
    kerfs: tuple[KerfSpec, ...] = ()
    voids: tuple[VoidSpec, ...] = ()
    noise: NoiseSpec = field(default_factory=NoiseSpec)
    arc: ArcSpec = field(default_factory=ArcSpec)
    faults: FaultSpec = field(default_factory=FaultSpec)
    thc_box: ThcBoxSpec = field(default_factory=ThcBoxSpec)
    zaxis: ZAxisSpec = field(default_factory=ZAxisSpec)
    gantry: GantrySpec = field(default_factory=GantrySpec)
    torch: TorchSpec = field(default_factory=TorchSpec)
    default_program: tuple[str, ...] = ()

    @property
    def thc_set_voltage_v(self) -> float:
        """The THC box set point: its own value or the material's cut voltage."""
        if self.thc_box.set_voltage_v is not None:
            return self.thc_box.set_voltage_v
        return self.material.cut_voltage_v


def list_scenarios() -> list[str]:
    """Names of the bundled scenarios (file stems in ``SCENARIO_DIR``), sorted."""
    return sorted(p.stem for p in SCENARIO_DIR.glob("*.toml"))


def load_scenario(name_or_path: str | Path) -> Scenario:
    """Read a bundled scenario by name, or any scenario TOML file by path."""
    text = str(name_or_path)
    if isinstance(name_or_path, Path) or text.endswith(".toml") or "/" in text:
        path = Path(name_or_path)
    else:
        path = SCENARIO_DIR / f"{text}.toml"
        if not path.is_file():
            known = ", ".join(list_scenarios())
            raise ScenarioError(text, "", f"no such scenario (known: {known})")
    try:
        with path.open("rb") as fh:
            data = tomllib.load(fh)
    except OSError as exc:
        raise ScenarioError(str(path), "", f"cannot read: {exc}") from exc
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(str(path), "", f"invalid TOML: {exc}") from exc
    data.setdefault("name", path.stem)
    return scenario_from_dict(data, source=str(path))


def scenario_from_dict(data: Mapping[str, object], *, source: str = "<dict>") -> Scenario:
    """Build a scenario from an already parsed table (tests, generated scenarios)."""
    if "name" not in data:
        data = {**data, "name": "unnamed"}
    try:
        return _build(Scenario, data, "")
    except _FieldError as exc:
        raise ScenarioError(source, exc.key, exc.reason) from None


def _build(cls: type[_T], table: Mapping[str, object], prefix: str) -> _T:
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(typing.cast(Any, cls))}
    for key in table:
        if key not in fields:
            known = ", ".join(sorted(fields))
            raise _FieldError(prefix + key, f"unknown key (known keys: {known})")
    kwargs: dict[str, object] = {}
    for key, value in table.items():
        kwargs[key] = _convert(hints[key], value, prefix + key, fields[key].metadata)
    for name, f in fields.items():
        no_default = f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
        if no_default and name not in kwargs:
            raise _FieldError(prefix + name, "missing required key")
    try:
        return cls(**kwargs)
    except _FieldError as exc:
        raise _FieldError(prefix + exc.key, exc.reason) from None


def _convert(tp: object, value: object, key: str, meta: Mapping[str, object]) -> object:
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if origin is types.UnionType or origin is typing.Union:
        inner = [a for a in args if a is not type(None)]
        return _convert(inner[0], value, key, meta)
    if origin is Literal:
        if value not in args:
            allowed = ", ".join(repr(a) for a in args)
            raise _FieldError(key, f"must be one of {allowed}, got {value!r}")
        return value
    if origin is tuple:
        if not isinstance(value, list):
            raise _FieldError(key, f"must be an array, got {type(value).__name__}")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_convert(args[0], v, f"{key}[{i}]", {}) for i, v in enumerate(value))
        if len(value) != len(args):
            raise _FieldError(key, f"must have {len(args)} elements, got {len(value)}")
        items = tuple(_convert(a, v, key, meta) for a, v in zip(args, value, strict=True))
        if meta.get("ordered") and list(items) != sorted(items):  # type: ignore[type-var]
            raise _FieldError(key, "must be [low, high] with low <= high")
        return items
    if dataclasses.is_dataclass(tp) and isinstance(tp, type):
        if not isinstance(value, dict):
            raise _FieldError(key, f"must be a table, got {type(value).__name__}")
        return _build(tp, value, key + ".")
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise _FieldError(key, f"must be a number, got {value!r}")
        number = float(value)
        if not math.isfinite(number):
            raise _FieldError(key, "must be finite")
        _check_bounds(number, key, meta)
        return number
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise _FieldError(key, f"must be an integer, got {value!r}")
        _check_bounds(value, key, meta)
        return value
    if tp is str:
        if not isinstance(value, str):
            raise _FieldError(key, f"must be a string, got {value!r}")
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise _FieldError(key, f"must be true or false, got {value!r}")
        return value
    raise TypeError(f"scenario field {key} has an unsupported type {tp!r}")


def _check_bounds(value: float, key: str, meta: Mapping[str, object]) -> None:
    ge, gt, le = meta.get("ge"), meta.get("gt"), meta.get("le")
    if isinstance(ge, int | float) and value < ge:
        raise _FieldError(key, f"must be >= {ge}, got {value}")
    if isinstance(gt, int | float) and value <= gt:
        raise _FieldError(key, f"must be > {gt}, got {value}")
    if isinstance(le, int | float) and value > le:
        raise _FieldError(key, f"must be <= {le}, got {value}")
