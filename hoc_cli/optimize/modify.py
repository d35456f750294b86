"""The Hessian modification shared by the Newton matrices: H + μ·GN, μ grown until the matrix factors.

Away from a minimum the Hessian H of a plan's cost may be indefinite; GN, the element blocks of a positive
semi-definite part of it (for the torque cost the Gauss-Newton matrix), is then added with the weight
μ = 1e-3·max(|tr H|, tr GN)/tr GN, ×10 while the banded Cholesky factorisation fails, at most ``TRIES`` times.
``ControlProblem.positive_definite`` (every Newton matrix of the inner solves and replans) and the banded SQP's
quadratic model (``hoc_cli.constraints.qp.QPModel.modify``) both use it. Pure maths: no I/O.
"""
from __future__ import annotations

from collections.abc import Callable
from typing import TypeVar

import numpy as np

from hoc_cli.errors import NumericalError

TRIES = 12  # weights tried: 1e-3 … 1e8 times the traces' ratio
Factor = TypeVar("Factor")


def gauss_newton_shift(H: np.ndarray, GN: np.ndarray, factor: Callable[[np.ndarray], Factor],
                       start: float | None = None) -> tuple[float, Factor | None]:
    """(μ, factor(H + μ·GN)) for the first μ of the sequence above whose matrix ``factor`` accepts (it raises
    ``NumericalError`` otherwise), or (the last μ tried × 10, None) when none is.

    H, GN : element blocks (N, 2mn, 2mn), GN positive semi-definite with a positive trace.
    start : the sequence starts here instead (when above its first weight): a sequence of Newton matrices along
        one solve's steps needs similar weights, and starting a decade below the last one accepted saves the
        factorisations of the weights below it (the torque catch's replan steps: weights 1e3-1e6 times the first).
    """
    tr = np.trace(GN.sum(axis=0))
    mu = abs(1e-3 * max(abs(np.trace(H.sum(axis=0))), tr) / tr)
    if start is not None and start > mu:
        mu = start
    for _ in range(TRIES):
        try:
            return mu, factor(H + mu * GN)
        except NumericalError:
            mu *= 10
    return mu, None
