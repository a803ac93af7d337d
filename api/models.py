"""Request bodies of the REST API (pydantic: unknown fields and non-finite numbers are
rejected with 422 and the reason)."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field

from supervisor.flight.setpoints import Setpoint

Finite = Annotated[float, Field(allow_inf_nan=False)]


class _Body(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class SetpointBody(_Body):
    """One setpoint: bar centre [m, arena frame], bar yaw [rad], UAV yaws [rad] (default:
    the bar yaw), cable angle θ_l [rad], hold time [s] once reached."""

    bar_position: Annotated[list[Finite], Field(min_length=3, max_length=3)]
    bar_yaw: Finite = 0.0
    uav_yaw: Annotated[list[Finite], Field(min_length=2, max_length=2)] | None = None
    theta_l: Finite = 0.0
    hold_s: Annotated[float, Field(ge=0.0, allow_inf_nan=False)] = 5.0

    def to_setpoint(self) -> Setpoint:
        p = self.bar_position
        yaws = (self.uav_yaw[0], self.uav_yaw[1]) if self.uav_yaw is not None else None
        return Setpoint((p[0], p[1], p[2]), self.bar_yaw, yaws, self.theta_l, self.hold_s)


class ModeRequest(_Body):
    """Which MPC flies the bar."""

    controller: Literal["centralized", "decentralized"]


class KillRequest(_Body):
    """Kill stops the motors in the air: the vehicles fall. It must be confirmed."""

    confirm: Literal[True]
