"""Every client logs in the same way (the daemon's broker model), says in one line what the
broker refused, and the daemon says which of its topics the broker's ACL denies it."""

from __future__ import annotations

import argparse
import asyncio
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
import structlog

from dthc_bridge.mqtt.broker import BrokerSettings
from dthc_bridge.mqtt.roles import Role, render_acl
from dthc_tools.broker_options import (
    PASSWORD_ENV,
    BrokerOptionError,
    add_broker_arguments,
    broker_from_args,
)
from dthc_tools.panel import cli as panel_cli
from dthc_tools.sender import cli as sender_cli

from .conftest import OPENSSL, Broker, _require_mosquitto, write_passwords
from .helpers import fast_settings, running_gateway

PASSWORDS = {"dthc-daemon": "daemon-secret-0123456789", "dthc-sender": "sender-secret-0123456789"}


def _options(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    add_broker_arguments(parser)
    return parser.parse_args(list(argv))


def test_the_broker_options_build_the_daemons_model(tmp_path: Path) -> None:
    secret = tmp_path / "sender.password"
    secret.write_text("s3cret\n")
    ca = tmp_path / "ca.pem"
    ca.write_text("")
    broker = broker_from_args(
        _options("--broker", "mqtts://dthc-sender@shop-pc", "--broker-password-file",
                 str(secret), "--broker-ca-file", str(ca)),
        environ={},
    )  # fmt: skip
    assert (broker.host, broker.port, broker.username) == ("shop-pc", 8883, "dthc-sender")
    assert broker.read_password() == "s3cret"
    assert broker.tls is not None
    assert broker.tls.ca_file == ca
    assert broker.url == "mqtts://dthc-sender@shop-pc:8883"
    plain = broker_from_args(_options(), environ={PASSWORD_ENV: "from-env"})
    assert (plain.host, plain.port, plain.tls) == ("localhost", 1883, None)
    assert plain.read_password() == "from-env"


@pytest.mark.parametrize(
    ("argv", "environ", "error"),
    [
        (("--broker", "mqtt://u:pw@host"), {}, "a password in the URL is visible"),
        (("--broker", "http://host"), {}, "expected mqtt://[USER@]HOST[:PORT]"),
        (("--broker", "mqtt://host:99999"), {}, "the port is not a number"),
        (("--broker-password-file", "x"), {PASSWORD_ENV: "y"}, "both given"),
        (("--broker-ca-file", "/nonexistent/ca.pem"), {}, "--broker-ca-file /nonexistent"),
        (("--broker-cert-file", __file__), {}, "go together"),
    ],
)
def test_a_broker_option_that_cannot_work_is_named(
    argv: tuple[str, ...], environ: dict[str, str], error: str
) -> None:
    with pytest.raises(BrokerOptionError, match=error.replace("[", r"\[").replace("]", r"\]")):
        broker_from_args(_options(*argv), environ=environ)


def test_a_password_file_that_cannot_be_read_is_named(tmp_path: Path) -> None:
    missing = tmp_path / "nope.password"
    broker = BrokerSettings(username="x", password_file=missing)
    with pytest.raises(OSError, match=f"password_file {missing}: No such file"):
        broker.client_options()


# --- against a real mosquitto -------------------------------------------------------------


@pytest.fixture
def password_broker(tmp_path: Path) -> Iterator[Broker]:
    """mosquitto with two users, and the roles' ACL less the daemon's ``materials`` topic."""
    _require_mosquitto()
    passwords = write_passwords(tmp_path / "passwd", PASSWORDS)
    acl = render_acl("dthc/table1", {Role.DAEMON: "dthc-daemon", Role.SENDER: "dthc-sender"})
    acl_file = tmp_path / "acl"
    acl_file.write_text(acl.replace("topic write dthc/table1/materials\n", ""))
    instance = Broker(tmp_path, password_file=passwords, acl_file=acl_file)
    instance.start()
    try:
        yield instance
    finally:
        instance.stop()


def _program(tmp_path: Path) -> Path:
    program = tmp_path / "part.ngc"
    program.write_text("T112 M6\nM3\nM5\n")
    return program


def test_a_wrong_password_is_one_line_naming_the_user_and_exit_2(
    password_broker: Broker,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    url = f"mqtt://dthc-sender@127.0.0.1:{password_broker.port}"
    monkeypatch.setenv(PASSWORD_ENV, "not-the-password")
    assert sender_cli.main([str(_program(tmp_path)), "--broker", url]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert err[0].startswith(
        f"dthc-bridge send: the broker at {url} refused the login of user 'dthc-sender': "
    ), err
    assert err[0].endswith("(check the user name and the password)"), err
    monkeypatch.delenv(PASSWORD_ENV)
    anonymous = f"mqtt://127.0.0.1:{password_broker.port}"
    assert panel_cli.main(["--broker", anonymous, "--listen", "127.0.0.1:0"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert "refused the login of an anonymous client" in err[0]


def test_a_broker_certificate_from_another_ca_is_one_line_naming_the_ca_file(
    tls_broker: Broker, tmp_path: Path
) -> None:
    assert OPENSSL is not None
    other_ca, other_key = tmp_path / "other-ca.pem", tmp_path / "other-key.pem"
    subprocess.run(
        [OPENSSL, "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "1",
         "-keyout", str(other_key), "-out", str(other_ca), "-subj", "/CN=another CA"],
        check=True, capture_output=True,
    )  # fmt: skip
    url = f"mqtts://127.0.0.1:{tls_broker.port}"
    # Its own process, as an owner runs it (paho leaves the failed TLS socket to the GC).
    done = subprocess.run(
        [sys.executable, "-m", "dthc_bridge", "send", str(_program(tmp_path)), "--broker", url,
         "--broker-ca-file", str(other_ca)],
        check=False, capture_output=True, text=True, timeout=20,
    )  # fmt: skip
    assert done.returncode == 2, done.stderr
    err = done.stderr.strip().splitlines()
    assert len(err) == 1, err
    assert f"the broker's certificate is not trusted by CA file {other_ca}" in err[0]


def test_the_daemon_exits_2_naming_a_refused_login(password_broker: Broker, tmp_path: Path) -> None:
    """A daemon that can never log in says so once and stops (it does not retry forever)."""
    secret = tmp_path / "daemon.password"
    secret.write_text("wrong")
    secret.chmod(0o600)
    config = tmp_path / "config.toml"
    config.write_text(
        f'[board]\nlink = "{tmp_path / "no-board"}"\n\n[mqtt]\nhost = "127.0.0.1"\n'
        f'port = {password_broker.port}\nusername = "dthc-daemon"\npassword_file = "{secret}"\n'
    )
    done = subprocess.run(
        [sys.executable, "-m", "dthc_bridge", "run", "--config", str(config)],
        check=False, capture_output=True, text=True, timeout=20,
    )  # fmt: skip
    assert done.returncode == 2, done.stderr[-2000:]
    refused = [line for line in done.stderr.splitlines() if "mqtt_login_refused" in line]
    assert len(refused) == 1, done.stderr[-2000:]
    assert "refused the login of user 'dthc-daemon': not authorized" in refused[0]


async def test_the_daemon_warns_once_naming_a_topic_the_broker_denies_it(
    password_broker: Broker,
) -> None:
    """The ACL lacks the daemon's ``materials``: the broker answers each retained publish
    there with "not authorized" (MQTT 5); the daemon names the topic once and counts."""
    settings = fast_settings(
        password_broker, base_topic="dthc", board_id="table1", username="dthc-daemon",
        password=PASSWORDS["dthc-daemon"],
    )  # fmt: skip
    with structlog.testing.capture_logs() as logs:
        async with running_gateway(settings) as (gateway, _):
            for _ in range(100):
                if gateway.broker_refusals:
                    break
                await asyncio.sleep(0.05)
            await asyncio.sleep(0.3)  # state polls republish nothing new; a change would
            refused = gateway.broker_refusals
    warnings = [entry for entry in logs if entry["event"] == "mqtt_broker_refused"]
    assert refused == {"dthc/table1/materials": 1}, refused
    assert [w["topic"] for w in warnings] == ["dthc/table1/materials"], warnings


def test_with_no_login_given_the_roles_copied_password_is_used(tmp_path: Path) -> None:
    """The installer says to copy a role's password to ~/.config/dthc-bridge/<role>.password:
    a tool then logs in as dthc-<role> with it, no option needed; given options still win."""
    home = tmp_path / "home"
    saved = home / ".config" / "dthc-bridge" / "panel.password"
    saved.parent.mkdir(parents=True)
    saved.write_text("copied\n")
    parser = argparse.ArgumentParser()
    add_broker_arguments(parser, role="panel")
    broker = broker_from_args(parser.parse_args([]), environ={"HOME": str(home)})
    assert (broker.username, broker.password_file) == ("dthc-panel", saved)
    assert broker.read_password() == "copied"
    own = broker_from_args(
        parser.parse_args(["--broker-user", "someone"]), environ={"HOME": str(home)}
    )
    assert (own.username, own.password_file) == ("someone", None)
    sender = broker_from_args(_options(), environ={"HOME": str(home)})  # no sender copy
    assert (sender.username, sender.password_file) == (None, None)
