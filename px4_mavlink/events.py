"""PX4's event catalog (libevents definitions) and the text of an EVENT, without I/O.

PX4 reports arming refusals, failsafes and health as EVENT messages that carry only an id and
packed arguments (docs/reference/px4-offboard.md §5 item 5); the words are in a definitions
file built with the firmware (``etc/extras/all_events.json.xz``, libevents format version 2):
``components`` (keyed by component id) → ``namespace``, ``enums`` and ``event_groups`` →
``events`` keyed by sub id, each with a ``name``, a one-line ``message`` template and its
``arguments``. An event's id is ``component id << 24 | sub id``.

Templates follow libevents (``README.md`` of mavlink/libevents): 1-based arguments
``{N[:.DIGITS][UNIT]}`` (units ``m``, ``m_v``, ``m^2``, ``m/s``, ``C`` …); ``\\`` escapes;
tags ``<param>``, ``<a>`` (their content kept) and ``<profile name="[!]NAME">`` (content shown
only for the ``normal`` profile, as a ground station user sees it). Arguments are serialized
in order, little-endian, unpadded; an enum argument is shown by its entry's description, a
bitfield by those of its set bits. The health and arming-check events begin with a
navigation-mode-group bitfield and a health-component index that their texts do not show.
"""

from __future__ import annotations

import json
import lzma
import math
import re
import struct
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

EVENT_ARGUMENTS_LEN = 40
PROFILE = "normal"  # libevents profiles: "dev" content is for developers

# libevents log levels (the low nibble of EVENT.log_levels is the one a ground station shows).
LOG_LEVELS = (
    "emergency",
    "alert",
    "critical",
    "error",
    "warning",
    "notice",
    "info",
    "debug",
    "protocol",
    "disabled",
)
LOG_LEVEL_ERROR = 3
LOG_LEVEL_PROTOCOL = 8  # "should not be shown" (libevents), nor anything above

# struct codes of libevents' base argument types.
BASE_TYPES = {
    "uint8_t": "B",
    "int8_t": "b",
    "uint16_t": "H",
    "int16_t": "h",
    "uint32_t": "I",
    "int32_t": "i",
    "uint64_t": "Q",
    "int64_t": "q",
    "float": "f",
}
UNITS = {"m": "m", "m_v": "m", "m^2": "m²", "m/s": "m/s", "m/s_v": "m/s", "C": "°C"}

Value = int | float


class EventCatalogError(ValueError):
    """A definitions file, an event id or arguments that do not fit the catalog."""


@dataclass(frozen=True)
class EventEnum:
    """An enum (or bitfield) of a namespace: its base type and ``value → (name, description)``."""

    name: str
    base_type: str
    entries: Mapping[int, tuple[str, str]]
    is_bitfield: bool = False

    def describe(self, value: int) -> str:
        """An entry's description (its name when the description is empty); a bitfield's set
        bits joined with ", "; an unknown value as the number."""
        if not self.is_bitfield:
            return self._entry(value) if value in self.entries else str(value)
        bits = [bit for bit in sorted(self.entries) if bit and value & bit == bit]
        rest = value & ~sum(bits)
        words = [self._entry(bit) for bit in bits] + ([hex(rest)] if rest else [])
        return ", ".join(words) if words else self._entry(0) if 0 in self.entries else "none"

    def _entry(self, value: int) -> str:
        name, description = self.entries[value]
        return description or name


@dataclass(frozen=True)
class EventArgument:
    """One argument: its name and type (a base type or an enum, maybe ``namespace::``d)."""

    name: str
    type: str


@dataclass(frozen=True)
class EventDefinition:
    """One event: ``event_id`` = component id << 24 | sub id."""

    event_id: int
    namespace: str
    group: str
    name: str
    message: str
    arguments: tuple[EventArgument, ...] = ()
    kind: str = ""  # libevents' optional "type": "summary", "append_health_and_arming_messages"


@dataclass(frozen=True)
class DecodedEvent:
    """An EVENT's id, what the catalog knows of it (None: unknown id), its argument values
    (raw numbers; enums as their integer) and its text."""

    event_id: int
    definition: EventDefinition | None
    values: tuple[Value, ...]
    text: str

    @property
    def group(self) -> str:
        return self.definition.group if self.definition else ""

    @property
    def kind(self) -> str:
        return self.definition.kind if self.definition else ""


