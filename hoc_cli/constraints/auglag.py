"""The augmented Lagrangian for what the SQP does not impose: one outer loop, its constraints as terms.

``minimize(base, terms, x, tol, inner_solve)`` is the method of multipliers (Hestenes 1969, Powell
1969; LANCELOT; Nocedal & Wright, Numerical Optimization, Alg. 17.4) around an inner minimiser
that keeps the Hermite unknowns, the exact gradient and the block-banded Newton matrix. Each
constraint is a ``Term``: its rows (box rows of the joint limits, ``augmented_lagrangian.LimitTerm``;
equality rows of the goals, ``hoc_cli.goals.plan.GoalTerm``), Φ(x; λ, ρ) and ∂Φ/∂C through the
existing reverse sweeps, Φ's element blocks of the Newton matrix, its violation measure and its
multiplier update. One outer iteration:

1. Solve min_x I(q_h) + Σ Φ(x; λ, ρ) over the terms from the current x (``term.problem(base)``: ``base``
   plus Φ while the term imposes rows; ``base`` itself otherwise, or when Φ is part of ``base`` already).
2. After a converged inner solve, one full Newton step on I + Φ (``polish``).
3. Measure the plan (``term.measure``): the worst violation, whether every row is within its set
   (``within``) and whether the term's stopping test holds (``met``). Stop when every term's holds, when the
   inner solve ran out of iterations, or (a term with ``stop_on_failure``) when it failed after the first
   iteration with rows still violated.
4. λ ← μ (``term.update``, which may also change which rows are imposed), then ρ × ``RHO_GROWTH``
   when, after a converged inner solve, the worst violation did not fall to ``DECREASE`` of the
   previous one (at most ``term.rho_cap``). A term with a start of its penalty range (``term.rho0``)
   is infeasible once ρ has grown past ``RHO_RANGE``·ρ0 with violations that no longer fall by a tenth
   (``STALL_RATIO``); while they still fall, ρ stays and the multiplier updates go on (a slowly
   converging iteration is not an infeasible task). A term without it (``rho0`` None) is never called
   infeasible: its ρ stops at its cap.

Steps 1 and 2 are ``solve``, step 4 (per term) ``update``: the collision loop's limit rounds
(``hoc_cli.collision.limit_rounds``) run the same two on the limits' term with stopping tests of their
own. ``Penalized`` is the inner problem (a base problem plus terms, with the evaluate/newton interface
of the inner solver). Pure maths: no I/O.
"""
from __future__ import annotations

import dataclasses
import logging
import math
from dataclasses import dataclass
from typing import Callable, Protocol, Sequence

import numpy as np

from hoc_cli.errors import NumericalError

_log = logging.getLogger(__name__)  # the outer iterations at DEBUG level (docs/design.md)
RHO_GROWTH = 10.0
DECREASE = 0.25  # ρ grows when the worst violation did not fall to this fraction of the previous one
RHO_RANGE = 1e8  # infeasible once ρ has grown this much from ρ0 without reaching feasibility ...
STALL_RATIO = 0.9  # ... and the worst violation no longer falls by a tenth from one outer iteration to the next


class Penalized:
    """``base`` (a ControlProblem or another ``Penalized``) plus ``terms``, with the evaluate/newton interface of
    the inner solver.

    Each term has ``evaluate(C, grad) -> (value, ∂/∂C (N+1, m, n) or None)`` and ``newton_blocks(C) -> (N, 2mn,
    2mn)`` (positive semi-definite element blocks), as ``ControlProblem.terms`` (``hoc_cli.problem``, "Hooks").
    """

    def __init__(self, base, terms: Sequence) -> None:
        self.base, self.terms = base, tuple(terms)
        self.mesh, self.layout = base.mesh, base.layout
        self.last = None
        self._newton: tuple | None = None  # (ev, the Newton matrix there): the polish at the inner solve's last one

    def coefficients(self, x: np.ndarray) -> np.ndarray:
        return self.base.coefficients(x)

    def evaluate(self, x: np.ndarray, grad: bool = True, keep_gradient: bool = False):
        """I + Σ Φ at x (``keep_gradient``: as ``ControlProblem.evaluate``'s, passed to the base)."""
        ev = self.base.evaluate(x, grad=grad, keep_gradient=keep_gradient) if keep_gradient else self.base.evaluate(x, grad=grad)
        C = self.base.coefficients(x)
        J, g = ev.J, ev.grad
        for term in self.terms:
            value, gC = term.evaluate(C, grad=grad)
            J = J + value
            g = None if g is None else g + self.layout.pack(gC)
        ev = dataclasses.replace(ev, J=J, grad=g)
        self.last = ev
        return ev

    def value(self, x: np.ndarray) -> float:
        return self.evaluate(x, grad=False).J

    def newton(self, ev, extra: np.ndarray | None = None):
        """The base's Newton matrix with the terms' blocks and ``extra`` (N, 2mn, 2mn) added. Without ``extra``, the
        last one is kept: a second at the same evaluation (the polish after an inner solve whose last iteration built
        it) is that one.
        """
        kept = self._newton
        if extra is None and kept is not None and kept[0] is ev:
            return kept[1]
        C = self.base.coefficients(ev.x)
        blocks = None
        for term in self.terms:
            b = term.newton_blocks(C)
            blocks = b if blocks is None else blocks + b
        if blocks is None:
            P = self.base.newton(ev, extra=extra)
        else:
            P = self.base.newton(ev, extra=blocks if extra is None else blocks + extra)
        if extra is None:
            self._newton = (ev, P)
        return P


