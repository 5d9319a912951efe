"""The daemon's material file: persisted on every change, never torn by a crash."""

from __future__ import annotations

import errno
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from dthc_bridge.materials import (
    TEMPORARY_BASE,
    MaterialError,
    MaterialStore,
    parse_material_file,
)
from dthc_tools.procs import die_with_parent
from tests.materials.recipes import recipe

MILD = recipe(1, name="Mild steel 1.5 mm 45 A", thc=True, cut_amps=45, cut_volts=121)
PLATE = recipe(7, name="Plate 6 mm 65 A", pierce_height=4.5, pierce_delay_s=0.9, cut_speed=1400)


def leftovers(directory: Path) -> list[str]:
    return sorted(p.name for p in directory.iterdir() if p.name.endswith(".tmp"))


def test_a_missing_file_is_an_empty_library(tmp_path: Path) -> None:
    store = MaterialStore(tmp_path / "materials.cfg")
    assert store.load() == {}
    assert store.all() == {}
    assert not store.path.exists()  # reading creates nothing


def test_changes_persist_at_once_and_a_new_store_reads_them(tmp_path: Path) -> None:
    path = tmp_path / "materials.cfg"
    store = MaterialStore(path)
    store.set(MILD)
    store.set(PLATE)
    assert parse_material_file(path.read_text()) == {1: MILD, 7: PLATE}
    again = MaterialStore(path)
    assert again.all() == {1: MILD, 7: PLATE}
    assert again.get(7) == PLATE

    faster = recipe(7, cut_speed=1500)
    again.set(faster)
    again.delete(1)
    assert MaterialStore(path).load() == {7: faster}
    assert store.load() == {7: faster}  # load() re-reads
    assert leftovers(tmp_path) == []


def test_all_returns_a_copy(tmp_path: Path) -> None:
    store = MaterialStore(tmp_path / "materials.cfg")
    store.set(MILD)
    store.all().clear()
    assert store.all() == {1: MILD}


def test_save_replaces_the_library_and_drops_temporaries(tmp_path: Path) -> None:
    path = tmp_path / "materials.cfg"
    store = MaterialStore(path)
    store.set(MILD)
    store.save({7: PLATE, TEMPORARY_BASE: recipe(TEMPORARY_BASE)})
    assert store.all() == {7: PLATE}
    assert MaterialStore(path).all() == {7: PLATE}


@pytest.mark.parametrize("number", [0, TEMPORARY_BASE])
def test_the_default_and_temporaries_are_not_library_materials(tmp_path: Path, number: int) -> None:
    store = MaterialStore(tmp_path / "materials.cfg")
    with pytest.raises(MaterialError) as info:
        store.set(recipe(number))
    assert info.value.where == f"material {number}"
    assert not store.path.exists()


def test_getting_or_deleting_an_absent_material_names_it(tmp_path: Path) -> None:
    store = MaterialStore(tmp_path / "materials.cfg")
    store.set(MILD)
    with pytest.raises(MaterialError, match=r"^material 9: not in the library$"):
        store.get(9)
    with pytest.raises(MaterialError, match=r"^material 9: not in the library$"):
        store.delete(9)


def test_a_bad_file_is_an_error_naming_the_path_and_line(tmp_path: Path) -> None:
    path = tmp_path / "materials.cfg"
    path.write_text("[MATERIAL_NUMBER_2]\nPIERCE_HEIGHT = 3.8\nCUT_HEIGHT = high\n")
    with pytest.raises(MaterialError) as info:
        MaterialStore(path).load()
    assert str(info.value) == (
        f"{path} line 3 [MATERIAL_NUMBER_2] CUT_HEIGHT: 'high' is not a number"
    )
    path.write_bytes(b"[MATERIAL_NUMBER_2]\nNAME = \xff\n")
    with pytest.raises(MaterialError, match=r"materials\.cfg: not UTF-8 text \(byte 27\)$"):
        MaterialStore(path).load()


def test_a_file_saved_with_a_byte_order_mark_reads(tmp_path: Path) -> None:
    path = tmp_path / "materials.cfg"
    MaterialStore(path).set(MILD)
    path.write_bytes(b"\xef\xbb\xbf" + path.read_bytes())
    assert MaterialStore(path).all() == {1: MILD}