@dataclass(frozen=True)
class EventCatalog:
    """The events and enums of a libevents definitions file."""

    events: Mapping[int, EventDefinition]
    enums: Mapping[str, EventEnum]  # keyed "namespace::name"
    namespaces: Mapping[int, str] = field(default_factory=dict)
    mode_groups: Mapping[int, int] = field(default_factory=dict)
    """PX4's navigation mode groups: custom_mode → the group's bit (``navigation_mode_groups``)."""

    # ---- loading ----------------------------------------------------------------------------
    @classmethod
    def load(cls, path: str | Path) -> EventCatalog:
        """Read a definitions file (``.json`` or ``.json.xz``); done once, at start-up."""
        data = Path(path).read_bytes()
        return cls.from_bytes(data)

    @classmethod
    def from_bytes(cls, data: bytes) -> EventCatalog:
        """Parse a definitions file's bytes, xz-compressed or not."""
        if data[:6] == b"\xfd7zXZ\x00":
            try:
                data = lzma.decompress(data)
            except lzma.LZMAError as error:
                raise EventCatalogError(f"not an xz file: {error}") from error
        try:
            document = json.loads(data)
        except (UnicodeDecodeError, json.JSONDecodeError) as error:
            raise EventCatalogError(f"not JSON: {error}") from error
        return cls.from_json(document)

    @classmethod
    def from_json(cls, document: Mapping[str, Any]) -> EventCatalog:
        """Build the catalog from a parsed definitions document."""
        try:
            return _parse(document)
        except (KeyError, TypeError, ValueError, AttributeError) as error:
            raise EventCatalogError(f"bad event definitions: {error!r}") from error

    # ---- use ----------------------------------------------------------------------------------
    def definition(self, event_id: int) -> EventDefinition | None:
        return self.events.get(event_id)

    def enum_of(self, definition: EventDefinition, type_name: str) -> EventEnum | None:
        """The enum an argument type names (``ns::name``, else the event's own namespace)."""
        if type_name in BASE_TYPES:
            return None
        key = type_name if "::" in type_name else f"{definition.namespace}::{type_name}"
        return self.enums.get(key)

    def base_type(self, definition: EventDefinition, type_name: str) -> str:
        enum = self.enum_of(definition, type_name)
        base = enum.base_type if enum is not None else type_name
        if base not in BASE_TYPES:
            raise EventCatalogError(f"{definition.name}: unknown argument type {type_name}")
        return base

    def decode(self, event_id: int, arguments: bytes) -> DecodedEvent:
        """The values and text of an EVENT; never raises (unknown or short: a fallback)."""
        definition = self.events.get(event_id)
        if definition is None:
            return DecodedEvent(event_id, None, (), fallback_text(event_id))
        try:
            fmt = "<" + "".join(
                BASE_TYPES[self.base_type(definition, a.type)] for a in definition.arguments
            )
            padded = bytes(arguments).ljust(struct.calcsize(fmt), b"\x00")
            values: tuple[Value, ...] = struct.unpack_from(fmt, padded)
            text = render(self, definition, values)
        except (EventCatalogError, struct.error):
            return DecodedEvent(event_id, definition, (), f"{definition.message} ({event_id:#x})")
        return DecodedEvent(event_id, definition, values, text)

    def text(self, event_id: int, arguments: bytes) -> str:
        """An EVENT's text (``decode(...).text``)."""
        return self.decode(event_id, arguments).text

    def find(self, name: str) -> EventDefinition:
        """An event by ``name`` or ``namespace::name``."""
        namespace, _, short = name.rpartition("::")
        for definition in self.events.values():
            if definition.name == short and namespace in ("", definition.namespace):
                return definition
        raise EventCatalogError(f"no event named {name}")


def fallback_text(event_id: int) -> str:
    """What an event without definition says: its id, component and sub id."""
    return f"PX4 event {event_id:#010x} (component {event_id >> 24}, sub id {event_id & 0xFFFFFF})"


def encode_event_arguments(catalog: EventCatalog, event_id: int, values: Sequence[Value]) -> bytes:
    """The packed arguments of ``event_id`` for ``values`` (one per argument, in order;
    enums as their integer values), as PX4 sends them. Raises ``EventCatalogError``."""
    definition = catalog.definition(event_id)
    if definition is None:
        raise EventCatalogError(f"unknown event {event_id:#x}")
    if len(values) != len(definition.arguments):
        raise EventCatalogError(
            f"{definition.name} takes {len(definition.arguments)} arguments, not {len(values)}"
        )
    fmt = "<" + "".join(
        BASE_TYPES[catalog.base_type(definition, a.type)] for a in definition.arguments
    )
    try:
        packed = struct.pack(fmt, *values)
    except struct.error as error:
        raise EventCatalogError(f"{definition.name}: {error}") from error
    if len(packed) > EVENT_ARGUMENTS_LEN:
        raise EventCatalogError(f"{definition.name}: arguments exceed {EVENT_ARGUMENTS_LEN} bytes")
    return packed


