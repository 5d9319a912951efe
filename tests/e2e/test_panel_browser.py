"""The operator panel in a real browser: headless Chromium (Debian's, driven through
chromedriver by Selenium) against the panel, the daemon, mosquitto, the mock board and the
sender, each its own process.

One stack, one browser, two programs watched and steered from the page: the page speaks
the operator's words (lights, parameters, states); cycle start on the page continues a G200
S1 program, torch up moves the target by 1 V, tests and jogs are disabled with the reason
while it runs, the history lists the cut with its figures and plots it; the material chosen
on the page is what a program without G200 cuts with, the preview draws that program's path
and colours the part done as the torch moves (pixels along the path compared between two
moments), a pause from the page puts the torch out; each input light follows the mock
board's input; a refused material edit shows the daemon's error, and the controls are
disabled with a banner once the board is gone, then the daemon. Prints the page's update
rates, the browser's CPU use during the cut and the pause's torch-out time as JSON; with
DTHC_PANEL_SCREENSHOTS=docs saves docs/panel-idle.png, panel-cutting.png, panel-paused.png."""

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
SCREENSHOTS_ENV = "DTHC_PANEL_SCREENSHOTS"  # a folder (docs/): idle, cutting, paused there
# G200 S1: stop after the pierce, wait for cycle start. Fixed volts (V132: the mock plant's
# arc at 1.5 mm), so torch up moves a target that is already there.
PROGRAM = [
    "(panel test: MASSO G200 S1)", "G21 G90", "T112 M6",
    "G200 F300 P3.8 D300 C1.5 V132 A90 O1 S1",
    "G0 X20 Y20", "M3", "M667 F600", "G1 X300 Y20 F1500", "M666", "M5", "G0 X0 Y0", "M30",
]  # fmt: skip
# No G200: the material chosen on the page (12) sets the cut; paused from the page mid-cut.
SQUARE = [
    "(panel test: a square, material from the panel)", "G21 G90", "T112 M6", "G0 X20 Y20",
    "M3", "G1 X200 Y20 F1200", "G1 X200 Y120", "G1 X20 Y120", "G1 X20 Y20", "M5",
    "G0 X0 Y0", "M30",
]  # fmt: skip
STAINLESS = """
[MATERIAL_NUMBER_12]
NAME = Stainless 3mm 65A
THC = 1
PIERCE_HEIGHT = 4.0
PIERCE_DELAY = 0.6
CUT_HEIGHT = 1.8
CUT_SPEED = 1200
CUT_AMPS = 65
CUT_VOLTS = 0
"""


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


def _sender(stack: Stack, program: Path, log: IO[str], *more: str) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-m", "dthc_bridge", "send", str(program),
         "--broker", f"mqtt://127.0.0.1:{stack.broker.port}", "--base-topic", stack.base,
         "--gantry", f"socket://127.0.0.1:{stack.gantry_port}", "--json", *more],
        stdout=subprocess.PIPE, stderr=log, text=True, preexec_fn=die_with_parent(),
    )  # fmt: skip


async def test_the_panel_in_a_browser_watches_and_steers_a_cut(
    tmp_path: Path, browser: Browser
) -> None:
    materials = tmp_path / "materials.cfg"
    materials.write_text((PROGRAMS / "shop_material.cfg").read_text() + STAINLESS)
    options = StackOptions(tmp_path, broker="mosquitto", telemetry_hz=10.0,
                           materials_file=materials)  # fmt: skip
    programs = {}
    for name, lines in (("s1_part.nc", PROGRAM), ("square.nc", SQUARE)):
        programs[name] = tmp_path / name
        programs[name].write_text("\n".join(lines) + "\n")
    async with Stack(options) as stack:
        panel = Panel(stack, tmp_path)
        try:
            await browser.call(browser.driver.get, panel.url)
            await browser.until("document.querySelector('#link-board').className === 'ok'", 10)
            assert await browser.js("return document.querySelector('#banner').hidden;")
            assert await browser.js(
                "return document.querySelector('[data-control=cycle_start]').disabled;"
            )
            await _words_on_the_page(browser)
            # The square first: the S1 program's G200 would still be in force after it.
            with (tmp_path / "sender-square.log").open("w") as log:
                figures = await _preview_material_and_pause(
                    stack,
                    browser,
                    _sender(stack, programs["square.nc"], log, "--wait-operator"),
                    tmp_path,
                )
            with (tmp_path / "sender.log").open("w") as log:
                await _steer_an_s1_cut(stack, browser, _sender(stack, programs["s1_part.nc"], log),
                                       tmp_path)  # fmt: skip
            await _input_lights(stack, browser)
            await _refusals_and_links(stack, browser)
        finally:
            assert panel.stop() == 0
        await stack.finish()
    print(json.dumps({"panel": figures}))


