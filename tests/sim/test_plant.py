"""Physics invariants of the simulator's plant: pendulum frequencies, energy, free fall,
resting, cables, motor lag, determinism — for the paper's two UAVs and bar, and for three
and four UAVs carrying a plate and a frame. Oracles are closed-form mechanics, not
snapshots."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import numpy as np
import pytest

from controllers.formation_params import FormationParams, PayloadParams
from controllers.params import UavParams
from geometry.frames import quaternion_from_euler_zyx, rotation_from_quaternion
from sim.plant import (
    ACT_OFFSET,
    BODY_NAMES,
    STATE_SIZE,
    Plant,
    actuator_slice,
    body_slice,
    hanging_state,
)
from sim.plant_formation import plant_params_from_formation
from sim.plant_params import (
    BarParams,
    CableParams,
    MismatchParams,
    PayloadBodyParams,
    PlantParams,
    UavBodyParams,
    WindParams,
    diagonal,
)
from sim.ports import AirframePort

G = 9.81
UNDAMPED = PlantParams(cables=(CableParams(damping_n_s_per_m=0.0),) * 2)
BAR = slice(26, 29)  # bar position in the state vector


def hanging_under_anchors(params: PlantParams = UNDAMPED) -> tuple[Plant, tuple[float, ...]]:
    """The bar hanging at rest on two vertical cables from UAVs held still at 2 m."""
    plant = Plant(params, anchored=(True, True))
    d1, d2 = params.bar.d1_m, params.bar.d2_m
    trim = plant.place_hanging((np.array([-d1, 0.0, 2.0]), np.array([d2, 0.0, 2.0])))
    return plant, trim.tension_n


def record(plant: Plant, steps: int, extract: slice | int) -> np.ndarray:
    """One state entry (or slice) after each of ``steps`` single steps."""
    samples = []
    for _ in range(steps):
        plant.step(1)
        samples.append(plant.get_state()[extract])
    return np.array(samples)


def mean_angular_frequency(signal: np.ndarray, step_s: float) -> float:
    """2π / mean period from upward zero crossings (linear interpolation)."""
    s = signal - signal.mean()
    i = np.nonzero((s[:-1] < 0.0) & (s[1:] >= 0.0))[0]
    crossings = (i + -s[i] / (s[i + 1] - s[i])) * step_s
    assert len(crossings) >= 4, "too few oscillations to measure"
    return 2.0 * math.pi / float(np.mean(np.diff(crossings)))


def energy_drift_of_a_swing(plant: Plant, body: str) -> float:
    """The largest change of total energy over 10 s of ``body`` swinging and turning on
    taut cables (none may go slack), relative to the swing's energy above rest."""
    rest = plant.energy().total_j
    plant.set_body(
        body,
        velocity_mps=np.array([0.08, 0.15, 0.0]),
        body_rates_radps=np.array([0.0, 0.0, 0.3]),
    )
    start = plant.energy().total_j
    swing = start - rest
    assert swing > 1e-3
    worst = 0.0
    for _ in range(1000):
        plant.step(10)
        assert not any(plant.cables().slack)
        worst = max(worst, abs(plant.energy().total_j - start))
    return worst / swing


# --- Pendulum frequencies --------------------------------------------------------------


@pytest.mark.parametrize("axis", [0, 1], ids=["along-bar", "across-bar"])
def test_parallelogram_swing_is_a_simple_pendulum(axis: int) -> None:
    """Two equal, parallel, vertical cables keep the bar parallel to itself, so every
    point of the bar moves on a circle of the cable's length: ω = √(g / l), whatever the
    bar's inertia or CoM offset. l is the stretched length l₀ + T/k (≈ 1e-4 longer)."""
    plant, tensions = hanging_under_anchors()
    cable = UNDAMPED.cables[0]
    length = cable.length_m + float(np.mean(tensions)) / cable.stiffness_n_per_m
    omega = math.sqrt(G / length)
    velocity = np.zeros(3)
    velocity[axis] = 0.02 * length * omega  # 0.02 rad amplitude: θ²/16 = 2.5e-5
    plant.set_body("bar", velocity_mps=velocity)
    trace = record(plant, 10_000, 26 + axis)
    measured = mean_angular_frequency(trace, plant.step_s)
    assert measured == pytest.approx(omega, rel=1e-3)  # the brief allows ±2 %


def test_bifilar_yaw_frequency() -> None:
    """Yawing about the vertical through the CoM (the bifilar pendulum used to measure
    J_b): each end moves d_i φ sideways and its cable pulls back T_i d_i φ / l_i, so
    ω² = Σ T_i d_i² / (l_i J_zz), which is m g d₁ d₂ / (l J_zz) for equal cables."""
    plant, (T1, T2) = hanging_under_anchors()
    bar = UNDAMPED.bar
    k = UNDAMPED.cables[0].stiffness_n_per_m
    l1, l2 = 1.0 + T1 / k, 1.0 + T2 / k
    J_zz = bar.inertia_tensor_kgm2()[2, 2]
    omega = math.sqrt((T1 * bar.d1_m**2 / l1 + T2 * bar.d2_m**2 / l2) / J_zz)
    assert omega == pytest.approx(math.sqrt(bar.mass_kg * G * bar.d1_m * bar.d2_m / J_zz), rel=1e-3)
    plant.set_body("bar", body_rates_radps=np.array([0.0, 0.0, 0.02 * omega]))
    quaternions = record(plant, 10_000, slice(32, 36))
    yaw = 2.0 * np.arctan2(quaternions[:, 3], quaternions[:, 0])
    assert mean_angular_frequency(yaw, plant.step_s) == pytest.approx(omega, rel=2e-3)


