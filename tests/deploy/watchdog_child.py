"""A tiny daemon for the watchdog tests: READY=1, the watchdog loop, and a blocked loop.

Run as a script with NOTIFY_SOCKET and WATCHDOG_USEC set. It marks its phases on the
notify socket itself, so the test reads one timeline: ``READY=1``, pings for
``RUN_S``, ``STATUS=blocking``, a ``time.sleep(BLOCK_S)`` on the event loop,
``STATUS=unblocked``, pings for ``RUN_S``, ``STOPPING=1``.
"""

from __future__ import annotations

import asyncio
import sys
import time

from dthc_bridge.deploy.sdnotify import SdNotifier

RUN_S = 0.35
BLOCK_S = 0.5


async def main() -> int:
    with SdNotifier.from_env() as notifier:
        if notifier.watchdog_period_s() is None:
            return 2
        async with asyncio.TaskGroup() as tasks:
            watchdog = tasks.create_task(notifier.watchdog_loop(), name="sd-watchdog")
            notifier.ready()
            await asyncio.sleep(RUN_S)
            notifier.status("blocking")
            time.sleep(BLOCK_S)  # noqa: ASYNC251 - the point: the event loop is blocked
            notifier.status("unblocked")
            await asyncio.sleep(RUN_S)
            notifier.stopping()
            watchdog.cancel()
    return 0


if __name__ == "__main__":
    sys.exit(asyncio.run(main()))
