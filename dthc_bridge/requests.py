"""The daemon's requests, declared once: for each name, the payload it takes, who may send
it and what serves it.

:data:`REQUESTS` is the one table. The MQTT gateway decodes a payload with its entry's model
(:class:`GcodeRequest` for ``gcode``, :class:`Request` otherwise) and hands it to the
:class:`~dthc_bridge.port.ControllerPort` (:func:`execute`); the controller service serves a
named request with its entry's handler (:func:`serve_request`); the broker's ACL gives the
panel's user only the entries that are not ``sender_only`` (:mod:`dthc_bridge.mqtt.roles`);
the fuzz bench draws its names from it. A request that becomes a controller command carries
its argument names and its parser here too, so arguments are checked in one place: an
unknown or missing argument, or a bad value, is a :class:`CommandError` naming
``"<name> <argument>"``; the envelope keys ``transaction`` and ``deadline_ms`` are ignored.

Below the gateway and the service, above the controller: it imports the controller's
typed commands and the seam's :class:`CommandResult`, never aiomqtt, the service or the
board.
"""

from __future__ import annotations

import math
from collections.abc import Awaitable, Callable, Mapping
from dataclasses import dataclass
from typing import Final, Literal, Protocol, Self

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    JsonValue,
    ValidationError,
    field_validator,
    model_validator,
)
from pydantic_core import PydanticCustomError

from .controller.commands import (
    Abort,
    Command,
    CommandError,
    CycleStart,
    HeightOverride,
    JogZ,
    OhmicTest,
    OperatingMode,
    ProbeTest,
    Rearm,
    SelectMaterial,
    ThcEnable,
    ThcHold,
    ThcMode,
    VelocityReduction,
    VoltageAdjust,
    check_range,
)
from .controller.dialect import Dialect
from .controller.gcode import MAX_VOLTAGE_STEP_V
from .port import CommandResult, ControllerPort

__all__ = [
    "COMMAND_REQUESTS",
    "GCODE_REQUEST",
    "REQUESTS",
    "GcodeRequest",
    "Request",
    "RequestHandlers",
    "RequestSpec",
    "Transaction",
    "check_transaction",
    "describe_validation_error",
    "execute",
    "parse_host_motion",
    "parse_request",
    "serve_request",
]

# --------------------------------------------------------------------------- payloads

GCODE_REQUEST: Final = "gcode"
MAX_LINE_CHARS: Final = 256
MAX_TRANSACTION_CHARS: Final = 128
MAX_SAFE_INT: Final = 2**53  # what a JavaScript sender can hold exactly
MAX_DEADLINE_MS: Final = 3_600_000
MAX_COORDINATE_MM: Final = 100_000.0

Transaction = str | int


def check_transaction(value: object) -> Transaction | None:
    """A request's ``transaction`` as given, or a pydantic error a JavaScript sender can read."""
    if value is None:
        return None
    if isinstance(value, str) and len(value) <= MAX_TRANSACTION_CHARS:
        return value
    if isinstance(value, int) and not isinstance(value, bool) and abs(value) <= MAX_SAFE_INT:
        return value
    raise PydanticCustomError(
        "transaction",
        "must be a string of at most {chars} characters or an integer within +/-2^53",
        {"chars": MAX_TRANSACTION_CHARS},
    )


class _RequestBase(BaseModel):
    model_config = ConfigDict(strict=True, frozen=True)

    transaction: Transaction | None = None
    deadline_ms: int | None = Field(default=None, gt=0, le=MAX_DEADLINE_MS)

    @field_validator("transaction", mode="before")
    @classmethod
    def _transaction(cls, value: object) -> Transaction | None:
        return check_transaction(value)

    @property
    def deadline_s(self) -> float | None:
        return None if self.deadline_ms is None else self.deadline_ms / 1000.0


