"""``dthc-bridge install-service`` and ``uninstall-service``: deploy the daemon on a shop PC.

Installing creates the system user and group (``dthc``, also in ``dialout``), writes the
unit to /etc/systemd/system, the udev rules to /etc/udev/rules.d and the example
configuration to /etc/dthc-bridge/config.toml (only if there is none), reloads udev and
systemd, and enables and starts the service. Every step is idempotent, so re-running the
installer (after an upgrade, or with the board's real ``--serial``) is the way to update.

With ``--broker-config DIR`` it also writes the table's mosquitto configuration, password
file and ACL, and each role's password (``broker.py``), so a broker that lets only the
sender light the torch is the same one command.

``--dry-run`` prints every step without doing it; ``--root DIR`` writes the files under a
staging directory and runs no command. Uninstalling removes the unit and the rules and
keeps the configuration, the state and the user unless ``--purge`` is given.
"""

from __future__ import annotations

import argparse
import grp
import os
import pwd
import shutil
import sys
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import TextIO

import dthc_bridge

from ..mqtt.roles import Role
from .actions import (
    Command,
    Context,
    MakeDir,
    Note,
    RemoveFile,
    RemoveTree,
    Runner,
    StartService,
    Step,
    WriteFile,
    run_command,
)
from .broker import (
    BROKER_GROUP,
    BROKER_USERS,
    DEBIAN_INCLUDE_DIR,
    BrokerOptions,
    BrokerTls,
    Listener,
    broker_steps,
    client_notes,
    daemon_mqtt_keys,
    existing_config_notes,
    password_path,
    set_mqtt_keys,
    validated_topics,
)
from .render import (
    BOARD_SYMLINK,
    DEFAULT_GRBL_LISTEN,
    DEFAULT_PID,
    DEFAULT_VID,
    BoardIds,
    DeployError,
    example_config,
    render_port_unit,
    render_udev_rules,
    render_unit,
    validate_account_name,
)

__all__ = [
    "CONFIG_DIR",
    "CONFIG_PATH",
    "DEFAULT_USER",
    "PORT_UNIT_NAME",
    "PORT_UNIT_PATH",
    "RULES_PATH",
    "STATE_DIR",
    "UNIT_NAME",
    "UNIT_PATH",
    "HostState",
    "InstallOptions",
    "UninstallOptions",
    "add_install_arguments",
    "add_uninstall_arguments",
    "install_service",
    "plan_install",
    "plan_uninstall",
    "run_install",
    "run_uninstall",
    "uninstall_service",
]

UNIT_NAME = "dthc-bridge.service"
UNIT_PATH = f"/etc/systemd/system/{UNIT_NAME}"
PORT_UNIT_NAME = "dthc-grbl-port.service"
PORT_UNIT_PATH = f"/etc/systemd/system/{PORT_UNIT_NAME}"
RULES_PATH = "/etc/udev/rules.d/99-dthc.rules"
CONFIG_DIR = "/etc/dthc-bridge"
CONFIG_PATH = f"{CONFIG_DIR}/config.toml"
STATE_DIR = "/var/lib/dthc-bridge"
DEFAULT_USER = "dthc"
SERIAL_GROUP = "dialout"
"""Debian's owner group of /dev/ttyACM* and /dev/ttyUSB*."""

# Compared against, never written to.
HIDDEN_FROM_SERVICE = ("/home", "/root", "/run/user", "/tmp", "/var/tmp")  # noqa: S108
"""Trees the unit's ProtectHome=yes and PrivateTmp=yes hide from the daemon."""

UDEV_SUBSYSTEMS = ("tty", "usb", "usb-serial")
BROKER_EXECUTABLE = "/usr/sbin/mosquitto"


def default_bin_dir() -> Path:
    """The bin directory of the environment this installer runs from."""
    return Path(sys.prefix) / "bin"


