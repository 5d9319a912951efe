"""The table's broker in one command: mosquitto's configuration, password file and ACL.

``dthc-bridge install-service --broker-config DIR`` (DIR: ``/etc/mosquitto/conf.d``, which
Debian's mosquitto.conf includes) writes

- ``DIR/dthc-bridge.conf`` (0644): ``allow_anonymous false``, the password file and the ACL
  (absolute paths), the listeners: plain MQTT on 127.0.0.1:1883 by default, and TLS when a
  certificate is given;
- ``DIR/dthc-bridge.passwd``: a user per role (``dthc-daemon``, ``dthc-sender``,
  ``dthc-panel``, ``dthc-dashboard``) in ``mosquitto_passwd``'s format;
- ``DIR/dthc-bridge.acl``: :func:`~dthc_bridge.mqtt.roles.render_acl`, the ACL's one source;
- ``/etc/dthc-bridge/broker/<role>.password``: each role's password, made once (192 random
  bits) and kept by every re-install; the daemon's root:dthc 0640, the others root:root 0600.

The password file and the ACL are root:mosquitto 0640: Debian's mosquitto 2 reads them
after dropping to its own user (root:root 0600 stops it: "Unable to open pwfile"); later
releases also warn about a world-readable file, or one its user does not own (and load it).
"""

from __future__ import annotations

import base64
import binascii
import hashlib
import hmac
import io
import re
import secrets
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

from pydantic import ValidationError

from ..mqtt.roles import Role, render_acl
from ..mqtt.settings import MqttSettings
from ..mqtt.topics import Topics
from .actions import Command, Context, MakeDir, Note, Step, WriteFile
from .render import DeployError

__all__ = [
    "ACL_NAME",
    "BROKER_GROUP",
    "BROKER_USERS",
    "CONF_NAME",
    "DEBIAN_INCLUDE_DIR",
    "PASSWD_NAME",
    "SECRETS_DIR",
    "BrokerFiles",
    "BrokerOptions",
    "BrokerTls",
    "Listener",
    "ReloadBroker",
    "broker_steps",
    "client_notes",
    "daemon_mqtt_keys",
    "example_files",
    "existing_config_notes",
    "hash_password",
    "password_path",
    "render_broker_conf",
    "render_passwd",
    "set_mqtt_keys",
    "validated_topics",
    "verify_password",
    "write_broker_files",
]

CONF_NAME = "dthc-bridge.conf"
PASSWD_NAME = "dthc-bridge.passwd"  # noqa: S105 - a file name
ACL_NAME = "dthc-bridge.acl"
DEBIAN_INCLUDE_DIR = "/etc/mosquitto/conf.d"
"""Where Debian's /etc/mosquitto/mosquitto.conf reads ``*.conf`` from (``include_dir``)."""
SECRETS_DIR = "/etc/dthc-bridge/broker"
BROKER_GROUP = "mosquitto"
"""The user and group Debian's mosquitto runs as."""
BROKER_UNIT = "mosquitto.service"

BROKER_USERS: Mapping[Role, str] = {
    Role.DAEMON: "dthc-daemon",
    Role.SENDER: "dthc-sender",
    Role.PANEL: "dthc-panel",
    Role.DASHBOARD: "dthc-dashboard",
}

PASSWORD_BYTES = 24
"""192 random bits per role's password."""
# mosquitto_passwd's own defaults (mosquitto 2.0: PW_DEFAULT_ITERATIONS, SALT_LEN, SHA-512).
# The passwords are random, so the iteration count guards nothing a brute force could use;
# the broker's default keeps a login as cheap as mosquitto_passwd's users expect.
PBKDF2_ITERATIONS = 101
SALT_BYTES = 12
HASH_BYTES = 64

_HOST = re.compile(r"[A-Za-z0-9._:-]+")
_PATH = re.compile(r"/\S*")


@dataclass(frozen=True)
class Listener:
    """One mosquitto listener: ``host`` None listens on every address."""

    port: int
    host: str | None = None

    @classmethod
    def parse(cls, text: str, option: str) -> Listener:
        """``HOST:PORT``, ``[IPV6]:PORT``, ``:PORT`` or ``PORT`` (every address)."""
        host, sep, port = text.strip().rpartition(":")
        if not sep:
            host = ""
        if host.startswith("[") and host.endswith("]"):
            host = host[1:-1]
        if not port.isdigit() or not 1 <= int(port) <= 65535:
            raise DeployError(f"{option} {text!r}: expected HOST:PORT, e.g. 127.0.0.1:1883")
        if host and _HOST.fullmatch(host) is None:
            raise DeployError(f"{option} {text!r}: {host!r} is not a host name or address")
        return cls(port=int(port), host=host or None)

    def conf_line(self) -> str:
        return f"listener {self.port}" + (f" {self.host}" if self.host else "")

    def overlaps(self, other: Listener) -> bool:
        """Whether both would bind the same port on some address."""
        return (self.port == other.port and None in (self.host, other.host)) or self == other


