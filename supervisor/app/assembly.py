"""Objects built from a validated ``Config``: the tick core, the plant and its mocap model.

The plant starts from the same ``system`` section the controllers use and then applies the
``sim`` section's deliberate mismatch, motor lag and wind, so that a simulated flight
exercises the controllers on a plant that is not their own model.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

from controllers.formation_equilibria import hanging_mass_shares_kg
from controllers.params import Clock
from mocap.client import QtmClient
from mocap.fusion import FusionConfig, MocapFusion
from sim.measurement import MocapParams, TrackingParams
from sim.plant import layout_of
from sim.plant_formation import plant_params_from_formation
from sim.plant_params import MismatchParams, PlantParams, UavBodyParams, WindParams
from sim.px4 import Px4Params
from supervisor.app.config import Config, host_port
from supervisor.flight.core import CONTROLLERS, CoreSettings, FlightCore
from supervisor.flight.estimation import BodyNames
from supervisor.flight.safety import SafetyLimits
from supervisor.flight.setpoints import Arena
from supervisor.mavlink.link import LinkConfig


def arena_from_config(config: Config) -> Arena:
    """The geofence of the configured arena."""
    return Arena.between(config.arena.min_m, config.arena.max_m)


def safety_limits_from_config(config: Config) -> SafetyLimits:
    """The monitors' thresholds for this setup (the ones it does not set at their defaults)."""
    return SafetyLimits(
        max_tilt_rad=math.radians(config.safety.max_tilt_deg),
        slack_time_s=config.safety.slack_time_s,
        slack_window_s=config.safety.slack_window_s,
        slack_in_window_s=config.safety.slack_in_window_s,
        max_bar_yaw_error_rad=math.radians(config.safety.max_bar_yaw_error_deg),
        max_refused_poses=config.safety.max_refused_poses,
    )


def core_settings_from_config(config: Config) -> CoreSettings:
    """The tick core's flight-phase settings of this setup (``control``)."""
    c = config.control
    return CoreSettings(
        takeoff_height_m=c.takeoff_height_m,
        reached_position_m=c.reached_position_m,
        reached_yaw_rad=math.radians(c.reached_yaw_deg),
        flight_rates=c.flight_rates.to_limits(),
        takeoff_rates=c.takeoff_rates.to_limits(),
        abort_rates=c.abort_rates.to_limits(),
        descend_speed_mps=c.descend_speed_mps,
        settle_on_ground_s=c.settle_on_ground_s,
        landing_clearance_m=c.landing_clearance_m,
        bumpless_ticks=c.bumpless_ticks,
        rate_lookahead_steps=c.rate_lookahead_steps,
        pd_gains=c.pd.to_gains(),
        feasibility=c.feasibility(),
    )


def flight_core_from_config(
    config: Config, controller: str = "centralized", *, clock: Clock
) -> FlightCore:
    """The tick core with both MPCs built for the configured system, timed on ``clock``."""
    return FlightCore(
        config.system.to_params(),
        {name: config.mpc_settings(name) for name in CONTROLLERS},
        arena_from_config(config),
        controller,
        settings=core_settings_from_config(config),
        safety=safety_limits_from_config(config),
        clock=clock,
    )


def fusion_from_config(config: Config) -> MocapFusion:
    """The rigid-body filters of the configured bodies."""
    m = config.mocap
    fusion_config = FusionConfig(
        position_accel_psd=m.position_accel_psd,
        position_noise_m=m.position_noise_m,
        angular_accel_psd=m.angular_accel_psd,
        attitude_noise_rad=math.radians(m.attitude_noise_deg),
        max_age_s=m.max_age_s,
        gate_max_accel_mps2=m.gate_max_accel_mps2,
        gate_max_angular_rate_radps=math.radians(m.gate_max_angular_rate_deg_s),
        gate_sigmas=m.gate_sigmas,
    )
    return MocapFusion(fusion_config, names=m.bodies)


def qtm_client_from_config(config: Config, world: dict[str, Any] | None) -> QtmClient:
    """The QTM client of the configured server, or of the embedded world's (whose UDP
    port is learned: the world picks it)."""
    m = config.mocap
    if world is not None:
        host, port = host_port(world["qtm"])
        return QtmClient(host, port, transport=m.transport)
    return QtmClient(m.host, m.port, transport=m.transport, server_udp_port=m.server_udp_port)


def body_names_from_config(config: Config) -> BodyNames:
    """Which QTM body is the payload and which the UAVs."""
    payload, *uavs = config.mocap.bodies
    return BodyNames(payload, tuple(uavs), is_bar=config.system.to_params().payload.is_bar)


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


def link_configs_from_config(
    config: Config,
    vehicle_addresses: Sequence[tuple[str, int]] | None = None,
    local_ports: Sequence[int] | None = None,
    events_path: str | None = None,
    signing_keys: Mapping[int, bytes] | None = None,
) -> tuple[LinkConfig, ...]:
    """Every vehicle's MAVLink link, UAV 1's first (the embedded world passes its own
    addresses, ports and event definitions; ``signing_keys``, by system id, are used when
    ``vehicles.signing``)."""
    v = config.vehicles
    n = config.system.n_vehicles
    thrust, torque = config.per_vehicle(v.thrust_max_n), config.per_vehicle(v.torque_max_nm)
    configured = [host_port(address) for address in v.addresses or []]
    addresses: Sequence[tuple[str, int] | None] = vehicle_addresses or configured or [None] * n
    ports = local_ports or v.ports
    return tuple(
        LinkConfig(
            system_id=v.system_ids[k],
            local_host=config.link_bind_host(),
            local_port=ports[k],
            vehicle_address=addresses[k],
            command_mode=v.command_mode,
            mocap_message=v.mocap_message,
            thrust_max_n=thrust[k],
            torque_max_nm=torque[k],
            ack_timeout_s=v.ack_timeout_s,
            retries=v.retries,
            link_loss_s=v.link_loss_s,
            events_path=events_path or v.px4_events,
            signing_key=(signing_keys or {}).get(v.system_ids[k]) if v.signing else None,
        )
        for k in range(n)
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
