"""Frozen parameters of N UAVs carrying one rigid payload on N rigid cables (SI units).

The payload frame has its origin at the payload's CoM; ``attachments_m[i-1]`` is where
cable i is fixed, in that frame. A payload whose attachments lie on one line through its
CoM is a bar: its spin about that line is left out, as in (5g), and only its moment of
inertia about the perpendicular axes enters (``controllers.formation_model``).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from controllers.params import UavParams
from geometry.arrays import FloatArray
from geometry.formation import MAX_VEHICLES, MIN_VEHICLES, FormationLayout

Vector3 = tuple[float, float, float]

BAR_TOLERANCE_M = 1e-9
"""How far an attachment may be from the line through the CoM and the other attachments
for the payload to count as a bar [m]."""

_INERTIA_RTOL = 1e-9


@dataclass(frozen=True)
class PayloadParams:
    """The rigid payload: mass [kg], inertia about its CoM in its own frame [kg m²], and
    the cables' attachment points in its frame relative to its CoM [m], one per UAV."""

    mass_kg: float
    inertia_kgm2: tuple[Vector3, Vector3, Vector3]
    attachments_m: tuple[Vector3, ...]

    def __post_init__(self) -> None:
        if not self.mass_kg > 0.0:
            raise ValueError(f"the payload's mass must be positive, not {self.mass_kg} kg")
        if not np.any(self._attachments()):
            raise ValueError("the attachments must not all be at the payload's CoM")
        J = self.inertia_matrix()
        scale = float(np.abs(J).max())
        if not np.allclose(J, J.T, rtol=0.0, atol=_INERTIA_RTOL * scale):
            raise ValueError("the payload's inertia must be symmetric")
        axis = self.bar_axis
        if axis is None:
            if not np.all(np.linalg.eigvalsh(J) > 0.0):
                raise ValueError(
                    "the inertia of a payload that is not a bar must be positive definite"
                )
            return
        # (5g) has one moment J_b: the same about every axis perpendicular to the bar.
        axial = float(axis @ J @ axis)
        rod = axial * np.outer(axis, axis) + self.perpendicular_inertia_kgm2 * (
            np.eye(3) - np.outer(axis, axis)
        )
        if not self.perpendicular_inertia_kgm2 > 0.0 or not np.allclose(
            J, rod, rtol=0.0, atol=_INERTIA_RTOL * scale
        ):
            raise ValueError(
                "a bar's inertia must be one positive moment about every axis "
                "perpendicular to it (5g)"
            )

    def _attachments(self) -> FloatArray:
        return np.array(self.attachments_m, dtype=float).reshape(-1, 3)

    def inertia_matrix(self) -> FloatArray:
        """J in the payload frame, shape (3, 3)."""
        return np.array(self.inertia_kgm2, dtype=float)

    @property
    def bar_axis(self) -> FloatArray | None:
        """The unit vector along the bar in the payload frame, shape (3,), pointing to the
        attachment farthest from the CoM; None if the payload is not a bar."""
        points = self._attachments()
        farthest = points[np.argmax(np.linalg.norm(points, axis=1))]
        axis: FloatArray = farthest / np.linalg.norm(farthest)
        off_line = points - np.outer(points @ axis, axis)
        if np.linalg.norm(off_line, axis=1).max() > BAR_TOLERANCE_M:
            return None
        return axis

    @property
    def is_bar(self) -> bool:
        """The attachments lie on one line through the CoM (to ``BAR_TOLERANCE_M``)."""
        return self.bar_axis is not None

    @property
    def perpendicular_inertia_kgm2(self) -> float:
        """A bar's J_b of (5g): its moment about an axis perpendicular to it [kg m²]."""
        axis = self.bar_axis
        if axis is None:
            raise ValueError("the payload is not a bar")
        J = self.inertia_matrix()
        return float(np.trace(J) - axis @ J @ axis) / 2.0


