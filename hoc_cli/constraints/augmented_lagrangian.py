"""Limits enforced: the unconstrained solve, an SQP on the kinematic rows, an augmented Lagrangian.

``enforce`` with ``use_sqp`` (the planner's default) first runs the unconstrained solve (when no
limit is known to bind), then ``sqp.sqp`` on the linear position/velocity/acceleration rows; the
augmented-Lagrangian loop below takes over only when an effort limit binds or the SQP fails (an
infeasible task) or stalls (its QP's accuracy reached before its stopping test held: the loop goes
on from the SQP's point and multipliers). Without ``use_sqp`` (goal problems) the loop below does
everything.

Warm starts (``duals``: a previous converged solve's multipliers, e.g. the coarser level's of a
continuation or the same mesh's before more Gauss points). They are carried to this mesh by
``prolong`` (the multiplier density per unit time transfers) and start the SQP's first QP where,
started from λ = 0, it would need H's modification: with the rows active at the optimum in its first
Newton matrix, the torque cost's indefinite H needs none, and the SQP gets near the optimum where,
started with λ = 0, it handed over. The loop below
starts from them (with ρ = ``WARM_RHO``·ρ0) only when they are on this mesh (a re-solve with more
Gauss points, or the SQP's own multipliers after it stalled): a coarser mesh's multipliers with a
large ρ made the first inner solve stiff (light-wristed arms, measured), and with ρ0 that solve
leaves the limited optimum as a cold start does. A warm loop that does not converge is run again
cold.

The augmented-Lagrangian loop is ``auglag.minimize`` with the limits as its term (``LimitTerm``:
Φ(x; λ, ρ) of ``LimitTerms``). Every constraint row lies in one element, so Φ's curvature only adds
to the element blocks of the banded Newton matrix. What the limits add to the loop:

1. A working set of (kind, joint) pairs whose rows are imposed. The first inner solve has an empty
   one (unless a coarser level found one): it IS the unconstrained solve, so a task whose optimum
   respects its limits pays nothing but the check. ρ0 = ``RHO_START``·|J|/T when the first pair binds.
2. The check of each plan (``check_limits``: exact extrema of q_h, q̇_h, q̈_h, q⃛_h per element, u at 32
   points per element). (kind, joint) pairs found beyond their bounds join the working set; an effort
   pair without multipliers whose torques stay ``EFFORT_SLACK``·σ inside its limit leaves it (its
   rows would cost the dynamics at 32 points per element in every evaluation and add nothing; the
   check brings it back if broken), so a level can again go to the SQP.
3. λ ← max(0, λ + ρ_w g) per row (box rows).
4. The stopping test: every value within its true bounds (the imposed bounds are tightened by a
   relative margin ``MARGIN``, so the plan ends strictly inside) and the complementarity Σ μ|g| below
   tol·|J|. A task whose violations no longer fall once ρ has grown ``auglag.RHO_RANGE``-fold is
   infeasible, and the least-violating plan found is returned; from a start within the limits the
   start is returned instead, not converged (the iteration stalled).
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Callable

import numpy as np

from hoc_cli.constraints import auglag
from hoc_cli.constraints.auglag import Measure, Penalized
from hoc_cli.constraints.bounds import KINDS, JointLimits
from hoc_cli.constraints.check import LimitCheck, check_limits
from hoc_cli.constraints.penalty import EFFORT, LimitRows, LimitTerms, PenaltyValue

if TYPE_CHECKING:  # the SQP and the multipliers' prolongation load when a solve reaches them (start-up)
    from hoc_cli.constraints.prolong import Duals

MARGIN = 1e-9  # relative inward margin of the imposed bounds
RHO_START = 10.0  # ρ0 = RHO_START·|J|/T: the penalty per unit time starts at ten times the cost rate
WARM_RHO = 100.0  # ... and at WARM_RHO·ρ0 when the multipliers start from a previous solve's (``Duals``)
SQP_ROUNDS = 4  # SQP runs, each with the pairs found broken by the previous one added
EFFORT_SLACK = 0.1  # an effort pair without multipliers whose torques stay this fraction of σ inside leaves the working set


@dataclass(frozen=True, eq=False)
class EnforceResult:
    """The outcome of the outer loop.

    status : "converged" | "infeasible" | "not_converged"; message : which test held or failed;
    inner : the last inner OptimizeResult; x : the plan's design vector; J : I(q_h) without Φ;
    outer_iterations; rho; check : the LimitCheck of the plan; working : (K, n) pairs imposed;
    rows : the LimitRows; penalty : Φ's terms at the plan (multipliers μ per row);
    sqp : "converged" (the SQP decided the plan), "handed_over" (it failed and the augmented
    Lagrangian took over), "stalled" or "crawled" (it stopped within the kinematic limits, at its
    QP's accuracy or converging too slowly; the augmented Lagrangian went on from its point and
    multipliers), or "" (not tried: no kinematic limit binds, an effort limit does, or the caller
    did not ask for it).
    """

    status: str
    message: str
    inner: object
    x: np.ndarray
    J: float
    outer_iterations: int
    rho: float
    check: LimitCheck
    working: np.ndarray
    rows: LimitRows
    penalty: PenaltyValue | None
    sqp: str = ""

    def duals(self) -> Duals | None:
        """The plan's multipliers on its rows: the warm start of the next solve, on this or another mesh (None: no rows)."""
        if self.penalty is None or not self.working.any():
            return None
        from hoc_cli.constraints.prolong import Duals

        return Duals(self.rows, self.penalty.mu_lo, self.penalty.mu_hi)

    def active_limits(self) -> list[dict]:
        """(joint, kind, intervals [[t0, t1], …] [s]) where a multiplier is positive at the optimum.

        Kinematic rows stand for a part of an element (1/pieces of it), effort rows for a point;
        adjacent active parts are merged.
        """
        if self.penalty is None:
            return []
        mesh = self.rows.mesh
        out = []
        for k, kind in enumerate(KINDS):
            mu = self.penalty.mu_lo[k] + self.penalty.mu_hi[k]
            for j, name in enumerate(self.check.limits.joints):
                if k == EFFORT:
                    on = mu[:, j] > 0
                    t = self.rows.points.t[on]
                    spans = np.stack([t, t], axis=1)
                    gap = 1.5 * float(mesh.hs.max()) / 32
                else:
                    on = mu[:, :, j] > 0  # (N, R)
                    e, r = np.nonzero(on)
                    part = self.rows.part[k][r]
                    t0 = mesh.time_of(e, part / self.rows.pieces)
                    spans = np.unique(np.stack([t0, t0 + mesh.hs[e] / self.rows.pieces], axis=1), axis=0)
                    gap = 1e-12 * mesh.T
                if spans.size == 0:
                    continue
                spans = spans[np.argsort(spans[:, 0])]
                merged = [list(spans[0])]
                for a, b in spans[1:]:
                    if a <= merged[-1][1] + gap:
                        merged[-1][1] = max(merged[-1][1], b)
                    else:
                        merged.append([a, b])
                out.append({"joint": name, "kind": kind, "intervals": [[float(a), float(b)] for a, b in merged]})
        return out


