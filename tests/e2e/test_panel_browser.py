"""The operator panel in a real browser: headless Chromium (Debian's, driven through
chromedriver by Selenium) against the panel, the daemon, mosquitto, the mock board and the
sender, each its own process.

One cut, watched and steered from the page: the chart draws during the cut, cycle start on
the page continues a G200 S1 program, torch up moves the target by 1 V, the history lists
the cut and plots it, a refused material edit shows the daemon's error, and the controls
are disabled with a banner once the board is gone, then the daemon. Prints the page's
update rate and the browser's CPU use during the cut as JSON."""

from __future__ import annotations

import asyncio
import json
import os
import shutil
import subprocess
import sys
import time
from collections.abc import AsyncIterator, Callable, Iterator
from pathlib import Path
from typing import IO, Any

import pytest

from dthc_tools.demo import Stack, StackOptions
from dthc_tools.procs import die_with_parent
from tests.e2e.test_broker_restart import wait_for_state
from tests.processes import stop

pytestmark = [pytest.mark.slow, pytest.mark.timeout(180)]

CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
CHROMEDRIVER = shutil.which("chromedriver") or "/usr/bin/chromedriver"
PROGRAMS = Path(__file__).parents[1] / "programs"
SCREENSHOT_ENV = "DTHC_PANEL_SCREENSHOT"  # also save the mid-cut screenshot here (README)
# G200 S1: stop after the pierce, wait for cycle start. Fixed volts (V132: the mock plant's
# arc at 1.5 mm), so torch up moves a target that is already there.
PROGRAM = [
    "(panel test: MASSO G200 S1)", "G21 G90", "T112 M6",
    "G200 F300 P3.8 D300 C1.5 V132 A90 O1 S1",
    "G0 X20 Y20", "M3", "M667 F600", "G1 X300 Y20 F1500", "M666", "M5", "G0 X0 Y0", "M30",
]  # fmt: skip


def _browser_or_skip() -> None:
    if os.path.exists(CHROMIUM) and os.path.exists(CHROMEDRIVER):
        return
    message = "Debian's chromium and chromium-driver are needed (make test installs them)"
    if os.environ.get("CI"):
        pytest.fail(message)
    pytest.skip(message)