class GcodeRequest(_RequestBase):
    """``request/gcode``: one G-code line, with the sender's line number and XY position."""

    model_config = ConfigDict(strict=True, frozen=True, extra="forbid")

    line: str = Field(min_length=1, max_length=MAX_LINE_CHARS)
    line_number: int | None = Field(default=None, ge=0, le=2**31 - 1)
    x: float | None = Field(
        default=None, ge=-MAX_COORDINATE_MM, le=MAX_COORDINATE_MM, allow_inf_nan=False
    )
    y: float | None = Field(
        default=None, ge=-MAX_COORDINATE_MM, le=MAX_COORDINATE_MM, allow_inf_nan=False
    )
    # The program's dialect (dthc_bridge.controller.dialect); absent: the daemon's own.
    dialect: Literal["masso", "plasmac", "rosetta", "relay"] | None = None

    @field_validator("line")
    @classmethod
    def _one_printable_line(cls, value: str) -> str:
        if any((ord(c) < 0x20 and c != "\t") or ord(c) == 0x7F for c in value):
            raise PydanticCustomError(
                "control_character", "must be one line without control characters"
            )
        if not value.strip():
            raise PydanticCustomError("blank", "must not be blank")
        return value

    @model_validator(mode="after")
    def _xy_together(self) -> Self:
        if (self.x is None) != (self.y is None):
            raise PydanticCustomError("xy_pair", "x and y must be given together")
        return self

    @property
    def xy_mm(self) -> tuple[float, float] | None:
        if self.x is None or self.y is None:
            return None
        return (self.x, self.y)


class Request(_RequestBase):
    """``request/<name>``: ``transaction`` and ``deadline_ms``, the rest are the arguments."""

    model_config = ConfigDict(strict=True, frozen=True, extra="allow")
    __pydantic_extra__: dict[str, JsonValue] = Field(init=False)

    @property
    def args(self) -> dict[str, JsonValue]:
        return dict(self.__pydantic_extra__)


def describe_validation_error(exc: ValidationError) -> str:
    """One line naming each offending field: ``line: String should have at most 256 ...``."""
    parts: list[str] = []
    for error in exc.errors(include_url=False):
        where = ".".join(str(part) for part in error["loc"]) or "payload"
        parts.append(f"{where}: {error['msg']}")
    return "; ".join(parts)


# --------------------------------------------------------------------------- arguments

_ENVELOPE_KEYS = frozenset({"transaction", "deadline_ms"})


def _arg_number(name: str, value: object) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise CommandError(name, f"{value!r} is not a number")
    result = float(value)
    if not math.isfinite(result):
        raise CommandError(name, f"{value!r} is not a finite number")
    return result


def _voltage_step(sign: float) -> Callable[[str, Mapping[str, object]], Command]:
    def parse(name: str, args: Mapping[str, object]) -> Command:
        volts = _arg_number(f"{name} volts", args.get("volts", 1.0))
        if not 0 < volts <= MAX_VOLTAGE_STEP_V:
            raise CommandError(
                f"{name} volts", f"{volts:g} is out of range (0..{MAX_VOLTAGE_STEP_V:g}]"
            )
        return VoltageAdjust(sign * volts)

    return parse


def _cycle_start(_name: str, _args: Mapping[str, object]) -> Command:
    return CycleStart()


def _rearm(_name: str, _args: Mapping[str, object]) -> Command:
    return Rearm()


MAX_HEIGHT_STEP_MM = 1.0


def _height_override(name: str, args: Mapping[str, object]) -> Command:
    if args.get("reset") is True:
        if "mm" in args:
            raise CommandError(f"{name} mm", "give a step or reset, not both")
        return HeightOverride(0.0, reset=True)
    if "reset" in args:
        raise CommandError(f"{name} reset", f"{args['reset']!r} is not true")
    if "mm" not in args:
        raise CommandError(f"{name} mm", "required argument is missing (or reset: true)")
    step = _arg_number(f"{name} mm", args["mm"])
    tenths = round(step * 10.0)
    if abs(step * 10.0 - tenths) > 1e-6 or tenths == 0:
        raise CommandError(f"{name} mm", f"{step:g} is not a step of 0.1 mm")
    if abs(step) > MAX_HEIGHT_STEP_MM:
        raise CommandError(f"{name} mm", f"{step:g} is more than {MAX_HEIGHT_STEP_MM:g} mm")
    return HeightOverride(tenths / 10.0)


