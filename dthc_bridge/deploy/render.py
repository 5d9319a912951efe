"""The deployment templates in ``systemd/`` and how their ``@NAME@`` placeholders are filled.

Pure functions: validate the values, substitute them, refuse to leave a placeholder behind.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

__all__ = [
    "BOARD_SYMLINK",
    "CONFIG_TEMPLATE",
    "DEFAULT_GRBL_LISTEN",
    "DEFAULT_PID",
    "DEFAULT_VID",
    "PORT_UNIT_TEMPLATE",
    "RULES_TEMPLATE",
    "UNIT_TEMPLATE",
    "BoardIds",
    "DeployError",
    "example_config",
    "load_template",
    "render",
    "render_port_unit",
    "render_udev_rules",
    "render_unit",
    "validate_account_name",
]

UNIT_TEMPLATE = "dthc-bridge.service"
RULES_TEMPLATE = "99-dthc.rules"
CONFIG_TEMPLATE = "config.example.toml"
PORT_UNIT_TEMPLATE = "dthc-grbl-port.service"
DEFAULT_GRBL_LISTEN = "/run/dthc-grbl-port/grbl"
"""The grbl port's stable path for a sender (in the port unit's RuntimeDirectory)."""

DEFAULT_VID = "1209"
"""pid.codes' vendor id: the board's ids are placeholders until its firmware has real ones."""
DEFAULT_PID = "d7c0"
BOARD_SYMLINK = "dthc0"
"""The udev name of the board's serial port: ``/dev/dthc0``, as in the example config."""

BRIDGE_CHIPS: Mapping[tuple[str, str], str] = {
    ("0403", "6001"): "FTDI FT232R",
    ("0403", "6015"): "FTDI FT-X",
    ("1a86", "7523"): "WCH CH340",
    ("10c4", "ea60"): "Silicon Labs CP210x",
}
"""Generic USB-serial bridges: their ids alone do not identify a board."""

_PLACEHOLDER = re.compile(r"@([A-Z][A-Z_]*)@")
_HEX_ID = re.compile(r"(?:0x)?([0-9a-fA-F]{4})")
_ACCOUNT = re.compile(r"[a-z_][a-z0-9_-]{0,31}")
# Printable ASCII without what udev would read as quoting, glob or substitution.
_SERIAL = re.compile(r"[!#&'()+,\-./0-9:;<=>@A-Z^_`a-z{}~]{1,126}")
# A path systemd takes literally in ExecStart= (no specifiers, variables, quoting).
_UNIT_PATH = re.compile(r"/[A-Za-z0-9_./+-]*")
# The table's grbl and the port's listener, as grbl-port takes them: a device path, or
# socket://HOST:PORT / tcp://HOST:PORT (nothing systemd would reinterpret in ExecStart=).
_UNIT_ENDPOINT = re.compile(
    r"(?:/[A-Za-z0-9_./+-]*|(?:socket|tcp)://[A-Za-z0-9_.:\[\]-]+:[0-9]{1,5})"
)
_TOPIC_WORD = re.compile(r"[A-Za-z0-9_.-]+")
_BROKER_ARG = re.compile(r"[A-Za-z0-9_@:/.+\[\]-]+")


class DeployError(Exception):
    """An installation step cannot be done; the message says what and how to fix it."""


@dataclass(frozen=True)
class BoardIds:
    """The board's USB ids (4 lower-case hex digits each) and optional serial number."""

    vid: str = DEFAULT_VID
    pid: str = DEFAULT_PID
    serial: str | None = None

    @classmethod
    def parse(cls, vid: str, pid: str, serial: str | None = None) -> BoardIds:
        """Accept ``1209``, ``0x1209`` or ``D7C0``; DeployError naming the bad option."""
        ids = []
        for option, text in (("--vid", vid), ("--pid", pid)):
            match = _HEX_ID.fullmatch(text.strip())
            if match is None:
                raise DeployError(f"{option} {text!r}: expected 4 hex digits, e.g. 1209")
            ids.append(match.group(1).lower())
        if serial is not None and _SERIAL.fullmatch(serial) is None:
            raise DeployError(
                f"--serial {serial!r}: expected printable characters without spaces, "
                "quotes, backslashes or * ? [ ] | $ % (see `udevadm info` for the exact value)"
            )
        return cls(vid=ids[0], pid=ids[1], serial=serial)

    @property
    def bridge_chip(self) -> str | None:
        """The bridge chip's name when these are a generic USB-serial bridge's ids."""
        return BRIDGE_CHIPS.get((self.vid, self.pid))


