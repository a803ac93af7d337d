"""What a tick record becomes in an MCAP flight log: named, typed messages, no I/O.

Two kinds of channel. Foxglove's well-known schemas (protobuf, encoded by ``foxglove-sdk``)
for what Foxglove draws in 3D: ``/tf`` (world → bar, uav1 … uavN, bar_reference),
``/bar/pose``, ``/uav1/pose`` … ``/uavN/pose`` and ``/scene`` (the payload, every cable and
the reference payload). Our own JSON messages, each with a JSON Schema, for everything
plotted or read back: ``/uavbar/state`` and ``/uavbar/reference`` (the states by name),
``/uavbar/inputs``, ``/uavbar/errors``, ``/uavbar/mpc``, ``/uavbar/mode``,
``/uavbar/timing``, ``/uavbar/mocap`` (one message each per tick) and ``/uavbar/notices``
(one per notice). The per-tick JSON channels carry everything a ``TickRecord`` holds, so the
record comes back whole from them (``record_from_messages``).

The channels name the N UAVs of the log's formation (``FormationLayout``) ``uav1`` …
``uavN``, and the payload ``bar`` whatever its shape: the paper's names, which the logs of
two UAVs and a bar had before any other payload flew.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from functools import cache, cached_property
from types import MappingProxyType
from typing import Any

import foxglove.messages as fg
import numpy as np

from controllers.formation_params import Vector3
from geometry.arrays import FloatArray
from geometry.formation import FormationLayout
from geometry.frames import quaternion_from_euler_zyx
from geometry.state import P_B, PAYLOAD_YAW, payload_points
from supervisor.flight.tick_record import TickRecord

WORLD_FRAME = "world"
PAYLOAD = "bar"  # the payload's name in every message, frame and topic
VEC3 = ("x", "y", "z")
EULER = ("roll", "pitch", "yaw")


def uav_names(layout: FormationLayout) -> tuple[str, ...]:
    """``uav1`` … ``uavN``: each UAV's name in the messages."""
    return tuple(f"uav{i}" for i in layout.vehicles)


@cache
def bodies(layout: FormationLayout) -> tuple[tuple[str, int], ...]:
    """Each body's name and where its (p, v, Θ, ω) block starts in the state: the payload's
    first, then UAV 1's … UAV N's."""
    return (
        (PAYLOAD, P_B.start),
        *zip(uav_names(layout), (layout.uav_block(i).start for i in layout.vehicles), strict=True),
    )


_NUMBER = {"type": ["number", "null"]}  # null: not finite (JSON has no NaN)


def _object(properties: Mapping[str, Any], **extra: Any) -> dict[str, Any]:
    return {"type": "object", "properties": dict(properties), **extra}


_VEC3_SCHEMA = _object(dict.fromkeys(VEC3, _NUMBER))
_EULER_SCHEMA = _object(dict.fromkeys(EULER, _NUMBER))
_BODY_SCHEMA = _object(
    {
        "position_m": _VEC3_SCHEMA,
        "velocity_m_s": _VEC3_SCHEMA,
        "euler_rad": _EULER_SCHEMA,
        "rates_rad_s": _VEC3_SCHEMA,
    }
)
_UAV_INPUT_SCHEMA = _object({"thrust_n": _NUMBER, "torque_nm": _VEC3_SCHEMA})
_UAV_ERROR_SCHEMA = _object({"position_m": _VEC3_SCHEMA, "attitude_deg": _EULER_SCHEMA})

NOTICES_TOPIC = "/uavbar/notices"
PER_TICK_TOPICS = (
    "/uavbar/state",
    "/uavbar/reference",
    "/uavbar/inputs",
    "/uavbar/errors",
    "/uavbar/mpc",
    "/uavbar/mode",
    "/uavbar/timing",
    "/uavbar/mocap",
)


