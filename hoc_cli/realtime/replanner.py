"""The real-time replanner of a catch: a few SQP steps per control cycle from the previous cycle's plan.

The real-time iteration (Diehl, Bock & Schlöder, "A real-time iteration scheme for nonlinear optimization in
optimal feedback control", SIAM J. Control Optim. 43(5), 2005) does not solve each cycle's problem to
convergence: it takes one (or a few) Newton-type steps from the previous cycle's solution shifted to the
current time, so the iterate tracks the moving optimum while the problem itself (here the ball's estimate)
converges. ``Replanner.update(t, x, target, budget_s)``:

1. shifts the plan in force to start at t from the robot's state x = (q, q̇) (``shift.shift_plan``: N elements
   on the remaining part, exactly the plan in force when its remaining duration is kept; the remaining duration
   stays free within the task's range, which is counted from the task's t = 0, or is held near the catch);
2. replaces the link goal by the target's latest estimate (position, velocity at t, constant acceleration);
3. takes the warm replan's SQP steps (``hoc_cli.goals.replan_qp.qp_steps``: exact Newton matrix, the goal
   rows linearised, the kinematic Bernstein rows near their bound as inequalities, T with them) from the
   shifted plan, the goal rows' and the limits' multipliers carried from the last cycle, until the
   programme's convergence test holds or the budget would be overrun: the first step unless the median of the
   measured first steps would not fit (then none, "skipped"), a further one only when the time spent plus the largest of the last measured step times
   (and of the wrap-up) fits in it; a step under way is stopped at the first of its checkpoints (``replan_qp.CHECKPOINTS``)
   from which the largest measured time to the step's end (and the wrap-up) would overrun it: the first step so
   stopped is "abandoned" (the plan in force kept), a later one ends the update at the last completed step;
4. returns a plan that passes ``check_limits`` (exact extrema of q, q̇, q̈ and the jerk, the torque at 32 points
   per element): its kinematic Bernstein rows are made to hold (``limits_guard.guard``), which bounds the
   kinematic kinds on the whole plan, and ``limits_guard.within_limits`` checks it (the extrema only where a row
   fixed by the start state is above its bound, the torques always); a plan that fails (the torque limits are
   not rows of the steps) is not returned: the plan in force is kept ("held"), which passed the same check when
   it was returned.

What one step guarantees: the step's programme imposes the Bernstein rows within 5 % of their bound as
linear inequalities, which they are in the coefficients at a fixed T; a full step at a fixed T therefore
meets them exactly (to the programme's rounding), a damped step from a point that met them too (convex
combination), and rows farther than 5 % from their bound hold unless one step crosses that gap. With a free
T the rows' dependence on T is linearised, so a step that moves T meets them to first order only. The
exact guarantee (every returned plan within its limits) comes from the guard and the check: the plan after the
steps is checked row by row; rows broken are projected back, at the plan's T, onto all the linear rows (a
least-distance programme, ``limits_guard.guard``), and the result must pass the check (``within_limits``, which
implies ``check_limits``); else the plan in force is kept.
Pure maths: no I/O.
"""
from __future__ import annotations

import dataclasses
import functools
import math
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from hoc_cli.dynamics import frame_jacobian, link_poses
from hoc_cli.elements import HermiteMesh
from hoc_cli.errors import NumericalError
from hoc_cli.goals.active_limits import ActiveRows, from_multipliers
from hoc_cli.goals.plan import Goals
from hoc_cli.goals.replan import DECREMENT_TOL, RHO_AUG, TimeRange
from hoc_cli.goals.replan_point import VIOLATION_FLOOR
from hoc_cli.goals.replan_qp import OutOfTime, qp_steps
from hoc_cli.goals.terms import GoalTerms
from hoc_cli.ocp.problem import Free, OptimalControlProblem
from hoc_cli.optimize.blas import one_thread
from hoc_cli.realtime.limits_guard import effort_only, guard, within_limits
from hoc_cli.realtime.shift import shift_plan

MIN_REMAINING = 1e-3  # [s] a plan shorter than this is not replanned (held)
HISTORY = 16  # step times remembered for the budget's prediction
GUARD_VIOLATION = 0.01  # [m, m/s] a projected plan farther than this from its goal rows, and farther than the
# shifted plan it started from, is not returned (held)


@dataclass(frozen=True)
class Target:
    """The ball's estimate at the update's time t: position (3,) [m], velocity (3,) [m/s], acceleration (3,) [m/s²]."""

    position: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray


