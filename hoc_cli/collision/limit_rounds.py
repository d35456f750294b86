"""The joint limits as terms of the collision loop's augmented Lagrangian: one outer loop for both.

Each outer iteration of the collision loop (``enforce.CollisionConstraint``) minimises
I + Φ_collision + Φ_limits (``LimitTerms``: the limits' own PHR terms) in a few rounds
(``LimitState.rounds``); after each round the limits' multipliers are updated by the rules of
``constraints.augmented_lagrangian`` (the (kind, joint) pairs found beyond their bounds join the
working set, idle effort pairs leave it, λ ← μ, ρ × 10 when the worst violation did not fall to a
quarter within the rounds, at most ``RHO_MAX``·ρ0), after a converged inner solve its polish (one full Newton step on
I + Φ: it meets the limits to the rounding level the inner test cannot see). The collision's
multipliers are updated by its loop after the rounds.

The limits' multipliers, ρ and working set go on from one outer iteration to the next and from
one solve to the next (``LimitWarm``), so the rounds of an outer iteration stop once the plan is
within ``SETTLED``·σ of every limit (at most ``ROUNDS``): the collision loop needs the limits
settled to judge its own progress, not met to 1e-9. Its final iterations (the clearance certified
at the plan's tolerance) ask them met: every value within its true bounds (``check_limits``) and
Σ μ|g| ≤ tol·|J| (at most ``EXACT_ROUNDS`` rounds an outer iteration).
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from hoc_cli.constraints import auglag
from hoc_cli.constraints import augmented_lagrangian as al
from hoc_cli.constraints.auglag import Penalized, polish
from hoc_cli.constraints.augmented_lagrangian import EnforceResult, idle_effort
from hoc_cli.constraints.bounds import EFFORT, KINDS, JointLimits
from hoc_cli.constraints.check import LimitCheck, check_limits
from hoc_cli.constraints.penalty import LimitObjective, LimitRows, LimitTerms, PenaltyValue
from hoc_cli.constraints.prolong import Duals, prolong, same_mesh

_log = logging.getLogger(__name__)  # the limits' rounds at DEBUG level

SETTLED = 1e-3    # the worst excess over a limit, relative to σ, below which a non-final outer iteration stops its rounds
ROUNDS = 4        # limits' rounds at most per outer iteration ...
EXACT_ROUNDS = 12 # ... and in the final ones (the limits met exactly)
RHO_MAX = 1e8     # ρ stays below RHO_MAX·ρ0 (the inner problems' conditioning; beyond, the collision loop's own caps end it)


@dataclass(frozen=True, eq=False)
class LimitWarm:
    """The limits' state at the end of a level, for the next solve: multipliers on their rows, ρ, ρ0."""

    duals: Duals
    rho: float | None
    rho0: float | None


