"""The systemd unit: systemd itself accepts it, and its sandbox scores 2.0 or better."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest

import dthc_bridge.deploy
from dthc_bridge.deploy.render import DeployError, render, render_unit

REPO_ROOT = Path(__file__).resolve().parents[2]
SYSTEMD_ANALYZE = shutil.which("systemd-analyze")
MAX_EXPOSURE = 2.0
SECURITY_OFFLINE_SINCE = 250  # first systemd release with `security --offline=`

needs_systemd_analyze = pytest.mark.skipif(
    SYSTEMD_ANALYZE is None,
    reason="systemd-analyze not installed (Debian/Ubuntu package: systemd)",
)


def _systemd_version() -> int:
    assert SYSTEMD_ANALYZE is not None
    first = subprocess.run(
        [SYSTEMD_ANALYZE, "--version"], capture_output=True, text=True, check=True
    ).stdout.split("\n", 1)[0]
    match = re.match(r"systemd (\d+)", first)
    return int(match.group(1)) if match else 0


@pytest.fixture
def unit_path(tmp_path: Path) -> Path:
    """The unit rendered into tmp, ExecStart pointing at a stub dthc-bridge executable."""
    bin_dir = tmp_path / "venv" / "bin"
    bin_dir.mkdir(parents=True)
    stub = bin_dir / "dthc-bridge"
    stub.write_text("#!/bin/sh\nexit 0\n")
    stub.chmod(0o755)
    path = tmp_path / "dthc-bridge.service"
    path.write_text(render_unit(bin_dir=bin_dir, user="dthc", group="dthc"))
    return path


def _settings(text: str) -> list[tuple[str, str, str]]:
    """(section, key, value) for every assignment, repeated keys kept in order."""
    section = ""
    found = []
    for raw in text.splitlines():
        line = raw.strip()
        if not line or line.startswith(("#", ";")):
            continue
        if line.startswith("["):
            section = line.strip("[]")
            continue
        key, _, value = line.partition("=")
        found.append((section, key, value))
    return found


def _values(text: str, key: str) -> list[str]:
    return [value for _, name, value in _settings(text) if name == key]


@needs_systemd_analyze
def test_systemd_analyze_verify_accepts_the_unit(unit_path: Path) -> None:
    """`systemd-analyze verify` exits 0 and has nothing to say about our unit."""
    assert SYSTEMD_ANALYZE is not None
    proc = subprocess.run(
        [SYSTEMD_ANALYZE, "verify", "--man=no", str(unit_path)],
        capture_output=True, text=True, timeout=60, check=False,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    complaints = [line for line in proc.stderr.splitlines() if "dthc-bridge" in line]
    assert complaints == []


@needs_systemd_analyze
def test_security_exposure_is_at_most_2(unit_path: Path) -> None:
    """`systemd-analyze security --offline=yes` rates the sandbox 2.0 or less (measured 1.5)."""
    assert SYSTEMD_ANALYZE is not None
    if _systemd_version() < SECURITY_OFFLINE_SINCE:
        pytest.skip(f"systemd-analyze older than {SECURITY_OFFLINE_SINCE} has no --offline")
    proc = subprocess.run(
        [SYSTEMD_ANALYZE, "security", "--offline=yes", "--no-pager", str(unit_path)],
        capture_output=True, text=True, timeout=60, check=False,
    )  # fmt: skip
    match = re.search(r"Overall exposure level for \S+: (\d+\.\d+)", proc.stdout)
    assert match is not None, proc.stdout + proc.stderr
    exposure = float(match.group(1))
    assert exposure <= MAX_EXPOSURE, proc.stdout


def test_unit_has_the_service_contract(unit_path: Path) -> None:
    """Readiness, watchdog, restart, user, directories and device confinement as documented."""
    text = unit_path.read_text()
    single = {key: value for _, key, value in _settings(text)}
    assert single["Type"] == "notify"
    assert single["NotifyAccess"] == "main"
    assert single["WatchdogSec"] == "10s"
    assert single["Restart"] == "on-failure"
    assert (single["User"], single["Group"]) == ("dthc", "dthc")
    assert single["ConfigurationDirectory"] == "dthc-bridge"
    assert single["StateDirectory"] == "dthc-bridge"
    assert single["ProtectSystem"] == "strict"
    assert single["DevicePolicy"] == "closed"
    assert single["CapabilityBoundingSet"] == ""
    assert single["ExecStart"] == (
        f"{unit_path.parent}/venv/bin/dthc-bridge run --config /etc/dthc-bridge/config.toml"
    )
    assert _values(text, "DeviceAllow") == [
        "char-ttyACM rw",
        "char-ttyUSB rw",
        "char-usb_device rw",
    ]
    assert "modprobe@cdc_acm.service" in " ".join(_values(text, "Wants"))
    assert "modprobe@cdc_acm.service" in " ".join(_values(text, "After"))
    # The daemon outlives an unplugged board, and device nodes stay visible.
    assert _values(text, "BindsTo") == []
    assert _values(text, "PrivateDevices") == []
    assert "@" not in single["ExecStart"]


def test_template_refuses_to_leave_a_placeholder() -> None:
    """A template value that is not supplied is an error, not a literal @NAME@ in /etc."""
    with pytest.raises(DeployError, match="BIN_DIR"):
        render("ExecStart=@BIN_DIR@/dthc-bridge", {})
    assert render("A=@X@ B=@X@", {"X": "1"}) == "A=1 B=1"


@pytest.mark.parametrize("bad", ["relative/bin", "/opt/my venv/bin", "/opt/%i/bin", "/o/$X"])
def test_unit_rejects_bin_dirs_systemd_would_reinterpret(bad: str) -> None:
    """Spaces, specifiers and variables in ExecStart= would change its meaning."""
    with pytest.raises(DeployError, match="--bin-dir"):
        render_unit(bin_dir=Path(bad), user="dthc", group="dthc")


def test_templates_are_the_systemd_directory() -> None:
    """The installer renders the very files in systemd/ (one source, no copies)."""
    templates = Path(dthc_bridge.deploy.__file__).parent / "templates"
    assert templates.resolve() == (REPO_ROOT / "systemd").resolve()
    assert (templates / "dthc-bridge.service").is_file()
