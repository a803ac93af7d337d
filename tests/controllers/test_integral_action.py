"""The integral action: what it integrates, its bounds, and a mismatched closed loop that
it makes offset-free."""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np
import pytest

from controllers.formation_equilibria import FormationReference, formation_equilibrium
from controllers.formation_model import FormationModel
from controllers.formation_params import FormationParams
from controllers.integral_action import IntegralLimits, ReferenceIntegrator
from controllers.mpc import CentralizedMpc, DecentralizedMpc
from controllers.params import RECOMMENDED_LEAD, ReferenceLead
from geometry.state import P_B, PAYLOAD_YAW
from supervisor.app.config import load_config
from tests.conftest import CONFIGS
from tests.controllers.closed_loop import hold

CONFIG = load_config(CONFIGS / "kth_sml.toml")
TICK_S = 0.02
HELD = FormationReference((0.0, 0.0, 1.0), 0.3, (0.1, -0.2), 0.0)


def _state_off_by(params: FormationParams, dz: float, dyaw: float) -> np.ndarray:
    x = formation_equilibrium(params, HELD).x
    x[P_B.start + 2] -= dz
    x[PAYLOAD_YAW] -= dyaw
    x[params.layout.uav_yaw_index(1)] -= dyaw
    return x


def test_a_held_reference_integrates_its_constant_error(lab_params: FormationParams) -> None:
    integrator = ReferenceIntegrator(lab_params.layout, 0.5)
    x = _state_off_by(lab_params, 0.04, 0.02)
    for k in range(51):  # 50 intervals of 20 ms: 1 s
        shifted = integrator.shifted(HELD, x, k * TICK_S)
    position, yaws = integrator.shift
    assert position == pytest.approx([0.0, 0.0, 0.5 * 0.04 * 1.0], abs=1e-12)
    assert yaws == pytest.approx([0.5 * 0.02, 0.5 * 0.02, 0.0], abs=1e-12)
    assert shifted.payload_position_m[2] == pytest.approx(1.0 + 0.02)
    assert shifted.payload_yaw_rad == pytest.approx(HELD.payload_yaw_rad + 0.01)
    assert shifted.uav_yaw_rad == pytest.approx((0.1 + 0.01, -0.2))
    assert shifted.cone_angle_rad == HELD.cone_angle_rad


def test_a_moving_reference_integrates_nothing_but_keeps_the_shift(
    lab_params: FormationParams,
) -> None:
    integrator = ReferenceIntegrator(lab_params.layout, 0.5)
    x = _state_off_by(lab_params, 0.04, 0.0)
    integrator.shifted(HELD, x, 0.0)
    integrator.shifted(HELD, x, 0.2)
    kept = integrator.shift[0].copy()
    for k in range(10):
        moving = dataclasses.replace(
            HELD, payload_position_m=(0.01 * k, 0.0, 1.0), velocity_mps=(0.5, 0.0, 0.0)
        )
        shifted = integrator.shifted(moving, x, 0.2 + (k + 1) * TICK_S)
        assert shifted.payload_position_m[2] == pytest.approx(1.0 + kept[2])
    assert np.array_equal(integrator.shift[0], kept)
    integrator.reset()
    assert not integrator.shift[0].any() and not integrator.shift[1].any()


def test_not_integrating_holds_the_shift(lab_params: FormationParams) -> None:
    """A held reference whose error is no offset (a set-down with one UAV lost): the
    shift stays as it was, and is still applied."""
    integrator = ReferenceIntegrator(lab_params.layout, 0.5)
    x = _state_off_by(lab_params, 0.04, 0.0)
    integrator.shifted(HELD, x, 0.0)
    integrator.shifted(HELD, x, 0.2)
    kept = integrator.shift[0].copy()
    assert kept[2] > 0.0
    far_off = _state_off_by(lab_params, 0.5, 0.3)
    for k in range(50):
        shifted = integrator.shifted(HELD, far_off, 0.2 + (k + 1) * TICK_S, integrating=False)
    assert np.array_equal(integrator.shift[0], kept)
    assert shifted.payload_position_m[2] == pytest.approx(1.0 + kept[2])


