"""The centralized (Section IV) and decentralized (Section V) MPCs, one ``step`` per tick.

Each tick: the reference maps to (x_eq, u_eq); the model is linearized at the same
equilibrium turned to the *measured* yaw angles (the yaws are parameters refreshed every
tick, as in the paper) and discretized (A = I + A_c h, B = B_c h); the QP (MPC) in
Δx = x − x_eq, Δu = u − u_eq is solved warm-started, and u* = u_eq + Δu_0 is applied.

A solve that fails, finishes late, or a state with NaN/inf gives the previous plan shifted
by one step, with a status that says so; ``step`` never raises.

``prepare`` splits a tick the way real-time MPC does: after a tick has sent its input, it
linearizes for the next one at the yaws one step ahead (the measured yaws moved on by
their estimated rates) and lets the QP back-end build what depends on that model alone
(condensing, the box-free solution map). The next ``step``
uses that model when its own measured yaws and its reference's θ_l lie within
``prepared_yaw_tolerance_rad`` of those (and the reference's velocity and turn rates
within the same number, in m/s and rad/s) — A and B do not depend on where the formation
is — so between a mocap frame and the input sent to the vehicles only the state-dependent
part of the tick remains. Otherwise it linearizes anew. A prepared model serves as long as
it fits: ``prepare`` keeps it while the yaws one step ahead stay within the tolerance of
those it was made at, so a hover linearizes about once, not fifty times a second.

Both controllers serve any formation of ``FormationParams`` (N UAVs, one rigid payload):
the centralized MPC plans the whole 12 + 12N-state, the decentralized one runs N agents.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from enum import Enum

import casadi as ca
import numpy as np

from controllers.codegen import NumericFunction
from controllers.formation_equilibria import (
    NO_FORCES,
    AgentEquilibrium,
    ExternalForces,
    FormationEquilibrium,
    FormationReference,
    formation_equilibrium,
    hanging_mass_shares_kg,
)
from controllers.formation_model import FormationModel
from controllers.formation_params import FormationParams
from controllers.linearization import discretize, formation_jacobians, payload_jacobians
from controllers.model import PayloadModel
from controllers.params import Clock, MpcSettings, ReferenceLead, StateBound
from controllers.preview import Kinematics, Preview, moved_like, stage_targets
from controllers.qp.base import OcpQp, QpBackend, QpStatus
from controllers.qp.registry import make_backend
from controllers.vectors import cross3, rotate_zyx
from geometry.arrays import FloatArray
from geometry.formation import FormationLayout
from geometry.state import (
    AGENT_INPUTS,
    AGENT_STATES,
    AGENT_YAW_INDICES,
    P_B,
    P_I,
    P_P,
    PAYLOAD_PITCH,
    PAYLOAD_YAW,
    TH_B,
    UAV_BLOCK,
    V_B,
    V_I,
    V_P,
    W_B,
    payload_yaw,
)


class PlanStatus(Enum):
    """Where a plan's input came from."""

    OPTIMAL = "optimal"
    SHIFTED_FAILED = "shifted_failed"  # QP infeasible / not converged / numerical error
    SHIFTED_LATE = "shifted_late"  # solved, but after the time budget
    SHIFTED_BAD_STATE = "shifted_bad_state"  # NaN/inf in the state or reference
    SHIFTED_ERROR = "shifted_error"  # anything else went wrong (see ``Plan.error``)
    EQUILIBRIUM = "equilibrium"  # no previous plan to shift: u_eq is held

    @property
    def is_fallback(self) -> bool:
        return self is not PlanStatus.OPTIMAL


@dataclass(frozen=True)
class Plan:
    """One tick's result. ``u`` (nu,) is the absolute input to apply now [N, N m];
    ``u_pred`` (horizon, nu) and ``x_pred`` (horizon + 1, nx) are the absolute predictions
    (for the decentralized controller x_pred stacks the agents' 18-states side by side,
    ``geometry.state.stacked_agent_slice``)."""

    u: FloatArray
    u_pred: FloatArray
    x_pred: FloatArray
    status: PlanStatus
    time_s: float
    solve_time_s: float = 0.0
    iterations: int = 0
    error: str | None = None

    def shifted(self, now_s: float, status: PlanStatus, error: str | None = None) -> Plan:
        """This plan advanced by one step (the last input and state repeated)."""
        u_pred = np.vstack([self.u_pred[1:], self.u_pred[-1:]])
        x_pred = np.vstack([self.x_pred[1:], self.x_pred[-1:]])
        return Plan(u_pred[0].copy(), u_pred, x_pred, status, now_s, 0.0, 0, error)


