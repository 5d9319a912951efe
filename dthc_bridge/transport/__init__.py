"""Bytes to and from one board, whatever the cable: serial/pty, TCP, USB bulk.

:func:`open_transport` is the one seam for opening a link::

    transport = await open_transport("/dev/serial/by-id/usb-DTHC_...", on_bytes, on_lost)
    transport = await open_transport("socket://127.0.0.1:5000", on_bytes, on_lost)
    transport = await open_transport("usb://1209:d7c0/ABC123", on_bytes, on_lost)

Only this package imports pyserial and pyusb (in ``serial.py`` and ``usb.py``). Tests do not
add a link kind here: they hand the link layer an opener of their own (``TransportOpener``).
"""

from __future__ import annotations

from .base import (
    BytesCallback,
    LinkUnavailable,
    LostCallback,
    Transport,
    TransportError,
    TransportOpener,
)
from .serial import open_serial
from .tcp import open_tcp
from .url import LinkUrl, SerialUrl, TcpUrl, UsbUrl, parse_link_url
from .usb import open_usb

__all__ = [
    "BytesCallback",
    "LinkUnavailable",
    "LinkUrl",
    "LostCallback",
    "SerialUrl",
    "TcpUrl",
    "Transport",
    "TransportError",
    "TransportOpener",
    "UsbUrl",
    "open_transport",
    "parse_link_url",
]


async def open_transport(
    url: str,
    on_bytes: BytesCallback,
    on_lost: LostCallback,
    *,
    baudrate: int = 921_600,
) -> Transport:
    """Open the link ``url`` names; bytes go to ``on_bytes``, its loss to ``on_lost`` (once).

    Raises ValueError for a malformed URL and TransportError when the link cannot be
    opened (missing device, port in use, connection refused); for a serial port the
    OS's refusal is a :class:`LinkUnavailable` naming the path and the OS error.
    ``baudrate`` applies to serial ports only.
    """
    link = parse_link_url(url)
    match link:
        case SerialUrl(path=path):
            return await open_serial(path, on_bytes, on_lost, baudrate=baudrate)
        case TcpUrl():
            return await open_tcp(url, link, on_bytes, on_lost)
        case UsbUrl():
            return await open_usb(url, link, on_bytes, on_lost)