def shortest_duration(limits: JointLimits, q0, dq0, q1, dq1) -> tuple[float, str, str] | None:
    """A lower bound on T from one joint: |Δq|/v (velocity) or, rest to rest, 2√(|Δq|/a) (acceleration)
    or ∛(12 |Δq|/j) (jerk).

    The jerk bound: with q̇(0) = q̇(T) = 0 and the end accelerations free (they are free coefficients of
    quintic elements), Δq = ∫ (T/2 − t) q̈ dt = −∫ F q⃛ dt with F(t) = t(T − t)/2 ≥ 0 (integration by
    parts, ∫ q̈ = 0), so |Δq| ≤ j ∫ F dt = j T³/12, with equality for q̈ falling linearly at rate j.
    Returns (T_min [s], joint, kind) for the largest such bound, or None when no joint has one.
    """
    dq = np.abs(np.asarray(q1, float) - np.asarray(q0, float))
    rest = (np.asarray(dq0) == 0) & (np.asarray(dq1) == 0)
    best = None
    with np.errstate(divide="ignore", invalid="ignore"):
        bounds = (("velocity", np.where(np.isfinite(limits.velocity), dq / limits.velocity, 0.0)),
                  ("acceleration", np.where(np.isfinite(limits.acceleration) & rest,
                                            2.0 * np.sqrt(dq / limits.acceleration), 0.0)),
                  ("jerk", np.where(np.isfinite(limits.jerk) & rest, np.cbrt(12.0 * dq / limits.jerk), 0.0)))
    for kind, arr in bounds:
        j = int(np.argmax(arr)) if arr.size else 0
        if arr.size and arr[j] > 0 and (best is None or arr[j] > best[0]):
            best = (float(arr[j]), limits.joints[j], kind)
    return best


