"""The proof that the in-process component is LinuxCNC's: replay into the real ``rtapi_app``.

A recorded in-process run (every input pin's value each period, and every output pin's)
is streamed into plasmac loaded by LinuxCNC's own ``halrun`` (``streamer`` drives the
inputs, ``sampler`` records the outputs, all three functions in one 1 ms thread in the
order streamer, plasmac, sampler), and the outputs are compared period by period.

``halrun`` needs LinuxCNC installed (``apt-get install linuxcnc-uspace``, about 430
packages: :func:`install_linuxcnc`, behind ``bench control --install-linuxcnc``). As root
it runs only with ``RTAPI_UID`` set to an unprivileged user and ``RTAPI_FIFO_PATH`` in a
world-writable directory, and then runs POSIX non-realtime, which is all a replay needs.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import tempfile
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

__all__ = [
    "ReplayResult",
    "compare",
    "halrun_available",
    "install_linuxcnc",
    "replay",
    "replay_recording",
]

PACKAGE = "linuxcnc-uspace"
_HAL_TYPES = {"bit": "b", "float": "f", "s32": "s"}
_MAX_STREAM_PINS = 20  # streamer and sampler take at most 20 pins per FIFO


def halrun_available() -> bool:
    return shutil.which("halrun") is not None and shutil.which("halcmd") is not None


def install_linuxcnc() -> str:
    """``apt-get install -y linuxcnc-uspace`` (root only); what happened, in one line."""
    if halrun_available():
        return "halrun already installed"
    if os.geteuid() != 0:
        return f"halrun missing; install {PACKAGE} as root (apt-get install {PACKAGE})"
    env = {**os.environ, "DEBIAN_FRONTEND": "noninteractive"}
    cmd = ["apt-get", "install", "-y", "--no-install-recommends", PACKAGE]
    result = subprocess.run(cmd, capture_output=True, text=True, env=env, check=False)  # noqa: S603 - fixed
    if result.returncode != 0:
        subprocess.run(["apt-get", "update"], capture_output=True, check=False)  # noqa: S607 - apt's own
        result = subprocess.run(cmd, capture_output=True, text=True, env=env, check=False)  # noqa: S603 - fixed
    if result.returncode != 0:
        tail = (result.stderr or result.stdout).strip().splitlines()
        return f"apt-get install {PACKAGE} failed: {tail[-1] if tail else result.returncode}"
    return f"installed {PACKAGE} (halrun for the replay proof)"


@dataclass(frozen=True)
class ReplayResult:
    periods: int  # compared
    matching: int  # periods where every output pin matched
    mismatching_pins: dict[str, int]  # pin -> periods it differed
    outputs: list[str]

    @property
    def identical(self) -> bool:
        return self.periods > 0 and self.matching == self.periods


def _fmt(kind: str, value: float) -> str:
    if kind == "float":
        return repr(float(value))
    return str(int(value))


def _chunks(n: int) -> list[range]:
    return [range(k, min(n, k + _MAX_STREAM_PINS)) for k in range(0, n, _MAX_STREAM_PINS)]


def replay(
    constants: Sequence[tuple[str, str, float]],
    inputs: Sequence[tuple[str, str]],
    rows_in: Sequence[Sequence[float]],
    outputs: Sequence[tuple[str, str]],
    *,
    timeout_s: float = 600.0,
) -> list[list[float]]:
    """Run ``rows_in`` (one value per pin of ``inputs``, (name, type) pairs) through the
    real plasmac under ``halrun``, ``constants`` (name, type, value) set with ``setp``;
    the output rows, one value per pin of ``outputs``.

    Each streamer FIFO is filled before the thread starts (``depth`` holds every row), so
    period k of the thread sees row k; the samplers' FIFOs hold every period too and are
    read after the thread stops. ``halsampler`` prints floats with 6 decimals."""
    n = len(rows_in)
    work = Path(tempfile.mkdtemp(prefix="plasmac-halrun-"))
    os.chmod(work, 0o777)  # noqa: S103 - the unprivileged RTAPI user makes its socket here
    try:
        in_chunks = _chunks(len(inputs))
        out_chunks = _chunks(len(outputs))
        depth = n + 64
        lines = [
            "loadrt threads name1=servo period1=1000000 fp1=1",
            f"loadrt streamer depth={','.join([str(depth)] * len(in_chunks))} cfg="
            + ",".join("".join(_HAL_TYPES[inputs[k][1]] for k in c) for c in in_chunks),
            f"loadrt sampler depth={','.join([str(depth)] * len(out_chunks))} cfg="
            + ",".join("".join(_HAL_TYPES[outputs[k][1]] for k in c) for c in out_chunks),
            "loadrt plasmac",
            *(f"addf streamer.{ch} servo" for ch in range(len(in_chunks))),
            "addf plasmac servo",
            *(f"addf sampler.{ch} servo" for ch in range(len(out_chunks))),
        ]
        lines += [f"setp {name} {_fmt(kind, value)}" for name, kind, value in constants]
        for ch, chunk in enumerate(in_chunks):
            data = work / f"in{ch}.txt"
            data.write_text(
                "".join(
                    " ".join(_fmt(inputs[k][1], row[k]) for k in chunk) + "\n" for row in rows_in
                )
            )
            lines += [
                f"net i{k} streamer.{ch}.pin.{j} => {inputs[k][0]}" for j, k in enumerate(chunk)
            ]
            lines.append(f"loadusr -w halstreamer -c {ch} {data}")
        for ch, chunk in enumerate(out_chunks):
            lines += [
                f"net o{k} {outputs[k][0]} => sampler.{ch}.pin.{j}" for j, k in enumerate(chunk)
            ]
        # The thread runs a little longer than the data (the samplers keep the first n).
        lines += ["start", f"loadusr -w sleep {n / 1000.0 * 1.25 + 1.0:.1f}", "stop"]
        lines += [
            f"loadusr -w halsampler -c {ch} -n {n} {work / f'out{ch}.txt'}"
            for ch in range(len(out_chunks))
        ]
        hal = work / "replay.hal"
        hal.write_text("\n".join(lines) + "\n")
        env = {
            **os.environ,
            "RTAPI_UID": os.environ.get("RTAPI_UID", "65534"),
            # The master's socket: a file in a directory the unprivileged user may write.
            "RTAPI_FIFO_PATH": str(work / "rtapi.sock"),
        }
        started = time.monotonic()
        result = subprocess.run(  # noqa: S603 - LinuxCNC's halrun on our own file
            ["halrun", "-f", str(hal)],  # noqa: S607 - found on PATH by halrun_available
            cwd=work,
            env=env,
            capture_output=True,
            text=True,
            timeout=timeout_s,
            check=False,
        )
        files = [work / f"out{ch}.txt" for ch in range(len(out_chunks))]
        if result.returncode != 0 or not all(f.is_file() for f in files):
            raise RuntimeError(
                f"halrun failed ({result.returncode}, {time.monotonic() - started:.0f} s): "
                f"{(result.stderr or result.stdout).strip()[-600:]}"
            )
        columns = [
            [[float(x) for x in line.split()] for line in f.read_text().splitlines() if line]
            for f in files
        ]
        rows = min(map(len, columns))
        return [[v for col in columns for v in col[k]] for k in range(rows)]
    finally:
        subprocess.run(["halrun", "-U"], capture_output=True, check=False)  # noqa: S607 - as above
        shutil.rmtree(work, ignore_errors=True)


def compare(
    outputs: Sequence[str],
    expected: Sequence[Sequence[float]],
    got: Sequence[Sequence[float]],
    *,
    shift: int = 0,
    float_tol: float = 5.01e-7,
) -> ReplayResult:
    """Period by period, every output pin; ``shift`` offsets ``got`` (a negative control)."""
    mismatching: dict[str, int] = {}
    periods = 0
    matching = 0
    for k, want in enumerate(expected):
        j = k + shift
        if not 0 <= j < len(got):
            continue
        periods += 1
        row_ok = True
        for name, a, b in zip(outputs, want, got[j], strict=True):
            # halsampler prints 6 decimals: floats agree to its rounding, the rest exactly.
            if abs(a - b) > float_tol:
                mismatching[name] = mismatching.get(name, 0) + 1
                row_ok = False
        matching += row_ok
    return ReplayResult(periods, matching, mismatching, list(outputs))


def replay_recording(
    inputs: Sequence[str],
    rows_in: Sequence[Sequence[float]],
    outputs: Sequence[str],
    rows_out: Sequence[Sequence[float]],
    types: Mapping[str, str],
) -> tuple[ReplayResult, ReplayResult]:
    """Replay an in-process run into the real runtime: (aligned, shifted by one period).

    Inputs that never changed are set once with ``setp``; the others are streamed."""
    varying = [k for k, _ in enumerate(inputs) if len({row[k] for row in rows_in}) > 1]
    constants = [
        (name, types[name], rows_in[0][k]) for k, name in enumerate(inputs) if k not in varying
    ]
    got = replay(
        constants,
        [(inputs[k], types[inputs[k]]) for k in varying],
        [[row[k] for k in varying] for row in rows_in],
        [(name, types[name]) for name in outputs],
    )
    return compare(outputs, rows_out, got), compare(outputs, rows_out, got, shift=1)