def polish(problem, x: np.ndarray, ev=None, trial_gradient: bool = False) -> np.ndarray:
    """One full Newton step on I + Φ from an inner optimum (``ev``: the evaluation at x with its gradient, when
    the caller has it; else it is made here). ``trial_gradient``: the trial point's evaluation also makes and keeps
    I(q_h)'s gradient there (``ControlProblem.evaluate``'s ``keep_gradient``), for a next inner solve that starts
    there; the terms are evaluated without theirs, as otherwise.

    The inner stopping test weighs the decrement against |J|; a violation δ changes Φ by about
    ½ρ δ², below the rounding level of J long before δ reaches 1e-9. The Newton step, made from
    gradients (which resolve what the value cannot) with Φ's curvature, still removes it. Taken only
    after the inner test held, so it is small; kept when the cost at the trial point is finite.
    """
    if ev is None:
        ev = problem.evaluate(x)
    trial = x - problem.newton(ev).solve(ev.grad)
    try:
        got = problem.evaluate(trial, grad=False, keep_gradient=True) if trial_gradient else problem.evaluate(trial, grad=False)
        if np.isfinite(got.J):
            return trial
    except NumericalError:  # a trial point the dynamics cannot evaluate (singular mass matrix)
        pass
    return x


@dataclass(frozen=True)
class Measure:
    """A term at a plan: ``violation`` its worst row's violation (≥ 0, the term's units), ``within`` every row in its
    set (to the term's tolerance), ``met`` the term's stopping test.
    """

    violation: float
    within: bool
    met: bool


class Term(Protocol):
    """One constraint's rows in the augmented Lagrangian (module docstring).

    rho : the penalty (None until a row is imposed); rho0 : the start of its range (None: never infeasible);
    rho_cap : ρ at most; stop_on_failure : a failed inner solve with rows violated ends the loop;
    imposed : rows are imposed for the next inner solve (set by ``begin``).
    """

    rho: float | None
    rho0: float | None
    rho_cap: float
    stop_on_failure: bool

    @property
    def imposed(self) -> bool: ...

    def evaluate(self, C: np.ndarray, grad: bool = True) -> tuple[float, np.ndarray | None]:
        """(Φ, ∂Φ/∂C (N+1, m, n) or None) at coefficients C (N+1, m, n)."""

    def newton_blocks(self, C: np.ndarray) -> np.ndarray:
        """Φ's positive semi-definite element blocks (N, 2mn, 2mn) of the Newton matrix at C."""

    def begin(self, base, x: np.ndarray) -> None:
        """Ready Φ for the next inner solve from x (e.g. ρ started when the first row is imposed)."""

    def problem(self, base):
        """The inner problem: ``base`` plus Φ (``base`` when Φ is part of it already, or nothing is imposed)."""

    def measure(self, base, x: np.ndarray, res, tol: float) -> Measure:
        """The plan x after the inner solve ``res`` at tolerance ``tol``."""

    def update(self, base, x: np.ndarray, measure: Measure) -> None:
        """λ ← μ at x (with the ρ of the last inner solve); the rows imposed next."""

    def feasible_start(self, base, x: np.ndarray) -> bool:
        """Whether x holds every row (then the term keeps its measure at x as the outcome's)."""


@dataclass(frozen=True, eq=False)
class Outcome:
    """The end of ``minimize``.

    status : "converged" (every term's test held after a converged inner solve), "not_converged" or "infeasible";
    stop : "met", "max_iter" (the inner solve's budget), "failed" (the inner solve failed with rows violated),
    "outer" (``max_outer`` outer iterations), "infeasible" or "stalled" (the penalty grew out of range from a start
    within the rows: x is that start); res : the last inner OptimizeResult; x : the plan; outer : outer iterations;
    iterations, n_evals : the inner solves' totals.
    """

    status: str
    stop: str
    res: object
    x: np.ndarray
    outer: int
    iterations: int
    n_evals: int