# --- Energy --------------------------------------------------------------------------------


def test_energy_is_conserved_while_swinging_on_taut_cables() -> None:
    """Cables undamped, no drag, UAVs as fixed anchors (they do no work): the bar swings
    across, along and in yaw at once (its pendulum modes) with both cables taut for 10 s.
    The energy above the rest state is conserved to 1e-4 relative (measured ~1e-9).

    Not excited on purpose: the stiff modes of the bar bouncing on its elastic cables
    (ω ≈ 300–400 rad/s). RK4 damps a mode numerically by ≈ (ω h)⁶/72 per step, which at
    1 kHz removes ~40 % of such a mode's energy in 10 s. With the default cable damping
    (ζ ≈ 0.2) those modes die out physically ~100× faster than that anyway."""
    plant, _ = hanging_under_anchors()
    assert energy_drift_of_a_swing(plant, "bar") < 1e-4


def test_energy_with_slack_and_snatch_in_zero_gravity() -> None:
    """Three free bodies tumbling in zero gravity, undamped cables snapping taut and
    going slack again (dozens of times). The tension is continuous but has a kink at
    zero stretch, which fixed-step RK4 steps across, so the energy error is larger than
    on taut cables: measured ≈ 2e-3 relative over 10 s; the bound is 1e-2."""
    params = dataclasses.replace(UNDAMPED, gravity_mps2=0.0)
    plant = Plant(params, ground=False)
    x = plant.get_state()
    rng = np.random.default_rng(1)
    for name, position in zip(
        BODY_NAMES, ([-0.705, 0.0, 1.0], [0.765, 0.0, 1.0], [0.0, 0.0, 0.2]), strict=True
    ):
        s = body_slice(name)
        x[s][0:3] = position
        x[s][3:6] = rng.normal(0.0, 1.0, 3)
        x[s][10:13] = rng.normal(0.0, 3.0, 3)
    plant.set_state(x)
    start = plant.energy().total_j
    transitions = 0
    previous = plant.cables().slack
    worst = 0.0
    for _ in range(5000):
        plant.step(2)
        slack = plant.cables().slack
        transitions += sum(a != b for a, b in zip(slack, previous, strict=True))
        previous = slack
        worst = max(worst, abs(plant.energy().total_j - start))
    assert transitions >= 20
    assert worst / start < 1e-2


def test_free_rigid_bodies_conserve_angular_momentum() -> None:
    """Zero gravity, no ground, cables slack: each body tumbles freely; J ω̇ = −ω × Jω
    (gyroscopic terms, full inertia) keeps R J ω and ½ ωᵀJω constant. The bar spins
    about its own axis too (its axial inertia is tiny, nothing assumes it away)."""
    J_bar = ((0.004, 0.001, 0.0), (0.001, 0.0706, 0.0005), (0.0, 0.0005, 0.07))
    # Cables long enough to stay slack whatever the bodies' orientations.
    params = dataclasses.replace(
        UNDAMPED,
        gravity_mps2=0.0,
        bar=BarParams(inertia_kgm2=J_bar),
        cables=(CableParams(length_m=5.0),) * 2,
    )
    plant = Plant(params, ground=False)
    x = plant.get_state()
    rates = {"uav1": [3.0, -1.0, 2.0], "uav2": [0.5, 4.0, -1.0], "bar": [20.0, 1.0, -2.0]}
    for name in BODY_NAMES:
        x[body_slice(name)][10:13] = rates[name]
    plant.set_state(x)

    def momentum(name: str) -> np.ndarray:
        truth = plant.body(name)
        J = np.array(J_bar) if name == "bar" else np.array(params.uavs[0].inertia_kgm2, dtype=float)
        result: np.ndarray = truth.rotation @ J @ truth.body_rates_radps
        return result

    before = {name: momentum(name) for name in BODY_NAMES}
    energy = plant.energy().kinetic_j
    for _ in range(100):
        plant.advance(0.02)
        assert all(plant.cables().slack)
    for name in BODY_NAMES:
        np.testing.assert_allclose(momentum(name), before[name], rtol=1e-6, atol=1e-9)
        q = plant.body(name).quaternion
        assert np.linalg.norm(q) == pytest.approx(1.0, abs=1e-12)
    assert plant.energy().kinetic_j == pytest.approx(energy, rel=1e-6)


# --- Cables --------------------------------------------------------------------------------


