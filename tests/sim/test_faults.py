"""The fault model of the simulated world, without sockets: validation, expiry on the
world's clock, and what each kind does to a frame and to a datagram."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np
import pytest

from mocap.qtm_protocol import BodyPose
from sim.faults import (
    REBOOT_S,
    FaultError,
    FaultSet,
    LinkLost,
    MocapBodyLost,
    MocapFreeze,
    MocapJump,
    MocapSilent,
    Push,
    Px4Reboot,
    UdpLoss,
    parse_fault,
)
from sim.loads import ExternalLoad

BODIES = ("bar", "uav1", "uav2")
VEHICLES = 2


def poses(x_m: float = 0.0) -> dict[str, BodyPose]:
    """A frame's tracked poses: each body at (x, k, 1) m, level."""
    return {
        name: BodyPose.from_quaternion(name, np.array([x_m, k, 1.0]), np.array([1.0, 0, 0, 0]))
        for k, name in enumerate(BODIES)
    }


def faults(*started: Any, now_s: float = 0.0) -> FaultSet:
    fault_set = FaultSet(BODIES, VEHICLES, seed=3)
    for fault in started:
        fault_set.start(fault, now_s)
    return fault_set


# ---- validation ----
@pytest.mark.parametrize(
    ("request_", "field"),
    [
        ({}, "kind"),
        ({"kind": "meteor"}, "kind"),
        ({"kind": 3}, "kind"),
        ({"kind": "mocap_silent", "vehicle": 1}, "vehicle"),
        ({"kind": "mocap_body_lost"}, "body"),
        ({"kind": "mocap_body_lost", "body": "ghost"}, "body"),
        ({"kind": "mocap_body_lost", "body": 7}, "body"),
        ({"kind": "mocap_jump", "body": "bar"}, "offset_m"),
        ({"kind": "mocap_jump", "body": "bar", "offset_m": [0.1, 0.0]}, "offset_m"),
        ({"kind": "mocap_jump", "body": "bar", "offset_m": [0.1, math.nan, 0]}, "offset_m"),
        ({"kind": "mocap_jump", "body": "bar", "offset_m": [True, 0, 0]}, "offset_m"),
        ({"kind": "push", "body": "bar"}, "force_n"),
        ({"kind": "push", "force_n": [1, 0, 0]}, "body"),
        ({"kind": "push", "body": "bar", "force_n": [1, 0]}, "force_n"),
        ({"kind": "push", "body": "bar", "force_n": [1, math.inf, 0]}, "force_n"),
        (
            {"kind": "push", "body": "bar", "force_n": [1, 0, 0], "torque_nm": [0, 0, 1]},
            "torque_nm",
        ),
        ({"kind": "push", "body": "bar", "force_n": [0, 0, 50.5]}, "force_n"),
        ({"kind": "push", "body": "ghost", "force_n": [1, 0, 0]}, "body"),
        ({"kind": "push", "body": "bar", "force_n": [1, 0, 0], "offset_m": [0, 0, 0]}, "offset_m"),
        ({"kind": "link_lost"}, "vehicle"),
        ({"kind": "link_lost", "vehicle": 3}, "vehicle"),
        ({"kind": "link_lost", "vehicle": 9}, "vehicle"),
        ({"kind": "link_lost", "vehicle": True}, "vehicle"),
        ({"kind": "px4_reboot", "vehicle": 0}, "vehicle"),
        ({"kind": "udp_loss", "fraction": 1.5}, "fraction"),
        ({"kind": "udp_loss", "fraction": -0.1}, "fraction"),
        ({"kind": "udp_loss", "fraction": math.nan}, "fraction"),
        ({"kind": "udp_loss", "fraction": "0.5"}, "fraction"),
        ({"kind": "mocap_silent", "duration_s": -1.0}, "duration_s"),
        ({"kind": "mocap_silent", "duration_s": 0.0}, "duration_s"),
        ({"kind": "mocap_silent", "duration_s": math.inf}, "duration_s"),
        ({"kind": "mocap_silent", "duration_s": math.nan}, "duration_s"),
        ({"kind": "mocap_silent", "duration_s": 1e300}, "duration_s"),
        ({"kind": "mocap_jump", "body": "bar", "offset_m": [0, 0, 1e9]}, "offset_m"),
    ],
)
def test_an_invalid_fault_names_the_field(request_: dict[str, Any], field: str) -> None:
    with pytest.raises(FaultError) as raised:
        parse_fault(request_, BODIES, VEHICLES)
    assert raised.value.field == field
    assert str(raised.value).startswith(f"{field}: ")


def test_valid_faults_parse_with_their_defaults() -> None:
    assert parse_fault({"kind": "mocap_silent"}, BODIES, VEHICLES) == MocapSilent(None)
    jump = parse_fault(
        {"kind": "mocap_jump", "body": "uav1", "offset_m": [0.1, 0, -0.2], "duration_s": 2},
        BODIES,
        VEHICLES,
    )
    assert jump == MocapJump("uav1", (0.1, 0, -0.2), 2)
    # A reboot always ends: without a duration it takes the boot time.
    reboot = parse_fault({"kind": "px4_reboot", "vehicle": 2}, BODIES, VEHICLES)
    assert reboot == Px4Reboot(2, REBOOT_S)
    loss = parse_fault({"kind": "udp_loss", "fraction": 0, "duration_s": None}, BODIES, VEHICLES)
    assert loss == UdpLoss(0)


