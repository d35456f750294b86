"""Derivative checks: an analytic gradient (or residual Jacobian) against central differences.

Every new term of the cost (a penalty, a constraint residual) brings its own derivatives; this is
the one place that checks them, for tests and for ``hoc plan --check-gradient``. For a residual
r(x) (r,) given only through vector-Jacobian products, check φ(x) = λᵀ r(x) with a random λ.

Error measure: per residual row i, e_i = max_j |A_ij − D_ij| / max_j max(|A_ij|, |D_ij|), with A the
analytic and D the central-difference derivative over the checked coordinates j (normwise relative
error: coordinates whose derivative is zero are held to the row's scale, not to their own).
Central differences with step h_j = step·max(1, |x_j|) have error O(h²) from truncation plus about
eps·|f| / h from rounding: with the default step 1e-6, ~1e-10·|f| / ‖∇f‖∞ relative.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

DEFAULT_STEP = 1e-6


@dataclass(frozen=True, eq=False)
class GradientCheck:
    """The result of ``check_gradient``.

    max_rel_error : the largest normwise relative error (see the module docstring)
    worst : (row, coordinate) where it occurs (row 0 for a scalar function)
    coordinates : (c,) the coordinates of x checked
    analytic, numeric : (c,) for a scalar function, else (r, c): the derivatives compared
    step : relative finite-difference step
    n_evals : evaluations of the function (2 per coordinate)
    """

    max_rel_error: float
    worst: tuple[int, int]
    coordinates: np.ndarray = field(repr=False)
    analytic: np.ndarray = field(repr=False)
    numeric: np.ndarray = field(repr=False)
    step: float
    n_evals: int

    def passed(self, rtol: float) -> bool:
        """True when the largest relative error is at most ``rtol``."""
        return bool(self.max_rel_error <= rtol)


def check_gradient(fun: Callable[[np.ndarray], float | np.ndarray], x: np.ndarray, grad: np.ndarray, *,
                   step: float = DEFAULT_STEP, coordinates: np.ndarray | None = None) -> GradientCheck:
    """Compare ``grad`` with central differences of ``fun`` at x.

    Parameters
    ----------
    fun : x (P,) -> a float, or a residual (r,)
    x : (P,) the point
    grad : (P,) the analytic gradient at x, or (r, P) the Jacobian of a residual
    step : relative step, h_j = step·max(1, |x_j|)
    coordinates : indices of x to check (default all; 2 evaluations of ``fun`` each)
    """
    x = np.asarray(x, dtype=float)
    A = np.asarray(grad, dtype=float)
    scalar = A.ndim == 1
    A = np.atleast_2d(A)
    if A.shape[1] != x.size:
        raise ValueError(f"grad has {A.shape[1]} columns, x has {x.size} entries")
    if not step > 0:
        raise ValueError(f"step must be > 0, got {step}")
    idx = np.arange(x.size) if coordinates is None else np.asarray(coordinates, dtype=int)
    D = np.empty((A.shape[0], idx.size))
    for c, j in enumerate(idx):  # one coordinate at a time: each needs its own two evaluations
        xp, xm = x.copy(), x.copy()
        h = step * max(1.0, abs(x[j]))
        xp[j] += h
        xm[j] -= h
        D[:, c] = (np.atleast_1d(fun(xp)) - np.atleast_1d(fun(xm))) / (xp[j] - xm[j])
    A = A[:, idx]
    scale = np.maximum(np.abs(A).max(axis=1, initial=0.0), np.abs(D).max(axis=1, initial=0.0))
    err = np.abs(A - D) / np.where(scale > 0, scale, 1.0)[:, None]
    if err.size:
        row, col = np.unravel_index(int(np.argmax(err)), err.shape)
        worst, max_err = (int(row), int(idx[col])), float(err[row, col])
    else:
        worst, max_err = (0, -1), 0.0
    if scalar:
        A, D = A[0], D[0]
    return GradientCheck(max_rel_error=max_err, worst=worst, coordinates=idx, analytic=A, numeric=D,
                         step=step, n_evals=2 * idx.size)