def test_cable_tension_is_never_negative_in_a_violent_flight() -> None:
    """Lift off, full-thrust jerks, motors cut, crash: the cables go slack and snatch taut
    many times; their tension is never negative, zero whenever slack."""
    plant = Plant()
    tensions = []
    slack_changes = 0
    previous = plant.cables().slack
    for thrust, torque, duration in (
        (16.0, [0.0, 0.0, 0.0], 1.2),
        (30.0, [0.05, 0.0, 0.0], 0.4),
        (0.0, [0.0, 0.0, 0.0], 0.8),
        (30.0, [0.0, 0.1, 0.0], 0.3),
        (0.0, [0.0, 0.0, 0.0], 1.0),
    ):
        plant.command(1, thrust, np.array(torque))
        plant.command(2, thrust, -np.array(torque))
        for _ in range(round(duration / 0.002)):
            plant.advance(0.002)
            cables = plant.cables()
            tensions.append(cables.tension_n)
            slack_changes += sum(a != b for a, b in zip(cables.slack, previous, strict=True))
            previous = cables.slack
            for tension, slack in zip(cables.tension_n, cables.slack, strict=True):
                assert tension >= 0.0
                if slack:
                    assert tension == 0.0
    assert slack_changes >= 20
    assert np.max(tensions) > 20.0  # a snatch load, several times the bar's weight


def test_hanging_state_is_an_equilibrium_of_the_free_system() -> None:
    """UAVs at different heights and yaws with cables tied 3 cm below their CoMs, lagged
    motors, free bodies: the placed state and the trim commands stay put."""
    uav = UavBodyParams(cable_attachment_body_m=(0.01, 0.0, -0.03))
    params = PlantParams(uavs=(uav, uav))
    plant = Plant(params)
    positions = (np.array([-0.9, 0.2, 2.0]), np.array([0.95, -0.1, 2.1]))
    trim = plant.place_hanging(positions, (0.3, -1.2))
    start = plant.get_state()
    assert min(trim.tension_n) > 1.0
    plant.advance(1.0)
    np.testing.assert_allclose(plant.get_state(), start, atol=1e-8)
    assert plant.cables().tension_n == pytest.approx(trim.tension_n, rel=1e-8)


# --- Free fall and ground --------------------------------------------------------------------


def test_free_fall_matches_half_g_t_squared() -> None:
    plant = Plant(ground=False)
    x = plant.get_state()
    for name, z in (("uav1", 10.0), ("uav2", 10.0), ("bar", 9.5)):
        x[body_slice(name)][2] = z
    plant.set_state(x)
    start = {name: plant.body(name).position_m for name in BODY_NAMES}
    plant.advance(1.0)
    t = plant.time_s
    assert t == pytest.approx(1.0, abs=1e-12)
    for name in BODY_NAMES:
        truth = plant.body(name)
        drop = start[name][2] - truth.position_m[2]
        assert drop == pytest.approx(0.5 * G * t * t, rel=1e-9)
        assert truth.velocity_mps[2] == pytest.approx(-G * t, rel=1e-9)
        np.testing.assert_array_equal(truth.position_m[:2], start[name][:2])
    assert all(plant.cables().slack)


def test_resting_on_the_ground_is_stable() -> None:
    """The default state: everything on the ground, cables slack. Over 10 s nothing
    moves more than 1 mm and the energy never rises."""
    plant = Plant()
    start = {name: plant.body(name).position_m for name in BODY_NAMES}
    energy = plant.energy().total_j
    assert all(plant.cables().slack)
    assert plant.on_ground(1) and plant.on_ground(2) and plant.payload_on_ground()
    for _ in range(100):
        plant.advance(0.1)
        assert plant.energy().total_j <= energy + 1e-12
    for name in BODY_NAMES:
        assert np.max(np.abs(plant.body(name).position_m - start[name])) < 1e-3


def test_dropped_bodies_come_to_rest_and_stay() -> None:
    """Dropped from 5 cm, sliding and spinning, even a UAV landing upside down (on its
    rotor tips): within 5 s everything stops, then nothing creeps or gains energy."""
    plant = Plant()
    x = plant.get_state()
    rng = np.random.default_rng(3)
    for name in BODY_NAMES:
        s = body_slice(name)
        x[s][2] += 0.05
        x[s][3:5] = rng.normal(0.0, 0.5, 2)
        x[s][10:13] = rng.normal(0.0, 1.0, 3)
    upside_down = quaternion_from_euler_zyx(math.pi, 0.0, 0.3)
    x[body_slice("uav2")][6:10] = upside_down
    x[body_slice("uav2")][2] = 0.2
    plant.set_state(x)
    plant.advance(5.0)
    settled = {name: plant.body(name).position_m for name in BODY_NAMES}
    energy = plant.energy().total_j
    for _ in range(50):
        plant.advance(0.2)
        assert plant.energy().total_j <= energy + 1e-9
    for name in BODY_NAMES:
        assert np.max(np.abs(plant.body(name).position_m - settled[name])) < 1e-3
    assert plant.body("uav2").position_m[2] > 0.0
    assert rotation_from_quaternion(plant.body("uav2").quaternion)[2, 2] < 0.0
    assert plant.energy().kinetic_j < 1e-9


