"""Equilibria of N UAVs carrying one payload: fixed points of the N-cable model, the cone
angle of a symmetric geometry, Section IV's equilibria for the bar (N = 2), refusals, and
the moving reference's feed-forward."""

from __future__ import annotations

import dataclasses
import itertools
import math

import numpy as np
import pytest

from controllers.equilibria import EquilibriumError
from controllers.formation_equilibria import (
    FormationLimits,
    FormationReference,
    agent_equilibrium,
    formation_equilibrium,
    hanging_mass_shares_kg,
)
from controllers.formation_model import FormationModel
from controllers.formation_params import FormationParams, PayloadParams
from controllers.model import PayloadModel
from controllers.params import UavParams
from geometry.formation import FormationLayout
from geometry.frames import rotation_from_euler_zyx
from geometry.state import AGENT_STATES, P_B, P_P, TH_B, UAV_BLOCK, V_B, W_B
from tests.conftest import LAB_INERTIA, symmetric_params, uneven_params

CONE_GRID_DEG = (0.0, 10.0, 30.0, 55.0, 75.0)
YAWS = (0.0, 0.7, -2.4, math.pi)


def plate_params(n: int, radius_m: float = 0.5) -> FormationParams:
    """A regular n-gon plate hung by equal UAVs on equal cables (a symmetric geometry)."""
    uav = UavParams(1.52, LAB_INERTIA)
    corners = tuple(
        (radius_m * math.cos(2 * math.pi * k / n), radius_m * math.sin(2 * math.pi * k / n), 0.0)
        for k in range(n)
    )
    m = 0.8
    plate = PayloadParams(
        m,
        (
            (m * radius_m**2 / 4, 0.0, 0.0),
            (0.0, m * radius_m**2 / 4, 0.0),
            (0.0, 0.0, m * radius_m**2 / 2),
        ),
        corners,
    )
    return FormationParams((uav,) * n, plate, (1.0,) * n)


def vector3(v: np.ndarray) -> tuple[float, float, float]:
    return float(v[0]), float(v[1]), float(v[2])


def irregular_params(n: int) -> FormationParams:
    """Nothing equal: attachments at jittered angles, radii and heights, a full inertia
    tensor, and different UAV masses and cable lengths."""
    rng = np.random.default_rng(n)
    angles = 2 * math.pi * (np.arange(n) + rng.uniform(-0.2, 0.2, n)) / n
    radii = rng.uniform(0.4, 0.8, n)
    heights = rng.uniform(-0.12, 0.12, n)
    attachments = tuple(
        (float(r * math.cos(a)), float(r * math.sin(a)), float(h))
        for a, r, h in zip(angles, radii, heights, strict=True)
    )
    turn = rotation_from_euler_zyx(0.3, -0.2, 0.9)
    inertia = turn @ np.diag([0.04, 0.07, 0.1]) @ turn.T
    payload = PayloadParams(
        0.9, (vector3(inertia[0]), vector3(inertia[1]), vector3(inertia[2])), attachments
    )
    uavs = tuple(UavParams(float(m), LAB_INERTIA) for m in rng.uniform(1.0, 1.6, n))
    lengths = tuple(float(length) for length in rng.uniform(0.7, 1.3, n))
    return FormationParams(uavs, payload, lengths)


def three_cable_bar() -> FormationParams:
    """Three UAVs on one bar (collinear attachments: the bar model (5g))."""
    J_b = 0.39 * 1.5**2 / 12
    bar = PayloadParams(
        0.39,
        ((0.0, 0.0, 0.0), (0.0, J_b, 0.0), (0.0, 0.0, J_b)),
        ((-0.7, 0.0, 0.0), (0.15, 0.0, 0.0), (0.75, 0.0, 0.0)),
    )
    return FormationParams(
        tuple(UavParams(m, LAB_INERTIA) for m in (1.1, 1.3, 1.2)), bar, (0.9, 1.0, 1.1)
    )


def reference_for(params: FormationParams, psi_b: float, cone_rad: float) -> FormationReference:
    n = params.n_vehicles
    uav_yaws = tuple(YAWS[k % len(YAWS)] - 0.3 * k for k in range(n))
    return FormationReference((0.4, -1.1, 1.3), psi_b, uav_yaws, cone_rad)


GEOMETRIES = {
    "plate3": plate_params(3),
    "plate4": plate_params(4),
    "plate6": plate_params(6),
    "irregular3": irregular_params(3),
    "irregular4": irregular_params(4),
    "irregular6": irregular_params(6),
    "bar3": three_cable_bar(),
}