@cache
def json_schemas(layout: FormationLayout) -> Mapping[str, tuple[str, dict[str, Any]]]:
    """Our JSON channels of a log of ``layout``'s formation: topic → (schema name, JSON
    Schema); every topic of ``PER_TICK_TOPICS`` and ``NOTICES_TOPIC``."""
    uavs = uav_names(layout)
    state = _object({"t_s": _NUMBER, **{name: _BODY_SCHEMA for name, _ in bodies(layout)}})
    bar_error = _object({"position_m": _VEC3_SCHEMA, "yaw_deg": _NUMBER})
    return MappingProxyType(
        {
            "/uavbar/state": ("uavbar.BarSystemState", state),
            "/uavbar/reference": ("uavbar.BarSystemState", state),
            "/uavbar/inputs": ("uavbar.Inputs", _object(dict.fromkeys(uavs, _UAV_INPUT_SCHEMA))),
            "/uavbar/errors": (
                "uavbar.TrackingErrors",
                _object({PAYLOAD: bar_error, **dict.fromkeys(uavs, _UAV_ERROR_SCHEMA)}),
            ),
            "/uavbar/mpc": (
                "uavbar.MpcStatus",
                _object(
                    {
                        "controller": {"type": "string"},
                        "plan_status": {"type": "string"},
                        "solve_ms": _NUMBER,
                    }
                ),
            ),
            "/uavbar/mode": ("uavbar.Mode", _object({"mode": {"type": "string"}})),
            "/uavbar/timing": (
                "uavbar.TickTiming",
                _object(
                    {"compute_ms": _NUMBER, "lateness_ms": _NUMBER, "extra": {"type": "object"}},
                ),
            ),
            "/uavbar/mocap": ("uavbar.MocapHealth", _object({"age_ms": _NUMBER})),
            NOTICES_TOPIC: (
                "uavbar.Notice",
                _object({"t_s": _NUMBER, "text": {"type": "string"}}),
            ),
        }
    )


@cache
def well_known(layout: FormationLayout) -> Mapping[str, type[Any]]:
    """Foxglove's channels of a log of ``layout``'s formation: topic → message type."""
    return MappingProxyType(
        {
            "/tf": fg.FrameTransforms,
            **{f"/{name}/pose": fg.PoseInFrame for name, _ in bodies(layout)},
            "/scene": fg.SceneUpdate,
        }
    )


def _finite(value: float) -> float | None:
    return value if math.isfinite(value) else None


def _named(values: Sequence[float], names: Sequence[str]) -> dict[str, float | None]:
    return {name: _finite(float(v)) for name, v in zip(names, values, strict=True)}


def _body(state: Sequence[float], offset: int) -> dict[str, Any]:
    return {
        "position_m": _named(state[offset : offset + 3], VEC3),
        "velocity_m_s": _named(state[offset + 3 : offset + 6], VEC3),
        "euler_rad": _named(state[offset + 6 : offset + 9], EULER),
        "rates_rad_s": _named(state[offset + 9 : offset + 12], VEC3),
    }


def _bar_system(t_s: float, state: Sequence[float], layout: FormationLayout) -> dict[str, Any]:
    return {"t_s": t_s, **{name: _body(state, offset) for name, offset in bodies(layout)}}


def _wrapped_deg(angle_rad: float) -> float:
    return math.degrees(math.remainder(angle_rad, 2 * math.pi))


def _errors(
    state: Sequence[float], ref: Sequence[float], layout: FormationLayout
) -> dict[str, Any]:
    def position(offset: int) -> dict[str, float | None]:
        return _named([state[offset + k] - ref[offset + k] for k in range(3)], VEC3)

    def attitude(offset: int) -> dict[str, float | None]:
        return _named(
            [_wrapped_deg(state[offset + 6 + k] - ref[offset + 6 + k]) for k in range(3)],
            EULER,
        )

    return {
        PAYLOAD: {
            "position_m": position(P_B.start),
            "yaw_deg": _finite(_wrapped_deg(state[PAYLOAD_YAW] - ref[PAYLOAD_YAW])),
        },
        **{
            uav: {"position_m": position(o), "attitude_deg": attitude(o)}
            for uav, o in bodies(layout)[1:]
        },
    }


def _inputs(inputs: Sequence[float], layout: FormationLayout) -> dict[str, Any]:
    def uav(first: int) -> dict[str, Any]:
        return {
            "thrust_n": _finite(inputs[first]),
            "torque_nm": _named(inputs[first + 1 : first + 4], VEC3),
        }

    return {
        name: uav(layout.thrust_index(i))
        for name, i in zip(uav_names(layout), layout.vehicles, strict=True)
    }


def json_messages(
    record: TickRecord, layout: FormationLayout
) -> Iterator[tuple[str, dict[str, Any]]]:
    """The per-tick JSON messages of ``record`` (of ``layout``'s formation), topic by topic
    (``PER_TICK_TOPICS``)."""
    state, ref = record.state, record.state_ref
    yield "/uavbar/state", _bar_system(record.t_s, state, layout)
    yield "/uavbar/reference", _bar_system(record.t_s, ref, layout)
    yield "/uavbar/inputs", _inputs(record.inputs, layout)
    yield "/uavbar/errors", _errors(state, ref, layout)
    yield (
        "/uavbar/mpc",
        {
            "controller": record.controller,
            "plan_status": record.plan_status,
            "solve_ms": _finite(record.solve_ms),
        },
    )
    yield "/uavbar/mode", {"mode": record.mode}
    yield (
        "/uavbar/timing",
        {
            "compute_ms": _finite(record.compute_ms),
            "lateness_ms": _finite(record.lateness_ms),
            "extra": record.extra,
        },
    )
    yield "/uavbar/mocap", {"age_ms": _finite(record.mocap_age_ms)}


