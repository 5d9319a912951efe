"""Link URL parsing: every supported form, and a clear ValueError for each malformed one."""

from __future__ import annotations

import re

import pytest

from dthc_bridge.transport import (
    LinkUrl,
    SerialUrl,
    TcpUrl,
    UsbUrl,
    open_transport,
    parse_link_url,
)

from .helpers import Recorder


@pytest.mark.parametrize(
    ("url", "expected"),
    [
        ("/dev/ttyACM0", SerialUrl("/dev/ttyACM0")),
        ("/dev/ttyUSB1", SerialUrl("/dev/ttyUSB1")),
        (
            "/dev/serial/by-id/usb-DTHC_Board_ABC123-if00",
            SerialUrl("/dev/serial/by-id/usb-DTHC_Board_ABC123-if00"),
        ),
        ("/tmp/dthc-mock/board", SerialUrl("/tmp/dthc-mock/board")),  # noqa: S108 - a pty symlink
        ("socket://127.0.0.1:5000", TcpUrl("127.0.0.1", 5000)),
        ("socket://board.local:23", TcpUrl("board.local", 23)),
        ("socket://[::1]:5000", TcpUrl("::1", 5000)),
        ("usb://1209:d7c0", UsbUrl(0x1209, 0xD7C0)),
        ("usb://1209:D7C0/ABC123", UsbUrl(0x1209, 0xD7C0, "ABC123")),
        ("usb://1:2", UsbUrl(1, 2)),
    ],
)
def test_every_link_form_parses_to_its_kind_and_parts(url: str, expected: LinkUrl) -> None:
    """Device paths, by-id and pty symlinks are serial; socket:// and usb:// split."""
    parsed = parse_link_url(url)
    assert parsed == expected
    assert parsed.kind == expected.kind


def test_link_kinds_are_named() -> None:
    """Each parsed form says which kind of link it is, for logs and config checks."""
    assert [parse_link_url(u).kind for u in ("/dev/ttyACM0", "socket://h:1", "usb://1:2")] == [
        "serial",
        "tcp",
        "usb",
    ]


@pytest.mark.parametrize(
    ("url", "message"),
    [
        ("", "empty"),
        ("   ", "empty"),
        (" /dev/ttyACM0", "whitespace"),
        ("usb://zz:1", "vendor id 'zz'"),
        ("usb://1209:xyz0", "product id 'xyz0'"),
        ("usb://12345:1", "vendor id '12345'"),
        ("usb://1209", "VID:PID"),
        ("usb://1209:d7c0/", "empty USB serial number"),
        ("usb://1209:d7c0/a/b", "may not contain"),
        ("socket://host", "needs a port"),
        ("socket://host:", "needs a port"),
        ("socket://host:http", "bad TCP port"),
        ("socket://host:0", "out of range"),
        ("socket://host:70000", "bad TCP port"),
        ("socket://:5000", "needs a host"),
        ("socket://host:5000/path", "only host:port"),
        ("memory://board", "unsupported scheme 'memory'"),
        ("rfc2217://host:5000", "unsupported scheme 'rfc2217'"),
        ("http://host", "unsupported scheme 'http'"),
    ],
)
def test_malformed_urls_raise_value_error_naming_the_problem(url: str, message: str) -> None:
    """A bad URL fails before any I/O, and the message says what is wrong with it."""
    with pytest.raises(ValueError, match=re.escape(message)):
        parse_link_url(url)


async def test_open_transport_rejects_a_malformed_url_with_value_error() -> None:
    """The seam checks the URL first: a typo is a ValueError, not a failed connection."""
    rec = Recorder()
    with pytest.raises(ValueError, match="needs a port"):
        await open_transport("socket://host", rec.on_bytes, rec.on_lost)
    assert rec.lost == []
