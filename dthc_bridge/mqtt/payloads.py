"""Inbound request payloads (pydantic, strict) and the response document (zigbee2mqtt form).

Decoding never raises anything but :class:`RequestRefused`, whose message names the
offending field, so the gateway can answer every bad request with one clear error.
"""

from __future__ import annotations

import contextlib
import json
import math
from collections.abc import Mapping
from typing import Any, Final, Literal, Self

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

from .port import CommandResult

__all__ = [
    "GCODE_REQUEST",
    "GcodeRequest",
    "Request",
    "RequestRefused",
    "Transaction",
    "decode_request",
    "describe_validation_error",
    "encode_json",
    "is_offline_payload",
    "peek_transaction",
    "response_payload",
]

GCODE_REQUEST: Final = "gcode"
MAX_LINE_CHARS: Final = 256
MAX_TRANSACTION_CHARS: Final = 128
MAX_SAFE_INT: Final = 2**53  # what a JavaScript sender can hold exactly
MAX_DEADLINE_MS: Final = 3_600_000
MAX_COORDINATE_MM: Final = 100_000.0

Transaction = str | int


class RequestRefused(Exception):
    """A request that is refused before reaching the controller; nothing was changed."""

    def __init__(self, reason: str, transaction: Transaction | None = None) -> None:
        super().__init__(reason)
        self.reason = reason
        self.transaction = transaction


def _check_transaction(value: object) -> Transaction | None:
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
        return _check_transaction(value)

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


def _refuse_constant(name: str) -> Any:
    raise ValueError(f"{name} is not valid JSON")


def _parse_json(payload: bytes) -> object:
    try:
        text = payload.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise RequestRefused(f"payload is not UTF-8 (byte {exc.start})") from None
    try:
        return json.loads(text, parse_constant=_refuse_constant)
    except json.JSONDecodeError as exc:
        raise RequestRefused(
            f"invalid JSON: {exc.msg} at line {exc.lineno} column {exc.colno}"
        ) from None
    except ValueError as exc:  # NaN / Infinity
        raise RequestRefused(f"invalid JSON: {exc}") from None
    except RecursionError:
        raise RequestRefused("invalid JSON: nested too deeply") from None


def decode_request(name: str, payload: bytes, *, max_payload_bytes: int) -> GcodeRequest | Request:
    """Validate one request payload; raise :class:`RequestRefused` with a clear reason."""
    if len(payload) > max_payload_bytes:
        raise RequestRefused(
            f"payload too large: {len(payload)} bytes, at most {max_payload_bytes}"
        )
    if not payload.strip():
        # Never "no arguments": an empty message is what a client sends by mistake (a
        # mosquitto_pub -n, a cleared retained request delivered live), not a request.
        if name == GCODE_REQUEST:
            raise RequestRefused("empty payload: expected a JSON object with 'line'")
        raise RequestRefused(
            "empty payload: expected a JSON object ({} for a request without arguments)"
        )
    document = _parse_json(payload)
    if name == GCODE_REQUEST and isinstance(document, str):
        document = {"line": document}  # a bare JSON string is the line
    if not isinstance(document, dict):
        raise RequestRefused(f"payload must be a JSON object, not {_json_type(document)}")
    transaction: Transaction | None = None
    with contextlib.suppress(PydanticCustomError):  # reported below, naming the field
        transaction = _check_transaction(document.get("transaction"))
    model: type[GcodeRequest | Request] = GcodeRequest if name == GCODE_REQUEST else Request
    try:
        return model.model_validate(document)
    except ValidationError as exc:
        raise RequestRefused(describe_validation_error(exc), transaction) from None
    except RecursionError:
        raise RequestRefused("payload nested too deeply", transaction) from None


def peek_transaction(payload: bytes, *, max_payload_bytes: int) -> Transaction | None:
    """The payload's valid ``transaction``, if any, for answering a request refused unread."""
    if len(payload) > max_payload_bytes or not payload.lstrip().startswith(b"{"):
        return None
    try:
        document = json.loads(payload)
        return _check_transaction(document.get("transaction"))
    except (ValueError, RecursionError, AttributeError, PydanticCustomError):
        return None


def _json_type(value: object) -> str:
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "a boolean"
    if isinstance(value, int | float):
        return "a number"
    if isinstance(value, str):
        return "a string"
    if isinstance(value, list):
        return "an array"
    return type(value).__name__


def _sanitize(value: object, depth: int = 0) -> object:
    """JSON-safe copy: mappings and sequences rebuilt, NaN/inf become null, rest as str."""
    if depth > 64:
        return str(value)
    if value is None or isinstance(value, bool | int | str):
        return value
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, Mapping):
        return {str(k): _sanitize(v, depth + 1) for k, v in value.items()}
    if isinstance(value, list | tuple | set | frozenset):
        return [_sanitize(v, depth + 1) for v in value]
    return str(value)


def encode_json(value: object) -> bytes:
    """Compact JSON bytes of anything the controller hands over; never raises."""
    try:
        return json.dumps(value, separators=(",", ":"), allow_nan=False).encode()
    except (TypeError, ValueError, RecursionError):
        return json.dumps(_sanitize(value), separators=(",", ":"), allow_nan=False).encode()


def response_payload(result: CommandResult, transaction: Transaction | None) -> bytes:
    """``{"status","data","error"?,"transaction"?}``: the zigbee2mqtt response contract."""
    document: dict[str, object] = {
        "status": "ok" if result.ok else "error",
        "data": dict(result.data),
    }
    if not result.ok:
        document["error"] = result.error or "failed"
    if transaction is not None:
        document["transaction"] = transaction
    return encode_json(document)


def is_offline_payload(payload: bytes) -> bool:
    """``offline`` (any case, bare or JSON string) or a JSON object with state offline."""
    text = payload.strip()
    if text.lower() in (b"offline", b'"offline"'):
        return True
    if not text.startswith(b"{") or len(text) > 4096:
        return False
    try:
        document = json.loads(text)
    except (ValueError, RecursionError):
        return False
    return (
        isinstance(document, dict)
        and isinstance(document.get("state"), str)
        and document["state"].lower() == "offline"
    )
