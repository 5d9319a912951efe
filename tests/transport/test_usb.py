"""USB bulk transport against a fake pyusb backend: threads, unplug, release, device choice.

The fake device mimics what pyusb hands the transport: a configuration of interfaces of
endpoints with ``bEndpointAddress``/``bmAttributes``, ``read`` that raises USBTimeoutError
when idle, and ``write``. The board's first interface has only an interrupt endpoint (like
a CDC control interface) so the transport must pick the bulk pair on the second one.
"""

from __future__ import annotations

import errno
import queue
import threading
from collections.abc import Iterator
from typing import Any

import pytest
import usb.core

from dthc_bridge.transport import TransportError, open_transport, parse_link_url
from dthc_bridge.transport.url import UsbUrl
from dthc_bridge.transport.usb import UsbTransport, open_usb

from .helpers import Recorder, poll_until, settle

BULK, INTERRUPT = 0x02, 0x03
VID, PID = 0x1209, 0xD7C0


def enodev() -> usb.core.USBError:
    return usb.core.USBError("No such device (it may have been disconnected)", errno=errno.ENODEV)


class FakeInEndpoint:
    """Bulk IN: the test queues bytes (or an exception to raise) for the reader thread."""

    def __init__(self, address: int = 0x81, attributes: int = BULK) -> None:
        self.bEndpointAddress = address
        self.bmAttributes = attributes
        self.pending: queue.SimpleQueue[bytes | BaseException] = queue.SimpleQueue()
        self.reads = 0

    def read(self, size: int, timeout: int | None = None) -> bytes:
        self.reads += 1
        try:
            item = self.pending.get(timeout=(timeout or 1000) / 1000)
        except queue.Empty:
            raise usb.core.USBTimeoutError("Operation timed out", errno=errno.ETIMEDOUT) from None
        if isinstance(item, BaseException):
            raise item
        assert len(item) <= size
        return item


class FakeOutEndpoint:
    """Bulk OUT: records what was written; may accept only part of a write, or fail."""

    def __init__(self, address: int = 0x01, attributes: int = BULK) -> None:
        self.bEndpointAddress = address
        self.bmAttributes = attributes
        self.received = bytearray()
        self.max_per_write: int | None = None
        self.fail_with: BaseException | None = None
        self.lock = threading.Lock()
        self.writer_threads: set[str] = set()

    def write(self, data: bytes, timeout: int | None = None) -> int:
        self.writer_threads.add(threading.current_thread().name)
        if self.fail_with is not None:
            raise self.fail_with
        accepted = bytes(data)[: self.max_per_write]
        with self.lock:
            self.received += accepted
        return len(accepted)


class FakeInterface:
    def __init__(self, number: int, endpoints: list[Any]) -> None:
        self.bInterfaceNumber = number
        self.endpoints = endpoints

    def __iter__(self) -> Iterator[Any]:
        return iter(self.endpoints)


class FakeDevice:
    def __init__(self, serial_number: str = "ABC123", *, bulk: bool = True) -> None:
        self.serial_number = serial_number
        self.ep_in = FakeInEndpoint()
        self.ep_out = FakeOutEndpoint()
        control = FakeInterface(0, [FakeInEndpoint(0x82, INTERRUPT)])
        data_endpoints: list[Any] = [self.ep_in, self.ep_out] if bulk else [self.ep_in]
        data = FakeInterface(1, [FakeInEndpoint(0x83, INTERRUPT), *data_endpoints])
        self.interfaces = [control, data]
        self.configured = False

    def get_active_configuration(self) -> list[FakeInterface]:
        if not self.configured:
            raise usb.core.USBError("Configuration not set")
        return self.interfaces

    def set_configuration(self) -> None:
        self.configured = True

    def is_kernel_driver_active(self, number: int) -> bool:
        return False

    def detach_kernel_driver(self, number: int) -> None:
        raise AssertionError("no kernel driver to detach")


class FakeBackend:
    """``find``, ``claim_interface`` and ``dispose_resources`` over a list of fake devices."""

    def __init__(self, *devices: FakeDevice) -> None:
        self.devices = list(devices)
        self.claimed: list[tuple[FakeDevice, int]] = []
        self.disposed: list[FakeDevice] = []

    def find(self, *, find_all: bool, idVendor: int, idProduct: int) -> list[FakeDevice]:  # noqa: N803
        assert find_all
        return list(self.devices) if (idVendor, idProduct) == (VID, PID) else []

    def claim_interface(self, device: FakeDevice, number: int) -> None:
        self.claimed.append((device, number))

    def dispose_resources(self, device: FakeDevice) -> None:
        self.disposed.append(device)

    async def open(self, url: str, rec: Recorder) -> UsbTransport:
        link = parse_link_url(url)
        assert isinstance(link, UsbUrl)
        return await open_usb(
            url,
            link,
            rec.on_bytes,
            rec.on_lost,
            find=self.find,
            claim_interface=self.claim_interface,
            dispose_resources=self.dispose_resources,
            read_timeout_ms=10,
            write_timeout_ms=100,
        )


def usb_threads() -> list[threading.Thread]:
    return [t for t in threading.enumerate() if t.name.startswith("dthc-usb")]


@pytest.fixture(autouse=True)
def no_threads_left() -> Iterator[None]:
    assert usb_threads() == []
    yield
    assert usb_threads() == [], "a USB thread outlived its test"


