"""The fault table's figures (docs/safety.md, docs/agents.md): each fault from a stable
hover on the embedded simulator, one ``serve`` per case — what the supervisor did, when,
and what the world saw (sim/truth.py: the worst UAV tilt, the fastest descent above 0.2 m,
of every body and of each).

    python -m benchmarks.faults [--json] [--case NAME ...] [--repeat N]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import signal
import sys
import tempfile
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx

from benchmarks.service import RunningService, all_disarmed, in_mode, notices, running_service
from benchmarks.tick import world_truth
from supervisor.flight.modes import Mode
from supervisor.flight.status import Status
from supervisor.logs.flight_log import read_flight_log

TOKEN = "faults-benchmark-token"
Case = Callable[[RunningService, httpx.AsyncClient], Awaitable[dict[str, Any]]]


async def hover(service: RunningService, http: httpx.AsyncClient) -> Path:
    """Take off and hover 2 s; the flight's log."""
    status = await service.take_off(http, again_after_world_stall=False)
    await asyncio.sleep(2.0)
    assert status.log is not None, "no flight log"
    return Path(status.log)


async def inject(http: httpx.AsyncClient, **fault: Any) -> float:
    response = await http.post("/api/sim/faults", json=fault)
    response.raise_for_status()
    return time.monotonic()


async def until_down(service: RunningService, http: httpx.AsyncClient) -> Status:
    """Land if still flying; the status once disarmed."""
    status = await service.status(http)
    if status.mode in (Mode.HOVER, Mode.TRACKING):
        (await http.post("/api/land")).raise_for_status()
    return await service.wait_for(http, in_mode(Mode.DISARMED), 90.0, "on the ground")


def said(status: Status) -> str:
    return " | ".join(notices(status)) or "-"


def mocap_silent(duration_s: float) -> Case:
    async def case(service: RunningService, http: httpx.AsyncClient) -> dict[str, Any]:
        log_path = await hover(service, http)
        injected = await inject(http, kind="mocap_silent", duration_s=duration_s)
        if duration_s < 1.0:
            await asyncio.sleep(1.0)
            status = await service.status(http)
            return {"mode_after_1s": status.mode.value, "notices": said(status)}
        await service.wait_for(
            http,
            lambda s: all(u.px4_mode == "AUTO.LAND" for u in s.uavs),
            5.0,
            "every PX4 landing",
        )
        both_landing_s = time.monotonic() - injected
        status = await until_down(service, http)
        log = read_flight_log(log_path)
        handed = log.modes.index("px4_landing")
        return {
            "mocap_age_at_hand_over_ms": round(float(log.mocap_age_ms[handed]), 1),
            "both_in_auto_land_after_s": round(both_landing_s, 2),
            "notices": said(status),
        }

    return case


def frozen_flight_process(freeze_s: float) -> Case:
    async def case(service: RunningService, http: httpx.AsyncClient) -> dict[str, Any]:
        await hover(service, http)
        flight = service.child_pid("uavbar-flight")
        os.kill(flight, signal.SIGSTOP)
        await asyncio.sleep(freeze_s)
        os.kill(flight, signal.SIGCONT)
        await asyncio.sleep(3.0)
        mode = (await service.status(http)).mode.value
        status = await until_down(service, http)
        failsafe_setpoints = sum("arrived in its failsafe" in line for line in service.output)
        return {
            "mode_3s_after": mode,
            "setpoints_to_a_vehicle_in_failsafe": failsafe_setpoints,
            "notices": said(status),
        }

    return case


async def link_lost(service: RunningService, http: httpx.AsyncClient) -> dict[str, Any]:
    """Vehicle 1's link lost for good: what the connected one does with the bar."""
    await hover(service, http)
    injected = await inject(http, kind="link_lost", vehicle=1)
    # Disarming, not disarmed, while vehicle 1 is unheard: it may still be armed.
    status = await service.wait_for(http, in_mode(Mode.DISARMING), 90.0, "down")
    down_s = time.monotonic() - injected
    (await http.delete("/api/sim/faults")).raise_for_status()
    await service.wait_for(http, all_disarmed, 30.0, "both disarmed, the link back")
    return {"down_after_s": round(down_s, 1), "notices": said(status)}


async def killed_agent(service: RunningService, http: httpx.AsyncClient) -> dict[str, Any]:
    """The last vehicle's agent killed (``agents.enabled``): the others set the payload
    down while its PX4's failsafe lands its vehicle."""
    agents = await service.wait_for(
        http,
        lambda s: s.agents is not None and all(a.alive for a in s.agents),
        60.0,
        "every agent alive",
    )
    assert agents.agents is not None
    last_pid = agents.agents[-1].pid
    assert last_pid is not None, "the last agent's pid is not known"
    await service.take_off(http, again_after_world_stall=False)
    await asyncio.sleep(2.0)
    os.kill(last_pid, signal.SIGKILL)
    killed = time.monotonic()
    status = await service.wait_for(
        http, in_mode(Mode.DISARMING, Mode.DISARMED), 60.0, "the others down"
    )
    return {"down_after_s": round(time.monotonic() - killed, 1), "notices": said(status)}


