"""Mock DTHC board: the firmware behaviour of PROTOCOL.md over a simulated plant.

Run it as a process (``dthc-mock --pty /tmp/dthc0``) or in-process in simulated time
(:class:`mock_device.sim.SimulatedBoard`).
"""

from __future__ import annotations

__all__: list[str] = []