def wrap_angles(dx: FloatArray, indices: tuple[int, ...]) -> FloatArray:
    """Wrap the yaw entries of a state difference to (−π, π] so a turn takes the short way."""
    for i in indices:
        dx[i] = math.remainder(dx[i], 2.0 * math.pi)
    return dx


def _finite(*arrays: FloatArray) -> bool:
    return all(bool(np.all(np.isfinite(a))) for a in arrays)


def _bound_vectors(bounds: tuple[StateBound, ...], nx: int) -> tuple[FloatArray, FloatArray] | None:
    if not bounds:
        return None
    lower, upper = np.full(nx, -np.inf), np.full(nx, np.inf)
    for bound in bounds:
        lower[bound.index], upper[bound.index] = bound.lower, bound.upper
    return lower, upper


class LinearMpc:
    """(MPC) for one linear model of fixed size: weights, U, X, X_N and a QP back-end."""

    def __init__(
        self,
        nx: int,
        nu: int,
        settings: MpcSettings,
        a_pattern: np.ndarray,
        b_pattern: np.ndarray,
        backend: str | None = None,
    ) -> None:
        self.settings = settings
        w = settings.weights
        self._q = np.asarray(w.q_diag, dtype=float)
        self._r = np.asarray(w.r_diag, dtype=float)
        if self._q.size != nx or self._r.size != nu:
            raise ValueError(
                f"weights have {self._q.size}/{self._r.size} entries, the model {nx}/{nu}"
            )
        self._qn = w.terminal_scale * self._q
        self._state_bounds = _bound_vectors(settings.state_bounds, nx)
        self._terminal_bounds = _bound_vectors(settings.terminal_bounds, nx)
        template = self.qp(
            np.eye(nx), np.zeros((nx, nu)), np.zeros(nx), -np.ones(nu), np.ones(nu), np.zeros(nx)
        )
        self.backend: QpBackend = make_backend(
            backend or settings.qp_backend, template, a_pattern, b_pattern
        )

    def qp(
        self,
        A: FloatArray,
        B: FloatArray,
        dx0: FloatArray,
        du_lb: FloatArray,
        du_ub: FloatArray,
        x_eq: FloatArray,
        targets: tuple[FloatArray, FloatArray] | None = None,
    ) -> OcpQp:
        """This tick's QP; absolute state bounds become bounds on Δx around ``x_eq``;
        ``targets`` (x̄, ū) are the per-stage ones of a preview (``controllers.preview``)."""
        state_box = self._state_bounds
        terminal = self._terminal_bounds
        return OcpQp(
            A=A,
            B=B,
            q_diag=self._q,
            r_diag=self._r,
            q_terminal_diag=self._qn,
            x0=dx0,
            u_lb=du_lb,
            u_ub=du_ub,
            horizon=self.settings.horizon,
            x_lb=None if state_box is None else state_box[0] - x_eq,
            x_ub=None if state_box is None else state_box[1] - x_eq,
            x_terminal_lb=None if terminal is None else terminal[0] - x_eq,
            x_terminal_ub=None if terminal is None else terminal[1] - x_eq,
            x_target=None if targets is None else targets[0],
            u_target=None if targets is None else targets[1],
        )


def _input_bounds(settings: MpcSettings, n_uavs: int) -> tuple[FloatArray, FloatArray]:
    lim = settings.limits
    lower = np.tile(
        [lim.thrust_min_n, -lim.torque_max_nm, -lim.torque_max_nm, -lim.torque_max_nm], n_uavs
    )
    upper = np.tile(
        [lim.thrust_max_n, lim.torque_max_nm, lim.torque_max_nm, lim.torque_max_nm], n_uavs
    )
    return lower, upper


