"""What a tick record becomes in an MCAP flight log: named, typed messages, no I/O.

Two kinds of channel. Foxglove's well-known schemas (protobuf, encoded by ``foxglove-sdk``)
for what Foxglove draws in 3D: ``/tf`` (world → bar, uav1, uav2, bar_reference),
``/bar/pose``, ``/uav1/pose``, ``/uav2/pose`` and ``/scene`` (the bar, both cables and the
reference bar). Our own JSON messages, each with a JSON Schema, for everything plotted or
read back: ``/uavbar/state`` and ``/uavbar/reference`` (the states by name),
``/uavbar/inputs``, ``/uavbar/errors``, ``/uavbar/mpc``, ``/uavbar/mode``,
``/uavbar/timing``, ``/uavbar/mocap`` (one message each per tick) and ``/uavbar/notices``
(one per notice). The per-tick JSON channels carry everything a ``TickRecord`` holds, so the
record comes back whole from them (``record_from_messages``).
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import foxglove.messages as fg
import numpy as np

from geometry.frames import quaternion_from_euler_zyx
from geometry.state import P_B, PAYLOAD_YAW, payload_points
from supervisor.flight.tick_record import TickRecord
from supervisor.logs.flight_log import LOG_LAYOUT

WORLD_FRAME = "world"
BODIES = (
    ("bar", P_B.start),
    *((f"uav{i}", LOG_LAYOUT.uav_block(i).start) for i in LOG_LAYOUT.vehicles),
)
VEC3 = ("x", "y", "z")
EULER = ("roll", "pitch", "yaw")

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
_STATE_SCHEMA = _object({"t_s": _NUMBER, **{name: _BODY_SCHEMA for name, _ in BODIES}})
_UAV_INPUT_SCHEMA = _object({"thrust_n": _NUMBER, "torque_nm": _VEC3_SCHEMA})

JSON_SCHEMAS: dict[str, tuple[str, dict[str, Any]]] = {
    "/uavbar/state": ("uavbar.BarSystemState", _STATE_SCHEMA),
    "/uavbar/reference": ("uavbar.BarSystemState", _STATE_SCHEMA),
    "/uavbar/inputs": (
        "uavbar.Inputs",
        _object({"uav1": _UAV_INPUT_SCHEMA, "uav2": _UAV_INPUT_SCHEMA}),
    ),
    "/uavbar/errors": (
        "uavbar.TrackingErrors",
        _object(
            {
                "bar": _object({"position_m": _VEC3_SCHEMA, "yaw_deg": _NUMBER}),
                **{
                    uav: _object({"position_m": _VEC3_SCHEMA, "attitude_deg": _EULER_SCHEMA})
                    for uav in ("uav1", "uav2")
                },
            }
        ),
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
    "/uavbar/notices": (
        "uavbar.Notice",
        _object({"t_s": _NUMBER, "text": {"type": "string"}}),
    ),
}

PER_TICK_TOPICS = tuple(topic for topic in JSON_SCHEMAS if topic != "/uavbar/notices")

WELL_KNOWN: dict[str, type[Any]] = {
    "/tf": fg.FrameTransforms,
    "/bar/pose": fg.PoseInFrame,
    "/uav1/pose": fg.PoseInFrame,
    "/uav2/pose": fg.PoseInFrame,
    "/scene": fg.SceneUpdate,
}


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


def _bar_system(t_s: float, state: Sequence[float]) -> dict[str, Any]:
    return {"t_s": t_s, **{name: _body(state, offset) for name, offset in BODIES}}


def _wrapped_deg(angle_rad: float) -> float:
    return math.degrees(math.remainder(angle_rad, 2 * math.pi))


def _errors(state: Sequence[float], ref: Sequence[float]) -> dict[str, Any]:
    def position(offset: int) -> dict[str, float | None]:
        return _named([state[offset + k] - ref[offset + k] for k in range(3)], VEC3)

    def attitude(offset: int) -> dict[str, float | None]:
        return _named(
            [_wrapped_deg(state[offset + 6 + k] - ref[offset + 6 + k]) for k in range(3)],
            EULER,
        )

    return {
        "bar": {
            "position_m": position(0),
            "yaw_deg": _finite(_wrapped_deg(state[PAYLOAD_YAW] - ref[PAYLOAD_YAW])),
        },
        **{uav: {"position_m": position(o), "attitude_deg": attitude(o)} for uav, o in BODIES[1:]},
    }


def json_messages(record: TickRecord) -> Iterator[tuple[str, dict[str, Any]]]:
    """The per-tick JSON messages of ``record``, topic by topic (``PER_TICK_TOPICS``)."""
    state, ref, u = record.state, record.state_ref, record.inputs
    yield "/uavbar/state", _bar_system(record.t_s, state)
    yield "/uavbar/reference", _bar_system(record.t_s, ref)
    yield (
        "/uavbar/inputs",
        {
            f"uav{i + 1}": {
                "thrust_n": _finite(u[4 * i]),
                "torque_nm": _named(u[4 * i + 1 : 4 * i + 4], VEC3),
            }
            for i in range(2)
        },
    )
    yield "/uavbar/errors", _errors(state, ref)
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


def _state_from(message: Mapping[str, Any]) -> list[float]:
    values: list[float] = []
    for name, _ in BODIES:
        body = message[name]
        values += _unnamed(body["position_m"], VEC3)
        values += _unnamed(body["velocity_m_s"], VEC3)
        values += _unnamed(body["euler_rad"], EULER)
        values += _unnamed(body["rates_rad_s"], VEC3)
    return values


def _number(value: float | None) -> float:
    return math.nan if value is None else float(value)


def record_from_messages(messages: Mapping[str, Mapping[str, Any]]) -> TickRecord:
    """The tick record back from its per-tick JSON messages (decoded), by topic."""
    inputs: list[float] = []
    for uav in ("uav1", "uav2"):
        entry = messages["/uavbar/inputs"][uav]
        inputs += [_number(entry["thrust_n"]), *_unnamed(entry["torque_nm"], VEC3)]
    mpc, timing = messages["/uavbar/mpc"], messages["/uavbar/timing"]
    return TickRecord(
        t_s=float(messages["/uavbar/state"]["t_s"]),
        mode=messages["/uavbar/mode"]["mode"],
        controller=mpc["controller"],
        state=_state_from(messages["/uavbar/state"]),
        state_ref=_state_from(messages["/uavbar/reference"]),
        inputs=inputs,
        plan_status=mpc["plan_status"],
        solve_ms=_number(mpc["solve_ms"]),
        compute_ms=_number(timing["compute_ms"]),
        lateness_ms=_number(timing["lateness_ms"]),
        mocap_age_ms=_number(messages["/uavbar/mocap"]["age_ms"]),
        extra=dict(timing["extra"]),
    )


@dataclass(frozen=True)
class SceneStyle:
    """How the bar system is drawn: its cable attachments' arms (d_1, d_2) [m]."""

    arms_m: tuple[float, float]

    @property
    def attachments_m(self) -> tuple[tuple[float, float, float], ...]:
        """The attachments in the bar's frame, its x axis from cable 1's to cable 2's."""
        d1, d2 = self.arms_m
        return ((-d1, 0.0, 0.0), (d2, 0.0, 0.0))


