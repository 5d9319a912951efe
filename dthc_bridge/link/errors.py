"""Link failures, each carrying what a log line or an MQTT error response needs."""

from __future__ import annotations

from firmware_protocol import NakCode

__all__ = [
    "BoardRebooted",
    "BoardTooOld",
    "LinkDown",
    "LinkError",
    "NegativeAck",
    "ProtocolVersionMismatch",
    "RequestTimeout",
]


class LinkError(Exception):
    """Base of every board-link failure."""


class LinkDown(LinkError):
    """The board connection is gone; every pending request fails with this."""

    def __init__(self, reason: str) -> None:
        super().__init__(f"board link down: {reason}")
        self.reason = reason


class RequestTimeout(LinkError):
    def __init__(self, command: str, attempts: int, timeout_s: float) -> None:
        super().__init__(
            f"{command}: no reply after {attempts} attempts of {timeout_s * 1e3:.0f} ms"
        )
        self.command = command
        self.attempts = attempts


class NegativeAck(LinkError):
    def __init__(self, command: str, code: int, detail: int) -> None:
        try:
            name = NakCode(code).name
        except ValueError:
            name = f"code {code}"
        super().__init__(f"{command} refused by the board: {name} (detail {detail})")
        self.command = command
        self.code = code
        self.detail = detail


class ProtocolVersionMismatch(LinkError):
    def __init__(self, board: tuple[int, int], host: tuple[int, int]) -> None:
        super().__init__(
            f"board speaks protocol {board[0]}.{board[1]}, this host speaks {host[0]}.{host[1]}: "
            "a different major version cannot be used; update the firmware or the daemon"
        )
        self.board = board
        self.host = host


class BoardTooOld(LinkError):
    """A command the board's protocol version does not have; refused before it is sent."""

    def __init__(self, command: str, needs: tuple[int, int], board: tuple[int, int]) -> None:
        super().__init__(
            f"{command} needs protocol {needs[0]}.{needs[1]}, the board speaks "
            f"{board[0]}.{board[1]}: update the firmware"
        )
        self.command = command
        self.needs = needs
        self.board = board


class BoardRebooted(LinkError):
    def __init__(self, old_boot_id: int, new_boot_id: int | None) -> None:
        new = "unknown" if new_boot_id is None else f"{new_boot_id:08x}"
        super().__init__(f"board rebooted (boot id {old_boot_id:08x} -> {new})")
        self.old_boot_id = old_boot_id
        self.new_boot_id = new_boot_id
