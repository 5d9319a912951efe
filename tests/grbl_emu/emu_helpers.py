"""A grbl emulator under a hand-turned clock, and the answers it sent, line by line."""

from __future__ import annotations

import re

from dthc_tools.grbl_emu import EmulatorConfig, GrblFirmware

TICK_S = 0.002
_FIELD = re.compile(r"([A-Za-z]+):([^|>]*)")


class Emu:
    """``GrblFirmware`` with a simulated clock; ``send``/``run`` return what it answered."""

    def __init__(self, config: EmulatorConfig | None = None) -> None:
        self.t = 0.0
        self.fw = GrblFirmware(config or EmulatorConfig(), now_s=self.t)
        self.fw.read()  # the power-on banner

    def send(self, data: bytes | str) -> list[str]:
        """Bytes to the controller now; the lines it answered."""
        raw = data.encode() if isinstance(data, str) else data
        self.fw.receive(raw, self.t)
        return self.lines()

    def run(self, seconds: float) -> list[str]:
        """Let time pass; the lines sent meanwhile."""
        end = self.t + seconds
        while self.t < end - 1e-12:
            self.t = min(end, self.t + TICK_S)
            self.fw.advance(self.t)
        return self.lines()

    def lines(self) -> list[str]:
        """Answers since the last call, without blank lines."""
        text = self.fw.read().decode("ascii")
        assert text == "" or text.endswith("\r\n"), repr(text)
        return [line for line in text.split("\r\n") if line]

    def status(self) -> str:
        """One status report (nothing else may be pending)."""
        (report,) = self.send(b"?")
        assert report.startswith("<"), report
        assert report.endswith(">"), report
        return report

    def fields(self) -> dict[str, str]:
        """A status report by field name; the state is under ``state``."""
        report = self.status()
        state = report[1:].split("|", 1)[0]
        return {"state": state, **dict(_FIELD.findall(report.split("|", 1)[1]))}

    def position(self) -> tuple[float, float]:
        """MPos X, Y from a status report."""
        x, y, _ = (float(v) for v in self.fields()["MPos"].split(","))
        return x, y

    def run_until(self, state: str, within_s: float) -> float:
        """Poll every 10 ms until the status shows ``state``; the time it took."""
        start = self.t
        while self.t - start < within_s:
            self.run(0.01)
            if self.fields()["state"] == state:
                return self.t - start
        raise AssertionError(f"not {state} within {within_s} s: {self.status()}")
