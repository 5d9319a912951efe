"""A table behind the broker `dthc-bridge install-service --broker-config` writes: users per
role, the roles' ACL, TLS with a CA and client certificates made here. The sender and the
panel log in as their roles and a program cuts; the panel's user cannot light the torch;
anonymous and wrong-password clients are refused (safety invariant 8)."""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import pwd
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request
from collections.abc import AsyncIterator, Iterator
from pathlib import Path

import aiomqtt
import pytest
from aiomqtt.exceptions import MqttConnectError
from pydantic import SecretStr

from dthc_bridge.deploy.broker import BrokerFiles, BrokerOptions, BrokerTls, Listener
from dthc_bridge.deploy.broker import write_broker_files as files_under
from dthc_bridge.mqtt.broker import BrokerSettings, MqttTls
from dthc_bridge.mqtt.denials import DenialWatch
from dthc_bridge.mqtt.roles import Role
from dthc_tools.demo import Stack, StackOptions, program_lines
from dthc_tools.demo.summary import summarize
from dthc_tools.procs import die_with_parent

from ..mqtt.conftest import MOSQUITTO, OPENSSL

pytestmark = [pytest.mark.slow, pytest.mark.timeout(180)]

BASE, BOARD = "shop", "table1"
ROOT = f"{BASE}/{BOARD}"


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port: int = sock.getsockname()[1]
        return port


def _openssl(*args: str) -> None:
    assert OPENSSL is not None
    subprocess.run([OPENSSL, *args], check=True, capture_output=True)


def make_pki(where: Path) -> dict[str, Path]:
    """A CA, the broker's certificate for 127.0.0.1 and a client certificate, all from it."""
    where.mkdir()
    pki = {name: where / f"{name}.pem" for name in
           ("ca", "ca-key", "broker", "broker-key", "client", "client-key")}  # fmt: skip
    _openssl("req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "2", "-subj",
             "/CN=dthc test CA", "-keyout", str(pki["ca-key"]), "-out", str(pki["ca"]))  # fmt: skip
    for name, subject, extension in (
        ("broker", "/CN=localhost", "subjectAltName=DNS:localhost,IP:127.0.0.1"),
        ("client", "/CN=shop-pc", "extendedKeyUsage=clientAuth"),
    ):
        request = where / f"{name}.csr"
        extfile = where / f"{name}.ext"
        extfile.write_text(extension + "\n")
        _openssl("req", "-new", "-newkey", "rsa:2048", "-nodes", "-subj", subject,
                 "-keyout", str(pki[f"{name}-key"]), "-out", str(request))  # fmt: skip
        _openssl("x509", "-req", "-in", str(request), "-CA", str(pki["ca"]), "-CAkey",
                 str(pki["ca-key"]), "-CAcreateserial", "-days", "2", "-out", str(pki[name]),
                 "-extfile", str(extfile))  # fmt: skip
    return pki


