"""LinuxCNC's plasmac component in this process: a private copy, its pins, one call a period.

plasmac keeps its state in module globals (``option singleton``), so every
:class:`PlasmacComponent` loads its own copy of ``plasmac.so`` (the file copied to a
temporary name, so the dynamic loader maps it afresh). The HAL shim is loaded once per
process, globally, so the copies' HAL symbols resolve to it; each copy reads back the pins
and the function it registered by index.
"""

from __future__ import annotations

import _ctypes
import ctypes
import os
import shutil
import tempfile
from pathlib import Path
from typing import ClassVar

__all__ = ["PERIOD_NS", "Pin", "PlasmacComponent"]

PERIOD_NS = 1_000_000  # QtPlasmaC's servo thread: 1 ms
_BIT, _FLOAT, _S32 = 1, 2, 3
_OUT = 32
_CTYPES: dict[int, type[ctypes.c_bool] | type[ctypes.c_double] | type[ctypes.c_int32]] = {
    _BIT: ctypes.c_bool,
    _FLOAT: ctypes.c_double,
    _S32: ctypes.c_int32,
}


class Pin:
    """One pin: ``value`` reads and writes the component's memory."""

    __slots__ = ("_cell", "name", "output", "type")

    def __init__(self, name: str, kind: int, output: bool, address: int) -> None:
        self.name = name
        self.type = {_BIT: "bit", _FLOAT: "float", _S32: "s32"}[kind]
        self.output = output
        self._cell = _CTYPES[kind].from_address(address)

    @property
    def value(self) -> float:
        return float(self._cell.value)

    @value.setter
    def value(self, v: float) -> None:
        self._cell.value = bool(v) if self.type == "bit" else (int(v) if self.type == "s32" else v)


class PlasmacComponent:
    """``pins['plasmac.arc-voltage-in'].value = ...``; ``run()`` calls the function once."""

    _shim: ClassVar[ctypes.CDLL | None] = None
    _shim_path: ClassVar[Path | None] = None

    def __init__(self, component: Path, shim: Path) -> None:
        lib = self._load_shim(shim)
        self._dir = Path(tempfile.mkdtemp(prefix="plasmac-"))
        private = self._dir / "plasmac.so"
        shutil.copyfile(component, private)
        first_pin = lib.shim_pin_count()
        first_funct = lib.shim_funct_count()
        self._lib = ctypes.CDLL(str(private), mode=os.RTLD_NOW | os.RTLD_LOCAL)
        rc = self._lib.rtapi_app_main()
        if rc != 0 or lib.shim_funct_count() != first_funct + 1:
            raise RuntimeError(f"plasmac rtapi_app_main failed ({rc})")
        self._funct = first_funct
        self.pins: dict[str, Pin] = {}
        for i in range(first_pin, lib.shim_pin_count()):
            name = lib.shim_pin_name(i).decode()
            self.pins[name] = Pin(
                name, lib.shim_pin_type(i), lib.shim_pin_dir(i) == _OUT, lib.shim_pin_data(i)
            )
        self._messages_seen = lib.shim_message_count()
        self._run = lib.shim_run
        self._first_pin = first_pin
        self._pin_count = len(self.pins)
        self._closed = False

    @classmethod
    def _load_shim(cls, shim: Path) -> ctypes.CDLL:
        if cls._shim is None:
            lib = ctypes.CDLL(str(shim), mode=os.RTLD_NOW | os.RTLD_GLOBAL)
            lib.shim_pin_name.restype = ctypes.c_char_p
            lib.shim_pin_data.restype = ctypes.c_void_p
            lib.shim_message.restype = ctypes.c_char_p
            lib.shim_message.argtypes = [ctypes.c_long]
            lib.shim_message_count.restype = ctypes.c_long
            lib.shim_run.argtypes = [ctypes.c_int, ctypes.c_long, ctypes.c_int]
            lib.shim_run.restype = None
            lib.shim_release.argtypes = [ctypes.c_int, ctypes.c_int, ctypes.c_int]
            lib.shim_release.restype = None
            cls._shim = lib
            cls._shim_path = shim
        return cls._shim

    def pin(self, short: str) -> Pin:
        """``pin('arc-voltage-in')`` for ``plasmac.arc-voltage-in``."""
        return self.pins[f"plasmac.{short}"]

    def run(self, periods: int = 1) -> None:
        """Call the component's function ``periods`` times, 1 ms each."""
        self._run(self._funct, PERIOD_NS, periods)

    def messages(self) -> list[str]:
        """Messages the component printed since the last call (its errors: pauses' reasons)."""
        lib = self._shim
        assert lib is not None
        end = lib.shim_message_count()
        out = [
            lib.shim_message(i).decode(errors="replace").strip()
            for i in range(max(self._messages_seen, end - 64), end)
        ]
        self._messages_seen = end
        return out

    def close(self) -> None:
        """Release the pins, unload the private copy and delete it. The pins are unusable
        afterwards."""
        if self._closed:
            return
        self._closed = True
        assert self._shim is not None
        self.pins.clear()
        self._shim.shim_release(self._first_pin, self._pin_count, self._funct)
        _ctypes.dlclose(self._lib._handle)
        shutil.rmtree(self._dir, ignore_errors=True)

    def __enter__(self) -> PlasmacComponent:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
