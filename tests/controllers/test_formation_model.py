"""The N-cable rigid-payload model: the bar system for N = 2, the constraints (7) held to
second order and along trajectories, energy, exact Jacobians, and its parameters."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import numpy as np
import pytest

from controllers.formation_equilibria import formation_equilibrium
from controllers.formation_model import FormationModel
from controllers.formation_params import FormationParams, PayloadParams
from controllers.linearization import formation_jacobians
from controllers.params import UavParams
from geometry.formation import FormationLayout
from geometry.frames import rotation_from_euler_zyx
from geometry.state import P_B, TH_B, V_B, W_B
from tests.conftest import LAB_INERTIA, symmetric_params, uneven_params
from tests.controllers.test_formation_equilibria import (
    irregular_params,
    plate_params,
    reference_for,
    three_cable_bar,
)
from tests.controllers.test_linearization import assert_matches, central_differences
from tests.controllers.test_model import rk4, unit

Vector = np.ndarray


@pytest.mark.parametrize("bar", [symmetric_params(), uneven_params()], ids=["symmetric", "uneven"])
def test_two_cables_on_a_bar_follow_the_bar_system_model(bar: FormationParams) -> None:
    """With its own tensions, ẋ is (5b), (5e) and (5g) of the UAV–bar model: the bar pulled
    by T_1 n_1 + T_2 n_2, turned by n_b × (d2 T2 n2 − d1 T1 n1) / J_b, each UAV by its
    thrust less T_i n_i; the tensions keep both cables' lengths to second order."""
    model, layout = FormationModel(bar), bar.layout
    d1, d2 = bar.bar_arms_m
    m_b, J_b, g = bar.payload.mass_kg, bar.payload.perpendicular_inertia_kgm2, bar.gravity_mps2
    rng = np.random.default_rng(11)
    x = perturbed_consistent_state(bar, rng)
    u = formation_equilibrium(bar, reference_for(bar, 0.2, 0.4)).u
    u += rng.normal(0.0, 1.0, layout.n_inputs)
    xdot = np.asarray(model.dynamics(x, u)).ravel()
    T = np.asarray(model.tensions(x, u)).ravel()
    n_b = rotation_from_euler_zyx(*x[TH_B])[:, 0]
    ends = (x[P_B] - d1 * n_b, x[P_B] + d2 * n_b)
    n = [(x[layout.uav_slices(i)[0]] - ends[i - 1]) / bar.cable_lengths_m[i - 1] for i in (1, 2)]
    np.testing.assert_allclose(xdot[V_B], (T[0] * n[0] + T[1] * n[1]) / m_b - (0, 0, g))
    np.testing.assert_allclose(
        xdot[W_B], np.cross(n_b, d2 * T[1] * n[1] - d1 * T[0] * n[0]) / J_b, atol=1e-12
    )
    for i, uav in zip((1, 2), bar.uavs, strict=True):
        _, v, th, _ = layout.uav_slices(i)
        thrust = u[layout.thrust_index(i)] * rotation_from_euler_zyx(*x[th])[:, 2]
        np.testing.assert_allclose(
            xdot[v], (thrust - T[i - 1] * n[i - 1]) / uav.mass_kg - (0, 0, g)
        )


def attachments(params: FormationParams, x: Vector) -> list[Vector]:
    """e_i = p_b + R(Θ_b) a_i, computed independently of the CasADi model."""
    R = rotation_from_euler_zyx(*x[TH_B])
    return [x[P_B] + R @ np.asarray(a) for a in params.payload.attachments_m]


def cable_lengths(params: FormationParams, x: Vector) -> Vector:
    layout = FormationLayout(params.n_vehicles)
    ends = attachments(params, x)
    return np.array(
        [np.linalg.norm(x[layout.uav_slices(i)[0]] - ends[i - 1]) for i in layout.vehicles]
    )