async def killed_flight_process(service: RunningService, http: httpx.AsyncClient) -> dict[str, Any]:
    await hover(service, http)
    os.kill(service.child_pid("uavbar-flight"), signal.SIGKILL)
    killed = time.monotonic()
    await service.wait_for(
        http,
        lambda s: s.processes["flight"].restarts == 1 and not s.stale,
        30.0,
        "the flight process back",
    )
    back_s = time.monotonic() - killed
    refused = await http.post("/api/arm")
    status = await service.wait_for(http, all_disarmed, 60.0, "every PX4 disarmed")
    return {
        "flight_process_back_after_s": round(back_s, 2),
        "arm_while_landing": refused.status_code,
        "both_disarmed_after_s": round(time.monotonic() - killed, 1),
        "notices": said(status),
    }


async def killed_api_process(service: RunningService, http: httpx.AsyncClient) -> dict[str, Any]:
    """The API process frozen: the terminal client's abort goes straight to the flight
    process; then the API process killed and back."""
    await hover(service, http)
    api = service.child_pid("uavbar-api")
    os.kill(api, signal.SIGSTOP)
    started = time.monotonic()
    client = await asyncio.create_subprocess_exec(
        sys.executable,
        *("-m", "supervisor.cli.main", "abort", "--url", service.url, "--json"),
        env={**os.environ, "UAVBAR_TOKEN": TOKEN},
        stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.DEVNULL,
    )
    out, _ = await client.communicate()
    cli_s = time.monotonic() - started
    os.kill(api, signal.SIGKILL)
    killed = time.monotonic()
    await service.wait_for(http, lambda s: s.processes["api"].restarts == 1, 30.0, "the API back")
    back_s = time.monotonic() - killed
    status = await until_down(service, http)
    answer = json.loads(out or b"{}")
    return {
        "direct_abort_exchange_ms": round(answer.get("took_s", float("nan")) * 1e3, 1),
        "abort_command_wall_s": round(cli_s, 2),
        "api_back_after_s": round(back_s, 2),
        "notices": said(status),
    }


async def displaced_arm(service: RunningService, http: httpx.AsyncClient) -> dict[str, Any]:
    await service.wait_for(http, lambda s: s.mocap.healthy, 60.0, "healthy mocap")
    await inject(http, kind="mocap_jump", body="uav1", offset_m=[1.0, 0.0, 0.0])
    await asyncio.sleep(0.5)
    refused = await http.post("/api/arm")
    return {"arm_status": refused.status_code, "reason": refused.json().get("detail")}


@dataclass(frozen=True)
class Served:
    """How ``serve`` runs for a case: its setup (``--config``; serve's default without)
    and its ``--set`` overrides."""

    setup: str | None = None
    overrides: tuple[str, ...] = ()


AGENTS = ("agents.enabled=true",)
CASES: dict[str, tuple[Case, Served]] = {
    "mocap_silent_0.05s": (mocap_silent(0.05), Served()),
    "mocap_silent_5s": (mocap_silent(5.0), Served()),
    "sigstop_flight_0.3s": (frozen_flight_process(0.3), Served()),
    "sigstop_flight_1s": (frozen_flight_process(1.0), Served()),
    "sigstop_flight_5s": (frozen_flight_process(5.0), Served()),
    "link_lost_uav1": (link_lost, Served()),
    "sigkill_agent_2_of_2": (killed_agent, Served(overrides=AGENTS)),
    "sigkill_agent_3_of_3": (killed_agent, Served("sim_tri", AGENTS)),
    "sigkill_flight": (killed_flight_process, Served()),
    "sigkill_api": (killed_api_process, Served()),
    "arm_with_uav1_1m_away": (displaced_arm, Served()),
}
TRUTH = ("min_tension_hanging_n", "slack_events", "max_uav_tilt_deg", "max_descent_mps")


async def run(name: str) -> dict[str, Any]:
    case, served = CASES[name]
    with tempfile.TemporaryDirectory() as scratch:
        async with (
            running_service(TOKEN, Path(scratch), served.overrides, setup=served.setup) as service,
            service.client() as http,
        ):
            result = await case(service, http)
        truth = world_truth(service.output)
    return {
        "case": name,
        **result,
        **{k: v for k, v in truth.items() if k in TRUTH or k.startswith("max_descent_")},
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--case", action="append", choices=sorted(CASES), default=None)
    parser.add_argument("--repeat", type=int, default=1, metavar="N", help="runs of each case")
    args = parser.parse_args(argv)
    for name in args.case or list(CASES):
        for k in range(args.repeat):
            print(f"# {name} ({k + 1}/{args.repeat}) …", file=sys.stderr, flush=True)
            result = asyncio.run(run(name))
            line = "  ".join(f"{key}={value}" for key, value in result.items())
            print(json.dumps(result) if args.json else line, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
