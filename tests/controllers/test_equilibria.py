"""Equilibria are fixed points of the nonlinear model; Proposition 1 and its closed form."""

from __future__ import annotations

import dataclasses
import itertools
import math

import numpy as np
import pytest

from controllers.equilibria import (
    EquilibriumError,
    Reference,
    bar_equilibrium,
    f_eq,
    theta_f_closed_form,
)
from controllers.model import BarSystemModel, payload_model_for
from controllers.params import BarSystemParams
from geometry.frames import rotation_from_euler_zyx
from geometry.state import uav_slices
from tests.conftest import symmetric_params, uneven_params

THETA_L_GRID_DEG = (0.0, 10.0, 25.0, 45.0, 60.0, 80.0)
YAWS = (0.0, 0.7, -2.4, math.pi)


def test_theta_f_of_section_vii() -> None:
    """θ_l = π/4, m_uav = 1.52 kg, m_b = 0.41 kg, g = 9.81 → θ_f = 0.1183 (Section VII)."""
    theta_f = theta_f_closed_form(math.pi / 4, 1.52, 0.41)
    assert theta_f == pytest.approx(0.1183, abs=1e-4)
    assert f_eq(theta_f, math.pi / 4, 1.52, 0.41, 9.81) == pytest.approx(0.0, abs=1e-12)


@pytest.mark.parametrize("theta_l_deg", THETA_L_GRID_DEG)
def test_closed_form_is_the_root_of_f_eq(theta_l_deg: float) -> None:
    theta_l = math.radians(theta_l_deg)
    theta_f = theta_f_closed_form(theta_l, 1.15, 0.39)
    assert f_eq(theta_f, theta_l, 1.15, 0.39, 9.81) < 1e-12
    # …and a root, not just a small value: f_eq grows away from it.
    assert f_eq(theta_f + 0.01, theta_l, 1.15, 0.39, 9.81) > 1e-6


@pytest.mark.parametrize(
    "params", [symmetric_params(), uneven_params()], ids=["symmetric", "uneven"]
)
def test_equilibria_are_fixed_points(params: BarSystemParams) -> None:
    """ẋ(x_eq, u_eq) = 0 in the full model (5)–(8) for every θ_l and yaw combination."""
    model = BarSystemModel(params)
    worst = 0.0
    for theta_l_deg, psi_b, psi_1, psi_2 in itertools.product(
        THETA_L_GRID_DEG, YAWS, YAWS, YAWS[:2]
    ):
        ref = Reference((0.4, -1.1, 1.3), psi_b, (psi_1, psi_2), math.radians(theta_l_deg))
        eq = bar_equilibrium(params, ref)
        xdot = np.asarray(model.dynamics(eq.x, eq.u)).ravel()
        worst = max(worst, float(np.abs(xdot).max()))
        tensions = np.asarray(model.tensions(eq.x, eq.u)).ravel()
        assert np.all(tensions > 0.0)
        np.testing.assert_allclose(tensions, eq.tensions_n, rtol=1e-10)
    assert worst < 1e-9


def test_thrust_tilts_along_the_cable_for_any_yaw(lab_params: BarSystemParams) -> None:
    """R(Θ_i) e_z lies in the bar's vertical plane, leaning outwards by θ_f,i."""
    for psi_b, psi_1 in itertools.product(YAWS, YAWS):
        eq = bar_equilibrium(
            lab_params, Reference((0, 0, 1), psi_b, (psi_1, -psi_1), math.radians(40))
        )
        n_b = np.array([math.cos(psi_b), math.sin(psi_b), 0.0])
        for i, sign in ((1, -1.0), (2, 1.0)):
            roll, pitch, yaw = eq.x[12 * i + 6 : 12 * i + 9]
            thrust_dir = rotation_from_euler_zyx(roll, pitch, yaw)[:, 2]
            assert yaw == pytest.approx([psi_1, -psi_1][i - 1])
            assert thrust_dir @ np.cross(n_b, [0, 0, 1]) == pytest.approx(0.0, abs=1e-12)
            tilt = math.atan2(sign * (thrust_dir @ n_b), thrust_dir[2])
            assert tilt == pytest.approx(eq.theta_f_rad[i - 1], abs=1e-12)


