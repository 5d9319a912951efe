"""Find LinuxCNC's ``plasmac.so`` and build the HAL shim that hosts it; find LinuxCNC's
standalone G-code interpreter ``rs274``.

LinuxCNC is GPL-2: nothing of it is in this repository. The component comes from the user's
own Debian package ``linuxcnc-uspace``, downloaded with ``apt-get download`` into a cache
directory and unpacked with ``dpkg-deb -x`` (not installed). The shim (``hal_shim.c``, ours)
is compiled with the system C compiler into the same cache, once per source version.

``rs274`` (:func:`provision_rs274`) comes from the same package: the binary and the
package's own libraries are kept in ``rs274-<version>/`` in the cache; a system library it
needs that is not installed (Debian 12: ``libboost_python311``, from
``libboost-python1.74.0``) is downloaded and unpacked there too, chosen among the package's
dependencies. It runs with ``LD_LIBRARY_PATH`` on that directory (:meth:`Rs274.environ`).
"""

from __future__ import annotations

import contextlib
import glob
import hashlib
import os
import re
import shutil
import subprocess
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

__all__ = [
    "DEFAULT_CACHE",
    "PACKAGE",
    "PlasmacUnavailable",
    "Provisioned",
    "Rs274",
    "build_shim",
    "find_component",
    "find_rs274",
    "provision",
    "provision_rs274",
]

PACKAGE = "linuxcnc-uspace"
COMPONENT_PATH = "usr/lib/linuxcnc/modules/plasmac.so"
DEFAULT_CACHE = Path(
    os.environ.get("DTHC_PLASMAC_CACHE", Path.home() / ".cache" / "dthc-bridge" / "plasmac")
)
SHIM_SOURCE = Path(__file__).with_name("hal_shim.c")
_APT_TIMEOUT_S = 300.0


class PlasmacUnavailable(RuntimeError):
    """The component could not be found or fetched, or the shim could not be built."""


@dataclass(frozen=True)
class Provisioned:
    component: Path  # the extracted plasmac.so (never modified: runs load private copies)
    shim: Path
    version: str  # the Debian package version it came from
    fetched: bool  # downloaded by this call


def find_component(cache: Path = DEFAULT_CACHE) -> tuple[Path, str] | None:
    """An already extracted component in ``cache``: (path, package version)."""
    for root in sorted(cache.glob("extract-*")):
        so = root / COMPONENT_PATH
        if so.is_file():
            return so, root.name.removeprefix("extract-")
    return None


