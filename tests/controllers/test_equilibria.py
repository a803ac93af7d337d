"""The paper's bar as a formation of two: its equilibria are fixed points of (5)–(8),
Proposition 1 and its closed form, the payload masses (13)."""

from __future__ import annotations

import dataclasses
import itertools
import math

import numpy as np
import pytest

from controllers.equilibria import EquilibriumError, f_eq, theta_f_closed_form
from controllers.formation_equilibria import (
    FormationReference,
    formation_equilibrium,
    hanging_mass_shares_kg,
)
from controllers.formation_model import FormationModel
from controllers.formation_params import FormationParams
from controllers.model import PayloadModel
from geometry.frames import rotation_from_euler_zyx
from tests.conftest import symmetric_params, uneven_params

THETA_L_GRID_DEG = (0.0, 10.0, 25.0, 45.0, 60.0, 80.0)
YAWS = (0.0, 0.7, -2.4, math.pi)


def test_theta_f_of_section_vii() -> None:
    """θ_l = π/4, m_uav = 1.52 kg, m_b = 0.41 kg, g = 9.81 → θ_f = 0.1183 (Section VII)."""
    theta_f = theta_f_closed_form(math.pi / 4, 1.52, 0.41, 2)
    assert theta_f == pytest.approx(0.1183, abs=1e-4)
    assert f_eq(theta_f, math.pi / 4, 1.52, 0.41, 9.81) == pytest.approx(0.0, abs=1e-12)


@pytest.mark.parametrize("theta_l_deg", THETA_L_GRID_DEG)
def test_closed_form_is_the_root_of_f_eq(theta_l_deg: float) -> None:
    theta_l = math.radians(theta_l_deg)
    theta_f = theta_f_closed_form(theta_l, 1.15, 0.39, 2)
    assert f_eq(theta_f, theta_l, 1.15, 0.39, 9.81) < 1e-12
    # …and a root, not just a small value: f_eq grows away from it.
    assert f_eq(theta_f + 0.01, theta_l, 1.15, 0.39, 9.81) > 1e-6


@pytest.mark.parametrize(
    "params", [symmetric_params(), uneven_params()], ids=["symmetric", "uneven"]
)
def test_equilibria_are_fixed_points(params: FormationParams) -> None:
    """ẋ(x_eq, u_eq) = 0 in the full model (5)–(8) for every θ_l and yaw combination."""
    model = FormationModel(params)
    worst = 0.0
    for theta_l_deg, psi_b, psi_1, psi_2 in itertools.product(
        THETA_L_GRID_DEG, YAWS, YAWS, YAWS[:2]
    ):
        ref = FormationReference((0.4, -1.1, 1.3), psi_b, (psi_1, psi_2), math.radians(theta_l_deg))
        eq = formation_equilibrium(params, ref)
        xdot = np.asarray(model.dynamics(eq.x, eq.u)).ravel()
        worst = max(worst, float(np.abs(xdot).max()))
        tensions = np.asarray(model.tensions(eq.x, eq.u)).ravel()
        assert np.all(tensions > 0.0)
        np.testing.assert_allclose(tensions, eq.tensions_n, rtol=1e-10)
    assert worst < 1e-9


def test_thrust_tilts_along_the_cable_for_any_yaw(lab_params: FormationParams) -> None:
    """R(Θ_i) e_z lies in the bar's vertical plane, leaning outwards by θ_f,i."""
    layout = lab_params.layout
    for psi_b, psi_1 in itertools.product(YAWS, YAWS):
        eq = formation_equilibrium(
            lab_params, FormationReference((0, 0, 1), psi_b, (psi_1, -psi_1), math.radians(40))
        )
        n_b = np.array([math.cos(psi_b), math.sin(psi_b), 0.0])
        for i, sign in ((1, -1.0), (2, 1.0)):
            roll, pitch, yaw = layout.uav_euler(eq.x, i)
            thrust_dir = rotation_from_euler_zyx(roll, pitch, yaw)[:, 2]
            assert yaw == pytest.approx([psi_1, -psi_1][i - 1])
            assert thrust_dir @ np.cross(n_b, [0, 0, 1]) == pytest.approx(0.0, abs=1e-12)
            tilt = math.atan2(sign * (thrust_dir @ n_b), thrust_dir[2])
            assert tilt == pytest.approx(eq.tilts_rad[i - 1], abs=1e-12)


