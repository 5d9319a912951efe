"""``dthc-bridge run``: the daemon process. One TaskGroup of named tasks.

    link        LinkSupervisor: board connection, handshake, reconnect
    controller  ControllerService: board actions in order
    mqtt        MqttGateway: requests, responses, state, events, telemetry
    watchdog    sd_notify WATCHDOG=1 while the event loop is healthy (under systemd)

SIGTERM/SIGINT: abort any cut, torch off, then a clean exit within a second.
"""

from __future__ import annotations

import asyncio
import contextlib
import signal
from collections.abc import Awaitable, Callable

import structlog

import firmware_protocol as fp

from .board import BoardClient, HomingPlan
from .config import BoardSettings, ControllerConfigs, ControllerSettings, DaemonConfig
from .consumables import ConsumableLog, default_consumables_file
from .controller.dialect import Dialect
from .controller.plasma import PlasmaController, default_material
from .controller.sequence import CutSequence
from .controller.thc import ThcController
from .deploy.sdnotify import SdNotifier
from .link import LinkSupervisor, SessionTrace
from .materials import MaterialStore
from .mqtt.broker import BrokerRefused
from .mqtt.gateway import MqttGateway
from .service import ControllerService
from .transport import TransportOpener

__all__ = [
    "board_link",
    "board_setup",
    "build_controller",
    "build_service",
    "controller_service",
    "run_daemon",
]

log = structlog.get_logger("dthc_bridge.daemon")


def build_controller(
    settings: ControllerSettings, configs: ControllerConfigs | None = None
) -> tuple[PlasmaController, MaterialStore | None]:
    """The pure controller (cut sequence, THC, mode, plasma mode at start, materials) and
    its material store, from the ``[controller]`` settings: the daemon runs it, and so do
    the closed-loop simulation the benchmarks measure and the simulated program runs.
    ``configs``: the sequence/THC/mode to use instead of the settings' own (a bench's)."""
    configs = configs or settings.configs()
    sequence = CutSequence(configs.sequence, ThcController(configs.thc))
    sequence.mode = configs.mode
    controller = PlasmaController(sequence)
    controller.plasma_only = settings.plasma_mode_at_start
    sequence.plasma_mode = settings.plasma_mode_at_start
    controller.default_material = default_material(settings.default_cut_feed_mm_min)
    controller.inch_materials = settings.materials_in_inches
    store = None if settings.materials_file is None else MaterialStore(settings.materials_file)
    controller.set_library(store.load() if store is not None else {})
    return controller, store


def controller_service(
    settings: ControllerSettings,
    supervisor: LinkSupervisor,
    client: BoardClient,
    *,
    configs: ControllerConfigs | None = None,
    consumables: ConsumableLog,
    command_timeout_s: float,
    board_setup: Callable[[BoardClient], Awaitable[None]] | None = None,
    homing: HomingPlan | None = None,
) -> ControllerService:
    """The controller service over a board link, as ``[controller]`` says."""
    controller, store = build_controller(settings, configs)
    return ControllerService(
        controller, supervisor, client, board_setup=board_setup,
        command_timeout_s=command_timeout_s, dialect=Dialect(settings.dialect),
        materials=store, codes=settings.codes, consumables=consumables, homing=homing,
    )  # fmt: skip


def board_link(
    board: BoardSettings,
    *,
    opener: TransportOpener | None = None,
    session_trace: SessionTrace | None = None,
) -> tuple[LinkSupervisor, BoardClient]:
    """The board link and its client, as ``[board]`` says. ``opener`` and ``session_trace``
    are a tool's (the latency bench opens its own transport and traces the hot path); the
    daemon gives neither."""
    supervisor = LinkSupervisor(
        board.link, board.timing(), baudrate=board.baudrate, opener=opener,
        session_trace=session_trace,
    )  # fmt: skip
    return supervisor, BoardClient(supervisor)


def board_setup(board: BoardSettings) -> Callable[[BoardClient], Awaitable[None]]:
    """What the service does with the board each time it comes online: configure its
    sampling and filter as ``[board]`` says."""

    async def setup(client: BoardClient) -> None:
        await client.configure(
            sample_rate_hz=board.sample_rate_hz,
            batch_size=board.batch_size,
            filter_kind=fp.FilterKind[board.filter.upper()],
            filter_param=board.filter_param,
            arc_lost_ms=board.arc_lost_ms,
            cal_offset=board.cal_offset,
            cal_scale=board.cal_scale,
        )

    return setup


def build_service(config: DaemonConfig) -> tuple[LinkSupervisor, ControllerService]:
    """The board link and the controller service, wired as the configuration says."""
    supervisor, client = board_link(config.board)
    settings = config.controller
    service = controller_service(
        settings, supervisor, client, board_setup=board_setup(config.board),
        homing=config.board.homing.plan(),
        # A backstop only: the gateway's request deadline cancels (and so aborts) first.
        command_timeout_s=config.mqtt.request_deadline_s + 5.0,
        consumables=ConsumableLog(settings.consumables_file or default_consumables_file()),
    )  # fmt: skip
    return supervisor, service


async def run_daemon(config: DaemonConfig) -> int:
    with SdNotifier.from_env() as notifier:
        return await _run(config, notifier)


async def _run(config: DaemonConfig, notifier: SdNotifier) -> int:
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGTERM, signal.SIGINT):
        loop.add_signal_handler(sig, stop.set)
    supervisor, service = build_service(config)
    gateway = MqttGateway(config.mqtt, service)
    log.info("starting", link=config.board.link, broker=f"{config.mqtt.host}:{config.mqtt.port}")
    status = 0
    try:
        await _serve(notifier, stop, supervisor, service, gateway)
    except* BrokerRefused as refused:
        # One line naming what failed, exit 2 as for a bad configuration: a wrong password,
        # user or CA is mended by the owner, not by retrying.
        log.error("mqtt_login_refused", error=str(refused.exceptions[0]))
        status = 2
    finally:
        for sig in (signal.SIGTERM, signal.SIGINT):
            with contextlib.suppress(Exception):
                loop.remove_signal_handler(sig)
    return status


async def _serve(
    notifier: SdNotifier,
    stop: asyncio.Event,
    supervisor: LinkSupervisor,
    service: ControllerService,
    gateway: MqttGateway,
) -> None:
    async with asyncio.TaskGroup() as group:
        tasks = [
            group.create_task(supervisor.run(), name="link"),
            group.create_task(service.run(), name="controller"),
            group.create_task(gateway.run(), name="mqtt"),
        ]
        if notifier.watchdog_period_s() is not None:
            tasks.append(group.create_task(notifier.watchdog_loop(), name="watchdog"))
        notifier.ready()
        notifier.status("running")
        await stop.wait()
        log.info("stopping")
        notifier.stopping()
        await asyncio.wait_for(service.shutdown(), 0.7)
        for task in tasks:
            task.cancel()
    log.info("stopped")
