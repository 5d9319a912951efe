"""Link URLs: which kind of connection a configured board address means.

``/dev/ttyACM0``, ``/dev/serial/by-id/...`` or any other filesystem path (a pty symlink)
is a serial port; ``socket://host:port`` is TCP; ``usb://VID:PID`` or
``usb://VID:PID/SERIAL`` (hex ids) is a vendor-specific bulk interface reached through
pyusb. There is no test-only kind: tests inject an opener into the link layer instead.
"""

from __future__ import annotations

import re
import urllib.parse
from dataclasses import dataclass, field
from typing import Literal

__all__ = ["LinkUrl", "SerialUrl", "TcpUrl", "UsbUrl", "parse_link_url"]

_SCHEME_RE = re.compile(r"^([A-Za-z][A-Za-z0-9+.-]*)://")
_USB_ID_RE = re.compile(r"[0-9A-Fa-f]{1,4}")
_MAX_PORT = 65535


@dataclass(frozen=True, slots=True)
class SerialUrl:
    """A serial port (tty, by-id symlink or pty symlink) at ``path``."""

    path: str
    kind: Literal["serial"] = field(default="serial", init=False)


@dataclass(frozen=True, slots=True)
class TcpUrl:
    """A TCP stream to ``host:port`` (``socket://host:port``)."""

    host: str
    port: int
    kind: Literal["tcp"] = field(default="tcp", init=False)


@dataclass(frozen=True, slots=True)
class UsbUrl:
    """A USB device by vendor/product id, optionally narrowed by its serial number string."""

    vid: int
    pid: int
    serial_number: str | None = None
    kind: Literal["usb"] = field(default="usb", init=False)


LinkUrl = SerialUrl | TcpUrl | UsbUrl


def parse_link_url(url: str) -> LinkUrl:
    """Tell which kind of link ``url`` names and split it into its parts.

    Raises ValueError naming the problem for an empty URL, an unknown scheme, a TCP
    address without a valid port, or USB ids that are not 1-4 hex digits.
    """
    if not url or not url.strip():
        raise ValueError("empty link URL")
    if url != url.strip():
        raise ValueError(f"link URL {url!r} has leading or trailing whitespace")
    if "\x00" in url:
        raise ValueError(f"link URL {url!r} contains a NUL byte")
    match = _SCHEME_RE.match(url)
    if match is None:
        return SerialUrl(path=url)
    scheme = match.group(1).lower()
    rest = url[match.end() :]
    if scheme == "socket":
        return _parse_tcp(url)
    if scheme == "usb":
        return _parse_usb(url, rest)
    raise ValueError(
        f"link URL {url!r}: unsupported scheme {scheme!r} "
        "(use a device path, socket://host:port, or usb://VID:PID[/SERIAL])"
    )


def _parse_tcp(url: str) -> TcpUrl:
    parts = urllib.parse.urlsplit(url)
    if parts.path not in ("", "/") or parts.query or parts.fragment:
        raise ValueError(f"link URL {url!r}: socket:// takes only host:port")
    if parts.username is not None or parts.password is not None:
        raise ValueError(f"link URL {url!r}: socket:// takes no user or password")
    host = parts.hostname
    if not host:
        raise ValueError(f"link URL {url!r}: socket:// needs a host")
    try:
        port = parts.port
    except ValueError as exc:  # non-numeric or out of range
        raise ValueError(f"link URL {url!r}: bad TCP port ({exc})") from None
    if port is None:
        raise ValueError(f"link URL {url!r}: socket:// needs a port (socket://host:port)")
    if not 0 < port <= _MAX_PORT:
        raise ValueError(f"link URL {url!r}: TCP port {port} is out of range 1-65535")
    return TcpUrl(host=host, port=port)


def _parse_usb(url: str, rest: str) -> UsbUrl:
    ids, slash, serial_number = rest.partition("/")
    vid_text, colon, pid_text = ids.partition(":")
    if not colon:
        raise ValueError(f"link URL {url!r}: usb:// needs VID:PID in hex, e.g. usb://1209:d7c0")
    for what, text in (("vendor id", vid_text), ("product id", pid_text)):
        if _USB_ID_RE.fullmatch(text) is None:
            raise ValueError(f"link URL {url!r}: USB {what} {text!r} is not 1-4 hex digits")
    if slash and not serial_number:
        raise ValueError(f"link URL {url!r}: empty USB serial number after '/'")
    if "/" in serial_number:
        raise ValueError(f"link URL {url!r}: USB serial number may not contain '/'")
    return UsbUrl(
        vid=int(vid_text, 16),
        pid=int(pid_text, 16),
        serial_number=serial_number or None,
    )