def test_a_body_must_be_one_qtm_streams_when_started_too() -> None:
    with pytest.raises(FaultError, match="not a configured rigid body"):
        faults().start(MocapBodyLost("ghost"), 0.0)


def test_a_vehicle_must_be_one_of_the_worlds_when_parsed_and_started() -> None:
    """Three vehicles and a plate: vehicle 3 is one of them, vehicle 4 is not."""
    bodies = ("plate", "uav1", "uav2", "uav3")
    assert parse_fault({"kind": "link_lost", "vehicle": 3}, bodies, 3) == LinkLost(3)
    with pytest.raises(FaultError) as raised:
        parse_fault({"kind": "px4_reboot", "vehicle": 4}, bodies, 3)
    assert raised.value.field == "vehicle"
    assert str(raised.value) == ("vehicle: 4 is not a vehicle of this world (its vehicles: 1 to 3)")
    fault_set = FaultSet(bodies, 3)
    fault_set.start(Px4Reboot(3, 1.0), 0.0)
    assert not fault_set.powered(3) and fault_set.powered(2)
    assert not fault_set.keep_mavlink(3, inbound=True)
    with pytest.raises(FaultError, match="4 is not a vehicle of this world"):
        fault_set.start(LinkLost(4), 0.0)
    assert [a.fault for a in fault_set.active] == [Px4Reboot(3, 1.0)]


# ---- expiry ----
def test_faults_end_on_the_world_clock_and_until_cleared_ones_do_not() -> None:
    fault_set = faults(MocapSilent(1.0), now_s=10.0)
    fault_set.start(MocapBodyLost("bar"), 10.5)
    assert fault_set.expire(10.99) == []
    [view_silent, view_lost] = fault_set.views(10.75)
    assert view_silent == {
        "kind": "mocap_silent",
        "params": {},
        "duration_s": 1.0,
        "started_s": 10.0,
        "remaining_s": pytest.approx(0.25),
    }
    assert view_lost["params"] == {"body": "bar"} and view_lost["remaining_s"] is None
    [ended] = fault_set.expire(11.0)
    assert ended.fault == MocapSilent(1.0)
    assert fault_set.expire(1e6) == []
    assert [a.fault for a in fault_set.clear()] == [MocapBodyLost("bar")]
    assert fault_set.active == ()


def test_a_fault_on_the_same_target_replaces_the_old_one_its_timer_too() -> None:
    fault_set = faults(LinkLost(1, 1.0), LinkLost(2, 1.0), MocapJump("bar", (1, 0, 0), 1.0))
    started, replaced = fault_set.start(LinkLost(1, 5.0), 0.8)
    assert replaced is not None and replaced.fault == LinkLost(1, 1.0)
    assert started.ends_s == pytest.approx(5.8)
    _, replaced = fault_set.start(MocapJump("uav1", (0, 1, 0)), 0.8)
    assert replaced is None  # another body: both in effect
    assert {a.fault for a in fault_set.expire(1.0)} == {
        LinkLost(2, 1.0),
        MocapJump("bar", (1, 0, 0), 1.0),
    }
    assert {a.fault for a in fault_set.active} == {LinkLost(1, 5.0), MocapJump("uav1", (0, 1, 0))}


# ---- effects on frames ----
def test_no_fault_passes_frames_and_datagrams_untouched() -> None:
    fault_set = faults()
    frame = poses()
    assert fault_set.frame(frame) is frame
    assert all(fault_set.keep_mocap_packet(udp) for udp in (True, False))
    assert all(fault_set.keep_mavlink(v, inbound) for v in (1, 2) for inbound in (True, False))
    assert fault_set.powered(1) and fault_set.powered(2)


def test_mocap_silent_drops_every_data_packet_udp_and_tcp() -> None:
    fault_set = faults(MocapSilent())
    assert not fault_set.keep_mocap_packet(True) and not fault_set.keep_mocap_packet(False)
    assert all(fault_set.keep_mavlink(v, True) for v in (1, 2))  # mocap only


def test_mocap_body_lost_reports_that_body_untracked_as_qtm_does() -> None:
    reported = faults(MocapBodyLost("bar")).frame(poses())
    assert not reported["bar"].tracked
    assert np.isnan(reported["bar"].position_m).all() and np.isnan(reported["bar"].quaternion).all()
    assert reported["uav1"].tracked and reported["uav2"].tracked


def test_mocap_jump_offsets_the_position_only() -> None:
    measured = poses(0.5)
    reported = faults(MocapJump("uav2", (0.1, -0.2, 0.3))).frame(measured)
    np.testing.assert_allclose(reported["uav2"].position_m, [0.6, 1.8, 1.3])
    np.testing.assert_array_equal(reported["uav2"].quaternion, measured["uav2"].quaternion)
    np.testing.assert_array_equal(reported["bar"].position_m, measured["bar"].position_m)
    both = faults(MocapBodyLost("uav2"), MocapJump("uav2", (1, 0, 0))).frame(measured)
    assert not both["uav2"].tracked  # an untracked body stays untracked


