"""The REST API and telemetry WebSocket, on the flight process's command interface.

``create_app`` takes everything as arguments (no settings read at import). Mutating routes
need ``Authorization: Bearer TOKEN`` (401 otherwise); a body that does not validate gets
422 with the reason; a request the flight modes or the queue refuse gets 409 with the
reason; no flight process answering gets 503.
"""

from __future__ import annotations

import contextlib
import math
import secrets
from pathlib import Path
from typing import Annotated, Any

from fastapi import (
    Depends,
    FastAPI,
    Header,
    HTTPException,
    Query,
    Request,
    WebSocket,
    WebSocketDisconnect,
)
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from fastapi.staticfiles import StaticFiles

from api.models import KillRequest, ModeRequest, SetpointBody
from controllers.equilibria import EquilibriumError
from controllers.params import BarSystemParams
from supervisor.flight.equilibrium_summary import equilibrium_summary
from supervisor.flight.setpoints import Arena, SetpointError, validate_setpoint
from supervisor.ipc.client import FlightClient, Reply
from supervisor.logs.flight_log import finite_or_none

STATIC_DIR = Path(__file__).resolve().parent / "static"
HTTP_STATUS = {"ok": 200, "refused": 409, "invalid": 422, "unavailable": 503}
TELEMETRY_STALE_S = 0.5


def _answer(reply: Reply) -> JSONResponse:
    if reply.ok:
        return JSONResponse({"accepted": True, **reply.data})
    return JSONResponse(
        {"accepted": False, "detail": reply.reason, **reply.data},
        status_code=HTTP_STATUS.get(reply.outcome, 503),
    )


def create_app(
    flight: FlightClient,
    params: BarSystemParams,
    arena: Arena,
    token: str,
) -> FastAPI:
    """The FastAPI application serving ``flight``."""
    app = FastAPI(
        title="uavbar-supervisor",
        summary="Two PX4 quadrotors carrying a bar under MPC: arm, fly, queue setpoints, abort.",
        version="0.1.0",
    )

    @app.exception_handler(RequestValidationError)
    async def invalid_body(request: Request, error: RequestValidationError) -> JSONResponse:
        # FastAPI's own handler echoes the input back, and JSON has no NaN: a body with
        # NaN in it would turn a 422 into a 500.
        problems = [
            {"loc": list(e.get("loc", ())), "msg": e.get("msg", ""), "type": e.get("type", "")}
            for e in error.errors()
        ]
        return JSONResponse({"detail": finite_or_none(problems)}, status_code=422)

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

    Auth = Depends(authorized)

    @app.get("/api/status")
    async def status() -> JSONResponse:
        """Mode, controller, vehicles, bar, mocap health, setpoints and tick timing."""
        if flight.latest is None:
            return JSONResponse({"detail": "no telemetry from the flight process yet"}, 503)
        body = {k: v for k, v in flight.latest.items() if k != "kind"}
        body["stale"] = flight.telemetry_age_s > TELEMETRY_STALE_S or not flight.connected
        return JSONResponse(body)

    async def operator(kind: str) -> JSONResponse:
        return _answer(await flight.request(kind))

    @app.post("/api/arm", dependencies=[Auth])
    async def arm() -> JSONResponse:
        """Arm both vehicles (motors idle on the ground)."""
        return await operator("arm")

    @app.post("/api/takeoff", dependencies=[Auth])
    async def takeoff() -> JSONResponse:
        """Lift the bar to the take-off height and hover."""
        return await operator("takeoff")

    @app.post("/api/land", dependencies=[Auth])
    async def land() -> JSONResponse:
        """Set the bar down, land both UAVs and disarm."""
        return await operator("land")

    @app.post("/api/abort", dependencies=[Auth])
    async def abort() -> JSONResponse:
        """Coordinated landing from any airborne mode, now. Always accepted."""
        return await operator("abort")

    @app.post("/api/disarm", dependencies=[Auth])
    async def disarm() -> JSONResponse:
        """Disarm on the ground."""
        return await operator("disarm")

    @app.post("/api/kill", dependencies=[Auth])
    async def kill(body: KillRequest) -> JSONResponse:
        """Force-disarm both vehicles at once, in the air too: they fall."""
        return await operator("kill")

    @app.post("/api/mode", dependencies=[Auth])
    async def mode(body: ModeRequest) -> JSONResponse:
        """Switch the controller (bumpless in flight)."""
        return _answer(await flight.request("controller", controller=body.controller))

    @app.get("/api/setpoints")
    async def get_setpoints() -> JSONResponse:
        """The active setpoint and the queue."""
        return _answer(await flight.request("setpoints"))

    @app.post("/api/setpoints", dependencies=[Auth])
    async def post_setpoints(body: SetpointBody | list[SetpointBody]) -> JSONResponse:
        """Queue one setpoint or a list, all or none, each validated against the arena and
        equilibrium feasibility first."""
        entries = body if isinstance(body, list) else [body]
        if not entries:
            raise HTTPException(422, "an empty list queues nothing")
        for index, entry in enumerate(entries):
            try:
                validate_setpoint(entry.to_setpoint(), params, arena)
            except SetpointError as error:
                where = f"setpoint {index}: " if len(entries) > 1 else ""
                raise HTTPException(422, f"{where}{error}") from None
        return _answer(await flight.request("queue", setpoints=[e.model_dump() for e in entries]))

    @app.delete("/api/setpoints", dependencies=[Auth])
    async def delete_setpoints() -> JSONResponse:
        """Drop the queue and the active setpoint: the bar holds where its reference is."""
        return _answer(await flight.request("clear_setpoints"))

    @app.get("/api/equilibria")
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

    @app.websocket("/api/telemetry")
    async def telemetry(websocket: WebSocket) -> None:
        """Telemetry messages as JSON, at the flight process's rate (25 Hz)."""
        await websocket.accept()
        subscription = flight.subscribe()
        try:
            # A pause in telemetry keeps the socket open: the page marks its data stale.
            while True:
                message = await subscription.next()
                await websocket.send_json({k: v for k, v in message.items() if k != "kind"})
        except WebSocketDisconnect:
            pass
        finally:
            subscription.close()
            with contextlib.suppress(RuntimeError):
                await websocket.close()

    if STATIC_DIR.is_dir():
        app.mount("/", StaticFiles(directory=STATIC_DIR, html=True), name="dashboard")
    return app
