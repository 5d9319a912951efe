"""Board input bits, exactly as the board firmware copies them onto the wire."""

import enum

__all__ = ["InputBit"]


class InputBit(enum.IntFlag):
    """Digital inputs of the board; the value of each member is ``1 << bit position``."""

    ARC_OK = 1 << 0
    OHMIC = 1 << 1
    FLOAT = 1 << 2
    BREAKAWAY = 1 << 3
    THC_UP = 1 << 4
    THC_DOWN = 1 << 5
    ESTOP = 1 << 6
    Z_LIMIT_MIN = 1 << 7
    Z_LIMIT_MAX = 1 << 8