def test_the_shift_is_bounded(lab_params: FormationParams) -> None:
    integrator = ReferenceIntegrator(
        lab_params.layout, 2.0, IntegralLimits(position_m=0.1, yaw_rad=0.05)
    )
    x = _state_off_by(lab_params, 0.5, 0.5)
    x[P_B.start] = math.nan  # a bad estimate integrates nothing
    integrator.shifted(HELD, x, 0.0)
    integrator.shifted(HELD, x, 10.0)
    assert not integrator.shift[0].any()
    x = _state_off_by(lab_params, 0.5, 0.5)
    for k in range(100):
        integrator.shifted(HELD, x, 10.0 + k)
    position, yaws = integrator.shift
    assert position[2] == pytest.approx(0.1) and yaws.max() == pytest.approx(0.05)


def test_no_gain_is_the_reference_itself_and_a_bad_gain_is_refused(
    lab_params: FormationParams,
) -> None:
    integrator = ReferenceIntegrator(lab_params.layout, 0.0)
    x = _state_off_by(lab_params, 0.3, 0.3)
    assert integrator.shifted(HELD, x, 0.0) is HELD
    assert integrator.shifted(HELD, x, 5.0) is HELD
    for bad in (-0.1, math.inf, math.nan):
        with pytest.raises(ValueError, match="integral gain"):
            ReferenceIntegrator(lab_params.layout, bad)


def _steady_error(
    controller: CentralizedMpc | DecentralizedMpc,
    plant: FormationParams,
    integrator: ReferenceIntegrator,
    duration_s: float = 20.0,
) -> float:
    """The model of ``plant`` flown by ``controller`` (built for other parameters) at a
    held reference from its own equilibrium; the bar's mean position error over the last
    2 s [m]."""
    model = FormationModel(plant)
    reference = FormationReference((0.0, 0.0, 1.0), 0.0, (0.0, 0.0))
    x = formation_equilibrium(controller.params, reference).x
    h, errors = TICK_S / 4, []
    ticks = round(duration_s / TICK_S)
    for k in range(ticks):
        u = controller.step(x, integrator.shifted(reference, x, k * TICK_S), k * TICK_S).u
        x = hold(model, x, u, h, 4)
        errors.append(x[P_B] - np.asarray(reference.payload_position_m))
    return float(np.linalg.norm(np.mean(errors[-100:], axis=0)))


@pytest.mark.slow
@pytest.mark.parametrize(
    "name, controller_cls, lead",
    [
        ("centralized", CentralizedMpc, ReferenceLead()),
        ("decentralized", DecentralizedMpc, RECOMMENDED_LEAD),
    ],
)
def test_a_bar_heavier_than_the_model_hangs_at_the_reference_with_the_integral(
    name: str, controller_cls: type, lead: ReferenceLead, lab_params: FormationParams
) -> None:
    """The plant's bar 50 % heavier than the controller's: without the integral it hangs
    centimetres off the reference for good; with it, within 2 cm after 20 s."""
    heavy = dataclasses.replace(
        lab_params,
        payload=dataclasses.replace(lab_params.payload, mass_kg=1.5 * lab_params.payload.mass_kg),
    )

    def controller() -> CentralizedMpc | DecentralizedMpc:
        options = dataclasses.replace(
            CONFIG.mpc_settings(name), late_after_s=10.0, reference_lead=lead
        )
        return controller_cls(lab_params, options, "hpipm", clock=time.perf_counter)  # type: ignore[no-any-return]

    layout = lab_params.layout
    assert _steady_error(controller(), heavy, ReferenceIntegrator(layout, 0.4)) < 0.02
    assert _steady_error(controller(), heavy, ReferenceIntegrator(layout, 0.0)) > 0.05
