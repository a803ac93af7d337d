"""The flight process: mocap in, the 20 ms control loop, vehicle links out, the flight log,
and the operator's connections. It runs in its own process so that nothing the API does
(requests, WebSockets, the GIL they hold) can delay a tick.

One event loop: the control loop on absolute deadlines, and the connections accepted on
the flight process's listening socket (``supervisor.ipc.rendezvous``) — the API process's
two (commands with the telemetry stream; abort and kill on their own), again after an API
restart, and the terminal client's direct abort. A connection closing ends only itself:
the flight process stops (landing first) on ``stop``. Operator requests are applied
between ticks. The setpoint stream to the vehicles runs from arming until they are
disarmed; when the control loop stops, setpoints stop.
"""

from __future__ import annotations

import asyncio
import gc
import logging
import math
import socket
import time
from collections.abc import Callable, Coroutine, Mapping
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from mocap.client import MocapSource
from mocap.qtm_protocol import MocapFrame
from supervisor.flight.arming import arm_blockers
from supervisor.flight.core import FlightCore, Notice, NoticeKind, TickResult
from supervisor.flight.modes import Event, Mode
from supervisor.flight.operator_requests import (
    ModeRequest,
    Outcome,
    Reply,
    Request,
    handle_request,
)
from supervisor.flight.status import FlightStatus
from supervisor.flight.telemetry import MocapView, ShellView, build_telemetry
from supervisor.logs.best_effort import BestEffortLog, write_error_words
from supervisor.logs.flight_log import (
    LogFormat,
    formation_header,
    mocap_recording_path,
    new_log_path,
)
from supervisor.logs.free_space import FreeSpaceFloor
from supervisor.runtime.operator_front import OperatorFront
from supervisor.runtime.phase_lock import MocapPhaseLock
from supervisor.runtime.scheduler import DeadlineTicker, TickTiming, TimingStats
from supervisor.runtime.tick_driver import TickDriver
from supervisor.vehicles.link import VehicleLink
from supervisor.vehicles.sequences import (
    PROOF_OF_LIFE_S,
    arm_for_offboard,
    check_failsafe_parameters,
    disarm_all,
    kill_all,
    land_all,
)

log = logging.getLogger(__name__)

LANDING_TIMEOUT_S = 90.0
FULL_COLLECTION_TICKS = 250  # a full garbage collection every 5 s, between two ticks
# A gap between two ticks this long (three periods): the process, or the whole computer,
# was stalled. The frames that came meanwhile are read before anything is decided: a
# 100 ms stall of a busy computer otherwise looked like 100 ms of lost mocap.
RESUME_GAP_S = 0.06
LOG_SPACE_PERIOD_S = 2.0
RESUME_READ_S = 0.06  # then this long to read the backlog (frames arrive one per read)
PX4_OF_LOSS_T_S = 1.0  # COM_OF_LOSS_T's default, when the setup does not set it
OFFBOARD_LOSS_MARGIN_S = 0.05


@dataclass(frozen=True)
class FlightSettings:
    """What the flight process needs of the setup besides its parts: the control period
    [s], whether ticks lock to the mocap frames, the setup's name (for flight logs), and
    whether it forwards the mocap to the vehicles itself (False: the relay process does)."""

    dt_s: float
    phase_lock: bool
    setup_name: str
    forward_mocap: bool = True
    log_format: LogFormat = "jsonl"
    # PX4 parameters every vehicle must hold before it may arm (its offboard-loss failsafe:
    # COM_OF_LOSS_T, COM_OBL_RC_ACT), read back from each vehicle at every arm.
    failsafe_parameters: Mapping[str, float] = field(default_factory=dict)
    min_free_log_mb: float = 0.0  # arming is refused with less free in the log folder
    own_vehicles: tuple[int, ...] | None = None
    """The vehicles this process commands (an agent: its own; None: every one). Another's
    link is its agent's report (``supervisor.agents.peer_vehicle``), its parameters that
    agent's to check."""