def _screenshot(workdir: Path, name: str) -> Path:
    """Where a screenshot goes: the test's folder, and docs/ when DTHC_PANEL_SCREENSHOTS is
    set (``make panel-screenshots``: the README's pictures)."""
    folder = os.environ.get(SCREENSHOTS_ENV)
    return Path(folder) / name if folder else workdir / name


async def _words_on_the_page(browser: Browser) -> None:
    """The operator's words: lights named as on the machine, parameters in words and units."""
    lights = await browser.until(
        "[...document.querySelectorAll('#lights li')].map((li) => li.textContent).join('|')"
        ".includes('E-stop') && [...document.querySelectorAll('#lights li')]"
        ".map((li) => li.textContent)", 5,
    )  # fmt: skip
    assert lights == ["Torch on", "Arc OK", "Ohmic", "Float", "Breakaway", "E-stop",
                      "Z limit min", "Z limit max", "THC up", "THC down"]  # fmt: skip
    rows = await browser.js(
        "return [...document.querySelectorAll('#params tr')].map((tr) => tr.textContent);"
    )
    assert "Touch-off feed200 mm/min" in rows
    assert "Cut voltageauto" in rows
    assert await browser.js("return document.querySelector('#r-state').textContent;") == "Idle"


async def _steer_an_s1_cut(
    stack: Stack, browser: Browser, sender: subprocess.Popen[str], workdir: Path
) -> None:
    # G200 S1: the pierce is made, the torch goes out, the program waits for cycle start;
    # the page says so in words, enables the button, and a click on it continues.
    await browser.until(
        "document.querySelector('#r-status').textContent.includes('Waiting for cycle start (S1)')",
        40,
    )
    state = await browser.js("return document.querySelector('#r-state').textContent;")
    assert state == "Waiting for cycle start (S1)"
    assert not await browser.js(
        "return document.querySelector('[data-control=cycle_start]').disabled;"
    )
    await browser.click("[data-control=cycle_start]")
    await browser.until("document.querySelector('#answer').textContent === 'Cycle start: done'", 5)
    await wait_for_state(stack, {"cutting"}, 0, 20.0)

    # Torch up: the target the daemon publishes rises by 1 V.
    target = await browser.until("window.lastTarget = (window.lastTelemetry || {}).target_v", 10)
    await browser.click("[data-control=torch_up]")
    await browser.until("document.querySelector('#answer').textContent === 'Voltage +1 V: done'", 5)
    raised = await browser.until(
        "(window.lastTelemetry || {}).target_v >= arguments[0] + 0.99 && "
        "(window.lastTelemetry || {}).target_v", 5, target,
    )  # fmt: skip
    assert raised == pytest.approx(target + 1.0, abs=0.01)
    # Tests and jogs wait while the program runs: disabled, with the reason.
    refused = await browser.js(
        "const b = document.querySelector('[data-control=ohmic_test]');"
        "return b.disabled && b.title;"
    )
    assert refused == "the program is running (pause it first)"

    # The program completes; the history lists the cut with its figures, plots it, offers CSV.
    out, _ = await asyncio.to_thread(sender.communicate, timeout=60)
    report = json.loads(out)
    assert report["ok"], report
    assert len(report["cycle_starts"]) == 1  # the one S1 stop, continued from the page
    await browser.until("document.querySelector('#cut-list tbody tr')", 10)
    cells = await browser.js(
        "return [...document.querySelectorAll('#cut-list tbody tr:first-child td')]"
        ".map((td) => td.textContent.trim());"
    )
    # Cut 2 (the square's was 1), started where the torch was when its M3 came (the move to
    # X20 Y20 or the M3).
    assert cells[0] == "2"
    assert cells[1] in {"5", "6"}
    assert float(cells[7]) < 5.0  # the arc voltage error, RMS (V): the headline
    title = await browser.js(
        "return document.querySelector('th[data-history=height_rms_mm]').title;"
    )
    assert "relative to the point probed" in title
    await browser.click("#cut-list button.plot")
    await browser.until("!document.querySelector('#cut-figure').hidden", 5)
    caption = await browser.js("return document.querySelector('#cut-caption').textContent;")
    assert caption.startswith(f"Cut 2: line {cells[1]}")
    href = await browser.js("return document.querySelector('#cut-list a').getAttribute('href');")
    assert href == "/api/cuts/2.csv"
    # Consumables: the pierces counted (the square's and this one's at least).
    pierces = await browser.until(
        "Number(document.querySelector('#r-pierces').textContent) >= 2 && "
        "Number(document.querySelector('#r-pierces').textContent)", 5,
    )  # fmt: skip
    assert pierces >= 2
    await browser.js("window.scrollTo(0, 0);")
    await browser.call(browser.driver.save_screenshot, str(_screenshot(workdir, "panel-idle.png")))