@pytest.mark.parametrize("params", GEOMETRIES.values(), ids=GEOMETRIES.keys())
def test_equilibria_are_fixed_points(params: FormationParams) -> None:
    """ẋ(x_eq, u_eq) = 0 in the N-cable model, and its tensions are the equilibrium's."""
    model = FormationModel(params)
    worst = 0.0
    for cone_deg, psi_b in itertools.product(CONE_GRID_DEG, YAWS):
        eq = formation_equilibrium(params, reference_for(params, psi_b, math.radians(cone_deg)))
        worst = max(worst, float(np.abs(np.asarray(model.dynamics(eq.x, eq.u))).max()))
        tensions = np.asarray(model.tensions(eq.x, eq.u)).ravel()
        assert np.all(tensions > 0.0)
        np.testing.assert_allclose(tensions, eq.tensions_n, rtol=1e-10)
        assert math.fsum(eq.payload_mass_share_kg) == pytest.approx(params.payload.mass_kg)
    assert worst < 1e-9


@pytest.mark.parametrize("n", [3, 4, 6])
def test_a_symmetric_geometry_has_every_cable_at_the_cone_angle(n: int) -> None:
    params = plate_params(n)
    m_b, g = params.payload.mass_kg, params.gravity_mps2
    for cone_deg, psi_b in itertools.product(CONE_GRID_DEG, YAWS):
        cone = math.radians(cone_deg)
        eq = formation_equilibrium(params, reference_for(params, psi_b, cone))
        assert eq.cable_angles_rad == pytest.approx((cone,) * n, abs=1e-12)
        assert eq.tensions_n == pytest.approx((m_b * g / n / math.cos(cone),) * n, rel=1e-12)
        assert eq.thrusts_n == pytest.approx((eq.thrusts_n[0],) * n, rel=1e-12)
        # Proposition 1's tilt with the payload shared by n: tan θ_f = m_s tan θ_l / (m_s + m).
        share = m_b / n
        expected_tilt = math.atan(share * math.tan(cone) / (share + params.uavs[0].mass_kg))
        assert eq.tilts_rad == pytest.approx((expected_tilt,) * n, abs=1e-12)


BAR_SETUPS = {"symmetric": symmetric_params(), "uneven": uneven_params()}


@pytest.mark.parametrize("bar", BAR_SETUPS.values(), ids=BAR_SETUPS.keys())
def test_two_cables_on_a_bar_are_section_iv_equilibria(
    bar: FormationParams, lab_params: FormationParams
) -> None:
    """The bar level along ψ_b with its ends at p_b − d1 n_b and p_b + d2 n_b; each cable
    carries the vertical load (13) and the same horizontal pull (m_b g / 2) tan θ_l, in
    the bar's vertical plane, outwards; the cable angles follow (any d1, d2, masses,
    cable lengths)."""
    for params in (bar, lab_params):
        d1, d2 = params.bar_arms_m
        m_b, g = params.payload.mass_kg, params.gravity_mps2
        for theta_deg, psi_b in itertools.product((0.0, 10.0, 45.0, 80.0), YAWS):
            theta = math.radians(theta_deg)
            eq = formation_equilibrium(
                params, FormationReference((0.4, -1.1, 1.3), psi_b, (0.3, -1.0), theta)
            )
            n_b = np.array([math.cos(psi_b), math.sin(psi_b), 0.0])
            p_b = np.array([0.4, -1.1, 1.3])
            pull = m_b * g / 2.0 * math.tan(theta)
            for i, sign, arm, other in ((1, -1.0, d1, d2), (2, 1.0, d2, d1)):
                np.testing.assert_allclose(eq.attachments_m[i - 1], p_b + sign * arm * n_b)
                vertical = m_b * g * other / (d1 + d2)
                np.testing.assert_allclose(
                    eq.payload_force_n[i - 1], -sign * pull * n_b, atol=1e-12
                )
                assert eq.tensions_n[i - 1] == pytest.approx(math.hypot(pull, vertical))
                assert eq.cable_angles_rad[i - 1] == pytest.approx(math.atan2(pull, vertical))


