"""Request payload validation, without a broker: clear errors, nothing else ever raised."""

from __future__ import annotations

import json

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dthc_bridge.mqtt import GcodeRequest, Request, RequestRefused, decode_request
from dthc_bridge.mqtt.payloads import encode_json, is_offline_payload, response_payload
from dthc_bridge.port import CommandResult

LIMIT = 4096


def refused(name: str, payload: bytes) -> RequestRefused:
    with pytest.raises(RequestRefused) as info:
        decode_request(name, payload, max_payload_bytes=LIMIT)
    return info.value


def test_a_full_gcode_request_decodes_with_xy_as_a_pair() -> None:
    """Every field of request/gcode arrives typed; x and y become xy_mm."""
    request = decode_request(
        "gcode",
        b'{"line":"G1 X5 Y6 F900","line_number":12,"x":5,"y":6.5,'
        b'"transaction":"a","deadline_ms":1500}',
        max_payload_bytes=LIMIT,
    )
    assert isinstance(request, GcodeRequest)
    assert request.line == "G1 X5 Y6 F900"
    assert request.line_number == 12
    assert request.xy_mm == (5.0, 6.5)
    assert request.transaction == "a"
    assert request.deadline_s == 1.5


def test_a_bare_json_string_is_a_gcode_line() -> None:
    """request/gcode accepts "M3" as shorthand for {"line": "M3"}."""
    request = decode_request("gcode", b'"M3"', max_payload_bytes=LIMIT)
    assert isinstance(request, GcodeRequest)
    assert request.line == "M3"
    assert request.xy_mm is None


def test_named_requests_keep_their_arguments_and_an_empty_object_is_no_arguments() -> None:
    """Everything but transaction and deadline_ms is an argument for the controller; ``{}``
    (not an empty payload, which is refused) is a request without arguments."""
    request = decode_request(
        "thc", b'{"on": true, "target_v": 118.5, "transaction": 3}', max_payload_bytes=LIMIT
    )
    assert isinstance(request, Request)
    assert request.args == {"on": True, "target_v": 118.5}
    assert request.transaction == 3
    empty = decode_request("status", b"{}", max_payload_bytes=LIMIT)
    assert isinstance(empty, Request)
    assert empty.args == {}


@pytest.mark.parametrize(
    ("payload", "message"),
    [
        (b'{"line": ""}', "line: String should have at least 1 character"),
        (b'{"line": "' + b"G" * 257 + b'"}', "line: String should have at most 256 characters"),
        (b'{"line": "M3\\nM5"}', "line: must be one line without control characters"),
        (b'{"line": "  "}', "line: must not be blank"),
        (b'{"line": 3}', "line: Input should be a valid string"),
        (b'{"line": "M3", "x": 1}', "x and y must be given together"),
        (b'{"line": "M3", "x": 1e9, "y": 0}', "x: Input should be less than or equal to 100000"),
        (b'{"line": "M3", "line_number": "4"}', "line_number: Input should be a valid integer"),
        (b'{"line": "M3", "deadline_ms": 0}', "deadline_ms: Input should be greater than 0"),
        (b'{"line": "M3", "transaction": [1]}', "transaction: must be a string"),
        (b'{"line": "M3", "transaction": true}', "transaction: must be a string"),
        (b'{"line": "M3", "speed": 1}', "speed: Extra inputs are not permitted"),
        (b'{"line": "M3", "x": NaN, "y": 1}', "invalid JSON: NaN is not valid JSON"),
        (b'{"line": ', "invalid JSON: Expecting value at line 1 column 10"),
        (b"[1, 2]", "payload must be a JSON object, not an array"),
        (b"", "empty payload"),
        (b"\xff\xfe", "payload is not UTF-8"),
        (b"[" * 5000, "invalid JSON: nested too deeply"),
    ],
)
def test_bad_gcode_payloads_are_refused_with_a_message_naming_the_field(
    payload: bytes, message: str
) -> None:
    """Each kind of bad input has its own clear message (docs/DESIGN.md invariant 4)."""
    if len(payload) > LIMIT:
        with pytest.raises(RequestRefused, match="too large"):
            decode_request("gcode", payload, max_payload_bytes=LIMIT)
        payload = payload[:LIMIT]
    assert message in refused("gcode", payload).reason


def test_a_refusal_keeps_a_valid_transaction_for_the_response() -> None:
    """The requester can match the error to its request even when validation failed."""
    error = refused("gcode", b'{"line": "", "transaction": "t7"}')
    assert error.transaction == "t7"


def test_the_response_document_follows_the_zigbee2mqtt_contract() -> None:
    """ok: status and data (+transaction); error: data {} and the error text."""
    ok = json.loads(response_payload(CommandResult(True, {"a": 1}), 5))
    assert ok == {"status": "ok", "data": {"a": 1}, "transaction": 5}
    error = json.loads(response_payload(CommandResult(False, error="arc lost"), None))
    assert error == {"status": "error", "data": {}, "error": "arc lost"}


def test_controller_data_that_json_cannot_hold_is_made_safe() -> None:
    """NaN becomes null, tuples lists, unknown objects strings: a response always goes out."""
    document = json.loads(encode_json({"v": float("nan"), "p": (1, 2), "o": object}))
    assert document["v"] is None
    assert document["p"] == [1, 2]
    assert isinstance(document["o"], str)


@pytest.mark.parametrize(
    ("payload", "offline"),
    [
        (b"offline", True),
        (b"OFFLINE\n", True),
        (b'"offline"', True),
        (b'{"state":"offline"}', True),
        (b'{"state":"online"}', False),
        (b"online", False),
        (b"", False),
        (b"{not json", False),
        (b'{"state": 0}', False),
    ],
)
def test_sender_will_payloads(payload: bytes, offline: bool) -> None:
    """Plain or JSON 'offline' is a lost sender; anything else is not."""
    assert is_offline_payload(payload) is offline


_json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=20),
    lambda inner: (
        st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner, max_size=4)
    ),
    max_leaves=12,
)
_near_requests = st.fixed_dictionaries(
    {},
    optional={
        "line": _json_values | st.text(max_size=300),
        "line_number": _json_values,
        "x": _json_values,
        "y": _json_values,
        "transaction": _json_values,
        "deadline_ms": _json_values,
        "extra": _json_values,
    },
)
_payloads = (
    st.binary(max_size=300)
    | _json_values.map(lambda v: json.dumps(v).encode())
    | _near_requests.map(lambda v: json.dumps(v).encode())
)


@settings(max_examples=1000, deadline=None)
@given(name=st.sampled_from(["gcode", "status", "thc"]), payload=_payloads)
def test_any_payload_either_decodes_to_a_valid_request_or_is_refused_cleanly(
    name: str, payload: bytes
) -> None:
    """Property: decode_request never raises anything but RequestRefused (with a reason),
    and what it accepts satisfies every documented bound."""
    try:
        request = decode_request(name, payload, max_payload_bytes=LIMIT)
    except RequestRefused as exc:
        reason = exc.reason
        assert reason, "a refusal always says why"
        return
    if isinstance(request, GcodeRequest):
        assert name == "gcode"
        assert 1 <= len(request.line) <= 256
        assert request.line.strip()
        assert "\n" not in request.line
        assert "\r" not in request.line
        assert (request.x is None) == (request.y is None)
    assert request.transaction is None or isinstance(request.transaction, str | int)
    assert not isinstance(request.transaction, bool)
    assert request.deadline_ms is None or request.deadline_ms > 0
