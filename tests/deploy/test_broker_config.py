"""install-service --broker-config: mosquitto's conf, password file and ACL for one table,
each role's password made once and kept, the daemon's config logging in with its own."""

from __future__ import annotations

import argparse
import base64
import io
import re
import subprocess
from pathlib import Path

import pytest

from dthc_bridge.config import load_config
from dthc_bridge.deploy.actions import Context
from dthc_bridge.deploy.broker import (
    BROKER_USERS,
    SECRETS_DIR,
    BrokerOptions,
    BrokerTls,
    Listener,
    broker_steps,
    example_files,
    hash_password,
    password_path,
    render_broker_conf,
    validated_topics,
    verify_password,
    write_broker_files,
)
from dthc_bridge.deploy.install import (
    CONFIG_PATH,
    HostState,
    add_install_arguments,
    run_install,
)
from dthc_bridge.deploy.render import DeployError
from dthc_bridge.mqtt.roles import Role, render_acl

from .conftest import file_mode, install_staged, staged

CONF = "/etc/mosquitto/conf.d/dthc-bridge.conf"
PASSWD = "/etc/mosquitto/conf.d/dthc-bridge.passwd"  # noqa: S105 - a path
ACL = "/etc/mosquitto/conf.d/dthc-bridge.acl"
MOSQUITTO_PASSWD = "/usr/bin/mosquitto_passwd"  # noqa: S105 - a path

HOST = HostState(
    user_exists=True,
    group_exists=True,
    serial_group_exists=True,
    user_in_serial_group=True,
    systemd_booted=True,
    has_udevadm=True,
    broker_group_exists=True,
    broker_installed=True,
)


def _install(
    root: Path, bin_dir: Path, host: HostState = HOST, **changes: object
) -> tuple[int, str]:
    changes.setdefault("broker", BrokerOptions())
    return install_staged(root, bin_dir, host, **changes)


def _snapshot(root: Path) -> dict[Path, tuple[bytes, int]]:
    return {p: (p.read_bytes(), file_mode(p)) for p in root.rglob("*") if p.is_file()}


def test_staged_broker_files_and_their_modes(root: Path, bin_dir: Path) -> None:
    """The conf, password file, ACL and one password per role land under the root: the
    broker's two files 0640 (group mosquitto on a live install), the daemon's password 0640
    (group dthc), the others' 0600; the conf names the files by their system paths."""
    code, output = _install(root, bin_dir)
    assert code == 0, output
    conf = staged(root, CONF).read_text()
    for line in (
        "per_listener_settings false",
        "allow_anonymous false",
        f"password_file {PASSWD}",
        f"acl_file {ACL}",
        "listener 1883 127.0.0.1",
    ):
        assert line in conf.splitlines()
    assert "cafile" not in conf
    assert file_mode(staged(root, CONF)) == 0o644
    assert file_mode(staged(root, PASSWD)) == 0o640
    assert file_mode(staged(root, ACL)) == 0o640
    assert file_mode(staged(root, SECRETS_DIR)) == 0o750
    assert file_mode(staged(root, password_path(Role.DAEMON))) == 0o640
    for role in (Role.SENDER, Role.PANEL, Role.DASHBOARD):
        assert file_mode(staged(root, password_path(role))) == 0o600
    passwords = {role: staged(root, password_path(role)).read_text().strip() for role in Role}
    assert len(set(passwords.values())) == 4
    for password in passwords.values():
        assert len(base64.urlsafe_b64decode(password + "==")) >= 16  # >= 128 random bits
    entries = dict(line.split(":", 1) for line in staged(root, PASSWD).read_text().splitlines())
    assert list(entries) == ["dthc-daemon", "dthc-sender", "dthc-panel", "dthc-dashboard"]
    for role, user in BROKER_USERS.items():
        assert re.fullmatch(r"\$7\$101\$[A-Za-z0-9+/]{16}\$[A-Za-z0-9+/]{86}==", entries[user])
        assert verify_password(passwords[role], entries[user])
        assert not verify_password(passwords[role] + "x", entries[user])
    assert "restart mosquitto.service (staging root)" in output
    # No secret is ever printed.
    assert not any(password in output for password in passwords.values())


