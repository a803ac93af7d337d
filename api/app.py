"""The REST API and telemetry WebSocket, on the flight process's command interface.

``create_app`` takes everything as arguments (no settings read at import). Every request
passes the gate first (``api.guard``: Host, Origin, token, body size — 421, 403, 401, 413),
before any body is read; each route's ``x-access`` says who may call it. A body that does
not fit its schema gets 422 with every problem (``{"detail": [{"loc", "msg", "type"}]}``);
a well-formed request the flight modes, the queue, the arena or the equilibria refuse gets
409 with the reason; no flight process answering gets 503. The OpenAPI document states
each of these per operation.

``/api/sim/*`` reaches the simulated world's process (fault injection and the world reset,
docs/faults.md), only when ``serve`` started the world itself (``sim.embedded``): else the
mutating ones are 409 with the reason, checked before the body.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

import pydantic_core
from fastapi import (
    APIRouter,
    Depends,
    FastAPI,
    HTTPException,
    Query,
    Request,
    WebSocket,
    WebSocketDisconnect,
)
from fastapi.exceptions import RequestValidationError
from fastapi.responses import FileResponse, JSONResponse, Response
from fastapi.staticfiles import StaticFiles

from api.guard import WEBSOCKET, Access, Gate, HttpPolicy
from api.models import (
    ErrorBody,
    KillRequest,
    ModeBody,
    SetpointsBody,
    ValidationFailed,
)
from api.world_reset import settle_after_reset
from controllers.equilibria import EquilibriumError
from controllers.formation_params import FormationParams
from supervisor.flight import outcomes
from supervisor.flight.equilibrium_summary import equilibrium_summary
from supervisor.flight.feasibility import SetpointBounds
from supervisor.flight.operator_requests import (
    THETA_L_LIMIT_RAD,
    ClearSetpointsRequest,
    ControllerRequest,
    ModeRequest,
    OperatorEvent,
    Outcome,
    PathFields,
    PathRequest,
    QueueRequest,
    Reply,
    SetpointsQuery,
)
from supervisor.flight.operator_requests import Request as FlightRequest
from supervisor.flight.setpoints import Arena, SetpointError, validate_setpoints
from supervisor.flight.status import FlightStatus, ProcessStatus, Status, WorldStatus
from supervisor.flight.waypoint_checks import validate_waypoints
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

log = logging.getLogger(__name__)

STATIC_DIR = Path(__file__).resolve().parent / "static"
HTTP_STATUS = {
    Outcome.OK: 200,
    Outcome.REFUSED: 409,
    Outcome.INVALID: 422,
    Outcome.UNAVAILABLE: 503,
}
TELEMETRY_PATH = "/api/telemetry"
URGENT_PATHS = frozenset({"/api/abort", "/api/kill"})  # never shed under load (api.guard)
TELEMETRY_STALE_S = 0.5
MAX_WAIT_S = 600.0  # of a request's ?wait_s= (a take-off: about 10 s; a long setpoint hold)
WAIT_INTERVAL_S = 0.04  # the telemetry's period
TOKEN_MESSAGE_TIMEOUT_S = 5.0
WS_TOKEN_REQUIRED = 4401  # a private close code (RFC 6455 §7.4.2): "send the token first"
NOT_EMBEDDED = (
    "the simulated world is not embedded (sim.embedded is false): serve did not start a "
    "simulated world, so there is nothing to inject faults into or reset"
)
# The dashboard page may not be framed by another site (clickjacking its buttons).
PAGE_HEADERS = {
    "X-Frame-Options": "DENY",
    "Content-Security-Policy": "frame-ancestors 'none'",
    "X-Content-Type-Options": "nosniff",
}

# Every response the API gives, by status, as the OpenAPI document states them.
RESPONSES: dict[int, dict[str, Any]] = {
    400: {"model": ErrorBody, "description": "the body cannot be parsed at all"},
    401: {
        "model": ErrorBody,
        "description": "no valid `Authorization: Bearer TOKEN` header",
        "headers": {"WWW-Authenticate": {"schema": {"type": "string"}}},
    },
    403: {"model": ErrorBody, "description": "sent by a web page of another origin"},
    409: {"model": ErrorBody, "description": "refused (the mode table, the queue, the world)"},
    413: {"model": ErrorBody, "description": "the body is larger than api.max_body_bytes"},
    421: {"model": ErrorBody, "description": "the Host header names no host of this API"},
    422: {"model": ValidationFailed, "description": "the request does not validate"},
    503: {
        "model": ErrorBody,
        "description": "the flight process (or world) is not answering, or the API is busy "
        "(too many requests at once: Retry-After; an abort is never refused so)",
        "headers": {"Retry-After": {"schema": {"type": "string"}}},
    },
}
FLIGHT = (409, 422, 503)  # what a request answered by the flight process or world may get
WITH_BODY = (400, 422)


def _json_text(value: Any) -> str:
    """JSON without NaN (JSON has none): non-finite numbers become null."""
    return pydantic_core.to_json(value, inf_nan_mode="null").decode()


def _problems(loc: list[str | int], msg: str, kind: str) -> list[dict[str, Any]]:
    return [{"loc": loc, "msg": msg, "type": kind}]


def _invalid(loc: list[str | int], msg: str, kind: str) -> RequestValidationError:
    """A 422 in the shape of pydantic's own."""
    return RequestValidationError(_problems(loc, msg, kind))


