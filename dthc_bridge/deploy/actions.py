"""The installer's steps: each one reports what it does, and does it unless this is a dry run.

Steps are idempotent: a file with the wanted content is left alone, a missing file is
"absent", a command whose input did not change is skipped. Paths are system paths
(``/etc/...``) resolved under the context's root, so a staging root (``--root DIR``)
receives exactly the files a live install would write, and no command touches the host.
"""

from __future__ import annotations

import grp
import os
import shlex
import shutil
import subprocess
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal, Protocol, TextIO

from .render import DeployError

__all__ = [
    "Command",
    "Context",
    "MakeDir",
    "Note",
    "RemoveFile",
    "RemoveTree",
    "Runner",
    "StartService",
    "Step",
    "WriteFile",
    "run_command",
]

Runner = Callable[[Sequence[str]], None]
"""Runs one command on the host; raises DeployError when it fails."""

Needs = Literal["host", "systemd", "udev"]
"""What a command acts on: the host's accounts, the running systemd, the running udev."""

_STATUS_WIDTH = 10


def run_command(argv: Sequence[str]) -> None:
    """Run ``argv`` (the program looked up on PATH); DeployError with its stderr on failure."""
    program = shutil.which(argv[0])
    if program is None:
        raise DeployError(f"{argv[0]} not found on PATH (needed for: {shlex.join(argv)})")
    # The argv is built by the installer from validated names, never from a shell string.
    proc = subprocess.run(  # noqa: S603
        [program, *argv[1:]], capture_output=True, text=True, check=False
    )
    if proc.returncode != 0:
        detail = (proc.stderr or proc.stdout).strip()
        raise DeployError(f"{shlex.join(argv)} failed (exit {proc.returncode}): {detail}")


@dataclass
class Context:
    """Where and how steps apply, and which files have changed so far.

    ``live``: this machine's own root, where commands run and files get their group;
    otherwise ``root`` is a staging directory that only receives files.
    """

    root: Path
    live: bool
    dry_run: bool
    out: TextIO
    runner: Runner = run_command
    systemd_booted: bool = False
    has_udevadm: bool = False
    changed: set[str] = field(default_factory=set)

    def path(self, system_path: str) -> Path:
        return self.root / system_path.lstrip("/")

    def report(self, status: str, what: str) -> None:
        verb = f"would {status}" if self.dry_run and status in _ACTIVE else status
        self.out.write(f"  {verb:<{_STATUS_WIDTH + 6}} {what}\n")

    def group_id(self, group: str | None) -> int | None:
        """The gid to give a file on a live install, None when ownership is left alone."""
        if group is None or not self.live or self.dry_run:
            return None
        try:
            return grp.getgrnam(group).gr_gid
        except KeyError as exc:
            raise DeployError(f"group {group} does not exist") from exc


_ACTIVE = {"write", "mkdir", "remove", "run", "chmod"}
"""Statuses that change something: shown as "would ..." in a dry run."""


class Step(Protocol):
    def apply(self, ctx: Context) -> None: ...


@dataclass(frozen=True)
class Note:
    """A line of information (an account that already exists, something kept)."""

    text: str
    status: str = "note"

    def apply(self, ctx: Context) -> None:
        ctx.report(self.status, self.text)


@dataclass(frozen=True)
class WriteFile:
    """Make ``target`` hold ``content`` with ``mode`` (root:``group`` on a live install).

    ``replace=False`` is for files the user owns once written (the configuration): an
    existing one is kept whatever it holds.
    """

    target: str
    content: str
    mode: int
    group: str | None = None
    replace: bool = True

    def apply(self, ctx: Context) -> None:
        path = ctx.path(self.target)
        if path.exists() and not self.replace:
            ctx.report("keep", f"{self.target} (exists; never overwritten)")
            return
        if path.is_file() and path.read_text(encoding="utf-8") == self.content:
            if _mode(path) != self.mode:
                ctx.report("chmod", f"{self.target} ({self.mode:04o})")
                if not ctx.dry_run:
                    path.chmod(self.mode)
            else:
                ctx.report("unchanged", self.target)
            _chown_group(ctx, path, self.group)
            return
        ctx.changed.add(self.target)
        ctx.report("write", f"{self.target} ({self.mode:04o})")
        if ctx.dry_run:
            return
        gid = ctx.group_id(self.group)
        path.parent.mkdir(parents=True, exist_ok=True)
        partial = path.with_name(f".{path.name}.partial")
        partial.write_text(self.content, encoding="utf-8")
        partial.chmod(self.mode)
        if gid is not None:
            os.chown(partial, 0, gid)
        partial.replace(path)


