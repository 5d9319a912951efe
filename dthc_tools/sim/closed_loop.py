"""The cut sequence and THC closing the loop over a SimulatedBoard, in simulated time.

No asyncio and no wall clock: each step advances the board by one sample batch, feeds
what the board sent to the sequence, and executes the sequence's actions as protocol
commands. The "sender" runs the gantry of the plant: M3 is sent, motion starts when M3
is answered, M5 is sent when the motion queue is empty.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import firmware_protocol as fp
from dthc_bridge.controller import actions as act
from dthc_bridge.controller.sequence import CutSequence, SequenceConfig, State, with_board_limits
from dthc_bridge.controller.thc import ThcConfig, ThcController
from dthc_bridge.service import feed_samples
from mock_device.sim import SimulatedBoard
from mock_device.sim_host import SimHost

SENSORS_OHMIC = 1 << fp.InputBit.OHMIC
SENSORS_FLOAT = 1 << fp.InputBit.FLOAT


@dataclass
class Trace:
    state: list[str] = field(default_factory=list)  # the sequence state after each step


class ClosedLoop:
    def __init__(
        self,
        scenario: str = "flat_clean",
        seed: int = 1,
        config: SequenceConfig | None = None,
        thc: ThcConfig | None = None,
        board: SimulatedBoard | None = None,
    ) -> None:
        self.board = board or SimulatedBoard(scenario, seed=seed)
        self.plant = self.board.plant
        self.host = SimHost(self.board)
        info = self.host.open_session(lease_ms=250)
        z = (info.z_min_um / 1000, info.z_max_um / 1000)
        self.seq = CutSequence(
            with_board_limits(config or SequenceConfig(), *z), ThcController(thc)
        )
        self.moves: dict[int, int] = {}
        self.replies: list[act.CommandReply] = []
        self.pauses: list[str] = []
        self.velocity_stream = 0
        self.last_tx_s = 0.0
        self.trace = Trace()
        self.velocities: list[float] = []
        # The programmed feed the sender reports, when it differs from what the gantry runs
        # (a PlasmaC M67 E3 velocity reduction slows the machine, not the reference).
        self.requested_override_mm_s: float | None = None

    @property
    def now(self) -> float:
        return self.board.t_s

    def execute(self, actions: list[act.Action]) -> None:
        for a in actions:
            self._execute(a)

    def _request(self, msg: fp.Message, action: act.Action) -> fp.Message | None:
        reply = self.host.request(msg)
        self.last_tx_s = self.now
        if isinstance(reply, fp.Nak):
            self.seq.on_action_failed(action, f"NAK {fp.NakCode(reply.code).name}")
            return None
        return reply

    def _execute(self, a: act.Action) -> None:
        if isinstance(a, act.Torch):
            self._request(fp.Torch(0, a.on), a)
        elif isinstance(a, act.OhmicSense):
            self._request(fp.OhmicSense(0, a.on), a)
        elif isinstance(a, act.MoveZ):
            reply = self._request(
                fp.ZMove(0, round(a.target_mm * 1000), round(a.feed_mm_s * 1000)), a
            )
            if reply is not None:
                self.moves[reply.seq] = a.token
        elif isinstance(a, act.ProbeZ):
            sensors = (SENSORS_OHMIC if a.ohmic else 0) | (SENSORS_FLOAT if a.float_switch else 0)
            self._request(
                fp.ZProbe(0, round(a.feed_mm_s * 1000), round(a.max_travel_mm * 1000), sensors), a
            )
        elif isinstance(a, act.ZVelocity):
            self.velocity_stream = (self.velocity_stream + 1) & 0xFFFF
            self.host.send(
                fp.ZVelocity(0, self.velocity_stream, round(a.velocity_mm_s * 1000), 20), seq=0
            )
            self.last_tx_s = self.now
            self.velocities.append(a.velocity_mm_s)
        elif isinstance(a, act.StopZ):
            self._request(fp.ZStop(0), a)
        elif isinstance(a, act.ResetFaults):
            self._request(fp.FaultReset(0, 0xFFFF), a)
        elif isinstance(a, act.SetCurrent):
            self._request(fp.SetCurrent(0, round(a.current_a * 10)), a)
        elif isinstance(a, act.CommandReply):
            self.replies.append(a)
        elif isinstance(a, act.PauseProgram):
            self.pauses.append(a.reason)
            self.plant.gantry.hold()

    def step(self) -> None:
        """One sample batch of board time."""
        self.board.advance_ms(5)
        for m in self.host.collect():
            self._feed(m)
        self.seq.tick(self.now)
        self.execute(self.seq.drain())
        if self.now - self.last_tx_s > 0.05:
            self.host.request(fp.Heartbeat(0))
            self.last_tx_s = self.now
        self._record()

    def _feed(self, m: fp.Message) -> None:
        seq = self.seq
        now = self.now
        if isinstance(m, fp.Samples):
            requested = (
                self.requested_override_mm_s or self.plant.gantry.requested_feed_mm_s or None
            )
            feed_samples(seq, m, requested, now)
        elif isinstance(m, fp.Event):
            seq.on_inputs(m.inputs, m.z_um / 1000, now)
        elif isinstance(m, fp.MotionDone):
            token = self.moves.pop(m.seq, None)
            if token is not None:
                seq.on_motion_done(token, m.result == fp.MotionResult.REACHED, m.z_um / 1000)
        elif isinstance(m, fp.ProbeResult):
            seq.on_probe_done(
                m.result == fp.ProbeOutcome.CONTACT, bool(m.sensor & SENSORS_OHMIC),
                m.contact_z_um / 1000, m.stop_z_um / 1000,
            )  # fmt: skip
        elif isinstance(m, fp.Fault):
            seq.on_board_fault(fp.FaultCode(m.code).name)
        self.execute(seq.drain())

    def _record(self) -> None:
        self.trace.state.append(str(self.seq.state))

    def run_until(self, done: object, max_s: float) -> bool:
        assert callable(done)
        end = self.now + max_s
        while self.now < end:
            self.step()
            if done():
                return True
        return False

    # --- the sender's side -----------------------------------------------------------------

    def m3(self, max_s: float = 20.0) -> act.CommandReply:
        before = len(self.replies)
        self.seq.start(self.now, (self.plant.gantry.x_mm, self.plant.gantry.y_mm))
        self.execute(self.seq.drain())
        assert self.run_until(lambda: len(self.replies) > before, max_s), self.seq.state
        return self.replies[before]

    def m5(self, max_s: float = 10.0) -> act.CommandReply:
        before = len(self.replies)
        self.seq.stop(self.now, (self.plant.gantry.x_mm, self.plant.gantry.y_mm))
        self.execute(self.seq.drain())
        assert self.run_until(lambda: len(self.replies) > before, max_s), self.seq.state
        return self.replies[before]

    def move(self, *lines: str, max_s: float = 60.0) -> bool:
        """Run motion lines on the gantry; False if the cut faulted (the sender paused)."""
        for line in lines:
            self.plant.gantry.feed_line(line)
        return (
            self.run_until(lambda: self.plant.gantry.idle or self.seq.state is State.FAULTED, max_s)
            and self.seq.state is not State.FAULTED
        )

    def cut(self, *lines: str) -> tuple[act.CommandReply, bool, act.CommandReply]:
        started = self.m3()
        ok = started.ok and self.move(*lines)
        ended = self.m5()
        return started, ok, ended