def test_mocap_freeze_repeats_the_first_frame_after_it_began() -> None:
    fault_set = faults()
    fault_set.frame(poses(0.0))
    fault_set.start(MocapFreeze(1.0), 0.0)
    held = fault_set.frame(poses(0.1))
    for x_m in (0.2, 0.3):
        assert fault_set.frame(poses(x_m)) is held
    assert held["bar"].position_m[0] == pytest.approx(0.1)
    fault_set.expire(1.0)
    assert fault_set.frame(poses(0.4))["bar"].position_m[0] == pytest.approx(0.4)
    fault_set.start(MocapFreeze(), 1.0)  # a new freeze holds the frame after it
    assert fault_set.frame(poses(0.5))["bar"].position_m[0] == pytest.approx(0.5)
    assert fault_set.frame(poses(0.6))["bar"].position_m[0] == pytest.approx(0.5)


def test_frozen_frames_carry_what_was_reported_faults_included() -> None:
    fault_set = faults(MocapJump("bar", (1.0, 0, 0)), MocapFreeze())
    assert fault_set.frame(poses(0.0))["bar"].position_m[0] == pytest.approx(1.0)
    assert fault_set.frame(poses(0.2))["bar"].position_m[0] == pytest.approx(1.0)


# ---- effects on datagrams ----
def test_link_lost_drops_that_vehicles_mavlink_both_ways_only() -> None:
    fault_set = faults(LinkLost(1))
    assert not fault_set.keep_mavlink(1, True) and not fault_set.keep_mavlink(1, False)
    assert fault_set.keep_mavlink(2, True) and fault_set.keep_mavlink(2, False)
    assert fault_set.keep_mocap_packet(True) and fault_set.powered(1)


def test_a_rebooting_px4_is_unpowered_and_silent_until_its_boot_time_is_over() -> None:
    fault_set = faults(Px4Reboot(2), now_s=4.0)
    assert not fault_set.powered(2) and fault_set.powered(1)
    assert not fault_set.keep_mavlink(2, True) and not fault_set.keep_mavlink(2, False)
    fault_set.expire(4.0 + REBOOT_S - 0.01)
    assert not fault_set.powered(2)
    fault_set.expire(4.0 + REBOOT_S)
    assert fault_set.powered(2) and fault_set.keep_mavlink(2, True)


@pytest.mark.parametrize("fraction", [0.0, 0.3, 1.0])
def test_udp_loss_drops_that_fraction_of_udp_datagrams(fraction: float) -> None:
    fault_set = faults(UdpLoss(fraction))
    n = 20_000
    kept_mocap = sum(fault_set.keep_mocap_packet(True) for _ in range(n))
    kept_mavlink = sum(fault_set.keep_mavlink(1 + k % 2, k % 3 == 0) for k in range(n))
    for kept in (kept_mocap, kept_mavlink):
        assert 1.0 - kept / n == pytest.approx(fraction, abs=0.015)
    # TCP carries frames without loss (it retransmits).
    assert all(fault_set.keep_mocap_packet(False) for _ in range(100))


def test_udp_loss_is_reproducible_from_the_seed() -> None:
    def draws(seed: int) -> list[bool]:
        fault_set = FaultSet(BODIES, VEHICLES, seed)
        fault_set.start(UdpLoss(0.5), 0.0)
        return [fault_set.keep_mocap_packet(True) for _ in range(200)]

    assert draws(1) == draws(1) != draws(2)


def test_faults_are_frozen_values() -> None:
    with pytest.raises(dataclasses.FrozenInstanceError):
        LinkLost(1).vehicle = 2  # type: ignore[misc]


def test_a_push_is_a_load_on_the_plant_body_for_its_time() -> None:
    push = parse_fault(
        {"kind": "push", "body": "uav1", "force_n": [1, 0, -2], "duration_s": 2}, BODIES, VEHICLES
    )
    assert push == Push("uav1", (1, 0, -2), 2.0)
    steady = parse_fault({"kind": "push", "body": "bar", "force_n": [0, -50, 50]}, BODIES, VEHICLES)
    fault_set = faults(push, now_s=5.0)
    fault_set.start(steady, 6.0)
    plant_body = {"bar": "bar", "uav1": "uav2", "uav2": "uav1"}  # QTM's names → the plant's
    assert fault_set.loads(plant_body) == [
        ExternalLoad("uav2", (1, 0, -2), start_s=5.0, duration_s=2.0),
        ExternalLoad("bar", (0, -50, 50), start_s=6.0),
    ]
    fault_set.expire(7.0)
    assert [load.body for load in fault_set.loads(plant_body)] == ["bar"]
    # A push on the same body replaces it (its force and its timer).
    fault_set.start(Push("bar", (0.0, 0.0, 3.0)), 8.0)
    assert fault_set.loads(plant_body) == [ExternalLoad("bar", (0.0, 0.0, 3.0), start_s=8.0)]