def _unnamed(values: Mapping[str, float | None], names: Sequence[str]) -> list[float]:
    return [math.nan if values[n] is None else float(values[n]) for n in names]  # type: ignore[arg-type]


def _state_from(message: Mapping[str, Any], layout: FormationLayout) -> list[float]:
    values: list[float] = []
    for name, _ in bodies(layout):
        body = message[name]
        values += _unnamed(body["position_m"], VEC3)
        values += _unnamed(body["velocity_m_s"], VEC3)
        values += _unnamed(body["euler_rad"], EULER)
        values += _unnamed(body["rates_rad_s"], VEC3)
    return values


def _number(value: float | None) -> float:
    return math.nan if value is None else float(value)


def _inputs_from(message: Mapping[str, Any], layout: FormationLayout) -> list[float]:
    uavs = uav_names(layout)
    if set(message) != set(uavs):
        raise ValueError(f"inputs of {sorted(message)}, not of the header's {list(uavs)}")
    inputs: list[float] = []
    for uav in uavs:
        inputs += [_number(message[uav]["thrust_n"]), *_unnamed(message[uav]["torque_nm"], VEC3)]
    return inputs


def record_from_messages(
    messages: Mapping[str, Mapping[str, Any]], layout: FormationLayout
) -> TickRecord:
    """The tick record back from its per-tick JSON messages (decoded), by topic, of a log
    of ``layout``'s formation. Raises ``ValueError`` for the inputs of another number of
    UAVs (``KeyError``, ``TypeError`` for other messages of another shape)."""
    mpc, timing = messages["/uavbar/mpc"], messages["/uavbar/timing"]
    return TickRecord(
        t_s=float(messages["/uavbar/state"]["t_s"]),
        mode=messages["/uavbar/mode"]["mode"],
        controller=mpc["controller"],
        state=_state_from(messages["/uavbar/state"], layout),
        state_ref=_state_from(messages["/uavbar/reference"], layout),
        inputs=_inputs_from(messages["/uavbar/inputs"], layout),
        plan_status=mpc["plan_status"],
        solve_ms=_number(mpc["solve_ms"]),
        compute_ms=_number(timing["compute_ms"]),
        lateness_ms=_number(timing["lateness_ms"]),
        mocap_age_ms=_number(messages["/uavbar/mocap"]["age_ms"]),
        extra=dict(timing["extra"]),
    )


@dataclass(frozen=True)
class SceneStyle:
    """How the formation is drawn: each cable's attachment in the payload's frame [m]
    (cable 1's first), one per UAV. The payload is the polygon through them, around its
    outline (a bar: the line between its two ends)."""

    attachments_m: tuple[Vector3, ...]

    @cached_property
    def layout(self) -> FormationLayout:
        """The formation drawn: one UAV per attachment."""
        return FormationLayout(len(self.attachments_m))

    @cached_property
    def outline(self) -> tuple[int, ...]:
        """The attachments' indices in turn around the payload's outline: by their angle
        about their centroid in the plane that fits them best (so that a plate is drawn as
        its polygon in whatever order its cables are numbered)."""
        points = np.array(self.attachments_m, dtype=float)
        centred = points - points.mean(axis=0)
        plane = np.linalg.svd(centred)[2]
        angles_rad = np.arctan2(centred @ plane[1], centred @ plane[0])
        return tuple(int(k) for k in np.argsort(angles_rad))

    def outline_m(self, state: Sequence[float]) -> list[FloatArray]:
        """The payload's polygon where ``state`` places it: its attachments in turn around
        it (``outline``), each (3,) [m]."""
        ends = payload_points(np.asarray(state), self.attachments_m)
        return [ends[k] for k in self.outline]

    def cables_m(self, state: Sequence[float]) -> list[tuple[FloatArray, FloatArray]]:
        """Each cable where ``state`` places it, cable 1's first: (its UAV's position, its
        attachment's), each (3,) [m]."""
        x = np.asarray(state)
        ends = payload_points(x, self.attachments_m)
        uavs = (self.layout.uav_position(x, i) for i in self.layout.vehicles)
        return list(zip(uavs, ends, strict=True))