@dataclass(frozen=True)
class BrokerTls:
    """A TLS listener: the broker's certificate and key, and the CA clients are checked
    against (``require_client_cert``) and that clients verify the broker with."""

    cert_file: Path
    key_file: Path
    ca_file: Path
    listen: Listener = field(default_factory=lambda: Listener(8883))
    require_client_cert: bool = False


@dataclass(frozen=True)
class BrokerOptions:
    """What ``--broker-config`` and its companions ask for."""

    config_dir: str = DEBIAN_INCLUDE_DIR
    listen: Listener | None = field(default_factory=lambda: Listener(1883, "127.0.0.1"))
    tls: BrokerTls | None = None

    def __post_init__(self) -> None:
        _system_path(self.config_dir, "--broker-config")
        if self.listen is None and self.tls is None:
            raise DeployError("--broker-listen none needs a TLS listener (--broker-tls-cert ...)")
        if self.tls is not None:
            for option, path in (
                ("--broker-tls-cert", self.tls.cert_file),
                ("--broker-tls-key", self.tls.key_file),
                ("--broker-tls-ca", self.tls.ca_file),
            ):
                _system_path(str(path), option)
        if (
            self.listen is not None
            and self.tls is not None
            and self.listen.overlaps(self.tls.listen)
        ):
            raise DeployError(f"the plain and the TLS listener both use port {self.listen.port}")

    @property
    def conf_path(self) -> str:
        return f"{self.config_dir.rstrip('/')}/{CONF_NAME}"

    @property
    def passwd_path(self) -> str:
        return f"{self.config_dir.rstrip('/')}/{PASSWD_NAME}"

    @property
    def acl_path(self) -> str:
        return f"{self.config_dir.rstrip('/')}/{ACL_NAME}"


def password_path(role: Role) -> str:
    """Where ``role``'s password is kept: /etc/dthc-bridge/broker/<role>.password."""
    return f"{SECRETS_DIR}/{role.value}.password"


# ------------------------------------------------------------------------ the password file
# Written by hand: no well-kept Python library writes mosquitto's format, and running
# mosquitto_passwd -b would put each password on a command line, where ps shows it.


def hash_password(password: str, *, salt: bytes | None = None) -> str:
    """``$7$<iterations>$<base64 salt>$<base64 PBKDF2-HMAC-SHA512>``, mosquitto 2's format."""
    salt = secrets.token_bytes(SALT_BYTES) if salt is None else salt
    digest = hashlib.pbkdf2_hmac(
        "sha512", password.encode("utf-8"), salt, PBKDF2_ITERATIONS, HASH_BYTES
    )
    b64 = base64.b64encode
    return f"$7${PBKDF2_ITERATIONS}${b64(salt).decode()}${b64(digest).decode()}"


def verify_password(password: str, encoded: str) -> bool:
    """Whether ``encoded`` (a ``$7$`` or ``$6$`` entry of a password file) is ``password``'s."""
    parts = encoded.split("$")
    try:
        if len(parts) == 5 and parts[:2] == ["", "7"]:
            iterations, salt, expected = int(parts[2]), parts[3], parts[4]
            raw_salt, raw_expected = base64.b64decode(salt), base64.b64decode(expected)
            got = hashlib.pbkdf2_hmac(
                "sha512", password.encode("utf-8"), raw_salt, iterations, len(raw_expected)
            )
        elif len(parts) == 4 and parts[:2] == ["", "6"]:  # mosquitto 1.x: salted SHA-512
            raw_salt, raw_expected = base64.b64decode(parts[2]), base64.b64decode(parts[3])
            got = hashlib.sha512(password.encode("utf-8") + raw_salt).digest()
        else:
            return False
    except (ValueError, binascii.Error):
        return False
    return hmac.compare_digest(got, raw_expected)


def render_passwd(passwords: Mapping[Role, str], existing: str = "") -> str:
    """The password file for ``passwords``; an entry of ``existing`` that still matches its
    user's password is kept as it is (a fresh salt would rewrite the file every time)."""
    old: dict[str, str] = {}
    for line in existing.splitlines():
        user, sep, encoded = line.partition(":")
        if sep:
            old[user] = encoded.strip()
    lines = []
    for role, password in passwords.items():
        user = BROKER_USERS[role]
        kept = old.get(user)
        encoded = kept if kept and verify_password(password, kept) else hash_password(password)
        lines.append(f"{user}:{encoded}")
    return "\n".join(lines) + "\n"


