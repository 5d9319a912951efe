"""A publishing loop's guard against a lost cancellation (Python 3.11).

Python 3.11's asyncio.wait_for, inside aiomqtt's QoS 1 publish, returns normally when the
PUBACK lands as the task is cancelled (CPython gh-86296): a publishing loop then runs on,
and whoever cancelled it (a TaskGroup, which does not cancel twice; a caller awaiting the
cancelled task) waits for it forever. Each loop asks at the top of every turn.
"""

from __future__ import annotations

import asyncio

__all__ = ["honour_cancellation"]


def honour_cancellation() -> None:
    """Raise CancelledError if this task was asked to stop."""
    task = asyncio.current_task()
    if task is not None and task.cancelling():
        raise asyncio.CancelledError