class SecuredBroker:
    """mosquitto on the files the installer wrote (plain listener on loopback, TLS beside it
    requiring a client certificate from the CA), run as this user for the test."""

    def __init__(self, workdir: Path) -> None:
        if MOSQUITTO is None or OPENSSL is None:
            pytest.skip("mosquitto and openssl are needed (make broker installs mosquitto)")
        self.pki = make_pki(workdir / "pki")
        self.plain_port, self.tls_port = _free_port(), _free_port()
        self.stage = workdir / "stage"
        self.stage.mkdir()
        tls = BrokerTls(
            self.pki["broker"], self.pki["broker-key"], self.pki["ca"],
            listen=Listener(self.tls_port, "127.0.0.1"), require_client_cert=True,
        )  # fmt: skip
        self.install_output = self._install(tls)
        # What the installer wrote, read back (the same options: nothing changes, passwords
        # are kept), for the paths of its files under the staging root.
        self.files: BrokerFiles = files_under(
            self.stage, BrokerOptions(listen=Listener(self.plain_port, "127.0.0.1"), tls=tls),
            base_topic=BASE, board_id=BOARD,
        )  # fmt: skip
        conf = workdir / "mosquitto.conf"
        me = pwd.getpwuid(os.getuid()).pw_name
        conf.write_text(
            self.files.conf_under_root()
            + f"\npersistence false\nuser {me}\nlog_dest file {workdir / 'mosquitto.log'}\n"
        )
        self.proc = subprocess.Popen(
            [MOSQUITTO, "-c", str(conf)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
            preexec_fn=die_with_parent(),
        )  # fmt: skip
        deadline = time.monotonic() + 5.0
        while True:
            with (
                contextlib.suppress(OSError),
                socket.create_connection(("127.0.0.1", self.tls_port), 0.2),
            ):
                break
            assert self.proc.poll() is None, (workdir / "mosquitto.log").read_text()
            assert time.monotonic() < deadline, "mosquitto did not start"
            time.sleep(0.05)

    def _install(self, tls: BrokerTls) -> str:
        """The owner's one command (staged: --root, nothing started)."""
        done = subprocess.run(
            [sys.executable, "-m", "dthc_bridge", "install-service", "--root", str(self.stage),
             "--no-start", "--broker-config", "/etc/mosquitto/conf.d",
             "--broker-listen", f"127.0.0.1:{self.plain_port}",
             "--broker-tls-listen", f"127.0.0.1:{self.tls_port}",
             "--broker-tls-cert", str(tls.cert_file), "--broker-tls-key", str(tls.key_file),
             "--broker-tls-ca", str(tls.ca_file), "--broker-require-client-cert",
             "--base-topic", BASE, "--board-id", BOARD],
            check=False, capture_output=True, text=True, timeout=60,
        )  # fmt: skip
        assert done.returncode == 0, done.stdout + done.stderr
        return done.stdout

    def login(self, role: Role, *, tls: bool = True) -> BrokerSettings:
        """``role``'s settings as its owner would give them: user, password file, CA and
        client certificate (the daemon's comes from the config the installer wrote)."""
        return BrokerSettings(
            host="127.0.0.1",
            port=self.tls_port if tls else self.plain_port,
            username=self.files.users[role],
            password_file=self.files.passwords[role],
            tls=MqttTls(
                ca_file=self.pki["ca"],
                cert_file=self.pki["client"],
                key_file=self.pki["client-key"],
            )
            if tls
            else None,
        )

    def stop(self) -> None:
        self.proc.terminate()
        self.proc.wait(5)


@pytest.fixture(scope="module")
def secured(tmp_path_factory: pytest.TempPathFactory) -> Iterator[SecuredBroker]:
    broker = SecuredBroker(tmp_path_factory.mktemp("secured"))
    try:
        yield broker
    finally:
        broker.stop()


@contextlib.asynccontextmanager
async def stack_on(secured: SecuredBroker, workdir: Path) -> AsyncIterator[Stack]:
    logins = {role.value: secured.login(role) for role in Role}
    options = StackOptions(workdir, scenario="masso_warped", base_topic=BASE, board_id=BOARD,
                           logins=logins, telemetry_hz=10.0)  # fmt: skip
    async with Stack(options) as stack:
        yield stack


@contextlib.contextmanager
def running_panel(secured: SecuredBroker, workdir: Path) -> Iterator[str]:
    """``dthc-bridge panel`` logged in as the panel's user over TLS; its URL."""
    login = secured.login(Role.PANEL)
    assert login.tls is not None
    with (workdir / "panel.log").open("w") as log:
        proc = subprocess.Popen(
            [sys.executable, "-m", "dthc_bridge", "panel",
             "--broker", f"mqtts://{login.username}@127.0.0.1:{login.port}",
             "--broker-password-file", str(login.password_file),
             "--broker-ca-file", str(login.tls.ca_file), "--broker-cert-file",
             str(login.tls.cert_file), "--broker-key-file", str(login.tls.key_file),
             "--base-topic", BASE, "--board-id", BOARD, "--listen", "127.0.0.1:0"],
            stdout=subprocess.PIPE, stderr=log, text=True, preexec_fn=die_with_parent(),
        )  # fmt: skip
        assert proc.stdout is not None
        try:
            line = proc.stdout.readline()
            assert line.startswith("PANEL "), (workdir / "panel.log").read_text()
            yield line.split()[1]
        finally:
            proc.terminate()
            proc.wait(5)
            proc.stdout.close()


def _forged_posts(url: str) -> list[int]:
    """A torch-up POST as a rebinding page sends it, then with a foreign Origin only."""
    statuses = []
    for headers in (
        {"Host": "attacker.example", "Origin": "http://attacker.example"},
        {"Origin": "http://attacker.example"},
    ):
        request = urllib.request.Request(  # noqa: S310 - our loopback panel
            url + "api/control/torch_up", data=b"{}", method="POST",
            headers={**headers, "Content-Type": "application/json", "X-DTHC-Panel": "1"},
        )  # fmt: skip
        try:
            with urllib.request.urlopen(request, timeout=5) as response:  # noqa: S310
                statuses.append(response.status)
        except urllib.error.HTTPError as exc:
            statuses.append(exc.code)
    return statuses


def _get_json(url: str) -> dict[str, object]:
    with urllib.request.urlopen(url, timeout=5) as response:  # noqa: S310 - our loopback panel
        document: dict[str, object] = json.loads(response.read())
        return document


async def test_a_program_cuts_with_the_sender_and_the_panel_logged_in_as_their_roles(
    secured: SecuredBroker, tmp_path: Path
) -> None:
    """Daemon, sender, panel and the observer each log in with their role's password and
    certificate over TLS; the MASSO sample cuts both parts, torch lit only inside cuts."""
    with running_panel(secured, tmp_path) as url:
        async with stack_on(secured, tmp_path) as stack:
            report = await stack.send(program_lines("masso_sample"))
            view = await asyncio.to_thread(_get_json, url + "api/view")
            forged = await asyncio.to_thread(_forged_posts, url)
            result = await stack.finish(report)
    summary = summarize(result, 10.0)
    assert summary["errors"] == [], summary["errors"]
    assert summary["completed_cuts"] == 2
    assert summary["safety_violations"] == 0
    assert view["daemon"] is True, view
    # DNS rebinding: another site's name for the panel's address is not served (421), and
    # an Origin of another site is refused (403) even with the panel's own Host.
    assert forged == [421, 403], forged


async def test_the_panels_user_cannot_light_the_torch_and_nobody_anonymous_gets_in(
    secured: SecuredBroker, tmp_path: Path
) -> None:
    """The panel's user publishing ``request/gcode`` M3 or ``cycle_start``: the broker answers
    "not authorized", the daemon never hears it and the board never lights. Its ``status``
    is answered. An anonymous client and a wrong password are refused at the door."""
    async with stack_on(secured, tmp_path) as stack:
        # The daemon is subscribed: the sender's status waits for its fresh availability (the
        # table's retained board state may still be the previous test's daemon's).
        async with stack.daemon_client().connected() as sender:
            assert (await sender.request("status"))["state"] == "idle"
        watch = DenialWatch()
        panel = aiomqtt.Client(**secured.login(Role.PANEL).client_options(), identifier="forger")
        watch.watch(panel)
        async with panel:
            await panel.subscribe(f"{ROOT}/response/#", qos=1)
            for name, document in (("gcode", {"line": "T112 M6"}), ("gcode", {"line": "M3"}),
                                   ("cycle_start", {}), ("rearm", {}), ("status", {})):  # fmt: skip
                payload = json.dumps({**document, "transaction": f"forged-{name}-{time.time()}"})
                await panel.publish(f"{ROOT}/request/{name}", payload, qos=1)
            answered: list[str] = []
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout(2.0):
                    async for message in panel.messages:
                        answered.append(message.topic.value.rsplit("/", 1)[-1])
        assert answered == ["status"], answered
        assert set(watch.refused) == {f"{ROOT}/request/gcode", f"{ROOT}/request/cycle_start",
                                      f"{ROOT}/request/rearm"}  # fmt: skip
        states = {point.get("state") for point in stack.telemetry}
        assert states <= {"idle"}, states
        result = await stack.finish()
    assert result.mock_exit["torch_on_commands"] == 0, result.mock_exit
    assert not [e for e in result.events if e.get("type") == "sequence"], result.events

    for settings, refusal in (
        (BrokerSettings(host="127.0.0.1", port=secured.plain_port), "Not authorized"),
        (secured.login(Role.SENDER, tls=False).model_copy(
            update={"password_file": None, "password": SecretStr("wrong")}), "Not authorized"),
    ):  # fmt: skip
        with pytest.raises(MqttConnectError, match=refusal):
            async with aiomqtt.Client(**settings.client_options(), identifier="intruder"):
                pass