def validate_account_name(name: str) -> str:
    """A system user/group name useradd accepts; DeployError otherwise."""
    if _ACCOUNT.fullmatch(name) is None:
        raise DeployError(f"--user {name!r}: expected a lower-case name such as dthc")
    return name


def load_template(name: str) -> str:
    """The text of one file of ``systemd/`` (shipped as ``dthc_bridge/deploy/templates``)."""
    template = resources.files("dthc_bridge.deploy") / "templates" / name
    try:
        return template.read_text(encoding="utf-8")
    except FileNotFoundError as exc:
        raise DeployError(
            f"template {name} not found: install dthc-bridge from a source checkout "
            "(pip install -e), which has the systemd/ directory"
        ) from exc


def render(template: str, values: Mapping[str, str]) -> str:
    """Replace every ``@NAME@`` with ``values[NAME]``; DeployError on a missing name."""
    missing = sorted({name for name in _PLACEHOLDER.findall(template) if name not in values})
    if missing:
        raise DeployError(f"template placeholders without a value: {', '.join(missing)}")
    return _PLACEHOLDER.sub(lambda match: values[match.group(1)], template)


def render_unit(*, bin_dir: Path, user: str, group: str) -> str:
    """The service unit for a daemon installed in ``bin_dir``, run as ``user``:``group``."""
    return render(load_template(UNIT_TEMPLATE), _service_values(bin_dir, user, group))


def _service_values(bin_dir: Path, user: str, group: str) -> dict[str, str]:
    """A unit's BIN_DIR, USER and GROUP, each checked."""
    text = str(bin_dir)
    if _UNIT_PATH.fullmatch(text) is None:
        raise DeployError(
            f"--bin-dir {text!r}: must be an absolute path of letters, digits and _ . / + - "
            "(systemd would interpret spaces, quotes, % and $ in ExecStart=)"
        )
    return {
        "BIN_DIR": text.rstrip("/") or "/",
        "USER": validate_account_name(user),
        "GROUP": validate_account_name(group),
    }


def render_port_unit(
    *,
    bin_dir: Path,
    user: str,
    group: str,
    grbl: str,
    listen: str = DEFAULT_GRBL_LISTEN,
    base_topic: str = "dthc",
    board_id: str = "table1",
    broker_args: tuple[str, ...] = (),
) -> str:
    """The grbl port's unit: ``dthc-bridge grbl-port`` in front of ``grbl`` (the table's
    grbl), listening for a sender on ``listen``, logged in with ``broker_args``."""
    for option, text in (("--grbl", grbl), ("--grbl-listen", listen)):
        if _UNIT_ENDPOINT.fullmatch(text) is None:
            raise DeployError(
                f"{option} {text!r}: expected a device path (/dev/ttyUSB0) or "
                "socket://HOST:PORT, without spaces, quotes, % or $"
            )
    for option, text in (("--base-topic", base_topic), ("--board-id", board_id)):
        if _TOPIC_WORD.fullmatch(text) is None:
            raise DeployError(f"{option} {text!r}: expected letters, digits, _ . -")
    for arg in broker_args:
        if _BROKER_ARG.fullmatch(arg) is None:
            raise DeployError(f"broker argument {arg!r}: systemd would reinterpret it")
    values = {
        **_service_values(bin_dir, user, group),
        "GRBL": grbl,
        "LISTEN": listen,
        "BASE_TOPIC": base_topic,
        "BOARD_ID": board_id,
        "BROKER_ARGS": " ".join(broker_args),
    }
    return render(load_template(PORT_UNIT_TEMPLATE), values)


def render_udev_rules(board: BoardIds, *, group: str) -> str:
    """The udev rules for ``board``; the serial, when known, narrows every board rule."""
    serial = board.serial
    values = {
        "VID": board.vid,
        "PID": board.pid,
        "TTY_SERIAL_MATCH": f', ATTRS{{serial}}=="{serial}"' if serial else "",
        "USB_SERIAL_MATCH": f', ATTR{{serial}}=="{serial}"' if serial else "",
        "SYMLINK": BOARD_SYMLINK,
        "GROUP": validate_account_name(group),
    }
    return render(load_template(RULES_TEMPLATE), values)


def example_config() -> str:
    """The example configuration, as installed to /etc/dthc-bridge/config.toml."""
    return load_template(CONFIG_TEMPLATE)
