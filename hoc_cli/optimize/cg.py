"""Preconditioned Polak-Ribière (PR+) nonlinear conjugate gradient, and Gauss-Newton as its β = 0 case.

With a symmetric positive-definite preconditioner P and z = P⁻¹ g (Nocedal & Wright §5.2;
Polak & Ribière 1969; PR+ truncation β = max(0, ·) after Gilbert & Nocedal 1992):

    d_0 = −z_0,   β_k = max(0, z_kᵀ (g_k − g_{k−1}) / (z_{k−1}ᵀ g_{k−1})),   d_k = −z_k + β_k d_{k−1}

and each step x_{k+1} = x_k + α_k d_k satisfies the strong Wolfe conditions. With P = I this is
the paper's plain Polak-Ribière method. ``method="newton"`` sets β = 0 and refreshes P every
iteration: with P the (modified) Hessian, a line-searched Newton method.

Stopping test: the decrement ½ gᵀP⁻¹g estimates J − J* when P approximates the Hessian;
we stop when ½ gᵀP⁻¹g <= max(tol·|J|, J_noise) where J_noise is the rounding level of J
supplied by the caller (with P = I: when ‖g‖∞ <= tol·max(|J|, 1)). P is the matrix built at the
current iterate, or at the previous one when that one already passes the test (a rebuild saved).
"""
from __future__ import annotations

import math
from typing import Any, Callable

import numpy as np

from hoc_cli.optimize.linesearch import strong_wolfe
from hoc_cli.optimize.result import MESSAGES, IterLog, OptimizeResult, Status

# evaluate(x) -> (J, g, payload); precondition(payload) -> object with .solve(g) (or None for P = I)
Evaluate = Callable[[np.ndarray], tuple[float, np.ndarray, Any]]
Precondition = Callable[[Any], Any]


class _Identity:
    def solve(self, g: np.ndarray) -> np.ndarray:
        return g