def _abort(_name: str, _args: Mapping[str, object]) -> Command:
    return Abort()


def _thc_hold(name: str, args: Mapping[str, object]) -> Command:
    on = args.get("on")
    if not isinstance(on, bool):
        raise CommandError(f"{name} on", f"{on!r} is not true or false")
    return ThcHold(on)


def _thc_switch(name: str, args: Mapping[str, object]) -> Command:
    """The operator's THC on/off (a panel's switch): M667 / M666 without a program line."""
    on = args.get("on")
    if not isinstance(on, bool):
        raise CommandError(f"{name} on", f"{on!r} is not true or false")
    return ThcEnable(on)


def _ohmic_test(_name: str, _args: Mapping[str, object]) -> Command:
    return OhmicTest()


def _probe_test(_name: str, _args: Mapping[str, object]) -> Command:
    return ProbeTest()


MAX_JOG_MM = 10.0
MAX_JOG_FEED_MM_MIN = 3000.0


def _jog_z(name: str, args: Mapping[str, object]) -> Command:
    if "mm" not in args:
        raise CommandError(f"{name} mm", "required argument is missing")
    mm = _arg_number(f"{name} mm", args["mm"])
    if mm == 0 or abs(mm) > MAX_JOG_MM:
        raise CommandError(f"{name} mm", f"{mm:g} is not a step of 0 < |mm| <= {MAX_JOG_MM:g}")
    feed = None
    if "feed_mm_min" in args:
        feed = check_range(
            f"{name} feed_mm_min", _arg_number(f"{name} feed_mm_min", args["feed_mm_min"]),
            1.0, MAX_JOG_FEED_MM_MIN,
        )  # fmt: skip
    return JogZ(mm, feed)


def _material_select(name: str, args: Mapping[str, object]) -> Command:
    """The panel's material selector: the next cut's material, as PlasmaC's M190 P<n>."""
    if "number" not in args:
        raise CommandError(f"{name} number", "required argument is missing")
    number = _arg_number(f"{name} number", args["number"])
    if number != int(number) or number < 0:
        raise CommandError(f"{name} number", f"{number:g} is not a material number (0, 1, ...)")
    return SelectMaterial(int(number), word=f"{name} number {int(number)}")


def _operating_mode(name: str, args: Mapping[str, object]) -> Command:
    if "mode" not in args:
        raise CommandError(f"{name} mode", "required argument is missing")
    mode = _arg_number(f"{name} mode", args["mode"])
    if mode not in (0, 1, 2):
        raise CommandError(f"{name} mode", f"{mode:g} must be 0, 1 or 2")
    return OperatingMode(ThcMode(int(mode)))


def _request_velocity_reduction(name: str, args: Mapping[str, object]) -> Command:
    if "percent" not in args:
        raise CommandError(f"{name} percent", "required argument is missing")
    percent = _arg_number(f"{name} percent", args["percent"])
    return VelocityReduction(
        check_range(f"{name} percent", percent, 0.0, 100.0), synchronized=False
    )


MAX_HOST_SPEED_MM_S = 2000.0  # 120 m/min: faster than any plasma table's rapids
_MOTION_KEYS = frozenset({"xy_speed_mm_s", "feed_mm_min", "state"})


def parse_host_motion(args: Mapping[str, object]) -> tuple[float, float | None, str | None]:
    """The ``motion`` request: (measured XY speed mm/s, programmed feed mm/min or None, the
    motion controller's state or None). The error names the argument, as for commands."""
    for key in args:
        if key not in _MOTION_KEYS and key not in _ENVELOPE_KEYS:
            raise CommandError(f"motion {key}", "unknown argument")
    if "xy_speed_mm_s" not in args:
        raise CommandError("motion xy_speed_mm_s", "required argument is missing")
    speed = check_range(
        "motion xy_speed_mm_s",
        _arg_number("motion xy_speed_mm_s", args["xy_speed_mm_s"]),
        0.0,
        MAX_HOST_SPEED_MM_S,
    )
    feed: float | None = None
    if args.get("feed_mm_min") is not None:
        feed = _arg_number("motion feed_mm_min", args["feed_mm_min"])
        if feed <= 0.0:
            raise CommandError("motion feed_mm_min", f"{feed:g} must be > 0")
    state = args.get("state")
    if state is not None and not isinstance(state, str):
        raise CommandError("motion state", f"{state!r} is not a string")
    return speed, feed, state


