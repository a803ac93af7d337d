"""PX4's event catalog: loading libevents definitions, decoding arguments, rendering texts."""

from __future__ import annotations

import copy
import json
import lzma
import struct
from pathlib import Path
from typing import Any

import pytest

from px4_mavlink.events import (
    EventCatalog,
    EventCatalogError,
    encode_event_arguments,
    fallback_text,
    log_level_name,
)
from tests.supervisor.test_mavlink_px4_messages import decode_one

# PX4 v1.15.4's arming checks seen in the capture: sub id, name, message.
ARMING_CHECKS = (
    ("10450063", "check_modes_attitude", "No valid attitude estimate"),
    ("13835193", "check_modes_local_pos", "No valid local position estimate"),
    ("10011251", "check_modes_global_pos", "No valid global position estimate"),
    ("377561", "check_modes_mission", "No valid mission available"),
    ("3087815", "check_modes_offboard_signal", "No offboard signal"),
    ("453929", "check_modes_manual_control", "No manual control input"),
)
# An excerpt of PX4 v1.15.4's own definitions (etc/extras/all_events.json.xz of the SITL
# build; the real ids and messages, enums trimmed to the entries used here) and one
# definition of our own with libevents markup, "test_markup".
PX4_EVENTS_EXCERPT: dict[str, Any] = {
    "version": 2,
    "components": {
        "1": {
            "namespace": "px4",
            "enums": {
                "sensor_type_t": {
                    "type": "uint8_t",
                    "entries": {
                        "0": {"name": "accel", "description": "Accelerometer"},
                        "1": {"name": "gyro", "description": "Gyroscope"},
                    },
                },
                "sensor_failover_reason_t": {
                    "type": "uint16_t",
                    "is_bitfield": True,
                    "entries": {
                        "1": {"name": "no_data", "description": "No data"},
                        "2": {"name": "stale_data", "description": "Stale data"},
                        "4": {"name": "timeout", "description": "Timeout"},
                    },
                },
                "navigation_mode_t": {
                    "type": "uint8_t",
                    "entries": {
                        "4": {"name": "auto_loiter", "description": "Hold"},
                        "7": {"name": "offboard", "description": "Offboard"},
                    },
                },
                "navigation_mode_group_t": {
                    "type": "uint32_t",
                    "is_bitfield": True,
                    "entries": {
                        "16": {"name": "loiter", "description": "Loiter"},
                        "16384": {"name": "offboard", "description": "Offboard"},
                    },
                },
                "health_component_t": {
                    "type": "uint32_t",
                    "is_bitfield": True,
                    "entries": {"1": {"name": "none", "description": "None"}},
                },
            },
            "event_groups": {
                "default": {
                    "events": {
                        "1203183": {
                            "name": "logger_open_file_time",
                            "message": "logging: opening log file {1}-{2}-{3}/{4}_{5}_{6}.ulg",
                            "arguments": [
                                {"name": "arg0", "type": "uint16_t"},
                                *({"name": f"arg{k}", "type": "uint8_t"} for k in range(1, 6)),
                            ],
                        },
                        "133277": {
                            "name": "commander_arm_denied_resolve_failures",
                            "message": "Arming denied: Resolve system health failures first",
                        },
                        "12894058": {
                            "name": "sensor_failover",
                            "message": "{1} sensor #{2} failure: {3}",
                            "arguments": [
                                {"name": "arg0", "type": "px4::sensor_type_t"},
                                {"name": "arg1", "type": "uint8_t"},
                                {"name": "arg2", "type": "px4::sensor_failover_reason_t"},
                            ],
                        },
                        "15624514": {
                            "name": "check_above_wind_limits_warning",
                            "message": "Wind speed above limit ({1:.1m/s}), landing advised",
                            "arguments": [{"name": "arg0", "type": "float"}],
                        },
                        "10503063": {
                            "name": "commander_modeswitch_not_avail",
                            "type": "append_health_and_arming_messages",
                            "message": "Switching to mode '{2}' is currently not possible",
                            "arguments": [
                                {"name": "arg0", "type": "uint32_t"},
                                {"name": "arg1", "type": "px4::navigation_mode_t"},
                            ],
                        },
                        "3321936": {
                            "name": "navigator_mission_item_index_out_of_bounds",
                            "message": "Waypoint index out of bounds (current {1} \\>= total {2})",
                            "arguments": [
                                {"name": "arg0", "type": "int16_t"},
                                {"name": "arg1", "type": "int16_t"},
                            ],
                        },
                        "16777215": {
                            "name": "test_markup",
                            "message": (
                                'Set <param>COM_OBL_RC_ACT</param> to {1}{2m_v}<profile name="dev">'
                                ' (developers only)</profile><profile name="!dev">.</profile>'
                                ' See <a href="https://docs.px4.io">the docs</a> \\{1\\}'
                            ),
                            "arguments": [
                                {"name": "arg0", "type": "int32_t"},
                                {"name": "arg1", "type": "float"},
                            ],
                        },
                    }
                },
                "arming_check": {
                    "events": {
                        "11047904": {
                            "name": "commander_arming_check_summary",
                            "type": "summary",
                            "message": "Arming check summary event",
                            "arguments": [
                                {"name": "chunk_idx", "type": "uint8_t"},
                                {"name": "error", "type": "px4::health_component_t"},
                                {"name": "warning", "type": "px4::health_component_t"},
                                {"name": "can_arm", "type": "px4::navigation_mode_group_t"},
                                {"name": "can_run", "type": "px4::navigation_mode_group_t"},
                            ],
                        },
                        **{
                            sub: {
                                "name": name,
                                "message": message,
                                "arguments": [
                                    {"name": "modes", "type": "navigation_mode_group_t"},
                                    {"name": "health_component_index", "type": "uint8_t"},
                                ],
                            }
                            for sub, name, message in ARMING_CHECKS
                        },
                    }
                },
                "health": {
                    "events": {
                        "1914663": {
                            "name": "commander_health_summary",
                            "type": "summary",
                            "message": "Health report summary event",
                            "arguments": [
                                {"name": "chunk_idx", "type": "uint8_t"},
                                {"name": "is_present", "type": "px4::health_component_t"},
                                {"name": "error", "type": "px4::health_component_t"},
                                {"name": "warning", "type": "px4::health_component_t"},
                            ],
                        },
                        "15289843": {
                            "name": "check_avionics_power_high",
                            "message": "Avionics Power high: {3:.2} Volt",
                            "arguments": [
                                {"name": "modes", "type": "navigation_mode_group_t"},
                                {"name": "health_component_index", "type": "uint8_t"},
                                {"name": "arg0", "type": "float"},
                                {"name": "arg1", "type": "float"},
                            ],
                        },
                    }
                },
            },
            # AUTO.LOITER (custom_mode 0x03040000) is group 4, OFFBOARD (0x00060000) group 14.
            "navigation_mode_groups": {"groups": {"4": [50593792], "14": [393216]}},
        }
    },
}
SENSOR_FAILOVER = 0x01C4BF6A
WIND = (1 << 24) | 15624514
MODE_SWITCH = (1 << 24) | 10503063
AVIONICS = (1 << 24) | 15289843
MARKUP = (1 << 24) | 16777215
OUT_OF_BOUNDS = (1 << 24) | 3321936