def test_each_cable_end_is_an_equilibrium_of_the_decentralized_model() -> None:
    """UAV i with a point mass V_i/g at its attachment and the pull −H_i of the rest of the
    payload is a fixed point of the single UAV–payload model (1)–(4)."""
    params = irregular_params(4)
    layout = FormationLayout(4)
    eq = formation_equilibrium(params, reference_for(params, 0.7, math.radians(35)))
    for i in layout.vehicles:
        model = PayloadModel(
            params.uavs[i - 1], eq.payload_mass_share_kg[i - 1], params.cable_lengths_m[i - 1]
        )
        x_i = np.zeros(AGENT_STATES)
        x_i[UAV_BLOCK] = eq.x[layout.uav_block(i)]
        x_i[P_P] = eq.attachments_m[i - 1]
        xdot = model.dynamics(x_i, eq.u[layout.uav_input_slice(i)], eq.payload_force_n[i - 1])
        assert float(np.abs(np.asarray(xdot)).max()) < 1e-9


def outside_support() -> FormationParams:
    """Three attachments all on one side of the CoM: no cable can hold the far side."""
    params = plate_params(3)
    shifted = tuple((x + 0.6, y, z) for x, y, z in params.payload.attachments_m)
    return dataclasses.replace(
        params, payload=dataclasses.replace(params.payload, attachments_m=shifted)
    )


def test_a_com_outside_the_support_is_refused_naming_the_cable() -> None:
    params = outside_support()
    with pytest.raises(EquilibriumError, match=r"cable 1 would carry -\d.* outside the support"):
        formation_equilibrium(params, reference_for(params, 0.0, math.radians(20)))


def test_a_payload_that_cannot_hang_level_is_refused() -> None:
    """Two cables whose attachments' line passes beside the CoM: it would tilt."""
    params = plate_params(3)
    payload = dataclasses.replace(params.payload, attachments_m=((-0.5, 0.2, 0.0), (0.5, 0.2, 0.0)))
    two = FormationParams(params.uavs[:2], payload, (1.0, 1.0))
    with pytest.raises(EquilibriumError, match="cannot hang level"):
        formation_equilibrium(two, reference_for(two, 0.0, 0.2))


def test_a_cone_that_puts_the_cables_meeting_point_above_an_attachment_is_refused() -> None:
    """Cable 3's attachment 0.6 m below the others: from tan(cone) = 1.25 on (51.3°), the
    point where the cables' lines meet is at or above it."""
    params = plate_params(3)
    lowered = tuple(
        (x, y, 0.3 if k < 2 else -0.3) for k, (x, y, _) in enumerate(params.payload.attachments_m)
    )
    params = dataclasses.replace(
        params, payload=dataclasses.replace(params.payload, attachments_m=lowered)
    )
    eq = formation_equilibrium(params, reference_for(params, 0.4, math.radians(50)))
    xdot = FormationModel(params).dynamics(eq.x, eq.u)
    assert float(np.abs(np.asarray(xdot)).max()) < 1e-9
    with pytest.raises(EquilibriumError, match="at or above cable 3's attachment"):
        formation_equilibrium(params, reference_for(params, 0.4, math.radians(52)))


@pytest.mark.parametrize(
    ("limits", "message"),
    [
        (
            FormationLimits(0.0, 17.5, math.radians(30)),
            r"UAV 1 would need 17\.80 N .*above the maximum thrust 17\.50 N",
        ),
        (
            FormationLimits(18.0, 40.0, math.radians(30)),
            r"UAV 1 would need 17\.80 N .*below the minimum thrust 18\.00 N",
        ),
        (
            FormationLimits(0.0, 40.0, math.radians(5)),
            r"UAV 1 would tilt 10\.1°, beyond the maximum tilt 5\.0°",
        ),
    ],
    ids=["thrust max", "thrust min", "tilt"],
)
def test_an_equilibrium_beyond_the_limits_is_refused_naming_vehicle_and_bound(
    limits: FormationLimits, message: str
) -> None:
    params = plate_params(3)
    reference = reference_for(params, 0.3, math.radians(50))
    eq = formation_equilibrium(params, reference)  # 17.80 N of thrust, tilted 10.1°, each
    assert eq.thrusts_n[0] == pytest.approx(17.80, abs=0.005)
    with pytest.raises(EquilibriumError, match=message):
        formation_equilibrium(params, reference, limits)
    assert (
        formation_equilibrium(
            params, reference, FormationLimits(0.0, 40.0, math.radians(30))
        ).thrusts_n
        == eq.thrusts_n
    )


