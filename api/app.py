"""The REST API and telemetry WebSocket, on the flight process's command interface.

``create_app`` takes everything as arguments (no settings read at import). Mutating routes
need ``Authorization: Bearer TOKEN`` (401 otherwise); a body that does not validate gets
422 with the reason; a request the flight modes or the queue refuse gets 409 with the
reason; no flight process answering gets 503.

``/api/sim/*`` reaches the simulated world's process (fault injection and the world reset,
docs/faults.md), only when ``serve`` started the world itself (``sim.embedded``): else the
mutating ones are 409 with the reason, checked right after the token and before the body.
"""

from __future__ import annotations

import contextlib
import math
import secrets
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any

import pydantic_core
from fastapi import (
    APIRouter,
    Depends,
    FastAPI,
    Header,
    HTTPException,
    Query,
    Request,
    WebSocket,
    WebSocketDisconnect,
)
from fastapi import params as fastapi_params
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse, Response
from fastapi.staticfiles import StaticFiles

from api.models import KillRequest, ModeBody, SetpointBody
from controllers.equilibria import EquilibriumError
from controllers.params import BarSystemParams
from supervisor.flight.equilibrium_summary import equilibrium_summary
from supervisor.flight.operator_requests import (
    ClearSetpointsRequest,
    ControllerRequest,
    ModeRequest,
    OperatorEvent,
    Outcome,
    QueueRequest,
    Reply,
    SetpointsQuery,
)
from supervisor.flight.setpoints import Arena, SetpointError, validate_setpoints
from supervisor.ipc.client import FlightClient, SubscriptionEndedError
from supervisor.ipc.world_client import WorldClient
from supervisor.ipc.world_messages import (
    ClearFaults,
    FaultSpec,
    ListFaults,
    ResetWorld,
    StartFault,
    WorldRequest,
)

STATIC_DIR = Path(__file__).resolve().parent / "static"
HTTP_STATUS = {
    Outcome.OK: 200,
    Outcome.REFUSED: 409,
    Outcome.INVALID: 422,
    Outcome.UNAVAILABLE: 503,
}
TELEMETRY_STALE_S = 0.5
NOT_EMBEDDED = (
    "the simulated world is not embedded (sim.embedded is false): serve did not start a "
    "simulated world, so there is nothing to inject faults into or reset"
)


def _json_text(value: Any) -> str:
    """JSON without NaN (JSON has none): non-finite numbers become null."""
    return pydantic_core.to_json(value, inf_nan_mode="null").decode()


def _answer(reply: Reply) -> JSONResponse:
    if reply.ok:
        return JSONResponse({"accepted": True, **reply.data})
    return JSONResponse(
        {"accepted": False, "detail": reply.reason, **reply.data},
        status_code=HTTP_STATUS[reply.outcome],
    )


def create_app(
    flight: FlightClient,
    params: BarSystemParams,
    arena: Arena,
    token: str,
    world: WorldClient | None = None,
    processes: Callable[[], dict[str, Any]] | None = None,
) -> FastAPI:
    """The FastAPI application serving ``flight`` (``params`` and ``arena``: the system and
    its flight volume, for the equilibria it reports and the setpoints it checks) and, when
    ``serve`` runs the simulated world itself, ``world``; ``processes``: serve's process
    table for the status."""
    app = FastAPI(
        title="uavbar-supervisor",
        summary="Two PX4 quadrotors carrying a bar under MPC: arm, fly, queue setpoints, abort.",
        version="0.1.0",
    )

    @app.exception_handler(RequestValidationError)
    async def invalid_body(request: Request, error: RequestValidationError) -> Response:
        # FastAPI's own handler echoes the input back, and JSON has no NaN: a body with
        # NaN in it would turn a 422 into a 500.
        problems = [
            {"loc": list(e.get("loc", ())), "msg": e.get("msg", ""), "type": e.get("type", "")}
            for e in error.errors()
        ]
        return Response(
            _json_text({"detail": problems}), status_code=422, media_type="application/json"
        )

    auth = Depends(_bearer_check(token))
    app.include_router(_status_routes(flight, params, processes))
    app.include_router(_operator_routes(flight), dependencies=[auth])
    app.include_router(_setpoint_routes(flight, params, arena, auth))
    app.include_router(_telemetry_route(flight))
    app.include_router(_sim_routes(world, auth))
    if STATIC_DIR.is_dir():
        app.mount("/", StaticFiles(directory=STATIC_DIR, html=True), name="dashboard")
    return app


