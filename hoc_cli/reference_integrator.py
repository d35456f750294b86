"""The reference integrator of ``hoc simulate --integrator rk``: scipy's DOP853 on ẋ = (q̇, FD(q, q̇, u(t))).

Shapes: n joints, K time samples; q0, q̇0 (n,); the dense solution x(t) = (q, q̇) stacked, (2n, K).
"""
from __future__ import annotations

import time

import numpy as np

from hoc_cli.errors import NumericalError
from hoc_cli.simulation_results import ReferenceSimulation, SimulationStatus
from hoc_cli.system import System
from hoc_cli.torque import TorqueSource


def simulate_reference(
    system: System,
    q0: np.ndarray,
    dq0: np.ndarray,
    torque: TorqueSource,
    T: float,
    *,
    rtol: float = 1e-12,
    atol: float = 1e-12,
    method: str = "DOP853",
) -> ReferenceSimulation:
    """Integrate ẋ = (q̇, FD(q, q̇, u(t))) on [0, T] with scipy's ``solve_ivp`` (dense output).

    q0, dq0 (n,); T [s]. Raises NumericalError when the integrator fails.
    """
    from scipy.integrate import solve_ivp

    started = time.perf_counter()
    q0 = np.asarray(q0, dtype=float).reshape(-1)
    dq0 = np.asarray(dq0, dtype=float).reshape(-1)
    n = q0.size

    def rhs(t: float, x: np.ndarray) -> np.ndarray:
        u = torque(np.array([t]))
        ddq = system.forward_dynamics(x[None, :n], x[None, n:], u)[0]
        return np.concatenate([x[n:], ddq])

    with np.errstate(all="ignore"):  # a blow-up is reported below
        sol = solve_ivp(rhs, (0.0, float(T)), np.concatenate([q0, dq0]), method=method, rtol=rtol, atol=atol,
                        dense_output=True)
    if not sol.success or not np.all(np.isfinite(sol.y[:, -1])):
        raise NumericalError(f"reference integrator ({method}) failed at t = {sol.t[-1]:.6g} s: {sol.message}")
    return ReferenceSimulation(
        T=float(T), n=n, solution=sol.sol, status=SimulationStatus.SUCCESS, nfev=int(sol.nfev),
        steps=int(sol.t.size - 1),
        wall_time_s=time.perf_counter() - started, message=f"{method}: {sol.t.size - 1} steps, {sol.nfev} evaluations",
    )