def test_the_files_mode_is_kept_and_a_new_file_is_0644(tmp_path: Path) -> None:
    path = tmp_path / "materials.cfg"
    store = MaterialStore(path)
    store.set(MILD)
    assert path.stat().st_mode & 0o777 == 0o644
    path.chmod(0o600)
    store.set(PLATE)
    assert path.stat().st_mode & 0o777 == 0o600


def test_a_symlinked_file_is_written_where_the_link_points(tmp_path: Path) -> None:
    real = tmp_path / "data" / "materials.cfg"
    real.parent.mkdir()
    link = tmp_path / "materials.cfg"
    link.symlink_to(real)
    MaterialStore(link).set(MILD)
    assert link.is_symlink()
    assert parse_material_file(real.read_text()) == {1: MILD}
    assert leftovers(real.parent) == []


@pytest.mark.parametrize("failing", ["fsync", "write", "replace"])
def test_a_failed_write_leaves_the_old_file_and_no_temporary(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, failing: str
) -> None:
    """A full disk or an I/O error: the library on disk and in memory stay as they were."""
    path = tmp_path / "materials.cfg"
    store = MaterialStore(path)
    store.set(MILD)
    before = path.read_bytes()

    def fail(*args: object) -> None:
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(os, failing, fail)
    with pytest.raises(OSError, match="No space left"):
        store.set(PLATE)
    monkeypatch.undo()
    assert path.read_bytes() == before
    assert leftovers(tmp_path) == []
    assert store.all() == {1: MILD}


# The child saves the new library with one os function replaced: on its ``call``-th call it
# does (half of) the real work, says so, and waits to be killed there.
CHILD = textwrap.dedent(
    """
    import os, sys, time
    from pathlib import Path
    from dthc_bridge.materials import Material, MaterialStore

    path, name, call = Path(sys.argv[1]), sys.argv[2], int(sys.argv[3])
    real = getattr(os, name)
    calls = 0

    def hook(*args):
        global calls
        calls += 1
        if calls < call:
            return real(*args)
        if name == "write":
            fd, data = args
            real(fd, bytes(data[: len(data) // 2]))
        else:
            real(*args)
        print("paused", flush=True)
        time.sleep(60)

    setattr(os, name, hook)
    store = MaterialStore(path)
    store.set(Material(999, name="new", pierce_height=3, pierce_delay_s=0.5, cut_height=1,
                       cut_speed=2000))
    """
)


@pytest.mark.parametrize(
    ("name", "call", "survivor"),
    [
        ("write", 1, "old"),  # half the temporary written
        ("fsync", 1, "old"),  # temporary complete and synced, not yet renamed
        ("replace", 1, "new"),  # renamed, directory not yet synced
        ("fsync", 2, "new"),  # directory synced, nothing left to do
    ],
)
def test_a_save_killed_at_any_point_leaves_the_old_or_the_new_library(
    tmp_path: Path, name: str, call: int, survivor: str
) -> None:
    """SIGKILL mid-save: the file parses to exactly one of the two libraries, never a mix."""
    path = tmp_path / "materials.cfg"
    store = MaterialStore(path)
    # A few kB, so that half a file is a torn file and not an empty one.
    old = {n: recipe(n, name=f"material {n}", cut_speed=1000.0 + n) for n in range(1, 60)}
    store.save(old)
    new = old | {
        999: recipe(
            999, name="new", pierce_height=3, pierce_delay_s=0.5, cut_height=1, cut_speed=2000
        )
    }

    child = subprocess.Popen(
        [sys.executable, "-c", CHILD, str(path), name, str(call)],
        stdout=subprocess.PIPE,
        text=True,
        preexec_fn=die_with_parent(),
    )
    try:
        assert child.stdout is not None
        assert child.stdout.readline() == "paused\n"
    finally:
        os.kill(child.pid, signal.SIGKILL)
        child.wait(timeout=10)
        if child.stdout is not None:
            child.stdout.close()
    assert child.returncode == -signal.SIGKILL

    on_disk = parse_material_file(path.read_text())
    assert on_disk == (old if survivor == "old" else new)
    # The killed save's temporary is cleared by the next one.
    if name == "write":
        assert len(leftovers(tmp_path)) == 1
    store.save(on_disk)
    assert leftovers(tmp_path) == []
    assert MaterialStore(path).all() == on_disk