def test_without_mosquitto_group_the_broker_files_are_root_only(root: Path, bin_dir: Path) -> None:
    """No mosquitto group to give them to: 0600 and a note saying what to do."""
    host = HostState(**{**HOST.__dict__, "broker_group_exists": False})
    code, output = _install(root, bin_dir, host=host)
    assert code == 0, output
    assert file_mode(staged(root, PASSWD)) == 0o600
    assert file_mode(staged(root, ACL)) == 0o600
    assert "no mosquitto group" in output


def test_acl_file_is_render_acl(root: Path, bin_dir: Path) -> None:
    """The ACL written is roles.render_acl for the board's root and the four users."""
    assert _install(root, bin_dir)[0] == 0
    assert staged(root, ACL).read_text() == render_acl("dthc/table1", dict(BROKER_USERS))


def test_second_install_changes_no_file_and_keeps_the_passwords(root: Path, bin_dir: Path) -> None:
    """Re-running with the same options rewrites nothing (the password file's salts too)
    and does not reload mosquitto."""
    assert _install(root, bin_dir)[0] == 0
    before = _snapshot(root)
    code, output = _install(root, bin_dir)
    assert code == 0, output
    assert _snapshot(root) == before
    assert "write" not in output
    assert "systemctl reload mosquitto.service (nothing changed)" in output


def test_a_kept_password_keeps_its_hash_when_the_listener_changes(
    root: Path, bin_dir: Path
) -> None:
    """A new listener rewrites the conf only; an added role password file is reused."""
    assert _install(root, bin_dir)[0] == 0
    passwd = staged(root, PASSWD).read_text()
    sender = staged(root, password_path(Role.SENDER))
    sender.write_text("chosen-by-the-owner\n")
    code, output = _install(
        root, bin_dir, broker=BrokerOptions(listen=Listener(1884, "192.168.1.5"))
    )
    assert code == 0, output
    assert "listener 1884 192.168.1.5" in staged(root, CONF).read_text()
    assert f"write            {CONF}" in output
    new = dict(line.split(":", 1) for line in staged(root, PASSWD).read_text().splitlines())
    old = dict(line.split(":", 1) for line in passwd.splitlines())
    assert new["dthc-daemon"] == old["dthc-daemon"]
    assert new["dthc-sender"] != old["dthc-sender"]
    assert verify_password("chosen-by-the-owner", new["dthc-sender"])
    assert sender.read_text() == "chosen-by-the-owner\n"


def test_an_empty_password_file_is_refused(root: Path, bin_dir: Path) -> None:
    """An empty role password is no password: say which file, change nothing."""
    empty = staged(root, password_path(Role.PANEL))
    empty.parent.mkdir(parents=True)
    empty.write_text("\n")
    code, output = _install(root, bin_dir)
    assert code == 1
    assert "panel.password is empty" in output
    assert not staged(root, CONF).exists()


def test_dry_run_prints_the_broker_files_and_writes_nothing(root: Path, bin_dir: Path) -> None:
    """--dry-run names every broker file and the restart, and the root stays empty."""
    code, output = _install(root, bin_dir, dry_run=True)
    assert code == 0, output
    for path in (CONF, PASSWD, ACL, *(password_path(role) for role in Role)):
        assert f"would write      {path}" in output
    assert list(root.iterdir()) == []