class Deferred:
    """A number evaluated on first use: ``float(value)`` calls ``evaluate()`` (no arguments, a float) once and keeps it."""

    def __init__(self, evaluate: Callable[[], float]) -> None:
        self._evaluate: Callable[[], float] | None = evaluate
        self._value = math.nan

    def __float__(self) -> float:
        if self._evaluate is not None:
            self._value, self._evaluate = float(self._evaluate()), None
        return self._value


@dataclass(frozen=True, eq=False)
class CyclePlan:
    """A plan in force from the absolute time ``t0`` [s]: ``mesh`` on [0, T], ``coeffs`` (N+1, m, n), ``J`` its cost
    (``cost``: the number, or a ``Deferred`` that evaluates it on the first read of ``J``: the controller does not
    need it, so an update whose limits' guard projected its plan leaves the projected plan's cost to whoever reads it);
    ``J_steps`` the cost at the steps' last point (before the guard's projection; that of a cold plan, its J;
    ``steps_cost``: the number, or a ``Deferred``: the steps' last point is evaluated without its cost).

    Per update: ``steps`` SQP steps taken; ``status`` "converged" | "budget" (stopped by the time budget or the
    replanner's ``max_steps``) |
    "stalled" (the steps stopped: a step could not be evaluated or its programme had no solution) | "skipped" (the
    predicted first step did not fit in the budget: no step started, the plan in force kept) | "abandoned" (a step
    under way was stopped at a checkpoint from which its measured remaining time would have overrun the budget:
    the plan in force kept) | "held" (no
    time left, the start could not be evaluated, or the result failed the limits' check: the plan in force kept) | "cold" (the
    replanner's first plan); ``decrement`` the last programme's model decrease relative to |J| (at the point the
    last step started from: how far that point was from converged); ``violation`` max |c| over the goal rows
    [m, m/s] and ``stationarity`` max |∇ₓℒ| / max(|J|, 1) at the returned point (the KKT residual; ``kkt``: the
    number, or a ``Deferred`` evaluated when read, as the steps' last point is evaluated without ℒ's derivatives);
    ``guarded`` whether the limits' guard had to project; ``wall_time_s`` the update [s]; ``worked`` whether the
    update ran SQP work (its plan may still have been held or abandoned: its time counts as compute).
    """

    t0: float
    mesh: HermiteMesh
    coeffs: np.ndarray
    cost: float | Deferred
    steps: int = 0
    status: str = "cold"
    decrement: float = math.nan
    violation: float = math.nan
    kkt: float | Deferred = math.nan
    guarded: bool = False
    wall_time_s: float = 0.0
    worked: bool = False
    steps_cost: float | Deferred = math.nan

    @property
    def J_steps(self) -> float:
        """The cost at the steps' last point (``steps_cost``; a ``Deferred`` is evaluated now, once)."""
        return float(self.steps_cost)

    @property
    def J(self) -> float:
        """The plan's cost I (the problem's objective, without weight·T; a ``Deferred`` is evaluated now, once)."""
        return float(self.cost)

    @property
    def stationarity(self) -> float:
        """The KKT residual max |∇ₓℒ| / max(|J|, 1) at the returned point (``kkt``; a ``Deferred`` is evaluated now, once)."""
        return float(self.kkt)

    @property
    def T(self) -> float:
        return self.mesh.T

    @property
    def t_end(self) -> float:
        """The plan's end (the catch) [s], absolute."""
        return self.t0 + self.mesh.T

    def state(self, t, deriv: int = 0) -> np.ndarray:
        """The deriv-th time derivative of q at absolute times t (k,) → (k, n) (t clipped to the plan)."""
        local = np.clip(np.asarray(t, float) - self.t0, 0.0, self.mesh.T)
        return self.mesh.evaluate(self.coeffs, np.atleast_1d(local), deriv)