_BAR_COLOUR = fg.Color(r=0.85, g=0.55, b=0.1, a=1.0)
_CABLE_COLOUR = fg.Color(r=0.2, g=0.2, b=0.2, a=1.0)
_REFERENCE_COLOUR = fg.Color(r=0.1, g=0.6, b=0.1, a=0.5)
_UAV_COLOUR = fg.Color(r=0.1, g=0.3, b=0.9, a=0.8)


def _point(p: Sequence[float]) -> fg.Point3:
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


def well_known_messages(
    record: TickRecord, timestamp: fg.Timestamp, style: SceneStyle
) -> Iterator[tuple[str, Any]]:
    """Foxglove's messages of ``record`` (``WELL_KNOWN``'s topics); none while the state
    is not finite (no estimate yet: nothing to draw), and no reference while there is none."""
    state, ref = record.state, record.state_ref
    if not _finite_state(state):
        return
    has_reference = _finite_state(ref)
    placements = {name: _placement(state, offset) for name, offset in BODIES}
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
            *([("bar_reference", _placement(ref, 0))] if has_reference else []),
        )
    ]
    yield "/tf", fg.FrameTransforms(transforms=transforms)
    poses = {
        name: fg.Pose(position=position, orientation=orientation)
        for name, (position, orientation) in placements.items()
    }
    for name, pose in poses.items():
        yield f"/{name}/pose", fg.PoseInFrame(timestamp=timestamp, frame_id=WORLD_FRAME, pose=pose)
    x = np.asarray(state)
    end_1, end_2 = payload_points(x, style.attachments_m)
    uav_1, uav_2 = (LOG_LAYOUT.uav_position(x, i) for i in LOG_LAYOUT.vehicles)

    def line(points: list[Any], colour: fg.Color, thickness: float) -> fg.LinePrimitive:
        return fg.LinePrimitive(
            type=fg.LinePrimitiveLineType.LineList,
            thickness=thickness,
            points=[_point(p) for p in points],
            color=colour,
        )

    def entity(name: str, **primitives: Any) -> fg.SceneEntity:
        return fg.SceneEntity(timestamp=timestamp, frame_id=WORLD_FRAME, id=name, **primitives)

    uav_size = fg.Vector3(x=0.25, y=0.25, z=0.06)
    entities = [
        entity("bar", lines=[line([end_1, end_2], _BAR_COLOUR, 0.03)]),
        entity("cables", lines=[line([uav_1, end_1, uav_2, end_2], _CABLE_COLOUR, 0.005)]),
        entity(
            "uavs",
            cubes=[
                fg.CubePrimitive(pose=poses[name], size=uav_size, color=_UAV_COLOUR)
                for name in ("uav1", "uav2")
            ],
        ),
    ]
    if has_reference:
        ref_1, ref_2 = payload_points(np.asarray(ref), style.attachments_m)
        entities.append(entity("reference", lines=[line([ref_1, ref_2], _REFERENCE_COLOUR, 0.02)]))
    yield "/scene", fg.SceneUpdate(entities=entities)
