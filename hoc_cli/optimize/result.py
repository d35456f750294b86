"""Optimiser results: a status enum, a message and the work counts; never a tuple."""
from __future__ import annotations

import enum
from dataclasses import dataclass, field

import numpy as np


class Status(enum.Enum):
    CONVERGED = "converged"
    MAX_ITER = "max_iter"
    LINE_SEARCH_FAILED = "line_search_failed"
    NOT_FINITE = "not_finite"


MESSAGES = {
    Status.CONVERGED: "the stopping test held: ½ gᵀP⁻¹g <= tol·|J|",
    Status.MAX_ITER: "the maximum number of iterations was reached before the stopping test held",
    Status.LINE_SEARCH_FAILED: "the line search could not make progress (even along the preconditioned gradient)",
    Status.NOT_FINITE: "the cost or gradient became NaN or infinite",
}


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


@dataclass(eq=False)
class OptimizeResult:
    x: np.ndarray
    fun: float
    grad: np.ndarray
    status: Status
    iterations: int
    n_evals: int
    n_precond: int
    decrement: float
    history: list[IterLog] = field(default_factory=list)
    message: str = ""

    @property
    def converged(self) -> bool:
        return self.status is Status.CONVERGED

    @property
    def grad_norm(self) -> float:
        return float(np.max(np.abs(self.grad))) if self.grad.size else 0.0