def _zeros(rows: LimitRows, n: int) -> tuple[np.ndarray, ...]:
    return tuple(np.zeros(rows.shape(k, n)) for k in range(len(KINDS)))


def _violated(check: LimitCheck) -> np.ndarray:
    """(K, n) bool: the (kind, joint) pairs the check finds beyond their bounds."""
    return ((check.hi_excess > 0) | (check.lo_excess > 0)).any(axis=1)


def _sqp_phase(base, system, limits: JointLimits, x: np.ndarray, tol: float,
               inner_solve: Callable[[object, np.ndarray, float], object], working: np.ndarray,
               record: Callable[[object], None] | None, duals: Duals | None = None):
    """The unconstrained solve (when nothing is known to bind), then the SQP on the kinematic rows.

    ``duals`` (a previous solve's multipliers, on any mesh) start the first QP's multipliers where,
    started from 0, it needs H's modification (``sqp``).
    Returns (outcome, x, working): outcome an EnforceResult when the plan is decided here, else
    "handed_over" (the SQP failed, e.g. an infeasible task), ("stalled" or "crawled", ``Duals``)
    (the SQP stopped within the kinematic limits, not converged: its multipliers) or None (not
    tried, or an effort limit is broken), with the point and working set the augmented-Lagrangian
    loop continues from.
    """
    mesh, n = base.mesh, limits.n
    first = not working.any()  # no pair known to bind yet (the plan's first level)
    if first:  # exactly the unconstrained solve: no price when nothing binds
        res = inner_solve(base, x, tol)
        x = res.x
        C = base.coefficients(x)
        check = check_limits(system, limits, mesh, C)
        violated = _violated(check)
        if not violated.any():
            rows = LimitRows.build(mesh, base.layout.free, n)
            empty = np.zeros((len(KINDS), n), bool)
            pv = LimitTerms(system, limits, rows, empty, _zeros(rows, n), _zeros(rows, n), 1.0,
                            MARGIN).evaluate(C, grad=False)
            ok = res.converged
            message = (f"{res.message}; every limit holds (outer iterations: 1)" if ok
                       else f"every limit holds, but the inner solve stopped: {res.message}")
            return EnforceResult(status="converged" if ok else "not_converged", message=message, inner=res, x=x,
                                 J=base.evaluate(x, grad=False).J, outer_iterations=1, rho=0.0, check=check,
                                 working=working, rows=rows, penalty=pv), x, working
        if res.status.value in ("max_iter", "not_finite"):
            return None, x, working | violated
        working = working | violated
    if working[EFFORT].any():
        return None, x, working
    from hoc_cli.constraints.prolong import Duals, prolong
    from hoc_cli.constraints.sqp import kinematic_working, sqp

    if not kinematic_working(limits).any():
        return None, x, working
    x_start = x
    for _ in range(SQP_ROUNDS):  # the SQP imposes the working set's rows; pairs the check finds broken join
        warm = None if duals is None else prolong(duals, LimitRows.build(mesh, base.layout.free, n))
        s = sqp(base, system, limits, x, tol, margin=MARGIN, working=None if first else working, multipliers=warm)
        if record is not None:
            record(s.result)
        duals = Duals(s.rows, s.penalty.mu_lo, s.penalty.mu_hi)
        if not s.ok:  # the augmented Lagrangian starts where the SQP did (its steps may have been poor)
            return "handed_over", x_start, working
        x = s.result.x
        C = base.coefficients(x)
        check = check_limits(system, limits, mesh, C)
        violated = _violated(check)
        active = np.stack([((lo + hi) > 0).reshape(-1, n).any(axis=0) for lo, hi in zip(s.penalty.mu_lo, s.penalty.mu_hi)])
        working = working | violated | active
        if not violated.any() or violated[EFFORT].any():
            break
    if violated.any():
        return None, x, working
    if not s.result.converged:  # stalled or out of iterations, within the kinematic limits: its multipliers go on
        return ("crawled" if s.crawled else "stalled", duals), x, working
    ok = s.result.converged
    message = (f"{s.result.message}; every limit holds (SQP iterations: {s.result.iterations})" if ok
               else f"every limit holds, but the SQP stopped: {s.result.message}")
    return EnforceResult(status="converged" if ok else "not_converged", message=message, inner=s.result, x=x,
                         J=s.result.fun, outer_iterations=s.result.iterations, rho=0.0,
                         check=check, working=working, rows=s.rows, penalty=s.penalty, sqp="converged"), x, working


