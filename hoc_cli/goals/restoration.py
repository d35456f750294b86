"""Feasibility restoration for a free T: a T at which the goal rows can be met within the kinematic limits.

The free-T SQP (``hoc_cli.goals.free_time_sqp``) first plans at the guess T. When the goal rows cannot be met
there within the limits (a fast catch: the arm cannot reach the target's position and velocity at T = guess
without breaking a velocity limit), every step at that T trades one violation for another and the steps never
converge. Here T moves instead: a Levenberg-Marquardt (Gauss-Newton) method minimises the violation

    m(x, T) = ½ Σ c_i² + ½ Σ max(0, g_j + κ)²

over the free Hermite coefficients x (s = t/T domain) and, when asked, T in [T_min, T_max]: c the goal rows (m,
rad, m/s), g the kinematic Bernstein rows of ``hoc_cli.goals.active_limits`` (dimensionless, relative to the
limit's size; g ≤ 0 within the limit), κ a margin (the rows tightened by κ of the limit's size, so that the T
found leaves the plan room inside the true limits). Each step's programme imposes the rows near their bound
(within 5 %) as linear inequalities that cut the broken ones by a fraction τ (1, halved with each rejected
trial, doubled after an accepted one: from far outside, a full correction of the limits in one step can throw
the goal rows off). A trial that is rejected and breaks rows the programme left out is solved again with those rows
in it (up to ``WIDEN`` times a step, σ and τ kept): a full step of the goal rows breaks rows well inside their bound
(on the UR5's fast catch up to 44 % of the limit's size from 5 % inside), which steps that do not see them then cut
slowly (21 restoration steps there on 4 elements instead of 13, 44 on 8 instead of 15, 97 on 16 instead of 18). A trial
whose limit rows alone leave the ratio below ¼ (½Σmax(0, g + κ)² ≥ m − ¼·predicted) is re-solved so without the goal
rows' forward kinematics at it (the same decisions: on the catch's 8 elements 22 goal-row evaluations for 38
programmes), and the re-solves of a step at the same σ share the factor of JᵀJ + σS. The
residual's Jacobian is exact in x (the goal rows' exact Jacobian, the Bernstein rows are linear) and in T along the
rescaled family (``_time_column``: the goal rows' ``GoalTerms.time_slopes``; a Bernstein row of d^k q/dt^k scales as
T^−k); each step solves (JᵀJ + σS) d = −JᵀR with S the diagonal of JᵀJ (Marquardt's
scaling) plus a floor, and σ follows the ratio of the actual to the predicted decrease of m (×4 when below ¼, ÷3
above ¾; Nocedal & Wright, *Numerical Optimization*, §10.3). T is clipped to its range.

It ends ``feasible`` when every goal row is met to ``tol`` and every tightened row to ``tol``, ``stalled``
when the predicted decrease of a step falls below 1e-12 of m or σ passes ``SIGMA_MAX`` (a local minimum of the
violation, or steps the rows at their bound block: infeasible there), or neither, after ``max_steps`` or a
step's programme that admits no step. Pure maths: no I/O.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from hoc_cli.errors import NumericalError
from hoc_cli.free_time import fixed_coefficient_motion, rescale, row_time_derivatives
from hoc_cli.goals.active_limits import ActiveRows, kinematic_rows
from hoc_cli.goals.mesh import mesh_fractions, scaled_mesh
from hoc_cli.goals.qp_step import solve_qp, upper_factor
from hoc_cli.goals.replan_point import limit_rows as build_limit_rows
from hoc_cli.goals.replan_point import point_problem, rows_on
from hoc_cli.goals.terms import GoalTerms, point_set

_log = logging.getLogger(__name__)  # solver traces at DEBUG level (docs/design.md)
MARGIN = 0.05  # κ: the rows tightened by this fraction of the limit's size
TOL = 1e-9  # the goal rows (m, rad, m/s) and the tightened rows (relative) met to this: feasible
GAP = 0.05  # the rows within this (relative) of the tightened bound enter each step's programme
STALL_RTOL = 1e-12  # a step whose predicted decrease is below this·m: a local minimum of the violation
SIGMA_MAX = 1e12  # σ beyond which no step decreases m: a local minimum of the violation
WIDEN = 3  # re-solves of a step's programme with the rows its rejected trial broke (module docstring)
MAX_STEPS = 200  # steps before the restoration gives up (the UR5's fast catch restored on its mesh: 15 steps on 8 elements,
# 15 on 10, 18 on 16; on 4 elements 13)


@dataclass(frozen=True, eq=False)
class Restoration:
    """Where the restoration ended: T [s], the coefficients C (N+1, m, n) on the mesh at T, the largest goal-row
    violation and the largest tightened limit row (g + κ; ≤ 0 within), ``feasible``, the steps taken, ``stalled``:
    not feasible at a local minimum of the violation (no step decreases m), as opposed to a step's programme that
    failed or ``max_steps``.
    """

    T: float
    coeffs: np.ndarray
    violation: float
    row_violation: float
    feasible: bool
    steps: int
    stalled: bool = False


def restore(system, plan0, goals, limits, *, span=None, margin: float = MARGIN, tol: float = TOL,
            max_steps: int = MAX_STEPS) -> Restoration:
    """Minimise the violation m(x, T) from the plan ``plan0`` (a ``GoalResult``: its mesh, coefficients, G,
    cost, x0) over x, and over T in ``span`` (a ``TimeRange``) when given (module docstring); ``limits``: the
    enforced ``JointLimits`` (its kinematic rows enter m).
    """
    mesh0, problem0 = plan0.mesh, plan0.problem
    order, N, G, cost = mesh0.order, mesh0.N, plan0.G, problem0.cost
    fractions = mesh_fractions(mesh0)
    q0, dq0 = problem0.boundary[:2]
    lam = [np.zeros(p.residual.size) for p in problem0.points]
    r = sum(v.size for v in lam)
    cache: dict = {}

    def problem_at(T_: float) -> tuple:
        """(problem, limit rows, the goal points' ``PointSet``) at T_, kept in ``cache``: ``point_problem``'s at the
        first T; at any other only the mesh, its limit rows (``rows_on``: rescaled) and its point set (on first use,
        ``_AtT.where``; None in the tuple) are new, the problem's layout, fixed coefficients and goal points (which do
        not depend on T) are the first's (``_AtT``), its quadrature is never read.
        """
        if T_ not in cache:
            if not cache:
                return point_problem(system, order, N, T_, q0, dq0, goals, cost, G, limits, cache, fractions)
            first, rows0, _ = next(iter(cache.values()))
            mesh = scaled_mesh(order, T_, N, fractions)
            rows = rows_on(rows0, mesh)
            if rows is None and limits is not None:
                rows = build_limit_rows(mesh, first.layout.free, limits.n)
            cache[T_] = (_AtT(mesh, first), rows, None)  # its point set made when the goal rows are (``_AtT.where``)
        return cache[T_]

    def limit_part(T_: float, C_: np.ndarray) -> tuple:
        """(problem, rows, where, C (N+1, m, n) with the fixed coefficients set, g + κ per kind, Σ max(0, g + κ)²) at
        (C_, T_): m's limit rows alone, without the goal rows' kinematics.
        """
        problem, rows, where = problem_at(T_)
        C = problem.coefficients(problem.layout.pack(C_))
        g_lo, g_hi = kinematic_rows(limits, rows, C)
        g = [v + margin for v in g_lo + g_hi]
        return problem, rows, where, C, g, sum(float(np.sum(np.maximum(v, 0.0) ** 2)) for v in g)

    def at(T_: float, C_: np.ndarray, part: tuple | None = None) -> _Point:
        """The restoration at (C_, T_) (``part``: ``limit_part`` there, when made)."""
        problem, rows, where, C, g, over = limit_part(T_, C_) if part is None else part
        pt = _goal_rows(problem, problem.where if isinstance(problem, _AtT) else where, C, lam)
        c = pt.c[:r]
        return _Point(pt, T_, rows, g, 0.5 * float(c @ c) + 0.5 * over, float(np.max(np.abs(c), initial=0.0)),
                      max(float(np.max(v, initial=-math.inf)) for v in g))

    def limit_rows(p: _Point, select: ActiveRows) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(g + κ (a,), ∂g/∂x (a, P), A_full (a, P_all): ∂g/∂C of every coefficient) of the selected rows at p."""
        A, A_full = select.jacobian(p.rows, limits, p.pt.problem.layout.free)
        return A_full @ p.pt.C.ravel() + select.offsets(limits) + margin, A, A_full

    p = at(mesh0.T, np.array(plan0.coeffs))
    sigma, tau, steps, why = 1e-3, 1.0, 0, ""
    while not (p.violation <= tol and p.row_violation <= tol) and steps < max_steps:
        half = len(p.g) // 2
        masks = [v > -GAP for v in p.g]  # the rows in the programme: lower per kind, then upper
        T, pt = p.T, p.pt
        E0, c = pt.D[:r], pt.c[:r]
        P = pt.x.size
        trial, why, widened, build = None, "stalled", 0, True  # (σ beyond SIGMA_MAX: no step decreases m)
        factor = None  # (σ, the factor of JᵀJ + σS): a widened programme keeps E, hence JᵀJ, S and this
        while trial is None and sigma <= SIGMA_MAX:
            if build:  # the programme of the rows in ``masks``: their values, Jacobian and T column
                select = ActiveRows.where(tuple(masks[:half]), tuple(masks[half:]))
                gA, A, A_full = limit_rows(p, select)
                E = E0
                b = -gA + (1.0 - tau) * np.maximum(gA, 0.0)
                if span is not None:
                    c_T, g_T = _time_column(pt, A_full, select.kind, T)
                    E = np.hstack([E, c_T[:r, None]])
                    A = np.hstack([A, g_T[:, None]])
                    bounds = np.zeros((2, P + 1))
                    bounds[0, -1], bounds[1, -1] = 1.0, -1.0
                    A = np.vstack([A, bounds])
                    b = np.concatenate([b, [span.max - T, T - span.min]])
                JtJ, grad = E.T @ E, E.T @ c
                scale = np.diag(JtJ) + 1e-9 * max(float(np.mean(np.diag(JtJ))), 1e-300)  # Marquardt's, with a floor
                build = False
            b[:gA.size] = -gA + (1.0 - tau) * np.maximum(gA, 0.0)
            try:
                if factor is None or factor[0] != sigma:
                    factor = sigma, upper_factor(JtJ + sigma * np.diag(scale))
                d = solve_qp(factor[1], grad, np.zeros((0, grad.size)), np.zeros(0),
                             A, b).d
            except NumericalError:
                why = "failed"
                break
            rows_after = np.maximum(gA + A[:gA.size] @ d, 0.0)
            predicted = p.m - 0.5 * float(np.sum((c + E @ d) ** 2)) - 0.5 * float(rows_after @ rows_after)
            if predicted <= STALL_RTOL * p.m:
                why = "stalled"
                break
            T_try = T if span is None else min(max(T + float(d[P]), span.min), span.max)
            try:
                part = limit_part(T_try, rescale(pt.problem.coefficients(pt.x + d[:P]), T, T_try))
                if widened < WIDEN and p.m - 0.5 * part[5] < 0.2 * predicted:  # rejected on its limit rows alone
                    broken = [(g > 0.0) & ~m for g, m in zip(part[4], masks)]
                    if any(x.any() for x in broken):  # the widening below, without the goal rows' kinematics there
                        masks = [m | x for m, x in zip(masks, broken)]
                        widened, build = widened + 1, True
                        continue
                candidate = at(T_try, None, part)
                ratio = (p.m - candidate.m) / predicted
            except NumericalError:
                candidate, ratio = None, -math.inf
            if ratio <= 0.25 and candidate is not None and widened < WIDEN:  # the rows it broke join the programme
                broken = [(g > 0.0) & ~m for g, m in zip(candidate.g, masks)]
                if any(x.any() for x in broken):
                    masks = [m | x for m, x in zip(masks, broken)]
                    widened, build = widened + 1, True
                    continue
            if ratio > 0.25:
                trial = candidate
                sigma = sigma / 3.0 if ratio > 0.75 else sigma
                tau = min(1.0, 2.0 * tau)
            else:
                sigma, tau = 4.0 * sigma, 0.5 * tau
        if _log.isEnabledFor(logging.DEBUG):
            _log.debug(f"restoration step {steps} T {T:.6f} m {p.m:.3e} goal rows {p.violation:.1e} "
                       f"limit rows {p.row_violation:.1e} sigma {sigma:.1e}")
        if trial is None:
            break
        steps, p, why = steps + 1, trial, ""
    feasible = p.violation <= tol and p.row_violation <= tol
    return Restoration(T=p.T, coeffs=p.pt.C, violation=p.violation, row_violation=p.row_violation,
                       feasible=feasible, steps=steps, stalled=not feasible and why == "stalled")