def _run(cmd: list[str], cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run(  # noqa: S603 - apt-get, dpkg-deb, cc with fixed arguments
        cmd, cwd=cwd, capture_output=True, text=True, timeout=_APT_TIMEOUT_S, check=False
    )


def _download(cache: Path, package: str = PACKAGE) -> Path:
    """``apt-get download <package>`` into ``cache`` (``apt-get update`` once if apt does not
    know the package)."""
    if shutil.which("apt-get") is None:
        raise PlasmacUnavailable(f"apt-get not found: cannot fetch {package}")
    cache.mkdir(parents=True, exist_ok=True)
    # As root, apt's sandbox user must be able to write here; a private dir avoids it.
    result = _run(["apt-get", "-o", "APT::Sandbox::User=root", "download", package], cache)
    if result.returncode != 0 and os.geteuid() == 0:
        _run(["apt-get", "update"])
        result = _run(["apt-get", "-o", "APT::Sandbox::User=root", "download", package], cache)
    debs = sorted(glob.glob(str(cache / f"{package}_*.deb")))
    if result.returncode != 0 or not debs:
        reason = (result.stderr or result.stdout).strip().splitlines()
        raise PlasmacUnavailable(
            f"apt-get download {package} failed: {reason[-1] if reason else 'no package'}"
        )
    return Path(debs[-1])


def _extract(deb: Path, cache: Path) -> tuple[Path, str]:
    version = deb.name.removeprefix(f"{PACKAGE}_").rsplit("_", 1)[0]
    root = cache / f"extract-{version}"
    tmp = cache / f".extract-{os.getpid()}"
    shutil.rmtree(tmp, ignore_errors=True)
    result = _run(["dpkg-deb", "-x", str(deb), str(tmp)])
    so = tmp / COMPONENT_PATH
    if result.returncode != 0 or not so.is_file():
        shutil.rmtree(tmp, ignore_errors=True)
        raise PlasmacUnavailable(
            f"dpkg-deb -x {deb.name}: {result.stderr.strip() or 'no plasmac.so'}"
        )
    # Keep only the component (and the package's copyright): the rest is 60 MB.
    keep = root / COMPONENT_PATH
    keep.parent.mkdir(parents=True, exist_ok=True)
    shutil.copy2(so, keep)
    copyright_file = tmp / "usr/share/doc" / PACKAGE / "copyright"
    if copyright_file.is_file():
        shutil.copy2(copyright_file, root / "copyright")
    shutil.rmtree(tmp, ignore_errors=True)
    return keep, version


def build_shim(cache: Path = DEFAULT_CACHE) -> Path:
    """Compile ``hal_shim.c`` with ``cc`` into ``cache`` (once per source version)."""
    source = SHIM_SOURCE.read_bytes()
    digest = hashlib.sha256(source).hexdigest()[:12]
    out = cache / f"hal_shim-{digest}.so"
    if out.is_file():
        return out
    compiler = os.environ.get("CC") or shutil.which("cc") or shutil.which("gcc")
    if compiler is None:
        raise PlasmacUnavailable("no C compiler (cc) to build the HAL shim")
    cache.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(f".{os.getpid()}.tmp")
    result = _run([compiler, "-shared", "-fPIC", "-O2", "-o", str(tmp), str(SHIM_SOURCE)])
    if result.returncode != 0:
        raise PlasmacUnavailable(f"building the HAL shim failed: {result.stderr.strip()}")
    tmp.replace(out)  # atomic: a parallel run sees a complete file or none
    return out


def provision(
    cache: Path = DEFAULT_CACHE, *, fetch: bool = True, note: object = None
) -> Provisioned:
    """The component (fetched through apt when missing and ``fetch``) and the shim.

    ``note``, when callable, is told what is being done (a download takes a while)."""
    found = find_component(cache)
    fetched = False
    if found is None:
        if not fetch:
            raise PlasmacUnavailable(f"plasmac.so not in {cache} (fetching disabled)")
        if callable(note):
            note(f"fetching {PACKAGE} with apt-get download into {cache} (not installed)")
        deb = _download(cache)
        found = _extract(deb, cache)
        deb.unlink(missing_ok=True)
        fetched = True
    component, version = found
    return Provisioned(component, build_shim(cache), version, fetched)


# --------------------------------------------------------------------------- rs274

RS274_PATH = "usr/bin/rs274"
_PACKAGE_LIBS = "usr/lib"  # the package's own libraries: librs274, libnml, libtooldata, ...
_RS274_TIMEOUT_S = 60.0


@dataclass(frozen=True)
class Rs274:
    """LinuxCNC's standalone interpreter, unpacked: ``binary`` runs with ``lib`` first on
    ``LD_LIBRARY_PATH``."""

    binary: Path
    lib: Path
    version: str  # the Debian package version it came from
    fetched: bool  # downloaded by this call

    def environ(self, base: dict[str, str] | None = None) -> dict[str, str]:
        env = dict(os.environ if base is None else base)
        env["LD_LIBRARY_PATH"] = os.pathsep.join(
            p for p in (str(self.lib), env.get("LD_LIBRARY_PATH", "")) if p
        )
        return env

    def run(
        self, program: Path, *, tool_table: Path, var_file: Path, ini: Path | None = None,
        timeout_s: float = _RS274_TIMEOUT_S,
    ) -> subprocess.CompletedProcess[str]:  # fmt: skip
        """``rs274 [-i ini] -t tool_table -v var_file -g program``: the canonical calls on
        stdout, one per line (``STRAIGHT_TRAVERSE(...)``, ``ARC_FEED(...)``, ...), in the
        program's units; errors on stderr (and a nonzero status). ``var_file`` is written
        back (LinuxCNC saves its parameters at the end): give each run its own. rs274 runs in
        the var file's directory and is given its bare name: it fails to save the file when
        its path is longer than about 95 characters (pytest's temporary paths are)."""
        cmd = [str(self.binary), *(["-i", str(ini.resolve())] if ini else [])]
        cmd += ["-t", str(tool_table.resolve()), "-v", var_file.name]
        cmd += ["-g", str(program.resolve())]
        return subprocess.run(  # noqa: S603 - the unpacked rs274, fixed arguments
            cmd, capture_output=True, text=True, env=self.environ(), stdin=subprocess.DEVNULL,
            cwd=var_file.parent, timeout=timeout_s, check=False,
        )  # fmt: skip


def find_rs274(cache: Path = DEFAULT_CACHE) -> Rs274 | None:
    """An already unpacked ``rs274`` in ``cache``."""
    for root in sorted(cache.glob("rs274-*")):
        binary = root / "bin" / "rs274"
        if binary.is_file():
            return Rs274(binary, root / "lib", root.name.removeprefix("rs274-"), False)
    return None


def _missing_libraries(binary: Path, lib: Path) -> list[str]:
    """The shared libraries ``ldd`` cannot find for ``binary`` with ``lib`` on the path."""
    env = dict(os.environ, LD_LIBRARY_PATH=str(lib))
    result = subprocess.run(  # noqa: S603 - ldd from the system's libc, fixed arguments
        ["ldd", str(binary)], capture_output=True, text=True, env=env,  # noqa: S607 - ldd
        timeout=_APT_TIMEOUT_S, check=False,
    )  # fmt: skip
    return re.findall(r"^\s*(\S+) => not found", result.stdout, re.MULTILINE)


def _providers(missing: Sequence[str], depends: str) -> list[str]:
    """The packages among ``depends`` (a ``Depends`` field) that provide the ``missing``
    libraries, by Debian's naming (``libboost_python311.so.1.74.0`` → the shortest
    dependency named ``libboost-python*``: ``libboost-python1.74.0``)."""
    names = [
        re.split(r"[\s(:]", part.strip(), maxsplit=1)[0] for part in re.split(r"[,|]", depends)
    ]
    chosen: list[str] = []
    for soname in missing:
        stem = re.sub(r"[\d.]+$", "", soname.split(".so")[0]).replace("_", "-")
        candidates = sorted((n for n in names if n.startswith(stem)), key=len)
        if not candidates:
            raise PlasmacUnavailable(f"rs274 needs {soname}: no {PACKAGE} dependency provides it")
        if candidates[0] not in chosen:
            chosen.append(candidates[0])
    return chosen


def _unpack_rs274(work: Path, note: object) -> tuple[Path, str]:
    """Download and unpack into ``work``: the package's rs274 and libraries, then what the
    system lacks. Returns the finished directory (``work/rs274``) and the version."""
    deb = _download(work)
    version = deb.name.removeprefix(f"{PACKAGE}_").rsplit("_", 1)[0]
    tree = work / "tree"
    result = _run(["dpkg-deb", "-x", str(deb), str(tree)])
    if result.returncode != 0 or not (tree / RS274_PATH).is_file():
        raise PlasmacUnavailable(f"dpkg-deb -x {deb.name}: {result.stderr.strip() or 'no rs274'}")
    out = work / "rs274"
    (out / "bin").mkdir(parents=True)
    (out / "lib").mkdir()
    shutil.copy2(tree / RS274_PATH, out / "bin" / "rs274")
    for so in (tree / _PACKAGE_LIBS).glob("lib*.so*"):
        shutil.copy2(so, out / "lib" / so.name)
    copyright_file = tree / "usr/share/doc" / PACKAGE / "copyright"
    if copyright_file.is_file():
        shutil.copy2(copyright_file, out / "copyright")
    missing = _missing_libraries(out / "bin" / "rs274", out / "lib")
    if missing:
        depends = _run(["dpkg-deb", "-f", str(deb), "Depends"]).stdout
        for package in _providers(missing, depends):
            if callable(note):
                note(f"fetching {package} (rs274 needs it) with apt-get download")
            lib_deb = _download(work / package, package)
            lib_tree = work / package / "tree"
            _run(["dpkg-deb", "-x", str(lib_deb), str(lib_tree)])
            for so in lib_tree.glob("usr/lib/**/*.so*"):
                if so.is_file():
                    shutil.copy2(so, out / "lib" / so.name)
        still = _missing_libraries(out / "bin" / "rs274", out / "lib")
        if still:
            raise PlasmacUnavailable(f"rs274 still lacks {', '.join(still)}")
    return out, version


def provision_rs274(
    cache: Path = DEFAULT_CACHE, *, fetch: bool = True, note: object = None
) -> Rs274:
    """``rs274`` from the cache, fetched through apt (``linuxcnc-uspace`` and any library
    the system lacks, unpacked, not installed) when missing and ``fetch``. Parallel callers
    each unpack privately; the first to finish publishes ``rs274-<version>``."""
    found = find_rs274(cache)
    if found is not None:
        return found
    if not fetch:
        raise PlasmacUnavailable(f"rs274 not in {cache} (fetching disabled)")
    if callable(note):
        note(f"fetching {PACKAGE} with apt-get download into {cache} for rs274 (not installed)")
    work = cache / f".rs274-{os.getpid()}"
    shutil.rmtree(work, ignore_errors=True)
    try:
        out, version = _unpack_rs274(work, note)
        with contextlib.suppress(OSError):  # atomic; another caller may have won
            out.rename(cache / f"rs274-{version}")
    finally:
        shutil.rmtree(work, ignore_errors=True)
    found = find_rs274(cache)
    if found is None:
        raise PlasmacUnavailable(f"rs274 could not be unpacked into {cache}")
    return Rs274(found.binary, found.lib, found.version, True)
