"""The broker files the installer writes, read by a real mosquitto: our password hashes log
in, wrong and anonymous logins are refused, and the ACL lets only dthc-sender send what
lights the torch while the panel keeps its stop."""

from __future__ import annotations

import grp
import io
import os
import shutil
import socket
import ssl
import subprocess
import tempfile
from collections.abc import Iterator
from pathlib import Path

import pytest

from dthc_bridge.deploy.actions import Context
from dthc_bridge.deploy.broker import (
    BROKER_GROUP,
    BROKER_USERS,
    BrokerFiles,
    BrokerOptions,
    BrokerTls,
    Listener,
    broker_steps,
    render_broker_conf,
    validated_topics,
    write_broker_files,
)
from dthc_bridge.mqtt.roles import Role

from .mosquitto_run import ACCEPTED, MOSQUITTO, NOT_AUTHORIZED, Client, free_port, mosquitto

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(
        MOSQUITTO is None, reason="mosquitto not installed (apt-get install mosquitto)"
    ),
]

ROOT = "dthc/table1"


def _has_group(name: str) -> bool:
    try:
        grp.getgrnam(name)
    except KeyError:
        return False
    return True


OPENSSL = shutil.which("openssl")


@pytest.fixture
def staged(tmp_path: Path) -> BrokerFiles:
    port = free_port()
    return write_broker_files(tmp_path / "root", BrokerOptions(listen=Listener(port, "127.0.0.1")))


@pytest.fixture
def broker(staged: BrokerFiles, tmp_path: Path) -> Iterator[int]:
    """mosquitto on exactly the staged conf (our files' paths under the staging root)."""
    assert staged.options.listen is not None
    port = staged.options.listen.port
    with mosquitto(staged.conf_under_root(), tmp_path, port):
        yield port


def test_our_hashes_log_in_and_nothing_else_does(staged: BrokerFiles, broker: int) -> None:
    """Each role logs in with its password file's password; a wrong password, an unknown
    user and an anonymous client are refused."""
    for role, user in BROKER_USERS.items():
        with Client(broker, user, staged.password(role)) as client:
            assert client.accepted, (user, client.connect_code)
    wrong: list[tuple[str | None, str | None]] = [
        ("dthc-sender", staged.password(Role.SENDER) + "x"),
        ("dthc-sender", staged.password(Role.PANEL)),
        ("intruder", staged.password(Role.SENDER)),
        (None, None),
    ]
    for name, password in wrong:
        with Client(broker, name, password) as client:
            assert not client.accepted, name
            assert client.connect_code is not None
            assert client.connect_code.value in (0x86, NOT_AUTHORIZED)


def test_only_the_sender_may_send_what_lights_the_torch(staged: BrokerFiles, broker: int) -> None:
    """As dthc-daemon, subscribed to every request: the panel's and the dashboard's G-code
    are refused (PUBACK 0x87) and never arrive; the sender's arrives; the panel's stop
    arrives too (a stop works whoever drives the table)."""
    with (
        Client(broker, "dthc-daemon", staged.password(Role.DAEMON)) as daemon,
        Client(broker, "dthc-sender", staged.password(Role.SENDER)) as sender,
        Client(broker, "dthc-panel", staged.password(Role.PANEL)) as panel,
        Client(broker, "dthc-dashboard", staged.password(Role.DASHBOARD)) as dashboard,
    ):
        daemon.subscribe(f"{ROOT}/request/#")
        assert panel.publish(f"{ROOT}/request/gcode", b"panel") == NOT_AUTHORIZED
        assert panel.publish(f"{ROOT}/request/torch_down", b"panel") == NOT_AUTHORIZED
        assert dashboard.publish(f"{ROOT}/request/abort", b"dashboard") == NOT_AUTHORIZED
        assert daemon.publish(f"{ROOT}/request/gcode", b"daemon") == NOT_AUTHORIZED
        assert panel.publish(f"{ROOT}/request/abort", b"panel") in ACCEPTED
        assert sender.publish(f"{ROOT}/request/gcode", b"sender") in ACCEPTED
        # The broker handles one client's packets before the next's: by the time the
        # sender's G-code arrives, anything the refused publishes had queued would have.
        assert daemon.wait_for(2) == [
            (f"{ROOT}/request/abort", b"panel"),
            (f"{ROOT}/request/gcode", b"sender"),
        ]
        # The daemon alone writes the state the others read.
        assert sender.publish(f"{ROOT}/state", b"forged") == NOT_AUTHORIZED
        assert daemon.publish(f"{ROOT}/state", b"{}") in ACCEPTED