def test_live_commands_restart_then_reload_then_nothing(root: Path, bin_dir: Path) -> None:
    """mosquitto reads listeners at start only: a new conf restarts it; a changed password
    file or ACL alone reloads it (SIGHUP); nothing changed, no command."""

    def run() -> list[tuple[str, ...]]:
        ran: list[tuple[str, ...]] = []
        ctx = Context(
            root=root, live=True, dry_run=False, out=io.StringIO(),
            runner=lambda argv: ran.append(tuple(argv)), systemd_booted=True,
        )  # fmt: skip
        for step in broker_steps(
            BrokerOptions(), root=root, topics=validated_topics("dthc", "table1"),
            service_group="root", broker_group_exists=False, broker_installed=True,
        ):  # fmt: skip
            step.apply(ctx)
        return ran

    assert run() == [("systemctl", "restart", "mosquitto.service")]
    assert run() == []
    staged(root, ACL).write_text("stale\n")
    assert run() == [("systemctl", "reload", "mosquitto.service")]


def test_new_config_logs_the_daemon_in(root: Path, bin_dir: Path) -> None:
    """A config written with --broker-config has the daemon's user and password file, and
    the daemon's own model loads it."""
    code, output = _install(root, bin_dir, board_id="plasma2", base_topic="shop")
    assert code == 0, output
    config = load_config(staged(root, CONFIG_PATH))
    assert config.mqtt.username == "dthc-daemon"
    assert config.mqtt.password_file == Path("/etc/dthc-bridge/broker/daemon.password")
    assert (config.mqtt.host, config.mqtt.port) == ("localhost", 1883)
    assert (config.mqtt.base_topic, config.mqtt.board_id) == ("shop", "plasma2")
    assert config.mqtt.tls is None
    assert "topic write shop/plasma2/request/#" in staged(root, ACL).read_text()


def test_tls_only_broker_config(root: Path, bin_dir: Path) -> None:
    """--broker-listen none: the conf has only the TLS listener, and the daemon's new
    config reaches it on its port with the CA."""
    tls = BrokerTls(
        cert_file=Path("/etc/ssl/dthc/broker.crt"),
        key_file=Path("/etc/ssl/dthc/broker.key"),
        ca_file=Path("/etc/ssl/dthc/ca.crt"),
        require_client_cert=True,
    )
    code, output = _install(root, bin_dir, broker=BrokerOptions(listen=None, tls=tls))
    assert code == 0, output
    conf = staged(root, CONF).read_text().splitlines()
    assert [line for line in conf if line.startswith("listener")] == ["listener 8883"]
    for line in (
        "cafile /etc/ssl/dthc/ca.crt",
        "certfile /etc/ssl/dthc/broker.crt",
        "keyfile /etc/ssl/dthc/broker.key",
        "require_certificate true",
    ):
        assert line in conf
    config = load_config(staged(root, CONFIG_PATH))
    assert config.mqtt.port == 8883
    assert config.mqtt.tls is not None
    assert config.mqtt.tls.ca_file == Path("/etc/ssl/dthc/ca.crt")
    assert "--broker mqtts://THIS-HOST:8883" in output


def test_existing_config_gets_a_note_with_the_lines_to_add(root: Path, bin_dir: Path) -> None:
    """A kept configuration is not touched; the installer says exactly what to set, and the
    ACL follows its board_id."""
    config = staged(root, CONFIG_PATH)
    config.parent.mkdir(parents=True)
    config.write_text('[mqtt]\nboard_id = "table7"\n')
    code, output = _install(root, bin_dir)
    assert code == 0, output
    assert config.read_text() == '[mqtt]\nboard_id = "table7"\n'
    assert (
        'set in its [mqtt] section: username = "dthc-daemon", '
        'password_file = "/etc/dthc-bridge/broker/daemon.password"'
    ) in output
    assert "topic read dthc/table7/request/#" in staged(root, ACL).read_text()
    config.write_text(
        '[mqtt]\nboard_id = "table7"\nusername = "dthc-daemon"\n'
        'password_file = "/etc/dthc-bridge/broker/daemon.password"\n'
    )
    assert "set in its [mqtt] section" not in _install(root, bin_dir)[1]
    # An option that disagrees with the daemon's own topics is refused.
    code, output = _install(root, bin_dir, board_id="table8")
    assert code == 1
    assert "board_id = 'table7'" in output