def perturbed_consistent_state(
    params: FormationParams, rng: np.random.Generator, uav_spin_radps: float = 0.3
) -> Vector:
    """A state away from equilibrium that satisfies every (7) and its time derivative;
    the UAVs' body rates random with standard deviation ``uav_spin_radps``."""
    layout = FormationLayout(params.n_vehicles)
    x = formation_equilibrium(params, reference_for(params, 0.3, math.radians(25))).x
    x[TH_B] += (0.12, -0.15, 0.2)  # tilt the payload: attachments at new heights
    x[V_B] = rng.normal(0.0, 0.3, 3)
    x[W_B] = rng.normal(0.0, 0.5, 3)
    R = rotation_from_euler_zyx(*x[TH_B])
    for i, end in zip(layout.vehicles, attachments(params, x), strict=True):
        p, v, th, w = layout.uav_slices(i)
        offset = R @ np.asarray(params.payload.attachments_m[i - 1])
        end_velocity = x[V_B] + np.cross(x[W_B], offset)
        n_i = unit(x[p] - end + rng.normal(0.0, 0.1, 3))
        x[p] = end + params.cable_lengths_m[i - 1] * n_i
        x[v] = end_velocity + np.cross(rng.normal(0.0, 0.4, 3), n_i)  # ṙ ⊥ r keeps |r|
        x[th] += rng.normal(0.0, 0.1, 3)
        x[w] = rng.normal(0.0, uav_spin_radps, 3)
    return x


@pytest.mark.parametrize(
    "params", [plate_params(4), irregular_params(6)], ids=["plate4", "irregular6"]
)
def test_the_tensions_keep_every_constraint_s_second_derivative_zero(
    params: FormationParams,
) -> None:
    """c̈_i = ṙ_i·ṙ_i + r_i·r̈_i = 0, with r̈_i from ẋ: v̇_i − v̇_b − (ω̇ × q_i + ω × (ω × q_i))."""
    model, layout = FormationModel(params), FormationLayout(params.n_vehicles)
    rng = np.random.default_rng(5)
    x = perturbed_consistent_state(params, rng)
    u = formation_equilibrium(params, reference_for(params, 0.0, 0.3)).u + rng.normal(
        0.0, 1.0, layout.n_inputs
    )
    xdot = np.asarray(model.dynamics(x, u)).ravel()
    R = rotation_from_euler_zyx(*x[TH_B])
    w, w_dot = x[W_B], xdot[W_B]
    for i, end in zip(layout.vehicles, attachments(params, x), strict=True):
        p, v, _, _ = layout.uav_slices(i)
        q = R @ np.asarray(params.payload.attachments_m[i - 1])
        r, r_dot = x[p] - end, x[v] - x[V_B] - np.cross(w, q)
        r_ddot = xdot[v] - xdot[V_B] - np.cross(w_dot, q) - np.cross(w, np.cross(w, q))
        assert r_dot @ r_dot + r @ r_ddot == pytest.approx(0.0, abs=1e-11)


def test_cable_lengths_hold_along_a_trajectory() -> None:
    """RK4 at 1 ms for 2 s from a perturbed, consistent state of a three-cable plate:
    |p_i − e_i| stays l_i without stabilization, and the cables stay taut."""
    params = irregular_params(3)
    model = FormationModel(params)
    # UAVs that do not spin: open loop, a spinning UAV soon thrusts sideways and the
    # cables go slack, which the rigid-link model cannot express.
    x0 = perturbed_consistent_state(params, np.random.default_rng(7), uav_spin_radps=0.0)
    np.testing.assert_allclose(cable_lengths(params, x0), params.cable_lengths_m, atol=1e-12)
    u = formation_equilibrium(params, reference_for(params, 0.0, 0.2)).u
    u[[FormationLayout(3).thrust_index(i) for i in (1, 2, 3)]] += (0.5, 0.8, 0.3)
    f = model.dynamics

    trajectory = rk4(lambda z: np.asarray(f(z, u)).ravel(), x0, 1e-3, 2000)
    drift = max(np.abs(cable_lengths(params, x) - params.cable_lengths_m).max() for x in trajectory)
    assert drift < 1e-6
    assert np.linalg.norm(trajectory[-1][P_B] - x0[P_B]) > 0.1  # the check has teeth
    assert np.ptp([x[TH_B] for x in trajectory], axis=0).max() > 0.1  # the payload turned
    tensions = np.array([np.asarray(model.tensions(x, u)).ravel() for x in trajectory[::100]])
    assert tensions.min() > 0.0


