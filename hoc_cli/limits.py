"""URDF limit checks along a trajectory (pure maths).

A violation is reported per joint and kind ("position", "velocity", "effort") with the worst
value found, the time where it occurs and the limit broken; a side without a limit (±inf in the
model) is reported as None, so that the violation is valid JSON. Units: rad (m), rad/s (m/s), N·m (N).
"""
from __future__ import annotations

import numpy as np


def limit_violations(joints, lower, upper, velocity, effort, t, q, dq, u) -> list[dict]:
    """Samples t (K,), q, dq, u (K, n) against limits (n,) (±inf where none); a list of violations."""
    out: list[dict] = []
    checks = (
        ("position", q, lambda x, i: np.maximum(lower[i] - x, x - upper[i]), lambda i: [lower[i], upper[i]]),
        ("velocity", dq, lambda x, i: np.abs(x) - velocity[i], lambda i: velocity[i]),
        ("effort", u, lambda x, i: np.abs(x) - effort[i], lambda i: effort[i]),
    )
    for kind, X, excess_of, limit_of in checks:
        for i, name in enumerate(joints):
            excess = excess_of(X[:, i], i)
            if not np.any(np.isfinite(excess)):
                continue
            k = int(np.argmax(np.where(np.isfinite(excess), excess, -np.inf)))
            if excess[k] > 1e-12:
                lim = limit_of(i)
                out.append({"joint": name, "kind": kind, "worst": float(X[k, i]), "t": float(t[k]),
                            "limit": [_finite(v) for v in lim] if isinstance(lim, list) else _finite(lim)})
    return out


def _finite(x) -> float | None:
    x = float(x)
    return x if np.isfinite(x) else None


def dense_times(T: float, N: int, per_element: int = 32) -> np.ndarray:
    """Times for a dense limit check: ``per_element`` points per element plus the nodes; (N·per_element + 1,)."""
    return np.linspace(0.0, T, N * per_element + 1)