def test_the_vehicle_named_is_the_one_beyond_the_limit() -> None:
    """The formation's equilibrium names it; that agent's own is refused alike, the others'
    are given."""
    params = irregular_params(4)
    reference = reference_for(params, 0.3, math.radians(40))
    eq = formation_equilibrium(params, reference)
    heaviest = int(np.argmax(eq.thrusts_n)) + 1
    ceiling = (sorted(eq.thrusts_n)[-2] + max(eq.thrusts_n)) / 2
    limits = FormationLimits(0.0, ceiling, math.radians(80))
    with pytest.raises(EquilibriumError, match=f"UAV {heaviest} would need"):
        formation_equilibrium(params, reference, limits)
    with pytest.raises(EquilibriumError, match=f"UAV {heaviest} would need"):
        agent_equilibrium(params, reference, heaviest, limits)
    others = [i for i in range(1, 5) if i != heaviest]
    assert all(agent_equilibrium(params, reference, i, limits).i == i for i in others)


@pytest.mark.parametrize("cone", [-0.01, math.pi / 2, 2.0, math.nan])
def test_impossible_cone_angles_are_refused(cone: float) -> None:
    params = plate_params(4)
    with pytest.raises(EquilibriumError, match=r"cone angle|finite"):
        formation_equilibrium(params, reference_for(params, 0.0, cone))


def test_a_reference_for_another_formation_size_is_refused() -> None:
    with pytest.raises(EquilibriumError, match="4 UAVs needs 4 UAV yaws"):
        formation_equilibrium(plate_params(4), FormationReference((0, 0, 1), 0.0, (0.0,) * 3))


@pytest.mark.parametrize(
    "params",
    [plate_params(3), irregular_params(4), three_cable_bar()],
    ids=["plate3", "irregular4", "bar3"],
)
def test_the_feed_forward_is_the_derivative_along_the_moving_reference(
    params: FormationParams,
) -> None:
    """For a reference moving in time (position, yaws, cone angle), the central difference
    of x_eq(t) matches the velocities, the payload's Euler rates H^E ω_b and the UAVs' yaw
    rates in x_eq(t)."""
    layout = FormationLayout(params.n_vehicles)
    velocity, psi_rate, cone_rate = np.array((0.3, -0.2, 0.1)), 0.4, 0.25
    uav_rates = tuple(0.2 - 0.15 * k for k in range(params.n_vehicles))
    start = reference_for(params, 0.7, math.radians(30))

    def at(t: float) -> np.ndarray:
        reference = FormationReference(
            vector3(np.asarray(start.payload_position_m) + velocity * t),
            start.payload_yaw_rad + psi_rate * t,
            tuple(y + r * t for y, r in zip(start.uav_yaw_rad, uav_rates, strict=True)),
            start.cone_angle_rad + cone_rate * t,
            vector3(velocity),
            psi_rate,
            uav_rates,
            cone_rate,
        )
        return formation_equilibrium(params, reference).x

    delta = 1e-6
    x, rate = at(0.0), (at(delta) - at(-delta)) / (2 * delta)
    positions = [(P_B, V_B)] + [layout.uav_slices(i)[:2] for i in layout.vehicles]
    for position, velocity_slice in positions:
        np.testing.assert_allclose(rate[position], x[velocity_slice], atol=1e-7)
    np.testing.assert_allclose(rate[TH_B], (0.0, 0.0, x[W_B][2]), atol=1e-7)
    for i, uav_rate in zip(layout.vehicles, uav_rates, strict=True):
        assert rate[layout.uav_yaw_index(i)] == pytest.approx(uav_rate, abs=1e-7)
        roll, pitch, _ = x[layout.uav_slices(i)[2]]
        body_rates = x[layout.uav_slices(i)[3]]
        yaw_rate = (math.sin(roll) * body_rates[1] + math.cos(roll) * body_rates[2]) / math.cos(
            pitch
        )  # (4)
        assert yaw_rate == pytest.approx(uav_rate, abs=1e-12)


def test_a_translating_reference_is_a_relative_equilibrium() -> None:
    """With velocity alone, everything moves at v and nothing accelerates."""
    params = irregular_params(4)
    velocity = (0.3, -0.2, 0.1)
    reference = dataclasses.replace(
        reference_for(params, 0.7, math.radians(30)), velocity_mps=velocity
    )
    eq = formation_equilibrium(params, reference)
    layout = FormationLayout(4)
    xdot = np.asarray(FormationModel(params).dynamics(eq.x, eq.u)).ravel()
    expected = np.zeros(layout.n_states)
    for position in (P_B, *(layout.uav_slices(i)[0] for i in layout.vehicles)):
        expected[position] = velocity
    np.testing.assert_allclose(xdot, expected, atol=1e-9)


