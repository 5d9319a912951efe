"""CNCjs, the grbl sender, run headless for the grbl port's end-to-end tests: its server as
its own process (installed by ``make cncjs`` into ``$CNCJS_DIR``), driven over the
socket.io API its browser client uses (``drive.js``), with the settings file (``.cncrc``)
the README tells an owner to write."""

from __future__ import annotations

import json
import os
import queue
import shutil
import socket
import subprocess
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

HERE = Path(__file__).parent
DRIVER = HERE / "drive.js"
SEND_M6_COMMANDS = 1  # CNCjs's tool-change policy "Send M6 commands" (MASSO's T112 M6)


def cncjs_dir() -> Path:
    """Where ``make cncjs`` installed CNCjs (the Makefile exports CNCJS_DIR)."""
    default = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return Path(os.environ.get("CNCJS_DIR") or default / "dthc-bridge" / "cncjs")


def missing() -> str | None:
    """Why CNCjs cannot run here, or None."""
    if shutil.which("node") is None:
        return "node is not installed (make cncjs)"
    if not (cncjs_dir() / "node_modules" / "cncjs" / "bin" / "cncjs").exists():
        return f"CNCjs is not installed in {cncjs_dir()} (make cncjs)"
    return None


def cncrc(ports: list[Path], secret: str) -> dict[str, Any]:
    """The settings an owner writes (README, "Use your own sender"): the grbl port's path
    offered as a serial port, M6 sent on to the port (MASSO's T112 M6)."""
    return {
        "secret": secret,
        "ports": [{"path": str(port), "manufacturer": "dthc-bridge grbl port"} for port in ports],
        "tool": {"toolChangePolicy": SEND_M6_COMMANDS},
    }


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@contextmanager
def cncjs_server(workdir: Path, ports: list[Path]) -> Iterator[tuple[str, str]]:
    """CNCjs's server on a loopback port; yields its URL and the secret its tokens are
    signed with."""
    secret = os.urandom(16).hex()
    config = workdir / ".cncrc"
    config.write_text(json.dumps(cncrc(ports, secret), indent=2))
    port = _free_port()
    log = (workdir / "cncjs.log").open("w")
    binary = cncjs_dir() / "node_modules" / "cncjs" / "bin" / "cncjs"
    proc = subprocess.Popen(
        ["node", str(binary), "--host", "127.0.0.1", "--port", str(port), "--config", str(config)],
        stdout=log, stderr=subprocess.STDOUT, env={**os.environ, "HOME": str(workdir)},
    )  # fmt: skip
    try:
        deadline = time.monotonic() + 60
        while True:
            try:
                socket.create_connection(("127.0.0.1", port), timeout=0.5).close()
                break
            except OSError:
                if proc.poll() is not None or time.monotonic() > deadline:
                    raise RuntimeError(
                        f"CNCjs did not start: {(workdir / 'cncjs.log').read_text()[-2000:]}"
                    ) from None
                time.sleep(0.2)
        yield f"http://127.0.0.1:{port}", secret
    finally:
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
        log.close()


class Cncjs:
    """One socket.io client of a CNCjs server: requests out, every event it pushes kept."""

    def __init__(self, url: str, secret: str) -> None:
        env = {**os.environ, "NODE_PATH": str(cncjs_dir() / "node_modules")}
        self._proc = subprocess.Popen(
            ["node", str(DRIVER), url, secret],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=env,
        )  # fmt: skip
        self.events: list[tuple[float, str, list[Any]]] = []  # (monotonic, name, args)
        self._replies: queue.Queue[tuple[int, list[Any]]] = queue.Queue()
        self._changed = threading.Condition()
        self._next_id = 0
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()
        self.wait_for(lambda: self.seen("connected"), 20, "connected to CNCjs")

    def _read(self) -> None:
        assert self._proc.stdout is not None
        for line in self._proc.stdout:
            message = json.loads(line)
            if "id" in message:
                self._replies.put((message["id"], message["reply"]))
                continue
            with self._changed:
                self.events.append((time.monotonic(), message["event"], message.get("args", [])))
                self._changed.notify_all()

    def emit(self, *args: Any, timeout: float = 20.0) -> list[Any]:
        """``socket.emit(*args, callback)``; what the callback was given."""
        assert self._proc.stdin is not None
        self._next_id += 1
        self._proc.stdin.write(json.dumps({"id": self._next_id, "emit": list(args)}) + "\n")
        self._proc.stdin.flush()
        deadline = time.monotonic() + timeout
        while True:
            number, reply = self._replies.get(timeout=max(0.01, deadline - time.monotonic()))
            if number == self._next_id:
                return reply

    def send(self, *args: Any) -> None:
        """``socket.emit(*args)`` for an event with no callback (a controller command)."""
        assert self._proc.stdin is not None
        self._next_id += 1
        self._proc.stdin.write(json.dumps({"id": self._next_id, "emit": list(args)}) + "\n")
        self._proc.stdin.flush()

    def seen(self, name: str, test: Callable[[list[Any]], bool] = lambda _: True) -> bool:
        return any(n == name and test(args) for _, n, args in list(self.events))

    def wait_for(self, done: Callable[[], bool], timeout: float, what: str) -> None:
        deadline = time.monotonic() + timeout
        with self._changed:
            while not done():
                left = deadline - time.monotonic()
                if left <= 0:
                    raise AssertionError(f"CNCjs: timed out waiting for {what}; {self.tail()}")
                self._changed.wait(min(left, 0.2))

    def console(self) -> list[str]:
        """What CNCjs's console shows of the port (its ``serialport:read`` lines)."""
        return [str(args[0]) for _, n, args in list(self.events) if n == "serialport:read"]

    def workflow(self) -> list[str]:
        return [str(args[0]) for _, n, args in list(self.events) if n == "workflow:state"]

    def active_state(self) -> str:
        """The grbl state CNCjs last showed (Idle, Run, Hold:0, ...)."""
        for _, name, args in reversed(list(self.events)):
            if name == "controller:state" and len(args) > 1:
                status = args[1].get("status", {}) if isinstance(args[1], dict) else {}
                if status.get("activeState"):
                    return str(status["activeState"])
        return ""

    def tail(self, n: int = 15) -> str:
        return "; ".join(f"{name} {args}"[:160] for _, name, args in self.events[-n:])

    def close(self) -> None:
        if self._proc.stdin is not None:
            self._proc.stdin.close()
        try:
            self._proc.wait(5)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            self._proc.wait(5)
        self._reader.join(5)
        if self._proc.stdout is not None:
            self._proc.stdout.close()
