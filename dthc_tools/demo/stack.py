"""The whole system on one machine: broker, board, daemon and sender, as in a shop.

Used by ``dthc-bridge demo``, the end-to-end tests and the soak benchmark. The broker is
mosquitto when installed, otherwise an embedded amqtt broker; the board (the mock board, or
the reference firmware on an emulated MCU) and the daemon run as their own processes on a
pty; the sender runs here.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import pwd
import shutil
import signal
import socket
import subprocess
import sys
import time
import uuid
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import aiomqtt

from dthc_bridge.controller.dialect import Dialect
from dthc_bridge.mqtt.broker import BrokerSettings

from ..emulated_board.build import MCUS
from ..emulated_board.harness import EmulatedBoard, HarnessOptions
from ..procs import die_with_parent
from ..sender import DaemonClient, Sender, SendReport, SimGantryBackend
from ..sender.backend import MotionBackend
from ..sender.grbl_backend import GrblBackend

__all__ = ["Stack", "StackOptions", "StackResult"]

STARTUP_S = 15.0


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port: int = sock.getsockname()[1]
        return port


@dataclass(frozen=True)
class StackOptions:
    workdir: Path
    scenario: str = "flat_clean"
    seed: int = 1
    broker: str = "auto"  # "mosquitto", "amqtt" or "auto"
    board_id: str = "table1"
    telemetry_hz: float = 50.0
    mock_args: tuple[str, ...] = ()
    daemon_env: dict[str, str] = field(default_factory=dict)
    materials_file: Path | None = None  # the daemon's material library (QtPlasmaC format)
    controller: dict[str, object] = field(default_factory=dict)  # more [controller] keys
    # "grbl": X and Y on an emulated grbl (its own process on a pty) mirrored into the mock's
    # plant; the mock board then has no XY speed input and the sender reports the speed.
    motion: str = "sim"
    grbl_args: tuple[str, ...] = ()
    # "mock": the mock board and its plant (ground truth). An MCU name ("atmega2560",
    # "atmega328p"): the reference firmware's ELF on the emulated board (no XY, so the
    # motion is grbl's), its plate and arc model set by ``board_model`` (the harness's
    # option names, e.g. {"plate-mm": 20, "warp-mm": 0.5}); its record in board-record.csv.
    board: str = "mock"
    board_model: dict[str, float] = field(default_factory=dict)
    # False: run the emulated board as built (a caller that ran ``ensure_built`` once, e.g.
    # the fault matrix, spares each stack the ``make`` of the firmware and its native tests).
    board_build: bool = True
    # A secured broker of the caller's (users, ACL, TLS), started by the caller: each client
    # of the stack logs in with its role's settings ("daemon", "sender", "panel", and
    # "dashboard" for the stack's own observer). Empty: the stack's own anonymous broker.
    logins: Mapping[str, BrokerSettings] = field(default_factory=dict)
    base_topic: str | None = None  # default: a fresh demo<hex> per stack

    def __post_init__(self) -> None:
        if self.board != "mock" and self.board not in MCUS:
            raise ValueError(f"board {self.board!r}: expected 'mock' or one of {MCUS}")
        if self.board != "mock" and self.motion != "grbl":
            raise ValueError("the emulated board has no XY: use motion='grbl'")

    @property
    def emulated(self) -> bool:
        return self.board != "mock"


@dataclass
class StackResult:
    report: SendReport
    mock_exit: dict[str, Any]
    daemon_exit_code: int | None
    daemon_exit_s: float
    telemetry: list[dict[str, Any]]
    events: list[dict[str, Any]]
    truth_path: Path


def _broker_toml(broker: BrokerSettings) -> str:
    """The ``[mqtt]`` keys of ``broker`` (the daemon's config), and ``[mqtt.tls]`` last."""
    lines = [f"host = {json.dumps(broker.host)}", f"port = {broker.port}",
             f"protocol = {json.dumps(broker.protocol)}"]  # fmt: skip
    if broker.username is not None:
        lines.append(f"username = {json.dumps(broker.username)}")
    if broker.password_file is not None:
        lines.append(f"password_file = {json.dumps(str(broker.password_file))}")
    return "\n".join(lines) + "\n"


def _tls_toml(broker: BrokerSettings) -> str:
    """The ``[mqtt.tls]`` table of ``broker`` (empty without TLS)."""
    if broker.tls is None:
        return ""
    lines = ["[mqtt.tls]"]
    for key in ("ca_file", "cert_file", "key_file"):
        value = getattr(broker.tls, key)
        if value is not None:
            lines.append(f"{key} = {json.dumps(str(value))}")
    return "\n".join(lines) + "\n\n"


class _Broker:
    def __init__(self, kind: str, workdir: Path) -> None:
        self.port = free_port()
        self.workdir = workdir
        mosquitto = shutil.which("mosquitto") or (
            "/usr/sbin/mosquitto" if os.access("/usr/sbin/mosquitto", os.X_OK) else None
        )
        if kind == "auto":
            kind = "mosquitto" if mosquitto else "amqtt"
        self.kind = kind
        self._mosquitto = mosquitto
        self._proc: subprocess.Popen[bytes] | None = None
        self._amqtt: Any = None

    @property
    def protocol(self) -> str:
        return "5" if self.kind == "mosquitto" else "3.1.1"  # amqtt speaks 3.1.1

    async def start(self) -> None:
        if self.kind == "mosquitto":
            if self._mosquitto is None:
                raise RuntimeError("mosquitto is not installed")
            config = self.workdir / "mosquitto.conf"
            # Stay this user: started as root, mosquitto would switch to user "mosquitto",
            # which clears the parent-death signal (procs.py) and outlives a killed demo.
            user = pwd.getpwuid(os.getuid()).pw_name
            config.write_text(
                f"listener {self.port} 127.0.0.1\nallow_anonymous true\npersistence false\n"
                f"user {user}\n"
            )
            self._proc = subprocess.Popen(  # noqa: S603, ASYNC220 - our broker, started once
                [self._mosquitto, "-c", str(config)],
                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                preexec_fn=die_with_parent(),
            )  # fmt: skip
        else:
            from amqtt.broker import Broker  # noqa: PLC0415 - only without mosquitto

            self._amqtt = Broker(
                {
                    "listeners": {"default": {"type": "tcp", "bind": f"127.0.0.1:{self.port}"}},
                    "plugins": {
                        "amqtt.plugins.authentication.AnonymousAuthPlugin": {
                            "allow_anonymous": True
                        }
                    },
                }
            )
            await self._amqtt.start()
        deadline = time.monotonic() + 5.0
        while time.monotonic() < deadline:
            with (
                contextlib.suppress(OSError),
                socket.create_connection(("127.0.0.1", self.port), 0.2),
            ):
                return
            await asyncio.sleep(0.05)
        raise RuntimeError(f"{self.kind} did not start on port {self.port}")

    async def stop(self) -> None:
        if self._proc is not None:
            self._proc.terminate()
            await asyncio.to_thread(self._proc.wait, 5)
        if self._amqtt is not None:
            await self._amqtt.shutdown()


class Stack:
    """``async with Stack(options) as stack: result = await stack.run(lines)``."""

    def __init__(self, options: StackOptions) -> None:
        self.options = options
        self.workdir = options.workdir
        self.base = options.base_topic or f"demo{uuid.uuid4().hex[:6]}"
        self.broker = _Broker(options.broker, self.workdir)
        # True: another Stack (or the caller, with logins) owns the broker
        self.broker_shared = bool(options.logins)
        self.pty = self.workdir / "dthc0"
        self.truth = self.workdir / "truth.jsonl"
        self.mock: subprocess.Popen[str] | None = None
        self.emulated_board: EmulatedBoard | None = None
        self.board_record = self.workdir / "board-record.csv"
        self.daemon: subprocess.Popen[bytes] | None = None
        self.gantry_port = 0
        self.grbl: subprocess.Popen[str] | None = None
        self.grbl_pty = self.workdir / "grbl0"
        self.last_backend: MotionBackend | None = None  # the last send()'s, for its figures
        self.telemetry: list[dict[str, Any]] = []
        self.events: list[dict[str, Any]] = []
        self._watch: asyncio.Task[None] | None = None
        self._logs: list[IO[str]] = []

    def _log(self, name: str) -> IO[str]:
        handle = (self.workdir / name).open("w")
        self._logs.append(handle)
        return handle

    async def __aenter__(self) -> Stack:
        if not self.broker_shared:
            await self.broker.start()
        if self.options.emulated:
            self._start_emulated_board()
        else:
            self._start_mock()
        if self.options.motion == "grbl":
            self._start_grbl()
        self._start_daemon()
        self._watch = asyncio.create_task(self._observe(), name="stack-observer")
        await self._wait_online()
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        if self._watch is not None:
            self._watch.cancel()
            with contextlib.suppress(asyncio.CancelledError, aiomqtt.MqttError):
                await self._watch
        for proc in (self.daemon, self.mock, self.grbl):
            if proc is not None and proc.poll() is None:
                proc.kill()
                await asyncio.to_thread(proc.wait, 5)
        if self.grbl is not None and self.grbl.stdout is not None:
            self.grbl.stdout.close()
        if self.mock is not None and self.mock.stdout is not None:
            self.mock.stdout.close()
        if self.emulated_board is not None:
            await asyncio.to_thread(self.emulated_board.stop)
        for handle in self._logs:
            handle.close()
        if not self.broker_shared:
            await self.broker.stop()

    def _start_mock(self) -> None:
        self.mock = subprocess.Popen(  # noqa: S603 - our own module, fixed arguments
            [sys.executable, "-m", "mock_device", "--pty", str(self.pty),
             "--scenario", self.options.scenario, "--seed", str(self.options.seed),
             "--truth", str(self.truth), "--gantry-listen", "socket://127.0.0.1:0",
             *(("--no-xy-speed",) if self.options.motion == "grbl" else ()),
             *self.options.mock_args],
            stdout=subprocess.PIPE, stderr=self._log("mock.log"), text=True,
            preexec_fn=die_with_parent(),
        )  # fmt: skip
        assert self.mock.stdout is not None
        ready = self.mock.stdout.readline().split()
        if not ready or ready[0] != "READY":
            raise RuntimeError("the mock board did not start: see mock.log")
        self.gantry_port = int(next(w for w in ready if w.startswith("gantry=")).split("=")[1])

    def _start_emulated_board(self) -> None:
        options = HarnessOptions(
            mcu=self.options.board, record=self.board_record, seed=self.options.seed,
            model=self.options.board_model, stderr=self.workdir / "board.log",
            build=self.options.board_build,
        )  # fmt: skip
        self.emulated_board = EmulatedBoard(self.pty, options)
        self.emulated_board.start()

    def _start_grbl(self) -> None:
        # With the mock board, grbl's motion is mirrored into the mock's plant (its gantry).
        plant = (
            () if self.options.emulated else ("--plant", f"socket://127.0.0.1:{self.gantry_port}")
        )
        self.grbl = subprocess.Popen(  # noqa: S603 - our own module, fixed arguments
            [sys.executable, "-m", "dthc_tools.grbl_emu", "--pty", str(self.grbl_pty),
             *plant, *self.options.grbl_args],
            stdout=subprocess.PIPE, stderr=self._log("grbl.log"), text=True,
            preexec_fn=die_with_parent(),
        )  # fmt: skip
        assert self.grbl.stdout is not None
        ready = self.grbl.stdout.readline().split()
        if not ready or ready[0] != "READY":
            raise RuntimeError("the grbl emulator did not start: see grbl.log")

    def motion_backend(self) -> MotionBackend:
        if self.options.motion == "grbl":
            return GrblBackend(str(self.grbl_pty))
        return SimGantryBackend("127.0.0.1", self.gantry_port)

    def _start_daemon(self) -> None:
        config = self.workdir / "config.toml"
        config.write_text(
            f'[board]\nlink = "{self.pty}"\n\n'
            f"[mqtt]\n{_broker_toml(self.broker_settings('daemon'))}"
            f'base_topic = "{self.base}"\n'
            f'board_id = "{self.options.board_id}"\ntelemetry_hz = {self.options.telemetry_hz}\n'
            f"state_poll_s = 0.05\nreconnect_initial_s = 0.1\nreconnect_max_s = 1.0\n\n"
            f"{_tls_toml(self.broker_settings('daemon'))}"
            f'[logging]\nlevel = "info"\njson_logs = true\n'
        )
        controller = dict(self.options.controller)
        # The stack's own counters: a demo's pierces are not the table's consumables.
        controller.setdefault("consumables_file", str(self.workdir / "consumables.json"))
        if self.options.materials_file is not None:
            controller["materials_file"] = str(self.options.materials_file)
        if controller:
            with config.open("a") as toml:
                toml.write("\n[controller]\n")
                toml.writelines(f"{key} = {_toml(value)}\n" for key, value in controller.items())
        self.daemon = subprocess.Popen(  # noqa: S603 - our own module, fixed arguments
            [sys.executable, "-m", "dthc_bridge", "run", "--config", str(config)],
            stdout=self._log("daemon.log"), stderr=subprocess.STDOUT,
            env={**os.environ, **self.options.daemon_env}, preexec_fn=die_with_parent(),
        )  # fmt: skip

    @property
    def root(self) -> str:
        return f"{self.base}/{self.options.board_id}"

    async def _observe(self) -> None:
        while True:
            try:
                async with aiomqtt.Client(
                    **self.broker_settings("dashboard").client_options(),
                    identifier=f"observer-{self.base}",
                ) as client:
                    for leaf in ("telemetry", "event", "board", "availability"):
                        await client.subscribe(f"{self.root}/{leaf}", qos=1)
                    async for message in client.messages:
                        self._record(message)
            except aiomqtt.MqttError:
                await asyncio.sleep(0.2)

    def _record(self, message: aiomqtt.Message) -> None:
        try:
            doc = json.loads(bytes(message.payload))
        except ValueError:
            return
        if not isinstance(doc, dict):
            return
        leaf = message.topic.value.rsplit("/", 1)[-1]
        doc["received_s"] = time.monotonic()
        if leaf == "telemetry":
            self.telemetry.append(doc)
        else:
            self.events.append({"topic": leaf, **doc})

    async def _wait_online(self) -> None:
        deadline = time.monotonic() + STARTUP_S
        while time.monotonic() < deadline:
            boards = [e for e in self.events if e["topic"] == "board"]
            if boards and boards[-1].get("state") == "online":
                return
            if self.daemon is not None and self.daemon.poll() is not None:
                raise RuntimeError("the daemon exited: see daemon.log")
            await asyncio.sleep(0.05)
        raise RuntimeError("the daemon did not bring the board online in time: see daemon.log")

    def daemon_client(
        self, cls: type[DaemonClient] = DaemonClient, timeout_s: float = 60.0, role: str = "sender"
    ) -> DaemonClient:
        return cls(
            self.broker_settings(role), base_topic=self.base, board_id=self.options.board_id,
            timeout_s=timeout_s, role=role,
        )  # fmt: skip

    def broker_settings(self, role: str = "sender") -> BrokerSettings:
        """How ``role``'s client reaches and logs in to this stack's broker."""
        if self.options.logins:
            return self.options.logins[role]
        protocol = "5" if self.broker.protocol == "5" else "3.1.1"
        return BrokerSettings(host="127.0.0.1", port=self.broker.port, protocol=protocol)

    async def send(
        self,
        lines: list[str],
        *,
        start_line: int = 1,
        daemon: DaemonClient | None = None,
        dialect: Dialect | None = None,
        codes: Mapping[str, str] | None = None,
        auto_cycle_start: bool = True,
    ) -> SendReport:
        """Run the sender over ``lines``; ``daemon`` must not be connected yet. No operator
        at a demo: cycle start is pressed at each G200 S1 stop unless ``auto_cycle_start``
        is False (a test presses it itself)."""
        daemon = daemon or self.daemon_client()
        backend = self.motion_backend()
        if isinstance(backend, GrblBackend):
            await backend.connect()
        self.last_backend = backend
        async with daemon.connected():
            try:
                return await Sender(daemon, backend, auto_cycle_start=auto_cycle_start).run(
                    lines, start_line=start_line, dialect=dialect, codes=codes
                )
            finally:
                await backend.close()

    async def reset_motion(self) -> None:
        """What an operator does before restarting after an error: clear and release."""
        backend = self.motion_backend()
        if isinstance(backend, GrblBackend):
            await backend.connect()
        try:
            await backend.clear()
            await backend.resume()
        finally:
            await backend.close()

    async def request(self, name: str, /, **args: Any) -> dict[str, Any]:
        # A tool's client, not a sender: its end must not read as the sender's will.
        daemon = self.daemon_client(role="tool")
        async with daemon.connected():
            return await daemon.request(name, **args)

    async def finish(self, report: SendReport | None = None) -> StackResult:
        """Stop the daemon (SIGTERM, timed) and the board; collect what happened (the mock's
        exit figures; none from the emulated board, whose record stays in board_record)."""
        assert self.daemon is not None
        await asyncio.sleep(0.3)  # let the last telemetry and state arrive
        t0 = time.monotonic()
        self.daemon.send_signal(signal.SIGTERM)
        try:
            code: int | None = await asyncio.to_thread(self.daemon.wait, 10)
        except subprocess.TimeoutExpired:
            code = None
        exit_s = time.monotonic() - t0
        if self.grbl is not None:  # its exit line (stats) goes to grbl.log
            self.grbl.send_signal(signal.SIGTERM)
            await asyncio.to_thread(self.grbl.wait, 10)
        mock_exit: dict[str, Any] = {}
        if self.emulated_board is not None:
            await asyncio.to_thread(self.emulated_board.stop)
        if self.mock is not None:
            self.mock.send_signal(signal.SIGTERM)
            await asyncio.to_thread(self.mock.wait, 10)
            for line in (self.workdir / "mock.log").read_text().splitlines():
                if '"event": "exit"' in line:
                    mock_exit = json.loads(line)
        return StackResult(
            report or SendReport(),
            mock_exit,
            code,
            exit_s,
            list(self.telemetry),
            list(self.events),
            self.truth,
        )


def _toml(value: object) -> str:
    """A TOML value for the scalars the demo writes (JSON strings and numbers are TOML's)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    return json.dumps(value)