def _bearer_check(token: str) -> Callable[[str | None], None]:
    """The dependency that refuses a request without ``Authorization: Bearer token``."""

    def authorized(authorization: Annotated[str | None, Header()] = None) -> None:
        scheme, _, presented = (authorization or "").partition(" ")
        if scheme.lower() != "bearer" or not secrets.compare_digest(
            presented.encode(), token.encode()
        ):
            raise HTTPException(
                401,
                "a valid 'Authorization: Bearer TOKEN' header is required",
                headers={"WWW-Authenticate": "Bearer"},
            )

    return authorized


def _status_routes(
    flight: FlightClient,
    params: BarSystemParams,
    processes: Callable[[], dict[str, Any]] | None,
) -> APIRouter:
    router = APIRouter()

    @router.get("/api/status")
    async def status() -> JSONResponse:
        """Mode, controller, vehicles, bar, mocap health, setpoints and tick timing."""
        if flight.latest is None:
            return JSONResponse({"detail": "no telemetry from the flight process yet"}, 503)
        body = dict(flight.latest)
        body["stale"] = flight.telemetry_age_s > TELEMETRY_STALE_S or not flight.connected
        if processes is not None:
            body["processes"] = processes()
        return JSONResponse(body)

    @router.get("/api/equilibria")
    async def equilibria(
        theta_l: Annotated[float, Query(description="cable angle θ_l [rad], in [0, π/2)")],
    ) -> dict[str, Any]:
        """The equilibrium a cable angle implies (Proposition 1 and the general one)."""
        if not math.isfinite(theta_l):
            raise HTTPException(422, "theta_l must be a finite number of radians")
        try:
            return equilibrium_summary(params, theta_l)
        except EquilibriumError as error:
            raise HTTPException(422, str(error)) from None

    return router


def _operator_routes(flight: FlightClient) -> APIRouter:
    """The mode requests and the controller switch (all need the token)."""
    router = APIRouter()

    async def operator(kind: OperatorEvent) -> JSONResponse:
        return _answer(await flight.request(ModeRequest(kind=kind)))

    @router.post("/api/arm")
    async def arm() -> JSONResponse:
        """Arm both vehicles (motors idle on the ground)."""
        return await operator("arm")

    @router.post("/api/takeoff")
    async def takeoff() -> JSONResponse:
        """Lift the bar to the take-off height and hover."""
        return await operator("takeoff")

    @router.post("/api/land")
    async def land() -> JSONResponse:
        """Set the bar down, land both UAVs and disarm."""
        return await operator("land")

    @router.post("/api/abort")
    async def abort() -> JSONResponse:
        """Coordinated landing from any airborne mode, now. Always accepted."""
        return await operator("abort")

    @router.post("/api/disarm")
    async def disarm() -> JSONResponse:
        """Disarm on the ground."""
        return await operator("disarm")

    @router.post("/api/kill")
    async def kill(body: KillRequest) -> JSONResponse:
        """Force-disarm both vehicles at once, in the air too: they fall."""
        return await operator("kill")

    @router.post("/api/mode")
    async def mode(body: ModeBody) -> JSONResponse:
        """Switch the controller (bumpless in flight)."""
        return _answer(await flight.request(ControllerRequest(controller=body.controller)))

    return router