# --- Motors ------------------------------------------------------------------------------


def test_first_order_lag_reaches_63_percent_at_one_time_constant() -> None:
    params = PlantParams()
    tau_f = params.uavs[0].thrust_time_constant_s
    tau_t = params.uavs[0].torque_time_constant_s
    plant = Plant(params, anchored=(True, True))
    plant.command(1, 10.0, np.array([0.5, -0.2, 0.1]))
    steps = round(tau_f / plant.step_s)
    assert steps * plant.step_s == pytest.approx(tau_f) and tau_f == tau_t
    plant.step(steps)
    thrust, torque = plant.actuator(1)
    reached = 1.0 - math.exp(-1.0)
    assert thrust == pytest.approx(10.0 * reached, rel=1e-6)
    np.testing.assert_allclose(torque, np.array([0.5, -0.2, 0.1]) * reached, rtol=1e-6)
    idle_thrust, idle_torque = plant.actuator(2)
    assert idle_thrust == 0.0
    np.testing.assert_array_equal(idle_torque, np.zeros(3))


def test_no_lag_when_the_time_constant_is_zero() -> None:
    uav = UavBodyParams(thrust_time_constant_s=0.0, torque_time_constant_s=0.0)
    plant = Plant(PlantParams(uavs=(uav, uav)), anchored=(True, True))
    plant.command(2, 7.0, np.array([0.1, 0.2, 0.3]))
    plant.step(1)
    thrust, torque = plant.actuator(2)
    assert thrust == 7.0
    np.testing.assert_array_equal(torque, [0.1, 0.2, 0.3])


def test_commands_saturate() -> None:
    plant = Plant(anchored=(True, True))
    limit = plant.params.uavs[0]
    plant.command(1, 100.0, np.array([5.0, -5.0, 0.3]))
    plant.command(2, -3.0, np.array([0.0, 0.0, -9.0]))
    assert plant.commanded(1)[0] == limit.thrust_max_n
    np.testing.assert_array_equal(plant.commanded(1)[1], [1.0, -1.0, 0.3])
    assert plant.commanded(2)[0] == 0.0
    np.testing.assert_array_equal(plant.commanded(2)[1], [0.0, 0.0, -1.0])
    plant.advance(1.0)
    thrust, torque = plant.actuator(1)
    assert 0.999 * limit.thrust_max_n < thrust <= limit.thrust_max_n
    assert np.all(np.abs(torque) <= 1.0)
    with pytest.raises(ValueError, match="non-finite"):
        plant.command(1, math.nan, np.zeros(3))


def test_thrust_lifts_along_body_z() -> None:
    """A UAV pitched 30°, no gravity, no ground, its cable slack: thrust accelerates it
    along its body z axis at F/m."""
    uav = UavBodyParams(thrust_time_constant_s=0.0)
    params = dataclasses.replace(UNDAMPED, gravity_mps2=0.0, uavs=(uav, uav))
    plant = Plant(params, ground=False)
    q = quaternion_from_euler_zyx(0.0, math.radians(30.0), 0.0)
    plant.set_body("uav1", quaternion=q)
    plant.command(1, 2.3, np.zeros(3))
    plant.advance(0.1)
    expected = rotation_from_quaternion(q)[:, 2] * 2.3 / 1.15 * 0.1
    np.testing.assert_allclose(plant.body("uav1").velocity_mps, expected, rtol=1e-9)


# --- Wind, drag, mismatch, determinism -----------------------------------------------------


def test_steady_wind_drags_a_body_to_the_wind_speed() -> None:
    """Linear drag c and a steady wind w, no gravity: v → w with rate c/m."""
    uav = UavBodyParams(drag_linear_n_s_per_m=0.5)
    params = dataclasses.replace(
        UNDAMPED,
        gravity_mps2=0.0,
        uavs=(uav, uav),
        wind=WindParams(mean_velocity_mps=(2.0, -1.0, 0.0)),
    )
    plant = Plant(params, ground=False)
    plant.advance(1.0)
    rate = 0.5 / 1.15
    expected = np.array([2.0, -1.0, 0.0]) * (1.0 - math.exp(-rate * 1.0))
    np.testing.assert_allclose(plant.body("uav1").velocity_mps, expected, rtol=1e-9)
    np.testing.assert_array_equal(plant.body("bar").velocity_mps, np.zeros(3))


def test_mismatch_changes_masses_and_the_bar_com() -> None:
    mismatch = MismatchParams((1.1, 0.9), 1.2, 0.03)
    params = PlantParams().with_mismatch(mismatch)
    assert params.uavs[0].mass_kg == pytest.approx(1.265)
    assert params.uavs[1].inertia_kgm2[2][2] == pytest.approx(0.9 * 0.0977)
    assert params.bar.mass_kg == pytest.approx(0.468)
    assert params.bar.d1_m == pytest.approx(0.735) and params.bar.d2_m == pytest.approx(0.735)
    assert MismatchParams.random(7) == MismatchParams.random(7)
    assert MismatchParams.random(7) != MismatchParams.random(8)


