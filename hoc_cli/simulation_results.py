"""What a forward simulation returns: the Hermite integrator's trajectory, or a dense ODE solution.

Shapes: N elements, m coefficients per node and joint (2 cubic, 3 quintic), n joints, K time samples.
"""
from __future__ import annotations

import enum
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from hoc_cli.elements import HermiteMesh


class SimulationStatus(enum.Enum):
    """How a simulation ended. Failures raise ``NumericalError`` instead of returning."""

    SUCCESS = "success"


@dataclass(eq=False)
class HermiteSimulation:
    """Result of ``simulate_hermite``: the Hermite trajectory and Newton's work.

    coeffs (N+1, m, n): a, b(, c) at every node. ``points`` (m,) the collocation coordinates.
    ``newton_iterations`` is the total number of Newton steps (Jacobian factorisations) over all
    elements, ``max_newton_iterations`` the worst element, ``evaluations`` the number of batched
    ``id_derivatives`` calls (m samples each), ``wall_time_s`` the march alone.
    ``subdivided`` lists (element, sub-elements) for each element whose Newton iteration failed and
    that was solved as 2, 4, … equal sub-elements instead (the node values at its ends then come
    from the sub-elements; between them the trajectory is the element's Hermite interpolant).
    """

    mesh: HermiteMesh
    coeffs: np.ndarray
    points: np.ndarray
    status: SimulationStatus
    newton_iterations: int
    max_newton_iterations: int
    evaluations: int
    wall_time_s: float
    message: str
    subdivided: tuple[tuple[int, int], ...] = ()

    def state(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """q_h(t), q̇_h(t) at times t (K,) [s]; each (K, n)."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        return self.mesh.evaluate(self.coeffs, t, 0), self.mesh.evaluate(self.coeffs, t, 1)

    def final_state(self) -> tuple[np.ndarray, np.ndarray]:
        """(q(T), q̇(T)), each (n,): the last node's a and b."""
        return self.coeffs[-1, 0].copy(), self.coeffs[-1, 1].copy()


@dataclass(eq=False)
class ReferenceSimulation:
    """Result of ``simulate_reference``: a dense ODE solution of the forward dynamics.

    ``solution(t)`` gives x = (q, q̇) stacked, shape (2n, K). ``nfev`` forward-dynamics calls,
    ``steps`` accepted steps.
    """

    T: float
    n: int
    solution: Callable[[np.ndarray], np.ndarray] = field(repr=False)
    status: SimulationStatus
    nfev: int
    steps: int
    wall_time_s: float
    message: str

    def state(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """q(t), q̇(t) at times t (K,) in [0, T]; each (K, n)."""
        x = self.solution(np.atleast_1d(np.asarray(t, dtype=float)))
        return x[: self.n].T.copy(), x[self.n :].T.copy()

    def final_state(self) -> tuple[np.ndarray, np.ndarray]:
        q, dq = self.state(np.array([self.T]))
        return q[0], dq[0]