def _patterns(jacobians: ca.Function) -> tuple[np.ndarray, np.ndarray]:
    """Structural nonzeros of A_c and B_c (fixed for every linearization point)."""
    return (np.asarray(jacobians.sparsity_out(0)) != 0, np.asarray(jacobians.sparsity_out(1)) != 0)


class _PlanKeeper:
    """The previous plan and the fallback rules shared by both controllers."""

    def __init__(self) -> None:
        self.previous: Plan | None = None

    def fallback(
        self, now_s: float, status: PlanStatus, hold: Plan, error: str | None = None
    ) -> Plan:
        plan = hold if self.previous is None else self.previous.shifted(now_s, status, error)
        if self.previous is None:
            plan = replace(hold, status=PlanStatus.EQUILIBRIUM, time_s=now_s, error=error)
        self.previous = plan
        return plan

    def accept(self, plan: Plan) -> Plan:
        self.previous = plan
        return plan


def _hold_plan(u_eq: FloatArray, x_eq: FloatArray, horizon: int, now_s: float) -> Plan:
    return Plan(
        u_eq.copy(),
        np.tile(u_eq, (horizon, 1)),
        np.tile(x_eq, (horizon + 1, 1)),
        PlanStatus.EQUILIBRIUM,
        now_s,
    )


def measured_yaws(state: FloatArray, layout: FormationLayout) -> tuple[float, tuple[float, ...]]:
    """(ψ_b, (ψ_1, …, ψ_N)) of a state."""
    return payload_yaw(state), layout.uav_yaws(state)


def yaws_ahead(
    state: FloatArray, layout: FormationLayout, dt_s: float
) -> tuple[float, tuple[float, ...]]:
    """(ψ_b, (ψ_1, …, ψ_N)) of a state ``dt_s`` later at its current yaw rates, from the
    rates it holds: the payload's ω in the inertial frame, each UAV's in its body frame (the
    third rows of H^E of (6) and H of (4), Z-Y-X Euler angles)."""
    theta_b, psi_b = state[PAYLOAD_PITCH], state[PAYLOAD_YAW]
    w_x, w_y, w_z = state[W_B]
    payload_rate = math.tan(theta_b) * (math.cos(psi_b) * w_x + math.sin(psi_b) * w_y) + w_z
    yaws = []
    for i in layout.vehicles:
        _, _, euler, rates = layout.uav_slices(i)
        phi, theta, psi = state[euler]
        _, q_rate, r_rate = state[rates]
        rate = (math.sin(phi) * q_rate + math.cos(phi) * r_rate) / math.cos(theta)
        yaws.append(float(psi + dt_s * rate))
    return float(psi_b + dt_s * payload_rate), tuple(yaws)


@dataclass(frozen=True)
class _PreparedModel:
    """A linearization made ahead of its tick: the reference turned to the yaws it used,
    and (A, B) for each QP of the controller."""

    reference: FormationReference
    models: tuple[tuple[FloatArray, FloatArray], ...]

    def fits(self, reference: FormationReference, tolerance: float) -> bool:
        """Whether it may stand for the linearization at ``reference`` (turned to the
        measured yaws): yaws and the cone angle within ``tolerance`` [rad], and the
        reference's velocity [m/s], acceleration [m/s²] and turn and cone-angle rates
        [rad/s] within the same number."""
        mine = self.reference
        angles = zip(
            (mine.payload_yaw_rad, *mine.uav_yaw_rad, mine.cone_angle_rad),
            (reference.payload_yaw_rad, *reference.uav_yaw_rad, reference.cone_angle_rad),
            strict=True,
        )
        if any(abs(math.remainder(a - b, 2.0 * math.pi)) > tolerance for a, b in angles):
            return False
        rates = zip(
            (*mine.velocity_mps, *mine.acceleration_mps2, *_rates(mine)),
            (*reference.velocity_mps, *reference.acceleration_mps2, *_rates(reference)),
            strict=True,
        )
        return all(abs(a - b) <= tolerance for a, b in rates)


def _rates(reference: FormationReference) -> tuple[float, ...]:
    """The reference's turn and cone-angle rates [rad/s]."""
    return (
        reference.payload_yaw_rate_radps,
        *reference.uav_yaw_rates_radps,
        reference.cone_angle_rate_radps,
    )


Models = tuple[tuple[FloatArray, FloatArray], ...]