def test_symmetric_equilibrium_matches_proposition_1() -> None:
    params = symmetric_params()
    theta_l = math.radians(30)
    eq = bar_equilibrium(params, Reference((0, 0, 0), 0.0, (0.0, 0.0), theta_l))
    m, m_b, g, d, length = 1.52, 0.41, 9.81, 0.735, 1.0
    theta_f = theta_f_closed_form(theta_l, m, m_b)
    assert eq.theta_f_rad == pytest.approx((theta_f, theta_f), abs=1e-12)
    assert eq.theta_l_rad == pytest.approx((theta_l, theta_l), abs=1e-12)
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


def test_payload_mass_of_equation_13(lab_params: BarSystemParams) -> None:
    d1, d2, m_b = 0.705, 0.765, 0.39
    assert lab_params.payload_mass_kg(1) == pytest.approx(m_b * d2 / (d1 + d2), rel=1e-15)
    assert lab_params.payload_mass_kg(2) == pytest.approx(m_b * d1 / (d1 + d2), rel=1e-15)
    assert lab_params.payload_mass_kg(1) + lab_params.payload_mass_kg(2) == pytest.approx(m_b)


def test_decentralized_equilibria_are_fixed_points() -> None:
    params = uneven_params()
    for theta_l_deg, psi_b in itertools.product(THETA_L_GRID_DEG, YAWS):
        eq = bar_equilibrium(
            params, Reference((1, 2, 1.5), psi_b, (0.3, -1.0), math.radians(theta_l_deg))
        )
        for i in (1, 2):
            model = payload_model_for(params, i)
            xdot = model.dynamics(
                eq.payload_state(i), eq.payload_input(i), eq.payload_force_n[i - 1]
            )
            assert float(np.abs(np.asarray(xdot)).max()) < 1e-9


@pytest.mark.parametrize("theta_l", [-0.01, math.pi / 2, 2.0, math.nan])
def test_impossible_theta_l_is_refused(theta_l: float, lab_params: BarSystemParams) -> None:
    with pytest.raises(EquilibriumError, match=r"theta_l|finite"):
        bar_equilibrium(lab_params, Reference((0, 0, 1), 0.0, (0.0, 0.0), theta_l))


@pytest.mark.parametrize("theta_l_deg", [5.0, 30.0, 70.0])
def test_a_moving_theta_l_moves_the_uavs_along_the_equilibrium_family(
    theta_l_deg: float, lab_params: BarSystemParams
) -> None:
    """The θ_l-rate feed-forward is the derivative of the UAVs' positions along the family
    (central differences), and it leaves every other entry and the input alone."""
    theta, rate, delta = math.radians(theta_l_deg), 0.3, 1e-6
    reference = Reference((0.2, -0.1, 1.1), 0.7, (0.3, -0.4), theta)
    moving = bar_equilibrium(lab_params, dataclasses.replace(reference, theta_l_rate_radps=rate))
    still = bar_equilibrium(lab_params, reference)
    ahead = bar_equilibrium(lab_params, dataclasses.replace(reference, theta_l_rad=theta + delta))
    behind = bar_equilibrium(lab_params, dataclasses.replace(reference, theta_l_rad=theta - delta))
    for i in (1, 2):
        position, velocity, *_ = uav_slices(i)
        expected = (ahead.x[position] - behind.x[position]) / (2 * delta) * rate
        assert moving.x[velocity] == pytest.approx(expected, abs=1e-7)
        still.x[velocity] = moving.x[velocity]
    assert np.array_equal(moving.x, still.x) and np.array_equal(moving.u, still.u)