class Replanner:
    """The catch's plan updated every cycle (module docstring).

    problem : the ``OptimalControlProblem`` with a link goal (its target is replaced each update), a free T
        (``Free(min, max, weight)``, counted from the problem's t = 0), N, limits, cost;
    plan : its solution (``hoc_cli.solve``'s ``Plan``) starting at ``t0`` [s];
    max_steps : steps per update at most (besides the budget); warm_up : run ``warm_up`` first.
    """

    def __init__(self, problem: OptimalControlProblem, plan, *, t0: float = 0.0, max_steps: int = 20,
                 warm_up: bool = True) -> None:
        if problem.link_goal is None or not isinstance(problem.time, Free):
            raise ValueError("the replanner needs a problem with a link goal and a free T")
        self.problem, self.system, self.limits = problem, problem.system, problem.limits
        self.effort = effort_only(problem.limits) if problem.limits is not None else None
        self.free: Free = problem.time
        self.goals: Goals = plan.goals if plan.goals is not None else problem.goals()
        result = plan.result
        self.G = result.G
        self.max_steps = max_steps
        self.lam = [np.array(v, float) for v in result.terms.lam] if result.terms is not None else None
        pen = result.limits.penalty if result.limits is not None else None
        active = from_multipliers(pen) if pen is not None else ActiveRows.empty()
        self.active = active if active is not None else ActiveRows.empty()
        self.mu = self.active.gather(pen.mu_lo, pen.mu_hi) if pen is not None and active is not None else np.zeros(0)
        self.current = CyclePlan(t0=t0, mesh=result.mesh, coeffs=np.array(result.coeffs), cost=float(result.J),
                                 steps_cost=float(result.J))
        self.step_times: deque = deque(maxlen=HISTORY)  # between two steps of one update [s]
        self.first_times: deque = deque(maxlen=HISTORY)  # from the update's start to its first step's end [s]
        self.wrap_times: deque = deque(maxlen=HISTORY)  # from the last step to the return, of updates the budget or
        # ``max_steps`` ended (one that converged ends with the convergence test's Newton matrix and programme) [s]
        self.to_step_end: dict[str, deque] = {}  # per checkpoint of a step (``CHECKPOINTS``): from it to the step's end [s]
        if warm_up:
            self.warm_up()

    def warm_up(self) -> None:
        """Two updates of one step each on a copy of the first plan (its own target, a long budget): the first call of the step
        functions loads modules and fills caches, which would make the first measured step time (and so every
        budget prediction) far too long, so the first one's times are forgotten; the second one's are kept, so
        that the first real update can already be skipped or abandoned by them (``update``).
        """
        saved = (self.current, self.lam, self.active, self.mu)
        cur = self.current
        t = cur.t0 + 0.01 * cur.T
        final = self.goals.final
        p, v = final.target(t - cur.t0)
        target = Target(p, v, np.zeros(3) if final.acceleration is None else final.acceleration)
        max_steps, self.max_steps = self.max_steps, 1  # one step each: what a budget-bound update measures
        for _ in range(2):
            for times in (self.step_times, self.first_times, self.wrap_times):
                times.clear()
            self.to_step_end.clear()
            self.update(t, (cur.state(t)[0], cur.state(t, 1)[0]), target, 10.0)
            self.current, self.lam, self.active, self.mu = saved
        self.max_steps = max_steps

    def state(self) -> tuple:
        """What an update changes (the plan in force, the multipliers, the working set): for ``restore``."""
        return self.current, self.lam, self.active, self.mu

    def restore(self, saved: tuple) -> None:
        """Back to ``saved`` (``state()``): an update whose plan came too late to be applied is forgotten."""
        self.current, self.lam, self.active, self.mu = saved

    # -- the problem of an update -------------------------------------------------------------------------
    def time_range(self, t: float) -> TimeRange | None:
        """The remaining duration's range [s] at absolute time t (None when it is empty)."""
        lo, hi = max(self.free.min - t, MIN_REMAINING), self.free.max - t
        return TimeRange(lo, hi, self.free.weight) if hi > lo else None

    def goals_for(self, target: Target) -> Goals:
        """The link goal with the target's estimate (its time origin the update's t)."""
        return goals_with_target(self.goals, target)

    # -- the update ---------------------------------------------------------------------------------------
    def update(self, t: float, x, target: Target, budget_s: float, *, free_time: bool = True) -> CyclePlan:
        """The plan from the state x = (q (n,), q̇ (n,)) at absolute time t [s] towards ``target`` (its estimate
        at t), computed within ``budget_s`` [s] of wall time as far as the measured step times predict (the
        first step unless the median of the measured first steps does not fit: "skipped"). ``free_time`` False keeps the catch time of the plan in force
        (T = its remaining time): near the catch, where a step in T is far from linear. On one BLAS thread
        (``optimize.blas.one_thread``), as ``hoc_cli.solve``: numpy imported before hoc would otherwise run the
        step's small dense solves on several (the docs' example's step: about 4 times slower on 2 cores).
        """
        with one_thread():
            return self._update(t, x, target, budget_s, free_time)

    def _update(self, t: float, x, target: Target, budget_s: float, free_time: bool) -> CyclePlan:
        start = time.perf_counter()
        deadline = start + budget_s
        cur = self.current
        span = self.time_range(t)
        remaining = cur.t_end - t
        if span is None or remaining < MIN_REMAINING:
            return self._hold(start)
        if self._first_late(start, deadline):
            return self._hold(start, "skipped")
        shifted = shift_plan(cur.mesh, cur.coeffs, cur.t0, t, min(max(remaining, span.min), span.max) if free_time else None)
        mesh, C = shifted.mesh, shifted.coeffs
        q, dq = (np.asarray(v, float) for v in x[:2])
        C[0, 0], C[0, 1] = q, dq
        goals = self.goals_for(target)
        plan0 = _Start(mesh=mesh, problem=_Boundary((q, dq), self.problem.cost), G=self.G, coeffs=C)
        lam = [v.copy() for v in self.lam] if self.lam is not None else [np.zeros(goals.final.size)]
        active, mu = carry_rows(self.active, self.mu, shifted.parent)
        lam.append(mu)
        marks = [start]
        ended: list[bool] = []  # the steps were ended by ``stop`` (not by the convergence test)
        passed: dict[str, float] = {}  # the checkpoints the step under way has passed, and when

        def stop(steps: int) -> bool:
            now = time.perf_counter()
            (self.first_times if steps == 1 else self.step_times).append(now - marks[-1])
            marks.append(now)
            for name, then in passed.items():
                self.to_step_end.setdefault(name, deque(maxlen=HISTORY)).append(now - then)
            passed.clear()
            if steps >= self.max_steps or self._late(now, deadline):
                ended.append(True)
                return True
            return False

        def late(name: str) -> bool:
            now = time.perf_counter()
            passed[name] = now
            ahead = self.to_step_end.get(name)
            wrap = max(self.wrap_times) if self.wrap_times else 0.0
            if not ahead or now + max(ahead) + wrap <= deadline:
                return False
            ahead.remove(max(ahead))  # forgotten, so that one slow step cannot stop every later update
            return True

        try:
            out = qp_steps(self.system, plan0, goals, lam, active, free=span if free_time else None, limits=self.limits,
                           tol=DECREMENT_TOL, max_steps=self.max_steps, rho_aug=RHO_AUG, relative_rho=True,
                           floor=VIOLATION_FLOOR, stop=stop, quick=True, late=late)
        except OutOfTime:
            return self._hold(start, "abandoned", worked=True)
        except NumericalError:
            return self._hold(start, worked=True)
        pt = out.point
        npts = len(lam) - 1
        r = sum(v.size for v in out.lam[:npts])
        C_new, mesh_new = pt.C, pt.problem.mesh
        safe = C_new
        if self.limits is not None:  # the goal rows kept by the projection if it can, else the limits alone
            safe = None
            near: list = []  # the rows the first projection needed: the second one starts from them
            for keep in (pt.D[:r], None):
                C_try = guard(self.system, self.limits, pt.rows, C_new, pt.problem.layout.free, keep=keep, near=near)
                if C_try is not None and within_limits(self.system, self.limits, pt.rows, C_try, self.effort, rows_hold=True):
                    safe = C_try
                    break
                if C_try is C_new:  # the plan's own rows hold: only the effort limits fail, whatever the projection
                    break
        if safe is None:  # no projection found, or the effort limits (not rows of the steps) broken
            return self._hold(start, worked=True)
        guarded = safe is not C_new
        violation = float(np.max(np.abs(pt.c[:r]), initial=0.0))
        # the steps' last point's cost: when read if it was not evaluated there (``qp_steps``' last point: J NaN)
        steps_cost: float | Deferred = pt.J
        if not math.isfinite(pt.J):
            steps_cost = Deferred(functools.partial(pt.problem.value, pt.problem.layout.pack(C_new)))
        cost = steps_cost
        if guarded:  # the projected plan's own goal rows; its cost when it is read (``Deferred``)
            cost = Deferred(functools.partial(pt.problem.value, pt.problem.layout.pack(safe)))
            violation = GoalTerms(mesh_new, pt.problem.points, [np.zeros(p.residual.size) for p in pt.problem.points], 0.0,
                                  pt.where).violation(safe)
        if guarded and violation > GUARD_VIOLATION and violation > self._miss(mesh, C, goals):
            return self._hold(start, worked=True)  # the projection gave up the goal for a plan no closer to it than the shifted one
        self.lam, self.active, self.mu = [np.array(v) for v in out.lam[:npts]], out.active, np.array(out.lam[-1])
        status = "converged" if out.status.name == "CONVERGED" else "budget" if len(marks) > 1 else "stalled"
        kkt: float | Deferred = math.nan
        if pt.g is not None:
            kkt = float(np.max(np.abs(pt.g), initial=0.0)) / max(abs(pt.J), 1.0)
        elif out.derive is not None:  # the steps' last point was evaluated without ℒ's derivatives: when read
            kkt = Deferred(functools.partial(_stationarity, out.derive))
        now = time.perf_counter()
        if ended:
            self.wrap_times.append(now - marks[-1])
        self.current = CyclePlan(t0=t, mesh=mesh_new, coeffs=safe, cost=cost, steps_cost=steps_cost, steps=out.steps,
                                 status=status, decrement=out.decrement / max(abs(out.J_from), 1.0), violation=violation,
                                 kkt=kkt, guarded=guarded, wall_time_s=now - start, worked=True)
        return self.current

    def _late(self, now: float, deadline: float) -> bool:
        """Whether a step started now would end after the deadline, by the largest measured step (and wrap-up) time
        (the first step's time, which includes the shift, while no later step has been measured).
        """
        times = self.step_times or self.first_times
        if not times:
            return False
        wrap = max(self.wrap_times) if self.wrap_times else 0.0
        return now + max(times) + wrap > deadline

    def _miss(self, mesh: HermiteMesh, C: np.ndarray, goals: Goals) -> float:
        """The largest |c| [m, m/s] of the link goal's position and velocity rows for the plan (mesh, C) at its end."""
        final, link = goals.final, self.problem.link_goal.link
        q, dq = C[-1, :1], C[-1, 1:2]
        p = link_poses(self.system.model, q)[link][0, :3, 3]
        v = frame_jacobian(self.system.model, q, link)[0, :3] @ dq[0]
        pt, vt = final.target(mesh.T)
        return float(np.max(np.abs(np.concatenate([p - pt, v - vt]))))

    def _first_late(self, now: float, deadline: float) -> bool:
        """Whether the first step started now would end after the deadline, by the median of the measured first
        steps (with the shift) plus the largest wrap-up. A skipped update forgets the largest measured first step,
        so that one slow step cannot stop every later update.
        """
        if not self.first_times:
            return False
        wrap = max(self.wrap_times) if self.wrap_times else 0.0
        if now + float(np.median(self.first_times)) + wrap <= deadline:
            return False
        self.first_times.remove(max(self.first_times))
        return True

    def _hold(self, start: float, status: str = "held", worked: bool = False) -> CyclePlan:
        self.current = dataclasses.replace(self.current, steps=0, status=status, worked=worked,
                                           wall_time_s=time.perf_counter() - start)
        return self.current