def idle_effort(pv: PenaltyValue, check: LimitCheck) -> np.ndarray:
    """(n,) bool: joints whose effort rows have no multiplier and whose torque is ``EFFORT_SLACK``·σ within its limit."""
    mu = pv.mu_lo[EFFORT] + pv.mu_hi[EFFORT]  # (P, n)
    return ~(mu > 0).any(axis=0) & (check.relative_excess()[EFFORT] < -EFFORT_SLACK)


def enforce(base, system, limits: JointLimits, x0: np.ndarray, tol: float,
            inner_solve: Callable[[object, np.ndarray, float], object], *, working: np.ndarray | None = None,
            max_outer: int = 40, use_sqp: bool = False,
            record: Callable[[object], None] | None = None, duals: Duals | None = None,
            terms: tuple = ()) -> EnforceResult:
    """Minimise I(q_h) over the free coefficients of ``base`` (a ControlProblem) within ``limits``.

    inner_solve(problem, x0, tol) -> OptimizeResult runs the unconstrained minimiser on any object
    with ``evaluate``/``newton``/``mesh``. ``working`` (K, n) carries over from a coarser level.
    With ``use_sqp`` (``base`` a ControlProblem) the kinematic limits are imposed by ``sqp`` first
    (``record`` receives its OptimizeResult, for work counts); the augmented-Lagrangian loop below
    takes over only when an effort limit binds or the SQP fails. ``terms``: further ``auglag.Term``s of the same loop
    (e.g. a goal's rows, whose Φ is part of ``base``), without ``use_sqp``; the result is converged when they are met too.
    """
    n = limits.n
    working = np.zeros((len(KINDS), n), bool) if working is None else working.copy()
    x = np.asarray(x0, float)
    handed_over = ""
    if use_sqp:
        done, x, working = _sqp_phase(base, system, limits, x, tol, inner_solve, working, record, duals)
        if isinstance(done, EnforceResult):
            return done
        if isinstance(done, tuple):  # the SQP's point and multipliers start the augmented Lagrangian
            done, duals = done
        handed_over = done or ""
    if duals is not None:
        from hoc_cli.constraints.prolong import same_mesh

        if not same_mesh(duals.rows, LimitRows.build(base.mesh, base.layout.free, n)):
            duals = None  # another mesh's multipliers start the SQP's QP only (see the module docstring)
    result = _rounds(base, system, limits, x, tol, inner_solve, working, max_outer, duals, terms)
    if result.status == "not_converged" and duals is not None:
        # the warm start did not converge (its multipliers or penalty did not suit this solve):
        # the cold start, λ = 0 and ρ0, from the same point
        result = _rounds(base, system, limits, x, tol, inner_solve, working, max_outer, None, terms)
    return dataclasses.replace(result, sqp=handed_over)