@dataclass(frozen=True)
class InstallOptions:
    root: Path = Path("/")
    dry_run: bool = False
    start: bool = True
    user: str = DEFAULT_USER
    bin_dir: Path = field(default_factory=default_bin_dir)
    board: BoardIds = field(default_factory=BoardIds)
    broker: BrokerOptions | None = None
    """``--broker-config``: write the broker's files too."""
    base_topic: str | None = None
    """The topics' base; None: the existing configuration's, else "dthc"."""
    board_id: str | None = None
    """None: the existing configuration's, else "table1"."""
    grbl: str | None = None
    """``--grbl``: the table's grbl; the grbl port's unit is installed in front of it."""
    grbl_listen: str = DEFAULT_GRBL_LISTEN
    """Where a sender opens the grbl port."""


@dataclass(frozen=True)
class UninstallOptions:
    root: Path = Path("/")
    dry_run: bool = False
    purge: bool = False
    user: str = DEFAULT_USER


@dataclass(frozen=True)
class HostState:
    """What the installer needs to know about the machine it runs on."""

    user_exists: bool
    group_exists: bool
    serial_group_exists: bool
    user_in_serial_group: bool
    systemd_booted: bool
    has_udevadm: bool
    broker_group_exists: bool = False
    """mosquitto's group, which must read the broker's password file and ACL."""
    broker_installed: bool = False

    @classmethod
    def probe(cls, user: str) -> HostState:
        serial_members: list[str] | None
        try:
            serial_members = grp.getgrnam(SERIAL_GROUP).gr_mem
        except KeyError:
            serial_members = None
        return cls(
            user_exists=_user_exists(user),
            group_exists=_group_exists(user),
            serial_group_exists=serial_members is not None,
            user_in_serial_group=serial_members is not None and user in serial_members,
            # sd_booted(3): this directory exists only when systemd is PID 1.
            systemd_booted=Path("/run/systemd/system").is_dir(),
            has_udevadm=shutil.which("udevadm") is not None,
            broker_group_exists=_group_exists(BROKER_GROUP),
            broker_installed=Path(BROKER_EXECUTABLE).exists(),
        )


# ---------------------------------------------------------------------------- install


def plan_install(options: InstallOptions, host: HostState) -> list[Step]:
    """Every step of an installation, in order. Nothing is done here; what is read: the
    configuration and the broker's passwords already under the root (both are kept)."""
    user = validate_account_name(options.user)
    group = user
    unit = render_unit(bin_dir=options.bin_dir, user=user, group=group)
    rules = render_udev_rules(options.board, group=group)
    existing = _read_config(options.root)
    base_topic, board_id = _topics_of(options, existing)
    topics = validated_topics(base_topic, board_id)
    config = example_config()
    config_keys: dict[str, str | int] = {}
    if options.base_topic is not None:
        config_keys["base_topic"] = options.base_topic
    if options.board_id is not None:
        config_keys["board_id"] = options.board_id
    if options.broker is not None:
        config_keys.update(daemon_mqtt_keys(options.broker))
    if config_keys:
        config = set_mqtt_keys(config, config_keys)
    steps: list[Step] = [
        *_account_steps(user, host),
        WriteFile(UNIT_PATH, unit, 0o644),
        WriteFile(RULES_PATH, rules, 0o644),
        MakeDir(CONFIG_DIR, 0o750, group=group),
        WriteFile(CONFIG_PATH, config, 0o640, group=group, replace=False),
    ]
    if options.broker is not None:
        if existing is not None:
            steps += existing_config_notes(CONFIG_PATH, existing, options.broker)
        steps += broker_steps(
            options.broker,
            root=options.root,
            topics=topics,
            service_group=group,
            broker_group_exists=host.broker_group_exists,
            broker_installed=host.broker_installed,
        )
    units = [(UNIT_NAME, UNIT_PATH)]
    if options.grbl is not None:
        port_unit = render_port_unit(
            bin_dir=options.bin_dir, user=user, group=group, grbl=options.grbl,
            listen=options.grbl_listen, base_topic=base_topic, board_id=board_id,
            broker_args=_sender_login(options.broker),
        )  # fmt: skip
        steps.append(WriteFile(PORT_UNIT_PATH, port_unit, 0o644))
        units.append((PORT_UNIT_NAME, PORT_UNIT_PATH))
    steps += [
        Command(("udevadm", "control", "--reload"), "udev", if_changed=(RULES_PATH,)),
        Command(
            ("udevadm", "trigger", "--action=change", *_subsystem_matches()),
            "udev",
            if_changed=(RULES_PATH,),
        ),
        Command(("systemctl", "daemon-reload"), "systemd", if_changed=tuple(p for _, p in units)),
        *(Command(("systemctl", "enable", name), "systemd") for name, _ in units),
    ]
    for name, path in units:
        if options.start:
            steps.append(StartService(name, restart_if_changed=(path,)))
        else:
            steps.append(Note(f"not started (--no-start): systemctl start {name}"))
    if options.grbl is not None:
        steps.append(
            Note(
                f"grbl senders: open {options.grbl_listen} as a grbl serial port (CNCjs: a "
                '"ports" entry in ~/.cncrc; UGS, bCNC: type the path); the user running the '
                "sender must be in group dialout"
            )
        )
    if options.broker is not None:
        steps += client_notes(options.broker)
    return steps