def _answer(reply: Reply) -> JSONResponse:
    if reply.ok:
        return JSONResponse({"accepted": True, **reply.data})
    detail: Any = reply.reason
    if reply.outcome is Outcome.INVALID:
        detail = _problems(["body"], reply.reason, "refused")
    return JSONResponse(
        {**reply.data, "accepted": False, "detail": detail},
        status_code=HTTP_STATUS[reply.outcome],
    )


@dataclass(frozen=True)
class StatusSource:
    """The status as the API tells it: the flight process's latest status, whether it is
    stale, ``serve``'s processes (None: no table) and the simulated world (None: none)."""

    flight: FlightClient
    processes: Callable[[], dict[str, ProcessStatus]] | None
    world: WorldClient | None

    def of(self, flight_status: FlightStatus) -> Status:
        """``flight_status`` with what the API process knows now."""
        flight = self.flight
        return Status.of(
            flight_status,
            stale=flight.telemetry_age_s > TELEMETRY_STALE_S or not flight.connected,
            processes=self.processes() if self.processes is not None else {},
            world=self.world.view() if self.world is not None else WorldStatus(embedded=False),
        )

    def now(self) -> Status | None:
        """The status now; None before any telemetry from the flight process."""
        latest = self.flight.latest
        return self.of(latest) if latest is not None else None


WaitSeconds = Annotated[
    float | None,
    Query(
        gt=0.0,
        le=MAX_WAIT_S,
        allow_inf_nan=False,
        description="wait for the outcome, up to this long [s]: 200 once the system is "
        "there, 409 with the reason (an abort's notice, PX4's refusal, the timeout) if not; "
        "`outcome` says which. Without it the answer comes at once.",
    ),
]


async def _settled(
    statuses: StatusSource, goal: outcomes.Goal, sent_at_s: float, wait_s: float
) -> outcomes.Outcome:
    """The outcome of a request sent at ``sent_at_s``, judged on each status for at most
    ``wait_s``."""
    staleness = outcomes.Staleness()
    while True:
        status, now_s = statuses.now(), time.monotonic()
        if status is not None:
            stale_for_s = staleness.stale_for_s(status, now_s)
            outcome = outcomes.judge(goal, status, now_s - sent_at_s, stale_for_s, wait_s)
            if outcome is not None:
                return outcome
        elif now_s - sent_at_s > wait_s:
            # Not after an accepted request (its status comes before its reply); said, not
            # waited on for ever.
            return outcomes.Outcome(outcomes.Verdict.FAILED, "no status from the flight process")
        await asyncio.sleep(WAIT_INTERVAL_S)


async def _answer_once_settled(
    statuses: StatusSource, request: FlightRequest, goal: outcomes.Goal, wait_s: float | None
) -> JSONResponse:
    """The flight process's answer to ``request``; with ``wait_s``, once its outcome is
    known (the notices since it was sent are the reasons)."""
    sent_at_s = time.monotonic()
    reply = await statuses.flight.request(request)
    if wait_s is None or not reply.ok:
        return _answer(reply)
    outcome = await _settled(statuses, goal, sent_at_s, wait_s)
    body = {"accepted": True, **reply.data}
    body["outcome"] = {"reached": outcome.reached, "message": outcome.message}
    if outcome.reached:
        return JSONResponse(body)
    return JSONResponse({**body, "detail": outcome.message}, status_code=409)