# ----------------------------------------------------------------------------- the conf


def render_broker_conf(options: BrokerOptions, topics_root: str, *, root: Path = Path("/")) -> str:
    """mosquitto's configuration snippet. ``root``: a staging root our own files' paths are
    put under (a test starting mosquitto on staged files); the TLS files are named as given."""

    def ours(system_path: str) -> str:
        return str(root / system_path.lstrip("/"))

    lines = [
        f"# mosquitto configuration for dthc-bridge, table {topics_root}: written by",
        "# `dthc-bridge install-service --broker-config`, which rewrites it. Every client logs",
        "# in (password_file) and may do only what the ACL grants: only dthc-sender may send the",
        "# requests that light the torch or move Z. Listeners and options other than the",
        "# password and ACL files are only read when mosquitto starts (restart, not reload).",
        "per_listener_settings false",
        "allow_anonymous false",
        f"password_file {ours(options.passwd_path)}",
        f"acl_file {ours(options.acl_path)}",
    ]
    if options.listen is not None:
        where = "this PC only" if _loopback(options.listen.host) else "the network, unencrypted"
        lines += ["", f"# Plain MQTT: {where}.", options.listen.conf_line()]
    tls = options.tls
    if tls is not None:
        clients = (
            "every client shows a certificate signed by cafile, and logs in"
            if tls.require_client_cert
            else "clients check the broker's certificate against cafile, and log in"
        )
        lines += [
            "",
            f"# MQTT over TLS: {clients}.",
            tls.listen.conf_line(),
            f"cafile {tls.ca_file}",
            f"certfile {tls.cert_file}",
            f"keyfile {tls.key_file}",
        ]
        if tls.require_client_cert:
            lines.append("require_certificate true")
    return "\n".join(lines) + "\n"


def daemon_mqtt_keys(options: BrokerOptions) -> dict[str, str | int]:
    """The daemon's ``[mqtt]`` keys for this broker (TOML values), ``tls.ca_file`` when
    TLS is its only way in."""
    keys: dict[str, str | int] = {}
    listener = options.listen
    if listener is None and options.tls is not None:
        listener = options.tls.listen
        keys["tls.ca_file"] = str(options.tls.ca_file)
    if listener is not None:
        # A wildcard or loopback listener is reached at the example's "localhost".
        if listener.host is not None and not _loopback(listener.host) and listener.host != "::":
            keys["host"] = listener.host
        keys["port"] = listener.port
    keys["username"] = BROKER_USERS[Role.DAEMON]
    keys["password_file"] = password_path(Role.DAEMON)
    return keys


def set_mqtt_keys(config: str, keys: Mapping[str, str | int]) -> str:
    """``config`` (the example configuration's text) with these ``[mqtt]`` keys set: an
    existing line replaced, a missing one added at the end of the section; ``tls.KEY`` go
    to an ``[mqtt.tls]`` table after it. DeployError if there is no ``[mqtt]``."""
    lines = config.splitlines()
    try:
        start = lines.index("[mqtt]")
    except ValueError:
        raise DeployError("the example configuration has no [mqtt] section") from None
    end = next((i for i in range(start + 1, len(lines)) if lines[i].startswith("[")), len(lines))
    while end > start + 1 and not lines[end - 1].strip():
        end -= 1
    section = lines[start + 1 : end]
    tls = {key[4:]: value for key, value in keys.items() if key.startswith("tls.")}
    for key, value in keys.items():
        if key.startswith("tls."):
            continue
        line = f"{key} = {_toml_value(value)}"
        at = next((i for i, old in enumerate(section) if re.match(rf"{key}\s*=", old)), None)
        if at is None:
            section.append(line)
        else:
            section[at] = line
    if tls:
        section += ["", "[mqtt.tls]", *(f"{k} = {_toml_value(v)}" for k, v in tls.items())]
    text = "\n".join([*lines[: start + 1], *section, *lines[end:]]) + "\n"
    tomllib.loads(text)  # a broken edit fails here, not in the daemon
    return text


def _toml_value(value: str | int) -> str:
    if isinstance(value, int):
        return str(value)
    return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'


# ---------------------------------------------------------------------------- the steps


