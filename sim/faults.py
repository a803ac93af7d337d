"""Faults injected into the simulated world at run time (docs/faults.md): the kinds, their
validation, when each ends on the world's clock, and what each does to a mocap frame or a
datagram, and which external loads it puts on the plant's bodies (``loads``: the ``push``
kind). Pure: no I/O, no clock; time is an argument, randomness one seeded generator.

The world (``sim.world.SimulatedWorld``) holds one ``FaultSet`` and asks it, for every
frame it publishes, which poses the frame carries (``frame``), and, for every datagram,
whether it passes (``keep_mocap_packet`` for the QTM server's data packets,
``keep_mavlink`` for each simulated PX4's MAVLink, both ways); ``powered`` says whether a
simulated PX4 is up or rebooting. ``expire(now_s)``, called as the world's clock advances,
ends the faults whose time is up. What the effects see is the set as of the last
``start``/``clear``/``expire`` call: between two world steps (2 ms) nothing changes.

A fault names its target: a rigid body QTM streams, or a vehicle 1 … N of the world
(``FaultSet.check``). A fault of a kind already active *on the same target* (the same body
or vehicle, or the kind alone for the target-less kinds) replaces it: its parameters and
its timer. Faults on different targets, or of different kinds, are active together; on a
frame they apply in the order body lost → jump → freeze, then silence or UDP loss decide
whether it leaves.
"""

from __future__ import annotations

import math
import random
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, fields, replace
from typing import Any, ClassVar, Final, TypeVar

import numpy as np

from geometry.formation import MAX_VEHICLES
from mocap.qtm_protocol import BodyPose
from sim.loads import ExternalLoad

REBOOT_S: Final = 3.0
"""How long a simulated PX4 stays silent when it reboots, unless the fault says otherwise:
about what a Pixhawk-class flight controller takes from reset to its first MAVLink
heartbeat (bootloader, NuttX start-up, the start-up script; a few seconds — not measured
here)."""


class FaultError(ValueError):
    """A fault request that is not valid: ``field`` names what is wrong (HTTP 422)."""

    def __init__(self, field_name: str, reason: str) -> None:
        super().__init__(f"{field_name}: {reason}")
        self.field = field_name
        self.reason = reason


def _number(value: object) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


MAX_DURATION_S = 3600.0  # longer is "until cleared" (no duration)
MAX_OFFSET_M = 20.0  # beyond any arena: a jump no mocap gives


def _check_duration(duration_s: float | None) -> None:
    if duration_s is None:
        return
    if not (_number(duration_s) and 0.0 < duration_s <= MAX_DURATION_S):
        raise FaultError(
            "duration_s",
            f"seconds, > 0 and at most {MAX_DURATION_S:.0f} (none: until cleared), "
            f"got {duration_s!r}",
        )


def _check_vehicle(vehicle: int) -> None:
    # Any vehicle a world may have; which of them this world has is FaultSet.check's.
    if not (
        isinstance(vehicle, int) and not isinstance(vehicle, bool) and 1 <= vehicle <= MAX_VEHICLES
    ):
        raise FaultError("vehicle", f"a vehicle number, 1 to {MAX_VEHICLES}, got {vehicle!r}")


def _check_body(body: str) -> None:
    if not (isinstance(body, str) and body):
        raise FaultError("body", f"a rigid-body name, got {body!r}")


# ---- the kinds ---------------------------------------------------------------------------------
# ``duration_s`` None: until cleared. Each kind's other fields are its parameters.


@dataclass(frozen=True)
class MocapSilent:
    """QTM sends no data packet at all (UDP or TCP stream); its frame count goes on, so the
    first frame after the silence shows the gap. Commands are still answered."""

    kind: ClassVar[str] = "mocap_silent"
    duration_s: float | None = None

    def __post_init__(self) -> None:
        _check_duration(self.duration_s)


@dataclass(frozen=True)
class MocapBodyLost:
    """``body`` is reported untracked (its 6D record all NaN, as QTM sends a body it cannot
    track); the other bodies stream as before."""

    kind: ClassVar[str] = "mocap_body_lost"
    body: str
    duration_s: float | None = None

    def __post_init__(self) -> None:
        _check_body(self.body)
        _check_duration(self.duration_s)


@dataclass(frozen=True)
class MocapFreeze:
    """A frozen QTM pipeline: frames keep coming at the frame rate, with new frame numbers
    and timestamps, but every one carries the poses of the first frame after the freeze
    began (as then reported, faults included)."""

    kind: ClassVar[str] = "mocap_freeze"
    duration_s: float | None = None

    def __post_init__(self) -> None:
        _check_duration(self.duration_s)


