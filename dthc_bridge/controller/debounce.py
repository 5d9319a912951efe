"""Input debouncing, pure: a raw input bit counts as changed once it has held its new level
for the debounce time, so a bouncing switch gives one edge, not a burst."""

from __future__ import annotations

from dataclasses import dataclass, field

__all__ = ["Edge", "InputDebouncer"]


@dataclass(frozen=True, slots=True)
class Edge:
    bit: int  # one InputMask bit
    active: bool


@dataclass
class InputDebouncer:
    """Per-bit debounce of an input snapshot. ``raw`` is the last snapshot, ``stable`` the
    debounced one; a bit's debounce time counts from its last raw change."""

    raw: int = 0
    stable: int = 0
    _changed_at: dict[int, float] = field(default_factory=dict)  # bit -> last raw change

    def feed(self, bits: int, now: float, hold_s: float) -> list[Edge]:
        """A raw snapshot at ``now``: the edges that have now held ``hold_s``."""
        changed = bits ^ self.raw
        self.raw = bits
        while changed:
            bit = changed & -changed
            changed &= changed - 1
            self._changed_at[bit] = now
        return self.poll(now, hold_s)

    def poll(self, now: float, hold_s: float) -> list[Edge]:
        """The edges whose raw level has held ``hold_s`` by ``now``, in the order the bits
        first changed; a bit that bounced back to its stable level gives none."""
        edges = []
        for bit, since in list(self._changed_at.items()):
            if now - since >= hold_s:
                del self._changed_at[bit]
                before = self.stable
                self.stable = (self.stable & ~bit) | (self.raw & bit)
                if before != self.stable:
                    edges.append(Edge(bit, bool(self.stable & bit)))
        return edges