def _operation(access: Access, policy: HttpPolicy, *codes: int) -> dict[str, Any]:
    """A route's access (``x-access``: what the gate enforces) and every response it may
    give, for its decorator: the gate's (421, 413 and 503 always, 401 where the token is needed,
    403 for another origin on the routes that change something — here exactly the ``token``
    and ``abort`` ones, all POST or DELETE) and ``codes``."""
    statuses = {421, 413, 503, *codes}
    if access in (Access.TOKEN, Access.ABORT):
        statuses.add(403)
    needs_token = access in (Access.TOKEN, Access.ABORT) or (
        access is Access.READ and policy.reads_need_token
    )
    extra: dict[str, Any] = {"x-access": access.value}
    if needs_token:
        statuses.add(401)
        extra["security"] = [{"bearer": []}]
    return {
        "openapi_extra": extra,
        "responses": {code: RESPONSES[code] for code in sorted(statuses)},
    }


def create_app(
    flight: FlightClient,
    params: FormationParams,
    arena: Arena,
    bounds: SetpointBounds,
    policy: HttpPolicy,
    world: WorldClient | None = None,
    processes: Callable[[], dict[str, ProcessStatus]] | None = None,
) -> FastAPI:
    """The FastAPI application serving ``flight`` (``params``, ``arena`` and ``bounds``: the
    system, its flight volume and what the vehicles can hold, for the equilibria it reports
    and the setpoints and waypoints it checks) behind the
    gate ``policy`` describes, and, when ``serve`` runs the simulated world itself,
    ``world``; ``processes``: serve's process table for the status."""
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

    statuses = StatusSource(flight, processes, world)
    app.include_router(_status_routes(statuses, params, bounds, policy))
    app.include_router(_operator_routes(statuses, policy))
    app.include_router(_setpoint_routes(statuses, params, arena, bounds, policy))
    app.include_router(_telemetry_route(statuses, policy))
    app.include_router(_sim_routes(world, flight, policy))
    if STATIC_DIR.is_dir():
        _dashboard(app)
    _document_bearer(app)
    app.add_middleware(Gate, policy=policy, routes=_access_table(app), urgent=URGENT_PATHS)
    return app


def _dashboard(app: FastAPI) -> None:
    """The page at ``/``, its files under ``/static/`` (not a mount at ``/``, which would
    answer an unknown method on an API path itself: 405 without ``Allow``)."""

    @app.get("/", include_in_schema=False)
    async def page() -> FileResponse:
        return FileResponse(STATIC_DIR / "index.html", headers=PAGE_HEADERS)

    app.mount("/static", StaticFiles(directory=STATIC_DIR), name="dashboard")


def _document_bearer(app: FastAPI) -> None:
    """The bearer scheme the operations' ``security`` names (the gate checks it, not a
    FastAPI dependency: a dependency runs after the body is parsed)."""
    generate = app.openapi

    def openapi() -> dict[str, Any]:
        schema = generate()
        components = schema.setdefault("components", {})
        components.setdefault("securitySchemes", {})["bearer"] = {
            "type": "http",
            "scheme": "bearer",
        }
        return schema

    app.openapi = openapi  # type: ignore[method-assign]


def _access_table(app: FastAPI) -> dict[tuple[str, str], Access]:
    """(method, path) → access, from each operation's ``x-access`` in the OpenAPI document
    (an operation without one needs the token: the safe default); the WebSocket is
    ``read``. Paths without an operation (the dashboard's files) are the router's."""
    table = {(WEBSOCKET, TELEMETRY_PATH): Access.READ}
    for path, operations in app.openapi()["paths"].items():
        for method, operation in operations.items():
            access = operation.get("x-access", Access.TOKEN.value)
            table[(method.upper(), path)] = Access(access)
    return table