class _ModelPreparation:
    """What both controllers share of ``prepare``: ``linearize`` gives (A, B) for each of
    ``mpcs`` at a reference turned to some yaws."""

    def __init__(
        self,
        layout: FormationLayout,
        settings: MpcSettings,
        linearize: Callable[[FormationReference], Models],
        mpcs: tuple[LinearMpc, ...],
    ) -> None:
        self._layout = layout
        self._settings = settings
        self._linearize = linearize
        self._mpcs = mpcs
        self._prepared: _PreparedModel | None = None
        self.last_was_used = False
        """Whether the last ``models`` call gave the prepared models."""
        self.last_kept = False
        """Whether the last ``prepare`` kept the models prepared before (they still fit)."""

    def prepare(self, state: FloatArray, reference: FormationReference) -> None:
        """Linearize at ``state``'s yaws one step ahead and prepare the back-ends, unless
        the models prepared before fit those yaws; never raises (the next step then
        linearizes itself, and reports what fails)."""
        kept, self._prepared = self._prepared, None
        self.last_kept = False
        tolerance = self._settings.prepared_yaw_tolerance_rad
        if tolerance == 0.0 or not _finite(state):
            return
        turned = reference.with_yaws(*yaws_ahead(state, self._layout, self._settings.dt_s))
        if kept is not None and kept.fits(turned, tolerance):
            self._prepared, self.last_kept = kept, True
            return
        try:
            models = self._linearize(turned)
            for mpc, (A, B) in zip(self._mpcs, models, strict=True):
                nx, nu = B.shape
                zeros = np.zeros(nx)
                mpc.backend.prepare(mpc.qp(A, B, zeros, -np.ones(nu), np.ones(nu), zeros))
        except Exception:
            return
        self._prepared = _PreparedModel(turned, models)

    def models(self, state: FloatArray, reference: FormationReference) -> Models:
        """The models for a step at ``state``: the prepared ones when they fit its measured
        yaws, else a new linearization (and the prepared ones are dropped: the back-ends
        were prepared for them, and the yaws have left them)."""
        prepared = self._prepared
        turned = reference.with_yaws(*measured_yaws(state, self._layout))
        tolerance = self._settings.prepared_yaw_tolerance_rad
        self.last_was_used = prepared is not None and prepared.fits(turned, tolerance)
        if prepared is not None and self.last_was_used:
            return prepared.models
        self._prepared = None
        return self._linearize(turned)


