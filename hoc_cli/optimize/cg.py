"""Preconditioned Polak-Ribière (PR+) nonlinear conjugate gradient, and a line-searched Newton method.

With a symmetric positive-definite preconditioner P and z = P⁻¹ g (Nocedal & Wright §5.2;
Polak & Ribière 1969; PR+ truncation β = max(0, ·) after Gilbert & Nocedal 1992):

    d_0 = −z_0,   β_k = max(0, z_kᵀ (g_k − g_{k−1}) / (z_{k−1}ᵀ g_{k−1})),   d_k = −z_k + β_k d_{k−1}

and each step x_{k+1} = x_k + α_k d_k satisfies the strong Wolfe conditions. The strong Wolfe
conditions alone do not make d_k a descent direction for PR+; Gilbert & Nocedal's convergence
theorem assumes the sufficient-descent condition g_kᵀd_k <= −σ g_kᵀP⁻¹g_k (here in the P⁻¹ norm,
σ = ``SUFFICIENT_DESCENT`` = 0.01, scipy's ``_minimize_cg`` value), so when d_k fails it the method
restarts along the preconditioned steepest descent d_k = −z_k. With P = I this is the paper's
plain Polak-Ribière method. ``method="newton"`` sets β = 0: with P the (modified) Hessian, a
line-searched Newton method. P is rebuilt at every iterate (one ``precondition`` call), except
when the previous one already passes the stopping test there (a rebuild saved).

Stopping tests (the one that held is reported as ``OptimizeResult.stop_test``). The decrement
½ gᵀP⁻¹g estimates J − J* when P approximates the Hessian; we stop when

    DECREMENT   ½ gᵀP⁻¹g <= tol·|J|, or
    ROUNDING    ½ gᵀP⁻¹g <= J_noise, the rounding level of J supplied by the caller (``noise``):
                J cannot be resolved further in double precision;
    GRADIENT    with P = I (no preconditioner) instead: ‖g‖∞ <= tol·max(|J|, 1).
"""
from __future__ import annotations

import math
from typing import Any, Callable

import numpy as np

from hoc_cli.optimize.linesearch import check_parameters, strong_wolfe
from hoc_cli.optimize.result import IterLog, OptimizeResult, Status, StopTest, message

# evaluate(x) -> (J, g, payload); precondition(payload) -> object with .solve(g) (or None for P = I)
Evaluate = Callable[[np.ndarray], tuple[float, np.ndarray, Any]]
Precondition = Callable[[Any], Any]
SUFFICIENT_DESCENT = 0.01


class _Identity:
    def solve(self, g: np.ndarray) -> np.ndarray:
        return g


class _Counted:
    """The objective and the preconditioner, counting their calls (the work reported in the result)."""

    def __init__(self, evaluate: Evaluate, precondition: Precondition | None) -> None:
        self._evaluate, self._precondition = evaluate, precondition
        self.n_evals = 0
        self.n_precond = 0

    def evaluate(self, x: np.ndarray) -> tuple[float, np.ndarray, Any]:
        self.n_evals += 1
        return self._evaluate(x)

    def precondition(self, payload: Any) -> Any:
        if self._precondition is None:
            return _Identity()
        self.n_precond += 1
        return self._precondition(payload)


def stop_test(J: float, g: np.ndarray, gz: float, *, tol: float, noise: float, preconditioned: bool) -> StopTest | None:
    """The stopping test that holds at cost J, gradient g (P,), gz = gᵀP⁻¹g, or None (see the module docstring).

    DECREMENT is reported whenever it holds, ROUNDING only when the decrement test does not.
    """
    if not preconditioned:
        return StopTest.GRADIENT if float(np.max(np.abs(g), initial=0.0)) <= tol * max(abs(J), 1.0) else None
    if 0.5 * gz <= tol * abs(J) or gz == 0.0:
        return StopTest.DECREMENT
    if 0.5 * gz <= noise:
        return StopTest.ROUNDING
    return None