def minimize(evaluate: Evaluate, x0: np.ndarray, *, precondition: Precondition | None = None,
             method: str = "pr-cg", tol: float = 1e-10, max_iter: int = 5000, refresh: int = 1,
             callback: Callable[[IterLog], None] | None = None,
             noise: Callable[[Any], float] | None = None, final_precondition: Precondition | None = None,
             switch: float = 1e-6) -> OptimizeResult:
    """Minimise a smooth function from x0.

    Parameters
    ----------
    evaluate : x (P,) -> (J, ∇J (P,), payload); the payload is handed to ``precondition``
    precondition : payload -> SPD solver with ``solve(g)``; None for no preconditioning
    method : "pr-cg" (PR+ conjugate gradient) or "newton" (β = 0)
    tol : relative tolerance of the stopping test on J (see the module docstring)
    max_iter : iteration limit; reaching it returns status MAX_ITER with the best iterate
    refresh : recompute the preconditioner every ``refresh`` iterations (always for newton)
    callback : called with an ``IterLog`` after every iteration (progress display)
    noise : payload -> rounding level of J at that point; the stopping test also holds when the
        decrement is below it (J cannot be resolved further in double precision)
    final_precondition : a better (costlier) preconditioner, e.g. the Newton matrix, used from the
        moment the decrement falls below ``switch``·|J|, and always to confirm the stopping test:
        with it P is refreshed every iteration, so the decrement estimates J − J* reliably
    """
    if method not in ("pr-cg", "newton"):
        raise ValueError(f"method must be 'pr-cg' or 'newton', got {method!r}")
    if not tol > 0:
        raise ValueError(f"tol must be > 0, got {tol}")
    if method == "newton":
        refresh = 1
    evals = 0
    n_precond = 0

    def ev(x: np.ndarray):
        nonlocal evals
        evals += 1
        return evaluate(x)

    def make_precond(payload: Any):
        nonlocal n_precond
        if precondition is None:
            return _Identity()
        n_precond += 1
        return precondition(payload)

    x = np.array(x0, dtype=float)
    J, g, payload = ev(x)
    history: list[IterLog] = []
    if not (math.isfinite(J) and np.all(np.isfinite(g))):
        return OptimizeResult(x, J, g, Status.NOT_FINITE, 0, evals, n_precond, math.nan, history, MESSAGES[Status.NOT_FINITE])
    P = make_precond(payload)
    z = P.solve(g)
    gz = float(g @ z)
    d = -z
    status = Status.MAX_ITER
    it = 0
    alpha_prev, J_prev = 1.0, None
    restarted = False

    def converged(J: float, g: np.ndarray, gz: float) -> bool:
        floor = noise(payload) if noise is not None else 0.0
        if precondition is None:
            return float(np.max(np.abs(g), initial=0.0)) <= tol * max(abs(J), 1.0)
        return 0.5 * gz <= max(tol * abs(J), floor) or gz == 0.0

    final = False

    def go_final() -> None:
        nonlocal P, z, gz, d, final
        final = True
        P = make_final(payload)
        z = P.solve(g)
        gz = float(g @ z)
        d = -z

    def make_final(payload: Any):
        nonlocal n_precond
        n_precond += 1
        return final_precondition(payload)  # type: ignore[misc]

    while True:
        if final_precondition is not None and not final and 0.5 * gz <= switch * abs(J):
            go_final()
        if converged(J, g, gz):
            if final_precondition is not None and not final:
                go_final()
                if not converged(J, g, gz):
                    continue
            status = Status.CONVERGED
            break
        if it >= max_iter:
            status = Status.MAX_ITER
            break
        dphi0 = float(g @ d)
        if not dphi0 < 0:  # not a descent direction: restart along −P⁻¹g
            d, dphi0 = -z, -gz
        # first trial: the unit (Newton-like) step with a preconditioner, else the previous decrease
        if precondition is not None:
            a0 = 1.0
        elif J_prev is not None:
            a0 = min(1.0, 1.01 * 2.0 * (J - J_prev) / dphi0) if J_prev > J else alpha_prev
        else:
            a0 = min(1.0, 1.0 / max(float(np.max(np.abs(g))), 1e-300))

        def phi(a: float, x=x, d=d):
            Ja, ga, pa = ev(x + a * d)
            ok = math.isfinite(Ja) and np.all(np.isfinite(ga))
            return (Ja if ok else math.inf), (float(ga @ d) if ok else math.nan), (Ja, ga, pa)

        ls = strong_wolfe(phi, J, dphi0, alpha0=a0)
        if not ls.ok:
            if ls.payload is not None and ls.phi < J:  # accept the best decrease found, then restart
                pass
            elif not restarted and not np.array_equal(d, -z):
                d = -z
                restarted = True
                continue
            else:
                status = Status.LINE_SEARCH_FAILED
                break
        J_prev = J
        x = x + ls.alpha * d
        J, g_new, payload = ls.payload
        alpha_prev = ls.alpha
        it += 1
        if not (math.isfinite(J) and np.all(np.isfinite(g_new))):
            status = Status.NOT_FINITE
            break
        z_new = P.solve(g_new)
        gz_new = float(g_new @ z_new)
        # When the matrix built one step ago already finds the decrement below tol·|J| (near the
        # optimum it differs from the current one by O(step)), the stopping test is taken with it and
        # the rebuild is skipped; otherwise P is refreshed as scheduled.
        settled = precondition is not None and 0.5 * gz_new <= tol * abs(J)
        if not settled:
            if final:
                P = make_final(payload)
            elif it % refresh == 0:
                P = make_precond(payload)
            z_new = P.solve(g_new)
            gz_new = float(g_new @ z_new)
        if method == "newton" or not ls.ok:
            beta = 0.0
        else:
            beta = max(0.0, float(z_new @ (g_new - g)) / gz) if gz > 0 else 0.0
        d = -z_new + beta * d
        g, z, gz = g_new, z_new, gz_new
        restarted = False
        log = IterLog(it, J, float(np.max(np.abs(g), initial=0.0)), 0.5 * gz, ls.alpha, evals)
        history.append(log)
        if callback is not None:
            callback(log)
    return OptimizeResult(x=x, fun=J, grad=g, status=status, iterations=it, n_evals=evals, n_precond=n_precond,
                          decrement=0.5 * gz, history=history, message=MESSAGES[status])