class CentralizedMpc:
    """The MPC of Section IV (Table I) on the whole 12 + 12N-state of the formation (the
    bar system's 36-state for N = 2); ``clock`` times each step (see ``Clock``)."""

    def __init__(
        self,
        params: FormationParams,
        settings: MpcSettings,
        backend: str | None = None,
        *,
        clock: Clock,
    ) -> None:
        self.params = params
        self.settings = settings
        self._clock = clock
        self._layout = params.layout
        jacobians = formation_jacobians(FormationModel(params))
        a_pattern, b_pattern = _patterns(jacobians)
        self._jacobians = NumericFunction(jacobians)
        self._mpc = LinearMpc(
            self._layout.n_states, self._layout.n_inputs, settings, a_pattern, b_pattern, backend
        )
        self._u_lb, self._u_ub = _input_bounds(settings, self._layout.n_vehicles)
        self._plans = _PlanKeeper()
        self._preparation = _ModelPreparation(
            self._layout, settings, lambda turned: (self._linearize(turned),), (self._mpc,)
        )
        layout = self._layout
        self._kinematics = Kinematics(
            (
                (P_B, V_B),
                *((layout.uav_slices(i)[0], layout.uav_slices(i)[1]) for i in layout.vehicles),
            ),
            ((PAYLOAD_YAW, 0), *((layout.uav_yaw_index(i), i) for i in layout.vehicles)),
        )

    def reset(self) -> None:
        """Forget the previous plan (e.g. after a controller switch)."""
        self._plans.previous = None

    def linearization(
        self, state: FloatArray, reference: FormationReference
    ) -> tuple[FloatArray, FloatArray]:
        """(A, B) of the discrete model at the reference equilibrium turned to the measured yaws."""
        return self._linearize(reference.with_yaws(*measured_yaws(state, self._layout)))

    def _linearize(self, turned: FormationReference) -> tuple[FloatArray, FloatArray]:
        lin = formation_equilibrium(self.params, turned)
        A_c, B_c = self._jacobians(lin.x, lin.u)
        return discretize(A_c, B_c, self.settings.dt_s)

    def prepare(self, state: FloatArray, reference: FormationReference) -> None:
        """Linearize for the next tick at ``state``'s yaws one step ahead and prepare the
        back-end for that model (see the module's docstring); never raises."""
        self._preparation.prepare(state, reference)

    @property
    def last_step_was_prepared(self) -> bool:
        """Whether the last ``step`` used the model of a ``prepare``."""
        return self._preparation.last_was_used

    @property
    def last_prepare_kept_models(self) -> bool:
        """Whether the last ``prepare`` kept the models it had (no new linearization)."""
        return self._preparation.last_kept

    def step(
        self,
        state: FloatArray,
        reference: FormationReference,
        now_s: float,
        preview: Preview | None = None,
        forces: ExternalForces = NO_FORCES,
    ) -> Plan:
        """One tick: u* for ``state`` (12 + 12N,, paper order) tracking ``reference`` now
        and, when given, ``preview``'s references at the stages ahead, its equilibria
        those under the external ``forces`` (``controllers.force_observer``)."""
        started = self._clock()
        try:
            eq = formation_equilibrium(self.params, reference, forces=forces)
        except ValueError as error:
            return self._plans.fallback(
                now_s, PlanStatus.SHIFTED_BAD_STATE, self._no_plan(now_s), str(error)
            )
        hold = _hold_plan(eq.u, eq.x, self.settings.horizon, now_s)
        if not _finite(state):
            return self._plans.fallback(
                now_s, PlanStatus.SHIFTED_BAD_STATE, hold, "state is not finite"
            )
        try:
            A, B = self._preparation.models(state, reference)[0]
            dx0 = wrap_angles(state - eq.x, self._layout.yaw_indices)
            targets = self._targets(eq.x, eq.u, reference, preview, forces)
            qp = self._mpc.qp(A, B, dx0, self._u_lb - eq.u, self._u_ub - eq.u, eq.x, targets)
            solution = self._mpc.backend.solve(qp)
        except Exception as error:
            return self._plans.fallback(now_s, PlanStatus.SHIFTED_ERROR, hold, repr(error))
        if solution.status is not QpStatus.SOLVED:
            return self._plans.fallback(
                now_s, PlanStatus.SHIFTED_FAILED, hold, solution.status.value
            )
        elapsed = self._clock() - started
        if elapsed > self.settings.late_after_s:
            return self._plans.fallback(
                now_s, PlanStatus.SHIFTED_LATE, hold, f"tick took {elapsed * 1e3:.1f} ms"
            )
        u_pred = np.clip(solution.u + eq.u, self._u_lb, self._u_ub)
        x_pred = solution.x + eq.x
        plan = Plan(
            u_pred[0].copy(),
            u_pred,
            x_pred,
            PlanStatus.OPTIMAL,
            now_s,
            elapsed,
            solution.iterations,
        )
        return self._plans.accept(plan)

    def _targets(
        self,
        x_eq: FloatArray,
        u_eq: FloatArray,
        reference: FormationReference,
        preview: Preview | None,
        forces: ExternalForces,
    ) -> tuple[FloatArray, FloatArray] | None:
        if not preview:
            return None
        sampled = _stage_equilibria(self.params, preview, forces)
        return stage_targets(
            x_eq,
            u_eq,
            reference,
            {k: (e.x, e.u) for k, e in sampled.items()},
            self.settings.horizon,
            self._kinematics,
            self.settings.dt_s,
        )

    def _no_plan(self, now_s: float) -> Plan:
        return _empty_plan(self._layout.n_states, self._layout.n_inputs, self.settings, now_s)


def _stage_equilibria(
    params: FormationParams, preview: Preview, forces: ExternalForces
) -> dict[int, FormationEquilibrium]:
    """The equilibrium of each stage's reference in ``preview`` under ``forces``."""
    return {
        k: formation_equilibrium(params, reference, remember=False, forces=forces)
        for k, reference in preview.items()
    }


