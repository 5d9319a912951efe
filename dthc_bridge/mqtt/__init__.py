"""The MQTT gateway: topics, payload validation, request/response, retained state.

Only this package imports aiomqtt. The daemon builds an :class:`MqttGateway` over its
controller service (a :class:`dthc_bridge.port.ControllerPort`) and runs it in its task group.
"""

from __future__ import annotations

from .gateway import GatewayStats, MqttGateway
from .payloads import GcodeRequest, Request, RequestRefused, decode_request, response_payload
from .settings import MqttSettings, MqttTls
from .topics import Topics

__all__ = [
    "GatewayStats",
    "GcodeRequest",
    "MqttGateway",
    "MqttSettings",
    "MqttTls",
    "Request",
    "RequestRefused",
    "Topics",
    "decode_request",
    "response_payload",
]
