"""The broker options every tool takes, into the daemon's own broker model.

``--broker mqtt://[USER@]HOST[:PORT]`` (``mqtts://`` for TLS), ``--broker-user``,
``--broker-password-file`` or the ``DTHC_BROKER_PASSWORD`` environment variable (never a
password on the command line: ``ps`` shows it to every user), ``--broker-ca-file``,
``--broker-cert-file`` and ``--broker-key-file``, ``--protocol``; with no login given,
the role's password copied where the installer says (``~/.config/dthc-bridge/<role>.password``).
They build a
:class:`dthc_bridge.mqtt.broker.BrokerSettings`, the model the daemon's ``[mqtt]`` extends,
so the sender, the panel and the daemon log in and verify the broker the same way.
"""

from __future__ import annotations

import argparse
import asyncio
import os
import sys
from collections.abc import Coroutine, Mapping, Sequence
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

import aiomqtt
from pydantic import SecretStr, ValidationError

from dthc_bridge.mqtt.broker import BrokerSettings, MqttTls, describe_broker_error

__all__ = [
    "PASSWORD_ENV",
    "BrokerOptionError",
    "add_broker_arguments",
    "broker_from_args",
    "login_file",
    "parse_with_broker",
    "run_with_broker",
]

PASSWORD_ENV = "DTHC_BROKER_PASSWORD"  # noqa: S105 - the variable's name, not a password
_PORTS = {"mqtt": 1883, "mqtts": 8883}


class BrokerOptionError(ValueError):
    """A broker option that cannot be used; the message names the option and the value."""


def login_file(role: str, environ: Mapping[str, str]) -> Path:
    """Where ``role``'s broker password is looked for when none is given: the copy the
    installer tells the owner to make (``~/.config/dthc-bridge/<role>.password``)."""
    config = environ.get("XDG_CONFIG_HOME") or str(Path(environ.get("HOME", "~")) / ".config")
    return Path(config).expanduser() / "dthc-bridge" / f"{role}.password"


def add_broker_arguments(parser: argparse.ArgumentParser, *, role: str = "sender") -> None:
    """The broker options; ``role`` names the login used when none is given: user
    ``dthc-<role>`` with the password in :func:`login_file`, if that file exists."""
    parser.set_defaults(broker_role=role)
    group = parser.add_argument_group(
        "broker", f"the MQTT broker and this tool's login (password: a file or {PASSWORD_ENV})"
    )
    group.add_argument(
        "--broker", default="mqtt://localhost:1883",
        help="mqtt://[USER@]HOST[:PORT], or mqtts://... for TLS (default port 1883 / 8883)",
    )  # fmt: skip
    group.add_argument("--broker-user", metavar="NAME", help="the user name (or USER@ in --broker)")
    group.add_argument(
        "--broker-password-file", type=Path, metavar="FILE",
        help=f"a file holding the password (owner-only); or the {PASSWORD_ENV} variable",
    )  # fmt: skip
    group.add_argument(
        "--broker-ca-file", type=Path, metavar="FILE",
        help="the CA that signed the broker's certificate (implies TLS)",
    )  # fmt: skip
    group.add_argument("--broker-cert-file", type=Path, metavar="FILE", help="client certificate")
    group.add_argument("--broker-key-file", type=Path, metavar="FILE", help="its private key")
    group.add_argument("--protocol", default="5", choices=["5", "3.1.1"], help="MQTT version")


def parse_with_broker(
    parser: argparse.ArgumentParser, argv: Sequence[str] | None
) -> argparse.Namespace:
    """``parser``'s arguments (``sys.argv`` without ``argv``) with ``broker_settings`` built
    from the broker options; a bad one is argparse's usage error naming it (exit 2)."""
    args = parser.parse_args(sys.argv[1:] if argv is None else argv)
    try:
        args.broker_settings = broker_from_args(args)
    except BrokerOptionError as exc:
        parser.error(str(exc))
    return args


def broker_from_args(
    args: argparse.Namespace, environ: Mapping[str, str] | None = None
) -> BrokerSettings:
    """The broker settings the options describe; BrokerOptionError names a bad one."""
    environ = os.environ if environ is None else environ
    url = str(args.broker)
    parts = urlsplit(url)
    if parts.scheme not in _PORTS or not parts.hostname or parts.path not in ("", "/"):
        raise BrokerOptionError(
            f"--broker {url!r}: expected mqtt://[USER@]HOST[:PORT] or mqtts://[USER@]HOST[:PORT]"
        )
    if parts.password is not None:
        raise BrokerOptionError(
            f"--broker: a password in the URL is visible to every user in `ps`; use "
            f"--broker-password-file FILE or the {PASSWORD_ENV} environment variable"
        )
    try:
        port = parts.port or _PORTS[parts.scheme]
    except ValueError:
        raise BrokerOptionError(f"--broker {url!r}: the port is not a number 1-65535") from None
    username = args.broker_user or parts.username
    password = environ.get(PASSWORD_ENV) or None
    password_file = args.broker_password_file
    if password is not None and password_file is not None:
        raise BrokerOptionError(
            f"--broker-password-file and {PASSWORD_ENV} are both given: keep one"
        )
    role = getattr(args, "broker_role", "sender")
    default_file = login_file(role, environ)
    if username is None and password is None and password_file is None and default_file.is_file():
        # The installer's broker has a user per role; its note says to copy the password
        # here, so an owner who did runs the tools with no login options at all.
        username, password_file = f"dthc-{role}", default_file
    tls = None
    certificate = args.broker_cert_file or args.broker_key_file
    if parts.scheme == "mqtts" or args.broker_ca_file is not None or certificate is not None:
        for option, path in (
            ("--broker-ca-file", args.broker_ca_file),
            ("--broker-cert-file", args.broker_cert_file),
            ("--broker-key-file", args.broker_key_file),
        ):
            if path is not None and not path.is_file():
                raise BrokerOptionError(f"{option} {path}: no such file")
        try:
            tls = MqttTls(
                ca_file=args.broker_ca_file,
                cert_file=args.broker_cert_file,
                key_file=args.broker_key_file,
            )
        except ValidationError:
            raise BrokerOptionError(
                "--broker-cert-file and --broker-key-file go together"
            ) from None
    try:
        return BrokerSettings(
            host=parts.hostname,
            port=port,
            username=username,
            password=SecretStr(password) if password is not None else None,
            password_file=password_file,
            tls=tls,
            protocol=args.protocol,
        )
    except ValidationError as exc:
        problems = "; ".join(f"{'.'.join(map(str, e['loc']))}: {e['msg']}" for e in exc.errors())
        raise BrokerOptionError(f"--broker {url!r}: {problems}") from None


def run_with_broker(
    prog: str,
    args: argparse.Namespace,
    work: Coroutine[Any, Any, int],
    *failures: type[Exception],
) -> int:
    """``work`` run to its end, its exit status; the broker failing (named as the broker
    settings would have it), or one of ``failures`` (the tool's own: a file, a port, its
    grbl), said on one line naming ``prog``: 2."""
    try:
        return asyncio.run(work)
    except aiomqtt.MqttError as exc:
        print(f"{prog}: {describe_broker_error(exc, args.broker_settings)}", file=sys.stderr)
        return 2
    except failures as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        return 2