# --------------------------------------------------------------------------- the table


class RequestHandlers(Protocol):
    """What serves the requests: the controller service (:mod:`dthc_bridge.service`)."""

    async def execute_gcode(
        self,
        line: str,
        *,
        line_number: int | None,
        xy_mm: tuple[float, float] | None,
        dialect: Dialect | None = None,
    ) -> CommandResult: ...

    async def execute_command(self, command: Command) -> CommandResult:
        """One typed command (from a request's arguments) through the plasma controller."""
        ...

    def snapshot(self) -> dict[str, object]: ...

    def material_request(self, name: str, args: Mapping[str, object]) -> CommandResult:
        """``materials``, ``material_get``, ``material_set``, ``material_delete``."""
        ...

    def host_motion(
        self, speed_mm_s: float, feed_mm_min: float | None, state: str | None
    ) -> CommandResult:
        """The sender's measured XY speed (``motion``)."""
        ...

    async def reset_consumables(self) -> CommandResult: ...

    def start_program(self) -> CommandResult: ...

    def end_program(self) -> CommandResult: ...


Handler = Callable[[RequestHandlers, str, Mapping[str, object]], Awaitable[CommandResult]]
CommandParser = Callable[[str, Mapping[str, object]], Command]


@dataclass(frozen=True, slots=True)
class RequestSpec:
    """One request: its payload model, who may send it, and what serves it."""

    payload: type[GcodeRequest] | type[Request]
    # True: it can light the torch or move Z (directly, or by changing what the THC or the
    # sequence does next): only the sender's role may send it. False: the panel may too.
    sender_only: bool
    handler: Handler
    # A request that becomes one controller command: its arguments and its parser.
    arguments: frozenset[str] = frozenset()
    command: CommandParser | None = None


async def _run_gcode(
    target: ControllerPort | RequestHandlers, request: GcodeRequest
) -> CommandResult:
    return await target.execute_gcode(
        request.line,
        line_number=request.line_number,
        xy_mm=request.xy_mm,
        dialect=None if request.dialect is None else Dialect(request.dialect),
    )


async def _gcode(
    handlers: RequestHandlers, _name: str, args: Mapping[str, object]
) -> CommandResult:
    try:
        request = GcodeRequest.model_validate(dict(args))
    except ValidationError as exc:
        return CommandResult(False, error=describe_validation_error(exc))
    return await _run_gcode(handlers, request)


async def _command(
    handlers: RequestHandlers, name: str, args: Mapping[str, object]
) -> CommandResult:
    try:
        command = parse_request(name, args)
    except CommandError as exc:
        return CommandResult(False, error=str(exc))
    return await handlers.execute_command(command)


async def _status(
    handlers: RequestHandlers, _name: str, _args: Mapping[str, object]
) -> CommandResult:
    return CommandResult(True, handlers.snapshot())


async def _material(
    handlers: RequestHandlers, name: str, args: Mapping[str, object]
) -> CommandResult:
    return handlers.material_request(name, args)


async def _motion(
    handlers: RequestHandlers, _name: str, args: Mapping[str, object]
) -> CommandResult:
    try:
        speed, feed, state = parse_host_motion(args)
    except CommandError as exc:
        return CommandResult(False, error=str(exc))
    return handlers.host_motion(speed, feed, state)


async def _consumables_reset(
    handlers: RequestHandlers, name: str, args: Mapping[str, object]
) -> CommandResult:
    unknown = sorted(set(args) - _ENVELOPE_KEYS)
    if unknown:
        return CommandResult(False, error=f"{name} {unknown[0]}: unknown argument")
    return await handlers.reset_consumables()


async def _program_start(
    handlers: RequestHandlers, _name: str, _args: Mapping[str, object]
) -> CommandResult:
    return handlers.start_program()


async def _program_end(
    handlers: RequestHandlers, _name: str, _args: Mapping[str, object]
) -> CommandResult:
    return handlers.end_program()