@dataclass(frozen=True)
class MocapJump:
    """``body``'s reported position is offset by ``offset_m`` (arena frame, metres); its
    orientation is unchanged. An untracked body stays untracked."""

    kind: ClassVar[str] = "mocap_jump"
    body: str
    offset_m: tuple[float, float, float]
    duration_s: float | None = None

    def __post_init__(self) -> None:
        _check_body(self.body)
        offset = self.offset_m
        if not (
            isinstance(offset, tuple)
            and len(offset) == 3
            and all(_number(v) and abs(v) <= MAX_OFFSET_M for v in offset)
        ):
            raise FaultError(
                "offset_m",
                f"three numbers [x, y, z] (metres), each within ±{MAX_OFFSET_M:.0f}, "
                f"got {offset!r}",
            )
        _check_duration(self.duration_s)


@dataclass(frozen=True)
class LinkLost:
    """Every MAVLink datagram between ``vehicle``'s simulated PX4 and anyone is dropped,
    both ways; the PX4 itself runs on (and its failsafes see the silence)."""

    kind: ClassVar[str] = "link_lost"
    vehicle: int
    duration_s: float | None = None

    def __post_init__(self) -> None:
        _check_vehicle(self.vehicle)
        _check_duration(self.duration_s)


@dataclass(frozen=True)
class Px4Reboot:
    """``vehicle``'s simulated PX4 reboots: motors off at once (disarmed; airborne, it
    falls), nothing sent or heard for ``duration_s`` (its boot time, ``REBOOT_S`` when not
    given: a reboot always ends), then it boots as at power-on — disarmed, in its boot mode,
    with the parameters it held, its clock and event sequence counting from zero."""

    kind: ClassVar[str] = "px4_reboot"
    vehicle: int
    duration_s: float | None = REBOOT_S

    def __post_init__(self) -> None:
        _check_vehicle(self.vehicle)
        if self.duration_s is None:
            object.__setattr__(self, "duration_s", REBOOT_S)
        _check_duration(self.duration_s)


@dataclass(frozen=True)
class UdpLoss:
    """Each UDP datagram of the world — mocap frames to every UDP client, MAVLink both ways
    for every simulated PX4 — is dropped with probability ``fraction``, independently (one
    generator seeded from ``sim.seed``). Frames streamed over TCP are not lost (TCP
    retransmits)."""

    kind: ClassVar[str] = "udp_loss"
    fraction: float
    duration_s: float | None = None

    def __post_init__(self) -> None:
        fraction = self.fraction
        if not (_number(fraction) and math.isfinite(fraction) and 0.0 <= fraction <= 1.0):
            raise FaultError("fraction", f"a number in [0, 1], got {fraction!r}")
        _check_duration(self.duration_s)


PUSH_MAX_N: Final = 50.0
"""The largest push along each axis [N]: about twice what a UAV's rotors give (the plant
is checked stable with it on every body for seconds on end)."""


@dataclass(frozen=True)
class Push:
    """A force ``force_n`` [N] (arena frame) at ``body``'s centre of mass acts on the plant
    (a hand, a tether, a steady gust); the measurement and the vehicles are untouched."""

    kind: ClassVar[str] = "push"
    body: str
    force_n: tuple[float, float, float]
    duration_s: float | None = None

    def __post_init__(self) -> None:
        _check_body(self.body)
        force = self.force_n
        if not (
            isinstance(force, tuple)
            and len(force) == 3
            and all(_number(v) and math.isfinite(v) and abs(v) <= PUSH_MAX_N for v in force)
        ):
            raise FaultError(
                "force_n", f"three numbers [x, y, z] within ±{PUSH_MAX_N:g} N, got {force!r}"
            )
        _check_duration(self.duration_s)


Fault = (
    MocapSilent | MocapBodyLost | MocapFreeze | MocapJump | LinkLost | Px4Reboot | UdpLoss | Push
)
FAULT_TYPES: Final[tuple[type[Fault], ...]] = (
    MocapSilent,
    MocapBodyLost,
    MocapFreeze,
    MocapJump,
    LinkLost,
    Px4Reboot,
    UdpLoss,
    Push,
)
F = TypeVar("F", bound=Fault)
KINDS: Final[Mapping[str, type[Fault]]] = {t.kind: t for t in FAULT_TYPES}
"""Every kind by its name."""