def _gusty_run(seed: int) -> np.ndarray:
    uav = UavBodyParams(drag_linear_n_s_per_m=0.2, drag_quadratic_n_s2_per_m2=0.05)
    params = PlantParams(
        uavs=(uav, uav),
        wind=WindParams(mean_velocity_mps=(1.0, 0.0, 0.0), gust_std_mps=(0.5, 0.5, 0.2), seed=seed),
    ).with_mismatch(MismatchParams.random(seed))
    plant = Plant(params)
    trim = plant.place_hanging((np.array([-0.8, 0.0, 1.5]), np.array([0.8, 0.0, 1.5])))
    for k in range(50):
        torque = np.array([0.01 * math.sin(k), 0.0, 0.0])
        plant.command(1, trim.thrust_n[0], torque)
        plant.command(2, trim.thrust_n[1], -torque)
        plant.advance(0.02)
    return plant.get_state()


def test_runs_are_deterministic_for_a_seed() -> None:
    first = _gusty_run(seed=5)
    np.testing.assert_array_equal(first, _gusty_run(seed=5))
    assert not np.array_equal(first, _gusty_run(seed=6))


# --- API -----------------------------------------------------------------------------------


def test_airframe_port_and_state_layout() -> None:
    plant = Plant()
    port: AirframePort = plant.uav(1)
    state = port.state()
    assert state.on_ground
    np.testing.assert_array_equal(state.position_m, plant.get_state()[body_slice("uav1")][:3])
    port.command(9.0, np.zeros(3))
    assert plant.commanded(1)[0] == 9.0
    assert plant.get_state().shape == (STATE_SIZE,)
    assert actuator_slice(2).start == ACT_OFFSET + 4
    with pytest.raises(ValueError):
        plant.uav(3)
    assert plant.advance(0.0104) == 10  # whole steps: 10.4 ms rounds to 10
    assert plant.time_s == pytest.approx(0.010)
    x = plant.get_state()
    x[BAR][2] = 0.5
    plant.set_state(x, time_s=3.0)
    assert plant.time_s == 3.0 and plant.body("bar").position_m[2] == 0.5


# --- N UAVs and a rigid payload --------------------------------------------------------------


def triangle_plate(cable: CableParams = UNDAMPED.cables[0]) -> PlantParams:
    """Three 1.15 kg UAVs hanging a 0.6 kg equilateral plate (1 m sides) by its corners on
    1 m cables. A thin triangular plate of side a: J = m a²/24 about its in-plane axes and
    m a²/12 about its normal."""
    a, m = 1.0, 0.6
    corners = tuple(
        (a / math.sqrt(3) * math.cos(t), a / math.sqrt(3) * math.sin(t), 0.0)
        for t in (0.0, 2 * math.pi / 3, 4 * math.pi / 3)
    )
    plate = PayloadBodyParams(
        m, diagonal((m * a * a / 24, m * a * a / 24, m * a * a / 12)), corners, corners, 0.005
    )
    return PlantParams(uavs=(UavBodyParams(),) * 3, cables=(cable,) * 3, payload=plate)


def square_frame(cable: CableParams = UNDAMPED.cables[0]) -> PlantParams:
    """Four UAVs hanging a 1 kg square frame (four 1.2 m rods) by its corners on 1 m
    cables: J = m a²/6 about the in-plane axes through its centre, m a²/3 about its
    normal."""
    a, m = 1.2, 1.0
    corners = tuple((x, y, 0.0) for x, y in ((0.6, 0.6), (-0.6, 0.6), (-0.6, -0.6), (0.6, -0.6)))
    frame = PayloadBodyParams(
        m, diagonal((m * a * a / 6, m * a * a / 6, m * a * a / 3)), corners, corners, 0.01
    )
    return PlantParams(uavs=(UavBodyParams(),) * 4, cables=(cable,) * 4, payload=frame)


FORMATIONS = pytest.mark.parametrize("build", [triangle_plate, square_frame], ids=["N=3", "N=4"])
DAMPED = CableParams()


def hover_positions(
    params: PlantParams, cone_rad: float = 0.3, height_m: float = 2.0
) -> list[np.ndarray]:
    """Each UAV a cable's length from its corner of the level payload (CoM at
    ``height_m``), the cable leaning out from the centre by ``cone_rad``."""
    positions = []
    for corner, cable in zip(params.payload_body().attachments_body_m, params.cables, strict=True):
        e = np.array(corner) + np.array([0.0, 0.0, height_m])
        out = np.array([corner[0], corner[1], 0.0]) / math.hypot(corner[0], corner[1])
        positions.append(
            e
            + cable.length_m
            * (math.sin(cone_rad) * out + math.cos(cone_rad) * np.array([0.0, 0.0, 1.0]))
        )
    return positions


def total_mass_kg(params: PlantParams) -> float:
    return sum(uav.mass_kg for uav in params.uavs) + params.payload_body().mass_kg