def _commanding(sender_only: bool, arguments: frozenset[str], parser: CommandParser) -> RequestSpec:
    return RequestSpec(Request, sender_only, _command, arguments, parser)


_NONE: Final = frozenset[str]()

REQUESTS: Final[Mapping[str, RequestSpec]] = {
    GCODE_REQUEST: RequestSpec(GcodeRequest, True, _gcode),
    "cycle_start": _commanding(True, _NONE, _cycle_start),
    "rearm": _commanding(True, _NONE, _rearm),
    "torch_up": _commanding(True, frozenset({"volts"}), _voltage_step(+1.0)),
    "torch_down": _commanding(True, frozenset({"volts"}), _voltage_step(-1.0)),
    "height_override": _commanding(True, frozenset({"mm", "reset"}), _height_override),
    "thc": _commanding(True, frozenset({"on"}), _thc_switch),
    "thc_hold": _commanding(True, frozenset({"on"}), _thc_hold),
    "ohmic_test": _commanding(True, _NONE, _ohmic_test),  # energises the ohmic circuit
    "probe_test": _commanding(True, _NONE, _probe_test),
    "jog_z": _commanding(True, frozenset({"mm", "feed_mm_min"}), _jog_z),
    "operating_mode": _commanding(True, frozenset({"mode"}), _operating_mode),
    "velocity_reduction": _commanding(True, frozenset({"percent"}), _request_velocity_reduction),
    # The anti-dive speed: a forged 0 or a forged full speed moves Z.
    "motion": RequestSpec(Request, True, _motion),
    "program_start": RequestSpec(Request, True, _program_start),
    "program_end": RequestSpec(Request, True, _program_end),
    # A stop only ever puts the torch out and raises it to safe height (the fault path):
    # the panel's Stop must work whoever drives the table, as a stop button on the machine.
    "abort": _commanding(False, _NONE, _abort),
    "status": RequestSpec(Request, False, _status),
    "materials": RequestSpec(Request, False, _material),
    "material_get": RequestSpec(Request, False, _material),
    # The next cut's parameters, validated; the sender selects them.
    "material_set": RequestSpec(Request, False, _material),
    "material_delete": RequestSpec(Request, False, _material),
    # The panel's material selector: the next cut's parameters from the library, as an M190
    # in the program would choose them; validated, and a program's own M190 comes after it.
    "material_select": _commanding(False, frozenset({"number"}), _material_select),
    # The pierce count and arc-on time start again from zero.
    "consumables_reset": RequestSpec(Request, False, _consumables_reset),
}

COMMAND_REQUESTS: Final = frozenset(name for name, spec in REQUESTS.items() if spec.command)
"""The requests that become one controller command (:func:`parse_request`)."""


def parse_request(name: str, args: Mapping[str, object]) -> Command:
    """The command of one request (``<root>/request/<name>`` with JSON ``args``).

    Raises :class:`CommandError` for a name that is no command request, an unknown or
    missing argument, or a bad value; the error's word is ``"<name> <argument>"``.
    """
    spec = REQUESTS.get(name)
    if spec is None or spec.command is None:
        raise CommandError(name or "request", "unknown request")
    for key in args:
        if key not in spec.arguments and key not in _ENVELOPE_KEYS:
            raise CommandError(f"{name} {key}", "unknown argument")
    return spec.command(name, args)


async def serve_request(
    handlers: RequestHandlers, name: str, args: Mapping[str, object]
) -> CommandResult:
    """A named request served by its table entry's handler; an unknown name is refused."""
    spec = REQUESTS.get(name)
    if spec is None:
        return CommandResult(False, error=str(CommandError(name or "request", "unknown request")))
    return await spec.handler(handlers, name, args)


async def execute(
    controller: ControllerPort, name: str, request: GcodeRequest | Request
) -> CommandResult:
    """A decoded request, run by the controller (the gateway's, and the simulated program
    runs' in-process daemon: one mapping from request to controller call)."""
    if isinstance(request, GcodeRequest):
        return await _run_gcode(controller, request)
    return await controller.execute_request(name, request.args)