def parameter_names(kind: type[Fault]) -> tuple[str, ...]:
    """The kind-specific fields of ``kind`` (all but ``duration_s``), in order."""
    return tuple(f.name for f in fields(kind) if f.name != "duration_s")


def parameters(fault: Fault) -> dict[str, Any]:
    """The kind-specific fields of ``fault`` as JSON values."""
    values: dict[str, Any] = {}
    for name in parameter_names(type(fault)):
        value = getattr(fault, name)
        values[name] = list(value) if isinstance(value, tuple) else value
    return values


def parse_fault(request: Mapping[str, object], body_names: Sequence[str], n_vehicles: int) -> Fault:
    """The fault a request describes (``kind``, ``duration_s`` and the kind's fields; a
    ``None`` value counts as absent), checked against the configured rigid bodies and the
    world's ``n_vehicles`` vehicles (``check_target``). Raises ``FaultError`` naming the
    first field that is wrong; nothing else."""
    given = {name: value for name, value in request.items() if value is not None}
    kind_name = given.pop("kind", None)
    if kind_name is None:
        raise FaultError("kind", f"required: one of {', '.join(KINDS)}")
    kind = KINDS.get(kind_name) if isinstance(kind_name, str) else None
    if kind is None:
        raise FaultError("kind", f"{kind_name!r} is not one of {', '.join(KINDS)}")
    allowed = {*parameter_names(kind), "duration_s"}
    for name in given:
        if name not in allowed:
            raise FaultError(name, f"not a field of {kind.kind} (its fields: {sorted(allowed)})")
    for name in parameter_names(kind):
        if name not in given:
            raise FaultError(name, f"required for {kind.kind}")
    for name in ("offset_m", "force_n"):
        if isinstance(given.get(name), list):
            given[name] = tuple(given[name])  # type: ignore[arg-type]
    try:
        fault: Fault = kind(**given)  # type: ignore[arg-type]
    except TypeError as error:  # not reachable with the checks above; a clear error anyway
        raise FaultError("kind", str(error)) from None
    check_target(fault, body_names, n_vehicles)
    return fault


def check_target(fault: Fault, body_names: Sequence[str], n_vehicles: int) -> None:
    """Raise ``FaultError`` when ``fault`` names a rigid body QTM does not stream or a
    vehicle beyond the world's ``n_vehicles`` (numbered 1 … N)."""
    body = getattr(fault, "body", None)
    if body is not None and body not in body_names:
        raise FaultError(
            "body", f"{body!r} is not a configured rigid body (mocap.bodies: {list(body_names)})"
        )
    vehicle = getattr(fault, "vehicle", None)
    if vehicle is not None and vehicle > n_vehicles:
        raise FaultError(
            "vehicle", f"{vehicle} is not a vehicle of this world (its vehicles: 1 to {n_vehicles})"
        )


def target(fault: Fault) -> tuple[str, str | int | None]:
    """What a fault acts on: a new fault with the same target replaces the old one."""
    return fault.kind, getattr(fault, "body", getattr(fault, "vehicle", None))


@dataclass(frozen=True)
class ActiveFault:
    """A fault in effect since ``started_s`` (world time [s])."""

    fault: Fault
    started_s: float

    @property
    def ends_s(self) -> float | None:
        """When it ends by itself (world time [s]); None: when cleared."""
        duration = self.fault.duration_s
        return None if duration is None else self.started_s + duration

    def remaining_s(self, now_s: float) -> float | None:
        """How long it still lasts, within [0, its duration] (``started_s + duration`` less
        ``now_s`` can round above the duration itself)."""
        duration = self.fault.duration_s
        if duration is None:
            return None
        return min(duration, max(0.0, self.started_s + duration - now_s))

    def view(self, now_s: float) -> dict[str, Any]:
        """As the API shows it (world seconds)."""
        return {
            "kind": self.fault.kind,
            "params": parameters(self.fault),
            "duration_s": self.fault.duration_s,
            "started_s": self.started_s,
            "remaining_s": self.remaining_s(now_s),
        }

    def describe(self) -> str:
        """One line for the world's log."""
        words = [self.fault.kind] + [f"{k}={v}" for k, v in parameters(self.fault).items()]
        duration = self.fault.duration_s
        words.append("until cleared" if duration is None else f"for {duration:g} s")
        return " ".join(words)