# What the page's preview shows along the program's cuts: one pixel every 4 px of the path.
SAMPLE_PATH = """
const pv = window.panelPreview; const c = document.querySelector('#preview');
if (!pv) return null;
const g = c.getContext('2d'); const r = c.width / c.clientWidth; const out = [];
for (const m of pv.moves) {
  if (m.cut === null) continue;
  for (let i = 0; i + 1 < m.points.length; i += 1) {
    const a = pv.toCanvas(...m.points[i]); const b = pv.toCanvas(...m.points[i + 1]);
    const n = Math.max(1, Math.ceil(Math.hypot(b[0] - a[0], b[1] - a[1]) / 4));
    for (let k = 0; k < n; k += 1) {
      const x = a[0] + (b[0] - a[0]) * k / n; const y = a[1] + (b[1] - a[1]) * k / n;
      out.push(g.getImageData(Math.round(x * r), Math.round(y * r), 1, 1).data.join(','));
    }
  }
}
return out;
"""
STATS = (
    "return [window.panelStats.telemetry, window.panelStats.draws, window.panelStats.previewDraws,"
    " window.panelStats.views, document.querySelector('#chart').toDataURL()];"
)


async def _preview_material_and_pause(
    stack: Stack, browser: Browser, sender: subprocess.Popen[str], workdir: Path
) -> dict[str, Any]:
    """A program without G200: the material chosen on the page is what it cuts with. The
    preview draws its path and colours the part done as the torch moves; a pause from the
    page puts the torch out."""
    mark = len(stack.telemetry)  # the sender has just started: its cut is to come
    await browser.js(
        "const s = document.querySelector('#material-select'); s.value = '12';"
        "s.dispatchEvent(new Event('change'));"
    )
    await browser.until(
        "document.querySelector('#answer').textContent === "
        '"Next cut\'s material: 12 · Stainless 3mm 65A"',
        5,
    )
    await browser.until("document.querySelector('#material-select').value === '12'", 5)
    await browser.until(
        "window.panelPreview && String(window.panelPreview.program).endsWith('square.nc')", 20
    )
    mark = await wait_for_state(stack, {"cutting"}, mark, 30.0)
    params = await browser.until(
        "(((window.panelView || {}).state || {}).params || {}).pierce_delay_ms === 600 && "
        "window.panelView.state.params", 5,
    )  # fmt: skip
    assert params["cut_height_mm"] == 1.8  # material 12's, not the defaults or the last G200

    # The preview: the path drawn (opaque pixels along every cut), then drawn differently as
    # the torch moves along it, and the marker where the sender says the torch is.
    await browser.until("(window.panelView.progress || {}).x_mm > 25", 10)
    first = await browser.js(SAMPLE_PATH)
    drawn = sum(1 for pixel in first if not pixel.endswith(",0"))
    assert drawn >= 0.9 * len(first), (drawn, len(first))
    where = await browser.js(
        "return [window.panelView.progress.x_mm, window.panelView.progress.y_mm];"
    )
    before = await browser.js(STATS)
    cpu0, t0 = await browser.call(browser.cpu_s), time.monotonic()
    await asyncio.sleep(2.0)
    after = await browser.js(STATS)
    cpu1, t1 = await browser.call(browser.cpu_s), time.monotonic()
    second = await browser.js(SAMPLE_PATH)
    changed = sum(1 for a, b in zip(first, second, strict=True) if a != b)
    assert changed >= 5, changed  # the part done grew along the path
    moved = await browser.js(
        "return [window.panelView.progress.x_mm, window.panelView.progress.y_mm];"
    )
    assert moved != where
    assert after[0] > before[0] and after[1] > before[1]  # noqa: PT018 - telemetry, chart
    assert after[4] != before[4]  # the chart's picture itself changed
    seconds = t1 - t0
    await browser.call(
        browser.driver.save_screenshot, str(_screenshot(workdir, "panel-cutting.png"))
    )

    # Pause from the page: the torch goes out and the cut ends at once (invariant 7).
    await browser.click("[data-control=pause]")
    pressed = time.monotonic()
    await browser.until(
        "window.lastTelemetry && !window.lastTelemetry.torch_on && "
        "window.lastTelemetry.state !== 'cutting'", 3,
    )  # fmt: skip
    torch_out_s = time.monotonic() - pressed
    await browser.until("document.querySelector('#r-status').textContent.startsWith('Paused')", 5)
    # The program stopped where the torch went out; cycle start would resume it there.
    at = await browser.until("window.panelView.progress.paused_at", 5)
    assert at["line"] == 6
    assert not await browser.js(
        "return document.querySelector('[data-control=cycle_start]').disabled;"
    )
    await wait_for_state(stack, {"idle"}, mark, 10.0)
    await browser.call(
        browser.driver.save_screenshot, str(_screenshot(workdir, "panel-paused.png"))
    )

    # Paused with the torch out, the table is idle: Z jogs and the probe test are allowed,
    # through the sender (the broker lets only its user move Z).
    z = await browser.js("return window.lastTelemetry.z_mm;")
    await browser.click("[data-control=jog_up]")  # the page's step: 1 mm
    await browser.until("document.querySelector('#answer').textContent === 'Z up ▲: done'", 10)
    await browser.until("window.lastTelemetry.z_mm >= arguments[0] + 0.95", 5, z)
    await browser.click("[data-control=probe_test]")
    probed = await browser.until(
        "document.querySelector('#answer').textContent.startsWith('Probe test: done') && "
        "document.querySelector('#answer').textContent", 20,
    )  # fmt: skip
    assert probed.startswith("Probe test: done (plate at Z "), probed

    await browser.click("[data-control=stop]")
    await asyncio.to_thread(sender.communicate, timeout=30)
    # The history's record of that cut names material 12.
    material = await browser.until(
        "document.querySelectorAll('#cut-list tbody tr').length >= 1 && "
        "document.querySelector('#cut-list tbody tr:first-child td:nth-child(3)').textContent", 10,
    )  # fmt: skip
    assert material == "12"
    return {
        "telemetry_rate_hz": round((after[0] - before[0]) / seconds, 1),
        "chart_draws_per_s": round((after[1] - before[1]) / seconds, 1),
        "preview_draws_per_s": round((after[2] - before[2]) / seconds, 1),
        "views_per_s": round((after[3] - before[3]) / seconds, 1),
        "browser_cpu_percent": round(100.0 * (cpu1 - cpu0) / seconds, 1),
        "pause_to_torch_out_s": round(torch_out_s, 2),
        "preview_pixels_changed": changed,
    }