_BAR_COLOUR = fg.Color(r=0.85, g=0.55, b=0.1, a=1.0)
_CABLE_COLOUR = fg.Color(r=0.2, g=0.2, b=0.2, a=1.0)
_REFERENCE_COLOUR = fg.Color(r=0.1, g=0.6, b=0.1, a=0.5)
_UAV_COLOUR = fg.Color(r=0.1, g=0.3, b=0.9, a=0.8)
_UAV_SIZE = fg.Vector3(x=0.25, y=0.25, z=0.06)


def _point(p: FloatArray) -> fg.Point3:
    return fg.Point3(x=float(p[0]), y=float(p[1]), z=float(p[2]))


def _placement(state: Sequence[float], offset: int) -> tuple[fg.Vector3, fg.Quaternion]:
    """A body's position and orientation (Foxglove's messages have no getters)."""
    w, x, y, z = quaternion_from_euler_zyx(state[offset + 6], state[offset + 7], state[offset + 8])
    return (
        fg.Vector3(x=state[offset], y=state[offset + 1], z=state[offset + 2]),
        fg.Quaternion(x=float(x), y=float(y), z=float(z), w=float(w)),
    )


def _finite_state(state: Sequence[float]) -> bool:
    return all(math.isfinite(v) for v in state)


def _line(
    points: Sequence[FloatArray],
    colour: fg.Color,
    thickness_m: float,
    kind: fg.LinePrimitiveLineType = fg.LinePrimitiveLineType.LineList,
) -> fg.LinePrimitive:
    return fg.LinePrimitive(
        type=kind, thickness=thickness_m, points=[_point(p) for p in points], color=colour
    )


def _scene(
    state: Sequence[float],
    ref: Sequence[float] | None,
    poses: Mapping[str, fg.Pose],
    timestamp: fg.Timestamp,
    style: SceneStyle,
) -> fg.SceneUpdate:
    """The payload, a cable from each UAV to its attachment, the UAVs, and the reference
    payload when there is one."""
    loop = fg.LinePrimitiveLineType.LineLoop
    cables = [point for cable in style.cables_m(state) for point in cable]

    def entity(name: str, **primitives: Any) -> fg.SceneEntity:
        return fg.SceneEntity(timestamp=timestamp, frame_id=WORLD_FRAME, id=name, **primitives)

    entities = [
        entity(PAYLOAD, lines=[_line(style.outline_m(state), _BAR_COLOUR, 0.03, loop)]),
        entity("cables", lines=[_line(cables, _CABLE_COLOUR, 0.005)]),
        entity(
            "uavs",
            cubes=[
                fg.CubePrimitive(pose=poses[name], size=_UAV_SIZE, color=_UAV_COLOUR)
                for name in uav_names(style.layout)
            ],
        ),
    ]
    if ref is not None:
        reference = _line(style.outline_m(ref), _REFERENCE_COLOUR, 0.02, loop)
        entities.append(entity("reference", lines=[reference]))
    return fg.SceneUpdate(entities=entities)


def well_known_messages(
    record: TickRecord, timestamp: fg.Timestamp, style: SceneStyle
) -> Iterator[tuple[str, Any]]:
    """Foxglove's messages of ``record`` (``well_known(style.layout)``'s topics); none while
    the state is not finite (no estimate yet: nothing to draw), and no reference while
    there is none."""
    state, ref = record.state, record.state_ref
    if not _finite_state(state):
        return
    reference = ref if _finite_state(ref) else None
    placements = {name: _placement(state, offset) for name, offset in bodies(style.layout)}
    transforms = [
        fg.FrameTransform(
            timestamp=timestamp,
            parent_frame_id=WORLD_FRAME,
            child_frame_id=name,
            translation=position,
            rotation=orientation,
        )
        for name, (position, orientation) in (
            *placements.items(),
            *(
                [(f"{PAYLOAD}_reference", _placement(ref, P_B.start))]
                if reference is not None
                else []
            ),
        )
    ]
    yield "/tf", fg.FrameTransforms(transforms=transforms)
    poses = {
        name: fg.Pose(position=position, orientation=orientation)
        for name, (position, orientation) in placements.items()
    }
    for name, pose in poses.items():
        yield f"/{name}/pose", fg.PoseInFrame(timestamp=timestamp, frame_id=WORLD_FRAME, pose=pose)
    yield "/scene", _scene(state, reference, poses, timestamp, style)
