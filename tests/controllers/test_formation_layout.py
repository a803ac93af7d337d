"""The N-vehicle layout: every index once, and the paper's UAV–bar layout for N = 2."""

from __future__ import annotations

import numpy as np
import pytest

from geometry.formation import MAX_VEHICLES, MIN_VEHICLES, FormationLayout
from geometry.state import P_B, TH_B, V_B, W_B


def indices(s: slice) -> list[int]:
    return list(range(s.start, s.stop))


def test_two_vehicles_is_the_papers_layout() -> None:
    """Section II-B: x = (p_b, v_b, Θ_b, ω_b, p_1, …, ω_1, p_2, …, ω_2) ∈ R^36,
    u = (F_1, τ_1, F_2, τ_2) ∈ R^8."""
    layout = FormationLayout(2)
    assert (layout.n_states, layout.n_inputs) == (36, 8)
    assert [layout.uav_block(i) for i in (1, 2)] == [slice(12, 24), slice(24, 36)]
    assert layout.yaw_indices == (8, 20, 32)
    assert [layout.thrust_index(i) for i in (1, 2)] == [0, 4]
    assert layout.torque_slice(2) == slice(5, 8)
    x = np.arange(36.0)
    assert layout.uav_yaws(x) == (20.0, 32.0)
    assert list(layout.uav_position(x, 2)) == [24, 25, 26]
    assert list(layout.uav_velocity(x, 1)) == [15, 16, 17]
    assert list(layout.uav_euler(x, 1)) == [18, 19, 20]
    assert layout.uav_rate_indices == [21, 22, 23, 33, 34, 35]


@pytest.mark.parametrize("n", range(MIN_VEHICLES, MAX_VEHICLES + 1))
def test_every_index_is_named_once(n: int) -> None:
    layout = FormationLayout(n)
    named = [k for s in (P_B, V_B, TH_B, W_B) for k in indices(s)]
    for i in layout.vehicles:
        parts = layout.uav_slices(i)
        named += [k for s in parts for k in indices(s)]
        assert indices(layout.uav_block(i)) == [k for s in parts for k in indices(s)]
        assert layout.uav_yaw_index(i) == parts[2].stop - 1  # ψ is Θ's last entry
    assert sorted(named) == list(range(layout.n_states)) == sorted(set(named))
    assert layout.n_states == 12 + 12 * n
    assert layout.yaw_indices == (
        TH_B.stop - 1,
        *(layout.uav_yaw_index(i) for i in layout.vehicles),
    )

    inputs = []
    for i in layout.vehicles:
        inputs += [layout.thrust_index(i), *indices(layout.torque_slice(i))]
        assert indices(layout.uav_input_slice(i)) == inputs[-4:]
    assert inputs == list(range(layout.n_inputs)) and layout.n_inputs == 4 * n


@pytest.mark.parametrize("n", [0, 1, MAX_VEHICLES + 1])
def test_formation_size_is_bounded(n: int) -> None:
    with pytest.raises(ValueError, match=f"{MIN_VEHICLES} to {MAX_VEHICLES} UAVs, not {n}"):
        FormationLayout(n)


@pytest.mark.parametrize("i", [0, 4])
def test_a_uav_outside_the_formation_has_no_indices(i: int) -> None:
    layout = FormationLayout(3)
    for accessor in (layout.uav_block, layout.uav_yaw_index, layout.thrust_index):
        with pytest.raises(IndexError, match=f"UAV {i} "):
            accessor(i)
