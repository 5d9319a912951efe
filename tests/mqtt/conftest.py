"""A real mosquitto on loopback: one for the session, and private ones tests may restart."""

from __future__ import annotations

import os
import pwd
import shutil
import socket
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from dthc_tools.procs import die_with_parent

MOSQUITTO = shutil.which("mosquitto") or (
    "/usr/sbin/mosquitto" if os.access("/usr/sbin/mosquitto", os.X_OK) else None
)
MOSQUITTO_PASSWD = shutil.which("mosquitto_passwd")
OPENSSL = shutil.which("openssl")
START_TIMEOUT_S = 5.0


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port: int = sock.getsockname()[1]
        return port


class Broker:
    """One mosquitto process on 127.0.0.1; ``stop()``/``start()`` keep the same port."""

    def __init__(
        self,
        workdir: Path,
        *,
        persistent: bool = False,
        password_file: Path | None = None,
        acl_file: Path | None = None,
        tls: tuple[Path, Path] | None = None,
    ) -> None:
        assert MOSQUITTO is not None
        self.workdir = workdir
        self.host = "127.0.0.1"
        self.port = free_port()
        self.persistent = persistent
        self.password_file = password_file
        self.acl_file = acl_file
        self.tls = tls  # (certificate, key): the listener speaks TLS only
        self.config = workdir / "mosquitto.conf"
        self.log = workdir / "mosquitto.log"
        self.proc: subprocess.Popen[bytes] | None = None

    def _write_config(self) -> None:
        lines = [
            f"listener {self.port} {self.host}",
            f"allow_anonymous {'false' if self.password_file else 'true'}",
            f"persistence {'true' if self.persistent else 'false'}",
            f"log_dest file {self.log}",
            "log_type error",
            "log_type warning",
            "log_type notice",
            # Stay this user: a root mosquitto would drop to "mosquitto" and lose the tmp files.
            f"user {pwd.getpwuid(os.getuid()).pw_name}",
        ]
        if self.tls is not None:
            lines += [f"certfile {self.tls[0]}", f"keyfile {self.tls[1]}"]
        if self.persistent:
            lines.append(f"persistence_location {self.workdir}/")
        if self.password_file is not None:
            lines.append(f"password_file {self.password_file}")
        if self.acl_file is not None:
            lines.append(f"acl_file {self.acl_file}")
        self.config.write_text("\n".join(lines) + "\n")

    def start(self) -> None:
        assert self.proc is None, "already running"
        assert MOSQUITTO is not None
        self._write_config()
        self.proc = subprocess.Popen(
            [MOSQUITTO, "-c", str(self.config)],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, preexec_fn=die_with_parent(),
        )  # fmt: skip
        deadline = time.monotonic() + START_TIMEOUT_S
        while True:
            if self.proc.poll() is not None:
                log = self.log.read_text() if self.log.exists() else ""
                self.proc = None
                raise RuntimeError(f"mosquitto exited at start:\n{log}")
            try:
                with socket.create_connection((self.host, self.port), timeout=0.2):
                    return
            except OSError:
                if time.monotonic() > deadline:
                    self.stop()
                    raise TimeoutError(f"mosquitto not listening on {self.port}") from None
                time.sleep(0.02)

    def stop(self) -> None:
        """SIGTERM (a persistent broker saves its sessions) and wait for the exit."""
        if self.proc is None:
            return
        self.proc.terminate()
        try:
            self.proc.wait(5)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait(5)
        self.proc = None

    @property
    def running(self) -> bool:
        return self.proc is not None and self.proc.poll() is None


def _require_mosquitto() -> None:
    if MOSQUITTO is None:
        pytest.skip("mosquitto is not installed (make broker installs it)")


@pytest.fixture(scope="session")
def broker(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Broker]:
    """The shared broker: tests keep apart by using their own base topic."""
    _require_mosquitto()
    instance = Broker(tmp_path_factory.mktemp("mosquitto"))
    instance.start()
    try:
        yield instance
    finally:
        instance.stop()


@pytest.fixture
def own_broker(tmp_path: Path) -> Iterator[Broker]:
    """A private broker without persistence: a restart loses every retained message."""
    _require_mosquitto()
    instance = Broker(tmp_path)
    instance.start()
    try:
        yield instance
    finally:
        instance.stop()


@pytest.fixture
def persistent_broker(tmp_path: Path) -> Iterator[Broker]:
    """A private broker that keeps sessions and queued messages across a restart."""
    _require_mosquitto()
    instance = Broker(tmp_path, persistent=True)
    instance.start()
    try:
        yield instance
    finally:
        instance.stop()


ACL_EXAMPLE = Path(__file__).parents[2] / "systemd" / "mosquitto-acl.example"
USERS = {"dthc-daemon": "daemon-secret", "dthc-sender": "sender-secret"}


def write_passwords(path: Path, users: dict[str, str]) -> Path:
    """A mosquitto password file made by Debian's own mosquitto_passwd (skips without it)."""
    if MOSQUITTO_PASSWD is None:
        pytest.skip("mosquitto_passwd is not installed")
    for index, (user, password) in enumerate(users.items()):
        create = ["-c"] if index == 0 else []
        subprocess.run(
            [MOSQUITTO_PASSWD, *create, "-b", str(path), user, password],
            check=True, capture_output=True,
        )  # fmt: skip
    return path


@pytest.fixture
def auth_broker(tmp_path: Path) -> Iterator[Broker]:
    """A private broker with passwords (mosquitto_passwd) and the shipped ACL example."""
    _require_mosquitto()
    passwords = write_passwords(tmp_path / "passwords", USERS)
    instance = Broker(tmp_path, password_file=passwords, acl_file=ACL_EXAMPLE)
    instance.start()
    try:
        yield instance
    finally:
        instance.stop()


@pytest.fixture
def tls_broker(tmp_path: Path) -> Iterator[Broker]:
    """A private broker speaking only TLS, with a self-signed certificate for 127.0.0.1."""
    _require_mosquitto()
    if OPENSSL is None:
        pytest.skip("openssl is not installed")
    cert, key = tmp_path / "cert.pem", tmp_path / "key.pem"
    subprocess.run(
        [OPENSSL, "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "1",
         "-keyout", str(key), "-out", str(cert), "-subj", "/CN=localhost",
         "-addext", "subjectAltName=DNS:localhost,IP:127.0.0.1"],
        check=True, capture_output=True,
    )  # fmt: skip
    instance = Broker(tmp_path, tls=(cert, key))
    instance.start()
    try:
        yield instance
    finally:
        instance.stop()
