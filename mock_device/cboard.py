"""The reference firmware's board logic (firmware/board/), loaded as a shared library.

``firmware/build/host/libdthc_board.so`` is the very C the AVR builds run, over
``firmware/host/hal_host.c``: a hardware layer whose pins, ADC, step generator, clock and
UART are a struct the host reads and writes (no callbacks). ``make -C firmware host``
builds it; :func:`library_path` builds it when it is missing or older than its sources.

Loaded with :mod:`ctypes` (the standard library): a binding library (cffi, pybind11) would
add a dependency and a build step for five plain C functions and two structs.

The board logic keeps its state in C globals, as on the MCU: each :class:`CBoard` loads a
private copy of the library (a copied file, so the dynamic loader maps it again), so several
boards (a test's, a reboot's) never share state.
"""

from __future__ import annotations

import ctypes
import fcntl
import os
import shutil
import subprocess
import tempfile
import weakref
from pathlib import Path

__all__ = ["HOST_TX_CAP", "CBoard", "HostState", "library_path"]

ROOT = Path(__file__).resolve().parents[1]
FIRMWARE = ROOT / "firmware"
HOST_TX_CAP = 16384  # hal_host.c's transmit buffer
HOST_RX_CAP = 8192

# The library builds: the board as it ships, and protocol 1.0's lease (latched at rest too:
# mock_device.variants' idle-lapse-latched board).
LIBRARIES = {
    "": "libdthc_board.so",
    "lease-1.0": "libdthc_board-lease-1.0.so",
}


class HostHal(ctypes.Structure):
    """hal_host.c's host_hal_t (the same fields in the same order)."""

    _fields_ = [
        ("inputs", ctypes.c_uint16),
        ("arc_raw", ctypes.c_uint16),
        ("xy_speed_dmm_s", ctypes.c_uint16),
        ("torch", ctypes.c_uint8),
        ("ohmic", ctypes.c_uint8),
        ("current_da", ctypes.c_uint16),
        ("steps", ctypes.c_int32),
        ("rate", ctypes.c_int32),
        ("lo", ctypes.c_int32),
        ("hi", ctypes.c_int32),
        ("now_us", ctypes.c_uint64),
        ("period_us", ctypes.c_uint16),
        ("tx_len", ctypes.c_uint32),
        ("tx", ctypes.c_uint8 * HOST_TX_CAP),
    ]


class HostState(ctypes.Structure):
    """hal_host.c's host_state_t: a snapshot of the board's state."""

    _fields_ = [
        ("boot_id", ctypes.c_uint32),
        ("last_rx_us", ctypes.c_uint32),
        ("event_counter", ctypes.c_uint32),
        ("crc_errors", ctypes.c_uint32),
        ("framing_errors", ctypes.c_uint32),
        ("faults", ctypes.c_uint16),
        ("inputs", ctypes.c_uint16),
        ("lease_ms", ctypes.c_uint16),
        ("zvel_seq", ctypes.c_uint16),
        ("rx_duplicates", ctypes.c_uint16),
        ("sample_seq", ctypes.c_uint16),
        ("period_us", ctypes.c_uint16),
        ("batch_size", ctypes.c_uint8),
        ("session", ctypes.c_uint8),
        ("lease", ctypes.c_uint8),
        ("zvel_applied", ctypes.c_uint8),
        ("status", ctypes.c_uint8),
        ("torch", ctypes.c_uint8),
        ("ohmic", ctypes.c_uint8),
    ]


def _sources() -> list[Path]:
    return [
        *FIRMWARE.glob("board/*.[ch]"),
        FIRMWARE / "hal" / "hal.h",
        FIRMWARE / "host" / "hal_host.c",
        FIRMWARE / "Makefile",
        *(ROOT / "firmware_protocol" / "c").glob("*.[ch]"),
    ]