def _sender_login(broker: BrokerOptions | None) -> tuple[str, ...]:
    """The grbl port's broker options: the sender role's login on the broker this install
    configured (the port lights the torch as a sender does); none for a broker it did not
    configure (the port's default, mqtt://localhost:1883, or a drop-in)."""
    if broker is None:
        return ()
    keys = daemon_mqtt_keys(broker)
    scheme = "mqtts" if "tls.ca_file" in keys else "mqtt"
    host = str(keys.get("host", "localhost"))
    host = f"[{host}]" if ":" in host else host
    port = keys.get("port", 8883 if scheme == "mqtts" else 1883)
    args: tuple[str, ...] = (
        "--broker", f"{scheme}://{BROKER_USERS[Role.SENDER]}@{host}:{port}",
        "--broker-password-file", password_path(Role.SENDER),
    )  # fmt: skip
    if "tls.ca_file" in keys:
        args += ("--broker-ca-file", str(keys["tls.ca_file"]))
    return args


def _read_config(root: Path) -> dict[str, object] | None:
    """The configuration already installed under ``root`` (None: there is none)."""
    path = root / CONFIG_PATH.lstrip("/")
    try:
        return tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        return None
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise DeployError(f"{CONFIG_PATH}: cannot be read ({exc})") from None


def _topics_of(options: InstallOptions, existing: dict[str, object] | None) -> tuple[str, str]:
    """(base_topic, board_id): the kept configuration's, which the daemon uses, so the ACL
    names the daemon's own topics; an option that disagrees with it is an error."""
    mqtt = existing.get("mqtt") if existing is not None else None
    mqtt = mqtt if isinstance(mqtt, dict) else {}
    chosen = []
    for key, option, given, default in (
        ("base_topic", "--base-topic", options.base_topic, "dthc"),
        ("board_id", "--board-id", options.board_id, "table1"),
    ):
        current = mqtt.get(key) if existing is not None else None
        if existing is not None and current is None:
            current = default  # the daemon's default
        if given is not None and current is not None and given != current:
            raise DeployError(
                f"{option} {given!r}, but {CONFIG_PATH} (kept) has {key} = {current!r}: the "
                f"ACL must name the daemon's topics; edit the configuration or drop {option}"
            )
        chosen.append(str(given or current or default))
    return chosen[0], chosen[1]


def _subsystem_matches() -> tuple[str, ...]:
    return tuple(f"--subsystem-match={name}" for name in UDEV_SUBSYSTEMS)


