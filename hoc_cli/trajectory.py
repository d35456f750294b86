"""One trajectory type shared by the planner, the simulator and the writers.

Symbols: K samples, n joints. Times in s, q in rad (m for prismatic joints), u in N·m (N).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hoc_cli.elements import HermiteMesh


def sample_times(T: float, rate: float) -> np.ndarray:
    """Output sample times from 0 to T inclusive at ``rate`` samples per second; the last is exactly T.

    Returns shape (K,) with K = floor(T·rate) + 1 (+1 more when T·rate is not an integer).
    """
    if not (T > 0 and rate > 0):
        raise ValueError(f"T and rate must be positive, got T={T}, rate={rate}")
    k = int(np.floor(T * rate + 1e-9))
    t = np.arange(k + 1, dtype=float) / rate
    if T - t[-1] > 1e-9 / rate:
        t = np.append(t, T)
    else:
        t[-1] = T
    return t


@dataclass(eq=False)
class Trajectory:
    """Sampled motion: t (K,), q, dq, ddq, u (K, n) in task joint order.

    ``mesh`` and ``coeffs`` (N+1, m, n) are the exact Hermite representation when the
    trajectory came from hoc's elements (plan or Hermite simulation), else None.
    """

    joints: tuple[str, ...]
    t: np.ndarray
    q: np.ndarray
    dq: np.ndarray
    ddq: np.ndarray
    u: np.ndarray
    mesh: HermiteMesh | None = None
    coeffs: np.ndarray | None = None

    @property
    def n(self) -> int:
        return len(self.joints)

    @property
    def K(self) -> int:
        return int(self.t.shape[0])
