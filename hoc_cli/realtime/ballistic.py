"""A thrown ball's state from noisy timed position observations: a least-squares ballistic fit.

Symbols and units
-----------------
k observations at times t_i [s] of positions y_i (3,) [m], each coordinate with independent Gaussian
noise of standard deviation σ [m]; gravity a (3,) [m/s²] known; the unknowns θ = (p, v) (6,): the
ball's position [m] and velocity [m/s] at a reference time t_r [s]. Without drag

    y_i = p + v (t_i − t_r) + ½ a (t_i − t_r)² + noise,

linear in θ, so the least-squares estimate solves the normal equations (AᵀA/σ² + Σ₀⁻¹) θ = Aᵀ(y − b)/σ² +
Σ₀⁻¹θ₀, A the (3k, 6) design matrix, b the gravity term, with an optional Gaussian prior (θ₀, Σ₀) (the
nominal throw: a maximum a posteriori estimate, which is the same least squares with the prior as 6 more
rows). Its covariance is (AᵀA/σ² + Σ₀⁻¹)⁻¹ [m², m²/s²]; without a prior the estimate needs two
observations at different times. The axes decouple (the same 2×2 normal matrix per coordinate), which is
how it is solved here. Pure maths: no I/O.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, eq=False)
class BallEstimate:
    """The fitted state at time ``t`` [s]: ``position`` (3,) [m], ``velocity`` (3,) [m/s], ``acceleration``
    (3,) [m/s²] (the known gravity), ``covariance`` (6, 6) of (position, velocity), ``observations`` used.
    """

    t: float
    position: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    covariance: np.ndarray
    observations: int

    def at(self, t: float) -> "BallEstimate":
        """The same fit propagated to time ``t`` [s] (p + vτ + ½aτ², v + aτ, τ = t − self.t; covariance FΣFᵀ)."""
        tau = float(t) - self.t
        F = np.eye(6)
        F[:3, 3:] = tau * np.eye(3)
        return BallEstimate(float(t), self.position + self.velocity * tau + 0.5 * self.acceleration * tau**2,
                            self.velocity + self.acceleration * tau, self.acceleration, F @ self.covariance @ F.T,
                            self.observations)


class BallisticFit:
    """The least-squares fit of a ball's position and velocity (module docstring), observations added one by one.

    gravity : (3,) [m/s²]; noise : σ [m] of each coordinate of an observation (> 0);
    prior : optional (θ₀ (6,) position and velocity at ``t_ref``, standard deviations (6,) or (2,) for
    position and velocity); t_ref : the reference time [s] of θ.
    The normal equations are accumulated (O(1) per observation), so ``estimate`` costs the same whatever k.
    """

    def __init__(self, gravity, noise: float, *, prior: tuple | None = None, t_ref: float = 0.0) -> None:
        self.a = np.asarray(gravity, float).reshape(3)
        if not (np.isfinite(noise) and noise > 0):
            raise ValueError(f"the observation noise must be a standard deviation > 0 m, got {noise!r}")
        self.w = 1.0 / noise**2
        self.t_ref = float(t_ref)
        self.M = np.zeros((2, 2))  # Σ w [1, τ; τ, τ²]: the normal matrix of each coordinate
        self.r = np.zeros((2, 3))  # Σ w [1; τ] (y − ½aτ²)ᵀ
        self.M0 = np.zeros((2, 2, 3))  # the prior's information per coordinate (diagonal prior)
        self.r0 = np.zeros((2, 3))
        self.count = 0
        if prior is not None:
            theta0, sd = prior
            theta0 = np.asarray(theta0, float).reshape(6)
            sd = np.asarray(sd, float).reshape(-1)
            sd = np.repeat(sd, 3) if sd.size == 2 else sd.reshape(6)
            if not np.all(sd > 0):
                raise ValueError(f"the prior's standard deviations must be > 0, got {sd!r}")
            info = 1.0 / sd**2
            self.M0[0, 0], self.M0[1, 1] = info[:3], info[3:]
            self.r0[0], self.r0[1] = info[:3] * theta0[:3], info[3:] * theta0[3:]

    def add(self, t: float, y) -> None:
        """One observation: time t [s], position y (3,) [m]."""
        tau = float(t) - self.t_ref
        y = np.asarray(y, float).reshape(3) - 0.5 * self.a * tau**2
        self.M += self.w * np.array([[1.0, tau], [tau, tau * tau]])
        self.r += self.w * np.outer([1.0, tau], y)
        self.count += 1

    def add_many(self, t, Y) -> None:
        """Observations at times t (k,) [s] with positions Y (k, 3) [m]."""
        for ti, yi in zip(np.asarray(t, float).reshape(-1), np.asarray(Y, float).reshape(-1, 3)):
            self.add(ti, yi)

    @property
    def ready(self) -> bool:
        """Whether the fit is determined: a prior, or two observations at different times."""
        return bool(np.any(self.M0)) or (self.count >= 2 and np.linalg.det(self.M) > 1e-12 * self.M[0, 0] ** 2)

    def estimate(self, t: float | None = None) -> BallEstimate:
        """The fit at time t [s] (default ``t_ref``); ``ValueError`` when it is not ``ready``."""
        if not self.ready:
            raise ValueError("the ballistic fit needs two observations at different times (or a prior)")
        theta = np.zeros((2, 3))
        cov = np.zeros((6, 6))
        for c in range(3):
            Mc = self.M + self.M0[:, :, c]
            inv = np.linalg.inv(Mc)
            theta[:, c] = inv @ (self.r[:, c] + self.r0[:, c])
            cov[np.ix_([c, c + 3], [c, c + 3])] = inv
        fit = BallEstimate(self.t_ref, theta[0], theta[1], self.a.copy(), cov, self.count)
        return fit if t is None else fit.at(t)
