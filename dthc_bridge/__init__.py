"""dthc-bridge: the torch height control daemon.

Layers, each talking only to its neighbours: MQTT gateway -> plasma controller (cut
sequence, THC loop, safety) -> board client -> link -> transport. The wire format lives in
:mod:`firmware_protocol`; the simulated board in :mod:`mock_device`.
"""

from __future__ import annotations

__version__ = "0.1.0"
__all__ = ["__version__"]