def test_a_bar_keeps_its_cable_lengths_along_a_trajectory() -> None:
    """The same for the paper's bar with everything uneven (5)–(8): RK4 at 1 ms for 2 s."""
    params = uneven_params()
    model = FormationModel(params)
    x0 = perturbed_consistent_state(params, np.random.default_rng(7))
    u = formation_equilibrium(params, reference_for(params, 0.0, 0.0)).u + np.array(
        [1.5, 0.02, -0.01, 0.0, -1.0, 0.0, 0.03, 0.01]
    )
    f = model.dynamics

    trajectory = rk4(lambda z: np.asarray(f(z, u)).ravel(), x0, 1e-3, 2000)
    drift = max(np.abs(cable_lengths(params, x) - params.cable_lengths_m).max() for x in trajectory)
    assert drift < 1e-6
    assert np.linalg.norm(trajectory[-1][P_B] - x0[P_B]) > 0.1  # the check has teeth
    tensions = np.array([np.asarray(model.tensions(x, u)).ravel() for x in trajectory[::100]])
    assert tensions.min() > 0.0


def energy(params: FormationParams, x: Vector) -> float:
    """Kinetic plus potential energy [J]; the payload's rotation ½ ωᵀ R J Rᵀ ω (ω inertial)."""
    layout, g = FormationLayout(params.n_vehicles), params.gravity_mps2
    R = rotation_from_euler_zyx(*x[TH_B])
    J_w = R @ params.payload.inertia_matrix() @ R.T
    total = (
        params.payload.mass_kg * (x[V_B] @ x[V_B] / 2 + g * x[P_B][2]) + x[W_B] @ J_w @ x[W_B] / 2
    )
    for i, uav in zip(layout.vehicles, params.uavs, strict=True):
        p, v, _, w = layout.uav_slices(i)
        total += uav.mass_kg * (x[v] @ x[v] / 2 + g * x[p][2])
        total += x[w] @ np.diag(uav.inertia_kgm2) @ x[w] / 2
    return float(total)


def angular_momentum(params: FormationParams, x: Vector) -> Vector:
    """The payload's and the UAVs' (as point masses) angular momentum about the common
    CoM [kg m²/s]; each UAV's spin is left out (with τ = 0 it is its own constant)."""
    layout = FormationLayout(params.n_vehicles)
    masses = [params.payload.mass_kg, *(uav.mass_kg for uav in params.uavs)]
    bodies = [(P_B, V_B), *(layout.uav_slices(i)[:2] for i in layout.vehicles)]
    total_mass = sum(masses)
    centre = sum(m * x[p] for m, (p, _) in zip(masses, bodies, strict=True)) / total_mass
    drift = sum(m * x[v] for m, (_, v) in zip(masses, bodies, strict=True)) / total_mass
    R = rotation_from_euler_zyx(*x[TH_B])
    spin: Vector = R @ params.payload.inertia_matrix() @ R.T @ x[W_B]
    orbital = [
        m * np.cross(x[p] - centre, x[v] - drift) for m, (p, v) in zip(masses, bodies, strict=True)
    ]
    total: Vector = spin + np.sum(orbital, axis=0)
    return total


def test_energy_and_angular_momentum_are_conserved_without_inputs() -> None:
    """With no thrust and no torque the only forces are gravity and the cables: the cables
    do no work on rigid massless links, and uniform gravity exerts no torque about the CoM.
    So a tumbling three-cable formation keeps its energy (the tensions) and its angular
    momentum about the CoM (the payload's rotation, gyroscopic term included)."""
    params = irregular_params(3)
    f = FormationModel(params).dynamics
    x0 = perturbed_consistent_state(params, np.random.default_rng(9))
    u = np.zeros(FormationLayout(3).n_inputs)
    trajectory = rk4(lambda z: np.asarray(f(z, u)).ravel(), x0, 1e-3, 2000)[::50]
    energies = np.array([energy(params, x) for x in trajectory])
    assert np.abs(energies - energies[0]).max() < 1e-9 * np.abs(energies).max()
    momenta = np.array([angular_momentum(params, x) for x in trajectory])
    assert np.abs(momenta - momenta[0]).max() < 1e-9 * np.abs(momenta).max()
    spins = [rotation_from_euler_zyx(*x[TH_B]).T @ x[W_B] for x in trajectory]
    assert np.ptp(spins, axis=0).max() > 0.1  # the payload's body rates really changed


