"""Consumable life: the pierces and the arc-on time since the operator last changed the
nozzle and electrode (QtPlasmaC's and MASSO's counters), kept across restarts.

Counted by the daemon, which sees every pierce and every sample: a pierce when a cut's arc
transfers (the sequence's ``pierce_count``), arc-on time from the batches in which the
torch relay is on and the board reads Arc OK. Saved, crash-safe, when the arc goes out
(the end of each burn) and at shutdown, so a power cut loses at most the burn in progress;
a file that cannot be read is reported once and counting starts again from zero rather
than stopping the daemon.
"""

from __future__ import annotations

import json
import os
from dataclasses import asdict, dataclass, field
from datetime import UTC, datetime
from pathlib import Path

import structlog

from .materials.store import write_atomically

__all__ = ["ConsumableLog", "Consumables", "default_consumables_file"]

log = structlog.get_logger("dthc_bridge.consumables")

FILE_NAME = "consumables.json"


def _now_iso() -> str:
    return datetime.now(UTC).replace(microsecond=0).isoformat().replace("+00:00", "Z")


def default_consumables_file() -> Path:
    """Under systemd, the unit's ``StateDirectory`` (``$STATE_DIRECTORY``); by hand, the
    user's XDG state directory (``~/.local/state/dthc-bridge``)."""
    state = os.environ.get("STATE_DIRECTORY", "").split(":")[0]
    if state:
        return Path(state) / FILE_NAME
    xdg = os.environ.get("XDG_STATE_HOME") or str(Path.home() / ".local" / "state")
    return Path(xdg) / "dthc-bridge" / FILE_NAME


@dataclass
class Consumables:
    pierces: int = 0
    arc_on_s: float = 0.0
    since: str = field(default_factory=_now_iso)  # when they were last reset

    def as_dict(self) -> dict[str, object]:
        return {"pierces": self.pierces, "arc_on_s": round(self.arc_on_s, 1), "since": self.since}


class ConsumableLog:
    """The counters and the file they live in (None: counted, not kept)."""

    def __init__(self, path: Path | None) -> None:
        self.path = path
        self.counters = self._load()
        self._dirty = False

    def _load(self) -> Consumables:
        if self.path is None or not self.path.exists():
            return Consumables()
        try:
            data = json.loads(self.path.read_text(encoding="utf-8"))
            return Consumables(
                pierces=int(data["pierces"]), arc_on_s=float(data["arc_on_s"]),
                since=str(data["since"]),
            )  # fmt: skip
        except (OSError, ValueError, KeyError, TypeError) as exc:
            log.error("consumables_unreadable", path=str(self.path), error=str(exc))
            return Consumables()

    def pierced(self) -> None:
        self.counters.pierces += 1
        self._dirty = True

    def burned(self, seconds: float) -> None:
        self.counters.arc_on_s += seconds
        self._dirty = True

    def reset(self) -> None:
        self.counters = Consumables()
        self._dirty = True
        self.save()

    def save(self) -> None:
        """Write the counters if they changed (blocking: at shutdown, on a reset)."""
        pending = self.pending()
        if pending is not None:
            self.write(pending)

    def pending(self) -> bytes | None:
        """The file's new content if the counters changed since the last one taken (the
        caller writes it, off the event loop), else None."""
        if self.path is None or not self._dirty:
            return None
        self._dirty = False
        return (json.dumps(asdict(self.counters), sort_keys=True) + "\n").encode("utf-8")

    def write(self, content: bytes) -> None:
        """Put ``content`` in the file, crash-safe; an error is logged, never raised (a full
        disk must not stop a cut)."""
        if self.path is None:
            return
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            write_atomically(self.path, content, 0o644)
        except OSError as exc:
            log.error("consumables_not_saved", path=str(self.path), error=str(exc))