class FaultSet:
    """The faults in effect in one world, and their effects. ``body_names``: the rigid
    bodies QTM streams (what ``body`` may name); ``n_vehicles``: the world's simulated PX4s
    (``vehicle`` names 1 … N); ``seed``: of the UDP-loss draws."""

    def __init__(self, body_names: Sequence[str], n_vehicles: int, seed: int = 0) -> None:
        self.body_names = tuple(body_names)
        self.n_vehicles = n_vehicles
        self._active: list[ActiveFault] = []
        self._frozen: Mapping[str, BodyPose] | None = None
        # Its own stream, apart from the measurement model's and the heartbeats'.
        self._random = random.Random(f"uavbar-faults-{seed}").random

    # ---- lifecycle --------------------------------------------------------------------------
    @property
    def active(self) -> tuple[ActiveFault, ...]:
        """The faults in effect, oldest first."""
        return tuple(self._active)

    def check(self, fault: Fault) -> None:
        """``FaultError`` when ``fault`` names a body QTM does not stream or a vehicle this
        world does not have."""
        check_target(fault, self.body_names, self.n_vehicles)

    def start(self, fault: Fault, now_s: float) -> tuple[ActiveFault, ActiveFault | None]:
        """Put ``fault`` in effect at ``now_s``; returns it and the fault it replaced (same
        kind, same target), if any. ``FaultError`` as ``check`` says."""
        self.check(fault)
        replaced = next((a for a in self._active if target(a.fault) == target(fault)), None)
        if replaced is not None:
            self._active.remove(replaced)
        started = ActiveFault(fault, now_s)
        self._active.append(started)
        if isinstance(fault, MocapFreeze):
            self._frozen = None  # hold the next frame's poses
        return started, replaced

    def clear(self) -> list[ActiveFault]:
        """End every fault now; returns those that were in effect."""
        ended, self._active = self._active, []
        self._frozen = None
        return ended

    def expire(self, now_s: float) -> list[ActiveFault]:
        """End the faults whose time is up at ``now_s``; returns them."""
        ended = [a for a in self._active if a.ends_s is not None and a.ends_s <= now_s]
        if ended:
            self._active = [a for a in self._active if a not in ended]
            if not self._of(MocapFreeze):
                self._frozen = None
        return ended

    def views(self, now_s: float) -> list[dict[str, Any]]:
        return [a.view(now_s) for a in self._active]

    def _of(self, kind: type[F]) -> list[F]:
        return [a.fault for a in self._active if isinstance(a.fault, kind)]

    # ---- effects ------------------------------------------------------------------------------
    def frame(self, poses: Mapping[str, BodyPose]) -> Mapping[str, BodyPose]:
        """The poses one frame reports, from the measured ``poses`` (by body name)."""
        if not self._active:
            return poses
        reported = dict(poses)
        for lost in self._of(MocapBodyLost):
            reported[lost.body] = BodyPose.untracked(lost.body)
        for jump in self._of(MocapJump):
            pose = reported.get(jump.body)
            if pose is not None and pose.tracked:
                offset = np.asarray(jump.offset_m, dtype=float)
                reported[jump.body] = replace(pose, position_m=pose.position_m + offset)
        if self._of(MocapFreeze):
            if self._frozen is None:
                self._frozen = reported
            return self._frozen
        return reported

    def _lost_at_random(self) -> bool:
        return any(self._random() < loss.fraction for loss in self._of(UdpLoss))

    def keep_mocap_packet(self, udp: bool) -> bool:
        """Whether one data packet of the QTM stream reaches its client (``udp``: streamed
        over UDP, else over the TCP connection)."""
        if self._of(MocapSilent):
            return False
        return not (udp and self._lost_at_random())

    def keep_mavlink(self, vehicle: int, inbound: bool) -> bool:
        """Whether one MAVLink datagram to (``inbound``) or from simulated PX4 ``vehicle``
        gets through."""
        for fault in self._active:
            if isinstance(fault.fault, LinkLost | Px4Reboot) and fault.fault.vehicle == vehicle:
                return False
        return not self._lost_at_random()

    def loads(self, plant_body: Mapping[str, str]) -> list[ExternalLoad]:
        """The external loads the pushes in effect put on the plant (``plant_body``: the
        plant's body of each rigid body QTM streams), each over its own time."""
        return [
            ExternalLoad(
                plant_body[a.fault.body],
                a.fault.force_n,
                start_s=a.started_s,
                duration_s=a.fault.duration_s,
            )
            for a in self._active
            if isinstance(a.fault, Push)
        ]

    def powered(self, vehicle: int) -> bool:
        """Whether simulated PX4 ``vehicle`` is up (not rebooting)."""
        return not any(reboot.vehicle == vehicle for reboot in self._of(Px4Reboot))
