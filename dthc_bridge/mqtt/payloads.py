"""Inbound request payloads decoded and the response document (zigbee2mqtt form).

The payload models (pydantic, strict) are declared with the requests, in
:mod:`dthc_bridge.requests`; each request name's entry there says which one decodes it.

Decoding never raises anything but :class:`RequestRefused`, whose message names the
offending field, so the gateway can answer every bad request with one clear error.
"""

from __future__ import annotations

import contextlib
import json
import math
from collections.abc import Mapping
from typing import Any

from pydantic import ValidationError
from pydantic_core import PydanticCustomError

from ..port import CommandResult
from ..requests import (
    GCODE_REQUEST,
    REQUESTS,
    GcodeRequest,
    Request,
    Transaction,
    check_transaction,
    describe_validation_error,
)

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


class RequestRefused(Exception):
    """A request that is refused before reaching the controller; nothing was changed."""

    def __init__(self, reason: str, transaction: Transaction | None = None) -> None:
        super().__init__(reason)
        self.reason = reason
        self.transaction = transaction


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
        transaction = check_transaction(document.get("transaction"))
    spec = REQUESTS.get(name)
    model = Request if spec is None else spec.payload
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
        return check_transaction(document.get("transaction"))
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
