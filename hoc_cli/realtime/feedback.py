"""The feedback correction of a catch's plan near the catch: the plan moved to meet the ball's latest estimate.

The real-time iteration splits each cycle into a preparation (the expensive linearisation) and a feedback phase
that applies the newest data to it, so that the latency between a measurement and its effect is a fraction of
a step's (Diehl, Bock & Schlöder 2005). Near the catch, where the catch time T_c [s] is held, an SQP update
(about 14 ms of compute at N = 8) acts on observations too old for the ball's estimate at the catch; this
correction, a few milliseconds, is the feedback phase that uses the newest ones.

Symbols and units: the plan in force, shifted to start at t_s [s] (``shift.shift_plan``, exact), lasts
L = T_c − t_s [s]; n joints. The correction added to joint j is the cubic

    δq_j(τ) = a_j H₁(s) + b_j L H₂(s),   s = τ / L,   H₁ = 3s² − 2s³,   H₂ = s³ − s²,

zero with its velocity at the start (the robot's state is kept), a_j [rad] and b_j [rad/s] at the catch; every
element represents it exactly (cubic or quintic Hermite). x = (a, b) (2n,) is the least-acceleration
correction,

    min ∫₀ᴸ ‖δq̈‖² dτ = Σ_j 12a_j²/L³ − 12a_j b_j/L² + 4b_j²/L,

subject to the flange's position and velocity at the catch meeting the estimate's (6 rows A x = −r, A by
forward differences of the forward kinematics; ``ITERATIONS``
Gauss-Newton rounds) and to the kinematic limits (position, velocity, acceleration; the jerk by the check) at
``SAMPLES`` points per element and two just after the start (a dense quadratic programme, ``hoc_cli.goals.qp_step.solve_qp``, from the rows
near their bound, the rows its step breaks added; the catch rides velocity limits). When the limits leave no
correction that meets the 6 rows (joints held at a velocity bound), the rows become a penalty ``SOFT`` times
the objective's scale: the closest correction within the limits, applied only if it is closer than the plan
in force. The corrected plan must
pass ``check_limits`` (exact extrema, the torques at 32 points per element), else there is none. Pure maths: no I/O.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from hoc_cli.constraints.check import check_limits
from hoc_cli.dynamics import frame_jacobian, link_poses
from hoc_cli.errors import NumericalError
from hoc_cli.goals.qp_step import solve_qp, upper_factor
from hoc_cli.realtime.shift import shift_plan

ITERATIONS = 2  # Gauss-Newton rounds of the 6 goal rows
EPS = 1e-6  # [rad, rad/s] the forward differences' step
SAMPLES = 16  # limit rows per element
NEAR = 0.02  # the programme starts with the rows within this fraction of their bound
MARGIN = 2e-4  # the rows' bounds moved inwards by this fraction (the extrema between the samples)
ROUNDS = 4  # cutting-plane rounds per Gauss-Newton step
SOFT = 1e6  # when the limits leave no exact correction: the rows' weight, relative to the largest of the objective's


def _flange(model, link: str, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
    """(k, 6): the position [m] and linear velocity [m/s] of ``link`` at joint states q, q̇ (k, n)."""
    P = link_poses(model, q)[link][:, :3, 3]
    J = frame_jacobian(model, q, link)[:, :3]
    return np.hstack([P, np.einsum("kij,kj->ki", J, dq)])


def basis(s: np.ndarray, L: float) -> np.ndarray:
    """(4, 2, k): the d-th τ-derivative (d = 0 … 3) of H₁ and L H₂ at s (k,) ∈ [0, 1] (module docstring)."""
    one, zero = np.ones_like(s), np.zeros_like(s)
    h1 = [3 * s**2 - 2 * s**3, (6 * s - 6 * s**2) / L, (6 - 12 * s) / L**2, -12 * one / L**3]
    h2 = [L * (s**3 - s**2), 3 * s**2 - 2 * s, (6 * s - 2) / L, 6 * one / L**2 + zero]
    return np.array([[a, b] for a, b in zip(h1, h2)])


def _limit_rows(limits, mesh, C: np.ndarray, L: float):
    """The kinematic limits at the sample points as rows G x ≤ h in x = (a (n,), b (n,)), with each row's current
    slack (G (R, 2n), h (R,), slack (R,) [the plan's own]); R = 2 · kinds · samples · n.
    """
    n = C.shape[2]
    # the start is the robot's state; two points just after it hold a bound the plan starts on
    tau = np.concatenate([[1e-4 * L, 1e-3 * L], np.linspace(0.0, L, SAMPLES * mesh.N + 1)[1:]])
    k = tau.size
    B = basis(tau / L, L)
    G, h, size = [], [], []
    for d, kind in enumerate(("position", "velocity", "acceleration")):
        if not limits.has(kind).any():
            continue
        lo, hi = limits.bounds(kind)
        v = mesh.evaluate(C, tau, d)  # (k, n)
        for sign, bound in ((1.0, hi), (-1.0, lo)):
            slack = sign * (bound - v) - MARGIN * np.abs(bound)  # ≥ 0 where the plan is within: (k, n)
            rows = np.zeros((k, n, 2 * n))
            j = np.arange(n)
            rows[:, j, j] = sign * B[d, 0][:, None]
            rows[:, j, n + j] = sign * B[d, 1][:, None]
            ok = np.isfinite(slack)
            G.append(rows[ok])
            h.append(np.maximum(slack[ok], 0.0))
            size.append(np.broadcast_to(np.abs(bound), slack.shape)[ok])
    if not G:
        return np.zeros((0, 2 * n)), np.zeros(0), np.zeros(0)
    return np.concatenate(G), np.concatenate(h), np.concatenate(size)


def _step(U, g, A, e, G, h, use) -> np.ndarray:
    """The programme's step d from rows ``use`` (changed in place), the rows it breaks added (cutting planes)."""
    for _ in range(ROUNDS):
        d = solve_qp(U, g, A, e, G[use], h[use]).d
        broken = G @ d > h + 1e-12
        if not np.any(broken & ~use):
            break
        use |= broken
    return d


def correct(system, limits, link: str, plan, t_s: float, position, velocity):
    """The plan in force ``plan`` (a ``replanner.CyclePlan``) from t_s [s] on, corrected so that ``link`` meets
    ``position`` (3,) [m] with ``velocity`` (3,) [m/s] at its end (module docstring); None when t_s is not
    before the end, the programme has no solution, the correction would leave the flange farther from the goal
    than the plan does, or the corrected plan breaks a limit. The returned plan keeps ``plan.J`` (not
    re-evaluated), has status "feedback" and its ``violation`` the largest |c| of the 6 rows [m, m/s].
    """
    L = plan.t_end - t_s
    if not L > 0.0:
        return None
    model = system.model
    sh = shift_plan(plan.mesh, plan.coeffs, plan.t0, t_s)
    mesh, C0 = sh.mesh, sh.coeffs
    n = C0.shape[2]
    goal = np.concatenate([np.asarray(position, float), np.asarray(velocity, float)])
    w = np.array([[12 / L**3, -6 / L**2], [-6 / L**2, 4 / L]])  # per joint, of (a_j, b_j)
    W = np.kron(w, np.eye(n))
    U = upper_factor(W)
    G, h, size = _limit_rows(limits, mesh, C0, L) if limits is not None else (np.zeros((0, 2 * n)),) + (np.zeros(0),) * 2
    use = h < NEAR * size  # the rows near their bound first
    x = np.zeros(2 * n)
    miss0 = None
    try:
        for _ in range(ITERATIONS):
            q, dq = C0[-1, 0] + x[:n], C0[-1, 1] + x[n:]
            Q = np.vstack([q, q + EPS * np.eye(n), np.repeat(q[None], n, 0)])
            DQ = np.vstack([dq, np.repeat(dq[None], n, 0), dq + EPS * np.eye(n)])
            F = _flange(model, link, Q, DQ)
            miss0 = np.max(np.abs(F[0] - goal)) if miss0 is None else miss0
            A = ((F[1:] - F[0]) / EPS).T  # (6, 2n): the columns of δq_j, then of δq̇_j at the catch
            g = W @ x  # the objective's gradient at x: the step d minimises from x
            try:
                d = _step(U, g, A, goal - F[0], G, h - G @ x, use)
            except NumericalError:  # the limits leave no correction meeting the 6 rows: the closest one instead
                Wp = W + SOFT * np.max(np.diag(W)) / np.max(np.abs(A)) ** 2 * A.T @ A
                gp = g - SOFT * np.max(np.diag(W)) / np.max(np.abs(A)) ** 2 * A.T @ (goal - F[0])
                d = _step(upper_factor(Wp), gp, A[:0], np.zeros(0), G, h - G @ x, use)
            x = x + d
    except NumericalError:
        return None
    miss = float(np.max(np.abs(_flange(model, link, (C0[-1, 0] + x[:n])[None], (C0[-1, 1] + x[n:])[None])[0] - goal)))
    if miss > miss0:  # the closest correction within the limits is farther from the goal than the plan in force
        return None
    B = basis(mesh.nodes / L, L)
    C = C0.copy()
    for d in range(C.shape[1]):
        C[:, d] += np.outer(B[d, 0], x[:n]) + np.outer(B[d, 1], x[n:])
    C[0, :2] = C0[0, :2]  # the start state exactly
    if limits is not None and not check_limits(system, limits, mesh, C).feasible:
        return None
    return dataclasses.replace(plan, t0=t_s, mesh=mesh, coeffs=C, steps=0, status="feedback", violation=miss)
