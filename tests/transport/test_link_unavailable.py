"""A serial device that cannot be opened is a :class:`LinkUnavailable` carrying the path
and what the OS said, in its words, not pyserial's message repeating both."""

from __future__ import annotations

import copy
import pickle
from pathlib import Path

import pytest

from dthc_bridge.transport import LinkUnavailable, TransportError, open_transport

from .helpers import Recorder


async def test_a_folder_in_place_of_the_device_says_is_a_directory(tmp_path: Path) -> None:
    """The OS's own reason (EISDIR), with the path once."""
    rec = Recorder()
    with pytest.raises(LinkUnavailable) as refused:
        await open_transport(str(tmp_path), rec.on_bytes, rec.on_lost)
    assert str(refused.value) == f"cannot open {tmp_path}: Is a directory"
    assert (refused.value.errno, refused.value.os_error) == (21, "[Errno 21] Is a directory")
    assert rec.lost == []


def test_link_unavailable_is_a_transport_error_that_copies_and_pickles() -> None:
    """Callers catching TransportError still catch it; a copy keeps every field."""
    error = LinkUnavailable("/dev/dthc0", "No such file or directory", 2)
    assert isinstance(error, TransportError)
    assert error.url == "/dev/dthc0"
    round_trip = pickle.loads(pickle.dumps(error))  # noqa: S301 - our own bytes
    for twin in (copy.copy(error), round_trip):
        assert isinstance(twin, LinkUnavailable)
        assert (twin.url, twin.reason, twin.errno) == ("/dev/dthc0", error.reason, 2)
        assert str(twin) == "cannot open /dev/dthc0: No such file or directory"


def test_without_an_errno_the_reason_is_the_os_error() -> None:
    """A refusal pyserial gives no errno for keeps its own words."""
    error = LinkUnavailable("/dev/dthc0", "Could not configure port: (25, 'Inappropriate')")
    assert error.os_error == error.reason