def minimize(evaluate: Evaluate, x0: np.ndarray, *, precondition: Precondition | None = None,
             method: str = "pr-cg", tol: float = 1e-10, max_iter: int = 5000,
             callback: Callable[[IterLog], None] | None = None,
             noise: Callable[[Any], float] | None = None, c1: float = 1e-4, c2: float = 0.1,
             first_step: Callable[[Any, np.ndarray, float], float] | None = None) -> OptimizeResult:
    """Minimise a smooth function from x0.

    Parameters
    ----------
    evaluate : x (P,) -> (J, ∇J (P,), payload); the payload is handed to ``precondition`` and ``noise``
    x0 : (P,) starting point
    precondition : payload -> SPD solver with ``solve(g)``; None for no preconditioning
    method : "pr-cg" (PR+ conjugate gradient) or "newton" (β = 0)
    tol : relative tolerance of the stopping test on J (see the module docstring)
    max_iter : iteration limit; reaching it returns status MAX_ITER with the best iterate
    callback : called with an ``IterLog`` after every iteration (progress display)
    noise : payload -> rounding level of J at that point; the stopping test also holds when the
        decrement is below it (J cannot be resolved further in double precision)
    c1, c2 : the strong Wolfe parameters of the line search (0 < c1 < c2 < 1/2 for PR+); a smaller
        c2 makes the line search more nearly exact (as scipy's ``minimize(method="CG")`` offers)
    first_step : (payload, d, gᵀd) -> the line search's first trial step along d, with a preconditioner
        (default: the unit step; e.g. a model of the penalty rows the step would activate)

    Returns
    -------
    OptimizeResult (frozen): the last iterate, status, the stopping test that held, work counts.
    """
    if method not in ("pr-cg", "newton"):
        raise ValueError(f"method must be 'pr-cg' or 'newton', got {method!r}")
    if not tol > 0:
        raise ValueError(f"tol must be > 0, got {tol}")
    check_parameters(c1, c2)
    f = _Counted(evaluate, precondition)
    x = np.array(x0, dtype=float)
    J, g, payload = f.evaluate(x)
    history: list[IterLog] = []
    if not (math.isfinite(J) and np.all(np.isfinite(g))):
        return OptimizeResult(x, J, g, Status.NOT_FINITE, 0, f.n_evals, f.n_precond, math.nan,
                              message=message(Status.NOT_FINITE))
    P = f.precondition(payload)
    z = P.solve(g)
    gz = float(g @ z)
    d = -z
    status, stop = Status.MAX_ITER, None
    it = restarts = 0
    alpha_prev, J_prev = 1.0, None
    restarted = False

    while True:
        stop = stop_test(J, g, gz, tol=tol, noise=noise(payload) if noise is not None else 0.0,
                         preconditioned=precondition is not None)
        if stop is not None:
            status = Status.CONVERGED
            break
        if it >= max_iter:
            status = Status.MAX_ITER
            break
        dphi0 = float(g @ d)
        if not dphi0 < 0:  # only with a preconditioner that is not positive definite: try −P⁻¹g
            d, dphi0 = -z, -gz
        # first trial: the unit (Newton-like) step with a preconditioner (or ``first_step``'s), else the previous decrease
        if precondition is not None:
            a0 = 1.0 if first_step is None else first_step(payload, d, dphi0)
        elif J_prev is not None:
            a0 = min(1.0, 1.01 * 2.0 * (J - J_prev) / dphi0) if J_prev > J else alpha_prev
        else:
            a0 = min(1.0, 1.0 / max(float(np.max(np.abs(g))), 1e-300))

        def phi(a: float, x=x, d=d):
            Ja, ga, pa = f.evaluate(x + a * d)
            ok = math.isfinite(Ja) and np.all(np.isfinite(ga))
            return (Ja if ok else math.inf), (float(ga @ d) if ok else math.nan), (Ja, ga, pa)

        ls = strong_wolfe(phi, J, dphi0, alpha0=a0, c1=c1, c2=c2)
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
        # the rebuild is skipped; otherwise P is rebuilt here.
        if not (precondition is not None and 0.5 * gz_new <= tol * abs(J)):
            P = f.precondition(payload)
            z_new = P.solve(g_new)
            gz_new = float(g_new @ z_new)
        if method == "newton" or not ls.ok:
            beta = 0.0
        else:
            beta = max(0.0, float(z_new @ (g_new - g)) / gz) if gz > 0 else 0.0
        d = -z_new + beta * d
        if beta > 0.0 and not float(g_new @ d) <= -SUFFICIENT_DESCENT * gz_new:  # Gilbert & Nocedal
            d = -z_new
            restarts += 1
        g, z, gz = g_new, z_new, gz_new
        restarted = False
        log = IterLog(it, J, float(np.max(np.abs(g), initial=0.0)), 0.5 * gz, ls.alpha, f.n_evals)
        history.append(log)
        if callback is not None:
            callback(log)
    return OptimizeResult(x=x, fun=J, grad=g, status=status, iterations=it, n_evals=f.n_evals,
                          n_precond=f.n_precond, decrement=0.5 * gz, history=tuple(history),
                          message=message(status, stop), stop_test=stop, restarts=restarts)