def px4_catalog() -> EventCatalog:
    return EventCatalog.from_json(PX4_EVENTS_EXCERPT)


def test_real_px4_events_render_through_the_catalog() -> None:
    catalog = px4_catalog()
    denied = decode_one("event_arming_denied")
    assert catalog.text(denied.id, bytes(denied.arguments)) == (
        "Arming denied: Resolve system health failures first"
    )
    failover = decode_one("event_sensor_failover")  # an enum and a bitfield
    assert catalog.text(failover.id, bytes(failover.arguments)) == (
        "Accelerometer sensor #0 failure: Timeout"
    )
    logging = decode_one("event_logging")  # a uint16 and five uint8, unpadded
    event = catalog.decode(logging.id, bytes(logging.arguments))
    assert event.values == (2026, 12, 2, 0, 49, 50)
    assert event.text == "logging: opening log file 2026-12-2/0_49_50.ulg"
    check = decode_one("event_no_attitude")  # the leading mode groups are not in the text
    event = catalog.decode(check.id, bytes(check.arguments))
    assert event.group == "arming_check" and event.values == (0x7ED07E, 20)
    assert event.text == "No valid attitude estimate"
    assert log_level_name(check.log_levels) == "critical"
    summary = catalog.decode(*_id_args("event_arming_check_summary"))
    assert summary.kind == "summary" and summary.values[0] == 0


