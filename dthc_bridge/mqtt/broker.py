"""How to reach and log in to the broker: one model for the daemon and every client.

The daemon's ``[mqtt]`` section (:class:`~.settings.MqttSettings`) extends
:class:`BrokerSettings`; the sender, the panel, the demo's and the benchmarks' clients build
the same model from their ``--broker`` options (``dthc_tools/broker_options.py``), so a
password file, a CA or a client certificate work the same way everywhere. Secrets come from
a file (owner-only) or the environment, never from the command line, where ``ps`` shows them.
"""

from __future__ import annotations

import ssl
from pathlib import Path
from typing import Any, Literal, Self

import aiomqtt
from aiomqtt.exceptions import MqttConnectError
from pydantic import BaseModel, ConfigDict, Field, SecretStr, model_validator

__all__ = ["BrokerRefused", "BrokerSettings", "MqttTls", "describe_broker_error", "is_refusal"]

# MQTT 3.1.1 CONNACK return codes and MQTT 5 reason codes that mean "who you are" is refused.
_V311_LOGIN_REFUSED = {4: "bad user name or password", 5: "not authorized"}
_V5_LOGIN_REFUSED = {134: "bad user name or password", 135: "not authorized"}


class MqttTls(BaseModel):
    """TLS to the broker; without ``ca_file`` the system's CA store is used."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    ca_file: Path | None = None
    cert_file: Path | None = Field(default=None, description="client certificate (with key_file)")
    key_file: Path | None = None
    insecure: bool = Field(
        default=False, description="skip the broker's hostname check (testing only)"
    )

    @model_validator(mode="after")
    def _cert_and_key_together(self) -> Self:
        if (self.cert_file is None) != (self.key_file is None):
            raise ValueError("cert_file and key_file must be given together")
        return self

    def context(self) -> ssl.SSLContext:
        """The client's TLS context; OSError/ssl.SSLError name the file that failed."""
        try:
            context = ssl.create_default_context(
                cafile=str(self.ca_file) if self.ca_file is not None else None
            )
        except (OSError, ssl.SSLError) as exc:
            raise _file_error("tls.ca_file", self.ca_file, exc) from None
        if self.cert_file is not None:
            try:
                context.load_cert_chain(str(self.cert_file), str(self.key_file))
            except (OSError, ssl.SSLError) as exc:
                where = f"{self.cert_file} / {self.key_file}"
                raise OSError(f"tls.cert_file/key_file {where}: {_reason(exc)}") from None
        if self.insecure:
            context.check_hostname = False
        return context


class BrokerSettings(BaseModel):
    """Where the broker is and who this client is to it."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    host: str = Field(default="localhost", min_length=1, max_length=253)
    port: int = Field(default=1883, ge=1, le=65535)
    username: str | None = Field(default=None, min_length=1, max_length=256)
    password: SecretStr | None = Field(
        default=None, description="prefer password_file (or DTHC_MQTT__PASSWORD)"
    )
    password_file: Path | None = Field(
        default=None, description="a file holding the broker password (owner-only)"
    )
    tls: MqttTls | None = None
    protocol: Literal["3.1.1", "5"] = "5"

    @model_validator(mode="after")
    def _one_password(self) -> Self:
        if self.password is not None and self.password_file is not None:
            raise ValueError("give password or password_file, not both")
        return self

    @property
    def url(self) -> str:
        """``mqtt(s)://[user@]host:port``, for messages (never the password)."""
        scheme = "mqtts" if self.tls is not None else "mqtt"
        user = f"{self.username}@" if self.username else ""
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"{scheme}://{user}{host}:{self.port}"

    def read_password(self) -> str | None:
        """The password, read from ``password_file`` now (OSError naming the file)."""
        if self.password is not None:
            return self.password.get_secret_value()
        if self.password_file is None:
            return None
        try:
            text = self.password_file.read_text().strip()
        except OSError as exc:
            raise _file_error("password_file", self.password_file, exc) from None
        if not text:
            raise OSError(f"password_file {self.password_file}: the file is empty")
        return text

    def client_options(self) -> dict[str, Any]:
        """Keyword arguments of ``aiomqtt.Client`` for this broker: address, login, TLS and
        protocol. OSError names a password, CA or certificate file that cannot be used."""
        v5 = self.protocol == "5"
        version = aiomqtt.ProtocolVersion.V5 if v5 else aiomqtt.ProtocolVersion.V311
        return {
            "hostname": self.host,
            "port": self.port,
            "username": self.username,
            "password": self.read_password(),
            "protocol": version,
            "tls_context": self.tls.context() if self.tls is not None else None,
        }


class BrokerRefused(Exception):
    """The broker refused who we are (the login, or our trust in its certificate): trying
    again cannot help until the configuration changes."""


def _login_refused(exc: BaseException, broker: BrokerSettings) -> str | None:
    """The broker's reason when it refused the login (bad user or password, not
    authorized), else None."""
    rc = getattr(exc, "rc", None)
    if not isinstance(exc, MqttConnectError) or rc is None:
        return None
    value = getattr(rc, "value", rc)
    table = _V5_LOGIN_REFUSED if broker.protocol == "5" else _V311_LOGIN_REFUSED
    return table.get(value) if isinstance(value, int) else None


def _untrusted(text: str) -> bool:
    """The TLS handshake failed on the broker's certificate."""
    return "CERTIFICATE_VERIFY_FAILED" in text or "certificate verify failed" in text


def is_refusal(exc: BaseException, broker: BrokerSettings) -> bool:
    """The broker refused the login, or its certificate is not trusted (not: unreachable)."""
    return _login_refused(exc, broker) is not None or _untrusted(str(exc))


def describe_broker_error(exc: BaseException, broker: BrokerSettings) -> str:
    """One line naming what failed when connecting to ``broker``: the login, the TLS
    handshake (certificate), the address, or a file of ours."""
    where = broker.url
    reason = _login_refused(exc, broker)
    if reason is not None:
        who = f"user {broker.username!r}" if broker.username else "an anonymous client"
        return (
            f"the broker at {where} refused the login of {who}: {reason} "
            "(check the user name and the password)"
        )
    if isinstance(exc, aiomqtt.MqttCodeError) and getattr(exc, "rc", None) is not None:
        return f"the broker at {where} refused the connection: {exc}"
    text = str(exc)
    if _untrusted(text):
        ca = broker.tls.ca_file if broker.tls is not None else None
        trust = f"CA file {ca}" if ca is not None else "the system's CA store"
        return f"TLS to {where}: the broker's certificate is not trusted by {trust} ({text})"
    if "SSL" in text or "TLS" in text:
        return f"TLS to {where} failed: {text}"
    if isinstance(exc, OSError) and not isinstance(exc, ConnectionError) and exc.errno is None:
        return text  # ours: a file named in the message
    if "refused" in text.lower():
        return f"cannot reach the broker at {where}: nothing accepts connections there ({text})"
    return f"cannot reach the broker at {where}: {text}"


def _reason(exc: BaseException) -> str:
    if isinstance(exc, OSError) and exc.strerror:
        return exc.strerror
    return str(exc)


def _file_error(key: str, path: Path | None, exc: BaseException) -> OSError:
    return OSError(f"{key} {path}: {_reason(exc)}")