@dataclass(frozen=True)
class FormationParams:
    """N UAVs (2 to 8), the payload and the cables: UAV i hangs the payload by cable i,
    of length ``cable_lengths_m[i-1]``, fixed at ``payload.attachments_m[i-1]``."""

    uavs: tuple[UavParams, ...]
    payload: PayloadParams
    cable_lengths_m: tuple[float, ...]
    gravity_mps2: float = 9.81

    def __post_init__(self) -> None:
        n = len(self.uavs)
        if not MIN_VEHICLES <= n <= MAX_VEHICLES:
            raise ValueError(f"a formation has {MIN_VEHICLES} to {MAX_VEHICLES} UAVs, not {n}")
        if len(self.cable_lengths_m) != n or len(self.payload.attachments_m) != n:
            raise ValueError(
                f"{n} UAVs need {n} cables and {n} attachments, not "
                f"{len(self.cable_lengths_m)} and {len(self.payload.attachments_m)}"
            )
        for i, uav in enumerate(self.uavs, start=1):
            if not uav.mass_kg > 0.0 or not all(j > 0.0 for j in uav.inertia_kgm2):
                raise ValueError(f"UAV {i}'s mass and moments of inertia must be positive")
        for i, length in enumerate(self.cable_lengths_m, start=1):
            if not length > 0.0:
                raise ValueError(f"cable {i}'s length must be positive, not {length} m")
        if not self.gravity_mps2 > 0.0:
            raise ValueError("gravity must be positive")

    @property
    def n_vehicles(self) -> int:
        """N."""
        return len(self.uavs)

    @cached_property
    def layout(self) -> FormationLayout:
        """The state and input layout for this formation's N."""
        return FormationLayout(self.n_vehicles)

    @property
    def is_symmetric(self) -> bool:
        """Assumption 1, for N UAVs: equal UAV masses, equal cable lengths, and the
        attachments equally far from the payload's CoM, their centroid (so that every
        cable carries the same share, at the same angle), to ``BAR_TOLERANCE_M``."""
        a = np.array(self.payload.attachments_m, dtype=float)
        distances = np.linalg.norm(a, axis=1)
        return (
            len({uav.mass_kg for uav in self.uavs}) == 1
            and len(set(self.cable_lengths_m)) == 1
            and float(np.ptp(distances)) <= BAR_TOLERANCE_M
            and float(np.abs(a.mean(axis=0)).max()) <= BAR_TOLERANCE_M
        )

    @property
    def bar_arms_m(self) -> tuple[float, float]:
        """(d1, d2) of the paper's UAV–bar system (``formation_from_bar``): the distances
        from the bar's CoM to cables 1 and 2 along its x axis. Raises ``ValueError`` for
        any other formation."""
        if self.n_vehicles == 2:
            (x1, y1, z1), (x2, y2, z2) = self.payload.attachments_m
            if not any((y1, z1, y2, z2)) and x1 < x2:
                return -x1, x2
        raise ValueError(
            "only a bar carried by two UAVs, along its x axis from cable 1 to cable 2, "
            "has the arms d1 and d2"
        )


def formation_from_bar(
    uavs: tuple[UavParams, UavParams],
    bar_mass_kg: float,
    d1_m: float,
    d2_m: float,
    bar_inertia_kgm2: float,
    cable_lengths_m: tuple[float, float],
    gravity_mps2: float = 9.81,
) -> FormationParams:
    """The paper's UAV–bar system (Section II-B) as a formation of two: the bar's CoM
    ``d1_m``/``d2_m`` from the attachments of cables 1 and 2, J_b = ``bar_inertia_kgm2``
    about an axis through its CoM perpendicular to it (5g). The attachments are (−d1, 0, 0)
    and (d2, 0, 0), the inertia diag(0, J_b, J_b): the bar's x axis points from cable 1's
    attachment to cable 2's."""
    return FormationParams(
        uavs=uavs,
        payload=PayloadParams(
            mass_kg=bar_mass_kg,
            inertia_kgm2=(
                (0.0, 0.0, 0.0),
                (0.0, bar_inertia_kgm2, 0.0),
                (0.0, 0.0, bar_inertia_kgm2),
            ),
            attachments_m=((-d1_m, 0.0, 0.0), (d2_m, 0.0, 0.0)),
        ),
        cable_lengths_m=cable_lengths_m,
        gravity_mps2=gravity_mps2,
    )
