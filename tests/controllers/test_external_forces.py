"""External loads in the formation's model and equilibria: the forced model keeps the
momentum balance, and the equilibria under loads are its fixed points with the payload
where the reference puts it."""

from __future__ import annotations

import dataclasses
import itertools
import math

import numpy as np
import pytest

from controllers.equilibria import EquilibriumError
from controllers.formation_equilibria import (
    ExternalForces,
    FormationReference,
    formation_equilibrium,
)
from controllers.formation_model import FormationModel
from controllers.formation_params import FormationParams
from controllers.model import E_Z, PayloadModel
from geometry.frames import rotation_from_euler_zyx
from geometry.state import AGENT_STATES, P_B, TH_B, V_B, W_B
from tests.conftest import symmetric_params, uneven_params
from tests.controllers.test_formation_equilibria import (
    irregular_params,
    level_attachments,
    plate_params,
)

LEVEL_GEOMETRIES = {
    "bar": symmetric_params(),
    "uneven bar": uneven_params(),
    "plate3": plate_params(3),
    "irregular4": level_attachments(irregular_params(4)),
}


def random_loads(params: FormationParams, seed: int) -> ExternalForces:
    rng = np.random.default_rng(seed)

    def triple(scale: float) -> tuple[float, float, float]:
        x, y, z = (float(v) for v in rng.uniform(-scale, scale, 3))
        return x, y, z

    return ExternalForces(
        payload_n=triple(1.0),
        payload_torque_nm=triple(0.05),
        uavs_n=tuple(triple(2.0) for _ in range(params.n_vehicles)),
    )


def reference(params: FormationParams, yaw: float, cone_deg: float) -> FormationReference:
    n = params.n_vehicles
    return FormationReference(
        (0.3, -0.4, 1.2), yaw, tuple(0.2 * k - 0.5 for k in range(n)), math.radians(cone_deg)
    )


def horizontal_torque(
    params: FormationParams, loads: ExternalForces, yaw: float, seed: int
) -> ExternalForces:
    """``loads`` with a payload torque that has a level equilibrium: horizontal (none
    balances one about the vertical), for a bar across it ((5g) has no spin about its
    axis), and moving the cables' balance point to a whole number of the equilibrium's
    0.1 mm steps (it rounds the point to them), within 1 cm."""
    rng = np.random.default_rng(seed)
    point = np.append(rng.integers(-100, 101, 2) * 1e-4, 0.0)  # in the payload's frame [m]
    if params.payload.is_bar:
        a = np.array(params.payload.attachments_m)
        axis = (a[-1] - a[0]) / np.linalg.norm(a[-1] - a[0])
        point = axis * round(float(axis @ point) / 1e-4) * 1e-4
    weight = params.payload.mass_kg * params.gravity_mps2 - loads.payload_n[2]
    shift = rotation_from_euler_zyx(0.0, 0.0, yaw) @ point
    torque = weight * np.cross((0.0, 0.0, 1.0), shift)  # the weight moved by the shift
    return dataclasses.replace(
        loads, payload_torque_nm=(float(torque[0]), float(torque[1]), float(torque[2]))
    )


@pytest.mark.parametrize("params", LEVEL_GEOMETRIES.values(), ids=LEVEL_GEOMETRIES.keys())
def test_equilibria_under_loads_are_fixed_points_of_the_forced_model(
    params: FormationParams,
) -> None:
    """ẋ(x_eq, u_eq, d) = 0 under forces on every body and a horizontal payload torque,
    at several yaws and cone angles, with the payload at the reference."""
    model = FormationModel(params)
    worst = 0.0
    for seed, yaw, cone_deg in itertools.product(range(3), (0.0, 0.8, -2.5), (0.0, 25.0, 50.0)):
        loads = horizontal_torque(params, random_loads(params, seed), yaw, seed)
        target = reference(params, yaw, cone_deg)
        eq = formation_equilibrium(params, target, forces=loads)
        d = loads.vector(params.n_vehicles)
        xdot = np.asarray(model.forced_dynamics(eq.x, eq.u, d)).ravel()
        worst = max(worst, float(np.abs(xdot).max()))
        np.testing.assert_allclose(eq.x[P_B], target.payload_position_m)
    assert worst < 1e-9


def test_without_loads_the_equilibrium_and_the_model_are_unchanged() -> None:
    """No loads gives the same numbers as before loads existed, and the forced model at
    d = 0 is the free one."""
    params = uneven_params()
    target = reference(params, 0.4, 30.0)
    free = formation_equilibrium(params, target)
    none = formation_equilibrium(params, target, forces=ExternalForces(), remember=False)
    np.testing.assert_array_equal(free.x, none.x)
    np.testing.assert_array_equal(free.u, none.u)
    model = FormationModel(params)
    rng = np.random.default_rng(3)
    x = free.x + rng.normal(0.0, 0.05, free.x.size)
    u = free.u + rng.normal(0.0, 0.5, free.u.size)
    np.testing.assert_allclose(
        np.asarray(model.forced_dynamics(x, u, np.zeros(model.n_forces))),
        np.asarray(model.dynamics(x, u)),
        rtol=0,
        atol=1e-12,
    )


