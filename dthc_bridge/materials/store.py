"""The daemon's material library on disk: one QtPlasmaC material file, replaced atomically.

The library is edited while the machine runs (over MQTT, by programs' ``o=1``/``o=2``
comments), and the daemon can lose power or be killed at any moment. A torn file would
cost the shop its recipes or, worse, cut with half of one. Every write therefore goes to a
temporary file in the same directory, which is flushed and fsynced before
:func:`os.replace` puts it in place in one step, and the directory is fsynced so the
rename itself survives a power cut: after a crash the file holds the old library or the
new one, never a mixture. A failed write leaves the old file and no temporary behind; a
temporary left by a killed process is removed by the next save.

The file keeps its permission bits (a new one gets 0644); it is written where a symlink
points, so a link from the configuration directory stays a link. Owner and comments are
not kept. The calls block on disk I/O (a few kB); an event loop can run them in a thread.
"""

from __future__ import annotations

import contextlib
import os
import stat
import tempfile
from collections.abc import Mapping
from pathlib import Path

from dthc_bridge.materials.library import (
    TEMPORARY_BASE,
    Material,
    MaterialError,
    format_material_file,
    parse_material_file,
)

__all__ = ["MaterialStore", "write_atomically"]

_NEW_FILE_MODE = 0o644
_TEMP_SUFFIX = ".tmp"


class MaterialStore:
    """The material file at ``path``, read once and rewritten on every change.

    A missing file is an empty library. :meth:`set` and :meth:`delete` persist at once;
    the in-memory copy changes only once the file has, so a failed write changes nothing.
    Material 0 (the default, in the daemon's settings) and temporary materials are not
    library materials and are refused.
    """

    def __init__(self, path: Path) -> None:
        self._path = Path(path)
        self._materials: dict[int, Material] | None = None

    @property
    def path(self) -> Path:
        return self._path

    def load(self) -> dict[int, Material]:
        """(Re)read the file. A missing file is an empty library; a bad one raises
        :class:`MaterialError` naming the path and line."""
        try:
            data = self._path.read_bytes()
        except FileNotFoundError:
            self._materials = {}
            return {}
        try:
            text = data.decode("utf-8-sig")  # tolerate a BOM from Windows editors
        except UnicodeDecodeError as e:
            raise MaterialError(str(self._path), f"not UTF-8 text (byte {e.start})") from None
        try:
            materials = parse_material_file(text)
        except MaterialError as e:
            raise MaterialError(f"{self._path} {e.where}", e.reason) from None
        self._materials = materials
        return dict(materials)

    def all(self) -> dict[int, Material]:
        """Every material, by number (a copy)."""
        return dict(self._loaded())

    def get(self, number: int) -> Material:
        """Material ``number``; :class:`MaterialError` when the library has none."""
        material = self._loaded().get(number)
        if material is None:
            raise MaterialError(f"material {number}", "not in the library")
        return material

    def set(self, material: Material) -> None:
        """Add ``material`` or replace the one with its number, and persist."""
        if material.number == 0 or material.temporary:
            raise MaterialError(
                f"material {material.number}",
                "library numbers are 1 to "
                f"{TEMPORARY_BASE - 1} (0 is the default material, higher ones temporary)",
            )
        self.save({**self._loaded(), material.number: material})

    def delete(self, number: int) -> None:
        """Remove material ``number`` and persist; :class:`MaterialError` if absent."""
        materials = dict(self._loaded())
        if materials.pop(number, None) is None:
            raise MaterialError(f"material {number}", "not in the library")
        self.save(materials)

    def save(self, materials: Mapping[int, Material]) -> None:
        """Replace the library with ``materials`` (temporaries are not written), atomically."""
        text = format_material_file(materials)
        target = Path(os.path.realpath(self._path))
        try:
            mode = stat.S_IMODE(target.stat().st_mode)
        except FileNotFoundError:
            mode = _NEW_FILE_MODE
        self._remove_stale_temporaries(target)
        write_atomically(target, text.encode("utf-8"), mode)
        self._materials = {n: m for n, m in materials.items() if not m.temporary}

    def _loaded(self) -> dict[int, Material]:
        if self._materials is None:
            self.load()
        assert self._materials is not None
        return self._materials

    @staticmethod
    def _remove_stale_temporaries(target: Path) -> None:
        """Temporaries of an earlier save that was killed (the daemon is the one writer)."""
        prefix = _temp_prefix(target)
        for leftover in target.parent.iterdir():
            if leftover.name.startswith(prefix) and leftover.name.endswith(_TEMP_SUFFIX):
                with contextlib.suppress(FileNotFoundError):
                    leftover.unlink()


def _temp_prefix(target: Path) -> str:
    return f".{target.name}."


def write_atomically(target: Path, data: bytes, mode: int) -> None:
    """Write ``data`` to ``target`` so that a crash leaves the old or the new content."""
    directory = target.parent
    # Beside the target (same file system, so the rename is atomic); created 0600, O_EXCL.
    fd, temp_name = tempfile.mkstemp(
        dir=directory, prefix=_temp_prefix(target), suffix=_TEMP_SUFFIX
    )
    try:
        try:
            os.fchmod(fd, mode)
            view = memoryview(data)
            while view:
                written = os.write(fd, view)
                view = view[written:]
            os.fsync(fd)
        finally:
            os.close(fd)
        os.replace(temp_name, target)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(temp_name)
        raise
    # The rename is in the directory: sync it, or a power cut can bring back the old file.
    dir_fd = os.open(directory, os.O_RDONLY | os.O_DIRECTORY)
    try:
        os.fsync(dir_fd)
    finally:
        os.close(dir_fd)