def test_symmetric_equilibrium_matches_proposition_1() -> None:
    params = symmetric_params()
    theta_l = math.radians(30)
    eq = formation_equilibrium(params, FormationReference((0, 0, 0), 0.0, (0.0, 0.0), theta_l))
    m, m_b, g, d, length = 1.52, 0.41, 9.81, 0.735, 1.0
    theta_f = theta_f_closed_form(theta_l, m, m_b, 2)
    assert params.is_symmetric
    assert eq.tilts_rad == pytest.approx((theta_f, theta_f), abs=1e-12)
    assert eq.cable_angles_rad == pytest.approx((theta_l, theta_l), abs=1e-12)
    F = g * (m_b + 2 * m) / (2 * math.cos(theta_f))  # (10)
    assert eq.thrusts_n == pytest.approx((F, F), rel=1e-12)
    assert eq.tensions_n[0] * math.cos(theta_l) == pytest.approx(m_b * g / 2, rel=1e-12)  # (12)
    reach = d + length * math.sin(theta_l)
    np.testing.assert_allclose(
        eq.uav_position(1), [-reach, 0.0, length * math.cos(theta_l)], atol=1e-12
    )
    np.testing.assert_allclose(
        eq.uav_position(2), [reach, 0.0, length * math.cos(theta_l)], atol=1e-12
    )


@pytest.mark.parametrize("theta_l_deg", THETA_L_GRID_DEG)
def test_payload_mass_of_equation_13(theta_l_deg: float, lab_params: FormationParams) -> None:
    """Each cable carries m_b d_j / (d1 + d2) of the bar, hanging still or at any θ_l."""
    d1, d2, m_b = 0.705, 0.765, 0.39
    expected = (m_b * d2 / (d1 + d2), m_b * d1 / (d1 + d2))
    assert hanging_mass_shares_kg(lab_params) == pytest.approx(expected, rel=1e-14)
    eq = formation_equilibrium(
        lab_params, FormationReference((0, 0, 1), 0.3, (0.0, 0.0), math.radians(theta_l_deg))
    )
    assert eq.payload_mass_share_kg == pytest.approx(expected, rel=1e-14)


def test_decentralized_equilibria_are_fixed_points() -> None:
    """Each UAV with its bar end as a point mass (13) and the pull of the other end is a
    fixed point of the UAV–payload model (1)–(4)."""
    params = uneven_params()
    shares = hanging_mass_shares_kg(params)
    for theta_l_deg, psi_b in itertools.product(THETA_L_GRID_DEG, YAWS):
        eq = formation_equilibrium(
            params,
            FormationReference((1, 2, 1.5), psi_b, (0.3, -1.0), math.radians(theta_l_deg)),
        )
        for i in (1, 2):
            model = PayloadModel(params.uavs[i - 1], shares[i - 1], params.cable_lengths_m[i - 1])
            xdot = model.dynamics(eq.agent_state(i), eq.agent_input(i), eq.payload_force_n[i - 1])
            assert float(np.abs(np.asarray(xdot)).max()) < 1e-9


@pytest.mark.parametrize("theta_l", [-0.01, math.pi / 2, 2.0, math.nan])
def test_impossible_theta_l_is_refused(theta_l: float, lab_params: FormationParams) -> None:
    with pytest.raises(EquilibriumError, match=r"cone angle|finite"):
        formation_equilibrium(lab_params, FormationReference((0, 0, 1), 0.0, (0.0, 0.0), theta_l))


@pytest.mark.parametrize("theta_l_deg", [5.0, 30.0, 70.0])
def test_a_moving_theta_l_moves_the_uavs_along_the_equilibrium_family(
    theta_l_deg: float, lab_params: FormationParams
) -> None:
    """The θ_l-rate feed-forward is the derivative of the UAVs' positions along the family
    (central differences), and it leaves every other entry and the input alone."""
    theta, rate, delta = math.radians(theta_l_deg), 0.3, 1e-6
    reference = FormationReference((0.2, -0.1, 1.1), 0.7, (0.3, -0.4), theta)

    moving = formation_equilibrium(
        lab_params, dataclasses.replace(reference, cone_angle_rate_radps=rate)
    )
    still = formation_equilibrium(lab_params, reference)
    ahead = formation_equilibrium(
        lab_params, dataclasses.replace(reference, cone_angle_rad=theta + delta)
    )
    behind = formation_equilibrium(
        lab_params, dataclasses.replace(reference, cone_angle_rad=theta - delta)
    )
    for i in (1, 2):
        position, velocity, *_ = lab_params.layout.uav_slices(i)
        expected = (ahead.x[position] - behind.x[position]) / (2 * delta) * rate
        assert moving.x[velocity] == pytest.approx(expected, abs=1e-7)
        still.x[velocity] = moving.x[velocity]
    assert np.array_equal(moving.x, still.x) and np.array_equal(moving.u, still.u)
