"""A real mosquitto started on a configuration file as written, and MQTT 5 clients that
report what the broker answered (CONNACK and PUBACK reason codes)."""

from __future__ import annotations

import os
import pwd
import shutil
import socket
import subprocess
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import paho.mqtt.client as paho
from paho.mqtt.enums import CallbackAPIVersion
from paho.mqtt.properties import Properties
from paho.mqtt.reasoncodes import ReasonCode

from dthc_tools.procs import die_with_parent

MOSQUITTO = shutil.which("mosquitto") or (
    "/usr/sbin/mosquitto" if os.access("/usr/sbin/mosquitto", os.X_OK) else None
)
START_TIMEOUT_S = 5.0
REPLY_TIMEOUT_S = 5.0
NOT_AUTHORIZED = 0x87
"""MQTT 5 reason code: a PUBACK for a publish the ACL denies, a CONNACK for a bad login."""
ACCEPTED = (0x00, 0x10)
"""PUBACK reason codes of an accepted publish: success, success with no subscriber."""


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port: int = sock.getsockname()[1]
        return port


@contextmanager
def mosquitto(
    conf_text: str, workdir: Path, port: int, *, as_user: str | None = None
) -> Iterator[Path]:
    """mosquitto running ``conf_text`` (listening on ``port``); yields its log file.

    ``as_user``: a root mosquitto drops to that user (None: stay the current user, so a
    root test run keeps reading the test's private files)."""
    assert MOSQUITTO is not None
    log = workdir / "mosquitto.log"
    user = as_user or pwd.getpwuid(os.getuid()).pw_name
    config = workdir / "run.conf"
    config.write_text(f"user {user}\nlog_dest file {log}\nlog_type all\n{conf_text}")
    config.chmod(0o644)
    proc = subprocess.Popen(
        [MOSQUITTO, "-c", str(config)],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, preexec_fn=die_with_parent(),
    )  # fmt: skip
    try:
        deadline = time.monotonic() + START_TIMEOUT_S
        while True:
            if proc.poll() is not None:
                stderr = proc.stderr.read().decode() if proc.stderr else ""
                text = log.read_text() if log.exists() else ""
                raise RuntimeError(f"mosquitto exited at start:\n{stderr}{text}")
            try:
                with socket.create_connection(("127.0.0.1", port), timeout=0.2):
                    break
            except OSError:
                if time.monotonic() > deadline:
                    raise TimeoutError(f"mosquitto not listening on {port}") from None
                time.sleep(0.02)
        yield log
    finally:
        proc.terminate()
        try:
            proc.wait(5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)
        if proc.stderr is not None:
            proc.stderr.close()


class Client:
    """One MQTT 5 client on its own network thread: connect, subscribe, publish at QoS 1,
    and what the broker answered to each."""

    def __init__(self, port: int, user: str | None, password: str | None, **tls: object) -> None:
        self.port = port
        self._client = paho.Client(CallbackAPIVersion.VERSION2, protocol=paho.MQTTv5)
        if user is not None:
            self._client.username_pw_set(user, password)
        if tls:
            self._client.tls_set(**tls)  # type: ignore[arg-type]
        self._connack = threading.Event()
        self.connect_code: ReasonCode | None = None
        self._acks: dict[int, ReasonCode] = {}
        self._acked = threading.Condition()
        self.received: list[tuple[str, bytes]] = []
        self._client.on_connect = self._on_connect
        self._client.on_publish = self._on_publish
        self._client.on_message = self._on_message
        self._client.on_subscribe = self._on_subscribe
        self._subscribed = threading.Event()

    def _on_connect(
        self, client: paho.Client, userdata: object, flags: object, rc: ReasonCode,
        properties: Properties | None,
    ) -> None:  # fmt: skip
        self.connect_code = rc
        self._connack.set()

    def _on_publish(
        self, client: paho.Client, userdata: object, mid: int, rc: ReasonCode,
        properties: Properties | None,
    ) -> None:  # fmt: skip
        with self._acked:
            self._acks[mid] = rc
            self._acked.notify_all()

    def _on_message(self, client: paho.Client, userdata: object, msg: paho.MQTTMessage) -> None:
        with self._acked:
            self.received.append((msg.topic, bytes(msg.payload)))
            self._acked.notify_all()

    def _on_subscribe(
        self, client: paho.Client, userdata: object, mid: int, codes: list[ReasonCode],
        properties: Properties | None,
    ) -> None:  # fmt: skip
        self._subscribed.set()

    def __enter__(self) -> Client:
        self._client.connect("127.0.0.1", self.port)
        self._client.loop_start()
        assert self._connack.wait(REPLY_TIMEOUT_S), "no CONNACK"
        return self

    def __exit__(self, *exc: object) -> None:
        self._client.disconnect()
        self._client.loop_stop()

    @property
    def accepted(self) -> bool:
        return self.connect_code is not None and not self.connect_code.is_failure

    def subscribe(self, topic_filter: str) -> None:
        self._subscribed.clear()
        self._client.subscribe(topic_filter, qos=1)
        assert self._subscribed.wait(REPLY_TIMEOUT_S), "no SUBACK"

    def publish(self, topic: str, payload: bytes = b"{}") -> int:
        """Publish at QoS 1; the PUBACK's reason code (:data:`ACCEPTED`, 0x87 refused)."""
        info = self._client.publish(topic, payload, qos=1)
        with self._acked:
            assert self._acked.wait_for(lambda: info.mid in self._acks, REPLY_TIMEOUT_S)
            return self._acks[info.mid].value

    def wait_for(self, count: int) -> list[tuple[str, bytes]]:
        """The first ``count`` messages received (AssertionError if they do not come)."""
        with self._acked:
            assert self._acked.wait_for(lambda: len(self.received) >= count, REPLY_TIMEOUT_S)
            return list(self.received)
