"""Find LinuxCNC's ``plasmac.so`` and build the HAL shim that hosts it.

LinuxCNC is GPL-2: nothing of it is in this repository. The component comes from the user's
own Debian package ``linuxcnc-uspace``, downloaded with ``apt-get download`` into a cache
directory and unpacked with ``dpkg-deb -x`` (not installed). The shim (``hal_shim.c``, ours)
is compiled with the system C compiler into the same cache, once per source version.
"""

from __future__ import annotations

import glob
import hashlib
import os
import shutil
import subprocess
from dataclasses import dataclass
from pathlib import Path

__all__ = [
    "DEFAULT_CACHE",
    "PACKAGE",
    "PlasmacUnavailable",
    "Provisioned",
    "build_shim",
    "find_component",
    "provision",
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


def _download(cache: Path) -> Path:
    """``apt-get download linuxcnc-uspace`` into ``cache`` (``apt-get update`` once if apt
    does not know the package)."""
    if shutil.which("apt-get") is None:
        raise PlasmacUnavailable("apt-get not found: cannot fetch linuxcnc-uspace")
    cache.mkdir(parents=True, exist_ok=True)
    # As root, apt's sandbox user must be able to write here; a private dir avoids it.
    result = _run(["apt-get", "-o", "APT::Sandbox::User=root", "download", PACKAGE], cache)
    if result.returncode != 0 and os.geteuid() == 0:
        _run(["apt-get", "update"])
        result = _run(["apt-get", "-o", "APT::Sandbox::User=root", "download", PACKAGE], cache)
    debs = sorted(glob.glob(str(cache / f"{PACKAGE}_*.deb")))
    if result.returncode != 0 or not debs:
        reason = (result.stderr or result.stdout).strip().splitlines()
        raise PlasmacUnavailable(
            f"apt-get download {PACKAGE} failed: {reason[-1] if reason else 'no package'}"
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