@FORMATIONS
def test_n_uavs_have_their_bodies_ports_and_state_layout(build: Callable[..., PlantParams]) -> None:
    params = build()
    plant = Plant(params)
    n = params.n_uavs
    assert plant.layout.body_names == (*(f"uav{i}" for i in range(1, n + 1)), "payload")
    assert plant.get_state().shape == (17 * n + 13,) == (plant.layout.state_size,)
    assert set(plant.truth().bodies) == set(plant.layout.body_names)
    assert plant.layout.actuator_slice(n).stop == plant.layout.state_size
    for i in range(1, n + 1):
        port = plant.uav(i)
        assert port.number == i and port.state().on_ground
        port.command(5.0 + i, np.array([0.0, 0.0, 9.0]))
        assert plant.commanded(i)[0] == 5.0 + i and plant.commanded(i)[1][2] == 1.0
    with pytest.raises(ValueError, match="numbered"):
        plant.uav(n + 1)
    with pytest.raises(ValueError, match="unknown body"):
        plant.body("bar")
    with pytest.raises(ValueError, match="one flag per UAV"):
        Plant(params, anchored=(True, True))


@FORMATIONS
def test_hanging_state_is_a_static_equilibrium_of_n_uavs(build: Callable[..., PlantParams]) -> None:
    """Cables leaning out 17°, tied 3 cm below the UAVs' CoMs, every UAV at its own yaw,
    lagged motors, free bodies: the trim thrusts carry the whole weight, and with them
    the placed state does not move (one step: no velocity above 1e-12 m/s, i.e. no
    acceleration above 1e-9 m/s²; one second: nothing moves by 1e-8)."""
    params = build()
    uav = UavBodyParams(cable_attachment_body_m=(0.0, 0.0, -0.03))
    params = dataclasses.replace(params, uavs=(uav,) * params.n_uavs)
    plant = Plant(params)
    yaws = [0.4 * i - 1.0 for i in range(params.n_uavs)]
    trim = plant.place_hanging(hover_positions(params), yaws)
    assert min(trim.tension_n) > 1.0
    lift = sum(
        thrust * plant.body(f"uav{i}").rotation[:, 2]
        for i, thrust in enumerate(trim.thrust_n, start=1)
    )
    np.testing.assert_allclose(lift, [0.0, 0.0, total_mass_kg(params) * G], atol=1e-9)
    for i, yaw in enumerate(yaws, start=1):
        R = plant.body(f"uav{i}").rotation
        assert math.atan2(R[1, 0], R[0, 0]) == pytest.approx(yaw, abs=1e-12)
    start = plant.get_state()
    plant.step(1)
    for name in plant.layout.body_names:
        body = plant.body(name)
        assert np.max(np.abs(body.velocity_mps)) < 1e-12
        assert np.max(np.abs(body.body_rates_radps)) < 1e-12
    plant.advance(1.0)
    np.testing.assert_allclose(plant.get_state(), start, atol=1e-8)
    assert plant.cables().tension_n == pytest.approx(trim.tension_n, rel=1e-8)


@FORMATIONS
def test_energy_is_conserved_on_undamped_cables_with_n_uavs(
    build: Callable[..., PlantParams],
) -> None:
    """UAVs as fixed anchors (no thrust, no work), undamped cables hanging vertically: the
    payload swings sideways and turns about the vertical for 10 s on taut cables; its
    energy above the rest state is conserved to 1e-5 relative (measured ~1e-7; RK4's own
    dissipation of the barely excited stiff modes)."""
    params = build()
    plant = Plant(params, anchored=(True,) * params.n_uavs)
    plant.place_hanging(hover_positions(params, cone_rad=0.0))
    assert energy_drift_of_a_swing(plant, "payload") < 1e-5


@FORMATIONS
def test_damped_cables_only_take_energy_away(build: Callable[..., PlantParams]) -> None:
    """The same swing on damped cables leaning out 17° (the swing stretches them): the
    energy never rises (to 1e-12 J) and has fallen measurably after 10 s."""
    params = build(DAMPED)
    plant = Plant(params, anchored=(True,) * params.n_uavs)
    plant.place_hanging(hover_positions(params))
    plant.set_body(
        "payload",
        velocity_mps=np.array([0.08, 0.15, 0.0]),
        body_rates_radps=np.array([0.0, 0.0, 0.3]),
    )
    start = previous = plant.energy().total_j
    for _ in range(1000):
        plant.step(10)
        energy = plant.energy().total_j
        assert energy <= previous + 1e-12
        previous = energy
    assert previous < start - 1e-5


@FORMATIONS
def test_cables_stay_taut_and_elastic_through_a_yank(build: Callable[..., PlantParams]) -> None:
    """A hovering formation, every UAV's thrust 15 % above its trim for 0.3 s and back:
    the payload follows on taut cables, lifted with the UAVs at 0.15 g, so each cable's
    stretch stays between its static stretch T/k (less 1 %) and 1.25 times it (measured
    1.00–1.15: the lagged motors barely ring the stiff cables)."""
    params = build(DAMPED)
    plant = Plant(params)
    trim = plant.place_hanging(hover_positions(params))
    static_m = np.array(trim.tension_n) / DAMPED.stiffness_n_per_m
    z0 = plant.body("payload").position_m[2]
    for boost, duration_s in ((1.15, 0.3), (1.0, 1.0)):
        for i, (thrust, torque) in enumerate(
            zip(trim.thrust_n, trim.torque_nm, strict=True), start=1
        ):
            plant.command(i, boost * thrust, torque)
        for _ in range(round(duration_s / 0.002)):
            plant.advance(0.002)
            stretch = np.array(plant.cables().stretch_m) / static_m
            assert np.all(stretch > 0.99) and np.all(stretch < 1.25)
    assert plant.body("payload").position_m[2] > z0 + 0.3  # lifted with the UAVs