def _empty_plan(nx: int, nu: int, settings: MpcSettings, now_s: float) -> Plan:
    """All zeros: what a first step holds when its reference has no equilibrium."""
    N = settings.horizon
    return Plan(
        np.zeros(nu), np.zeros((N, nu)), np.zeros((N + 1, nx)), PlanStatus.EQUILIBRIUM, now_s
    )


def agent_state(state: FloatArray, params: FormationParams, i: int) -> FloatArray:
    """UAV ``i``'s decentralized state x_i = (p_i, v_i, Θ_i, ω_i, p_p, v_p) from the
    formation's state: its cable's attachment e_i = p_b + q_i, q_i = R(Θ_b) a_i, and that
    point's velocity v_b + ω_b × q_i."""
    q_i = rotate_zyx(state[TH_B], params.payload.attachments_m[i - 1])
    x_i = np.empty(AGENT_STATES)
    x_i[UAV_BLOCK] = state[params.layout.uav_block(i)]
    x_i[P_P] = state[P_B] + q_i
    x_i[V_P] = state[V_B] + cross3(state[W_B], q_i)
    return x_i


# The yaw lead fades out towards θ_l = 45°: the bar's yaw swing quickens with θ_l (0.86 Hz
# hovering, 1.43 Hz at 45°), a fixed lead then overshoots in phase, and from about 45° on
# the agents damp that swing on their own (benchmarks/modes.py).
YAW_LEAD_FADE_RAD = math.pi / 4


def led_reference(
    reference: FormationReference, state: FloatArray, lead: ReferenceLead
) -> FormationReference:
    """``reference`` moved along the payload's measured motion (``ReferenceLead``): position
    by ``lead.position_s`` × (v_b − v_ref), yaw by the faded ``lead.yaw_s`` × (ω_b,z − ψ̇_ref)."""
    if lead.position_s == 0.0 and lead.yaw_s == 0.0:
        return reference
    velocity_error = state[V_B] - np.asarray(reference.velocity_mps)
    yaw_rate_error = float(state[W_B][2]) - reference.payload_yaw_rate_radps
    if not (_finite(velocity_error) and math.isfinite(yaw_rate_error)):
        return reference  # the step reports the bad state
    position = np.asarray(reference.payload_position_m) + lead.position_s * velocity_error
    fade = max(0.0, 1.0 - reference.cone_angle_rad / YAW_LEAD_FADE_RAD)
    return replace(
        reference,
        payload_position_m=(float(position[0]), float(position[1]), float(position[2])),
        payload_yaw_rad=reference.payload_yaw_rad + fade * lead.yaw_s * yaw_rate_error,
    )