def _stationarity(derive: Callable) -> float:
    """The KKT residual max |∇ₓℒ| / max(|J|, 1) at the point ``derive()`` evaluates with its derivatives (and J)."""
    pt = derive()
    return float(np.max(np.abs(pt.g), initial=0.0)) / max(abs(pt.J), 1.0)


def goals_with_target(goals: Goals, target: Target) -> Goals:
    """``goals`` with its link goal's target replaced by ``target`` (position, velocity, acceleration at time 0)."""
    final = dataclasses.replace(goals.final, position=np.asarray(target.position, float),
                                velocity=np.asarray(target.velocity, float),
                                acceleration=np.asarray(target.acceleration, float))
    return dataclasses.replace(goals, final=final)


def carry_rows(active: ActiveRows, mu: np.ndarray, parent: np.ndarray) -> tuple[ActiveRows, np.ndarray]:
    """The working set (and its multipliers μ (a,)) of a plan carried to its shifted plan: each row of an element
    goes to every new element inside it (``parent`` (N,): the old element of each new one).
    """
    old, new = [], []
    for e_new, e_old in enumerate(np.asarray(parent)):
        sel = np.flatnonzero(active.elem == e_old)
        old.append(sel)
        new.append(np.full(sel.size, e_new))
    sel = np.concatenate(old).astype(int) if old else np.zeros(0, int)
    elem = np.concatenate(new).astype(int) if new else np.zeros(0, int)
    rows = ActiveRows(active.kind[sel], elem, active.row[sel], active.joint[sel], active.side[sel])
    return rows, np.asarray(mu, float)[sel]


@dataclass(frozen=True, eq=False)
class _Boundary:
    """What ``qp_steps`` reads of its starting plan's problem: the start state (q0, q̇0) and the cost's name."""

    boundary: tuple
    cost: str


@dataclass(frozen=True, eq=False)
class _Start:
    """What ``qp_steps`` reads of its starting plan: mesh, problem (start state, cost), G, coefficients; no factor."""

    mesh: HermiteMesh
    problem: _Boundary
    G: int | None
    coeffs: np.ndarray
    newton_factor: None = None