def _setpoint_routes(
    flight: FlightClient, params: BarSystemParams, arena: Arena, auth: fastapi_params.Depends
) -> APIRouter:
    """Reading the queue is open; changing it needs the token (``auth``)."""
    router = APIRouter()

    @router.get("/api/setpoints")
    async def get_setpoints() -> JSONResponse:
        """The active setpoint and the queue."""
        return _answer(await flight.request(SetpointsQuery()))

    @router.post("/api/setpoints", dependencies=[auth])
    async def post_setpoints(body: SetpointBody | list[SetpointBody]) -> JSONResponse:
        """Queue one setpoint or a list, all or none, each validated against the arena and
        equilibrium feasibility. Checked here first, so that a flood of setpoints no vehicle
        can fly never reaches the flight process; the tick core checks again as the
        authority for every way in (the simulator's scripts too)."""
        entries = body if isinstance(body, list) else [body]
        if not entries:
            raise HTTPException(422, "an empty list queues nothing")
        try:
            validate_setpoints([e.to_setpoint() for e in entries], params, arena)
        except SetpointError as error:
            raise HTTPException(422, str(error)) from None
        return _answer(await flight.request(QueueRequest(setpoints=entries)))

    @router.delete("/api/setpoints", dependencies=[auth])
    async def delete_setpoints() -> JSONResponse:
        """Drop the queue and the active setpoint: the bar holds where its reference is."""
        return _answer(await flight.request(ClearSetpointsRequest()))

    return router


def _sim_routes(world: WorldClient | None, auth: fastapi_params.Depends) -> APIRouter:
    """Faults and reset of the embedded world: reading is open, the rest needs the token
    (``auth``) and an embedded world."""
    router = APIRouter()

    def embedded() -> WorldClient:
        """The world, or 409: as a route dependency it runs after the token's and before
        the body is parsed, so without a world nothing else is said."""
        if world is None:
            raise HTTPException(409, NOT_EMBEDDED)
        return world

    needs_world = [auth, Depends(embedded)]

    async def ask(request: WorldRequest) -> JSONResponse:
        reply = await embedded().request(request)
        if reply.ok:
            return JSONResponse({"accepted": True, "embedded": True, **reply.data})
        return _answer(reply)

    @router.get("/api/sim/faults")
    async def get_faults() -> JSONResponse:
        """The faults in effect (kind, params, started_s and remaining_s in world seconds;
        remaining_s null: until cleared); ``embedded`` false when there is no world."""
        if world is None:
            return JSONResponse({"embedded": False, "faults": []})
        reply = await world.request(ListFaults())
        if not reply.ok:
            return _answer(reply)
        return JSONResponse({"embedded": True, **reply.data})

    @router.post("/api/sim/faults", dependencies=needs_world)
    async def post_fault(body: FaultSpec) -> JSONResponse:
        """Inject a fault into the simulated world (one of its kind on the same target is
        replaced); the answer lists the faults in effect."""
        return await ask(StartFault(fault=body))

    @router.delete("/api/sim/faults", dependencies=needs_world)
    async def delete_faults() -> JSONResponse:
        """End every fault now."""
        return await ask(ClearFaults())

    @router.post("/api/sim/reset", dependencies=needs_world)
    async def reset() -> JSONResponse:
        """Put the simulated world back in its resting pose: the plant's initial state, the
        simulated PX4s disarmed in their boot mode, faults cleared. Refused while a vehicle
        is armed."""
        return await ask(ResetWorld())

    return router


def _telemetry_route(flight: FlightClient) -> APIRouter:
    router = APIRouter()

    @router.websocket("/api/telemetry")
    async def telemetry(websocket: WebSocket) -> None:
        """Telemetry messages as JSON, at the flight process's rate (25 Hz)."""
        await websocket.accept()
        subscription = flight.subscribe()
        try:
            # A pause in telemetry keeps the socket open: the page marks its data stale.
            while True:
                message = await subscription.next()
                await websocket.send_text(_json_text(message))
        except (WebSocketDisconnect, SubscriptionEndedError):
            pass
        finally:
            subscription.close()
            with contextlib.suppress(RuntimeError, WebSocketDisconnect):
                await websocket.close()

    return router
