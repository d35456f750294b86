"""Optimiser results: a status enum, the stopping test that held, a message and the work counts; never a tuple."""
from __future__ import annotations

import enum
from dataclasses import dataclass

import numpy as np


class Status(enum.Enum):
    """How ``minimize`` ended (the value is what ``hoc plan --json`` reports as ``status``)."""

    CONVERGED = "converged"
    MAX_ITER = "max_iter"
    LINE_SEARCH_FAILED = "line_search_failed"
    NOT_FINITE = "not_finite"


class StopTest(enum.Enum):
    """Which stopping test held when the status is ``CONVERGED`` (see ``hoc_cli.optimize.cg``)."""

    DECREMENT = "decrement"  # ½ gᵀP⁻¹g <= tol·|J|
    ROUNDING = "rounding"  # ½ gᵀP⁻¹g <= the rounding level of J, which exceeds tol·|J|
    GRADIENT = "gradient"  # no preconditioner: ‖g‖∞ <= tol·max(|J|, 1)


MESSAGES = {
    Status.MAX_ITER: "the maximum number of iterations was reached before the stopping test held",
    Status.LINE_SEARCH_FAILED: "the line search could not make progress (even along the preconditioned gradient)",
    Status.NOT_FINITE: "the cost or gradient became NaN or infinite",
}
STOP_MESSAGES = {
    StopTest.DECREMENT: "the stopping test held: ½ gᵀP⁻¹g <= tol·|J|",
    StopTest.ROUNDING: "the rounding-level test held: ½ gᵀP⁻¹g <= the rounding level of J, which exceeds tol·|J|",
    StopTest.GRADIENT: "the stopping test held: ‖g‖∞ <= tol·max(|J|, 1)",
}


def message(status: Status, stop_test: StopTest | None = None) -> str:
    """The one-line explanation of a result: which stopping test held, or why none did."""
    if status is Status.CONVERGED:
        if stop_test is None:
            raise ValueError("a converged result needs the stopping test that held")
        return STOP_MESSAGES[stop_test]
    return MESSAGES[status]


@dataclass(frozen=True)
class IterLog:
    """One iteration: cost J, gradient norm ‖g‖∞, decrement ½gᵀP⁻¹g, step α, evaluations so far, mesh level."""

    iteration: int
    J: float
    grad_norm: float
    decrement: float
    alpha: float
    n_evals: int
    level: int = 0  # number of elements of the mesh being solved (coarse-to-fine), 0 if not applicable


@dataclass(frozen=True, eq=False)
class OptimizeResult:
    """The final iterate of ``minimize`` and how it was reached.

    x (P,) the best iterate; fun its cost J; grad (P,) its gradient; status and, when converged,
    stop_test (else None); iterations; n_evals cost-and-gradient evaluations (line-search trials
    included); n_precond preconditioner builds; decrement ½ gᵀP⁻¹g at x; history one ``IterLog``
    per iteration; message (``message(status, stop_test)``); restarts the number of times the
    conjugate direction failed the sufficient-descent test and was replaced by −P⁻¹g.
    """

    x: np.ndarray
    fun: float
    grad: np.ndarray
    status: Status
    iterations: int
    n_evals: int
    n_precond: int
    decrement: float
    history: tuple[IterLog, ...] = ()
    message: str = ""
    stop_test: StopTest | None = None
    restarts: int = 0

    @property
    def converged(self) -> bool:
        return self.status is Status.CONVERGED

    @property
    def grad_norm(self) -> float:
        return float(np.max(np.abs(self.grad))) if self.grad.size else 0.0