def _account_steps(user: str, host: HostState) -> list[Step]:
    common = (
        "--system", "--no-create-home", "--home-dir", STATE_DIR,
        "--shell", "/usr/sbin/nologin", "--comment", "dthc-bridge daemon",
    )  # fmt: skip
    groups = ("--groups", SERIAL_GROUP) if host.serial_group_exists else ()
    if host.user_exists:
        steps: list[Step] = [Note(f"user {user} exists", status="exists")]
        if not host.group_exists:
            steps.append(Command(("groupadd", "--system", user), "host"))
        if host.serial_group_exists and not host.user_in_serial_group:
            steps.append(Command(("usermod", "--append", "--groups", SERIAL_GROUP, user), "host"))
        return steps
    primary = ("--gid", user) if host.group_exists else ("--user-group",)
    return [Command(("useradd", *common, *primary, *groups, user), "host")]


def _preflight(options: InstallOptions) -> tuple[list[str], list[str]]:
    """(problems, notes): problems stop a live install and are warnings otherwise."""
    problems: list[str] = []
    notes: list[str] = []
    executable = options.bin_dir / "dthc-bridge"
    if not os.access(executable, os.X_OK):
        problems.append(
            f"{executable} is missing or not executable: run the installer with the "
            "environment's own dthc-bridge, or pass --bin-dir"
        )
    interpreter = options.bin_dir / "python3"
    looked_at = [("the daemon's environment", options.bin_dir)]
    if interpreter.exists():
        looked_at.append(("its Python interpreter", interpreter.resolve()))
    looked_at.append(("the dthc_bridge package", Path(dthc_bridge.__file__).resolve().parent))
    for what, path in looked_at:
        hidden = _hidden_prefix(path)
        if hidden is not None:
            problems.append(
                f"{what} is under {hidden} ({path}), which the service cannot see "
                "(ProtectHome=yes, PrivateTmp=yes): create the environment from the system "
                "Python under /opt, e.g. /usr/bin/python3 -m venv /opt/dthc-bridge/.venv"
            )
    board = options.board
    if (board.vid, board.pid) == (DEFAULT_VID, DEFAULT_PID):
        notes.append(
            f"board ids {board.vid}:{board.pid} are the placeholder: pass --vid/--pid "
            "(see lsusb) when the board's firmware reports its own"
        )
    chip = board.bridge_chip
    if chip is not None and board.serial is None:
        notes.append(
            f"{board.vid}:{board.pid} is a generic {chip} bridge: without --serial, "
            f"/dev/{BOARD_SYMLINK} and the service group go to every such adapter on this PC"
        )
    return problems, notes


def install_service(
    options: InstallOptions,
    *,
    out: TextIO | None = None,
    err: TextIO | None = None,
    host: HostState | None = None,
    runner: Runner = run_command,
) -> int:
    """Install (or update) the service; 0 on success, 1 with a message on ``err``."""
    out = sys.stdout if out is None else out
    err = sys.stderr if err is None else err
    try:
        live = options.root == Path("/")
        _require_root(live=live, dry_run=options.dry_run, command="install-service")
        problems, notes = _preflight(options)
        if problems and live and not options.dry_run:
            raise DeployError("\n  ".join(problems))
        host = HostState.probe(options.user) if host is None else host
        steps = plan_install(options, host)
        out.write(_heading("install-service", options.root, options.dry_run))
        for text in problems:
            out.write(f"  warning: {text}\n")
        for text in notes:
            out.write(f"  note: {text}\n")
        _apply(steps, root=options.root, dry_run=options.dry_run, out=out, host=host, runner=runner)
    except DeployError as exc:
        err.write(f"dthc-bridge install-service: error: {exc}\n")
        return 1
    if live and not options.dry_run:
        out.write(
            f"done. Edit {CONFIG_PATH}, then: systemctl restart dthc-bridge; "
            "systemctl status dthc-bridge; journalctl -u dthc-bridge -f\n"
        )
    return 0


# -------------------------------------------------------------------------- uninstall


