"""Serial ports (USB CDC-ACM, FTDI, pty) through pyserial and pyserial-asyncio-fast.

The port is opened exclusively (a second opener fails instead of stealing bytes) and
switched to low-latency mode where the driver supports it (FTDI: 16 ms -> 1 ms latency
timer; a pty refuses with ENOTTY, which is fine). An unplugged USB port, like a pty whose
master was closed, makes pyserial raise SerialException on read or write; the wrapper
then closes the port and we report ``on_lost(TransportError)`` once.
"""

from __future__ import annotations

import os

import serial
import serial_asyncio_fast
import structlog

from .base import BytesCallback, LinkUnavailable, LostCallback, TransportError
from .stream import StreamTransport

__all__ = ["CLOSE_TIMEOUT_S", "SerialTransport", "open_serial"]

log = structlog.get_logger("dthc_bridge.transport")

CLOSE_TIMEOUT_S = 2.0
"""Bound on draining the output queue and closing the port in :meth:`SerialTransport.close`."""


class SerialTransport(StreamTransport):
    """An open serial port. Create with :func:`open_serial` (or ``open_transport``)."""

    kind = "serial port"
    close_timeout_s = CLOSE_TIMEOUT_S
    _lib: serial_asyncio_fast.SerialTransport | None

    async def _open_port(self, baudrate: int) -> None:
        try:
            transport, _ = await serial_asyncio_fast.create_serial_connection(
                self._loop,
                self._protocol,
                self.url,
                baudrate=baudrate,
                exclusive=True,
            )
        except (serial.SerialException, OSError) as exc:
            raise _unavailable(self.url, exc) from exc
        except ValueError as exc:
            raise TransportError(self.url, f"cannot open serial port: {exc}") from exc
        self._opened(transport)
        try:
            port = transport.serial
            if port is not None:
                port.set_low_latency_mode(True)
        except (ValueError, OSError, serial.SerialException) as exc:
            log.debug("serial_low_latency_unsupported", url=self.url, reason=str(exc))

    def discard_output(self) -> None:
        lib = self._lib
        if lib is None or not self.is_open:
            return
        # "flush" in pyserial-asyncio-fast drops its own buffer; reset_output_buffer drops the
        # kernel's queue (tcflush TCOFLUSH).
        lib.flush()
        try:
            if lib.serial is not None:
                lib.serial.reset_output_buffer()
        except (serial.SerialException, OSError, ValueError) as exc:
            log.debug("serial_discard_output_failed", url=self.url, reason=str(exc))

    async def _close_timed_out(self) -> None:
        log.warning("serial_close_timeout", url=self.url, timeout_s=CLOSE_TIMEOUT_S)

    def _lost_detail(self, exc: Exception | None) -> str:
        return f"connection lost: {exc}" if exc is not None else "closed by the driver"


def _unavailable(path: str, exc: OSError) -> LinkUnavailable:
    """What the OS said, in its words: pyserial's message repeats the path and the errno
    ("[Errno 2] could not open port /dev/x: [Errno 2] No such file or directory: '/dev/x'")."""
    code = exc.errno if isinstance(exc.errno, int) else None
    if code is None:
        return LinkUnavailable(path, str(exc))
    reason = os.strerror(code)
    if "exclusively lock" in str(exc):
        reason = f"in use by another program ({reason})"
    return LinkUnavailable(path, reason, code)


async def open_serial(
    path: str, on_bytes: BytesCallback, on_lost: LostCallback, *, baudrate: int = 921_600
) -> SerialTransport:
    """Open the serial port at ``path`` exclusively; TransportError if that fails."""
    transport = SerialTransport(path, on_bytes, on_lost)
    await transport._open_port(baudrate)
    return transport