def _status_routes(
    statuses: StatusSource,
    params: FormationParams,
    bounds: SetpointBounds,
    policy: HttpPolicy,
) -> APIRouter:
    router = APIRouter()

    @router.get("/api/status", response_model=Status, **_operation(Access.READ, policy, 503))
    async def status() -> Status | JSONResponse:
        """Mode, controller, vehicles, bar, mocap health, setpoints and tick timing; with
        an embedded simulated world, ``world``: its faults and its own stalls (moments a
        busy computer did not run it, when its mocap and vehicles paused too)."""
        now = statuses.now()
        if now is None:
            return JSONResponse({"detail": "no telemetry from the flight process yet"}, 503)
        return now

    @router.get("/api/equilibria", **_operation(Access.READ, policy, 422))
    async def equilibria(
        theta_l: Annotated[
            float,
            Query(
                ge=0.0,
                lt=THETA_L_LIMIT_RAD,
                allow_inf_nan=False,
                description="cable angle θ_l [rad], in [0, π/2)",
            ),
        ],
    ) -> dict[str, Any]:
        """The equilibrium a cable angle implies (Proposition 1 and the general one), and
        ``refusals``: why a setpoint at it would be refused (empty: it would be taken)."""
        try:
            return equilibrium_summary(params, theta_l, bounds)
        except EquilibriumError as error:
            raise _invalid(["query", "theta_l"], str(error), "equilibrium") from None

    return router


def _operator_routes(statuses: StatusSource, policy: HttpPolicy) -> APIRouter:
    """The mode requests and the controller switch (the token; abort: the token or the
    dashboard's own origin)."""
    router = APIRouter()
    flight = statuses.flight
    token = _operation(Access.TOKEN, policy, *FLIGHT)

    async def operator(kind: OperatorEvent) -> JSONResponse:
        return _answer(await flight.request(ModeRequest(kind=kind)))

    async def awaited(
        kind: OperatorEvent, goal: outcomes.Goal, wait_s: float | None
    ) -> JSONResponse:
        return await _answer_once_settled(statuses, ModeRequest(kind=kind), goal, wait_s)

    @router.post("/api/arm", **token)
    async def arm(wait_s: WaitSeconds = None) -> JSONResponse:
        """Arm every vehicle (motors idle on the ground); with ``wait_s``, until every PX4
        say they are armed."""
        return await awaited("arm", outcomes.armed, wait_s)

    @router.post("/api/takeoff", **token)
    async def takeoff(wait_s: WaitSeconds = None) -> JSONResponse:
        """Lift the bar to the take-off height and hover; with ``wait_s``, until hovering."""
        return await awaited("takeoff", outcomes.hovering, wait_s)

    @router.post("/api/land", **token)
    async def land(wait_s: WaitSeconds = None) -> JSONResponse:
        """Set the bar down, land both UAVs and disarm; with ``wait_s``, until disarmed on
        the ground."""
        return await awaited("land", outcomes.landed, wait_s)

    @router.post("/api/abort", **_operation(Access.ABORT, policy, *FLIGHT))
    async def abort(request: Request) -> JSONResponse:
        """Coordinated landing from any airborne mode, now. Always accepted. The emergency
        stop: it takes the token, or no token at all when the dashboard's own page sends
        it (its ``Origin`` is this API's), so that a missing or wrong token never stops it.
        Logged with where it came from."""
        reply = await flight.request(ModeRequest(kind="abort"))
        state = request.scope.get("state", {})
        peer = f"{request.client.host}:{request.client.port}" if request.client else "unknown"
        log.warning(
            "abort from %s (origin %s, %s): %s",
            peer,
            state.get("origin") or "none",
            "with the token" if state.get("authenticated") else "the dashboard, no valid token",
            reply.outcome.value,
        )
        return _answer(reply)

    @router.post("/api/disarm", **token)
    async def disarm() -> JSONResponse:
        """Disarm on the ground."""
        return await operator("disarm")

    @router.post("/api/kill", **_operation(Access.TOKEN, policy, *FLIGHT, *WITH_BODY))
    async def kill(body: KillRequest) -> JSONResponse:
        """Force-disarm every vehicle at once, in the air too: they fall."""
        return await operator("kill")

    @router.post("/api/mode", **_operation(Access.TOKEN, policy, *FLIGHT, *WITH_BODY))
    async def mode(body: ModeBody, wait_s: WaitSeconds = None) -> JSONResponse:
        """Switch the controller (bumpless in flight); with ``wait_s``, until it flies."""
        switch = ControllerRequest(controller=body.controller)
        return await _answer_once_settled(
            statuses, switch, outcomes.controller(body.controller), wait_s
        )

    return router