def plan_uninstall(options: UninstallOptions, host: HostState) -> list[Step]:
    """Every step of an uninstallation, in order (pure)."""
    user = validate_account_name(options.user)
    steps: list[Step] = [
        Command(
            ("systemctl", "disable", "--now", PORT_UNIT_NAME), "systemd", if_exists=PORT_UNIT_PATH
        ),
        RemoveFile(PORT_UNIT_PATH),
        Command(("systemctl", "disable", "--now", UNIT_NAME), "systemd", if_exists=UNIT_PATH),
        RemoveFile(UNIT_PATH),
        RemoveFile(RULES_PATH),
        Command(("systemctl", "daemon-reload"), "systemd", if_changed=(UNIT_PATH, PORT_UNIT_PATH)),
        Command(("udevadm", "control", "--reload"), "udev", if_changed=(RULES_PATH,)),
    ]
    if not options.purge:
        steps.append(Note(f"kept {CONFIG_DIR}, {STATE_DIR} and user {user} (--purge removes them)"))
        return steps
    steps += [RemoveTree(CONFIG_DIR), RemoveTree(STATE_DIR)]
    if host.user_exists:
        steps.append(Command(("userdel", user), "host"))
    # userdel removes a user's own group itself; whatever is left goes here.
    steps.append(Command(("groupdel", user), "host", when=lambda: _group_exists(user)))
    return steps


def uninstall_service(
    options: UninstallOptions,
    *,
    out: TextIO | None = None,
    err: TextIO | None = None,
    host: HostState | None = None,
    runner: Runner = run_command,
) -> int:
    """Remove the service; 0 on success, 1 with a message on ``err``."""
    out = sys.stdout if out is None else out
    err = sys.stderr if err is None else err
    try:
        live = options.root == Path("/")
        _require_root(live=live, dry_run=options.dry_run, command="uninstall-service")
        host = HostState.probe(options.user) if host is None else host
        steps = plan_uninstall(options, host)
        out.write(_heading("uninstall-service", options.root, options.dry_run))
        _apply(steps, root=options.root, dry_run=options.dry_run, out=out, host=host, runner=runner)
    except DeployError as exc:
        err.write(f"dthc-bridge uninstall-service: error: {exc}\n")
        return 1
    return 0


# ---------------------------------------------------------------------------- argparse


def add_install_arguments(parser: argparse.ArgumentParser) -> None:
    """The ``install-service`` options."""
    _add_common_arguments(parser)
    parser.add_argument(
        "--no-start", action="store_true", help="enable the service but do not (re)start it"
    )
    parser.add_argument(
        "--bin-dir",
        type=Path,
        default=None,
        help="bin directory holding the dthc-bridge executable (default: this environment's)",
    )
    parser.add_argument(
        "--vid", default=DEFAULT_VID, help=f"board USB vendor id, hex (default {DEFAULT_VID})"
    )
    parser.add_argument(
        "--pid", default=DEFAULT_PID, help=f"board USB product id, hex (default {DEFAULT_PID})"
    )
    parser.add_argument(
        "--serial",
        default=None,
        help=f"board USB serial number: /dev/{BOARD_SYMLINK} then names only that board",
    )
    parser.add_argument(
        "--base-topic",
        default=None,
        help='topics base of a new config and the ACL (default: the config\'s, else "dthc")',
    )
    parser.add_argument(
        "--board-id",
        default=None,
        help="this table's id in its topics (default: the config's, else \"table1\")",
    )
    parser.add_argument(
        "--grbl", default=None, metavar="DEVICE",
        help="the table's grbl (/dev/ttyUSB0, socket://HOST:PORT): also install the grbl port "
        "(dthc-grbl-port.service), so the owner's grbl sender keeps working",
    )  # fmt: skip
    parser.add_argument(
        "--grbl-listen", default=DEFAULT_GRBL_LISTEN, metavar="PATH",
        help=f"where a sender opens the grbl port (default {DEFAULT_GRBL_LISTEN})",
    )  # fmt: skip
    broker = parser.add_argument_group(
        "broker",
        "write mosquitto's configuration, password file and ACL for this table: a user per "
        "role, only dthc-sender may send what lights the torch or moves Z",
    )
    broker.add_argument(
        "--broker-config",
        metavar="DIR",
        default=None,
        help=f"where mosquitto reads *.conf from (Debian: {DEBIAN_INCLUDE_DIR}); the default "
        "on a first install beside Debian's mosquitto",
    )
    broker.add_argument(
        "--no-broker-config",
        action="store_true",
        help="leave the broker alone (one elsewhere, secured by its own users and ACL)",
    )
    broker.add_argument(
        "--broker-listen",
        metavar="HOST:PORT",
        default="127.0.0.1:1883",
        help="the plain MQTT listener (default 127.0.0.1:1883; 'none': TLS only)",
    )
    broker.add_argument("--broker-tls-cert", type=Path, metavar="FILE", help="broker certificate")
    broker.add_argument("--broker-tls-key", type=Path, metavar="FILE", help="its private key")
    broker.add_argument(
        "--broker-tls-ca", type=Path, metavar="FILE", help="the CA clients verify the broker with"
    )
    broker.add_argument(
        "--broker-tls-listen",
        metavar="HOST:PORT",
        default=":8883",
        help="the TLS listener (default :8883, every address)",
    )
    broker.add_argument(
        "--broker-require-client-cert",
        action="store_true",
        help="TLS clients must show a certificate signed by --broker-tls-ca",
    )