class LimitTerm:
    """The joint limits as the augmented Lagrangian's term (``auglag.Term``): box rows imposed per (kind, joint)
    pair of the working set, the multipliers λ per row, ρ per unit time (module docstring, steps 1 to 4). The
    limits' rules live here for every loop that imposes them: ``auglag.minimize`` (``enforce``) and the collision
    loop's limit rounds (``hoc_cli.collision.limit_rounds``), which carry this term's λ, ρ and working set across
    its outer iterations.

    ``rows``: the level's ``LimitRows``; ``working`` (K, n) bool, the pairs imposed from the start; ``lam_lo``,
    ``lam_hi``: the start's multipliers; ``warm``: they come from a previous solve on this mesh (ρ starts at
    ``WARM_RHO``·ρ0); ``rho``, ``rho0``: a penalty carried from a previous solve on this mesh (else None: ρ0 is set
    when the first pair binds); ``rho_max``: ρ at most ``rho_max``·ρ0 (∞: no cap, the infeasible verdict ends a
    growing ρ); ``cost(base, x) -> J``: the plan's cost that prices ρ0 and the complementarity test (default
    ``base.evaluate(x, grad=False).J``). After each ``measure``: ``check`` (LimitCheck), ``pv`` (PenaltyValue, μ per
    row) and ``J`` of the plan; ``working`` the pairs imposed at its end.
    """

    stop_on_failure = True

    def __init__(self, system, limits: JointLimits, rows: LimitRows, working: np.ndarray,
                 lam_lo: tuple[np.ndarray, ...], lam_hi: tuple[np.ndarray, ...], warm: bool, *,
                 rho: float | None = None, rho0: float | None = None, rho_max: float = math.inf,
                 cost: Callable[[object, np.ndarray], float] | None = None) -> None:
        self.system, self.limits, self.rows, self.working = system, limits, rows, working
        self.lam_lo, self.lam_hi, self.warm = lam_lo, lam_hi, warm
        self.rho: float | None = rho
        self.rho0: float | None = rho0
        self.rho_max = rho_max
        self.cost = cost or (lambda base, x: base.evaluate(x, grad=False).J)
        self.terms: LimitTerms | None = None  # Φ of the current inner solve
        self.check: LimitCheck | None = None
        self.pv: PenaltyValue | None = None
        self.J = math.nan

    @property
    def rho_cap(self) -> float:
        return math.inf if self.rho0 is None else self.rho0 * self.rho_max

    def _start_rho(self, J: float, mesh) -> None:
        self.rho = self.rho0 = RHO_START * max(abs(J), 1e-6) / mesh.T

    @property
    def imposed(self) -> bool:
        return not self.terms.empty

    def begin(self, base, x: np.ndarray) -> None:
        if self.working.any() and self.rho is None:
            self._start_rho(self.cost(base, x), base.mesh)
            if self.warm:
                self.rho = WARM_RHO * self.rho0
        self.terms = LimitTerms(self.system, self.limits, self.rows, self.working, self.lam_lo, self.lam_hi,
                                self.rho or 1.0, MARGIN)

    def problem(self, base):
        return Penalized(base, (self,)) if self.imposed else base

    def evaluate(self, C: np.ndarray, grad: bool = True) -> tuple[float, np.ndarray | None]:
        pv = self.terms.evaluate(C, grad=grad)
        return pv.value, pv.grad

    def newton_blocks(self, C: np.ndarray) -> np.ndarray:
        return self.terms.newton_blocks(C)

    def measure(self, base, x: np.ndarray, res, tol: float) -> Measure:
        """Within: the exact check finds every value within its true bounds; met: within and Σ μ|g| ≤ tol·|J|."""
        C = base.coefficients(x)
        self.check = check_limits(self.system, self.limits, base.mesh, C)
        self.pv = self.terms.evaluate(C, grad=False)
        self.J = self.cost(base, x)
        within = not _violated(self.check).any()
        return Measure(self.pv.max_violation(), within,
                       within and self.pv.complementarity() <= tol * max(abs(self.J), 1.0))

    def update(self, base, x: np.ndarray, measure: Measure) -> None:
        """λ ← μ; idle effort pairs leave the working set, pairs found beyond their bounds join it."""
        newly = _violated(self.check) & ~self.working
        self.lam_lo, self.lam_hi = self.pv.mu_lo, self.pv.mu_hi
        idle = idle_effort(self.pv, self.check) & self.working[EFFORT]
        if idle.any():  # effort rows far from their limits cost dynamics at every point and add nothing: dropped
            self.working = self.working.copy()
            self.working[EFFORT] &= ~idle
        if newly.any():
            self.working = self.working | newly
            if self.rho is None:
                self._start_rho(self.J, base.mesh)

    def feasible_start(self, base, x: np.ndarray) -> bool:
        start = check_limits(self.system, self.limits, base.mesh, base.coefficients(x))
        if _violated(start).any():
            return False
        self.check, self.pv = start, self.terms.evaluate(base.coefficients(x), grad=False)
        return True

    def result(self, status: str, message: str, res, x: np.ndarray, J: float, outer: int) -> EnforceResult:
        """The limits' outcome (``EnforceResult``) at the plan x last measured: J its cost, ``outer`` the loop's outer
        iterations, ``res`` its last inner OptimizeResult.
        """
        return EnforceResult(status=status, message=message, inner=res, x=x, J=J, outer_iterations=outer,
                             rho=self.rho or 0.0, check=self.check, working=self.working, rows=self.rows,
                             penalty=self.pv)


