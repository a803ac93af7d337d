"""The N-vehicle layout: every index once, and the bar system's layout for N = 2."""

from __future__ import annotations

import pytest

from geometry import state
from geometry.formation import MAX_VEHICLES, MIN_VEHICLES, FormationLayout
from geometry.state import P_B, TH_B, V_B, W_B


def indices(s: slice) -> list[int]:
    return list(range(s.start, s.stop))


def test_two_vehicles_is_the_bar_systems_layout() -> None:
    layout = FormationLayout(2)
    assert (layout.n_states, layout.n_inputs) == (state.BAR_STATES, state.BAR_INPUTS)
    assert layout.yaw_indices == state.YAW_INDICES
    for i in (1, 2):
        assert layout.uav_block(i) == state.uav_block(i)
        assert layout.uav_slices(i) == state.uav_slices(i)
        assert layout.uav_yaw_index(i) == state.uav_yaw_index(i)
        assert layout.thrust_index(i) == state.thrust_index(i)
        assert layout.torque_slice(i) == state.torque_slice(i)
        assert layout.uav_input_slice(i) == state.uav_input_slice(i)


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