@dataclass(frozen=True)
class MakeDir:
    """Make directory ``target`` with ``mode`` (root:``group`` on a live install)."""

    target: str
    mode: int
    group: str | None = None

    def apply(self, ctx: Context) -> None:
        path = ctx.path(self.target)
        if path.is_dir() and _mode(path) == self.mode:
            ctx.report("exists", self.target)
        else:
            ctx.report("mkdir", f"{self.target} ({self.mode:04o})")
            if not ctx.dry_run:
                path.mkdir(parents=True, exist_ok=True)
                path.chmod(self.mode)
        _chown_group(ctx, path, self.group)


@dataclass(frozen=True)
class RemoveFile:
    target: str

    def apply(self, ctx: Context) -> None:
        path = ctx.path(self.target)
        if not path.exists() and not path.is_symlink():
            ctx.report("absent", self.target)
            return
        ctx.changed.add(self.target)
        ctx.report("remove", self.target)
        if not ctx.dry_run:
            path.unlink()


@dataclass(frozen=True)
class RemoveTree:
    """Remove a directory the service owns, with everything in it (``--purge`` only)."""

    target: str

    def apply(self, ctx: Context) -> None:
        if self.target.count("/") < 2 or not self.target.startswith("/"):
            raise DeployError(f"refusing to remove {self.target!r}: not a service directory")
        path = ctx.path(self.target)
        if not path.exists():
            ctx.report("absent", self.target)
            return
        ctx.changed.add(self.target)
        ctx.report("remove", f"{self.target} (and everything in it)")
        if not ctx.dry_run:
            shutil.rmtree(path)


@dataclass(frozen=True)
class Command:
    """Run ``argv`` on the host, when what it needs is there and its inputs changed.

    ``if_changed``: run only if one of these targets changed in this run;
    ``if_exists``: only if that target exists; ``when``: a last check made when the step
    applies (an account that an earlier step may have removed).
    """

    argv: tuple[str, ...]
    needs: Needs
    if_changed: tuple[str, ...] = ()
    if_exists: str | None = None
    when: Callable[[], bool] | None = None

    def apply(self, ctx: Context) -> None:
        command = shlex.join(self.argv)
        reason = _skip_reason(ctx, self.needs) or self._skip_reason(ctx)
        if reason is not None:
            ctx.report("skip", f"{command} ({reason})")
            return
        ctx.report("run", command)
        if not ctx.dry_run:
            ctx.runner(self.argv)

    def _skip_reason(self, ctx: Context) -> str | None:
        if self.if_changed and not ctx.changed.intersection(self.if_changed):
            return "nothing changed"
        if self.if_exists is not None and not ctx.path(self.if_exists).exists():
            return f"{self.if_exists} absent"
        if self.when is not None and not self.when():
            return "not needed"
        return None


@dataclass(frozen=True)
class StartService:
    """Start ``unit``; restart it instead when one of ``restart_if_changed`` changed.

    An unchanged, running service is left alone (``systemctl start`` is then a no-op):
    re-running the installer must not interrupt a cut.
    """

    unit: str
    restart_if_changed: tuple[str, ...]

    def apply(self, ctx: Context) -> None:
        verb = "restart" if ctx.changed.intersection(self.restart_if_changed) else "start"
        Command(("systemctl", verb, self.unit), "systemd").apply(ctx)


def _chown_group(ctx: Context, path: Path, group: str | None) -> None:
    """root:``group`` on a live install, when it is not already."""
    gid = ctx.group_id(group)
    if gid is not None and path.stat().st_gid != gid:
        os.chown(path, 0, gid)


def _skip_reason(ctx: Context, needs: Needs) -> str | None:
    if not ctx.live:
        return "staging root"
    if needs == "systemd" and not ctx.systemd_booted:
        return "this system is not running systemd"
    if needs == "udev" and not ctx.has_udevadm:
        return "udevadm not installed"
    return None


def _mode(path: Path) -> int:
    return path.stat().st_mode & 0o7777