@pytest.mark.parametrize("params", LEVEL_GEOMETRIES.values(), ids=LEVEL_GEOMETRIES.keys())
def test_the_forced_model_keeps_the_momentum_balance(params: FormationParams) -> None:
    """Away from any equilibrium, Σ m v̇ = Σ thrusts + Σ forces − M g: the cables' pulls
    are internal, and the payload torque moves no mass centre."""
    model = FormationModel(params)
    layout = params.layout
    eq = formation_equilibrium(params, reference(params, 0.3, 20.0))
    rng = np.random.default_rng(7)
    x = eq.x + rng.normal(0.0, 0.03, eq.x.size)
    u = eq.u + rng.normal(0.0, 0.4, eq.u.size)
    loads = random_loads(params, 11)
    xdot = np.asarray(model.forced_dynamics(x, u, loads.vector(params.n_vehicles))).ravel()
    g = params.gravity_mps2
    momentum_rate = params.payload.mass_kg * xdot[V_B]
    external = np.array(loads.payload_n) - params.payload.mass_kg * g * np.asarray(E_Z).ravel()
    for i in layout.vehicles:
        uav = params.uavs[i - 1]
        _, v_i, th_i, _ = layout.uav_slices(i)
        momentum_rate += uav.mass_kg * xdot[v_i]
        thrust = u[layout.thrust_index(i)] * rotation_from_euler_zyx(*x[th_i])[:, 2]
        external += thrust + np.array(loads.uavs_n[i - 1]) - uav.mass_kg * g * np.array(E_Z).ravel()
    np.testing.assert_allclose(momentum_rate, external, atol=1e-9)


def test_a_payload_torque_turns_the_payload_by_its_inertia() -> None:
    """At an equilibrium, a torque τ on a plate starts it turning at ω̇ = J⁻¹ τ less what
    the cables take back: with the cables rigid the response is smaller than free, and in
    the torque's direction."""
    params = plate_params(3)
    model = FormationModel(params)
    eq = formation_equilibrium(params, reference(params, 0.0, 0.0))
    torque = np.array((0.0, 0.0, 0.2))
    d = ExternalForces(payload_torque_nm=(0.0, 0.0, 0.2)).vector(3)
    spin = np.asarray(model.forced_dynamics(eq.x, eq.u, d)).ravel()[W_B]
    free = np.linalg.solve(np.array(params.payload.inertia_matrix()), torque)
    # About the vertical the cables give no moment at first: hanging straight, they pull
    # through the attachments along e_z.
    np.testing.assert_allclose(spin, free, atol=1e-9)


def test_a_bar_takes_no_torque_about_its_own_axis() -> None:
    params = symmetric_params()
    model = FormationModel(params)
    eq = formation_equilibrium(params, reference(params, 0.6, 0.0))
    axis = rotation_from_euler_zyx(*eq.x[TH_B]) @ np.array((1.0, 0.0, 0.0))
    d = np.zeros(model.n_forces)
    d[3:6] = 0.3 * axis
    xdot = np.asarray(model.forced_dynamics(eq.x, eq.u, d)).ravel()
    assert np.abs(xdot).max() < 1e-9


def test_each_cable_end_is_at_rest_under_its_share_of_the_payload_force() -> None:
    """The decentralized model: UAV i with its point mass V_i/g and f_ext the equilibrium's
    ``payload_force_n`` (the rest of the payload and its share of f_b) is at rest."""
    params = level_attachments(irregular_params(4))
    loads = ExternalForces(payload_n=(0.6, -0.4, 0.3))
    eq = formation_equilibrium(params, reference(params, 0.7, 35.0), forces=loads)
    for i in params.layout.vehicles:
        agent = eq.agent(i)
        model = PayloadModel(
            params.uavs[i - 1], agent.payload_mass_share_kg, params.cable_lengths_m[i - 1]
        )
        xdot = np.asarray(model.dynamics(agent.x, agent.u, agent.payload_force_n)).ravel()
        np.testing.assert_allclose(xdot, np.zeros(AGENT_STATES), atol=1e-9)
    shares = np.sum([f for f in eq.payload_force_n], axis=0)
    np.testing.assert_allclose(shares, loads.payload_n, atol=1e-9)


def test_loads_are_refused_when_not_finite_or_for_another_formation() -> None:
    params = symmetric_params()
    target = reference(params, 0.0, 0.0)
    with pytest.raises(EquilibriumError, match="finite"):
        formation_equilibrium(params, target, forces=ExternalForces(payload_n=(math.nan, 0, 0)))
    with pytest.raises(EquilibriumError, match="2 UAV forces"):
        formation_equilibrium(params, target, forces=ExternalForces(uavs_n=((0.0, 0.0, 1.0),)))
    assert ExternalForces.from_vector(np.zeros(12)).vector(2).tolist() == [0.0] * 12
