"""``dthc-bridge send`` fails with one clear line, not a traceback."""

from __future__ import annotations

import socket
from pathlib import Path

import pytest

from dthc_tools.sender import cli


def _closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port  # nothing listens once the socket is closed


def test_an_unreachable_broker_is_named(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """No broker at the URL: exit 2 and the URL the user gave in the message."""
    program = tmp_path / "part.ngc"
    program.write_text("T112 M6\nM3\nM5\n")
    url = f"mqtt://127.0.0.1:{_closed_port()}"
    assert cli.main([str(program), "--broker", url]) == 2
    err = capsys.readouterr().err
    assert f"cannot reach the broker at {url}" in err
    assert "Traceback" not in err


def test_a_missing_program_file_is_named(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A program path that does not exist: exit 2 and the path in the message."""
    missing = tmp_path / "nope.ngc"
    assert cli.main([str(missing)]) == 2
    assert str(missing) in capsys.readouterr().err


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--backend", "grbl"], "--backend grbl needs --port"),
        (["--backend", "grbl", "--port", "/dev/nonexistent-grbl"], "/dev/nonexistent-grbl"),
        (["--backend", "grbl", "--port", "/dev/null", "--status-hz", "50"], "use 5-20 Hz"),
    ],
)
def test_a_bad_grbl_backend_is_named(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], args: list[str], message: str
) -> None:
    program = tmp_path / "part.ngc"
    program.write_text("G0 X1\n")
    try:
        code: object = cli.main([str(program), *args])
    except SystemExit as exc:  # argparse-style: the message is the exit code
        code = exc.code
    out = capsys.readouterr()
    assert code not in (0, None)
    assert message in str(code) + out.err
    assert "Traceback" not in out.err
