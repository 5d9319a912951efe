"""Where the source checkout is, which build tools are missing, and ``make`` for what is
stale: the host program (``firmware/emulator``) and the firmware ELF (``firmware``)."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path
from typing import Final

__all__ = [
    "ARC_INPUTS",
    "BOOTLOADER_AVRDUDE",
    "BOOTLOADER_HEX",
    "INSTALL_HINT",
    "MCUS",
    "MCU_BOOTLOADERS",
    "BuildError",
    "EmulatedBoardError",
    "ToolsMissing",
    "arduino_bootloader",
    "checkout_root",
    "ensure_built",
    "firmware_elf",
    "firmware_hex",
    "host_binary",
    "missing_tools",
    "selftest_elf",
]

MCUS: Final = ("atmega2560", "atmega328p")
# How the firmware reads the arc voltage: the ADC (both MCUs), or a voltage-to-frequency
# card (THCAD type) on the Mega 2560's T5 pin (a build of its own: the Nano has no such
# option, its T1 pin is the OHMIC input).
ARC_INPUTS: Final = ("adc", "vtof")
VTOF_MCUS: Final = ("atmega2560",)
INSTALL_HINT: Final = (
    "sudo apt-get install simavr libsimavr-dev libsimavrparts1 gcc-avr avr-libc "
    "binutils-avr libelf-dev pkg-config"
)
BUILD_TIMEOUT_S: Final = 600.0
AVR_LIBC_HEADER: Final = Path("/usr/lib/avr/include/avr/io.h")


class EmulatedBoardError(Exception):
    """Root of this package's errors."""


class ToolsMissing(EmulatedBoardError):
    def __init__(self, missing: list[str]) -> None:
        self.missing = missing
        super().__init__(f"missing: {', '.join(missing)}; install them with: {INSTALL_HINT}")


class BuildError(EmulatedBoardError):
    def __init__(self, command: list[str], status: int) -> None:
        self.command = command
        self.status = status
        super().__init__(f"{' '.join(command)} failed (exit status {status})")


def checkout_root() -> Path:
    """The source checkout this package was installed (editable) from: it holds firmware/."""
    root = Path(__file__).resolve().parents[2]
    if not (root / "firmware" / "emulator" / "Makefile").is_file():
        raise EmulatedBoardError(
            f"no firmware/emulator/Makefile under {root}: dthc_tools must be installed "
            "editable from a source checkout (pip install -e .) to run the emulated board"
        )
    return root


def host_binary(root: Path) -> Path:
    return root / "firmware" / "emulator" / "build" / "dthc-emulated-board-host"


def firmware_elf(root: Path, mcu: str, arc_input: str = "adc") -> Path:
    """The firmware's ELF for ``mcu`` and its arc front end (``make -C firmware`` builds
    all three: atmega2560, atmega328p, atmega2560-vtof)."""
    if arc_input not in ARC_INPUTS:
        raise EmulatedBoardError(f"arc input {arc_input!r}: one of {', '.join(ARC_INPUTS)}")
    if arc_input == "adc":
        return root / "firmware" / "build" / mcu / "dthc-firmware.elf"
    if mcu not in VTOF_MCUS:
        raise EmulatedBoardError(
            f"the {mcu} build has no V-to-F arc input (its T1 pin is the OHMIC input); "
            "the Mega 2560's is T5 (D47)"
        )
    return root / "firmware" / "build" / f"{mcu}-{arc_input}" / "dthc-firmware.elf"


def firmware_hex(root: Path, mcu: str, arc_input: str = "adc") -> Path:
    """The HEX beside the ELF: what a table owner flashes with avrdude."""
    return firmware_elf(root, mcu, arc_input).with_suffix(".hex")