class FlightProcess:
    """Everything that flies, on one event loop: the tick ``driver`` (its core built for
    ``settings``), and ``mocap`` and ``links``, already running. ``run`` returns when
    ``stop`` has landed what was airborne."""

    def __init__(
        self,
        settings: FlightSettings,
        driver: TickDriver,
        mocap: MocapSource,
        links: tuple[VehicleLink, ...],
        log_folder: Path | None,
        clock: Callable[[], float] = time.monotonic,
        proof_of_life_s: float = PROOF_OF_LIFE_S,
    ) -> None:
        self.settings = settings
        self.on_tick: Callable[[TickResult], Mapping[str, float]] | None = None
        """Called after each tick's send (an agent tells its peers); what it returns is
        logged with the tick."""
        self.mocap = mocap
        self.links = links
        self.log_folder = log_folder
        self._log_space = (
            FreeSpaceFloor(log_folder, settings.min_free_log_mb) if log_folder else None
        )
        self._log_problem: str | None = None  # why no log could be written, last looked
        self.log_stopped: str | None = None
        """Why the last flight's log stopped by itself (a write error), for the status."""
        self._flight_log: BestEffortLog | None = None
        self.clock = clock
        self.proof_of_life_s = proof_of_life_s
        self.driver = driver
        self.stats = TimingStats()
        self.streaming = False
        self.last_tick: TickResult | None = None
        self.phase_lock = MocapPhaseLock(settings.dt_s) if settings.phase_lock else None
        self._stopping = asyncio.Event()
        self._on_ground = asyncio.Event()
        self._sequences: set[asyncio.Task[None]] = set()
        self._mocap_rate = (0, clock(), 0.0)  # frames, since, rate
        self._frames_since_tick = 0
        self._last_tick_s = math.inf  # the start of the last tick (none yet)
        self._reading_until_s = -math.inf  # after a freeze, no tick before this
        self._newest_frame: MocapFrame | None = None

    @property
    def core(self) -> FlightCore:
        """The tick core the driver runs."""
        return self.driver.core

    # ---- lifecycle ------------------------------------------------------------------------
    async def run(self, listener: socket.socket | None, token: str) -> None:
        """Fly until ``stop``, answering every connection to ``listener`` (if any) that
        presents ``token`` (or asks only to abort) meanwhile."""
        self.core.await_vehicles(self.clock())
        front = OperatorFront(token, self.handle, self.telemetry, self.clock)
        if listener is not None:
            await front.start(listener)
        try:
            async with asyncio.TaskGroup() as group:
                control = group.create_task(self._control_loop(), name="control-loop")
                watch = group.create_task(self._watch_log_space(), name="log-space")
                await self._stopping.wait()
                await self._land_if_airborne()
                control.cancel()
                watch.cancel()
        finally:
            await front.close()
            self.streaming = False
            self._close_log()

    async def _watch_log_space(self) -> None:
        """Look at the log folder's free space every ``LOG_SPACE_PERIOD_S`` (in a thread:
        a statvfs of a stuck network folder must not hold the loop), for the status."""
        while self._log_space is not None:
            self._log_problem = await asyncio.to_thread(self._log_space.problem)
            await asyncio.sleep(LOG_SPACE_PERIOD_S)

    def stop(self) -> None:
        """Land (if airborne), disarm, then return from ``run``."""
        self._stopping.set()

    async def _land_if_airborne(self) -> None:
        now = self.clock()
        mode = self.core.modes.mode
        if mode.airborne:
            log.info("stopping: landing first (the system is in %s)", mode.value)
            self.core.request(Event.LAND, now)
            try:
                async with asyncio.timeout(LANDING_TIMEOUT_S):
                    await self._on_ground.wait()
                log.info("landed: stopping")
            except TimeoutError:
                log.error("not on the ground after %.0f s: stopping anyway", LANDING_TIMEOUT_S)
        if self.core.modes.mode is Mode.ARMED:
            self.core.request(Event.DISARM, self.clock())
        if self.streaming:
            await disarm_all(self.links)
            self.streaming = False

    # ---- the control loop -------------------------------------------------------------------
    async def _control_loop(self) -> None:
        ticker = DeadlineTicker(self.settings.dt_s, clock=self.clock)

        def on_frame() -> None:
            self._fuse(self.mocap.drain())  # on arrival: off the path of the tick it waits for
            if self.phase_lock is not None:
                ticker.trigger()  # an on-time frame starts its tick at once

        self.mocap.on_frame(on_frame)
        # Python's collector may start a full collection in any allocation; one took 80 ms
        # here. What exists now (modules, models, solvers) is never scanned again, and the
        # collections run right after a tick, when the next frame is most of a period away.
        gc.collect()
        gc.freeze()
        gc.disable()
        try:
            async for timing in ticker:
                self._tick(timing)
                if self.phase_lock is not None:
                    ticker.shift(self.phase_lock.correction(ticker.next_deadline_s))
                    ticker.early_window_s = self.phase_lock.trigger_window_s
                gc.collect(2 if timing.index % FULL_COLLECTION_TICKS == 0 else 0)
        finally:
            gc.enable()
            self.mocap.on_frame(None)
            ticker.close()

    def _fuse(self, frames: list[MocapFrame]) -> None:
        """Fuse frames as they come; the tick reads the newest since the last tick."""
        for frame in frames:
            self.driver.fusion.update(frame)
        if frames:
            self._frames_since_tick += len(frames)
            self._newest_frame = frames[-1]
            if self.phase_lock is not None:
                self.phase_lock.observe((f.frame_number, f.receive_time_s) for f in frames)

    def _tick(self, timing: TickTiming) -> None:
        started = self.clock()
        # Back from a freeze (a stall, SIGSTOP): what the mocap and the vehicles did meanwhile
        # is still in the socket buffers. Decide and send nothing until it has been read: a
        # vehicle may be in its failsafe by now, and must not be told anything.
        gap_s = started - self._last_tick_s
        self._last_tick_s = started
        if gap_s > RESUME_GAP_S:
            log.warning("no tick for %.2f s: reading what came meanwhile first", gap_s)
            self._reading_until_s = started + RESUME_READ_S
            self._hand_over_after_freeze(gap_s, started)
        if started < self._reading_until_s:
            return
        before = self.core.modes.mode
        self._follow_vehicles_to_ground(started)
        self._hand_over_vehicles_out_of_offboard(started)
        repeats_refused = self.driver.fusion.refuse_repeats
        self._fuse(self.mocap.drain())
        newest = self._newest_frame if self._frames_since_tick else None
        self._count_frames(self._frames_since_tick, started)
        self._frames_since_tick = 0
        connected = tuple(link.connected for link in self.links)
        result = self.driver.decide(started, connected, timing.lateness_s)
        latency_ms = wait_ms = math.nan
        if self.streaming and result.mode is not Mode.PX4_LANDING:
            for link, command, commanded in zip(
                self.links, result.commands, result.commanded, strict=True
            ):
                if link.connected and commanded:  # a lost vehicle is left to its failsafe
                    link.send_setpoint(command)
            if newest is not None and math.isfinite(newest.receive_time_s):
                latency_ms = (self.clock() - newest.receive_time_s) * 1e3
                wait_ms = (started - newest.receive_time_s) * 1e3
                self.stats.record_latency(latency_ms)
        if self.settings.forward_mocap:
            self._forward_mocap()
        compute_s = self.clock() - started
        self.stats.record(timing, compute_s, self.settings.dt_s)
        self.last_tick = result
        if result.mode.airborne:
            self._on_ground.clear()
        else:
            self._on_ground.set()
        for notice in result.notices:
            log.warning("%s", notice)
        if result.mode is not before:
            log.info("mode %s → %s", before.value, result.mode.value)
        self._react(before, result.mode)
        self._notice_self_disarm(started)
        figures = self.on_tick(result) if self.on_tick is not None else {}
        self.driver.finish(  # logs, then the next tick's model while no frame waits
            result,
            **figures,
            compute_total_ms=compute_s * 1e3,
            latency_ms=latency_ms,
            mocap_wait_ms=wait_ms,
            skipped=timing.skipped,
            mpc_prepared=self.core.mpc_was_prepared,
            repeats_refused=repeats_refused,
        )
        self._stop_log_after_write_error(started)
        if result.mode is Mode.DISARMED:  # a flight's log ends with its first tick disarmed
            self._close_log()

    def _count_frames(self, new_frames: int, now_s: float) -> None:
        frames, since, rate = self._mocap_rate
        frames += new_frames
        if now_s - since >= 1.0:
            rate, frames, since = frames / (now_s - since), 0, now_s
        self._mocap_rate = (frames, since, rate)

    def _forward_mocap(self) -> None:
        frame = self.mocap.latest()
        if frame is None:
            return
        names = self.driver.names
        for link, name in zip(self.links, names.uavs, strict=True):
            pose = frame.bodies.get(name)
            if pose is not None and pose.tracked:
                link.send_mocap(pose.position_m, pose.quaternion, frame.receive_time_s)

    def _notice_self_disarm(self, now_s: float) -> None:
        """Armed and waiting for take-off, a vehicle that shows itself disarmed has disarmed
        on its own (PX4 does COM_DISARM_PRFLT, 10 s by default, after an arm without
        take-off): the system is disarmed too, and says why, so that a take-off is never
        flown on a vehicle that will not spin its motors."""
        if self.core.modes.mode is not Mode.ARMED:
            return
        views = [link.view() for link in self.links]
        idle = [i for i, view in enumerate(views, start=1) if view.connected and not view.armed]
        if not idle:
            return
        vehicles = " and ".join(f"vehicle {i}" for i in idle)
        text = (
            f"{vehicles} disarmed by itself before take-off (PX4 disarms when no take-off "
            "follows arming): arm again"
        )
        handle_request(self.core, ModeRequest(kind="disarm"), now_s)
        self.core.notices.append((now_s, Notice(NoticeKind.VEHICLE, text)))
        self._sequence(self._disarm_vehicles())

    def _hand_over_after_freeze(self, gap_s: float, now_s: float) -> None:
        """A freeze as long as PX4's offboard-loss timeout (less a margin, counting the
        backlog's reading): each PX4 is in its failsafe, or about to be, whatever its last
        report said (its mode shows up to a heartbeat later). One more setpoint would take
        it out of that failsafe, so none is sent: every vehicle is handed to its landing."""
        timeout_s = self.settings.failsafe_parameters.get("COM_OF_LOSS_T", PX4_OF_LOSS_T_S)
        if gap_s + RESUME_READ_S < timeout_s - OFFBOARD_LOSS_MARGIN_S:
            return
        before = self.core.modes.mode
        why = f"no tick for {gap_s:.2f} s, beyond PX4's offboard-loss timeout ({timeout_s:g} s)"
        notice = self.core.hand_over_to_px4(why, now_s)
        if notice is not None:
            self.core.notices.append((now_s, notice))
            self._react(before, self.core.modes.mode)

    def _hand_over_vehicles_out_of_offboard(self, now_s: float) -> None:
        """Flying under the supervisor, a vehicle that shows another mode than offboard has
        left it (its failsafe after a stall, or a pilot): the MPC no longer flies both, so
        none is commanded; each PX4 lands on its own."""
        mode = self.core.modes.mode
        if not (self.streaming and mode.airborne and mode is not Mode.PX4_LANDING):
            return
        left = [
            f"vehicle {i} in {view.px4_mode}"
            for i, view in enumerate((link.view() for link in self.links), start=1)
            if view.connected
            and view.px4_mode not in ("OFFBOARD", "unknown")
            and i != self.core.left_to_px4  # lost before, in its failsafe: expected
        ]
        if not left:
            return
        notice = self.core.hand_over_to_px4(" and ".join(left) + ", out of offboard", now_s)
        if notice is not None:
            self.core.notices.append((now_s, notice))

    def _follow_vehicles_to_ground(self, now_s: float) -> None:
        """Handed to PX4's own landing, or landed and disarming, the system is disarmed
        once every vehicle says it has disarmed (PX4 also disarms COM_DISARM_LAND after
        touch-down)."""
        mode = self.core.modes.mode
        if mode not in (Mode.PX4_LANDING, Mode.DISARMING):
            return
        views = [link.view() for link in self.links]
        if not all(view.connected and not view.armed for view in views):
            return
        if mode is Mode.PX4_LANDING:
            self.core.vehicles_landed(now_s)
        else:
            self.core.vehicles_disarmed(now_s)

    def _react(self, before: Mode, after: Mode) -> None:
        """Vehicle sequences the tick core's own mode changes call for."""
        if before is after:
            return
        if after is Mode.PX4_LANDING:  # blind: not one more setpoint, PX4 lands each
            self.streaming = False
            self._sequence(self._land_vehicles())
        elif after is Mode.DISARMING:  # landed (after a landing or an abort)
            self._sequence(self._disarm_vehicles())

    async def _land_vehicles(self) -> None:
        """AUTO.LAND for every vehicle still in offboard (one in its failsafe is left to it)."""
        in_offboard = tuple(link for link in self.links if link.view().px4_mode == "OFFBOARD")
        failures = await land_all(in_offboard)
        if failures:
            # Refused, or unanswered (a stalled link): each failure says which.
            text = "AUTO.LAND not confirmed: " + "; ".join(failures)
            self.core.notices.append((self.clock(), Notice(NoticeKind.VEHICLE, text)))

    def _sequence(self, coroutine: Coroutine[Any, Any, None]) -> None:
        task = asyncio.get_running_loop().create_task(coroutine)
        self._sequences.add(task)
        task.add_done_callback(self._sequences.discard)

    async def _disarm_vehicles(self) -> None:
        failures = await disarm_all(self.links)
        if failures:
            text = "disarm not confirmed: " + "; ".join(failures)
            self.core.notices.append((self.clock(), Notice(NoticeKind.VEHICLE, text)))
        self.streaming = False

    def own_links(self) -> tuple[VehicleLink, ...]:
        """The links of the vehicles this process commands."""
        own = self.settings.own_vehicles
        if own is None:
            return self.links
        return tuple(link for i, link in enumerate(self.links, start=1) if i in own)

    # ---- requests ---------------------------------------------------------------------------
    async def handle(self, request: Request) -> Reply:
        """Apply one operator request (the connections call this); returns the reply."""
        if not isinstance(request, ModeRequest):
            return handle_request(self.core, request, self.clock())
        before = self.core.modes.mode
        reply = await self._mode_request(request)
        after = self.core.modes.mode
        if reply.ok:
            log.info("%s: mode %s → %s", request.kind, before.value, after.value)
        else:
            log.info("%s refused: %s", request.kind, reply.reason)
        return reply

    async def _mode_request(self, request: ModeRequest) -> Reply:
        event = Event(request.kind)
        if event is Event.ARM:
            return await self._arm(request)
        reply = handle_request(self.core, request, self.clock())
        if event is Event.KILL:
            failures = await kill_all(self.links)
            self.streaming = False
            self._close_log()
            if failures:
                reply = reply.model_copy(update={"reason": "; ".join(failures)})
            return reply
        on_ground = self.core.modes.mode is Mode.DISARMED
        if event in (Event.DISARM, Event.ABORT) and on_ground and self.streaming:
            await self._disarm_vehicles()
        return reply

    async def _arm(self, request: ModeRequest) -> Reply:
        if self._log_space is not None:
            self._log_problem = await asyncio.to_thread(self._log_space.problem)
        views = [link.view() for link in self.links]
        blockers = arm_blockers(self.core, views, self._log_problem)
        if blockers:  # before any vehicle is armed
            return Reply(
                outcome=Outcome.REFUSED,
                reason="cannot arm: " + "; ".join(blockers),
                data={"mode": self.core.modes.mode.value},
            )
        expected = self.settings.failsafe_parameters
        own = self.own_links()
        numbers = self.settings.own_vehicles
        failures = await check_failsafe_parameters(own, expected, numbers) if expected else []
        if not failures:
            self.streaming = True  # idle setpoints: PX4's proof of life before offboard
            failures = await arm_for_offboard(self.links, self.proof_of_life_s)
        if failures:
            self.streaming = False
            text = "arming refused: " + "; ".join(failures)
            self.core.notices.append((self.clock(), Notice(NoticeKind.VEHICLE, text)))
            return Reply(
                outcome=Outcome.REFUSED,
                reason="arming failed: " + "; ".join(failures),
                data={"mode": self.core.modes.mode.value},
            )
        reply = handle_request(self.core, request, self.clock())
        if reply.ok and self.log_folder is not None:
            self._open_log(self.log_folder)
        return reply

    def _open_log(self, folder: Path) -> None:
        """A new flight log, and beside it the recording of the mocap as received from now
        on; the log's header holds where the fusion and the receiver stand as the recording
        starts, so that the flight's estimates can be replayed from it exactly
        (supervisor/logs/mocap_replay.py). Nothing is waiting unfused when the recording
        starts, and nothing arrives until this returns (one turn of the loop)."""
        self._close_log()
        self.log_stopped = None
        self._fuse(self.mocap.drain())
        path = new_log_path(folder, datetime.now(UTC), f".{self.settings.log_format}")
        sequence = self.mocap.record(mocap_recording_path(path))
        header: dict[str, Any] = {
            "setup": self.settings.setup_name,
            "controller": self.core.controller,
            **formation_header(self.core.params),
        }
        if sequence is not None:
            header["mocap_recording"] = {
                "file": mocap_recording_path(path).name,
                "receiver": sequence,
                "fusion": self.driver.fusion.snapshot(),
            }
        self._flight_log = self.driver.log = BestEffortLog(path, header)
        log.info("flight log %s", path)
        self._stop_log_after_write_error(self.clock())

    def _close_log(self) -> None:
        if self._flight_log is not None:
            self.mocap.record(None)
            self._flight_log.close()
            self._flight_log = self.driver.log = None

    def _stop_log_after_write_error(self, now_s: float) -> None:
        """A write error of the log or the mocap recording (a full disk) ends both, said in
        a notice and the status; the flight goes on: logging is best-effort."""
        flight_log = self._flight_log
        if flight_log is None:
            return
        failure = flight_log.failure or self.mocap.recording_failure()
        if failure is None:
            return
        self._close_log()
        words = write_error_words(failure, flight_log.path.parent)
        self.log_stopped = f"{words}: no longer recording"
        log.error("%s (%s): the flight goes on", self.log_stopped, flight_log.path)
        text = f"{self.log_stopped} ({flight_log.path.name}); the flight goes on"
        self.core.notices.append((now_s, Notice(NoticeKind.LOG, text)))

    # ---- telemetry ----------------------------------------------------------------------------
    def telemetry(self) -> FlightStatus:
        """The status now."""
        stats = self.mocap.stats()
        refused = stats.refused() | {
            reason: n for reason, n in self.driver.fusion.refused().items() if n
        }
        mocap = MocapView(
            stats.connected,
            self._mocap_rate[2],
            stats.frames,
            stats.frames_missed,
            refused,
            stats.server,
            stats.last_error,
        )
        live = self.driver.live
        shell = ShellView(
            streaming=self.streaming,
            log_path=str(self._flight_log.path) if self._flight_log is not None else None,
            log_stopped=self.log_stopped,
            live_view_port=live.port if live is not None else None,
        )
        return build_telemetry(
            self.core,
            self.driver.estimate,
            self.last_tick,
            tuple(link.view() for link in self.links),
            mocap,
            self.stats.summary(),
            shell,
            self.clock(),
            self._log_problem,
        )