def log_level_name(log_levels: int) -> str:
    """The external (ground-station) level of an EVENT's ``log_levels`` byte."""
    level = log_levels & 0x0F
    return LOG_LEVELS[level] if level < len(LOG_LEVELS) else f"level {level}"


# ---- rendering ----------------------------------------------------------------------------------
_TOKEN = re.compile(
    r"\\(?P<escaped>.)"
    r"|\{(?P<index>\d+)(?::\.(?P<digits>\d+))?(?P<unit>[^}]*)\}"
    r"|<(?P<close>/?)(?P<tag>[a-z]+)(?P<attributes>[^>]*)>",
    re.DOTALL,
)
_PROFILE_NAME = re.compile(r'name="(!?)([^"]*)"')


def render(catalog: EventCatalog, definition: EventDefinition, values: Sequence[Value]) -> str:
    """The event's message with its arguments put in, markup resolved."""
    out: list[str] = []
    hidden = False  # inside a profile this user does not see (profiles do not nest)
    position = 0
    template = definition.message
    for match in _TOKEN.finditer(template):
        if not hidden:
            out.append(template[position : match.start()])
        position = match.end()
        if match["escaped"] is not None:
            if not hidden:
                out.append(match["escaped"])
        elif match["index"] is not None:
            if not hidden:
                out.append(_argument(catalog, definition, values, match))
        elif match["tag"] == "profile":
            if match["close"]:
                hidden = False
            else:
                negate, name = _profile(match["attributes"])
                hidden = (name == PROFILE) if negate else (name != PROFILE)
        # <param>, <a>: keep the content, drop the tags; unknown tags likewise
    if not hidden:
        out.append(template[position:])
    return " ".join("".join(out).split())


def _profile(attributes: str) -> tuple[bool, str]:
    found = _PROFILE_NAME.search(attributes)
    return (found[1] == "!", found[2]) if found else (False, "")


def _argument(
    catalog: EventCatalog,
    definition: EventDefinition,
    values: Sequence[Value],
    match: re.Match[str],
) -> str:
    index = int(match["index"]) - 1
    if not 0 <= index < len(values) or index >= len(definition.arguments):
        return match[0]
    value = values[index]
    enum = catalog.enum_of(definition, definition.arguments[index].type)
    if enum is not None and isinstance(value, int):
        text = enum.describe(value)
    elif match["digits"] is not None:
        text = f"{float(value):.{int(match['digits'])}f}"
    elif isinstance(value, float):
        text = f"{value:g}" if math.isfinite(value) else str(value)
    else:
        text = str(value)
    unit = match["unit"].strip()
    return f"{text} {UNITS.get(unit, unit)}" if unit else text


# ---- parsing the definitions ----------------------------------------------------------------
def _parse(document: Mapping[str, Any]) -> EventCatalog:
    components = document["components"]
    events: dict[int, EventDefinition] = {}
    enums: dict[str, EventEnum] = {}
    namespaces: dict[int, str] = {}
    mode_groups: dict[int, int] = {}
    for component_key, component in components.items():
        component_id = int(component_key)
        if not 0 <= component_id <= 0xFF:
            raise ValueError(f"component id {component_id}")
        namespace = str(component["namespace"])
        namespaces[component_id] = namespace
        for enum_name, enum in component.get("enums", {}).items():
            enums[f"{namespace}::{enum_name}"] = EventEnum(
                name=enum_name,
                base_type=str(enum["type"]),
                entries={
                    int(value): (str(entry.get("name", "")), str(entry.get("description", "")))
                    for value, entry in enum.get("entries", {}).items()
                },
                is_bitfield=bool(enum.get("is_bitfield", False)),
            )
        for group_name, group in component.get("event_groups", {}).items():
            for sub_key, event in group.get("events", {}).items():
                sub_id = int(sub_key)
                if not 0 <= sub_id <= 0xFFFFFF:
                    raise ValueError(f"sub id {sub_id}")
                event_id = (component_id << 24) | sub_id
                events[event_id] = EventDefinition(
                    event_id=event_id,
                    namespace=namespace,
                    group=str(group_name),
                    name=str(event["name"]),
                    message=str(event.get("message", "")),
                    arguments=tuple(
                        EventArgument(str(a["name"]), str(a["type"]))
                        for a in event.get("arguments", [])
                    ),
                    kind=str(event.get("type", "")),
                )
        groups = component.get("navigation_mode_groups", {}).get("groups", {})
        for bit, custom_modes in groups.items():
            for custom_mode in custom_modes:
                mode_groups[int(custom_mode)] = 1 << int(bit)
    return EventCatalog(events, enums, namespaces, mode_groups)
