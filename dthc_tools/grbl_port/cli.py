"""``dthc-bridge grbl-port --listen PTY_PATH|tcp://HOST:PORT --grbl PORT_OR_URL``: a grbl 1.1
that any grbl sender drives, in front of the table's own grbl and beside the daemon.

To the sender it is a grbl on a pty behind a stable path (``--listen /run/dthc/grbl``), or
on a raw TCP port for senders that reach grblHAL over the network; behind it, the table's
grbl through the reference sender's grbl backend; beside it, the daemon over MQTT with the
reference sender's own client. The pty and TCP ends are the mock board's own
(:mod:`mock_device.links`: a raw pty behind an atomically replaced symlink, one TCP client
at a time)."""

from __future__ import annotations

import argparse
import grp
import ipaddress
import os
import sys
from collections.abc import Sequence
from pathlib import Path

from dthc_bridge.program.options import add_dialect_options
from dthc_tools.broker_options import add_broker_arguments, parse_with_broker, run_with_broker
from mock_device.links import BoardLink, PtyLink, TcpLink

from ..sender import DaemonClient, Sender
from ..sender.backend import BackendError
from ..sender.grbl_backend import GrblBackend
from .session import BANNER, PortSession

__all__ = ["build_parser", "main", "share_pty"]

DEFAULT_PTY_GROUP = "dialout"  # Debian's group of serial ports: senders' users are in it


def build_parser(prog: str = "dthc-bridge grbl-port") -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=prog,
        description="A grbl 1.1 for any grbl sender (CNCjs, UGS, gSender, bCNC), in front of "
        "the table's grbl and beside the daemon.",
    )
    parser.add_argument(
        "--listen", required=True,
        help="a path for the sender's serial port (a pty behind it), or tcp://HOST:PORT",
    )  # fmt: skip
    parser.add_argument(
        "--grbl", required=True, help="the table's grbl: /dev/ttyUSB0, or socket://HOST:PORT"
    )
    parser.add_argument(
        "--pty-group", default=DEFAULT_PTY_GROUP, metavar="GROUP",
        help="the group given the pty (mode 0660) so a sender running as another user in it "
        f"opens it like a serial port (default {DEFAULT_PTY_GROUP}, where it exists; '' to "
        "leave the pty its owner's)",
    )  # fmt: skip
    parser.add_argument("--baud", type=int, default=115_200)
    parser.add_argument("--status-hz", type=float, default=10.0, help="grbl polling, 5-20 Hz")
    parser.add_argument("--base-topic", default="dthc")
    parser.add_argument("--board-id", default="table1")
    add_broker_arguments(parser)
    add_dialect_options(parser)
    return parser


def _link(listen: str, session: PortSession) -> BoardLink:
    if listen.startswith("tcp://"):
        host, _, port = listen.removeprefix("tcp://").rpartition(":")
        if not host or not port.isdigit():
            raise SystemExit(f"--listen {listen!r}: expected tcp://HOST:PORT")
        if not _loopback(host):
            # A grbl's TCP port has no login (senders speak raw grbl to it): whoever reaches
            # it can start a cut. The pty (the default) is the serial ports' group's only.
            print(
                f"--listen {listen}: anyone who can reach this address can start a cut "
                "through the port (grbl's TCP has no login); keep it on the shop's own "
                "network, or firewalled to the sender's PC",
                file=sys.stderr,
            )
        return TcpLink(host, int(port), session.received)
    return PtyLink(Path(listen), session.received)


def _loopback(host: str) -> bool:
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return host == "localhost"


async def _serve(args: argparse.Namespace) -> int:
    daemon = DaemonClient(args.broker_settings, base_topic=args.base_topic, board_id=args.board_id)
    try:
        grbl = GrblBackend(args.grbl, baudrate=args.baud, poll_hz=args.status_hz)
    except ValueError as exc:
        raise SystemExit(str(exc)) from None
    await grbl.connect()
    try:
        async with daemon.connected():
            ends: list[BoardLink] = []  # the sender's end, once made (it needs the session)

            def to_sender(data: bytes) -> None:
                for end in ends:
                    end.write(data)

            session = PortSession(Sender(daemon, grbl), grbl, to_sender,
                                  dialect=args.dialect, codes=args.codes)  # fmt: skip
            link = _link(args.listen, session)
            ends.append(link)
            await link.open()
            if isinstance(link, PtyLink) and args.pty_group:
                share_pty(link, args.pty_group)
            link.write(BANNER.encode() + b"\r\n")  # read by a sender when it opens the port
            print(f"grbl port on {args.listen}, table's grbl on {args.grbl}", file=sys.stderr)
            try:
                await session.run()
            finally:
                await link.close()
    finally:
        await grbl.close()
    return 0


def share_pty(link: PtyLink, group: str) -> None:
    """The pty's device to ``group``, mode 0660, as a USB-serial port is: a sender running
    as another user of that group opens it. A group that does not exist, or one this user
    may not give (not a member): the pty stays its owner's, said once on stderr."""
    device = link.device
    if device is None:
        return
    try:
        gid = grp.getgrnam(group).gr_gid
    except KeyError:
        if group != DEFAULT_PTY_GROUP:
            print(f"--pty-group {group!r}: no such group; the pty stays yours", file=sys.stderr)
        return
    try:
        os.chown(device, -1, gid)
        os.chmod(device, 0o660)
    except PermissionError:
        print(
            f"the pty {device} stays yours: this user may not give it to group {group!r} "
            "(not a member); a sender running as you opens it",
            file=sys.stderr,
        )


def main(argv: Sequence[str] | None = None, *, prog: str = "dthc-bridge grbl-port") -> int:
    args = parse_with_broker(build_parser(prog), argv)
    try:
        return run_with_broker(prog, args, _serve(args), BackendError, OSError)
    except KeyboardInterrupt:
        return 0