def minimize(base, terms: Sequence[Term], x: np.ndarray, tol: float,
             inner_solve: Callable[[object, np.ndarray, float], object], max_outer: int) -> Outcome:
    """The augmented-Lagrangian loop (module docstring) of ``terms`` around ``inner_solve(problem, x, tol) ->
    OptimizeResult`` on ``base``, from x (each term's multipliers and ρ as it holds them).

    Several terms share the loop: one inner solve of I + Σ Φ per outer iteration, each term measured, updated and
    its ρ grown on its own; it stops when every term's test holds, and is infeasible when one term is.
    """
    x_begin = x  # a start within the rows proves the task feasible (the "infeasible" test below)
    prev = [math.inf] * len(terms)
    res = None
    its = evs = 0
    status, stop, outer = "not_converged", "outer", 0
    for outer in range(1, max_outer + 1):
        res, x = solve(base, terms, x, tol, inner_solve)
        its, evs = its + res.iterations, evs + res.n_evals
        ms = [term.measure(base, x, res, tol) for term in terms]
        if all(m.met for m in ms):
            status, stop = ("converged" if res.converged else "not_converged"), "met"
            break
        if res.status.value == "max_iter":
            stop = "max_iter"
            break
        if (res.status.value in ("not_finite", "line_search_failed") and outer > 1
                and any(term.stop_on_failure and not m.within for term, m in zip(terms, ms))):
            stop = "failed"
            break
        infeasible = False
        for i, (term, m) in enumerate(zip(terms, ms)):
            prev[i], out_of_range = update(term, base, x, m, prev[i], res.converged)
            if _log.isEnabledFor(logging.DEBUG):
                _log.debug(f"outer {outer} it {res.iterations} ev {res.n_evals} {type(term).__name__} "
                           f"violation {m.violation:.2e} rho {term.rho} within {m.within}")
            infeasible |= out_of_range
        if infeasible:
            status, stop = "infeasible", "infeasible"
            if all(term.feasible_start(base, x_begin) for term in terms):
                # the start holds every row, so the task is not infeasible: the iteration stalled (degenerate
                # rows at a huge penalty). The start is returned.
                status, stop, x = "not_converged", "stalled", x_begin
            break
    return Outcome(status=status, stop=stop, res=res, x=x, outer=outer, iterations=its, n_evals=evs)


def solve(base, terms: Sequence[Term], x: np.ndarray, tol: float,
          inner_solve: Callable[[object, np.ndarray, float], object], polish_step: bool = True,
          trial_gradient: bool = False):
    """Steps 1 and 2 of an outer iteration (module docstring): each term readied (``term.begin``), the inner solve
    of I + Σ Φ from x, then, after a converged inner solve with rows imposed and ``polish_step``, ``polish`` from the
    inner solve's last evaluation when it was at its x (its trial point keeping I(q_h)'s gradient when
    ``trial_gradient``).
    Returns (the inner OptimizeResult, the plan x).
    """
    problem = base
    for term in terms:
        term.begin(base, x)
        problem = term.problem(problem)
    res = inner_solve(problem, x, tol)
    x = res.x
    if polish_step and res.converged and any(term.imposed for term in terms):
        ev = getattr(problem, "last", None)  # the inner solve's accepted point: no second evaluation there
        if ev is None or ev.grad is None or not np.array_equal(ev.x, x):
            ev = None
        x = polish(problem, x, ev, trial_gradient)
    return res, x


def update(term: Term, base, x: np.ndarray, m: Measure, prev: float, converged: bool) -> tuple[float, bool]:
    """Step 4 of an outer iteration for one term (module docstring): λ ← μ (``term.update``), then ρ × ``RHO_GROWTH``
    when, after a converged inner solve (``converged``), the worst violation ``m.violation`` did not fall to
    ``DECREASE`` of ``prev`` (the previous one; ∞ at first), at most ``term.rho_cap``.

    Returns (the violation the next one is compared with, whether the term is infeasible: ρ beyond
    ``RHO_RANGE``·ρ0 with rows violated and the violation no longer falling by a tenth).
    """
    term.update(base, x, m)
    rho, rho0 = term.rho, term.rho0
    falling = m.violation <= STALL_RATIO * prev  # the multiplier updates still make progress
    if (rho is not None and not m.within and m.violation > DECREASE * prev and converged
            and not (rho0 is not None and rho >= rho0 * RHO_RANGE and falling)):
        term.rho = rho = min(rho * RHO_GROWTH, term.rho_cap)
    infeasible = rho0 is not None and rho > rho0 * RHO_RANGE and not m.within and not falling
    return (m.violation if m.violation > 0 else prev), infeasible