def _setpoint_routes(
    statuses: StatusSource,
    params: FormationParams,
    arena: Arena,
    bounds: SetpointBounds,
    policy: HttpPolicy,
) -> APIRouter:
    """Reading the queue is ``read``; changing it (setpoints, paths) needs the token."""
    router = APIRouter()
    flight = statuses.flight

    @router.get("/api/setpoints", **_operation(Access.READ, policy, *FLIGHT))
    async def get_setpoints() -> JSONResponse:
        """The active setpoint and the queue."""
        return _answer(await flight.request(SetpointsQuery()))

    @router.post("/api/setpoints", **_operation(Access.TOKEN, policy, *FLIGHT, *WITH_BODY))
    async def post_setpoints(body: SetpointsBody, wait_s: WaitSeconds = None) -> JSONResponse:
        """Queue one setpoint or a list of at most 32 (the queue's capacity), all or none.
        A longer list is refused by its length before any entry is read (422). Each is then
        checked against the arena and equilibrium feasibility — θ_l, and each UAV's thrust and
        tilt at the equilibrium, within the setup's bounds with their margins (409 with the
        reason, naming the bound and the excess, when it cannot be flown here, or when the
        queue is full). Checked here first, so that a flood
        of setpoints no vehicle can fly never reaches the flight process; the tick core
        checks again as the authority for every way in (the simulator's scripts too).
        With ``wait_s``, until the last one queued has been reached and held."""
        entries = body if isinstance(body, list) else [body]
        try:
            validate_setpoints([e.to_setpoint() for e in entries], params, arena, bounds)
        except SetpointError as error:
            # Well-formed (the schema holds) but not flyable here: 409, as the queue's
            # refusals; 422 is kept for what the schema itself refuses.
            return JSONResponse({"accepted": False, "detail": str(error)}, 409)
        flown = outcomes.setpoint_flown(entries[-1])
        return await _answer_once_settled(statuses, QueueRequest(setpoints=entries), flown, wait_s)

    @router.post("/api/path", **_operation(Access.TOKEN, policy, *FLIGHT, *WITH_BODY))
    async def post_path(body: PathFields, wait_s: WaitSeconds = None) -> JSONResponse:
        """Queue a path after what is queued: the bar from where it will be then through the
        waypoints (at most 64), smooth, timed within ``speed_mps``, ``accel_mps2`` and
        ``jerk_mps3`` (default: the setup's) and the flight's yaw and θ_l rates, its end a
        setpoint held ``hold_s``. Each waypoint is checked here first as a setpoint at rest
        (the arena, equilibrium feasibility; a yaw or θ_l not yet named is the start's,
        which only the flight knows: then only the bar's centre); the tick core then checks
        the whole timed path from its start, with the mode and the queue's room. Either
        refusal is 409 with the reason. Accepted, the answer says how many are queued and
        the path's ``duration_s`` and ``length_m``. With ``wait_s``, until its end has been
        reached and held."""
        waypoints = [point.to_waypoint() for point in body.waypoints]
        try:
            # Up to 64 equilibria (about 15 ms): in a thread, so that no abort's turn of the
            # event loop waits behind them.
            await asyncio.to_thread(validate_waypoints, waypoints, params, arena, bounds)
        except SetpointError as error:
            return JSONResponse({"accepted": False, "detail": str(error)}, 409)
        flown = outcomes.path_flown([point.bar_position for point in body.waypoints])
        request = PathRequest.model_validate(dict(body))
        return await _answer_once_settled(statuses, request, flown, wait_s)

    @router.delete("/api/setpoints", **_operation(Access.TOKEN, policy, *FLIGHT))
    async def delete_setpoints() -> JSONResponse:
        """Drop the queue and the active setpoint: the bar holds where its reference is."""
        return _answer(await flight.request(ClearSetpointsRequest()))

    return router


