"""Starting trajectories that leave the straight joint-space path: via candidates from a cheap search.

The minimum-jerk guess moves every joint along the straight segment q0 → q1; when that segment
runs through an obstacle the penalty pushes the path out along the nearest contact normal, which
can hold it against the obstacle's far side. ``via_candidates`` draws joint states q_v about the
midpoint (seeded, reproducible), scores the two straight segments q0 → q_v → q1 by their smallest
clearance at ``SEGMENT_SAMPLES`` configurations each, the best of them again at ``FINE_SAMPLES`` (a
search heuristic, not a proof: the plan is certified afterwards), and returns the shortest clear ones; ``via_guess`` is the trajectory through q_v at T/2.

Symbols: n joints; distances in m; joint values in rad (m for prismatic joints).
"""
from __future__ import annotations

import numpy as np

from hoc_cli.collision.evaluate import distances
from hoc_cli.collision.scene import CollisionScene
from hoc_cli.elements import HermiteMesh
from hoc_cli.model.tree import RobotModel

SEGMENT_SAMPLES = 12  # configurations per straight segment when screening the candidates
FINE_SAMPLES = 96     # ... and when checking the best CHECKED·count of them
CHECKED = 4
SCALES = (0.35, 0.7, 1.2, 2.0)  # rad: the spread of the candidates about the midpoint, a quarter of them each
CANDIDATES = 128


def via_candidates(model: RobotModel, scene: CollisionScene, q0: np.ndarray, q1: np.ndarray, *,
                   count: int = 3, candidates: int = CANDIDATES, seed: int = 0) -> list[tuple[np.ndarray, float]]:
    """Up to ``count`` vias (q_v (n,), clearance m) among ``candidates`` seeded draws
    q_v = (q0 + q1)/2 + σ z (z standard normal, σ in ``SCALES``) within the position limits: those
    clear by the margin shortest first (joint-space length |q_v − q0| + |q1 − q_v|), then the others
    clearest first.

    The clearance of a via is the smallest signed distance over every pair at ``SEGMENT_SAMPLES``
    configurations on each straight segment q0 → q_v → q1 (ends excluded) to rank all candidates,
    then at ``FINE_SAMPLES`` for the best ``CHECKED``·count (the clearance returned).
    """
    rng = np.random.default_rng(seed)
    n = q0.size
    lo = np.where(np.isfinite(model.lower), model.lower, -np.pi)
    hi = np.where(np.isfinite(model.upper), model.upper, np.pi)
    sigma = np.repeat(SCALES, -(-candidates // len(SCALES)))[:candidates]
    vias = np.clip((q0 + q1) / 2 + sigma[:, None] * rng.standard_normal((candidates, n)), lo, hi)
    length = np.linalg.norm(vias - q0, axis=1) + np.linalg.norm(q1 - vias, axis=1)
    order, clearance = _ranked(model, scene, q0, q1, vias, length, SEGMENT_SAMPLES)
    best = order[:CHECKED * count]  # the best of the screening, checked on a finer sampling
    order_fine, fine = _ranked(model, scene, q0, q1, vias[best], length[best], FINE_SAMPLES)
    return [(vias[best[i]], float(fine[i])) for i in order_fine[:count]]


def _ranked(model, scene, q0, q1, vias, length, samples: int) -> tuple[np.ndarray, np.ndarray]:
    """(the vias' order: clear by the margin shortest first, then clearest first; each via's clearance (V,) m)
    at ``samples`` configurations per straight segment.
    """
    V, n = vias.shape
    s = (np.arange(samples) + 1) / (samples + 1)
    first = q0 + s[None, :, None] * (vias[:, None, :] - q0)            # (V, S, n)
    second = vias[:, None, :] + s[None, :, None] * (q1 - vias[:, None, :])
    q = np.concatenate([first, second, vias[:, None, :]], axis=1)       # (V, 2S + 1, n)
    d = distances(model, scene, q.reshape(-1, n)).reshape(V, -1)
    clearance = d.min(axis=1) if d.size else np.full(V, np.inf)
    clear = clearance >= scene.margin
    return np.lexsort((np.where(clear, length, -clearance), ~clear)), clearance


def _quintic(p0, v0, p1, v1, h: float, tau: np.ndarray) -> tuple[np.ndarray, ...]:
    """q, q̇, q̈ (len(tau), n) at times tau ∈ [0, h] of the quintic with p, v at both ends and q̈ = 0 there."""
    A = np.array([[1, 0, 0, 0, 0, 0], [0, 1, 0, 0, 0, 0], [0, 0, 2, 0, 0, 0],
                  [1, 1, 1, 1, 1, 1], [0, 1, 2, 3, 4, 5], [0, 0, 2, 6, 12, 20]], dtype=float)
    coef = np.linalg.solve(A, np.stack([p0, v0 * h, np.zeros_like(p0), p1, v1 * h, np.zeros_like(p0)]))
    s = tau / h
    k = np.arange(6)
    P = s[:, None] ** k
    D1 = np.where(k >= 1, k * s[:, None] ** np.maximum(k - 1, 0), 0.0) / h
    D2 = np.where(k >= 2, k * (k - 1) * s[:, None] ** np.maximum(k - 2, 0), 0.0) / h ** 2
    return P @ coef, D1 @ coef, D2 @ coef


def via_guess(mesh: HermiteMesh, q0, dq0, qv, q1, dq1) -> np.ndarray:
    """Coefficients C (N+1, m, n) through qv at T/2: two quintics (rest accelerations at their ends,
    velocity (q1 − q0)/T at the via), sampled at the mesh's nodes.
    """
    q0, dq0, qv, q1, dq1 = (np.asarray(v, float) for v in (q0, dq0, qv, q1, dq1))
    T = mesh.T
    half = T / 2
    vv = (q1 - q0) / T
    t = mesh.nodes
    out = np.zeros((t.size, 3, q0.size))
    early = t <= half
    out[early] = np.stack(_quintic(q0, dq0, qv, vv, half, t[early]), axis=1)
    out[~early] = np.stack(_quintic(qv, vv, q1, dq1, half, t[~early] - half), axis=1)
    C = out[:, : mesh.m].copy()
    C[0, 0], C[0, 1], C[-1, 0], C[-1, 1] = q0, dq0, q1, dq1
    return C