@pytest.mark.skipif(os.geteuid() != 0, reason="needs root to give files to mosquitto's group")
@pytest.mark.skipif(not _has_group(BROKER_GROUP), reason="no mosquitto group")
def test_debian_mosquitto_reads_the_files_as_installed(tmp_path: Path) -> None:
    """Installed as on a live system (root:mosquitto 0640), the files are read by a root
    mosquitto that drops to its own user, as Debian's service does."""
    # Under a directory the mosquitto user can walk (pytest's tmp_path is root-only).
    root = Path(tempfile.mkdtemp(prefix="dthc-broker-", dir="/tmp"))
    try:
        root.chmod(0o755)
        port = free_port()
        options = BrokerOptions(listen=Listener(port, "127.0.0.1"))
        ctx = Context(root=root, live=True, dry_run=False, out=io.StringIO())
        for step in broker_steps(
            options, root=root, topics=validated_topics("dthc", "table1"), service_group="root",
            broker_group_exists=True, broker_installed=True,
        ):  # fmt: skip
            step.apply(ctx)
        for path in (ctx.path(options.passwd_path), ctx.path(options.acl_path)):
            info = path.stat()
            assert (info.st_uid, info.st_gid) == (0, grp.getgrnam(BROKER_GROUP).gr_gid)
            assert info.st_mode & 0o777 == 0o640
        conf = render_broker_conf(options, ROOT, root=root)
        password = ctx.path("/etc/dthc-bridge/broker/sender.password").read_text().strip()
        with (
            mosquitto(conf, tmp_path, port, as_user=BROKER_GROUP),
            Client(port, "dthc-sender", password) as sender,
        ):
            assert sender.accepted
            assert sender.publish(f"{ROOT}/request/gcode") in ACCEPTED
            assert sender.publish(f"{ROOT}/state") == NOT_AUTHORIZED
    finally:
        shutil.rmtree(root)


def _make_certificates(directory: Path) -> tuple[Path, Path, Path]:
    """A CA and a broker certificate for 127.0.0.1 signed by it (openssl)."""
    assert OPENSSL is not None
    ca_key, ca = directory / "ca.key", directory / "ca.crt"
    key, csr, cert = directory / "broker.key", directory / "broker.csr", directory / "broker.crt"
    ext = directory / "ext.cnf"
    ext.write_text("subjectAltName=IP:127.0.0.1,DNS:localhost\n")

    def openssl(*args: str) -> None:
        subprocess.run([OPENSSL, *args], check=True, capture_output=True)

    openssl("req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", str(ca_key), "-out",
            str(ca), "-days", "2", "-subj", "/CN=dthc test CA")  # fmt: skip
    openssl("req", "-newkey", "rsa:2048", "-nodes", "-keyout", str(key), "-out", str(csr),
            "-subj", "/CN=localhost")  # fmt: skip
    openssl("x509", "-req", "-in", str(csr), "-CA", str(ca), "-CAkey", str(ca_key),
            "-CAcreateserial", "-out", str(cert), "-days", "2", "-extfile", str(ext))  # fmt: skip
    return cert, key, ca


@pytest.mark.skipif(OPENSSL is None, reason="openssl not installed")
def test_tls_listener_with_the_written_conf(tmp_path: Path) -> None:
    """A TLS-only broker as written: a client that trusts the CA logs in over TLS; one that
    does not trust it never gets to log in."""
    cert, key, ca = _make_certificates(tmp_path)
    port = free_port()
    tls = BrokerTls(cert_file=cert, key_file=key, ca_file=ca, listen=Listener(port, "127.0.0.1"))
    files = write_broker_files(tmp_path / "root", BrokerOptions(listen=None, tls=tls))
    with mosquitto(files.conf_under_root(), tmp_path, port):
        with Client(port, "dthc-sender", files.password(Role.SENDER), ca_certs=str(ca)) as sender:
            assert sender.accepted
            assert sender.publish(f"{ROOT}/request/gcode") in ACCEPTED
        untrusted = ssl.create_default_context()  # the system's CAs, not the table's
        with (
            socket.create_connection(("127.0.0.1", port), timeout=5) as raw,
            pytest.raises(ssl.SSLCertVerificationError),
        ):
            untrusted.wrap_socket(raw, server_hostname="localhost").close()
