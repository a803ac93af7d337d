"""A_c and B_c are the exact Jacobians: they match central finite differences."""

from __future__ import annotations

import math
from collections.abc import Callable

import casadi as ca
import numpy as np
import pytest

from controllers.codegen import NumericFunction
from controllers.formation_equilibria import (
    FormationReference,
    formation_equilibrium,
    hanging_mass_shares_kg,
)
from controllers.formation_model import FormationModel
from controllers.formation_params import FormationParams
from controllers.linearization import discretize, formation_jacobians, payload_jacobians
from controllers.model import PayloadModel
from tests.conftest import uneven_params

CASES = [
    FormationReference((0.0, 0.0, 1.0), 0.0, (0.0, 0.0), 0.0),
    FormationReference((1.0, -0.5, 1.2), 0.9, (-0.4, 2.2), math.radians(30)),
    FormationReference((-0.3, 0.8, 0.9), -2.0, (1.3, -1.3), math.radians(45)),
    FormationReference((0.2, 0.2, 1.4), 3.0, (0.0, 3.0), math.radians(70)),
]


def central_differences(
    f: Callable[[np.ndarray], np.ndarray], z: np.ndarray, step: float = 1e-6
) -> np.ndarray:
    columns = []
    for k in range(z.size):
        dz = np.zeros_like(z)
        dz[k] = step
        columns.append((f(z + dz) - f(z - dz)) / (2 * step))
    return np.column_stack(columns)


def assert_matches(analytic: np.ndarray, numeric: np.ndarray) -> None:
    """Relative to the Jacobian's scale, entrywise: |J − J_fd| ≤ 1e-6 max(1, |J|)."""
    np.testing.assert_array_less(
        np.abs(analytic - numeric), 1e-6 * np.maximum(1.0, np.abs(analytic))
    )


@pytest.mark.parametrize("reference", CASES)
@pytest.mark.parametrize("params", [None, uneven_params()], ids=["lab", "uneven"])
def test_bar_jacobians_match_finite_differences(
    reference: FormationReference, params: FormationParams | None, lab_params: FormationParams
) -> None:
    model = FormationModel(params or lab_params)
    eq = formation_equilibrium(model.params, reference)
    A_c, B_c = (np.asarray(m) for m in formation_jacobians(model)(eq.x, eq.u))
    f = model.dynamics
    assert_matches(A_c, central_differences(lambda x: np.asarray(f(x, eq.u)).ravel(), eq.x))
    assert_matches(B_c, central_differences(lambda u: np.asarray(f(eq.x, u)).ravel(), eq.u))
    assert np.abs(A_c).max() > 1.0  # the check above is not vacuous


@pytest.mark.parametrize("reference", CASES)
def test_payload_jacobians_match_finite_differences(
    reference: FormationReference, lab_params: FormationParams
) -> None:
    eq = formation_equilibrium(lab_params, reference)
    shares = hanging_mass_shares_kg(lab_params)
    for i in (1, 2):
        model = PayloadModel(
            lab_params.uavs[i - 1], shares[i - 1], lab_params.cable_lengths_m[i - 1]
        )
        x, u, f_ext = eq.agent_state(i), eq.agent_input(i), eq.payload_force_n[i - 1]
        A_c, B_c = (np.asarray(m) for m in payload_jacobians(model)(x, u, f_ext))
        f = model.dynamics

        def by_state(
            z: np.ndarray, f: ca.Function = f, u: np.ndarray = u, e: np.ndarray = f_ext
        ) -> np.ndarray:
            return np.asarray(f(z, u, e)).ravel()

        def by_input(
            z: np.ndarray, f: ca.Function = f, x: np.ndarray = x, e: np.ndarray = f_ext
        ) -> np.ndarray:
            return np.asarray(f(x, z, e)).ravel()

        assert_matches(A_c, central_differences(by_state, x))
        assert_matches(B_c, central_differences(by_input, u))


def test_first_order_discretization() -> None:
    A_c = np.array([[0.0, 1.0], [-4.0, -0.2]])
    B_c = np.array([[0.0], [2.0]])
    A, B = discretize(A_c, B_c, 0.02)
    np.testing.assert_array_equal(A, np.eye(2) + 0.02 * A_c)
    np.testing.assert_array_equal(B, 0.02 * B_c)


def test_compiled_jacobians_equal_the_virtual_machine(lab_params: FormationParams) -> None:
    jacobians = formation_jacobians(FormationModel(lab_params))
    compiled = NumericFunction(jacobians)
    interpreted = NumericFunction(jacobians, compile_c=False)
    assert compiled.compiled and not interpreted.compiled
    eq = formation_equilibrium(lab_params, CASES[2])
    for fast, slow in zip(compiled(eq.x, eq.u), interpreted(eq.x, eq.u), strict=True):
        np.testing.assert_array_equal(fast, slow)
    A_c = np.asarray(jacobians(eq.x, eq.u)[0])
    np.testing.assert_array_equal(compiled(eq.x, eq.u)[0], A_c)