def add_uninstall_arguments(parser: argparse.ArgumentParser) -> None:
    """The ``uninstall-service`` options."""
    _add_common_arguments(parser)
    parser.add_argument(
        "--purge",
        action="store_true",
        help=f"also remove {CONFIG_DIR} (the configuration), {STATE_DIR} and the user",
    )


def run_install(args: argparse.Namespace) -> int:
    """``install-service`` from parsed arguments (see :func:`add_install_arguments`)."""
    try:
        board = BoardIds.parse(args.vid, args.pid, args.serial)
        if args.broker_config is None and not args.no_broker_config:
            args.broker_config = _default_broker_config(args.root)
        broker = _broker_options(args)
    except DeployError as exc:
        sys.stderr.write(f"dthc-bridge install-service: error: {exc}\n")
        return 2
    options = InstallOptions(
        root=args.root,
        dry_run=args.dry_run,
        start=not args.no_start,
        user=args.user,
        bin_dir=default_bin_dir() if args.bin_dir is None else args.bin_dir.absolute(),
        board=board,
        broker=broker,
        base_topic=args.base_topic,
        board_id=args.board_id,
        grbl=args.grbl,
        grbl_listen=args.grbl_listen,
    )
    return install_service(options)


def _default_broker_config(root: Path) -> str | None:
    """Safety invariant 8, a default install is the secure one: a first install beside
    Debian's mosquitto locks that broker (users per role, the ACL) unless told not to, and
    a re-install keeps it locked. A re-install over an open broker leaves it (its kept
    configuration would lack the daemon's login) and says how to lock it."""
    fresh = not (root / CONFIG_PATH.lstrip("/")).exists()
    local = (root / DEBIAN_INCLUDE_DIR.lstrip("/")).is_dir()
    locked = (root / BrokerOptions().conf_path.lstrip("/")).exists()  # by an earlier install
    if local and (fresh or locked):
        return DEBIAN_INCLUDE_DIR
    why = (
        f"{CONFIG_PATH} exists (its [mqtt] has no login to add by itself)"
        if not fresh
        else f"no local mosquitto ({DEBIAN_INCLUDE_DIR} is missing)"
    )
    sys.stdout.write(
        f"note: the broker is not locked by this install: {why}. Anyone who may publish "
        f"to it can light the torch: add --broker-config {DEBIAN_INCLUDE_DIR} for a local "
        "mosquitto, or give a remote broker users per role and the ACL of "
        "systemd/mosquitto-acl.example; --no-broker-config silences this\n"
    )
    return None


