"""The files a configuration names, checked before the daemon runs (``check-config`` and
the start of ``run``), so a missing CA file is refused by key and path at once instead of
a nameless ``[Errno 2]`` on every reconnect.

Every ``Path`` value of the loaded :class:`~dthc_bridge.config.DaemonConfig` is found by
walking its sections, so a field added later (``[mqtt] password_file``) is checked without
a list to keep up to date. Each is a file the daemon reads, which must exist and open for
reading, except the files in :data:`WRITTEN_FILES`: the material library is created when
missing, so only its folder must exist; a folder this user cannot write to is a warning
(the service user may differ from the one running ``check-config``), with its owner and
mode.
"""

from __future__ import annotations

import os
import pwd
import stat
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from pydantic import BaseModel

__all__ = ["WRITTEN_FILES", "PathProblem", "check_paths", "config_paths"]

WRITTEN_FILES = frozenset({"controller.materials_file", "controller.consumables_file"})
"""Keys of files the daemon writes (replaced through a temporary in the same folder)."""


@dataclass(frozen=True, slots=True)
class PathProblem:
    """A file of the configuration the daemon cannot use (``fatal``) or may not (a warning)."""

    key: str  # the dotted configuration key: mqtt.tls.ca_file
    path: Path
    problem: str  # what is wrong, with the OS error: "cannot open: [Errno 2] No such ..."
    fatal: bool = True

    def __str__(self) -> str:
        return f"{self.key} {self.path}: {self.problem}"


def config_paths(model: BaseModel, where: str = "") -> Iterator[tuple[str, Path]]:
    """Every ``Path`` value set in ``model`` and its sections, with its dotted key."""
    for name in type(model).model_fields:
        value = getattr(model, name)
        key = f"{where}.{name}" if where else name
        if isinstance(value, Path):
            yield key, value
        elif isinstance(value, BaseModel):
            yield from config_paths(value, key)


def check_paths(config: BaseModel) -> list[PathProblem]:
    """The problems of every file ``config`` names, fatal ones and warnings, in key order."""
    problems: list[PathProblem] = []
    for key, path in config_paths(config):
        if key in WRITTEN_FILES:
            problems += _check_written(key, path)
        else:
            problem = _unreadable(path)
            if problem is not None:
                problems.append(PathProblem(key, path, problem))
    return problems


def _os_error(exc: OSError) -> str:
    if exc.errno is not None and exc.strerror:
        return f"[Errno {exc.errno}] {exc.strerror}"
    return str(exc)


def _unreadable(path: Path) -> str | None:
    """Why ``path`` cannot be read as a file, or None. Opened, not only stat'ed, so a
    permission the daemon lacks shows; O_NONBLOCK so a FIFO cannot hang the check."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    except OSError as exc:
        return f"cannot open: {_os_error(exc)}{_as_user(exc)}"
    try:
        if stat.S_ISDIR(os.fstat(fd).st_mode):
            return "is a folder, not a file"
    finally:
        os.close(fd)
    return None


def _check_written(key: str, path: Path) -> list[PathProblem]:
    """A file the daemon creates or replaces: read at start if it exists; its folder must
    exist (the file is created, the folder is not) and is written to."""
    if path.exists() or path.is_symlink():
        problem = _unreadable(path)
        if problem is not None:
            return [PathProblem(key, path, problem)]
    folder = path.resolve().parent  # where a symlinked file is written
    try:
        info = folder.stat()
    except OSError as exc:
        reason = f"its folder {folder} cannot be used: {_os_error(exc)}"
        return [PathProblem(key, path, f"{reason} (the file is created, the folder is not)")]
    if not stat.S_ISDIR(info.st_mode):
        return [PathProblem(key, path, f"{folder} is not a folder")]
    if not os.access(folder, os.W_OK | os.X_OK):
        owner = _user_name(info.st_uid)
        return [
            PathProblem(
                key, path,
                f"its folder {folder} is not writable by user {_user_name(os.geteuid())} "
                f"(owner {owner}, mode {stat.S_IMODE(info.st_mode):04o}): changes to the "
                "library cannot be saved unless the service user can write there",
                fatal=False,
            )
        ]  # fmt: skip
    return []


def _as_user(exc: OSError) -> str:
    """A permission error depends on who asks: say who did."""
    if isinstance(exc, PermissionError):
        return f" (as user {_user_name(os.geteuid())})"
    return ""


def _user_name(uid: int) -> str:
    try:
        return pwd.getpwuid(uid).pw_name
    except KeyError:
        return str(uid)