@dataclass(frozen=True)
class ReloadBroker:
    """Restart mosquitto when its configuration changed (listeners are read at start only),
    reload it (SIGHUP) when only the password file or the ACL did, else leave it alone."""

    conf: str
    reloadable: tuple[str, ...]
    installed: bool

    def apply(self, ctx: Context) -> None:
        if ctx.changed.intersection((self.conf,)):
            verb = "restart"
        elif ctx.changed.intersection(self.reloadable):
            verb = "reload"
        else:
            ctx.report("skip", f"systemctl reload {BROKER_UNIT} (nothing changed)")
            return
        if not self.installed and ctx.live:
            text = f"mosquitto is not installed: apt-get install mosquitto (it reads {self.conf})"
            ctx.report("note", text)
            return
        Command(("systemctl", verb, BROKER_UNIT), "systemd").apply(ctx)


def broker_steps(
    options: BrokerOptions,
    *,
    root: Path,
    topics: Topics,
    service_group: str,
    broker_group_exists: bool,
    broker_installed: bool,
) -> list[Step]:
    """The broker's files and mosquitto's reload. Reads the passwords already under
    ``root`` (kept) and makes the missing ones, so it is only pure for a given root."""
    passwords: dict[Role, str] = {}
    secret_texts: dict[Role, str] = {}
    for role in BROKER_USERS:
        path = root / password_path(role).lstrip("/")
        text = _read(path)
        if text is not None and not text.strip():
            raise DeployError(f"{password_path(role)} is empty: remove it to have one made")
        if text is None:
            text = secrets.token_urlsafe(PASSWORD_BYTES) + "\n"
        passwords[role] = text.strip()
        secret_texts[role] = text
    passwd = render_passwd(passwords, _read(root / options.passwd_path.lstrip("/")) or "")
    acl = render_acl(topics.root, dict(BROKER_USERS))
    # Without mosquitto's group only root could read them, and Debian's mosquitto could not.
    broker_mode, broker_group = (0o640, BROKER_GROUP) if broker_group_exists else (0o600, None)
    steps: list[Step] = [MakeDir(SECRETS_DIR, 0o750, group=service_group)]
    for role, text in secret_texts.items():
        if role is Role.DAEMON:
            steps.append(WriteFile(password_path(role), text, 0o640, group=service_group))
        else:
            steps.append(WriteFile(password_path(role), text, 0o600))
    steps += [
        WriteFile(options.conf_path, render_broker_conf(options, topics.root), 0o644),
        WriteFile(options.passwd_path, passwd, broker_mode, group=broker_group),
        WriteFile(options.acl_path, acl, broker_mode, group=broker_group),
    ]
    if not broker_group_exists:
        steps.append(
            Note(
                f"no {BROKER_GROUP} group: {options.passwd_path} and {options.acl_path} are "
                "root-only; give them to the broker's user (chgrp, 0640)"
            )
        )
    if options.config_dir.rstrip("/") != DEBIAN_INCLUDE_DIR:
        steps.append(
            Note(f"mosquitto must read {options.conf_path}: include_dir {options.config_dir}")
        )
    steps.append(
        ReloadBroker(
            options.conf_path, (options.passwd_path, options.acl_path), installed=broker_installed
        )
    )
    return steps


def client_notes(options: BrokerOptions) -> list[Step]:
    """How the sender and the panel get their logins (printed after an install)."""
    tls = options.tls
    notes: list[Step] = []
    for role, command in ((Role.SENDER, "send"), (Role.PANEL, "panel")):
        copy = f"~/.config/dthc-bridge/{role.value}.password"
        notes.append(
            Note(
                f"{role.value}'s login: mkdir -p ~/.config/dthc-bridge && sudo install -m 600 "
                f'-o "$USER" {password_path(role)} {copy}; dthc-bridge {command} then logs '
                f"in as {BROKER_USERS[role]} with it by itself (or: --broker-user "
                f"{BROKER_USERS[role]} --broker-password-file FILE)"
            )
        )
    if tls is not None:
        notes.append(
            Note(
                f"other PCs: --broker mqtts://THIS-HOST:{tls.listen.port} --broker-ca-file "
                f"(a copy of {tls.ca_file})"
                + (" --broker-cert-file --broker-key-file" if tls.require_client_cert else "")
            )
        )
    return notes