def _broker_options(args: argparse.Namespace) -> BrokerOptions | None:
    tls_files = (args.broker_tls_cert, args.broker_tls_key, args.broker_tls_ca)
    if args.broker_config is None:
        if any(f is not None for f in tls_files) or args.broker_require_client_cert:
            raise DeployError("the --broker-tls-* options need --broker-config DIR")
        return None
    tls = None
    if any(f is not None for f in tls_files):
        if any(f is None for f in tls_files):
            raise DeployError("TLS needs --broker-tls-cert, --broker-tls-key and --broker-tls-ca")
        cert, key, ca = (f.absolute() for f in tls_files)
        tls = BrokerTls(
            cert_file=cert,
            key_file=key,
            ca_file=ca,
            listen=Listener.parse(args.broker_tls_listen, "--broker-tls-listen"),
            require_client_cert=args.broker_require_client_cert,
        )
    elif args.broker_require_client_cert:
        raise DeployError("--broker-require-client-cert needs the --broker-tls-* files")
    listen = None
    if args.broker_listen.strip().lower() not in ("none", "off", ""):
        listen = Listener.parse(args.broker_listen, "--broker-listen")
    return BrokerOptions(config_dir=args.broker_config, listen=listen, tls=tls)


def run_uninstall(args: argparse.Namespace) -> int:
    """``uninstall-service`` from parsed arguments (see :func:`add_uninstall_arguments`)."""
    options = UninstallOptions(
        root=args.root, dry_run=args.dry_run, purge=args.purge, user=args.user
    )
    return uninstall_service(options)


def _add_common_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--root",
        type=_root_dir,
        default=Path("/"),
        metavar="DIR",
        help="write the files under DIR (a staging root) and run no command",
    )
    parser.add_argument("--dry-run", action="store_true", help="print every step without doing it")
    parser.add_argument(
        "--user",
        default=DEFAULT_USER,
        help=f"service user and group (default {DEFAULT_USER})",
    )


# ----------------------------------------------------------------------------- helpers


def _apply(
    steps: list[Step], *, root: Path, dry_run: bool, out: TextIO, host: HostState, runner: Runner
) -> None:
    ctx = Context(
        root=root,
        live=root == Path("/"),
        dry_run=dry_run,
        out=out,
        runner=runner,
        systemd_booted=host.systemd_booted,
        has_udevadm=host.has_udevadm,
    )
    for step in steps:
        step.apply(ctx)


def _require_root(*, live: bool, dry_run: bool, command: str) -> None:
    if live and not dry_run and os.geteuid() != 0:
        raise DeployError(
            f"{command} changes /etc and the system's accounts: run it as root "
            f"(sudo {sys.prefix}/bin/dthc-bridge {command} ...), preview it with --dry-run, "
            "or stage the files with --root DIR"
        )


def _heading(command: str, root: Path, dry_run: bool) -> str:
    where = "this system" if root == Path("/") else f"staging root {root}"
    return f"dthc-bridge {command}: {where}{' (dry run: nothing is changed)' if dry_run else ''}\n"


def _root_dir(text: str) -> Path:
    path = Path(text).absolute()
    if path != Path("/") and not path.is_dir():
        raise argparse.ArgumentTypeError(f"{text}: not a directory")
    return path


def _hidden_prefix(path: Path) -> str | None:
    for prefix in HIDDEN_FROM_SERVICE:
        if path == Path(prefix) or Path(prefix) in path.parents:
            return prefix
    return None


def _user_exists(name: str) -> bool:
    try:
        pwd.getpwnam(name)
    except KeyError:
        return False
    return True


def _group_exists(name: str) -> bool:
    try:
        grp.getgrnam(name)
    except KeyError:
        return False
    return True