def library_path(build: str = "") -> Path:
    """The library (``build``: a key of LIBRARIES), built first when it is missing or older
    than a source (``make -C firmware host``, under a lock: test workers share it)."""
    lib = FIRMWARE / "build" / "host" / LIBRARIES[build]
    if _fresh(lib):
        return lib
    make = shutil.which("make")
    if make is None or not (shutil.which("cc") or shutil.which("gcc")):
        raise RuntimeError(
            f"{lib} is missing and there is no C compiler to build it: "
            "apt-get install gcc make, then make -C firmware host"
        )
    lib.parent.mkdir(parents=True, exist_ok=True)
    with (lib.parent / ".build.lock").open("w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not _fresh(lib):
            subprocess.run(  # noqa: S603 - our own Makefile, no outside input
                [make, "--no-print-directory", "-C", str(FIRMWARE), "host"],
                check=True, capture_output=True, text=True, timeout=300,
            )  # fmt: skip
    return lib


def _fresh(lib: Path) -> bool:
    if not lib.exists():
        return False
    built = lib.stat().st_mtime
    return all(src.stat().st_mtime <= built for src in _sources())


def _load_private_copy(lib: Path) -> ctypes.CDLL:
    """A copy of ``lib`` loaded on its own: the loader maps a file once per path."""
    fd, name = tempfile.mkstemp(prefix="dthc_board_", suffix=".so")
    try:
        with os.fdopen(fd, "wb") as out, lib.open("rb") as src:
            shutil.copyfileobj(src, out)
        return ctypes.CDLL(name, mode=os.RTLD_LOCAL)
    finally:
        os.unlink(name)  # the mapping stays


def _unload(handle: int) -> None:
    import _ctypes  # noqa: PLC0415 - CPython's dlclose, only at finalisation

    _ctypes.dlclose(handle)


class CBoard:
    """One board: the C board logic and its hardware layer's state (``hal``)."""

    def __init__(self, build: str = "") -> None:
        lib = _load_private_copy(library_path(build))
        lib.host_hal.restype = ctypes.POINTER(HostHal)
        lib.host_init.argtypes = [
            ctypes.c_char_p, ctypes.c_uint32, ctypes.c_int32, ctypes.c_int32, ctypes.c_int32,
            ctypes.c_int32, ctypes.c_int32, ctypes.c_uint16, ctypes.c_uint8, ctypes.c_int32,
            ctypes.c_uint32,
        ]  # fmt: skip
        lib.host_init.restype = None
        lib.host_rx.argtypes = [ctypes.c_char_p, ctypes.c_uint32]
        lib.host_rx.restype = ctypes.c_uint32
        lib.host_advance.restype = None
        lib.host_tick.restype = None
        lib.host_state.argtypes = [ctypes.POINTER(HostState)]
        lib.host_state.restype = None
        self._lib = lib
        self.hal: HostHal = lib.host_hal().contents
        self._state = HostState()
        self._state_ref = ctypes.byref(self._state)
        # Unmapped with the board, not at interpreter exit (something may still read it).
        weakref.finalize(self, _unload, lib._handle).atexit = False

    def init(
        self, *, serial: str, capabilities: int, z_min_um: int, z_max_um: int, z_boot_um: int,
        z_max_speed_um_s: int, z_accel_um_s2: int, z_steps_per_mm: int, reset_reason: int,
        z_home_um: int, entropy: int,
    ) -> None:  # fmt: skip
        """Power-on (board_init) with this hardware description."""
        self._lib.host_init(
            serial.encode("ascii"), capabilities, z_min_um, z_max_um, z_boot_um,
            z_max_speed_um_s, z_accel_um_s2, z_steps_per_mm, reset_reason, z_home_um, entropy,
        )  # fmt: skip

    def receive(self, data: bytes) -> None:
        """Host bytes arriving now; the board's main loop handles them at once."""
        rx = self._lib.host_rx
        while data:
            taken = rx(data, len(data))
            data = data[taken:]

    def advance(self) -> None:
        """The clock and the step generator run one sample period (the tick follows)."""
        self._lib.host_advance()

    def tick(self) -> None:
        """The sample tick at the clock's time, then the main loop."""
        self._lib.host_tick()

    def take_tx(self) -> bytes:
        """What the board sent since the last call."""
        hal = self.hal
        n = hal.tx_len
        if not n:
            return b""
        data = ctypes.string_at(ctypes.addressof(hal) + HostHal.tx.offset, n)
        hal.tx_len = 0
        return data

    def state(self) -> HostState:
        """A snapshot of the board's state, as it is now."""
        self._lib.host_state(self._state_ref)
        return self._state
