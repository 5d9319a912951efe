"""Serial ports (USB CDC-ACM, FTDI, pty) through pyserial and pyserial-asyncio-fast.

The port is opened exclusively (a second opener fails instead of stealing bytes) and
switched to low-latency mode where the driver supports it (FTDI: 16 ms -> 1 ms latency
timer; a pty refuses with ENOTTY, which is fine). An unplugged USB port, like a pty whose
master was closed, makes pyserial raise SerialException on read or write; the wrapper
then closes the port and we report ``on_lost(TransportError)`` once.
"""

from __future__ import annotations

import asyncio

import serial
import serial_asyncio_fast
import structlog

from .base import BytesCallback, LostCallback, Transport, TransportError

__all__ = ["CLOSE_TIMEOUT_S", "SerialTransport", "open_serial"]

log = structlog.get_logger("dthc_bridge.transport")

CLOSE_TIMEOUT_S = 2.0
"""Bound on draining the output queue and closing the port in :meth:`SerialTransport.close`."""


class _SerialProtocol(asyncio.Protocol):
    """Forwards pyserial-asyncio-fast's protocol calls to the owning :class:`SerialTransport`."""

    def __init__(self, owner: SerialTransport) -> None:
        self._owner = owner

    def data_received(self, data: bytes) -> None:
        self._owner._data_received(data)

    def connection_lost(self, exc: Exception | None) -> None:
        self._owner._connection_lost(exc)


class SerialTransport(Transport):
    """An open serial port. Create with :func:`open_serial` (or ``open_transport``)."""

    def __init__(self, url: str, on_bytes: BytesCallback, on_lost: LostCallback) -> None:
        self.url = url
        self._on_bytes = on_bytes
        self._on_lost = on_lost
        self._loop = asyncio.get_running_loop()
        self._lib_transport: serial_asyncio_fast.SerialTransport | None = None
        self._open = False
        self._closing = False
        self._reported = False
        self._released: asyncio.Future[None] = self._loop.create_future()

    async def _open_port(self, baudrate: int) -> None:
        try:
            transport, _ = await serial_asyncio_fast.create_serial_connection(
                self._loop,
                lambda: _SerialProtocol(self),
                self.url,
                baudrate=baudrate,
                exclusive=True,
            )
        except (serial.SerialException, OSError, ValueError) as exc:
            raise TransportError(self.url, f"cannot open serial port: {exc}") from exc
        self._lib_transport = transport
        self._open = True
        try:
            port = transport.serial
            if port is not None:
                port.set_low_latency_mode(True)
        except (ValueError, OSError, serial.SerialException) as exc:
            log.debug("serial_low_latency_unsupported", url=self.url, reason=str(exc))

    @property
    def is_open(self) -> bool:
        lib = self._lib_transport
        return self._open and lib is not None and not lib.is_closing()

    def write(self, data: bytes) -> None:
        lib = self._lib_transport
        if lib is None or not self.is_open:
            raise TransportError(self.url, "write on a closed serial port")
        # Errors surface asynchronously: the wrapper aborts and connection_lost reports them.
        lib.write(data)

    def discard_output(self) -> None:
        lib = self._lib_transport
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

    async def close(self) -> None:
        lib = self._lib_transport
        if lib is None:
            return
        first = self._open
        self._open = False
        self._closing = True
        if first and not lib.is_closing():
            lib.close()  # drains queued bytes, then closes the port
        try:
            async with asyncio.timeout(CLOSE_TIMEOUT_S):
                await asyncio.shield(self._released)
        except TimeoutError:
            log.warning("serial_close_timeout", url=self.url, timeout_s=CLOSE_TIMEOUT_S)
        if first:
            self._report(None)

    # --- called by _SerialProtocol ----------------------------------------------------------

    def _data_received(self, data: bytes) -> None:
        if self._open:
            self._on_bytes(data)

    def _connection_lost(self, exc: Exception | None) -> None:
        if not self._released.done():
            self._released.set_result(None)
        if self._closing:
            return  # close() reports on_lost(None)
        self._open = False
        detail = f"connection lost: {exc}" if exc is not None else "closed by the driver"
        error = TransportError(self.url, detail)
        error.__cause__ = exc
        self._report(error)

    def _report(self, exc: Exception | None) -> None:
        if not self._reported:
            self._reported = True
            self._on_lost(exc)


async def open_serial(
    path: str, on_bytes: BytesCallback, on_lost: LostCallback, *, baudrate: int = 921_600
) -> SerialTransport:
    """Open the serial port at ``path`` exclusively; TransportError if that fails."""
    transport = SerialTransport(path, on_bytes, on_lost)
    await transport._open_port(baudrate)
    return transport