async def _gantry(stack: Stack, request: dict[str, Any]) -> dict[str, Any]:
    reader, writer = await asyncio.open_connection("127.0.0.1", stack.gantry_port)
    try:
        writer.write((json.dumps(request) + "\n").encode())
        await writer.drain()
        answer: dict[str, Any] = json.loads(await asyncio.wait_for(reader.readline(), 5))
        return answer
    finally:
        writer.close()


async def _input_lights(stack: Stack, browser: Browser) -> None:
    """Each light follows the board's input: forced on at the mock, the light turns on;
    released, off."""
    for name in ("estop", "float"):
        light = f"document.querySelector('#lights li[data-input={name}]').classList"
        assert not await browser.js(f"return {light}.contains('on');")
        answer = await _gantry(stack, {"op": "input", "name": name, "on": True})
        assert answer["ok"], answer
        await browser.until(f"{light}.contains('on')", 3)
        await _gantry(stack, {"op": "input", "name": name, "on": None})
        await browser.until(f"!{light}.contains('on')", 3)


async def _refusals_and_links(stack: Stack, browser: Browser) -> None:
    # New electrode and nozzle: two presses reset the counters (the daemon keeps them).
    await browser.click("#consumables-reset")
    assert await browser.js("return document.querySelector('#r-pierces').textContent;") != "0"
    await browser.click("#consumables-reset")
    await browser.until("document.querySelector('#r-pierces').textContent === '0'", 5)
    assert await browser.js("return document.querySelector('#r-arc-on').textContent;") == "0 s"

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