# Arduino's own bootloaders from Debian's arduino-core-avr (loaded from /usr/share at run
# time, never copied): the Mega 2560's stk500v2 (avrdude -c wiring, 115200 baud), the Uno's
# and new Nano's optiboot (-c arduino, 115200) and the old Nano's ATmegaBOOT (-c arduino,
# 57600). Optiboot is built from Debian's own source of it (firmware/emulator/Makefile):
# Debian's prebuilt optiboot_atmega328.hex (arduino-core-avr 1.8.7+dfsg-1~deb12u1) is 532
# bytes, 20 past the 512-byte boot section it must fit (code at 0x8000-0x8013, beyond the
# 328P's flash); built without its start-up LED flashes it is 496.
ARDUINO_BOOTLOADERS: Final = Path("/usr/share/arduino/hardware/arduino/avr/bootloaders")
OPTIBOOT_BUILT: Final = Path("firmware/emulator/build/optiboot_atmega328.hex")  # in the checkout
BOOTLOADER_HEX: Final = {
    "stk500v2": ARDUINO_BOOTLOADERS / "stk500v2" / "stk500boot_v2_mega2560.hex",
    "optiboot": OPTIBOOT_BUILT,
    "atmegaboot": ARDUINO_BOOTLOADERS / "atmega" / "ATmegaBOOT_168_atmega328.hex",
}
# Each MCU's bootloaders, the one an Arduino of today ships with first.
MCU_BOOTLOADERS: Final = {
    "atmega2560": ("stk500v2",),
    "atmega328p": ("optiboot", "atmegaboot"),
}
# avrdude's programmer and baud rate for each: as firmware/README.md tells owners.
BOOTLOADER_AVRDUDE: Final = {
    "stk500v2": ("wiring", 115_200),
    "optiboot": ("arduino", 115_200),
    "atmegaboot": ("arduino", 57_600),
}
BOOTLOADER_INSTALL_HINT: Final = "sudo apt-get install arduino-core-avr avrdude"


def arduino_bootloader(mcu: str, kind: str | None = None) -> Path:
    """Arduino's bootloader HEX for ``mcu`` (``kind``: one of MCU_BOOTLOADERS[mcu], the
    first by default) from Debian's arduino-core-avr (EmulatedBoardError naming the package
    when it is not installed, or the make target when optiboot is not built)."""
    kinds = MCU_BOOTLOADERS.get(mcu, ())
    if not kinds:
        raise EmulatedBoardError(f"no Arduino bootloader known for {mcu}")
    kind = kind or kinds[0]
    if kind not in kinds:
        raise EmulatedBoardError(f"{mcu} has no {kind} bootloader (it has {', '.join(kinds)})")
    path = BOOTLOADER_HEX[kind]
    if not path.is_absolute():
        path = checkout_root() / path
        if not path.is_file():
            raise EmulatedBoardError(
                f"{path} is not built: make -C firmware/emulator optiboot "
                f"(needs {BOOTLOADER_INSTALL_HINT.split(' install ')[-1]})"
            )
    if not path.is_file():
        raise EmulatedBoardError(f"{path} is missing: {BOOTLOADER_INSTALL_HINT}")
    return path


def selftest_elf(root: Path, mcu: str) -> Path:
    """The harness's own test program (echo, steps, ADC, inputs), not the firmware."""
    return root / "firmware" / "emulator" / "build" / f"selftest-{mcu}.elf"


def _pkg_exists(name: str) -> bool:
    if shutil.which("pkg-config") is None:
        return False
    done = subprocess.run(  # noqa: S603 - fixed arguments
        ["pkg-config", "--exists", name],  # noqa: S607 - found on PATH, as make finds it
        check=False,
        capture_output=True,
        timeout=30,
    )
    return done.returncode == 0


def missing_tools() -> list[str]:
    """What the build needs and this machine lacks (empty when all is there)."""
    missing = [tool for tool in ("make", "gcc", "avr-gcc", "pkg-config") if not shutil.which(tool)]
    if not AVR_LIBC_HEADER.is_file():
        missing.append("avr-libc")
    if shutil.which("pkg-config"):
        missing += [f"{pkg} (pkg-config)" for pkg in ("simavr", "libelf") if not _pkg_exists(pkg)]
    return missing


def _make(directory: Path, *targets: str) -> None:
    command = ["make", "-C", str(directory), *targets]
    # make's chatter goes to stderr: stdout carries READY and the control replies.
    done = subprocess.run(  # noqa: S603 - make, our own Makefiles
        command, check=False, stdout=sys.stderr, stderr=sys.stderr, timeout=BUILD_TIMEOUT_S
    )
    if done.returncode != 0:
        raise BuildError(command, done.returncode)


def ensure_built(root: Path, *, firmware: bool = True) -> None:
    """``make`` the host program and the self-test ELFs, and the firmware unless
    ``firmware`` is False (make rebuilds only what is missing or stale). ToolsMissing
    names what to install; BuildError the command that failed."""
    missing = missing_tools()
    if missing:
        raise ToolsMissing(missing)
    _make(root / "firmware" / "emulator", "all")  # host, self-tests, optiboot if its source is here
    if firmware:
        if not (root / "firmware" / "Makefile").is_file():
            raise EmulatedBoardError(f"no firmware/Makefile under {root}: the firmware is missing")
        _make(root / "firmware")