class Browser:
    """A headless Chromium session; every call runs in a thread (Selenium blocks)."""

    def __init__(self, profile: Path) -> None:
        from selenium import webdriver
        from selenium.webdriver.chrome.options import Options
        from selenium.webdriver.chrome.service import Service

        options = Options()
        options.binary_location = CHROMIUM
        for flag in (
            "--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
            "--no-first-run", "--disable-background-networking", "--disable-component-update",
            "--disable-sync", "--disable-quic", "--window-size=1400,1250",
            f"--user-data-dir={profile}",
        ):  # fmt: skip
            options.add_argument(flag)
        self.driver = webdriver.Chrome(service=Service(CHROMEDRIVER), options=options)

    async def call(self, fn: Callable[..., Any], *args: Any) -> Any:
        return await asyncio.to_thread(fn, *args)

    async def js(self, script: str, *args: Any) -> Any:
        return await self.call(self.driver.execute_script, script, *args)

    async def until(self, script: str, timeout_s: float, *args: Any) -> Any:
        """Poll ``script`` (a JS expression returning a value) until it is truthy."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            value = await self.js(f"return ({script});", *args)
            if value:
                return value
            await asyncio.sleep(0.1)
        raise AssertionError(f"the page never showed: {script}")

    async def click(self, selector: str) -> None:
        await self.js(f"document.querySelector({json.dumps(selector)}).click();")

    def cpu_s(self) -> float:
        """CPU time of chromedriver and every browser process under it (Linux /proc)."""
        root = self.driver.service.process.pid
        ticks = os.sysconf("SC_CLK_TCK")
        total = 0.0
        for pid in _tree(root):
            try:
                fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            total += (int(fields[11]) + int(fields[12])) / ticks  # utime + stime
        return total

    def quit(self) -> None:
        self.driver.quit()


def _tree(root: int) -> Iterator[int]:
    children: dict[int, list[int]] = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            parent = int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1])
        except (OSError, IndexError, ValueError):
            continue
        children.setdefault(parent, []).append(int(entry.name))
    stack = [root]
    while stack:
        pid = stack.pop()
        yield pid
        stack.extend(children.get(pid, []))


class Panel:
    def __init__(self, stack: Stack, workdir: Path) -> None:
        self.log = (workdir / "panel.log").open("w")
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "dthc_bridge", "panel",
             "--broker", f"mqtt://127.0.0.1:{stack.broker.port}", "--base-topic", stack.base,
             "--listen", "127.0.0.1:0", "--history", str(workdir / "cuts.jsonl")],
            stdout=subprocess.PIPE, stderr=self.log, text=True, preexec_fn=die_with_parent(),
        )  # fmt: skip
        assert self.proc.stdout is not None
        line = self.proc.stdout.readline()
        assert line.startswith("PANEL "), line
        self.url = line.split()[1]

    def stop(self) -> int:
        try:
            return stop(self.proc)
        finally:
            self.log.close()


@pytest.fixture
async def browser(tmp_path: Path) -> AsyncIterator[Browser]:
    _browser_or_skip()
    session = await asyncio.to_thread(Browser, tmp_path / "chromium-profile")
    try:
        yield session
    finally:
        await asyncio.to_thread(session.quit)


def _sender(stack: Stack, program: Path, log: IO[str]) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-m", "dthc_bridge", "send", str(program),
         "--broker", f"mqtt://127.0.0.1:{stack.broker.port}", "--base-topic", stack.base,
         "--gantry", f"socket://127.0.0.1:{stack.gantry_port}", "--json"],
        stdout=subprocess.PIPE, stderr=log, text=True, preexec_fn=die_with_parent(),
    )  # fmt: skip


async def test_the_panel_in_a_browser_watches_and_steers_a_cut(
    tmp_path: Path, browser: Browser
) -> None:
    materials = tmp_path / "materials.cfg"
    shutil.copyfile(PROGRAMS / "shop_material.cfg", materials)
    options = StackOptions(tmp_path, broker="mosquitto", telemetry_hz=10.0,
                           materials_file=materials)  # fmt: skip
    program = tmp_path / "s1_part.nc"
    program.write_text("\n".join(PROGRAM) + "\n")
    async with Stack(options) as stack:
        panel = Panel(stack, tmp_path)
        try:
            figures = await _steer_a_cut(stack, panel, browser, program, tmp_path)
        finally:
            assert panel.stop() == 0
        await stack.finish()
    print(json.dumps({"panel": figures}))


async def _steer_a_cut(
    stack: Stack, panel: Panel, browser: Browser, program: Path, workdir: Path
) -> dict[str, Any]:
    await browser.call(browser.driver.get, panel.url)
    await browser.until("document.querySelector('#link-board').className === 'ok'", 10)
    assert await browser.js("return document.querySelector('#banner').hidden;")
    assert await browser.js("return document.querySelector('[data-control=cycle_start]').disabled;")

    with (workdir / "sender.log").open("w") as log:
        return await _steer(stack, panel, browser, _sender(stack, program, log), workdir)


async def _steer(
    stack: Stack, panel: Panel, browser: Browser, sender: subprocess.Popen[str], workdir: Path
) -> dict[str, Any]:
    # G200 S1: the pierce is made, the torch goes out, the program waits for cycle start;
    # the page enables the button, and a click on it continues the program.
    await browser.until(
        "document.querySelector('#r-cut').textContent.includes('waiting for cycle start')", 40
    )
    assert not await browser.js(
        "return document.querySelector('[data-control=cycle_start]').disabled;"
    )
    await browser.click("[data-control=cycle_start]")
    await browser.until("document.querySelector('#answer').textContent === 'cycle start: done'", 5)
    await wait_for_state(stack, {"cutting"}, 0, 20.0)

    # The chart draws as telemetry comes: measured over two seconds of the cut.
    await browser.until("window.panelStats.telemetry > 0", 5)
    before = await browser.js("return [window.panelStats.telemetry, window.panelStats.draws,"
                              " document.querySelector('#chart').toDataURL()];")  # fmt: skip
    cpu0, t0 = await browser.call(browser.cpu_s), time.monotonic()
    await asyncio.sleep(2.0)
    after = await browser.js("return [window.panelStats.telemetry, window.panelStats.draws,"
                             " document.querySelector('#chart').toDataURL()];")  # fmt: skip
    cpu1, t1 = await browser.call(browser.cpu_s), time.monotonic()
    assert after[0] > before[0]
    assert after[1] > before[1]
    assert after[2] != before[2]  # the picture itself changed
    rate_hz = (after[0] - before[0]) / (t1 - t0)

    # Torch up: the target the daemon publishes rises by 1 V.
    target = await browser.until("window.lastTarget = (window.lastTelemetry || {}).target_v", 10)
    await browser.click("[data-control=torch_up]")
    await browser.until("document.querySelector('#answer').textContent === 'torch up: done'", 5)
    raised = await browser.until(
        "(window.lastTelemetry || {}).target_v >= arguments[0] + 0.99 && "
        "(window.lastTelemetry || {}).target_v", 5, target,
    )  # fmt: skip
    assert raised == pytest.approx(target + 1.0, abs=0.01)
    shot = workdir / "panel-mid-cut.png"
    await browser.call(browser.driver.save_screenshot, str(shot))
    if os.environ.get(SCREENSHOT_ENV):
        shutil.copyfile(shot, os.environ[SCREENSHOT_ENV])

    # The program completes; the history lists the cut, plots it, offers its CSV.
    out, _ = await asyncio.to_thread(sender.communicate, timeout=60)
    report = json.loads(out)
    assert report["ok"], report
    assert report["cycle_starts"] == [6]
    row = await browser.until("document.querySelector('#cut-list tbody tr')", 10)
    assert row
    cells = await browser.js(
        "return [...document.querySelectorAll('#cut-list tbody tr:first-child td')]"
        ".map((td) => td.textContent.trim());"
    )
    assert cells[:2] == ["1", "6"]  # cut 1 started at program line 6 (the M3)
    await browser.click("#cut-list button.plot")
    await browser.until("!document.querySelector('#cut-figure').hidden", 5)
    caption = await browser.js("return document.querySelector('#cut-caption').textContent;")
    assert caption.startswith("Cut 1: line 6")
    await browser.js("document.querySelector('#history').scrollIntoView();")
    await browser.call(browser.driver.save_screenshot, str(workdir / "panel-history.png"))
    href = await browser.js("return document.querySelector('#cut-list a').getAttribute('href');")
    assert href == "/api/cuts/1.csv"

    # A material edit the daemon refuses: its error, naming the field, on the page.
    await browser.click("#material-add")
    await browser.js(
        "const f = document.querySelector('#material-form');"
        "f.elements.number.value = 7; f.elements.cut_height.value = -1;"
        "f.requestSubmit();"
    )
    error = await browser.until(
        "document.querySelector('#answer').className === 'error' && "
        "document.querySelector('#answer').textContent", 5,
    )  # fmt: skip
    assert error == "cut_height: must be more than 0, got -1"

    # The board gone: a banner, and every table control disabled.
    assert stack.mock is not None
    stack.mock.kill()
    banner = await browser.until(
        "!document.querySelector('#banner').hidden && "
        "document.querySelector('#banner').textContent", 10,
    )  # fmt: skip
    assert banner.startswith("Board ")
    disabled = await browser.js(
        "return [...document.querySelectorAll('[data-control]')].map((b) => b.disabled);"
    )
    assert all(disabled)

    # The daemon killed: its will says offline, and the banner says so.
    assert stack.daemon is not None
    stack.daemon.kill()
    await browser.until(
        "document.querySelector('#banner').textContent.startsWith('Daemon offline')", 10
    )
    return {
        "telemetry_rate_hz": round(rate_hz, 1),
        "chart_draws_per_s": round((after[1] - before[1]) / (t1 - t0), 1),
        "browser_cpu_percent": round(100.0 * (cpu1 - cpu0) / (t1 - t0), 1),
        "screenshot": str(shot),
    }


async def test_the_page_asks_for_the_token_then_streams_with_its_cookie(browser: Browser) -> None:
    """A panel with a token (in-process, no broker): the page shows the token form and no
    stream; a wrong token is refused on the page; the right one logs in, and the stream, the
    history and a control press then carry the cookie the login set."""
    from aiohttp import web

    from dthc_tools.panel.connections import start_guarded_site
    from dthc_tools.panel.server import PanelLimits, build_app
    from tests.panel.test_server import TOKEN, RecordingHub

    hub = RecordingHub()
    limits = PanelLimits()
    runner = web.AppRunner(build_app(hub, token=TOKEN, limits=limits), shutdown_timeout=0.5)
    await runner.setup()
    server, _ = await start_guarded_site(runner, "127.0.0.1", 0, limits.connections)
    url = f"http://127.0.0.1:{server.sockets[0].getsockname()[1]}/"
    try:
        await browser.call(browser.driver.get, url)
        await browser.until("!document.querySelector('#token-form').hidden", 10)
        assert await browser.js("return document.querySelector('#banner').textContent;") == (
            "This panel needs its token"
        )
        assert await browser.js("return window.panelStats.views;") == 0
        for given, shown in (("wrong", "the panel token is wrong"), (TOKEN, None)):
            await browser.js(
                "document.querySelector('#token').value = arguments[0];"
                "document.querySelector('#token-form').requestSubmit();", given,
            )  # fmt: skip
            if shown is not None:
                await browser.until(
                    f"document.querySelector('#answer').textContent === '{shown}'", 5
                )
        await browser.until("window.panelStats.views > 0", 10)
        await browser.until("document.querySelector('#link-panel').className === 'ok'", 5)
        assert await browser.js("return document.querySelector('#token-form').hidden;")
        assert await browser.js("return document.cookie;") == ""  # HttpOnly: not for scripts
        answer = await browser.js(
            "return fetch('/api/control/torch_up', {method: 'POST', body: '{}', headers: "
            "{'Content-Type': 'application/json', 'X-DTHC-Panel': '1'}}).then((r) => r.status);"
        )
        assert answer == 200
        assert hub.pressed == [("torch_up", {})]
    finally:
        server.close()
        await runner.cleanup()
        await server.wait_closed()