@FORMATIONS
@pytest.mark.parametrize("com_shift_m", [0.0, 0.15])
def test_resting_n_uavs_stay_at_rest(build: Callable[..., PlantParams], com_shift_m: float) -> None:
    """The resting state with the payload turned and moved, its CoM off the centre of its
    corners or not (then it rests slightly tilted on unevenly loaded corners): everything
    on the ground, cables slack; over 5 s nothing moves by 1 µm (measured 1e-11 m) and the
    energy never rises."""
    params = build()
    shift = MismatchParams((1.0,) * params.n_uavs, 1.0, com_shift_m)
    plant = Plant(params.with_mismatch(shift))
    plant.place_resting((0.4, -0.3), 0.6)
    np.testing.assert_allclose(plant.body("payload").position_m[:2], [0.4, -0.3])
    start = {name: plant.body(name).position_m for name in plant.layout.body_names}
    energy = plant.energy().total_j
    assert all(plant.cables().slack) and plant.payload_on_ground()
    assert all(plant.on_ground(i) for i in range(1, params.n_uavs + 1))
    for _ in range(50):
        plant.advance(0.1)
        assert plant.energy().total_j <= energy + 1e-12
    for name in plant.layout.body_names:
        assert np.max(np.abs(plant.body(name).position_m - start[name])) < 1e-6