class _Agent:
    """UAV i's own MPC on its 18-state UAV–payload model (Table II): its cable's attachment
    as a point mass, the cable's share of the payload's weight hanging still with vertical
    cables (``payload_mass_kg``; (13) for the bar)."""

    def __init__(
        self,
        params: FormationParams,
        settings: MpcSettings,
        i: int,
        payload_mass_kg: float,
        backend: str | None,
    ) -> None:
        self.i = i
        self.params = params
        self.settings = settings
        self.payload_mass_kg = payload_mass_kg
        model = PayloadModel(
            params.uavs[i - 1], payload_mass_kg, params.cable_lengths_m[i - 1], params.gravity_mps2
        )
        jacobians = payload_jacobians(model)
        a_pattern, b_pattern = _patterns(jacobians)
        self._jacobians = NumericFunction(jacobians)
        self.mpc = LinearMpc(AGENT_STATES, AGENT_INPUTS, settings, a_pattern, b_pattern, backend)
        self.u_lb, self.u_ub = _input_bounds(settings, 1)
        self.kinematics = Kinematics(((P_I, V_I), (P_P, V_P)), ((PAYLOAD_YAW, i),))
        """Where x_i keeps its bodies' motion (``controllers.preview``)."""

    def external_force(self, lin: AgentEquilibrium) -> FloatArray:
        """f_ext [N] that makes ``lin`` a fixed point of this agent's model (accelerating
        with the formation at ``lin``'s acceleration a): the pull of the rest of the
        payload, and the difference between the load the cable carries at ``lin`` and the
        model's payload mass under g and a (zero for a bar, and at a cone angle of 0)."""
        surplus_kg = self.payload_mass_kg - lin.payload_mass_share_kg
        gravity = np.array((0.0, 0.0, self.params.gravity_mps2))
        force: FloatArray = lin.payload_force_n + surplus_kg * (lin.acceleration_mps2 + gravity)
        return force

    def linearize(self, lin: AgentEquilibrium) -> tuple[FloatArray, FloatArray]:
        """(A, B) of the discrete 18-state model at this agent's equilibrium ``lin``."""
        A_c, B_c = self._jacobians(lin.x, lin.u, self.external_force(lin))
        return discretize(A_c, B_c, self.settings.dt_s)

    def solve(
        self,
        x_i: FloatArray,
        eq: AgentEquilibrium,
        model: tuple[FloatArray, FloatArray],
        targets: tuple[FloatArray, FloatArray] | None = None,
    ) -> tuple[FloatArray, FloatArray, int] | str:
        """(u_pred, x_pred, iterations) in absolute terms, or the failure text; ``targets``
        are the per-stage ones of a preview."""
        i = self.i
        x_eq, u_eq = eq.x, eq.u
        A, B = model
        dx0 = wrap_angles(x_i - x_eq, AGENT_YAW_INDICES)
        solution = self.mpc.backend.solve(
            self.mpc.qp(A, B, dx0, self.u_lb - u_eq, self.u_ub - u_eq, x_eq, targets)
        )
        if solution.status is not QpStatus.SOLVED:
            return f"UAV {i}: {solution.status.value}"
        u_pred = np.clip(solution.u + u_eq, self.u_lb, self.u_ub)
        return u_pred, solution.x + x_eq, solution.iterations


PeerInputs = Callable[[int, float], FloatArray | None]
"""Agent i's planned inputs from now (one row per stage ahead), as it told its peers; None
when it is not heard."""