@dataclass(frozen=True, eq=False)
class _AtT:
    """The restoration's problem at another T: the mesh there, and the layout, fixed coefficients (t-domain values) and
    goal points of ``first`` (a ``GoalProblem`` at the first T), which do not depend on T.
    """

    mesh: object
    first: object

    @property
    def layout(self):
        return self.first.layout

    @property
    def points(self) -> list:
        return self.first.points

    def coefficients(self, x: np.ndarray) -> np.ndarray:
        """C (N+1, m, n) from the free coefficients x (P,): ``GoalProblem.coefficients``."""
        return self.first.coefficients(x)

    @cached_property
    def where(self):
        """The goal points' ``PointSet`` on the mesh (None without points), made on first use: a trial whose limit rows
        alone reject it never needs it.
        """
        return point_set(self.mesh, self.first.points) if self.first.points else None


@dataclass(frozen=True, eq=False)
class _GoalRows:
    """The goal rows at one (x, T): the problem (its mesh at T), the free coefficients x (P,), C (N+1, m, n), the rows
    c (r,), their ``GoalTerms`` and residuals (``GoalTerms.residuals``), and (``D``) their Jacobian (r, P) in x.
    """

    problem: object
    x: np.ndarray
    C: np.ndarray
    c: np.ndarray
    terms: object = None
    res: list | None = None

    @cached_property
    def D(self) -> np.ndarray:
        """∂c/∂x (r, P), made on first use: a trial the restoration rejects never needs it."""
        if self.terms is None:
            return np.zeros((0, self.x.size))
        dc = self.terms.jacobian(self.C, self.res)[1]
        return dc.reshape(self.c.size, -1)[:, self.problem.layout.free]