class LimitState:
    """The joint limits' multipliers, penalty and working set across the collision loop's iterations on one mesh."""

    def __init__(self, system, limits: JointLimits, working: np.ndarray | None, problem,
                 warm: LimitWarm | None = None) -> None:
        """``system``: the dynamics (for effort); ``working`` (K, n) bool: the pairs imposed from the start (a
        coarser level's), or None; ``problem``: the level's ControlProblem; ``warm``: the previous solve's state:
        on the same mesh its multipliers and ρ go on, on another its multipliers are carried (``prolong``) and ρ
        starts again.
        """
        self.system, self.limits = system, limits
        n = limits.n
        self.mesh = problem.mesh
        self.rows = LimitRows.build(problem.mesh, problem.layout.free, n)
        self.working = np.zeros((len(KINDS), n), bool) if working is None else working.copy()
        self.lam_lo = tuple(np.zeros(self.rows.shape(k, n)) for k in range(len(KINDS)))
        self.lam_hi = tuple(np.zeros(self.rows.shape(k, n)) for k in range(len(KINDS)))
        self.rho: float | None = None
        self.rho0: float | None = None
        self.prev = math.inf
        if warm is not None and self.working.any():
            self.lam_lo, self.lam_hi = prolong(warm.duals, self.rows)
            if same_mesh(warm.duals.rows, self.rows):
                self.rho, self.rho0 = warm.rho, warm.rho0
        self.check: LimitCheck | None = None
        self.pv: PenaltyValue | None = None
        self.met = False

    def _start_rho(self, J: float) -> None:
        if self.rho is None:
            self.rho = self.rho0 = al.RHO_START * max(abs(J), 1e-6) / self.mesh.T

    def terms(self, J: float) -> LimitTerms:
        """The limits' terms for the next inner solve (``J``: the plan's cost, for ρ0 when the first pair binds)."""
        if self.working.any():
            self._start_rho(J)
        return LimitTerms(self.system, self.limits, self.rows, self.working, self.lam_lo, self.lam_hi,
                          self.rho or 1.0, al.MARGIN)

    @staticmethod
    def problem(base, terms: LimitTerms):
        """The inner problem: ``base`` (with its own ``terms``) plus the limits' terms, if any pair is imposed."""
        return base if terms.empty else Penalized(base, (LimitObjective(terms),))

    @staticmethod
    def polish(problem, x: np.ndarray) -> np.ndarray:
        """One full Newton step on I + Φ after a converged inner solve (``auglag.polish``), from the
        inner solve's last evaluation when it was at x (its accepted point: no second evaluation there).
        """
        if not isinstance(problem, Penalized):
            return x
        ev = problem.last
        if ev is None or ev.grad is None or not np.array_equal(ev.x, x):
            ev = None
        return polish(problem, x, ev)

    def update(self, terms: LimitTerms, C: np.ndarray, J: float, tol: float) -> bool:
        """Check the plan C (J its cost), update λ, the working set and ρ; True when the limits are met."""
        check = check_limits(self.system, self.limits, self.mesh, C)
        pv = terms.evaluate(C, grad=False)
        beyond = (check.hi_excess > 0) | (check.lo_excess > 0)
        within = not beyond.any()
        self.check, self.pv = check, pv
        self.met = within and pv.complementarity() <= tol * max(abs(J), 1.0)
        self.lam_lo, self.lam_hi = pv.mu_lo, pv.mu_hi
        idle = idle_effort(pv, check) & self.working[EFFORT]
        if idle.any():
            self.working = self.working.copy()
            self.working[EFFORT] &= ~idle
        newly = beyond.any(axis=1) & ~self.working
        if newly.any():
            self.working = self.working | newly
            self._start_rho(J)
        excess = pv.max_violation()
        falling = excess <= auglag.STALL_RATIO * self.prev
        if (self.rho is not None and not within and excess > 0.25 * self.prev
                and not (self.rho >= self.rho0 * auglag.RHO_RANGE and falling)):
            self.rho = min(self.rho * auglag.RHO_GROWTH, self.rho0 * RHO_MAX)
        self.prev = excess if excess > 0 else self.prev
        return self.met

    def settled(self) -> bool:
        """The plan's worst excess over a limit is within ``SETTLED``·σ (the collision loop may judge its own progress)."""
        return self.check is not None and float(np.max(self.check.relative_excess(), initial=0.0)) <= SETTLED

    def rounds(self, problem, x: np.ndarray, tol: float, minimize, *, exact: bool, polish: bool = True,
               spent=lambda: False):
        """Inner solves of ``problem`` (a ControlProblem with the collision's terms) plus the limits' terms, each
        followed by the polish and the limits' update, until the limits are met (``exact``) or settled, at most
        ``EXACT_ROUNDS`` or ``ROUNDS`` of them, or until ``spent()`` (the caller's iteration budget). Returns (the
        last inner result, x, whether the limits are met).
        """
        self.prev = math.inf  # ρ grows on a stall within these rounds, not on the collision's move before them
        known: list = [None, math.nan]  # [x, I(x)]: the cost of the last plan, for the next round's start

        def bare(v: np.ndarray) -> float:
            if known[0] is not v:
                known[:] = [v, problem.bare_cost(v)]
            return known[1]

        for _ in range(EXACT_ROUNDS if exact else ROUNDS):
            lt = self.terms(bare(x) if self.working.any() and self.rho is None else math.nan)  # J prices ρ0 only
            inner = self.problem(problem, lt)
            res = minimize(inner, x, tol)
            x = self.polish(inner, res.x) if res.converged and (polish or exact) else res.x
            if exact and x is not res.x:  # the polish step: the next round's first Newton matrix takes this one's cost Hessian
                problem.carry_hessian(x)
            met = self.update(lt, problem.coefficients(x), bare(x), tol)
            if _log.isEnabledFor(logging.DEBUG):
                _log.debug(f"limits round N {self.mesh.N} it {res.iterations} ev {res.n_evals} met {met} "
                           f"excess {np.max(self.check.relative_excess()):.2e} rho {self.rho or 0:.3g}")
            if met or (not exact and self.settled()) or not res.converged or spent():
                break
        return res, x, met

    def warm(self) -> LimitWarm:
        """The state for the next solve (``LimitWarm``)."""
        return LimitWarm(Duals(self.rows, self.lam_lo, self.lam_hi), self.rho, self.rho0)

    def result(self, res, x: np.ndarray, J: float, outer: int) -> EnforceResult:
        """The limits' outcome of the level (``EnforceResult``, as the limits' own loop reports it)."""
        if self.met and res.converged:
            status, message = "converged", f"{res.message}; every limit holds (outer iterations: {outer})"
        elif self.met:
            status, message = "not_converged", f"every limit holds, but the inner solve stopped: {res.message}"
        else:
            status, message = "not_converged", "the joint limits were not met within the collision loop's iterations"
        return EnforceResult(status=status, message=message, inner=res, x=x, J=J, outer_iterations=outer,
                             rho=self.rho or 0.0, check=self.check, working=self.working, rows=self.rows,
                             penalty=self.pv)