async def test_bytes_flow_both_ways_through_the_threads() -> None:
    """Board bytes reach on_bytes on the loop; writes reach bulk OUT in order, off the loop."""
    device = FakeDevice()
    backend = FakeBackend(device)
    rec = Recorder()
    transport = await backend.open("usb://1209:d7c0", rec)
    try:
        assert transport.is_open
        assert backend.claimed == [(device, 1)]
        assert device.configured
        assert len(usb_threads()) == 2
        device.ep_in.pending.put(b"\x00hello")
        device.ep_in.pending.put(b" world\x00")
        assert await rec.wait_for_bytes(13) == b"\x00hello world\x00"
        device.ep_out.max_per_write = 3  # partial writes are completed by the writer
        for chunk in (b"\x00abc", b"defgh", b"\x00"):
            transport.write(chunk)
        await poll_until(lambda: bytes(device.ep_out.received) == b"\x00abcdefgh\x00")
        assert all(n.startswith("dthc-usb-writer") for n in device.ep_out.writer_threads)
    finally:
        await transport.close()
    assert rec.lost == [None]
    assert usb_threads() == []
    assert backend.disposed == [device]
    with pytest.raises(TransportError, match="closed"):
        transport.write(b"late")


async def test_an_idle_link_stays_up_through_read_timeouts() -> None:
    """Read timeouts are the normal idle case: many of them pass and the link is still up."""
    device = FakeDevice()
    backend = FakeBackend(device)
    rec = Recorder()
    transport = await backend.open("usb://1209:d7c0", rec)  # read timeout 10 ms
    try:
        await poll_until(lambda: device.ep_in.reads >= 5)
        assert transport.is_open
        assert rec.lost == []
        device.ep_in.pending.put(b"still here")
        assert await rec.wait_for_bytes(10) == b"still here"
    finally:
        await transport.close()
    assert rec.lost == [None]


async def test_close_sends_bytes_already_queued() -> None:
    """Bytes written just before close still go out: the writer drains the queue first."""
    device = FakeDevice()
    backend = FakeBackend(device)
    rec = Recorder()
    transport = await backend.open("usb://1209:d7c0", rec)
    transport.write(b"goodbye")
    await transport.close()
    await transport.close()
    assert bytes(device.ep_out.received) == b"goodbye"
    assert rec.lost == [None]


async def test_enodev_from_read_reports_one_transport_error_and_releases() -> None:
    """An unplug (USBError errno 19 from read) ends the link once, after the bytes before it."""
    device = FakeDevice()
    backend = FakeBackend(device)
    rec = Recorder()
    transport = await backend.open("usb://1209:d7c0", rec)
    try:
        device.ep_in.pending.put(b"last bytes")
        device.ep_in.pending.put(enodev())
        error = await rec.wait_for_lost()
        assert isinstance(error, TransportError)
        assert "disconnected" in error.detail
        assert rec.data == b"last bytes"
        assert not transport.is_open
        with pytest.raises(TransportError):
            transport.write(b"after unplug")
        await poll_until(lambda: usb_threads() == [])
        assert backend.disposed == [device]  # released without waiting for close()
        await settle()
        assert len(rec.lost) == 1
    finally:
        await transport.close()
    assert len(rec.lost) == 1


async def test_write_failure_reports_one_transport_error() -> None:
    """A bulk OUT error (ENODEV on write) also ends the link exactly once."""
    device = FakeDevice()
    backend = FakeBackend(device)
    rec = Recorder()
    transport = await backend.open("usb://1209:d7c0", rec)
    try:
        device.ep_out.fail_with = enodev()
        transport.write(b"doomed")
        error = await rec.wait_for_lost()
        assert isinstance(error, TransportError)
        assert "write" in error.detail
        await poll_until(lambda: usb_threads() == [])
    finally:
        await transport.close()
    assert len(rec.lost) == 1
    assert backend.disposed == [device]


async def test_serial_number_picks_the_right_board() -> None:
    """usb://VID:PID/SERIAL claims the board with that serial and lets the others go."""
    other, wanted = FakeDevice("OTHER"), FakeDevice("ABC123")
    backend = FakeBackend(other, wanted)
    rec = Recorder()
    transport = await backend.open("usb://1209:d7c0/ABC123", rec)
    try:
        wanted.ep_in.pending.put(b"from the wanted board")
        await rec.wait_for_bytes(21)
        assert backend.claimed == [(wanted, 1)]
        assert other in backend.disposed
    finally:
        await transport.close()


@pytest.mark.parametrize(
    ("url", "devices", "message"),
    [
        ("usb://1209:d7c0", [], "no USB device 1209:d7c0"),
        ("usb://1209:d7c0/NOPE", [FakeDevice("ABC123")], "none with serial number 'NOPE'"),
        ("usb://1209:d7c0", [FakeDevice(bulk=False)], "no interface with a bulk IN and"),
    ],
)
async def test_open_fails_with_transport_error_and_leaves_nothing_behind(
    url: str, devices: list[FakeDevice], message: str
) -> None:
    """No device, wrong serial or no bulk pair: TransportError, nothing claimed or running."""
    backend = FakeBackend(*devices)
    rec = Recorder()
    with pytest.raises(TransportError, match=message):
        await backend.open(url, rec)
    assert backend.claimed == []
    assert backend.disposed == devices
    assert usb_threads() == []
    assert rec.lost == []


async def test_real_pyusb_without_the_board_raises_transport_error() -> None:
    """Through open_transport and real pyusb: no board (or no libusb) is a TransportError."""
    rec = Recorder()
    with pytest.raises(TransportError):
        await open_transport("usb://1209:0001/NO-SUCH-BOARD", rec.on_bytes, rec.on_lost)
    assert rec.lost == []
