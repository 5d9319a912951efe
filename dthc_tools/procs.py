"""Children that die with their parent, even when the parent is SIGKILLed.

Every long-lived process a tool or a test starts (the mock board, the daemon, mosquitto)
is started with ``preexec_fn=die_with_parent()``::

    subprocess.Popen(cmd, preexec_fn=die_with_parent())
    await asyncio.create_subprocess_exec(*cmd, preexec_fn=die_with_parent())

On Linux the child asks the kernel, between fork and exec, for SIGKILL when its parent
dies (``prctl(PR_SET_PDEATHSIG)``); the setting survives exec, so it covers the
executables we start. Elsewhere ``die_with_parent()`` is None: Popen's default.

Hand-written on purpose: no well-kept library sets the parent-death signal (the ``prctl``,
``python-prctl`` and ``pyprctl`` packages on PyPI saw their last releases in 2010-2021),
and the call is a few lines of ctypes.

Caveats, from prctl(2):

* "Parent" is the *thread* that forked: the signal fires when that thread exits, even if
  the process lives on. Spawn from the main or the event-loop thread, never from
  ``asyncio.to_thread`` or another worker thread.
* The setting is cleared when the child execs a set-user-ID or set-group-ID binary (or one
  with file capabilities) or changes its effective or filesystem user or group ID: a
  mosquitto started as root drops to the ``mosquitto`` user unless its configuration names
  the current user (``user NAME``), and would then outlive its parent.
"""

from __future__ import annotations

import ctypes
import functools
import os
import signal
import sys
from collections.abc import Callable
from typing import Any

__all__ = ["PARENT_DEATH_SIGNAL", "die_with_parent"]

# SIGKILL, not SIGTERM: what a child does on a clean exit (the mock's truth file, the
# daemon's goodbye, mosquitto's persistence) is for the parent, which is gone; and SIGTERM
# can be ignored, or wait behind a handler on a busy event loop or a shutdown that waits
# for a broker dying too. SIGKILL cannot: the child is gone within milliseconds.
PARENT_DEATH_SIGNAL = signal.SIGKILL
_PR_SET_PDEATHSIG = 1  # <linux/prctl.h>


@functools.cache
def _prctl() -> Any:
    """libc's prctl, loaded in the parent: dlopen is not safe between fork and exec."""
    prctl = ctypes.CDLL(None, use_errno=True).prctl
    prctl.restype = ctypes.c_int
    return prctl


def die_with_parent() -> Callable[[], None] | None:
    """A ``preexec_fn`` that makes the child die (SIGKILL) when this process dies.

    Call it in the parent, once per spawn: it captures the parent's pid, so the child can
    tell whether the parent died between fork and prctl (the child then has a new parent
    and would never get the signal) and kill itself at once.
    """
    if sys.platform != "linux":
        return None
    prctl = _prctl()
    parent_pid = os.getpid()

    def preexec() -> None:
        # Between fork and exec: no imports, no locks; what fails here fails the Popen.
        if prctl(_PR_SET_PDEATHSIG, ctypes.c_ulong(PARENT_DEATH_SIGNAL)) != 0:
            errno = ctypes.get_errno()
            raise OSError(errno, f"prctl(PR_SET_PDEATHSIG): {os.strerror(errno)}")
        if os.getppid() != parent_pid:
            os.kill(os.getpid(), PARENT_DEATH_SIGNAL)

    return preexec
