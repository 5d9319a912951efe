"""MQTT gateway settings: one closed, typed model; the daemon embeds it as ``[mqtt]``."""

from __future__ import annotations

from typing import Self

import aiomqtt
from pydantic import ConfigDict, Field, field_validator, model_validator

from .broker import BrokerSettings, MqttTls
from .topics import Topics, filter_error

__all__ = ["BrokerSettings", "MqttSettings", "MqttTls"]

AUTO_WILL = "auto"  # the reference sender's availability under this board's topics
NO_WILL = "off"


class MqttSettings(BrokerSettings):
    """The daemon's ``[mqtt]`` section: the broker (shared with every client) and the
    gateway's own topics, rates and limits."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    keepalive_s: int = Field(default=30, ge=5, le=3600)
    operation_timeout_s: float = Field(
        default=10.0, gt=0.0, le=120.0, description="CONNACK, SUBACK and PUBACK wait"
    )
    base_topic: str = Field(
        default="dthc", min_length=1, max_length=128, pattern=r"^[^/+#\x00]+(/[^/+#\x00]+)*$"
    )
    board_id: str = Field(default="table1", pattern=r"^[A-Za-z0-9_-]+$", max_length=64)
    client_id: str | None = Field(
        default=None, min_length=1, max_length=128, description="default: dthc-bridge-<board_id>"
    )
    telemetry_hz: float = Field(default=10.0, ge=0.0, le=50.0, description="0 turns telemetry off")
    state_poll_s: float = Field(default=0.1, ge=0.01, le=5.0)
    diagnostics_period_s: float = Field(default=5.0, ge=0.1, le=3600.0)
    request_deadline_s: float = Field(default=30.0, gt=0.0, le=3600.0)
    max_payload_bytes: int = Field(default=4096, ge=256, le=1_048_576)
    max_concurrent_requests: int = Field(default=16, ge=1, le=256)
    max_pending_requests: int = Field(default=64, ge=1, le=4096, description="beyond this: 'busy'")
    sender_will_topic: str | None = Field(
        default=AUTO_WILL,
        min_length=1,
        max_length=512,
        description="filter where the sender's will arrives; 'auto': <base_topic>/<board_id>/"
        "sender/availability (the reference sender's), 'off': none",
    )
    reconnect_initial_s: float = Field(default=0.5, ge=0.01, le=60.0)
    reconnect_max_s: float = Field(default=30.0, ge=0.01, le=3600.0)
    outbox_hold_s: float = Field(
        default=60.0,
        gt=0.0,
        le=3600.0,
        description="how long responses and events wait for the broker",
    )
    outbox_max_messages: int = Field(default=1000, ge=10, le=100_000)
    transaction_cache_size: int = Field(
        default=1024, ge=0, le=100_000,
        description="answered requests kept by transaction, so a repeat is not run twice",
    )  # fmt: skip
    transaction_cache_s: float = Field(
        default=600.0, ge=0.0, le=86_400.0, description="how long an answer is kept for repeats"
    )

    @field_validator("sender_will_topic")
    @classmethod
    def _valid_filter(cls, value: str | None) -> str | None:
        if value in (AUTO_WILL, NO_WILL):
            return value
        if value is not None and (error := filter_error(value)) is not None:
            raise ValueError(error)
        return value

    @model_validator(mode="after")
    def _consistent(self) -> Self:
        if self.reconnect_max_s < self.reconnect_initial_s:
            raise ValueError("reconnect_max_s must be >= reconnect_initial_s")
        if self.max_pending_requests < self.max_concurrent_requests:
            raise ValueError("max_pending_requests must be >= max_concurrent_requests")
        will = self.sender_will_filter
        if will is not None:
            for own in self.topics.samples():
                if aiomqtt.Topic(own).matches(will):
                    raise ValueError(
                        f"sender_will_topic {self.sender_will_topic!r} overlaps the "
                        f"gateway's own topic {own!r}"
                    )
        return self

    @property
    def sender_will_filter(self) -> str | None:
        """Where a sender's will is honoured: by default the reference sender's own
        availability, so a sender killed mid-cut stops the cut (the torch does not burn on
        at a standstill); None with ``off``."""
        if self.sender_will_topic in (None, NO_WILL):
            return None
        if self.sender_will_topic == AUTO_WILL:
            return f"{self.topics.root}/sender/availability"
        return self.sender_will_topic

    @property
    def topics(self) -> Topics:
        return Topics.for_board(self.base_topic, self.board_id)

    @property
    def effective_client_id(self) -> str:
        return self.client_id or f"dthc-bridge-{self.board_id}"