def _goal_rows(problem, where, C: np.ndarray, lam: list) -> _GoalRows:
    """The goal rows at coefficients C on the problem's mesh: the numbers of ``replan_point.evaluate_point`` (the same
    ``GoalTerms`` calls) without its dynamics sweep, which the violation m does not need.
    """
    x = problem.layout.pack(C)
    C = problem.coefficients(x)
    if not problem.points:
        return _GoalRows(problem, x, C, np.zeros(0))
    terms = GoalTerms(problem.mesh, problem.points, lam, 0.0, where)
    res = terms.residuals(C)
    return _GoalRows(problem, x, C, np.concatenate([r[0] for r in res]), terms, res)


def _time_column(pt: _GoalRows, A_full: np.ndarray, kind: np.ndarray, T: float) -> tuple[np.ndarray, np.ndarray]:
    """(c' (r,), g' (a,)): the T derivatives of the goal rows and of the limit rows A_full·C + offsets (A_full (a, P_all),
    ``kind`` (a,) their derivative orders) at ``pt`` along the rescaled family (``free_time.rescale``: fixed s-domain free
    coefficients, the fixed ones at their t-domain values), exact: ``GoalTerms.time_slopes`` and
    ``free_time.row_time_derivatives`` (a row of d^k q/dt^k scales as T^−k).
    """
    V1, _ = fixed_coefficient_motion(pt.problem.layout.free, pt.C, T)
    c_T = pt.terms.time_slopes(pt.C, T, V1, pt.res) if pt.terms is not None else np.zeros(0)
    return c_T, row_time_derivatives(A_full @ pt.C.ravel(), kind, T, A_full @ V1.ravel())[0]


@dataclass(frozen=True, eq=False)
class _Point:
    """The restoration at one (x, T): the goal rows (``_GoalRows``), T, the mesh's limit rows, every
    kinematic row's g + κ (lower rows per kind, then upper), m, the largest |c| and the largest g + κ.
    """

    pt: object
    T: float
    rows: object
    g: list
    m: float
    violation: float
    row_violation: float
