"""Exactly-once requests: a repeated transaction is answered, never executed again.

A sender whose response did not arrive (the broker restarted, its client reconnected)
sends the same request again with the same ``transaction``. Executing it twice could light
the torch twice, so the gateway keeps, per transaction (whatever the request's name):

- while the first copy executes: the repeats, answered with its result when it ends;
- after it ended: its result, for ``hold_s`` and at most ``size`` entries, so a repeat is
  answered from here.

The same transaction with a different payload, or under another request name, is a sender
bug and is refused (a ``gcode`` transaction reused for an ``abort`` must not run the abort
as if it were new). Requests without a transaction cannot be recognised, so they are
executed each time (documented for sender authors in the README).
"""

from __future__ import annotations

import hashlib
from collections import OrderedDict
from dataclasses import dataclass, field
from typing import Generic, TypeVar

from ..port import CommandResult
from .payloads import Transaction

__all__ = ["Seen", "TransactionCache"]

_W = TypeVar("_W")  # whatever the gateway needs to answer a waiting repeat


@dataclass
class _Entry(Generic[_W]):
    name: str  # the request the transaction was first used for
    digest: bytes
    result: CommandResult | None = None  # None while the first copy executes
    done_s: float = 0.0
    waiting: list[_W] = field(default_factory=list)


@dataclass(frozen=True)
class Seen:
    """What to do with a request: ``run`` it, or it is a repeat (answered or waiting)."""

    run: bool
    result: CommandResult | None = None  # a repeat of a request that already ended
    conflict: bool = False  # the transaction was used for a different request
    used_for: str | None = None  # with conflict: the name of the request it was used for


class TransactionCache(Generic[_W]):
    def __init__(self, size: int, hold_s: float) -> None:
        self.size = size
        self.hold_s = hold_s
        self._entries: OrderedDict[str, _Entry[_W]] = OrderedDict()

    @staticmethod
    def _key(transaction: Transaction) -> str:
        # 17 and "17" are one transaction to a sender that retries with JSON round trips.
        return str(transaction)

    def admit(
        self, name: str, transaction: Transaction, payload: bytes, waiter: _W, now_s: float
    ) -> Seen:
        """First sight: remember it and run it. A repeat: its result, or wait for it.
        The transaction used for another request (name or payload): a conflict."""
        self._expire(now_s)
        key = self._key(transaction)
        digest = hashlib.blake2b(payload, digest_size=16).digest()
        entry = self._entries.get(key)
        if entry is None:
            if self.size > 0:
                self._entries[key] = _Entry(name, digest)
            return Seen(run=True)
        if entry.name != name or entry.digest != digest:
            return Seen(run=False, conflict=True, used_for=entry.name)
        if entry.result is None:
            entry.waiting.append(waiter)
            return Seen(run=False)
        return Seen(run=False, result=entry.result)

    def finish(
        self, name: str, transaction: Transaction, result: CommandResult, now_s: float
    ) -> list[_W]:
        """The first copy ended: keep its result; the repeats that waited for it."""
        entry = self._entries.get(self._key(transaction))
        if entry is None or entry.name != name:
            return []
        entry.result, entry.done_s = result, now_s
        waiting, entry.waiting = entry.waiting, []
        self._expire(now_s)
        return waiting

    def forget(self, name: str, transaction: Transaction) -> list[_W]:
        """The first copy was not executed after all (refused busy): a repeat may run."""
        key = self._key(transaction)
        entry = self._entries.get(key)
        if entry is None or entry.name != name:
            return []
        del self._entries[key]
        return entry.waiting

    def _expire(self, now_s: float) -> None:
        entries = self._entries
        for key in list(entries):  # oldest first
            entry = entries[key]
            if entry.result is None:
                continue  # still running: its repeats wait on it
            if now_s - entry.done_s > self.hold_s or len(entries) > self.size:
                del entries[key]

    def __len__(self) -> int:
        return len(self._entries)