def test_command_line_broker_options(root: Path, bin_dir: Path, tmp_path: Path) -> None:
    """The flags the CLI takes, and the ones that cannot go together."""
    parser = argparse.ArgumentParser()
    add_install_arguments(parser)
    base = ["--root", str(root), "--bin-dir", str(bin_dir), "--no-start"]
    args = parser.parse_args(
        [*base, "--broker-config", "/etc/mosquitto/conf.d", "--board-id", "t2",
         "--broker-listen", "[::1]:1884", "--broker-tls-cert", "/c.crt", "--broker-tls-key",
         "/c.key", "--broker-tls-ca", "/ca.crt", "--broker-tls-listen", "10.0.0.5:8884"]
    )  # fmt: skip
    assert run_install(args) == 0
    conf = staged(root, CONF).read_text()
    assert "listener 1884 ::1" in conf
    assert "listener 8884 10.0.0.5" in conf
    assert "require_certificate" not in conf
    for wrong in (
        ["--broker-tls-cert", "/c.crt"],  # without --broker-config
        ["--broker-config", "/etc/mosquitto/conf.d", "--broker-tls-cert", "/c.crt"],
        ["--broker-config", "/etc/mosquitto/conf.d", "--broker-listen", "none"],
        ["--broker-config", "/etc/mosquitto/conf.d", "--broker-listen", "localhost"],
        ["--broker-config", "relative/dir"],
    ):
        assert run_install(parser.parse_args([*base, *wrong])) == 2, wrong


def test_listener_parsing() -> None:
    """HOST:PORT, [IPV6]:PORT, :PORT and PORT; anything else names the option."""
    assert Listener.parse("127.0.0.1:1883", "-x") == Listener(1883, "127.0.0.1")
    assert Listener.parse("[::]:8883", "-x") == Listener(8883, "::")
    assert Listener.parse(":8883", "-x") == Listener(8883)
    assert Listener.parse("8883", "-x").conf_line() == "listener 8883"
    for bad in ("host", "host:0", "host:65536", "a b:1883"):
        with pytest.raises(DeployError, match="-x"):
            Listener.parse(bad, "-x")


def test_bad_topics_are_refused(root: Path, bin_dir: Path) -> None:
    """A board id the daemon would refuse is refused here too, naming the option."""
    code, output = _install(root, bin_dir, board_id="table/1")
    assert code == 1
    assert "--board-id 'table/1'" in output


@pytest.mark.skipif(not Path(MOSQUITTO_PASSWD).exists(), reason="mosquitto_passwd not installed")
def test_hash_format_matches_mosquitto_passwd(tmp_path: Path) -> None:
    """mosquitto_passwd's own line and ours agree: same fields, same lengths, and each
    verifies with the other's reading (the real hash checked by our verify)."""
    made = tmp_path / "passwd"
    subprocess.run(
        [MOSQUITTO_PASSWD, "-c", "-b", str(made), "user", "secret"], check=True,
        capture_output=True,
    )  # fmt: skip
    theirs = made.read_text().strip().split(":", 1)[1]
    ours = hash_password("secret")
    assert verify_password("secret", theirs)
    assert not verify_password("secreT", theirs)
    pattern = r"\$7\$(\d+)\$([A-Za-z0-9+/=]+)\$([A-Za-z0-9+/=]+)"
    theirs_m, ours_m = re.fullmatch(pattern, theirs), re.fullmatch(pattern, ours)
    assert theirs_m is not None
    assert ours_m is not None
    assert [len(g) for g in theirs_m.groups()] == [len(g) for g in ours_m.groups()]
    assert theirs_m.group(1) == ours_m.group(1)
    # The same salt gives mosquitto_passwd's own bytes.
    salt = base64.b64decode(theirs_m.group(2))
    assert hash_password("secret", salt=salt) == theirs


