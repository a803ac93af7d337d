"""Objects built from a validated ``Config`` for flying: the tick core, the mocap client
and fusion, the MAVLink links (the simulator's parts: ``supervisor.app.sim_assembly``)."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

from controllers.mpc import PeerInputs
from controllers.params import Clock
from mocap.client import QtmClient
from mocap.fusion import FusionConfig, MocapFusion
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
        acceleration_feed_forward=c.acceleration_feed_forward,
        preview=c.preview,
        path_jerk_mps3=c.path_jerk_mps3,
        pd_gains=c.pd.to_gains(),
        feasibility=c.feasibility(),
    )


def flight_core_from_config(
    config: Config,
    controller: str = "centralized",
    *,
    clock: Clock,
    agent: int | None = None,
    peer_inputs: PeerInputs | None = None,
) -> FlightCore:
    """The tick core with both MPCs built for the configured system, timed on ``clock``;
    for ``agent``, its decentralized MPC alone (``FlightCore``'s ``agent``)."""
    return FlightCore(
        config.system.to_params(),
        {name: config.mpc_settings(name) for name in CONTROLLERS},
        arena_from_config(config),
        "decentralized" if agent is not None else controller,
        settings=core_settings_from_config(config),
        safety=safety_limits_from_config(config),
        clock=clock,
        agent=agent,
        peer_inputs=peer_inputs,
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
