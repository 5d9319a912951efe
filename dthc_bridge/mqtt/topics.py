"""Topic names under ``<base>/<board_id>/`` and a small MQTT topic-filter matcher (pure)."""

from __future__ import annotations

import re
from dataclasses import dataclass

__all__ = [
    "REQUEST_NAME",
    "Topics",
    "filter_error",
    "topic_error",
]

REQUEST_NAME = re.compile(r"[A-Za-z0-9_-]{1,64}")

# Topics the gateway publishes (or listens on) under its root; used to refuse overlaps.
_OWN_LEAVES = (
    "state", "availability", "board", "event", "telemetry", "diagnostics", "materials",
)  # fmt: skip
_OWN_TREES = ("request", "response", "reply")


@dataclass(frozen=True)
class Topics:
    """Every topic of one board, under ``root`` = ``<base>/<board_id>``."""

    root: str

    @classmethod
    def for_board(cls, base_topic: str, board_id: str) -> Topics:
        return cls(f"{base_topic}/{board_id}")

    @property
    def request_filter(self) -> str:
        return f"{self.root}/request/#"

    @property
    def request_prefix(self) -> str:
        return f"{self.root}/request/"

    def response(self, name: str) -> str:
        return f"{self.root}/response/{name}"

    @property
    def state(self) -> str:
        return f"{self.root}/state"

    @property
    def availability(self) -> str:
        return f"{self.root}/availability"

    @property
    def board(self) -> str:
        return f"{self.root}/board"

    @property
    def event(self) -> str:
        return f"{self.root}/event"

    @property
    def telemetry(self) -> str:
        return f"{self.root}/telemetry"

    @property
    def diagnostics(self) -> str:
        return f"{self.root}/diagnostics"

    @property
    def materials(self) -> str:
        return f"{self.root}/materials"

    def request_name(self, topic: str) -> str | None:
        """The part after ``request/`` (maybe empty or invalid), or None for other topics."""
        if topic.startswith(self.request_prefix):
            return topic[len(self.request_prefix) :]
        return None

    def samples(self) -> list[str]:
        """One concrete topic per kind the gateway owns (for overlap checks)."""
        leaves = [f"{self.root}/{leaf}" for leaf in _OWN_LEAVES]
        return leaves + [f"{self.root}/{tree}/x" for tree in _OWN_TREES]

    def may_reply_to(self, topic: str) -> bool:
        """A v5 Response Topic is honoured unless it would write over the board's own topics."""
        if not topic.startswith(self.root + "/"):
            return True
        return topic.startswith((f"{self.root}/response/", f"{self.root}/reply/"))


def topic_error(topic: str) -> str | None:
    """Why ``topic`` cannot be published to, or None when it can."""
    if not topic:
        return "empty topic"
    if "+" in topic or "#" in topic:
        return "wildcards are not allowed in a topic name"
    if "\x00" in topic:
        return "NUL is not allowed in a topic"
    if len(topic.encode()) > 65535:
        return "topic longer than 65535 bytes"
    return None


def filter_error(topic_filter: str) -> str | None:
    """Why ``topic_filter`` is not a valid subscription filter, or None when it is."""
    if not topic_filter:
        return "empty topic filter"
    if "\x00" in topic_filter:
        return "NUL is not allowed in a topic filter"
    levels = topic_filter.split("/")
    for index, level in enumerate(levels):
        if "#" in level and (level != "#" or index != len(levels) - 1):
            return "'#' must be a whole level and the last one"
        if "+" in level and level != "+":
            return "'+' must be a whole level"
    return None