def _id_args(name: str) -> tuple[int, bytes]:
    message = decode_one(name)
    return int(message.id), bytes(message.arguments)


@pytest.mark.parametrize(
    ("event_id", "values", "text"),
    [
        (SENSOR_FAILOVER, (1, 2, 0b101), "Gyroscope sensor #2 failure: No data, Timeout"),
        (SENSOR_FAILOVER, (9, 0, 0x22), "9 sensor #0 failure: Stale data, 0x20"),  # unknowns
        (WIND, (12.345,), "Wind speed above limit (12.3 m/s), landing advised"),
        (MODE_SWITCH, (0, 4), "Switching to mode 'Hold' is currently not possible"),
        (AVIONICS, (16, 20, 5.7, 5.5), "Avionics Power high: 5.70 Volt"),
        (OUT_OF_BOUNDS, (7, -3), "Waypoint index out of bounds (current 7 >= total -3)"),
        (MARKUP, (4, 2.5), "Set COM_OBL_RC_ACT to 42.5 m. See the docs {1}"),
    ],
)
def test_arguments_are_encoded_and_rendered(
    event_id: int, values: tuple[float, ...], text: str
) -> None:
    catalog = px4_catalog()
    arguments = encode_event_arguments(catalog, event_id, values)
    assert catalog.text(event_id, arguments) == text


def test_arguments_are_packed_little_endian_without_padding() -> None:
    catalog = px4_catalog()
    assert encode_event_arguments(catalog, SENSOR_FAILOVER, (0, 0, 4)) == b"\x00\x00\x04\x00"
    assert encode_event_arguments(catalog, AVIONICS, (16, 20, 1.0, 2.0)) == (
        struct.pack("<IBff", 16, 20, 1.0, 2.0)
    )


def test_bad_arguments_are_refused() -> None:
    catalog = px4_catalog()
    with pytest.raises(EventCatalogError, match="takes 3 arguments"):
        encode_event_arguments(catalog, SENSOR_FAILOVER, (0, 0))
    with pytest.raises(EventCatalogError, match="sensor_failover"):
        encode_event_arguments(catalog, SENSOR_FAILOVER, (0, 300, 0))  # uint8 overflow
    with pytest.raises(EventCatalogError, match="unknown event"):
        encode_event_arguments(catalog, 0x0ABCDEF0, ())


def test_an_unknown_event_has_a_clear_fallback_text() -> None:
    catalog = px4_catalog()
    event = catalog.decode(0x0ABCDEF0, b"\x01\x02")
    assert event.definition is None
    assert event.text == "PX4 event 0x0abcdef0 (component 10, sub id 12377840)"
    assert event.text == fallback_text(0x0ABCDEF0)


def test_a_definition_with_an_unknown_type_falls_back_without_raising() -> None:
    document = copy.deepcopy(PX4_EVENTS_EXCERPT)
    events = document["components"]["1"]["event_groups"]["default"]["events"]
    events["12894058"]["arguments"][0]["type"] = "px4::no_such_enum"
    catalog = EventCatalog.from_json(document)
    assert catalog.text(SENSOR_FAILOVER, b"") == ("{1} sensor #{2} failure: {3} (0x1c4bf6a)")


def test_the_catalog_loads_json_and_json_xz_files(tmp_path: Path) -> None:
    raw = json.dumps(PX4_EVENTS_EXCERPT).encode()
    (tmp_path / "events.json").write_bytes(raw)
    (tmp_path / "events.json.xz").write_bytes(lzma.compress(raw))
    plain = EventCatalog.load(tmp_path / "events.json")
    packed = EventCatalog.load(tmp_path / "events.json.xz")
    assert plain == packed == px4_catalog()
    assert len(plain.events) == 16 and plain.namespaces == {1: "px4"}
    assert plain.mode_groups == {0x03040000: 1 << 4, 0x00060000: 1 << 14}
    assert plain.find("px4::sensor_failover").event_id == SENSOR_FAILOVER


@pytest.mark.parametrize(
    "data",
    [b"", b"not json", b"\xfd7zXZ\x00broken", b'{"components": {"1": {}}}', b"[]"],
)
def test_a_bad_definitions_file_is_a_catalog_error(data: bytes) -> None:
    with pytest.raises(EventCatalogError):
        EventCatalog.from_bytes(data)
