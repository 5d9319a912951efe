"""The files a configuration names are checked before the daemon runs: ``check-config``
and ``run`` refuse a missing or unreadable file by key, path and OS error; the material
library may be missing (it is created) but its folder may not."""

from __future__ import annotations

import errno
import os
import types
from collections.abc import Iterator
from pathlib import Path
from typing import Union, get_args, get_origin

import pytest
from pydantic import BaseModel

from dthc_bridge import cli, daemon
from dthc_bridge.config import DaemonConfig, load_config
from dthc_bridge.config_paths import check_paths


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "config.toml"
    path.write_text(text)
    return path


def _path_fields(model: type[BaseModel], where: str = "") -> Iterator[str]:
    """Every field of the model tree whose annotation allows a Path, by dotted key."""
    for name, field in model.model_fields.items():
        key = f"{where}.{name}" if where else name
        annotation = field.annotation
        kinds = get_args(annotation) if get_origin(annotation) in (Union, types.UnionType) else ()
        for kind in kinds or (annotation,):
            if kind is Path:
                yield key
            elif isinstance(kind, type) and issubclass(kind, BaseModel):
                yield from _path_fields(kind, key)


def _set(document: dict[str, object], key: str, value: object) -> None:
    *sections, name = key.split(".")
    for section in sections:
        document = document.setdefault(section, {})  # type: ignore[assignment]
    document[name] = value


def test_every_path_field_of_the_configuration_is_checked(tmp_path: Path) -> None:
    """Whatever Path fields the model has (the TLS files, ``password_file``, the material
    file, a field added next year), each one set to a missing file is refused by its key:
    the walk needs no list."""
    keys = sorted(_path_fields(DaemonConfig))
    assert {"mqtt.tls.ca_file", "controller.materials_file"} <= set(keys)
    document: dict[str, object] = {}
    for key in keys:
        _set(document, key, str(tmp_path / "gone" / key))
    config = DaemonConfig(**document)  # type: ignore[arg-type]
    assert sorted(problem.key for problem in check_paths(config)) == keys
    assert all(problem.fatal for problem in check_paths(config))


def test_check_config_refuses_a_missing_ca_file_naming_key_path_and_os_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The tester's probe: ``check-config`` said ok for a ``ca_file`` that does not exist
    (``run`` then retried forever with a nameless ``[Errno 2]``); now it exits 1 naming the
    key, the path and the OS error."""
    ca = tmp_path / "ca.pem"
    path = _write(tmp_path, f'[mqtt.tls]\nca_file = "{ca}"\n')
    assert cli.main(["check-config", str(path)]) == 1
    err = capsys.readouterr().err
    assert f"invalid: {path}: mqtt.tls.ca_file {ca}: cannot open: [Errno 2] No such file" in err
    ca.write_text("-----BEGIN CERTIFICATE-----\n")
    assert cli.main(["check-config", str(path)]) == 0


def test_an_unreadable_key_file_is_refused_as_permission_denied(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A file that exists but cannot be opened (root-only key) is refused with the OS's
    reason and the user who tried (root reads anything, so the refusal is simulated)."""
    cert, key = tmp_path / "client.crt", tmp_path / "client.key"
    cert.write_text("c")
    key.write_text("k")
    real_open = os.open

    def refusing_open(path: os.PathLike[str] | str, flags: int, *args: int) -> int:
        if Path(path) == key:
            raise PermissionError(errno.EACCES, "Permission denied", str(path))
        return real_open(path, flags, *args)

    monkeypatch.setattr(os, "open", refusing_open)  # config_paths opens with os.open
    config = load_config(
        _write(tmp_path, f'[mqtt.tls]\ncert_file = "{cert}"\nkey_file = "{key}"\n')
    )
    [problem] = check_paths(config)
    assert problem.key == "mqtt.tls.key_file"
    assert str(problem).startswith(f"mqtt.tls.key_file {key}: cannot open: [Errno 13] Permission")
    assert "(as user " in problem.problem


def test_a_folder_where_a_file_belongs_is_refused(tmp_path: Path) -> None:
    """``ca_file`` naming a folder opens (on Linux) but is no certificate file."""
    config = load_config(_write(tmp_path, f'[mqtt.tls]\nca_file = "{tmp_path}"\n'))
    [problem] = check_paths(config)
    assert problem.problem == "is a folder, not a file"


def test_a_material_file_that_does_not_exist_yet_is_fine_in_an_existing_folder(
    tmp_path: Path,
) -> None:
    """The library is created on the first change: only its folder must exist."""
    library = tmp_path / "materials.cfg"
    config = load_config(_write(tmp_path, f'[controller]\nmaterials_file = "{library}"\n'))
    assert check_paths(config) == []


def test_a_material_file_in_a_missing_folder_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The folder is not created: a typo in it is refused by ``check-config``, saying
    that the file itself may be missing."""
    library = tmp_path / "no-such-dir" / "materials.cfg"
    path = _write(tmp_path, f'[controller]\nmaterials_file = "{library}"\n')
    assert cli.main(["check-config", str(path)]) == 1
    err = capsys.readouterr().err
    assert f"controller.materials_file {library}: its folder {library.parent} cannot" in err
    assert "[Errno 2] No such file or directory" in err
    assert "(the file is created, the folder is not)" in err


def test_a_material_folder_this_user_cannot_write_is_a_warning_with_owner_and_mode(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """``check-config`` may run as another user than the service: a folder it cannot
    write to is a warning naming its owner and mode, and the file still passes."""
    folder = tmp_path / "lib"
    folder.mkdir(mode=0o755)
    library = folder / "materials.cfg"
    monkeypatch.setattr(os, "access", lambda path, mode: Path(path) != folder)
    path = _write(tmp_path, f'[controller]\nmaterials_file = "{library}"\n')
    assert cli.main(["check-config", str(path)]) == 0
    out = capsys.readouterr()
    assert "ok:" in out.out
    assert f"warning: {path}: controller.materials_file {library}: its folder {folder}" in out.err
    assert "mode 0755" in out.err
    assert "owner " in out.err


def test_run_refuses_to_start_with_the_same_message(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """``run`` with a missing ``ca_file`` exits 2 at once with check-config's message,
    instead of starting and retrying the broker forever."""
    started: list[object] = []

    async def never_run(config: object) -> int:
        started.append(config)
        return 0

    monkeypatch.setattr(daemon, "run_daemon", never_run)
    ca = tmp_path / "ca.pem"
    path = _write(tmp_path, f'[mqtt.tls]\nca_file = "{ca}"\n')
    assert cli.main(["run", "--config", str(path)]) == 2
    err = capsys.readouterr().err
    assert f"dthc-bridge: {path}: mqtt.tls.ca_file {ca}: cannot open: [Errno 2]" in err
    assert started == []
    ca.write_text("x")
    assert cli.main(["run", "--config", str(path)]) == 0
    assert len(started) == 1
