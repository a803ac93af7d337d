"""The embedded simulator's parts from a validated ``Config``: the plant, its motion capture and its
simulated PX4s. Apart from ``supervisor.app.assembly`` so that the flight and relay
processes, which fly whatever is there, never import the simulator (its kernels take a
second of every start).

The plant starts from the same ``system`` section the controllers use and then applies the
``sim`` section's deliberate mismatch, motor lag and wind, so that a simulated flight
exercises the controllers on a plant that is not their own model."""

from __future__ import annotations

import math

from controllers.formation_equilibria import hanging_mass_shares_kg
from sim.measurement import MocapParams, TrackingParams
from sim.plant import layout_of
from sim.plant_formation import plant_params_from_formation
from sim.plant_params import MismatchParams, PlantParams, UavBodyParams, WindParams
from sim.px4 import Px4Params
from supervisor.app.config import Config


def plant_params_from_config(
    config: Config, rotor_limits: tuple[float, tuple[float, float, float]] | None = None
) -> PlantParams:
    """The simulator's plant: the configured system, then the ``sim`` mismatch.
    ``rotor_limits`` (thrust [N], torque per axis [N m]) replace the configured actuator
    limits when real rotors are mixed (PX4 SITL allocates to four motors itself)."""
    sim = config.sim
    thrust_max, torque_max = rotor_limits or (
        sim.uav_thrust_max_n,
        (config.mpc.torque_max_nm,) * 3,
    )
    airframe = UavBodyParams(
        thrust_time_constant_s=sim.motor_time_constant_s,
        torque_time_constant_s=sim.motor_time_constant_s,
        thrust_max_n=thrust_max,
        torque_max_nm=torque_max,
        drag_linear_n_s_per_m=sim.drag_linear_n_s_per_m,
    )
    wind = WindParams(
        mean_velocity_mps=(sim.wind_mean_mps[0], sim.wind_mean_mps[1], sim.wind_mean_mps[2]),
        gust_std_mps=(
            sim.wind_gust_std_mps[0],
            sim.wind_gust_std_mps[1],
            sim.wind_gust_std_mps[2],
        ),
        seed=sim.seed,
    )
    plant = plant_params_from_formation(
        config.system.to_params(),
        airframe=airframe,
        payload_drag_linear_n_s_per_m=sim.drag_linear_n_s_per_m,
        wind=wind,
        step_s=sim.step_s,
    )
    mismatch = MismatchParams(tuple(sim.uav_mass_scale), sim.bar_mass_scale, sim.bar_com_shift_m)
    return plant.with_mismatch(mismatch)


def qtm_names_of_plant_bodies(config: Config) -> dict[str, str]:
    """The QTM name (``mocap.bodies``) of each of the plant's bodies, in the plant's order
    ("uav1" … "uavN", then "bar" or "payload")."""
    plant_names = layout_of(plant_params_from_config(config)).body_names
    payload, *uavs = config.mocap.bodies
    return dict(zip(plant_names, (*uavs, payload), strict=True))


def mocap_params_from_config(config: Config, seed: int | None = None) -> MocapParams:
    """The simulated motion capture of ``sim.mocap`` over the plant's bodies (``seed``
    overrides ``sim.seed``)."""
    m = config.sim.mocap
    return MocapParams(
        bodies=tuple(qtm_names_of_plant_bodies(config)),
        rate_hz=m.rate_hz,
        position_sigma_m=m.position_sigma_m,
        orientation_sigma_rad=math.radians(m.orientation_sigma_deg),
        latency_s=m.latency_s,
        tracking=TrackingParams(
            dropout_probability=m.dropout_probability,
            burst_probability=m.burst_probability,
            burst_frames=(m.burst_frames[0], m.burst_frames[1]),
        ),
        seed=config.sim.seed if seed is None else seed,
    )


def px4_params_from_config(config: Config, uav: int) -> Px4Params:
    """The simulated PX4 of UAV ``uav`` (1 … N): the vehicle's true calibration (the
    configured one, times ``sim.px4_thrust_scale``), its hover thrust with its share of the
    payload (13), and
    the parameters a mocap lab boots with — the same ``LabParameters`` the real-firmware
    back-end writes (offboard loss: land after ``vehicles.offboard_loss_timeout_s``; vision
    only; MAV_SYS_ID the configured system id)."""
    from sim.px4_firmware import LabParameters  # here: only this function may change

    params = config.system.to_params()
    k = uav - 1
    inertia = params.uavs[k].inertia_kgm2
    carried_kg = params.uavs[k].mass_kg + hanging_mass_shares_kg(params)[k]  # (13)
    thrust_max_n = config.per_vehicle(config.vehicles.thrust_max_n)[k]
    thrust_scale = config.sim.px4_thrust_scale[k]
    hover_thrust_n = carried_kg * params.gravity_mps2
    lab = LabParameters(
        system_id=config.vehicles.system_ids[k],
        offboard_loss_timeout_s=config.vehicles.offboard_loss_timeout_s,
        hover_thrust=hover_thrust_n / (thrust_max_n * thrust_scale),
    )
    return Px4Params(
        inertia_kgm2=(inertia[0], inertia[1], inertia[2]),
        thrust_max_n=thrust_max_n,
        torque_max_nm=config.per_vehicle(config.vehicles.torque_max_nm)[k],
        thrust_scale=thrust_scale,
        hover_thrust_n=hover_thrust_n,
        offboard_loss_timeout_s=config.vehicles.offboard_loss_timeout_s,
        offboard_loss_action=4,  # COM_OBL_RC_ACT: land (LabParameters sets it too)
        require_vision=config.sim.px4_require_vision,
        boot_parameters=tuple((name, float(value)) for name, value in lab.values().items()),
        seed=config.sim.seed,
    )
