"""The plant of N UAVs carrying a rigid payload, built from the controllers' formation
(``controllers.formation_params.FormationParams``) and what only the plant has: each
airframe's feet, motors and limits, the cables' elasticity, the payload's contact points
and drag, the wind, the step.

``sim`` imports nothing of ``controllers`` (docs/architecture.md: the plant is never the
controllers' model), so the formation is read through the Protocols below, which
``FormationParams`` satisfies; only its masses, inertias, attachments and cable lengths
are taken.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Protocol

import numpy as np

from sim.plant_params import (
    BarParams,
    CableParams,
    PayloadBodyParams,
    PlantParams,
    UavBodyParams,
    Vec3,
    WindParams,
    as_mat3,
    diagonal,
)
from sim.plant_statics import bar_axis

_AIRFRAME = UavBodyParams()
_CABLE = CableParams()
_CALM = WindParams()
_TUBE_RADIUS_M = BarParams().tube_radius_m


class FormationUav(Protocol):
    """One UAV of a formation: mass [kg], principal moments of inertia [kg m²]."""

    @property
    def mass_kg(self) -> float: ...

    @property
    def inertia_kgm2(self) -> tuple[float, float, float]: ...


class FormationPayload(Protocol):
    """A formation's payload: mass [kg], inertia about its CoM in its frame [kg m²]
    (singular about a bar's axis), and cable i's attachment in that frame [m]."""

    @property
    def mass_kg(self) -> float: ...

    @property
    def inertia_kgm2(self) -> tuple[Vec3, Vec3, Vec3]: ...

    @property
    def attachments_m(self) -> tuple[Vec3, ...]: ...


class Formation(Protocol):
    """N UAVs, the payload, cable i from UAV i [m], gravity [m/s²]."""

    @property
    def uavs(self) -> Sequence[FormationUav]: ...

    @property
    def payload(self) -> FormationPayload: ...

    @property
    def cable_lengths_m(self) -> Sequence[float]: ...

    @property
    def gravity_mps2(self) -> float: ...


def plant_params_from_formation(
    formation: Formation,
    *,
    airframe: UavBodyParams = _AIRFRAME,
    cable: CableParams = _CABLE,
    payload_contact_points_m: tuple[Vec3, ...] | None = None,
    payload_contact_radius_m: float = _TUBE_RADIUS_M,
    payload_drag_linear_n_s_per_m: float = 0.0,
    wind: WindParams = _CALM,
    step_s: float = 0.001,
) -> PlantParams:
    """The plant of ``formation``: every UAV ``airframe`` with the formation's mass and
    inertia, every cable ``cable`` with the formation's length, the payload resting on
    ``payload_contact_points_m`` (its frame; None: its attachment points — a plate's or a
    frame's corners), each a sphere of ``payload_contact_radius_m``.

    Two UAVs with their attachments on the payload's x axis, cable 1's behind the CoM and
    cable 2's ahead, carry the paper's bar (``BarParams``, the body "bar", resting on its
    ends, a tube of ``payload_contact_radius_m``), as ``plant_params_from_config`` builds it
    from the same figures. Any other payload is a ``PayloadBodyParams`` (the body
    "payload"); one whose attachments lie on a line through its CoM (a bar of three or more
    cables) gets the tube's axial inertia m r², which the formation leaves out.
    """
    uavs = tuple(
        dataclasses.replace(airframe, mass_kg=uav.mass_kg, inertia_kgm2=diagonal(uav.inertia_kgm2))
        for uav in formation.uavs
    )
    cables = tuple(
        dataclasses.replace(cable, length_m=length) for length in formation.cable_lengths_m
    )
    arms = _bar_arms_m(formation.payload)
    bar = BarParams()
    payload: PayloadBodyParams | None = None
    if arms is None:
        payload = _payload_body(
            formation.payload,
            payload_contact_points_m,
            payload_contact_radius_m,
            payload_drag_linear_n_s_per_m,
        )
    elif payload_contact_points_m is not None:
        raise ValueError("the bar rests on its ends: it takes no contact points")
    else:
        d1, d2 = arms
        J = formation.payload.inertia_kgm2
        perpendicular = (J[1][1] + J[2][2]) / 2.0
        mass = formation.payload.mass_kg
        bar = BarParams(
            mass_kg=mass,
            length_m=d1 + d2,
            com_from_end1_m=d1,
            tube_radius_m=payload_contact_radius_m,
            inertia_kgm2=diagonal(
                (mass * payload_contact_radius_m**2, perpendicular, perpendicular)
            ),
            drag_linear_n_s_per_m=payload_drag_linear_n_s_per_m,
        )
    return PlantParams(
        uavs=uavs,
        bar=bar,
        cables=cables,
        wind=wind,
        gravity_mps2=formation.gravity_mps2,
        step_s=step_s,
        payload=payload,
    )


def _bar_arms_m(payload: FormationPayload) -> tuple[float, float] | None:
    """(d1, d2) of a payload that is the paper's bar: two attachments on its x axis, cable
    1's at x < 0 and cable 2's at x > 0; None for any other."""
    if len(payload.attachments_m) != 2:
        return None
    (x1, y1, z1), (x2, y2, z2) = payload.attachments_m
    if any((y1, z1, y2, z2)) or not x1 < 0.0 < x2:
        return None
    return -x1, x2


def _payload_body(
    payload: FormationPayload,
    contact_points_m: tuple[Vec3, ...] | None,
    contact_radius_m: float,
    drag_linear_n_s_per_m: float,
) -> PayloadBodyParams:
    attachments = np.array(payload.attachments_m, dtype=float)
    J = np.array(payload.inertia_kgm2, dtype=float)
    axis = bar_axis(attachments)
    if axis is not None:
        J += payload.mass_kg * contact_radius_m**2 * np.outer(axis, axis)
    return PayloadBodyParams(
        mass_kg=payload.mass_kg,
        inertia_kgm2=as_mat3(J),
        attachments_body_m=payload.attachments_m,
        contact_points_body_m=(
            payload.attachments_m if contact_points_m is None else contact_points_m
        ),
        contact_radius_m=contact_radius_m,
        drag_linear_n_s_per_m=drag_linear_n_s_per_m,
    )