class DecentralizedMpc:
    """N independent 18-state MPCs of Section V; each sees only its UAV and its cable's
    attachment. ``clock`` times each step (see ``Clock``). An agent's own process solves
    only ``own`` (None: every agent); the others' rows of the plan are their plans as
    ``peer_inputs`` gives them, else their equilibrium's."""

    def __init__(
        self,
        params: FormationParams,
        settings: MpcSettings,
        backend: str | None = None,
        *,
        clock: Clock,
        own: tuple[int, ...] | None = None,
        peer_inputs: PeerInputs | None = None,
    ) -> None:
        self.params = params
        self.settings = settings
        self._clock = clock
        self._layout = params.layout
        self._peer_inputs = peer_inputs
        shares = hanging_mass_shares_kg(params)
        solved = self._layout.vehicles if own is None else own
        self.agents = tuple(_Agent(params, settings, i, shares[i - 1], backend) for i in solved)
        self._plans = _PlanKeeper()
        self._preparation = _ModelPreparation(
            self._layout, settings, self._linearize, tuple(agent.mpc for agent in self.agents)
        )

    def reset(self) -> None:
        """Forget the previous plan (e.g. after a controller switch)."""
        self._plans.previous = None

    def _targets(
        self,
        eq: FormationEquilibrium,
        reference: FormationReference,
        preview: Preview | None,
        forces: ExternalForces,
    ) -> list[tuple[FloatArray, FloatArray] | None]:
        """Each agent's per-stage targets from ``preview`` (None each without one)."""
        if not preview:
            return [None] * len(self.agents)
        sampled = _stage_equilibria(self.params, preview, forces)
        return [
            stage_targets(
                eq.agent_state(agent.i),
                eq.agent_input(agent.i),
                reference,
                {k: (e.agent_state(agent.i), e.agent_input(agent.i)) for k, e in sampled.items()},
                self.settings.horizon,
                agent.kinematics,
                self.settings.dt_s,
            )
            for agent in self.agents
        ]

    def _linearize(self, turned: FormationReference) -> Models:
        lin = formation_equilibrium(self.params, turned)
        return tuple(agent.linearize(lin.agent(agent.i)) for agent in self.agents)

    def prepare(self, state: FloatArray, reference: FormationReference) -> None:
        """Linearize every agent for the next tick at ``state``'s yaws one step ahead and
        prepare their back-ends (see the module's docstring); never raises."""
        self._preparation.prepare(state, reference)

    @property
    def last_step_was_prepared(self) -> bool:
        """Whether the last ``step`` used the models of a ``prepare``."""
        return self._preparation.last_was_used

    @property
    def last_prepare_kept_models(self) -> bool:
        """Whether the last ``prepare`` kept the models it had (no new linearization)."""
        return self._preparation.last_kept

    def step(
        self,
        state: FloatArray,
        reference: FormationReference,
        now_s: float,
        preview: Preview | None = None,
        forces: ExternalForces = NO_FORCES,
    ) -> Plan:
        """One tick for every agent; ``state`` is the formation's (each agent takes its
        part). The agents regulate to ``reference`` moved by the settings'
        ``reference_lead`` and, when given, track ``preview``'s references at the stages
        ahead (moved the same way), their equilibria those under the external ``forces``:
        each agent's f_ext carries its cable's share of the payload's, its input the
        thrust against its own UAV's."""
        started = self._clock()
        led = led_reference(reference, state, self.settings.reference_lead)
        preview = moved_like(preview, reference, led) if preview else None
        reference = led
        try:
            eq = formation_equilibrium(self.params, reference, forces=forces)
        except ValueError as error:
            stacked = AGENT_STATES * self._layout.n_vehicles
            empty = _empty_plan(stacked, self._layout.n_inputs, self.settings, now_s)
            return self._plans.fallback(now_s, PlanStatus.SHIFTED_BAD_STATE, empty, str(error))
        stacked_eq = np.concatenate([eq.agent_state(agent.i) for agent in self.agents])
        hold = _hold_plan(eq.u, stacked_eq, self.settings.horizon, now_s)
        if not _finite(state):
            return self._plans.fallback(
                now_s, PlanStatus.SHIFTED_BAD_STATE, hold, "state is not finite"
            )
        try:
            models = self._preparation.models(state, reference)
            targets = self._targets(eq, reference, preview, forces)
            results = [
                agent.solve(
                    agent_state(state, self.params, agent.i), eq.agent(agent.i), model, target
                )
                for agent, model, target in zip(self.agents, models, targets, strict=True)
            ]
        except Exception as error:
            return self._plans.fallback(now_s, PlanStatus.SHIFTED_ERROR, hold, repr(error))
        failures = [r for r in results if isinstance(r, str)]
        if failures:
            return self._plans.fallback(now_s, PlanStatus.SHIFTED_FAILED, hold, "; ".join(failures))
        solved = {
            agent.i: r
            for agent, r in zip(self.agents, results, strict=True)
            if not isinstance(r, str)
        }
        elapsed = self._clock() - started
        if elapsed > self.settings.late_after_s:
            return self._plans.fallback(
                now_s, PlanStatus.SHIFTED_LATE, hold, f"tick took {elapsed * 1e3:.1f} ms"
            )
        parts = [solved.get(i) or self._peer_part(eq, i, now_s) for i in self._layout.vehicles]
        u_pred = np.hstack([u for u, _, _ in parts])
        x_pred = np.hstack([x for _, x, _ in parts])
        plan = Plan(
            u_pred[0].copy(),
            u_pred,
            x_pred,
            PlanStatus.OPTIMAL,
            now_s,
            elapsed,
            sum(iterations for _, _, iterations in solved.values()),
        )
        return self._plans.accept(plan)

    def _peer_part(
        self, eq: FormationEquilibrium, i: int, now_s: float
    ) -> tuple[FloatArray, FloatArray, int]:
        """Agent i's rows of the plan, solved in its own process: its inputs as it planned
        them (else its equilibrium's), its states at its equilibrium."""
        N = self.settings.horizon
        u_eq = eq.agent_input(i)
        planned = self._peer_inputs(i, now_s) if self._peer_inputs is not None else None
        u = np.tile(u_eq, (N, 1))
        if planned is not None and planned.shape[1:] == u_eq.shape and len(planned):
            k = min(len(planned), N)
            u[:k] = planned[:k]
            u[k:] = planned[k - 1]
        return u, np.tile(eq.agent_state(i), (N + 1, 1)), 0
