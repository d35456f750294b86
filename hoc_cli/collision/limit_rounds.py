"""The joint limits inside the collision loop: ``LimitTerm``'s rounds, its state carried across outer iterations.

Each outer iteration of the collision loop (``enforce.CollisionConstraint``) minimises
I + Φ_collision + Φ_limits in a few rounds (``LimitState.rounds``). The limits are one
``augmented_lagrangian.LimitTerm`` per level, driven by ``auglag``'s steps, the same as
``auglag.minimize`` drives it: ``auglag.solve`` (the inner solve of the collision's problem plus Φ_limits,
then ``auglag.polish``), ``LimitTerm.measure`` and ``auglag.update`` (λ ← μ, the working set, ρ × 10 when
the worst violation did not fall to a quarter, at most ``RHO_MAX``·ρ0, the term's ``rho_max``). Their rules
are ``LimitTerm``'s; this module decides only when the rounds stop. The collision's multipliers are updated
by its loop after the rounds.

The term, with its multipliers, ρ and working set, goes on from one outer iteration to the next, and its
multipliers and ρ from one solve to the next (``LimitWarm``), so the rounds of an outer iteration stop once
the plan is within ``SETTLED``·σ of every limit (at most ``ROUNDS``): the collision loop needs the limits
settled to judge its own progress, not met to 1e-9. Unlike ``auglag.minimize``, each round ends with the
update (the next outer iteration starts from λ ← μ) and the rounds stop after any inner solve that did not
converge (the collision loop decides what follows). Its final iterations (the clearance certified at the
plan's tolerance) ask the limits met: ``LimitTerm``'s stopping test (every value within its true bounds and
Σ μ|g| ≤ tol·|J|, at most ``EXACT_ROUNDS`` rounds an outer iteration). On full levels a round's converged
inner solve is polished only in the final iterations.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from hoc_cli.constraints import auglag
from hoc_cli.constraints.augmented_lagrangian import EnforceResult, LimitTerm
from hoc_cli.constraints.bounds import KINDS, JointLimits
from hoc_cli.constraints.penalty import LimitRows
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


def _bare_cost(base, x: np.ndarray) -> float:
    """I(q_h) without the collision's (and a goal's) terms: the cost that prices ρ0 and the complementarity test."""
    return base.bare_cost(x)


class LimitState:
    """The joint limits' term (``LimitTerm``) across the collision loop's iterations on one mesh."""

    def __init__(self, system, limits: JointLimits, working: np.ndarray | None, problem,
                 warm: LimitWarm | None = None) -> None:
        """``system``: the dynamics (for effort); ``working`` (K, n) bool: the pairs imposed from the start (a
        coarser level's), or None; ``problem``: the level's ControlProblem; ``warm``: the previous solve's state:
        on the same mesh its multipliers and ρ go on, on another its multipliers are carried (``prolong``) and ρ
        starts again.
        """
        n = limits.n
        self.mesh = problem.mesh
        rows = LimitRows.build(problem.mesh, problem.layout.free, n)
        working = np.zeros((len(KINDS), n), bool) if working is None else working.copy()
        lam_lo = tuple(np.zeros(rows.shape(k, n)) for k in range(len(KINDS)))
        lam_hi = tuple(np.zeros(rows.shape(k, n)) for k in range(len(KINDS)))
        rho = rho0 = None
        if warm is not None and working.any():
            lam_lo, lam_hi = prolong(warm.duals, rows)
            if same_mesh(warm.duals.rows, rows):
                rho, rho0 = warm.rho, warm.rho0
        self.term = LimitTerm(system, limits, rows, working, lam_lo, lam_hi, False, rho=rho, rho0=rho0,
                              rho_max=RHO_MAX, cost=_bare_cost)
        self.met = False

    @property
    def rho(self) -> float | None:
        return self.term.rho

    @property
    def working(self) -> np.ndarray:
        return self.term.working

    def settled(self) -> bool:
        """The plan's worst excess over a limit is within ``SETTLED``·σ (the collision loop may judge its own progress)."""
        check = self.term.check
        return check is not None and float(np.max(check.relative_excess(), initial=0.0)) <= SETTLED

    def rounds(self, problem, x: np.ndarray, tol: float, minimize, *, exact: bool, polish: bool = True,
               spent=lambda: False):
        """Inner solves of ``problem`` (a ControlProblem with the collision's terms) plus the limits' terms, each
        followed by the polish (when ``polish`` or ``exact``) and the limits' update, until the limits are met
        (``exact``) or settled, at most ``EXACT_ROUNDS`` or ``ROUNDS`` of them, until an inner solve does not
        converge, or until ``spent()`` (the caller's iteration budget). Returns (the last inner result, x, whether
        the limits are met).
        """
        term = self.term
        prev = math.inf  # ρ grows on a stall within these rounds, not on the collision's move before them
        for _ in range(EXACT_ROUNDS if exact else ROUNDS):
            res, x = auglag.solve(problem, (term,), x, tol, minimize, polish_step=polish or exact,
                                trial_gradient=True)  # the next round starts at the polished point
            if exact and x is not res.x:  # the polish step: the next round's first Newton matrix takes this one's cost Hessian
                problem.carry_hessian(x)
            m = term.measure(problem, x, res, tol)
            prev, _ = auglag.update(term, problem, x, m, prev, res.converged)
            self.met = m.met
            if _log.isEnabledFor(logging.DEBUG):
                _log.debug(f"limits round N {self.mesh.N} it {res.iterations} ev {res.n_evals} met {m.met} "
                           f"excess {np.max(term.check.relative_excess()):.2e} rho {term.rho or 0:.3g}")
            if m.met or (not exact and self.settled()) or not res.converged or spent():
                break
        return res, x, self.met

    def warm(self) -> LimitWarm:
        """The state for the next solve (``LimitWarm``)."""
        term = self.term
        return LimitWarm(Duals(term.rows, term.lam_lo, term.lam_hi), term.rho, term.rho0)

    def result(self, res, x: np.ndarray, J: float, outer: int) -> EnforceResult:
        """The limits' outcome of the level (``EnforceResult``, as the limits' own loop reports it)."""
        if self.met and res.converged:
            status, message = "converged", f"{res.message}; every limit holds (outer iterations: {outer})"
        elif self.met:
            status, message = "not_converged", f"every limit holds, but the inner solve stopped: {res.message}"
        else:
            status, message = "not_converged", "the joint limits were not met within the collision loop's iterations"
        return self.term.result(status, message, res, x, J, outer)
