"""The udev rules: /dev/dthc0 by ids and serial, ModemManager off, FTDI at 1 ms, pyusb access."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest

from dthc_bridge.deploy.render import (
    BoardIds,
    DeployError,
    render_udev_rules,
)

UDEVADM = shutil.which("udevadm")

# KEY, KEY{attr}, then an operator and a double-quoted value: what udev(7) reads.
_TOKEN = re.compile(
    r'(?P<key>[A-Z_]+)(?:\{(?P<attr>[A-Za-z0-9_]+)\})?(?P<op>==|!=|\+=|:=|=)"(?P<value>[^"]*)"'
)
_MATCH_KEYS = {"ACTION", "SUBSYSTEM", "DRIVER", "ATTR", "ATTRS", "ENV"}
_ASSIGN_KEYS = {"SYMLINK", "GROUP", "MODE", "ENV", "ATTR", "GOTO", "LABEL"}


def _rules(text: str) -> list[list[tuple[str, str | None, str, str]]]:
    """Each rule as (key, attr, op, value) tokens; AssertionError on anything udev rejects."""
    rules = []
    for line in text.splitlines():
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        tokens = []
        for part in line.split(", "):
            match = _TOKEN.fullmatch(part.strip())
            assert match is not None, f"not a udev token: {part!r} in {line!r}"
            key, attr, op, value = match.group("key", "attr", "op", "value")
            keys = _MATCH_KEYS if op in {"==", "!="} else _ASSIGN_KEYS
            assert key in keys, f"{key}{op} in {line!r}"
            tokens.append((key, attr, op, value))
        rules.append(tokens)
    return rules


def _rule_for(text: str, subsystem: str, vid: str) -> set[str]:
    """The tokens, as text, of the first rule on ``subsystem`` matching vendor ``vid``."""
    for rule in _rules(text):
        parts = {f"{k}{{{a}}}{op}{v}" if a else f"{k}{op}{v}" for k, a, op, v in rule}
        vendor = {f"ATTRS{{idVendor}}=={vid}", f"ATTR{{idVendor}}=={vid}"}
        if f"SUBSYSTEM=={subsystem}" in parts and parts & vendor:
            return parts
    raise AssertionError(f"no {subsystem} rule for {vid}")


def test_rules_parse_and_leave_no_placeholder() -> None:
    """Every line is a valid rule (or comment); the board's ids are filled in."""
    text = render_udev_rules(BoardIds(), group="dthc")
    assert "@" not in "".join(line for line in text.splitlines() if not line.startswith("#"))
    assert len(_rules(text)) >= 8
    assert 'LABEL="dthc_end"' in text


def test_board_port_gets_the_symlink_group_and_no_modemmanager() -> None:
    """Without a serial: the board's ids alone give /dev/dthc0, group dthc, MM ignore."""
    tty = _rule_for(render_udev_rules(BoardIds(), group="dthc"), "tty", "1209")
    assert {
        "ATTRS{idProduct}==d7c0",
        "SYMLINK+=dthc0",
        "GROUP=dthc",
        "MODE=0660",
        "ENV{ID_MM_DEVICE_IGNORE}=1",
    } <= tty
    assert not any("serial" in part for part in tty)


def test_serial_narrows_every_board_rule() -> None:
    """With --serial, the tty, the USB device and the FTDI latency rule match only it."""
    board = BoardIds.parse("0x0403", "6015", "DN05ABCD")
    text = render_udev_rules(board, group="thc")
    tty = _rule_for(text, "tty", "0403")
    assert {"ATTRS{serial}==DN05ABCD", "SYMLINK+=dthc0", "GROUP=thc"} <= tty
    usb = _rule_for(text, "usb", "0403")
    assert {"ATTR{serial}==DN05ABCD", "ENV{DEVTYPE}==usb_device", "GROUP=thc", "MODE=0660"} <= usb
    latency = _rule_for(text, "usb-serial", "0403")
    assert {"ATTRS{serial}==DN05ABCD", "ATTR{latency_timer}=1"} <= latency


def test_pyusb_boards_get_their_usb_device_node() -> None:
    """Vendor bulk boards: /dev/bus/usb/... in the service group, read-write."""
    usb = _rule_for(render_udev_rules(BoardIds(), group="dthc"), "usb", "1209")
    assert {"ENV{DEVTYPE}==usb_device", "ATTR{idProduct}==d7c0", "GROUP=dthc"} <= usb


@pytest.mark.parametrize(
    ("vid", "pids"), [("0403", "6001|6015"), ("1a86", "7523"), ("10c4", "ea60")]
)
def test_common_bridges_are_kept_from_modemmanager_only(vid: str, pids: str) -> None:
    """FTDI, CH340, CP210x ports: MM ignore, but their group stays dialout for other programs."""
    text = render_udev_rules(BoardIds(), group="dthc")
    rule = _rule_for(text, "tty", vid)
    assert {f"ATTRS{{idProduct}}=={pids}", "ENV{ID_MM_DEVICE_IGNORE}=1"} <= rule
    assert not any(part.startswith(("GROUP", "SYMLINK", "MODE")) for part in rule)


def test_ftdi_bridges_get_a_1_ms_latency_timer() -> None:
    """The FT232R/FT-X latency timer drops from 16 ms to 1 ms at plug-in."""
    text = render_udev_rules(BoardIds(), group="dthc")
    rule = _rule_for(text, "usb-serial", "0403")
    assert {"DRIVER==ftdi_sio", "ATTRS{idProduct}==6001|6015", "ATTR{latency_timer}=1"} <= rule


def test_board_ids_are_normalised_and_checked() -> None:
    """Hex ids in any usual spelling; a bad id or a serial udev would misread is refused."""
    assert BoardIds.parse("0x1209", "D7C0") == BoardIds("1209", "d7c0", None)
    assert BoardIds.parse("0403", "6001").bridge_chip == "FTDI FT232R"
    with pytest.raises(DeployError, match="--vid"):
        BoardIds.parse("12090", "d7c0")
    with pytest.raises(DeployError, match="--pid"):
        BoardIds.parse("1209", "xyz1")
    for serial in ['A"B', "A B", "A*", "A$B", ""]:
        with pytest.raises(DeployError, match="--serial"):
            BoardIds.parse("1209", "d7c0", serial)


@pytest.mark.skipif(UDEVADM is None, reason="udevadm not installed (Debian package: udev)")
def test_udevadm_verify_accepts_the_rules(tmp_path: Path) -> None:
    """`udevadm verify` (systemd 253 and later) finds nothing wrong."""
    assert UDEVADM is not None
    probe = subprocess.run([UDEVADM, "verify", "--help"], capture_output=True, check=False)
    if probe.returncode != 0:
        pytest.skip("this udevadm has no verify command (systemd < 253)")
    path = tmp_path / "99-dthc.rules"
    path.write_text(render_udev_rules(BoardIds.parse("0403", "6015", "DN05ABCD"), group="dthc"))
    proc = subprocess.run(
        [UDEVADM, "verify", "--resolve-names=never", str(path)],
        capture_output=True, text=True, check=False,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stdout + proc.stderr