_MESSAGES = {
    "max_iter": "not within tol: {}",
    "failed": "the inner solve failed: {}",
    "outer": "the augmented-Lagrangian iteration limit was reached",
    "infeasible": "no trajectory within the limits was found (the penalty grew 1e8-fold)",
    "stalled": ("the limit solver stalled (the penalty grew 1e8-fold without meeting the limits); the plan "
                "returned is its start, within the limits"),
}


def _rounds(base, system, limits: JointLimits, x: np.ndarray, tol: float,
            inner_solve: Callable[[object, np.ndarray, float], object], working: np.ndarray, max_outer: int,
            duals: Duals | None, terms: tuple = ()) -> EnforceResult:
    """The augmented-Lagrangian loop (``auglag.minimize`` with ``terms`` and a ``LimitTerm``) from x, λ from ``duals``
    (else 0).
    """
    rows = LimitRows.build(base.mesh, base.layout.free, limits.n)
    lam_lo, lam_hi = _zeros(rows, limits.n), _zeros(rows, limits.n)
    warm = duals is not None and working.any()
    if warm:
        from hoc_cli.constraints.prolong import prolong

        lam_lo, lam_hi = prolong(duals, rows)
    term = LimitTerm(system, limits, rows, working, lam_lo, lam_hi, warm)
    out = auglag.minimize(base, (*terms, term), x, tol, inner_solve, max_outer)
    res = out.res
    if out.stop == "met":
        message = (f"{res.message}; every limit holds (outer iterations: {out.outer})" if res.converged
                   else f"every limit holds, but the inner solve stopped: {res.message}")
    else:
        message = _MESSAGES[out.stop].format(res.message)
    return term.result(out.status, message, res, out.x, base.evaluate(out.x, grad=False).J, out.outer)
