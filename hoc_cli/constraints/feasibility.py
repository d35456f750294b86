"""Tasks that no trajectory within the joint limits can meet, found before the solve (pure maths, no I/O).

The task pins the joint state at some instants: q and q̇ at t = 0 (x0), at T (a joint goal x1) and at
each joint via (q, and q̇ when the via gives it), at fractions s of T. Every bound below holds for
*every* C² trajectory through those states within the limits (so for every plan hoc can write), and
each gives the shortest duration T for which one might exist; a task whose T (for a free T, its
``max``) is shorter is infeasible. Between two consecutive pinned instants, Δt = Δs·T apart, for
each joint with Δq = q_b − q_a, velocities v_a, v_b and limits v (velocity), a (acceleration):

- velocity: |Δq| = |∫ q̇ dt| <= v·Δt, so Δt >= |Δq| / v (``shortest_duration``);
- acceleration, both rates known: the time-optimal double integrator with |q̈| <= a from (0, v_a) to
  (Δq, v_b) (one switch of bang-bang; ignoring v, so a lower bound); at rest at both ends with v too,
  the bang-coast-bang time |Δq|/v + v/a when |Δq| >= v²/a, else 2√(|Δq|/a);
- energy, both rates known: along any trajectory dE/dt = q̇ᵀu with E = ½ q̇ᵀM(q)q̇ + V(q) (rigid
  bodies are passive), and |u_i q̇_i| <= e_i v_i, so |E_b − E_a| <= Δt Σ_i e_i v_i. V(q_b) − V(q_a) =
  ∫ g(q)ᵀ dq along the straight segment, g(q) = ID(q, 0, 0), by Gauss–Legendre quadrature (the
  bound is claimed only when 32 and 64 points agree far inside the margin).

And one check at an instant, for every T: where q and q̇ are pinned, u = M(q) q̈ + h(q, q̇) with q̈
free (x0 and x1 fix q and q̇ only: q̈ at the boundary is a free coefficient of quintic elements, and
of cubic ones through the neighbouring node), so the limits can hold there only if some q̈ with
|q̈| <= a gives |u| <= e: a linear feasibility problem. Without acceleration limits it always has a
solution (q̈ = −M⁻¹h gives u = 0): an effort limit that gravity alone breaks at x0 is then *not* a
proof of infeasibility (the arm may start by falling), and none is claimed.

Each claim keeps a relative margin (``MARGIN``) against rounding.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from hoc_cli.constraints.augmented_lagrangian import shortest_duration
from hoc_cli.constraints.bounds import JointLimits

MARGIN = 1e-6  # a bound is claimed only when the task misses it by more than this (relative)
_GAUSS = (32, 64)  # quadrature points of the potential-energy difference (both must agree)


@dataclass(frozen=True)
class Pinned:
    """A pinned instant: fraction ``s`` of T, q (n,) [rad or m], q̇ (n,) or None, and its task key."""

    s: float
    q: np.ndarray
    dq: np.ndarray | None
    label: str


@dataclass(frozen=True)
class Bound:
    """A shortest duration ``T_min`` [s] (inf: no T works) and what sets it: ``kind`` (velocity,
    acceleration, effort, energy), the ``joint`` (None for several) and ``why`` (one clause).
    """

    T_min: float
    kind: str
    joint: str | None
    why: str


def double_integrator_time(d: np.ndarray, v0: np.ndarray, v1: np.ndarray, a: np.ndarray) -> np.ndarray:
    """Shortest time (n,) [s] to go from (0, v0) to (d, v1) with |q̈| <= a (no velocity limit).

    Bang-bang with one switch: accelerate then brake (peak rate +√(a d + (v0² + v1²)/2)) or the
    mirror; the shorter of the cases that exist. 0 where a is infinite.
    """
    d, v0, v1, a = (np.asarray(x, float) for x in (d, v0, v1, a))
    out = np.zeros(d.shape)
    finite = np.isfinite(a) & (a > 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean_sq = 0.5 * (v0 ** 2 + v1 ** 2)
        up = np.sqrt(a * d + mean_sq)  # NaN where the case does not exist
        down = -np.sqrt(-a * d + mean_sq)
        t_up = np.where(up >= np.maximum(v0, v1) - 1e-12 * (1 + np.abs(up)), (2 * up - v0 - v1) / a, np.inf)
        t_down = np.where(down <= np.minimum(v0, v1) + 1e-12 * (1 + np.abs(down)), (v0 + v1 - 2 * down) / a, np.inf)
    best = np.fmin(t_up, t_down)
    ok = finite & np.isfinite(best)
    out[ok] = np.maximum(best[ok], 0.0)
    return out


def rest_to_rest_time(d: np.ndarray, v: np.ndarray, a: np.ndarray) -> np.ndarray:
    """Shortest time (n,) [s] for a move of |d| from rest to rest with |q̇| <= v and |q̈| <= a (each may be inf)."""
    d, v, a = np.abs(np.asarray(d, float)), np.asarray(v, float), np.asarray(a, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        triangle = np.where(np.isfinite(a), 2.0 * np.sqrt(d / a), 0.0)
        trapezoid = np.where(np.isfinite(v), d / v, 0.0) + np.where(np.isfinite(v) & np.isfinite(a), v / a, 0.0)
        coast = np.isfinite(v) & (~np.isfinite(a) | (d >= v ** 2 / a))
    return np.where(coast, trapezoid, np.where(np.isfinite(a), triangle, np.where(np.isfinite(v), d / v, 0.0)))


def potential_difference(system, q_a: np.ndarray, q_b: np.ndarray) -> float | None:
    """V(q_b) − V(q_a) [J] = ∫ g(q)ᵀ dq along the straight segment; None when the quadratures disagree."""
    dq = np.asarray(q_b, float) - np.asarray(q_a, float)
    values = []
    for points in _GAUSS:
        x, w = np.polynomial.legendre.leggauss(points)
        s = 0.5 * (x + 1.0)
        q = np.asarray(q_a, float)[None, :] + s[:, None] * dq[None, :]
        zero = np.zeros_like(q)
        g = system.inverse_dynamics(q, zero, zero)
        values.append(float(0.5 * np.sum(w * (g @ dq))))
    scale = max(abs(values[1]), 1e-300)
    if not all(math.isfinite(v) for v in values) or abs(values[0] - values[1]) > 1e-3 * MARGIN * scale:
        return None
    return values[1]


def kinetic(system, q: np.ndarray, dq: np.ndarray) -> float:
    """½ q̇ᵀ M(q) q̇ [J]."""
    M = system.mass_matrix(np.asarray(q, float)[None, :])[0]
    return float(0.5 * dq @ M @ dq)


def segment_bounds(system, limits: JointLimits, a: Pinned, b: Pinned) -> list[Bound]:
    """Lower bounds on T from the segment between pinned instants a and b (b.s > a.s)."""
    span = b.s - a.s
    if span <= 0:
        return []
    where = f"between {a.label} and {b.label}"
    out: list[Bound] = []
    both = a.dq is not None and b.dq is not None
    simple = shortest_duration(limits, a.q, a.dq if both else np.ones_like(a.q), b.q,
                               b.dq if both else np.ones_like(b.q))
    if simple is not None:
        t, joint, kind = simple
        out.append(Bound(t / span, kind, joint, f"{joint}'s {kind} limit {where}"))
    if not both:
        return out
    d = b.q - a.q
    rest = (a.dq == 0) & (b.dq == 0)
    t = np.where(rest, rest_to_rest_time(d, limits.velocity, limits.acceleration),
                 double_integrator_time(d, a.dq, b.dq, limits.acceleration))
    j = int(np.argmax(t)) if t.size else 0
    if t.size and t[j] > 0:
        kinds = "velocity and acceleration" if rest[j] and np.isfinite(limits.velocity[j]) else "acceleration"
        out.append(Bound(float(t[j]) / span, "acceleration", limits.joints[j], f"{limits.joints[j]}'s {kinds} limits {where}"))
    power = float(np.sum(limits.effort * limits.velocity))  # inf when any joint lacks either limit
    if math.isfinite(power):
        dV = potential_difference(system, a.q, b.q)
        if dV is not None:
            dE = abs(kinetic(system, b.q, b.dq) - kinetic(system, a.q, a.dq) + dV)
            t_min = dE / power / span if power > 0 else (math.inf if dE > 0 else 0.0)
            out.append(Bound(t_min, "energy", None,
                             f"the effort and velocity limits: the move {where} changes the energy by {dE:.6g} J, "
                             f"and they let the joints do at most Σ effort·velocity = {power:.6g} W of work"))
    return out


def instant_bound(system, limits: JointLimits, p: Pinned) -> Bound | None:
    """``Bound(inf, "effort", …)`` when no q̈ within the acceleration limits keeps |u| within the effort
    limits at the pinned state p (q and q̇ known); None when one exists or nothing can be claimed.
    """
    e, acc = limits.effort, limits.acceleration
    if p.dq is None or not np.isfinite(e).any() or not np.isfinite(acc).any():
        return None  # without acceleration limits q̈ = −M⁻¹h gives u = 0
    q, dq = p.q[None, :], p.dq[None, :]
    M = system.mass_matrix(q)[0]
    h = system.inverse_dynamics(q, dq, np.zeros_like(q))[0]
    a_wide = acc * (1 + MARGIN)
    e_wide = e * (1 + MARGIN) + MARGIN * 1e-6
    reach = np.abs(M) @ np.where(np.isfinite(a_wide), a_wide, np.inf)  # how far q̈ can move each u_i
    with np.errstate(invalid="ignore"):
        least = np.abs(h) - reach  # min |u_i| over the box of q̈, row by row
    rows = np.flatnonzero(np.isfinite(e) & (least > e_wide))
    if rows.size:
        i = int(rows[np.argmax(least[rows] - e[rows])])
        return Bound(math.inf, "effort", limits.joints[i],
                     f"at {p.label} {limits.joints[i]} needs |u| >= {least[i]:.6g} (effort limit {e[i]:.6g}) for every "
                     "acceleration within the acceleration limits, with q and q̇ pinned")
    if not _box_feasible(M, h, e_wide, a_wide):
        return Bound(math.inf, "effort", None,
                     f"at {p.label} no acceleration within the acceleration limits keeps every torque within its "
                     "effort limit, with q and q̇ pinned")
    return None


def holding_bound(system, limits: JointLimits, p: Pinned) -> Bound | None:
    """``Bound(inf, "effort", …)`` when p is a rest state at an end of the move (x0 at s = 0, a joint goal x1 at
    s = 1, q̇ = 0) whose gravity torque g(q) = u(q, 0, 0) breaks an effort limit, else None.

    A rest state at an end is one the arm holds: before t = 0 it stands at x0, after T at x1. Holding q
    takes u = g(q) (no q̈, no q̇), so an effort limit below |g_i(q)| leaves the arm unable to stand there
    whatever the plan does between. (Within the move q̈(0) and q̈(T) are free, so this is the end states'
    requirement, not a bound on the plan's own torques.)
    """
    if p.dq is None or p.s not in (0.0, 1.0) or np.any(p.dq != 0) or not np.isfinite(limits.effort).any():
        return None
    g = system.inverse_dynamics(p.q[None, :], np.zeros((1, p.q.size)), np.zeros((1, p.q.size)))[0]
    e = limits.effort
    over = np.isfinite(e) & (np.abs(g) > e * (1 + MARGIN) + MARGIN * 1e-6)
    if not over.any():
        return None
    i = int(np.argmax(np.where(over, np.abs(g) - e, -np.inf)))
    return Bound(math.inf, "effort", limits.joints[i],
                 f"{p.label} is a rest state the arm holds, and holding it against gravity takes {limits.joints[i]} "
                 f"|u| = {abs(g[i]):.6g}, over its effort limit {e[i]:.6g}")


def _box_feasible(M: np.ndarray, h: np.ndarray, e: np.ndarray, a: np.ndarray) -> bool:
    """Whether some x with |x| <= a has |M x + h| <= e (a linear programme; True when undecided)."""
    from scipy.optimize import linprog

    rows = np.isfinite(e)
    A = np.vstack([M[rows], -M[rows]])
    ub = np.concatenate([e[rows] - h[rows], e[rows] + h[rows]])
    bounds = [(-x if np.isfinite(x) else None, x if np.isfinite(x) else None) for x in a]
    try:
        res = linprog(np.zeros(len(a)), A_ub=A, b_ub=ub, bounds=bounds, method="highs")
    except (ValueError, np.linalg.LinAlgError):
        return True
    return res.status != 2  # 2: proven infeasible


def infeasibility(system, limits: JointLimits, pinned: Sequence[Pinned], T_max: float) -> Bound | None:
    """The strongest bound the task breaks when its longest admissible duration is ``T_max`` [s], or None.

    ``pinned``: the pinned instants in any order (fractions s in [0, 1]). The result's ``T_min`` is
    the shortest duration the bound allows (inf for a state no T can meet).
    """
    points = sorted(pinned, key=lambda p: p.s)
    bounds: list[Bound] = []
    for p in points:
        for b in (instant_bound(system, limits, p), holding_bound(system, limits, p)):
            if b is not None:
                bounds.append(b)
    for a, b in zip(points, points[1:]):
        bounds += segment_bounds(system, limits, a, b)
    known = [p for p in points if p.dq is not None]
    for a, b in zip(known, known[1:]):  # energy over the spans between instants with known rates
        if any(p.s > a.s and p.s < b.s for p in points):
            bounds += [x for x in segment_bounds(system, limits, a, b) if x.kind == "energy"]
    broken = [b for b in bounds if b.T_min > T_max * (1 + MARGIN)]
    return max(broken, key=lambda b: b.T_min) if broken else None