def test_write_broker_files_for_an_end_to_end_test(tmp_path: Path) -> None:
    """The staging helper writes what the installer writes and returns the paths; its
    conf_under_root() points mosquitto at the staged password file and ACL."""
    files = write_broker_files(tmp_path, BrokerOptions(listen=Listener(1999, "127.0.0.1")))
    assert files.conf == tmp_path / CONF.lstrip("/")
    assert files.acl.read_text() == render_acl("dthc/table1", dict(BROKER_USERS))
    assert files.password(Role.SENDER) == files.passwords[Role.SENDER].read_text().strip()
    conf_text = files.conf_under_root()
    assert f"password_file {files.passwd}" in conf_text
    assert f"acl_file {files.acl}" in conf_text
    assert conf_text.replace(str(tmp_path), "") == files.conf.read_text()
    assert render_broker_conf(files.options, "dthc/table1") == files.conf.read_text()
    again = write_broker_files(tmp_path, files.options)
    assert again.password(Role.SENDER) == files.password(Role.SENDER)


def test_systemd_examples_are_what_the_installer_writes() -> None:
    """systemd/mosquitto-acl.example is render_acl for the default topics and users, and
    systemd/mosquitto-dthc.conf.example the conf for the default listener plus TLS."""
    systemd = Path(__file__).resolve().parents[2] / "systemd"
    for name, text in example_files().items():
        assert (systemd / name).read_text() == text, (
            f"systemd/{name} differs from what the installer writes; regenerate it: "
            ".venv/bin/python -c 'from pathlib import Path; from dthc_bridge.deploy.broker "
            'import example_files; [Path("systemd", n).write_text(t) for n, t in '
            "example_files().items()]'"
        )
    assert example_files()["mosquitto-acl.example"] == render_acl(
        "dthc/table1",
        {Role.DAEMON: "dthc-daemon", Role.SENDER: "dthc-sender", Role.PANEL: "dthc-panel",
         Role.DASHBOARD: "dthc-dashboard"},
    )  # fmt: skip


def test_a_first_install_beside_mosquitto_locks_the_broker_by_default(
    root: Path, bin_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Safety invariant 8, a default install is the secure one: no broker flag, Debian's
    mosquitto present, no configuration yet: the broker files are written and the new
    configuration logs the daemon in. A re-install keeps what it has and says so; with
    --no-broker-config nothing is written or said."""
    parser = argparse.ArgumentParser()
    add_install_arguments(parser)
    base = ["--root", str(root), "--bin-dir", str(bin_dir), "--no-start"]
    staged(root, "/etc/mosquitto/conf.d").mkdir(parents=True)
    assert run_install(parser.parse_args(base)) == 0
    assert "allow_anonymous false" in staged(root, CONF).read_text()
    config = staged(root, "/etc/dthc-bridge/config.toml").read_text()
    assert 'username = "dthc-daemon"' in config
    assert "password_file" in config
    capsys.readouterr()

    passwd = staged(root, PASSWD).read_text()
    assert run_install(parser.parse_args(base)) == 0  # a re-install (an upgrade) stays locked
    assert "not locked" not in capsys.readouterr().out
    assert staged(root, PASSWD).read_text() == passwd  # the passwords are kept


def test_without_a_local_mosquitto_or_with_a_kept_config_the_install_says_the_broker_is_open(
    root: Path, bin_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    parser = argparse.ArgumentParser()
    add_install_arguments(parser)
    base = ["--root", str(root), "--bin-dir", str(bin_dir), "--no-start"]
    assert run_install(parser.parse_args(base)) == 0
    assert not staged(root, CONF).exists()
    assert "no local mosquitto" in capsys.readouterr().out
    staged(root, "/etc/mosquitto/conf.d").mkdir(parents=True)
    assert run_install(parser.parse_args(base)) == 0  # the configuration is kept: no login
    assert not staged(root, CONF).exists()
    assert "config.toml exists" in capsys.readouterr().out
    assert run_install(parser.parse_args([*base, "--no-broker-config"])) == 0
    assert "not locked" not in capsys.readouterr().out
