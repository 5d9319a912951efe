"""The seam between the MQTT gateway and the plasma controller.

The gateway knows nothing about G-code, the cut sequence or the board: it hands every
validated request to a :class:`ControllerPort` and publishes what comes back. The daemon's
controller service implements this protocol; the tests use a fake.
"""

from __future__ import annotations

from collections.abc import AsyncIterator, Mapping
from dataclasses import dataclass, field
from typing import Protocol

from .controller.dialect import Dialect
from .events import ControllerEvent

__all__ = ["CommandResult", "ControllerPort"]


@dataclass(frozen=True)
class CommandResult:
    """What a command did: ``ok`` with ``data``, or not ok with a human-readable ``error``."""

    ok: bool
    data: Mapping[str, object] = field(default_factory=dict)
    error: str = ""


class ControllerPort(Protocol):
    async def execute_gcode(
        self,
        line: str,
        *,
        line_number: int | None,
        xy_mm: tuple[float, float] | None,
        dialect: Dialect | None = None,
    ) -> CommandResult:
        """Run one G-code line; M3 returns when XY motion may start (seconds).

        ``dialect``: the program's (:mod:`dthc_bridge.controller.dialect`); None = the
        daemon's configured one.

        The gateway cancels the call when the request's deadline passes: a cancelled
        command must end safely (a cancelled M3 aborts the cut).
        """
        ...

    async def execute_request(self, name: str, args: Mapping[str, object]) -> CommandResult:
        """Run a named request (``status``, ``thc``, ...); unknown names give ok=False."""
        ...

    async def sender_lost(self, reason: str) -> None:
        """The sender's last will arrived: stop a cut safely."""
        ...

    def snapshot(self) -> dict[str, object]:
        """The retained state document (JSON-able)."""
        ...

    def materials(self) -> dict[str, object]:
        """The retained material library document (JSON-able)."""
        ...

    def link_state(self) -> tuple[str, str]:
        """Board link: ("online"|"offline"|"connecting"|"incompatible", reason)."""
        ...

    def diagnostics(self) -> dict[str, object]:
        """Link statistics etc., published periodically."""
        ...

    def telemetry(self) -> dict[str, object] | None:
        """The latest telemetry point, or None when there is none."""
        ...

    def subscribe_events(self) -> AsyncIterator[ControllerEvent]:
        """Typed events (:mod:`dthc_bridge.events`), published as their ``as_payload()``."""
        ...
