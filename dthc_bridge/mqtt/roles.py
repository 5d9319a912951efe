"""Who may publish and read what on one table's topics: the broker's ACL, declared once.

MQTT carries no trustworthy identity inside a message, so who may light the torch is the
broker's decision: a user per role and an ACL. This table is that ACL's one source: the
installer writes mosquitto's ``acl_file`` from it (``dthc-bridge install-service
--broker-config``), ``systemd/mosquitto-acl.example`` is its rendering for the default
topics. Who may send which request is declared in the request table
(:data:`dthc_bridge.requests.REQUESTS`, ``sender_only``); :data:`REQUESTS` here is read from it.

- ``daemon``: reads the requests and the sender's will; alone writes the state topics.
- ``sender``: the one role that may send requests that light the torch or move Z.
- ``panel``: reads everything; sends the daemon only requests that cannot start the torch
  or move Z (status, the material library, a stop), and everything else to the running
  sender (``sender/request/<name>``), which owns the program and its guards.
- ``dashboard``: reads the daemon's published state, writes nothing.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

from ..requests import REQUESTS as REQUEST_TABLE

__all__ = ["PANEL_REQUESTS", "REQUESTS", "Grant", "Role", "grants", "render_acl"]


class Role(StrEnum):
    DAEMON = "daemon"
    SENDER = "sender"
    PANEL = "panel"
    DASHBOARD = "dashboard"


# Every request the daemon serves, and whether it can light the torch or move Z (directly,
# or by changing what the THC or the sequence does next): only the sender may send these.
# Declared with each request in the request table (dthc_bridge/requests.py), read here.
REQUESTS: dict[str, bool] = {name: spec.sender_only for name, spec in REQUEST_TABLE.items()}

PANEL_REQUESTS = frozenset(name for name, moves in REQUESTS.items() if not moves)
"""The daemon's requests the panel may send itself."""

# The topics under the board's root that the daemon alone publishes.
DAEMON_TOPICS = (
    "availability", "board", "state", "event", "telemetry", "diagnostics", "materials",
    "response/#", "reply/#",
)  # fmt: skip


@dataclass(frozen=True)
class Grant:
    """One ACL line: ``topic read|write|readwrite <root>/<leaf>``."""

    access: str  # "read", "write" or "readwrite"
    leaf: str  # under the board's root


def grants(role: Role) -> list[Grant]:
    """What ``role`` may do under one board's root, least privilege."""
    if role is Role.DAEMON:
        return [
            Grant("read", "request/#"),
            Grant("read", "sender/availability"),
            *(Grant("write", leaf) for leaf in DAEMON_TOPICS),
        ]
    if role is Role.SENDER:
        return [
            Grant("write", "request/#"),
            Grant("readwrite", "sender/availability"),
            Grant("readwrite", "sender/progress"),
            Grant("readwrite", "sender/path"),
            Grant("readwrite", "sender/response/#"),
            Grant("read", "#"),
        ]
    if role is Role.PANEL:
        return [
            *(Grant("write", f"request/{name}") for name in sorted(PANEL_REQUESTS)),
            Grant("write", "sender/request/#"),
            Grant("readwrite", "panel/availability"),
            Grant("read", "#"),
        ]
    return [
        Grant("read", leaf) for leaf in DAEMON_TOPICS if not leaf.startswith(("response", "reply"))
    ]


_EXPLAIN = {
    Role.DAEMON: "reads the requests and the sender's will; alone writes the table's state",
    Role.SENDER: "the one role whose requests can light the torch or move Z",
    Role.PANEL: "reads all; sends the daemon only status, materials and stop; "
    "everything else goes to the running sender",
    Role.DASHBOARD: "reads the daemon's state; writes nothing",
}


def render_acl(root: str, users: dict[Role, str]) -> str:
    """mosquitto's ``acl_file`` text for the board under ``root`` (``<base>/<board_id>``),
    one ``user`` section per role in ``users``. Anything not granted is denied."""
    lines = [
        f"# mosquitto ACL for dthc-bridge, table {root} (written by dthc-bridge install-service).",
        "# Anything not granted here is denied. The daemon's requests that light the torch or",
        "# move Z are the sender's alone; see dthc_bridge/mqtt/roles.py for the reasons.",
    ]
    for role, user in users.items():
        lines += ["", f"# {role}: {_EXPLAIN[role]}", f"user {user}"]
        lines += [f"topic {grant.access} {root}/{grant.leaf}" for grant in grants(role)]
    return "\n".join(lines) + "\n"