ACCELERATIONS = ((1.0, 0.0, 0.0), (-0.7, 1.8, 0.0), (0.5, -0.4, 1.2), (0.0, 0.0, -2.0))


def level_attachments(params: FormationParams) -> FormationParams:
    """``params`` with every attachment moved to the height of the payload's CoM."""
    level = tuple((x, y, 0.0) for x, y, _ in params.payload.attachments_m)
    return dataclasses.replace(
        params, payload=dataclasses.replace(params.payload, attachments_m=level)
    )


def uniform_motion(
    layout: FormationLayout, velocity: tuple[float, ...], acceleration: tuple[float, ...]
) -> np.ndarray:
    """ẋ of a formation that translates rigidly at ``velocity`` and ``acceleration``."""
    expected = np.zeros(layout.n_states)
    for i in (0, *layout.vehicles):
        position, speed = (P_B, V_B) if i == 0 else layout.uav_slices(i)[:2]
        expected[position], expected[speed] = velocity, acceleration
    return expected


@pytest.mark.parametrize(
    "params",
    [level_attachments(p) for p in GEOMETRIES.values()],
    ids=[f"{name}-level" for name in GEOMETRIES],
)
def test_an_accelerating_reference_accelerates_everything_alike(params: FormationParams) -> None:
    """With the attachments level with the CoM, the equilibrium for an acceleration a is
    a uniform acceleration of the whole formation: every body's ẍ = a, nothing turns
    (x_eq + v t + a t²/2 solves the model with u_eq), and the tensions are the model's."""
    model = FormationModel(params)
    layout = params.layout
    velocity = (0.4, -0.3, 0.1)
    worst = 0.0
    for acceleration, cone_deg in itertools.product(ACCELERATIONS, (0.0, 30.0, 55.0)):
        reference = dataclasses.replace(
            reference_for(params, 0.7, math.radians(cone_deg)),
            velocity_mps=velocity,
            acceleration_mps2=acceleration,
        )
        eq = formation_equilibrium(params, reference)
        xdot = np.asarray(model.dynamics(eq.x, eq.u)).ravel()
        worst = max(
            worst, float(np.abs(xdot - uniform_motion(layout, velocity, acceleration)).max())
        )
        tensions = np.asarray(model.tensions(eq.x, eq.u)).ravel()
        np.testing.assert_allclose(tensions, eq.tensions_n, rtol=1e-9)
    assert worst < 1e-9


def test_with_attachments_off_the_com_level_the_acceleration_is_a_feed_forward() -> None:
    """Attachments above or below the CoM: a level payload under acceleration would need a
    moment no cable gives, so the equilibrium is no longer exact; what it leaves over
    (through the payload's turn and the rigid cables, every body's ẍ) stays a small part
    of a (12 % with these attachments, up to 12 cm off the CoM's level)."""
    params = irregular_params(4)
    layout = params.layout
    acceleration = (1.0, 0.5, 0.0)
    reference = dataclasses.replace(
        reference_for(params, 0.7, math.radians(30)), acceleration_mps2=acceleration
    )
    eq = formation_equilibrium(params, reference)
    xdot = np.asarray(FormationModel(params).dynamics(eq.x, eq.u)).ravel()
    left_over = np.abs(xdot - uniform_motion(layout, (0.0, 0.0, 0.0), acceleration)).max()
    assert 1e-3 < left_over < 0.2 * math.hypot(*acceleration)


def test_each_cable_end_accelerates_with_the_formation_in_the_decentralized_model() -> None:
    """Under acceleration, UAV i with its point mass V_i/g and the rest of the payload's
    pull moves as the formation does in the single UAV–payload model: ẍ = a."""
    params = level_attachments(irregular_params(4))
    layout = FormationLayout(4)
    acceleration = (0.8, -0.6, 0.5)
    reference = dataclasses.replace(
        reference_for(params, 0.7, math.radians(35)), acceleration_mps2=acceleration
    )
    eq = formation_equilibrium(params, reference)
    for i in layout.vehicles:
        agent = eq.agent(i)
        model = PayloadModel(
            params.uavs[i - 1], agent.payload_mass_share_kg, params.cable_lengths_m[i - 1]
        )
        xdot = np.asarray(model.dynamics(agent.x, agent.u, agent.payload_force_n)).ravel()
        expected = np.zeros(AGENT_STATES)
        expected[3:6] = expected[15:18] = acceleration
        np.testing.assert_allclose(xdot, expected, atol=1e-9)