@FORMATIONS
def test_a_falling_formation_falls_at_g(build: Callable[..., PlantParams]) -> None:
    """Released from hover with the motors cut, no ground: the stretched cables snap the
    bodies together and ring, but they are internal forces: the formation's momentum is
    −M g t and its CoM falls ½ g t² for 1 s."""
    params = build()
    x, _ = hanging_state(params, hover_positions(params))
    layout = Plant(params).layout
    x[layout.actuator_offset :] = 0.0
    plant = Plant(params, ground=False, state=x)
    masses = [uav.mass_kg for uav in params.uavs] + [params.payload_body().mass_kg]

    def centre() -> tuple[np.ndarray, np.ndarray]:
        bodies = [plant.body(name) for name in layout.body_names]
        com = sum(m * b.position_m for m, b in zip(masses, bodies, strict=True)) / sum(masses)
        momentum = sum(m * b.velocity_mps for m, b in zip(masses, bodies, strict=True))
        return np.asarray(com), np.asarray(momentum)

    com0, _ = centre()
    plant.advance(1.0)
    com, momentum = centre()
    np.testing.assert_allclose(momentum, [0.0, 0.0, -sum(masses) * G], rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(com - com0, [0.0, 0.0, -0.5 * G], rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("lengths_m", [(0.8, 1.2), (1.0, 1.0001)])
@pytest.mark.parametrize("yaw_rad", [0.0, 0.7])
def test_hanging_state_with_unequal_cables(lengths_m: tuple[float, float], yaw_rad: float) -> None:
    """Issue 33: each UAV straight above its bar end at its own cable's length (as a
    hover at θ_l = 0 places them), cables of unequal length. The solver used to start
    from a pitch of 1e-16 (rounding) and step it by 1e-24; now an equilibrium is found
    and the free system stays put."""
    params = PlantParams(cables=tuple(CableParams(length_m=length) for length in lengths_m))
    axis = np.array([math.cos(yaw_rad), math.sin(yaw_rad), 0.0])
    ends = (-params.bar.d1_m * axis, params.bar.d2_m * axis)
    positions = [
        end + np.array([0.0, 0.0, 1.5 + length])
        for end, length in zip(ends, lengths_m, strict=True)
    ]
    plant = Plant(params)
    trim = plant.place_hanging(positions, (yaw_rad, yaw_rad))
    bar = plant.body("bar").rotation
    assert bar[:, 0] @ axis == pytest.approx(1.0, abs=1e-6)  # the ends hang straight below
    assert math.atan2(bar[2, 1], bar[2, 2]) == pytest.approx(0.0, abs=1e-12)  # no roll
    start = plant.get_state()
    plant.advance(1.0)
    np.testing.assert_allclose(plant.get_state(), start, atol=1e-8)
    assert sum(trim.tension_n) == pytest.approx(params.bar.mass_kg * G, rel=1e-6)


@pytest.mark.parametrize("com_shift_m", [0.05, -0.05, 0.3])
def test_a_bar_hangs_under_its_uavs_whatever_its_com(com_shift_m: float) -> None:
    """Each UAV straight above a bar end, the bar's CoM off its midpoint either way (the
    plant's mismatch; a shift toward cable 2 makes cable 1's end the farthest from the
    CoM). The bar hangs level below, upright (the solver used to turn it end for end and
    find no taut cables), the tensions carry its weight with its moment balanced, and the
    free system stays put."""
    params = PlantParams().with_mismatch(MismatchParams((1.0, 1.0), 1.0, com_shift_m))
    bar = params.bar
    cable = params.cables[0].length_m
    positions = [np.array([-bar.d1_m, 0.0, 1.0 + cable]), np.array([bar.d2_m, 0.0, 1.0 + cable])]
    plant = Plant(params)
    trim = plant.place_hanging(positions, (0.0, 0.0))
    rotation = plant.body("bar").rotation
    assert rotation[:, 0] @ np.array([1.0, 0.0, 0.0]) == pytest.approx(1.0, abs=1e-6)
    assert rotation[2, 2] == pytest.approx(1.0, abs=1e-6)  # upright
    assert plant.body("bar").position_m[0] == pytest.approx(0.0, abs=1e-6)
    tension_1, tension_2 = trim.tension_n
    assert tension_1 + tension_2 == pytest.approx(bar.mass_kg * G, rel=1e-6)
    assert tension_1 * bar.d1_m == pytest.approx(tension_2 * bar.d2_m, rel=1e-4)
    start = plant.get_state()
    plant.advance(1.0)
    np.testing.assert_allclose(plant.get_state(), start, atol=1e-8)


def test_a_payload_that_cannot_hang_is_refused() -> None:
    params = triangle_plate()
    positions = hover_positions(params)
    positions[1] = positions[1] + np.array([3.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="UAV 2"):
        hanging_state(params, positions)
    with pytest.raises(ValueError, match="3 UAVs need 3 positions"):
        hanging_state(params, positions[:2])


def test_plant_parameters_of_n_uavs_are_consistent() -> None:
    plate = triangle_plate().payload_body()
    with pytest.raises(ValueError, match="need 3 cables"):
        PlantParams(uavs=(UavBodyParams(),) * 3, payload=plate)
    with pytest.raises(ValueError, match="need 2 cables and 2 attachments"):
        PlantParams(uavs=(UavBodyParams(),) * 2, cables=(CableParams(),) * 2, payload=plate)
    mismatch = MismatchParams((1.1, 1.0, 0.9), 1.2, 0.03)
    shifted = triangle_plate().with_mismatch(mismatch).payload_body()
    assert shifted.mass_kg == pytest.approx(0.72)
    np.testing.assert_allclose(
        np.array(shifted.attachments_body_m) - np.array(plate.attachments_body_m),
        [[-0.03, 0.0, 0.0]] * 3,
    )
    assert shifted.inertia_kgm2[2][2] == pytest.approx(1.2 * 0.05 + 0.72 * 0.03**2)
    with pytest.raises(ValueError, match="2 UAV mass scales for 3 UAVs"):
        triangle_plate().with_mismatch(MismatchParams())
    assert len(MismatchParams.random(7, n_uavs=3).uav_mass_scale) == 3
    assert MismatchParams.random(7, n_uavs=2) == MismatchParams.random(7)


def test_the_plant_of_a_formation() -> None:
    """The controllers' formation becomes the plant's: masses, inertias, cable lengths
    and attachments carried over, the rest from the plant's own templates. Two UAVs on a
    bar along its x axis are the paper's bar, as ``plant_params_from_config`` builds it."""
    uav = UavParams(1.15, (0.0348, 0.0459, 0.0977))
    J_b = 0.0706
    bar = FormationParams(
        (uav, uav),
        PayloadParams(
            0.39,
            ((0.0, 0.0, 0.0), (0.0, J_b, 0.0), (0.0, 0.0, J_b)),
            ((-0.705, 0.0, 0.0), (0.765, 0.0, 0.0)),
        ),
        (1.0, 1.1),
    )
    airframe = UavBodyParams(thrust_time_constant_s=0.03, thrust_max_n=26.0)
    params = plant_params_from_formation(bar, airframe=airframe)
    assert params.payload is None and params.payload_name == "bar"
    assert params.bar == BarParams(
        mass_kg=0.39,
        length_m=0.705 + 0.765,
        com_from_end1_m=0.705,
        inertia_kgm2=diagonal((0.39 * 0.01**2, J_b, J_b)),
    )
    assert (
        params.uavs == (dataclasses.replace(airframe, inertia_kgm2=diagonal(uav.inertia_kgm2)),) * 2
    )
    assert [c.length_m for c in params.cables] == [1.0, 1.1]
    with pytest.raises(ValueError, match="rests on its ends"):
        plant_params_from_formation(bar, payload_contact_points_m=((0.0, 0.0, -0.1),))

    plate = triangle_plate().payload_body()
    formation = FormationParams(
        (uav,) * 3, PayloadParams(0.6, plate.inertia_kgm2, plate.attachments_body_m), (1.0,) * 3
    )
    params = plant_params_from_formation(formation, payload_contact_radius_m=0.005)
    assert params.payload_name == "payload" and params.payload_body() == plate
    assert Plant(params).layout.body_names == ("uav1", "uav2", "uav3", "payload")