def _sim_routes(world: WorldClient | None, flight: FlightClient, policy: HttpPolicy) -> APIRouter:
    """Faults and reset of the embedded world: reading is ``read``, the rest needs the
    token and an embedded world."""
    router = APIRouter()

    def embedded() -> WorldClient:
        """The world, or 409: as a route dependency it runs before the body is validated,
        so without a world nothing else is said."""
        if world is None:
            raise HTTPException(409, NOT_EMBEDDED)
        return world

    async def ask(request: WorldRequest) -> JSONResponse:
        reply = await embedded().request(request)
        if reply.ok:
            data = dict(reply.data)
            if isinstance(request, ResetWorld):
                data |= await settle_after_reset(flight, data.pop("resting_positions"))
            return JSONResponse({"accepted": True, "embedded": True, **data})
        if reply.outcome is Outcome.INVALID:
            # The body fitted its schema here; what the world still refuses (a rigid body
            # it does not have) is a refusal, 409, like the queue's and the arena's.
            reply = reply.model_copy(update={"outcome": Outcome.REFUSED})
        return _answer(reply)

    def mutating(*codes: int) -> dict[str, Any]:
        operation = _operation(Access.TOKEN, policy, *FLIGHT, *codes)
        return {**operation, "dependencies": [Depends(embedded)]}

    @router.get("/api/sim/faults", **_operation(Access.READ, policy, *FLIGHT))
    async def get_faults() -> JSONResponse:
        """The faults in effect (kind, params, started_s and remaining_s in world seconds;
        remaining_s null: until cleared); ``embedded`` false when there is no world."""
        if world is None:
            return JSONResponse({"embedded": False, "faults": []})
        reply = await world.request(ListFaults())
        if not reply.ok:
            return _answer(reply)
        return JSONResponse({"embedded": True, **reply.data})

    @router.post("/api/sim/faults", **mutating(*WITH_BODY))
    async def post_fault(body: FaultSpec) -> JSONResponse:
        """Inject a fault into the simulated world (one of its kind on the same target is
        replaced); the answer lists the faults in effect."""
        return await ask(StartFault(fault=body))

    @router.delete("/api/sim/faults", **mutating())
    async def delete_faults() -> JSONResponse:
        """End every fault now."""
        return await ask(ClearFaults())

    @router.post("/api/sim/reset", **mutating())
    async def reset() -> JSONResponse:
        """Put the simulated world back in its resting pose: the plant's initial state, the
        simulated PX4s disarmed in their boot mode, faults cleared. Refused while a vehicle
        is armed. Answers once the motion capture tracks the bodies there (at most 3 s):
        ``tracked``, and ``arm_blocked_by`` (null: the pre-arm checks pass)."""
        return await ask(ResetWorld())

    return router


def _telemetry_route(statuses: StatusSource, policy: HttpPolicy) -> APIRouter:
    router = APIRouter()
    flight = statuses.flight
    # Every subscriber gets the same message object: it is serialized once, not per client.
    last: dict[str, Any] = {"message": None, "text": ""}

    def text_of(message: FlightStatus) -> str:
        if message is not last["message"]:
            # The status as GET /api/status has it, the embedded world's own stalls too:
            # the page tells a gap of this computer's making from the lab's.
            last["message"], last["text"] = message, statuses.of(message).model_dump_json()
        return str(last["text"])

    @router.websocket(TELEMETRY_PATH)
    async def telemetry(websocket: WebSocket) -> None:
        """Telemetry messages as JSON, at the flight process's rate (25 Hz): each the status
        ``GET /api/status`` answers (``Status``), as it stands when it comes. When the API
        listens beyond loopback it takes the token, in the handshake's ``Authorization``
        header or (a browser cannot set one) as the first message, ``{"token": TOKEN}``;
        without it the socket is closed with code 4401."""
        await websocket.accept()
        authenticated = bool(websocket.scope.get("state", {}).get("authenticated"))
        needs_token = policy.reads_need_token and not authenticated
        if needs_token and not await _token_message(websocket, policy):
            await websocket.close(WS_TOKEN_REQUIRED, "the token is required")
            return
        subscription = flight.subscribe()
        try:
            # A pause in telemetry keeps the socket open: the page marks its data stale.
            # A client that does not read holds only this coroutine: its queue drops the
            # oldest messages (TelemetrySubscription) and the others are not slowed.
            while True:
                message = await subscription.next()
                await websocket.send_text(text_of(message))
        except (WebSocketDisconnect, SubscriptionEndedError, OSError):
            pass  # gone (uvicorn's ClientDisconnected is an OSError), or serve is stopping
        finally:
            subscription.close()
            with contextlib.suppress(RuntimeError, OSError, WebSocketDisconnect):
                await websocket.close()

    return router


async def _token_message(websocket: WebSocket, policy: HttpPolicy) -> bool:
    """The first message is ``{"token": TOKEN}`` with the right token, within 5 s."""
    try:
        async with asyncio.timeout(TOKEN_MESSAGE_TIMEOUT_S):
            first = json.loads(await websocket.receive_text())
    except (TimeoutError, ValueError, KeyError, WebSocketDisconnect, RuntimeError):
        return False
    presented = first.get("token") if isinstance(first, dict) else None
    return isinstance(presented, str) and policy.token_matches(f"Bearer {presented}")
