"""The sequences the flight process runs over every vehicle: arming the PX4 way, disarming
after a landing, killing, and checking or setting the parameters a flight relies on.

PX4 enters offboard only after setpoints have streamed for more than a second at more than
2 Hz (docs/reference/px4-offboard.md §2.3), so arming starts the idle stream first, waits out
that proof of life, then selects offboard and arms each vehicle, checking every acknowledgement. A
vehicle that refuses leaves both disarmed.
"""

from __future__ import annotations

import asyncio
import math
from collections.abc import Mapping

from supervisor.vehicles.link import VehicleLink
from supervisor.vehicles.types import VehicleCommandError

PROOF_OF_LIFE_S = 1.2


async def _each(links: tuple[VehicleLink, ...], action: str) -> list[str]:
    """Run ``action`` on every link at once; the failures, as 'vehicle i: reason'."""
    results = await asyncio.gather(
        *(getattr(link, action)() for link in links), return_exceptions=True
    )
    return [
        f"vehicle {i}: {result}"
        for i, result in enumerate(results, start=1)
        if isinstance(result, BaseException)
    ]


async def arm_for_offboard(links: tuple[VehicleLink, ...], proof_of_life_s: float) -> list[str]:
    """Offboard then arm on every vehicle; the caller already streams idle setpoints. On any
    failure both are disarmed again; returns the failures (empty: all armed)."""
    disconnected = [
        f"vehicle {i}: no link" for i, link in enumerate(links, 1) if not link.connected
    ]
    if disconnected:
        return disconnected
    await asyncio.sleep(proof_of_life_s)
    failures = await _each(links, "set_offboard")
    if not failures:
        failures = await _each(links, "arm")
    if failures:
        await _each(links, "disarm")
    return failures


async def _disarm_landed(link: VehicleLink) -> None:
    """Disarm a vehicle the motion capture shows on the ground. PX4 refuses a normal disarm
    while its own land detector still says airborne (it lags a second or two after
    touch-down); on the ground a forced disarm is safe, and waiting would leave it armed
    with motors idling next to people."""
    try:
        await link.disarm()
    except VehicleCommandError:
        await link.kill()


async def disarm_all(links: tuple[VehicleLink, ...]) -> list[str]:
    """Disarm every landed vehicle (forced if PX4 refuses) and leave offboard; returns the
    failures."""
    results = await asyncio.gather(
        *(_disarm_landed(link) for link in links), return_exceptions=True
    )
    failures = [
        f"vehicle {i}: {result}"
        for i, result in enumerate(results, start=1)
        if isinstance(result, BaseException)
    ]
    return failures + await _each(links, "set_hold")


async def land_all(links: tuple[VehicleLink, ...]) -> list[str]:
    """Hand every vehicle to its own landing at once; returns the failures."""
    return await _each(links, "land")


async def kill_all(links: tuple[VehicleLink, ...]) -> list[str]:
    """Force-disarm every vehicle at once; returns the failures."""
    return await _each(links, "kill")


def _show(value: float) -> str:
    """A parameter value as a person writes it: 4, 1.0 → 1, 0.5."""
    return f"{value:g}"


def _same(actual: float, expected: float) -> bool:
    """Equal as PX4 stores them: exactly for integers, to float32 precision otherwise."""
    return math.isclose(actual, expected, rel_tol=1e-6, abs_tol=1e-9)


async def _check_one(index: int, link: VehicleLink, expected: Mapping[str, float]) -> list[str]:
    problems = []
    for name, want in expected.items():
        try:
            actual = await link.read_parameter(name)
        except VehicleCommandError as error:
            problems.append(f"vehicle {index}: {name} unreadable ({error})")
            continue
        if not _same(actual, want):
            problems.append(f"vehicle {index}: {name} is {_show(actual)}, expected {_show(want)}")
    return problems


async def check_failsafe_parameters(
    links: tuple[VehicleLink, ...],
    expected: Mapping[str, float],
    vehicles: tuple[int, ...] | None = None,
) -> list[str]:
    """Read every parameter of ``expected`` on every vehicle (all at once) and name each one
    that differs or cannot be read, e.g. "vehicle 1: COM_OBL_RC_ACT is 0, expected 4". An
    empty list: all as expected. Which parameters and values matter is the caller's choice
    (the failsafes a flight relies on: COM_OF_LOSS_T, COM_OBL_RC_ACT, …). ``vehicles``
    numbers the links (None: 1, 2, …)."""
    numbers = vehicles or tuple(range(1, len(links) + 1))
    results = await asyncio.gather(
        *(_check_one(i, link, expected) for i, link in zip(numbers, links, strict=True))
    )
    return [problem for problems in results for problem in problems]


async def _apply_one(index: int, link: VehicleLink, values: Mapping[str, float]) -> list[str]:
    problems = []
    for name, value in values.items():
        try:
            await link.set_parameter(name, value)
        except VehicleCommandError as error:
            problems.append(f"vehicle {index}: {error}")
    return problems


async def apply_parameters(
    links: tuple[VehicleLink, ...], values: Mapping[str, float]
) -> list[str]:
    """Set every parameter of ``values`` on every vehicle, each verified by the vehicle's
    echo; returns the failures (empty: all set)."""
    results = await asyncio.gather(
        *(_apply_one(i, link, values) for i, link in enumerate(links, start=1))
    )
    return [problem for problems in results for problem in problems]