@pytest.mark.parametrize("perturbed", [False, True], ids=["equilibrium", "perturbed"])
def test_jacobians_match_finite_differences(perturbed: bool) -> None:
    params = irregular_params(3)
    model = FormationModel(params)
    eq = formation_equilibrium(params, reference_for(params, 0.9, math.radians(35)))
    x = perturbed_consistent_state(params, np.random.default_rng(3)) if perturbed else eq.x
    A_c, B_c = (np.asarray(m) for m in formation_jacobians(model)(x, eq.u))
    f = model.dynamics
    assert_matches(A_c, central_differences(lambda z: np.asarray(f(z, eq.u)).ravel(), x))
    assert_matches(B_c, central_differences(lambda z: np.asarray(f(x, z)).ravel(), eq.u))
    assert np.abs(A_c).max() > 1.0


def test_a_bar_is_recognized_and_its_inertia_is_its_perpendicular_moment() -> None:
    bar = uneven_params().payload
    assert bar.is_bar and bar.perpendicular_inertia_kgm2 == 0.0706
    assert three_cable_bar().payload.is_bar
    assert not plate_params(3).payload.is_bar
    with pytest.raises(ValueError, match="not a bar"):
        _ = plate_params(3).payload.perpendicular_inertia_kgm2


Point = tuple[float, float, float]


def payload(attachments: tuple[Point, ...], inertia: Point = (0.1, 0.1, 0.1)) -> PayloadParams:
    J = ((inertia[0], 0.0, 0.0), (0.0, inertia[1], 0.0), (0.0, 0.0, inertia[2]))
    return PayloadParams(0.4, J, attachments)


def uavs(n: int) -> tuple[UavParams, ...]:
    return (UavParams(1.0, LAB_INERTIA),) * n


TRIANGLE = ((1.0, 0.0, 0.0), (-0.5, 0.8, 0.0), (-0.5, -0.8, 0.0))


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (lambda: payload(((-0.5, 0.0, 0.0), (0.5, 0.0, 0.0)), (0.0, 0.07, 0.05)), "one positive"),
        (lambda: payload(((-0.5, 0.1, 0.0), (0.5, 0.1, 0.0)), (0.0, 0.07, 0.07)), "definite"),
        (lambda: payload(((0.0, 0.0, 0.0), (0.0, 0.0, 0.0))), "not all be at"),
        (
            lambda: PayloadParams(0.4, ((0.1, 0.02, 0), (0, 0.1, 0), (0, 0, 0.1)), TRIANGLE),
            "symmetric",
        ),
        (lambda: dataclasses.replace(payload(TRIANGLE), mass_kg=-0.4), "mass must be positive"),
        (lambda: FormationParams(uavs(4), payload(TRIANGLE), (1.0,) * 4), "4 UAVs need 4 cables"),
        (lambda: FormationParams(uavs(9), payload(TRIANGLE * 3), (1.0,) * 9), "2 to 8 UAVs, not 9"),
        (
            lambda: FormationParams(
                (UavParams(0.0, LAB_INERTIA),) * 3, payload(TRIANGLE), (1,) * 3
            ),
            "UAV 1's mass",
        ),
        (lambda: FormationParams(uavs(3), payload(TRIANGLE), (1.0, 0.0, 1.0)), "cable 2's length"),
    ],
    ids=[
        "bar inertia",
        "off-line CoM",
        "coincident",
        "asymmetric",
        "mass",
        "counts",
        "nine",
        "uav mass",
        "length",
    ],
)
def test_invalid_parameters_are_refused(make: Callable[[], object], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        make()
