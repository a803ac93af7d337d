"""The disturbance-force observer against a plant it does not share: the formation's
model integrated with true loads at a fine step, measured with noise. Its estimate makes
the equilibrium the plant really holds; it is bounded, and bad input is ignored."""

from __future__ import annotations

import math

import numpy as np
import pytest

from controllers.delay import DelayPredictor
from controllers.force_observer import MAX_TORQUE_NM, ForceObserver, velocity_indices
from controllers.formation_equilibria import (
    NO_FORCES,
    ExternalForces,
    FormationReference,
    formation_equilibrium,
)
from controllers.formation_model import FormationModel
from controllers.formation_params import FormationParams
from geometry.arrays import FloatArray
from tests.conftest import symmetric_params, uneven_params
from tests.controllers.test_formation_equilibria import plate_params

TICK_S = 0.02
HOLD = FormationReference((0.0, 0.0, 1.0), 0.3, (0.3, 0.3))


def fly_held(
    params: FormationParams,
    truth: ExternalForces,
    observer: ForceObserver,
    predictor: DelayPredictor,
    seconds: float,
    noise_mps: float = 0.0,
) -> None:
    """The formation at the equilibrium of ``truth``, held there by its inputs: a fixed
    point of the forced model, so the state stays (measured with ``noise_mps`` of white
    noise on every velocity). The observer sees the free model's inputs being sent."""
    reference = (
        HOLD
        if params.n_vehicles == 2
        else FormationReference((0.0, 0.0, 1.0), 0.3, (0.3,) * params.n_vehicles)
    )
    held = formation_equilibrium(params, reference, forces=truth)
    xdot = np.asarray(
        FormationModel(params).forced_dynamics(held.x, held.u, truth.vector(params.n_vehicles))
    ).ravel()
    # At rest but for the balance point's 0.1 mm rounding under a payload torque.
    assert np.abs(xdot).max() < 1e-3
    rng = np.random.default_rng(5)
    velocities = velocity_indices(params)
    for k in range(round(seconds / TICK_S)):
        t = k * TICK_S
        predictor.sent(t, held.u)
        measured = held.x.copy()
        measured[velocities] += rng.normal(0.0, noise_mps, len(velocities))
        observer.update(measured, t)


def make(params: FormationParams, tau_s: float = 0.3) -> tuple[ForceObserver, DelayPredictor]:
    predictor = DelayPredictor(params, 0.0)
    return ForceObserver(params, predictor, tau_s, max_force_n=5.0), predictor


CASES = {
    "bar, push and a heavy UAV": (
        symmetric_params(),
        ExternalForces(payload_n=(0.8, -0.3, 0.0), uavs_n=((0.0, 0.0, -2.5), (0.2, 0.0, 0.0))),
    ),
    "uneven bar, CoM off (torque)": (
        uneven_params(),
        ExternalForces(payload_torque_nm=(0.0, 0.3, 0.0)),
    ),
    "plate, wind on everything": (
        plate_params(3),
        ExternalForces(payload_n=(0.6, 0.0, 0.0), uavs_n=((0.4, 0.0, 0.0),) * 3),
    ),
}


@pytest.mark.parametrize(("params", "truth"), CASES.values(), ids=CASES.keys())
def test_the_estimate_explains_what_the_plant_does(
    params: FormationParams, truth: ExternalForces
) -> None:
    """After a few time constants the forced model under the estimate is at rest where
    the plant is, with the inputs it gets, and the net external force is the true one.
    The split between the bodies is not unique: a tension pair along a cable, or a couple
    on the payload against opposite forces on the UAVs below it, moves nothing."""
    observer, predictor = make(params)
    fly_held(params, truth, observer, predictor, seconds=4.0)
    reference = FormationReference((0.0, 0.0, 1.0), 0.3, (0.3,) * params.n_vehicles)
    held = formation_equilibrium(params, reference, forces=truth)
    model = FormationModel(params)
    rows = velocity_indices(params)
    estimated = observer.forces.vector(params.n_vehicles)
    at_rest = np.asarray(model.forced_dynamics(held.x, held.u, estimated)).ravel()[rows]
    free = np.asarray(model.dynamics(held.x, held.u)).ravel()[rows]
    assert np.abs(at_rest).max() < 0.01 * np.abs(free).max()
    np.testing.assert_allclose(
        net_force(estimated), net_force(truth.vector(params.n_vehicles)), atol=0.02
    )


def net_force(d: FloatArray) -> FloatArray:
    """The loads' net force [N]: the payload's and every UAV's."""
    total: FloatArray = d[0:3] + d[6:].reshape(-1, 3).sum(axis=0)
    return total


def test_it_settles_with_its_time_constant() -> None:
    """A first-order estimate: about 63 % of a step after one time constant, and its
    noise filtered (velocity noise of 2 cm/s per tick moves the force by centinewtons)."""
    params = symmetric_params()
    truth = ExternalForces(payload_n=(1.0, 0.0, 0.0))
    observer, predictor = make(params, tau_s=0.5)
    fly_held(params, truth, observer, predictor, seconds=0.5 + TICK_S)
    assert 0.5 < observer.forces.payload_n[0] < 0.75
    quiet, quiet_predictor = make(params, tau_s=0.5)
    fly_held(params, NO_FORCES, quiet, quiet_predictor, seconds=5.0, noise_mps=0.02)
    assert np.linalg.norm(quiet.forces.vector(2)) < 0.5


def test_the_estimate_is_bounded_and_bad_input_ignored() -> None:
    params = symmetric_params()
    observer, predictor = make(params, tau_s=0.05)
    fly_held(
        params,
        ExternalForces(payload_n=(0.0, 0.0, 0.0), uavs_n=((0.0, 0.0, -30.0), (0.0, 0.0, 0.0))),
        observer,
        predictor,
        2.0,
    )
    d = observer.forces.vector(2)
    assert all(np.linalg.norm(d[k : k + 3]) <= 5.0 + 1e-12 for k in (0, 6, 9))
    assert np.linalg.norm(d[3:6]) <= MAX_TORQUE_NM + 1e-12
    lifted, lifted_predictor = make(params, tau_s=0.05)
    upward = ExternalForces(payload_n=(0.0, 0.0, 3.0))  # three quarters of the bar's weight
    fly_held(params, upward, lifted, lifted_predictor, 2.0)
    weight_n = params.payload.mass_kg * params.gravity_mps2
    assert lifted.forces.payload_n[2] <= 0.5 * weight_n + 1e-12
    before = observer.forces
    x = formation_equilibrium(params, HOLD).x
    x[4] = math.nan
    assert observer.update(x, 2.1) == before
    assert observer.update(formation_equilibrium(params, HOLD).x, 2.12) == before  # restarts
    observer.reset()
    assert observer.forces == NO_FORCES
    assert not np.any(predictor.forces)


def test_a_time_constant_of_zero_is_off() -> None:
    params = symmetric_params()
    observer, predictor = make(params, tau_s=0.0)
    fly_held(params, ExternalForces(payload_n=(1.0, 0.0, 0.0)), observer, predictor, 1.0)
    assert observer.forces == NO_FORCES


@pytest.mark.parametrize(("tau", "bound"), [(-1.0, 5.0), (math.nan, 5.0), (0.5, 0.0)])
def test_bad_settings_are_refused(tau: float, bound: float) -> None:
    params = symmetric_params()
    with pytest.raises(ValueError, match="force observer"):
        ForceObserver(params, DelayPredictor(params, 0.0), tau, bound)