def test_a_reference_spells_none_turns_one_way_and_turns_to_other_yaws() -> None:
    """No UAV yaw rates given is zeros (so a shaped reference at rest equals its target);
    ``with_yaws`` turns it, ``at_rest`` stops it."""
    still = FormationReference((0.0, 0.0, 1.0), 0.2, (0.1, 0.3, -0.4), 0.3)
    assert still.uav_yaw_rates_radps == (0.0, 0.0, 0.0)
    assert still == FormationReference((0.0, 0.0, 1.0), 0.2, (0.1, 0.3, -0.4), 0.3, (0, 0, 0), 0.0)
    moving = dataclasses.replace(
        still, velocity_mps=(0.1, 0.0, 0.0), uav_yaw_rates_radps=(0.2, 0.0, 0.1)
    )
    turned = moving.with_yaws(1.0, (0.5, 0.6, 0.7))
    assert (turned.payload_yaw_rad, turned.uav_yaw_rad) == (1.0, (0.5, 0.6, 0.7))
    assert turned.uav_yaw_rates_radps == (0.2, 0.0, 0.1) and turned.velocity_mps[0] == 0.1
    assert moving.at_rest() == still


def test_each_call_gets_its_own_state_and_input() -> None:
    params = plate_params(4)
    reference = reference_for(params, 0.3, 0.2)
    first = formation_equilibrium(params, reference)
    first.x[:] = 0.0
    first.u[:] = 0.0
    second = formation_equilibrium(params, reference)
    assert second.x.any() and second.u.any()
    with pytest.raises(ValueError, match="read-only"):
        second.attachments_m[0][0] = 1.0


def test_the_hanging_shares_are_the_vertical_loads_at_no_cone_angle() -> None:
    """For attachments at different heights the vertical loads change with the cone angle;
    the decentralized agents' masses are the still, vertical-cable ones."""
    params = irregular_params(4)
    shares = hanging_mass_shares_kg(params)
    assert math.fsum(shares) == pytest.approx(params.payload.mass_kg)
    assert (
        shares
        == formation_equilibrium(params, reference_for(params, 1.0, 0.0)).payload_mass_share_kg
    )
    tilted = formation_equilibrium(params, reference_for(params, 1.0, math.radians(40)))
    assert max(abs(a - b) for a, b in zip(shares, tilted.payload_mass_share_kg, strict=True)) > 1e-3


def test_symmetry_and_the_bar_s_arms() -> None:
    """Assumption 1 for N: equal UAVs and cables, attachments equally far from the CoM, at
    their centroid; only the paper's bar of two has the arms d1, d2."""
    assert plate_params(5).is_symmetric and symmetric_params().is_symmetric
    assert not uneven_params().is_symmetric and not irregular_params(3).is_symmetric
    assert uneven_params().bar_arms_m == (0.6, 0.87)
    for other in (plate_params(3), three_cable_bar()):
        with pytest.raises(ValueError, match="arms d1 and d2"):
            _ = other.bar_arms_m


@pytest.mark.parametrize("params", GEOMETRIES.values(), ids=GEOMETRIES.keys())
def test_an_agents_own_equilibrium_is_its_part_of_the_formations(params: FormationParams) -> None:
    """Bit for bit, moving and turning: an agent on a computer of its own flies what the
    formation's controller would give it."""
    n = params.n_vehicles
    moving = dataclasses.replace(
        reference_for(params, 0.8, math.radians(30)),
        velocity_mps=(0.4, -0.2, 0.1),
        payload_yaw_rate_radps=0.3,
        uav_yaw_rates_radps=tuple(0.1 * k for k in range(n)),
        cone_angle_rate_radps=0.05,
    )
    formation = formation_equilibrium(params, moving)
    for i in range(1, n + 1):
        mine, theirs = agent_equilibrium(params, moving, i), formation.agent(i)
        assert mine.i == theirs.i == i
        for a, b in ((mine.x, theirs.x), (mine.u, theirs.u)):
            np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(mine.payload_force_n, theirs.payload_force_n)
        assert mine.payload_mass_share_kg == theirs.payload_mass_share_kg


def test_an_agents_equilibrium_is_refused_for_a_bad_number_or_reference() -> None:
    params = irregular_params(4)
    reference = reference_for(params, 0.3, math.radians(40))
    with pytest.raises(EquilibriumError, match="numbered 1 to 4, got 5"):
        agent_equilibrium(params, reference, 5)
    with pytest.raises(EquilibriumError, match="cone angle"):
        agent_equilibrium(params, reference_for(params, 0.0, math.pi / 2), 1)