def existing_config_notes(
    config_path: str, config: Mapping[str, object], options: BrokerOptions
) -> list[Step]:
    """Notes naming the ``[mqtt]`` lines a kept configuration lacks to log in."""
    mqtt = config.get("mqtt")
    mqtt = mqtt if isinstance(mqtt, dict) else {}
    missing = []
    for key, value in daemon_mqtt_keys(options).items():
        table, name = (mqtt.get("tls") or {}, key[4:]) if key.startswith("tls.") else (mqtt, key)
        default = None if key.startswith("tls.") else MqttSettings.model_fields[name].default
        if not isinstance(table, dict) or table.get(name, default) != value:
            missing.append((key, value))
    if not missing:
        return []
    plain = ", ".join(f"{k} = {_toml_value(v)}" for k, v in missing if not k.startswith("tls."))
    tls = ", ".join(f"{k[4:]} = {_toml_value(v)}" for k, v in missing if k.startswith("tls."))
    notes: list[Step] = [Note(f"{config_path} is kept: set in its [mqtt] section: {plain}")]
    if tls:
        notes.append(Note(f"and in its [mqtt.tls] section: {tls}"))
    notes.append(Note("then: systemctl restart dthc-bridge (never during a cut)"))
    return notes


# ------------------------------------------------------------------------ the examples


def example_files() -> dict[str, str]:
    """systemd/'s broker examples for the default topics and users, the conf with the
    default plain listener and a TLS one. A test holds the committed files to these."""
    root = Topics.for_board("dthc", "table1").root
    certs = Path("/etc/mosquitto/certs")
    tls = BrokerTls(certs / "broker.crt", certs / "broker.key", certs / "ca.crt")
    return {
        "mosquitto-dthc.conf.example": render_broker_conf(BrokerOptions(tls=tls), root),
        "mosquitto-acl.example": render_acl(root, dict(BROKER_USERS)),
    }


# ------------------------------------------------------------------------- for the tests


@dataclass(frozen=True)
class BrokerFiles:
    """The broker's files as written under a staging ``root``."""

    root: Path
    options: BrokerOptions
    topics_root: str
    conf: Path
    passwd: Path
    acl: Path
    passwords: dict[Role, Path]
    users: Mapping[Role, str] = field(default_factory=lambda: dict(BROKER_USERS))

    def conf_under_root(self) -> str:
        """The conf as written, with the password file's and the ACL's paths under the
        staging root: what a mosquitto started on the staged files reads."""
        return render_broker_conf(self.options, self.topics_root, root=self.root)

    def password(self, role: Role) -> str:
        return self.passwords[role].read_text().strip()


def write_broker_files(
    root: Path,
    options: BrokerOptions | None = None,
    *,
    base_topic: str = "dthc",
    board_id: str = "table1",
    broker_group_exists: bool = False,
) -> BrokerFiles:
    """Write the broker's files under the staging ``root`` exactly as ``install-service
    --root ROOT --broker-config ...`` does (passwords kept if already there)."""
    options = BrokerOptions() if options is None else options
    topics = validated_topics(base_topic, board_id)
    ctx = Context(root=root, live=False, dry_run=False, out=io.StringIO())
    for step in broker_steps(
        options,
        root=root,
        topics=topics,
        service_group="dthc",
        broker_group_exists=broker_group_exists,
        broker_installed=False,
    ):
        step.apply(ctx)
    return BrokerFiles(
        root=root,
        options=options,
        topics_root=topics.root,
        conf=ctx.path(options.conf_path),
        passwd=ctx.path(options.passwd_path),
        acl=ctx.path(options.acl_path),
        passwords={role: ctx.path(password_path(role)) for role in BROKER_USERS},
    )


def validated_topics(base_topic: str, board_id: str) -> Topics:
    """The board's topics; DeployError naming ``--base-topic``/``--board-id`` if the daemon
    would refuse them (the daemon's own model decides) or the ACL could not hold them."""
    try:
        MqttSettings(base_topic=base_topic, board_id=board_id)
    except ValidationError as exc:
        error = exc.errors()[0]
        option = "--base-topic" if error["loc"] == ("base_topic",) else "--board-id"
        value = base_topic if option == "--base-topic" else board_id
        raise DeployError(f"{option} {value!r}: {error['msg']}") from None
    if any(c.isspace() for c in base_topic):
        raise DeployError(f"--base-topic {base_topic!r}: no spaces (mosquitto's ACL lines)")
    return Topics.for_board(base_topic, board_id)


def _loopback(host: str | None) -> bool:
    return host is not None and (host in {"localhost", "::1"} or host.startswith("127."))


def _system_path(text: str, option: str) -> str:
    if _PATH.fullmatch(text) is None:
        raise DeployError(f"{option} {text!r}: must be an absolute path without spaces")
    return text


def _read(path: Path) -> str | None:
    try:
        return path.read_text(encoding="utf-8")
    except FileNotFoundError:
        return None
    except OSError as exc:
        raise DeployError(f"{path}: {exc.strerror}") from None
