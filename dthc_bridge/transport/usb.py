"""Boards with a vendor-specific USB interface (one bulk IN, one bulk OUT endpoint), via pyusb.

pyusb only offers blocking calls, so they all live here, off the event loop:

* opening (find, configure, claim) runs in the loop's default executor;
* one reader thread polls ``ep_in.read(READ_SIZE, READ_TIMEOUT_MS)`` (timeouts are the
  normal idle case) and hands bytes to the loop with ``call_soon_threadsafe``;
* one writer thread drains a ``queue.SimpleQueue`` into ``ep_out.write``, so
  :meth:`UsbTransport.write` never blocks.

Any USB error other than a read timeout (ENODEV after an unplug, EPIPE, a stalled OUT
endpoint) ends the link: both threads stop, the device handle and claimed interface are
released with ``usb.util.dispose_resources``, and ``on_lost(TransportError)`` is called
once, after every byte read before the error has been delivered.

The pyusb entry points (``find``, ``claim_interface``, ``dispose_resources``) are
parameters so tests can run the threads against a fake device.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import queue
import threading
from collections.abc import Callable, Iterable
from typing import Any

import structlog
import usb.core
import usb.util

from .base import BytesCallback, LostCallback, Transport, TransportError
from .url import UsbUrl

__all__ = [
    "JOIN_TIMEOUT_S",
    "READ_SIZE",
    "READ_TIMEOUT_MS",
    "WRITE_TIMEOUT_MS",
    "UsbTransport",
    "open_usb",
]

log = structlog.get_logger("dthc_bridge.transport")

READ_SIZE = 64 * 8
"""Bytes asked for per bulk IN read: eight full-speed packets. A short packet ends it early."""

READ_TIMEOUT_MS = 50
"""Bulk IN read timeout; bounds how long the reader takes to notice a close."""

WRITE_TIMEOUT_MS = 1000
"""Bulk OUT write timeout; a board that accepts nothing for this long is treated as lost."""

JOIN_TIMEOUT_S = 2.0
"""Bound on waiting for both threads to stop in :meth:`UsbTransport.close`."""

_THREAD_POLL_S = 0.002

FindFunc = Callable[..., Any]
"""``usb.core.find``: called as ``find(find_all=True, idVendor=..., idProduct=...)``."""
DeviceFunc = Callable[..., Any]
"""``usb.util.claim_interface(device, number)`` / ``usb.util.dispose_resources(device)``."""


def _is_timeout(exc: BaseException) -> bool:
    return isinstance(exc, usb.core.USBTimeoutError) or (
        isinstance(exc, usb.core.USBError) and exc.errno == errno.ETIMEDOUT
    )


def _describe(what: str, exc: BaseException) -> str:
    if isinstance(exc, usb.core.USBError) and exc.errno == errno.ENODEV:
        return f"device disconnected ({what}: {exc})"
    return f"{what} failed: {exc}"


def _bulk_endpoints(configuration: Iterable[Any]) -> tuple[Any, Any, Any]:
    """Find the first interface with a bulk IN and a bulk OUT endpoint: (interface, in, out)."""
    for interface in configuration:
        bulk_in = bulk_out = None
        for endpoint in interface:
            if usb.util.endpoint_type(endpoint.bmAttributes) != usb.util.ENDPOINT_TYPE_BULK:
                continue
            if usb.util.endpoint_direction(endpoint.bEndpointAddress) == usb.util.ENDPOINT_IN:
                bulk_in = bulk_in or endpoint
            else:
                bulk_out = bulk_out or endpoint
        if bulk_in is not None and bulk_out is not None:
            return interface, bulk_in, bulk_out
    raise LookupError("no interface with a bulk IN and a bulk OUT endpoint")


class UsbTransport(Transport):
    """A claimed USB bulk interface. Create with :func:`open_usb` (or ``open_transport``)."""

    def __init__(
        self,
        url: str,
        link: UsbUrl,
        on_bytes: BytesCallback,
        on_lost: LostCallback,
        *,
        find: FindFunc | None = None,
        claim_interface: DeviceFunc | None = None,
        dispose_resources: DeviceFunc | None = None,
        read_size: int = READ_SIZE,
        read_timeout_ms: int = READ_TIMEOUT_MS,
        write_timeout_ms: int = WRITE_TIMEOUT_MS,
        join_timeout_s: float = JOIN_TIMEOUT_S,
    ) -> None:
        self.url = url
        self.vid = link.vid
        self.pid = link.pid
        self.serial_number = link.serial_number
        self._on_bytes = on_bytes
        self._on_lost = on_lost
        self._find: FindFunc = find if find is not None else usb.core.find
        self._claim: DeviceFunc = (
            claim_interface if claim_interface is not None else usb.util.claim_interface
        )
        self._dispose: DeviceFunc = (
            dispose_resources if dispose_resources is not None else usb.util.dispose_resources
        )
        self._read_size = read_size
        self._read_timeout_ms = read_timeout_ms
        self._write_timeout_ms = write_timeout_ms
        self._join_timeout_s = join_timeout_s
        self._loop = asyncio.get_running_loop()
        self._device: Any = None
        self._ep_in: Any = None
        self._ep_out: Any = None
        self._queue: queue.SimpleQueue[bytes | None] = queue.SimpleQueue()
        self._stop = threading.Event()
        self._write_error: BaseException | None = None
        self._reader_thread: threading.Thread | None = None
        self._writer_thread: threading.Thread | None = None
        self._finished: asyncio.Future[None] = self._loop.create_future()
        self._open = False
        self._closing = False
        self._reported = False

    # --- opening (blocking part runs in the executor) ---------------------------------------

    async def _start(self) -> None:
        opening = self._loop.run_in_executor(None, self._open_blocking)
        try:
            await asyncio.shield(opening)
        except asyncio.CancelledError:
            # The blocking open carries on; release whatever it ends up holding.
            opening.add_done_callback(self._release_after_cancelled_open)
            raise
        self._open = True
        self._reader_thread = threading.Thread(
            target=self._read_loop, name=f"dthc-usb-reader {self.url}", daemon=True
        )
        self._writer_thread = threading.Thread(
            target=self._write_loop, name=f"dthc-usb-writer {self.url}", daemon=True
        )
        self._writer_thread.start()
        self._reader_thread.start()

    def _release_after_cancelled_open(self, opening: asyncio.Future[None]) -> None:
        if not opening.cancelled() and opening.exception() is None:
            self._release_quietly()

    def _open_blocking(self) -> None:
        try:
            device = self._find_device()
        except usb.core.NoBackendError as exc:
            raise TransportError(self.url, f"no libusb backend available: {exc}") from exc
        except (usb.core.USBError, OSError, ValueError) as exc:
            raise TransportError(self.url, f"cannot enumerate USB devices: {exc}") from exc
        try:
            configuration = self._configuration(device)
            interface, self._ep_in, self._ep_out = _bulk_endpoints(configuration)
            number = interface.bInterfaceNumber
            with contextlib.suppress(NotImplementedError):
                if device.is_kernel_driver_active(number):
                    device.detach_kernel_driver(number)
            self._claim(device, number)
        except LookupError as exc:
            self._dispose_quietly(device)
            raise TransportError(self.url, str(exc)) from exc
        except (usb.core.USBError, OSError, ValueError) as exc:
            self._dispose_quietly(device)
            raise TransportError(self.url, f"cannot claim the USB interface: {exc}") from exc
        self._device = device

    def _find_device(self) -> Any:
        candidates = list(self._find(find_all=True, idVendor=self.vid, idProduct=self.pid) or ())
        ids = f"{self.vid:04x}:{self.pid:04x}"
        if not candidates:
            raise TransportError(self.url, f"no USB device {ids} found")
        if self.serial_number is None:
            chosen = candidates[0]
        else:
            chosen = None
            for device in candidates:
                try:
                    matches = device.serial_number == self.serial_number
                except (usb.core.USBError, OSError, ValueError) as exc:
                    # Reading the string descriptor needs access rights (udev rule).
                    log.debug("usb_serial_unreadable", url=self.url, reason=str(exc))
                    matches = False
                if matches and chosen is None:
                    chosen = device
            if chosen is None:
                for device in candidates:
                    self._dispose_quietly(device)
                raise TransportError(
                    self.url,
                    f"{len(candidates)} USB device(s) {ids} found, "
                    f"none with serial number {self.serial_number!r}",
                )
        for device in candidates:
            if device is not chosen:
                self._dispose_quietly(device)
        return chosen

    @staticmethod
    def _configuration(device: Any) -> Any:
        try:
            return device.get_active_configuration()
        except usb.core.USBError:  # unconfigured: select the first configuration
            device.set_configuration()
            return device.get_active_configuration()

    # --- Transport --------------------------------------------------------------------------

    @property
    def is_open(self) -> bool:
        return self._open and not self._stop.is_set()

    def write(self, data: bytes) -> None:
        if not self.is_open:
            raise TransportError(self.url, "write on a closed USB link")
        if data:
            self._queue.put(bytes(data))

    def discard_output(self) -> None:
        if not self.is_open:
            return
        with contextlib.suppress(queue.Empty):
            while True:
                self._queue.get_nowait()

    async def close(self) -> None:
        if self._reader_thread is None:
            return
        first = self._open
        self._open = False
        self._closing = True
        self._stop.set()
        self._queue.put(None)  # after any queued bytes: the writer sends them, then stops
        try:
            async with asyncio.timeout(self._join_timeout_s):
                await asyncio.shield(self._finished)
                for thread in (self._reader_thread, self._writer_thread):
                    # A thread's end is not awaitable; the reader signalled _finished as its
                    # last step, so this spins for a few milliseconds at most.
                    while thread is not None and thread.is_alive():  # noqa: ASYNC110
                        await asyncio.sleep(_THREAD_POLL_S)
        except TimeoutError:
            log.warning("usb_close_timeout", url=self.url, timeout_s=self._join_timeout_s)
        if first:
            self._report(None)

    # --- threads ----------------------------------------------------------------------------

    def _read_loop(self) -> None:
        error: BaseException | None = None
        try:
            while not self._stop.is_set():
                try:
                    data = self._ep_in.read(self._read_size, timeout=self._read_timeout_ms)
                except usb.core.USBError as exc:
                    if _is_timeout(exc):
                        continue
                    if not self._stop.is_set():
                        error = exc
                    break
                if data:
                    self._post(self._deliver, bytes(data))
        except Exception as exc:  # a bug or an unexpected backend error still ends the link
            error = exc
        finally:
            self._stop.set()
            self._queue.put(None)
            if self._writer_thread is not None:
                self._writer_thread.join(self._write_timeout_ms / 1000 + 1.0)
            self._release_quietly()
            if error is not None:
                self._post(self._reader_exited, TransportError(self.url, _describe("read", error)))
            elif self._write_error is not None:
                detail = _describe("write", self._write_error)
                self._post(self._reader_exited, TransportError(self.url, detail))
            else:
                self._post(self._reader_exited, None)

    def _write_loop(self) -> None:
        while True:
            data = self._queue.get()
            if data is None:
                return
            try:
                while data:
                    sent = self._ep_out.write(data, timeout=self._write_timeout_ms)
                    if sent <= 0:
                        raise usb.core.USBError("bulk OUT accepted no bytes")
                    data = data[sent:]
            except Exception as exc:  # any failure, timeouts included, ends the link
                if not self._closing:
                    self._write_error = exc
                self._stop.set()
                return

    def _post(self, callback: Callable[..., None], *args: object) -> None:
        with contextlib.suppress(RuntimeError):  # the loop is already closed: nobody listens
            self._loop.call_soon_threadsafe(callback, *args)

    def _release_quietly(self) -> None:
        device, self._device = self._device, None
        if device is not None:
            self._dispose_quietly(device)

    def _dispose_quietly(self, device: Any) -> None:
        try:
            self._dispose(device)
        except Exception as exc:  # releasing a vanished device may fail; nothing to do
            log.debug("usb_dispose_failed", url=self.url, reason=str(exc))

    # --- on the loop ------------------------------------------------------------------------

    def _deliver(self, data: bytes) -> None:
        if self._open:
            self._on_bytes(data)

    def _reader_exited(self, error: TransportError | None) -> None:
        if not self._finished.done():
            self._finished.set_result(None)
        if self._closing:
            return  # close() reports on_lost(None)
        self._open = False
        self._report(error or TransportError(self.url, "USB reader stopped"))

    def _report(self, exc: Exception | None) -> None:
        if not self._reported:
            self._reported = True
            self._on_lost(exc)


async def open_usb(
    url: str,
    link: UsbUrl,
    on_bytes: BytesCallback,
    on_lost: LostCallback,
    *,
    find: FindFunc | None = None,
    claim_interface: DeviceFunc | None = None,
    dispose_resources: DeviceFunc | None = None,
    read_timeout_ms: int = READ_TIMEOUT_MS,
    write_timeout_ms: int = WRITE_TIMEOUT_MS,
) -> UsbTransport:
    """Find, claim and start reading the board's bulk interface; TransportError if that fails."""
    transport = UsbTransport(
        url,
        link,
        on_bytes,
        on_lost,
        find=find,
        claim_interface=claim_interface,
        dispose_resources=dispose_resources,
        read_timeout_ms=read_timeout_ms,
        write_timeout_ms=write_timeout_ms,
    )
    await transport._start()
    return transport
