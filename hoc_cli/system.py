"""The small interface between the planner/simulator and a mechanical system.

A ``System`` maps joint trajectories sampled at K instants to torques and gives the
derivatives the planner and simulator need. ``RobotSystem`` wraps a URDF model
(recursive Newton-Euler, ``hoc_cli.dynamics``); ``LinearOscillator`` is the paper's
validation system q̈ + ω² q = u, so both run through the same code.

Shapes: q, dq, ddq, u, lam, v (K, n); matrices (K, n, n). Units: SI.
"""
from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np


@runtime_checkable
class System(Protocol):
    """What the planner and simulator need from a mechanical system with n joints."""

    joint_names: tuple[str, ...]

    @property
    def n(self) -> int: ...

    def inverse_dynamics(self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> np.ndarray:
        """U = M(q) q̈ + C(q, q̇) q̇ + g(q), (K, n)."""

    def mass_matrix(self, q: np.ndarray) -> np.ndarray:
        """M(q), (K, n, n), symmetric positive definite."""

    def id_and_mass(self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(U, M(q)): ``inverse_dynamics`` and ``mass_matrix`` at once, (K, n) and (K, n, n)."""

    def forward_dynamics(self, q: np.ndarray, dq: np.ndarray, u: np.ndarray) -> np.ndarray:
        """q̈ = M⁻¹ (u − h(q, q̇)), (K, n)."""

    def id_derivatives(self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> tuple[np.ndarray, ...]:
        """(u, ∂u/∂q, ∂u/∂q̇, M): (K, n), (K, n, n) ×3 with [k, i, j] = ∂u_i/∂x_j."""

    def id_vjp(self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray, lam: np.ndarray) -> tuple[np.ndarray, ...]:
        """(u, λᵀ∂u/∂q, λᵀ∂u/∂q̇, λᵀ∂u/∂q̈ = M λ), each (K, n)."""

    def mass_quadratic_grad(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """∂(vᵀ M(q) v)/∂q with v held fixed, (K, n)."""

    def covariant_gradient_terms(self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> tuple[np.ndarray, ...]:
        """(u, M, gq, gdq, w) for L = ½ uᵀM⁻¹u: w = M⁻¹u, gq = ∂L/∂q, gdq = ∂L/∂q̇ (∂L/∂q̈ = u).

        Raises numpy.linalg.LinAlgError when M is not positive definite.
        """


class LinearOscillator:
    """q̈ + ω² q = u for n independent unit masses (the paper's validation system with ω = 1)."""

    def __init__(self, n: int = 1, omega: float = 1.0) -> None:
        self.joint_names = tuple(f"q{i}" for i in range(n))
        self.omega2 = float(omega) ** 2
        self._n = n

    @property
    def n(self) -> int:
        return self._n

    def inverse_dynamics(self, q, dq, ddq):
        return np.asarray(ddq, float) + self.omega2 * np.asarray(q, float)

    def mass_matrix(self, q):
        K = np.shape(q)[0]
        return np.broadcast_to(np.eye(self.n), (K, self.n, self.n)).copy()

    def id_and_mass(self, q, dq, ddq):
        return self.inverse_dynamics(q, dq, ddq), self.mass_matrix(q)

    def forward_dynamics(self, q, dq, u):
        return np.asarray(u, float) - self.omega2 * np.asarray(q, float)

    def id_derivatives(self, q, dq, ddq):
        K = np.shape(q)[0]
        eye = np.broadcast_to(np.eye(self.n), (K, self.n, self.n))
        return self.inverse_dynamics(q, dq, ddq), self.omega2 * eye.copy(), np.zeros((K, self.n, self.n)), eye.copy()

    def id_vjp(self, q, dq, ddq, lam):
        lam = np.asarray(lam, float)
        return self.inverse_dynamics(q, dq, ddq), self.omega2 * lam, np.zeros_like(lam), lam.copy()

    def mass_quadratic_grad(self, q, v):
        return np.zeros_like(np.asarray(q, float))

    def covariant_gradient_terms(self, q, dq, ddq):
        u = self.inverse_dynamics(q, dq, ddq)
        return u, self.mass_matrix(q), self.omega2 * u, np.zeros_like(u), u.copy()


class RobotSystem:
    """A URDF robot (``hoc_cli.model.RobotModel``) seen through the ``System`` interface."""

    def __init__(self, model) -> None:
        self.model = model
        self.joint_names = tuple(model.joint_names)

    @property
    def n(self) -> int:
        return len(self.joint_names)

    def inverse_dynamics(self, q, dq, ddq):
        from hoc_cli import dynamics

        return dynamics.inverse_dynamics(self.model, q, dq, ddq)

    def mass_matrix(self, q):
        from hoc_cli import dynamics

        return dynamics.mass_matrix(self.model, q)

    def id_and_mass(self, q, dq, ddq):
        from hoc_cli import dynamics

        return dynamics.id_and_mass(self.model, q, dq, ddq)

    def forward_dynamics(self, q, dq, u):
        from hoc_cli import dynamics

        return dynamics.forward_dynamics(self.model, q, dq, u)

    def id_derivatives(self, q, dq, ddq):
        from hoc_cli import dynamics

        return dynamics.id_derivatives(self.model, q, dq, ddq)

    def id_vjp(self, q, dq, ddq, lam):
        from hoc_cli import dynamics

        return dynamics.id_vjp(self.model, q, dq, ddq, lam)

    def inverse_dynamics_kept(self, q, dq, ddq):
        """(``inverse_dynamics``, what ``id_vjp_kept`` takes to reuse its Newton-Euler pass)."""
        from hoc_cli import dynamics

        return dynamics.inverse_dynamics_kept(self.model, q, dq, ddq)

    def id_vjp_kept(self, kept, lam):
        """``id_vjp`` at the inputs of an ``inverse_dynamics_kept`` call (its ``kept``): the same numbers."""
        from hoc_cli import dynamics

        return dynamics.id_vjp_kept(self.model, kept, lam)

    def mass_quadratic_grad(self, q, v):
        from hoc_cli import dynamics

        return dynamics.mass_quadratic_grad(self.model, q, v)

    def covariant_gradient_terms(self, q, dq, ddq):
        from hoc_cli import dynamics

        u, M, gq, gdq, w = dynamics.covariant_gradient_terms(self.model, q, dq, ddq, return_w=True)
        return u, M, gq, gdq, w
