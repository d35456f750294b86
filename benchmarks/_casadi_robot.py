"""Symbolic (CasADi SX) rigid-body dynamics of a hoc ``RobotModel`` and collocation operators, for the
IPOPT baselines of ``bench_plan.py`` and ``ipopt_limits.py`` only (CasADi is a benchmark-only
dependency; the pip Pinocchio has no casadi module).

Symbols (SI units): n joints; q, dq, ddq (n,) joint positions, velocities, accelerations;
u (n,) joint torques; M(q) (n, n) mass matrix; spatial vectors (ω, v) / (n, f), 6 rows.

The tree data come from the frozen model (``hoc_cli.model.RobotModel``): ``tree_motion[i]`` is the
Plücker transform from the parent body frame to joint i's aligned frame (joint axis = local z),
``inertia[i]`` the spatial inertia of body i about its frame origin, ``gravity`` in the root frame.
The recursion is Featherstone's RNEA (*Rigid Body Dynamics Algorithms*, 2008, table 5.1):

    v_i = X_i v_λ + S_i q̇_i,   a_i = X_i a_λ + S_i q̈_i + v_i ×ₘ S_i q̇_i,   a_base = (0, −g)
    f_i = I_i a_i + v_i ×* I_i v_i,   u_i = S_iᵀ f_i,   f_λ += X_iᵀ f_i

with X_i = X_J(q_i) X_tree,i. The kinetic-energy form ``mass_quadratic`` gives wᵀ M(q) w =
Σ_i v_iᵀ I_i v_i (v_i the body velocities for joint velocities w) with one outward pass and no
matrix of n² entries.
"""
from __future__ import annotations

# isort: off
import _blas_threads  # noqa: F401  (before numpy: one BLAS thread, as hoc_cli sets)
# isort: on
import casadi as ca
import numpy as np
from numpy.polynomial import legendre as L

from hoc_cli import dynamics


def _const(A: np.ndarray) -> ca.DM:
    """Constant matrix with its exact zeros made structural, so SX drops their products."""
    return ca.sparsify(ca.DM(np.asarray(A, float)))


def _joint_transform(joint_type: str, q) -> ca.SX:
    """X_J(q) (6, 6): motion from the joint's aligned frame into the moved body frame."""
    if joint_type == "prismatic":
        X = ca.SX.eye(6)
        # pose translation r = q e_z: v_B = v − r × ω  →  rows (3:6, 0:3) = −[r]×
        X[3, 1] = q
        X[4, 0] = -q
        return X
    c, s = ca.cos(q), ca.sin(q)
    E_T = ca.SX.zeros(3, 3)  # Rz(q)ᵀ
    E_T[0, 0], E_T[0, 1], E_T[1, 0], E_T[1, 1], E_T[2, 2] = c, s, -s, c, 1
    X = ca.SX.zeros(6, 6)
    X[0:3, 0:3] = E_T
    X[3:6, 3:6] = E_T
    return X


def _crm(v) -> ca.SX:
    """Spatial motion cross-product matrix v ×ₘ (6, 6)."""
    w, vl = v[0:3], v[3:6]
    X = ca.SX.zeros(6, 6)
    X[0:3, 0:3] = ca.skew(w)
    X[3:6, 0:3] = ca.skew(vl)
    X[3:6, 3:6] = ca.skew(w)
    return X


class CasadiRobot:
    """SX expressions of inverse dynamics and wᵀ M(q) w for ``model`` (a ``RobotModel``)."""

    def __init__(self, model) -> None:
        self.model = model
        self.n = model.n
        self.Xtree = [_const(X) for X in model.tree_motion]
        self.I = [_const(I) for I in model.inertia]
        self.S = []
        for t in model.joint_types:
            S = np.zeros(6)
            S[5 if t == "prismatic" else 2] = 1.0
            self.S.append(_const(S))

    def _transforms(self, q):
        return [ca.mtimes(_joint_transform(t, q[i]), self.Xtree[i]) for i, t in enumerate(self.model.joint_types)]

    def inverse_dynamics(self, q, dq, ddq, gravity: bool = True) -> ca.SX:
        """u = M(q) q̈ + C(q, q̇) q̇ + g(q) (n, 1) by RNEA; q, dq, ddq SX (n, 1)."""
        m = self.model
        X = self._transforms(q)
        a_base = ca.SX(_const(np.r_[0.0, 0.0, 0.0, -m.gravity] if gravity else np.zeros(6)))
        v = [None] * self.n
        acc = [None] * self.n
        f = [None] * self.n
        for i in (int(k) for k in m.order):
            p = int(m.parent[i])
            vJ = self.S[i] * dq[i]
            if p < 0:
                v[i] = vJ
                a = ca.mtimes(X[i], a_base) + self.S[i] * ddq[i]
            else:
                v[i] = ca.mtimes(X[i], v[p]) + vJ
                a = ca.mtimes(X[i], acc[p]) + self.S[i] * ddq[i] + ca.mtimes(_crm(v[i]), vJ)
            acc[i] = a
            Iv = ca.mtimes(self.I[i], v[i])
            f[i] = ca.mtimes(self.I[i], a) - ca.mtimes(_crm(v[i]).T, Iv)  # v ×* = −(v ×ₘ)ᵀ
        u = [None] * self.n
        for i in reversed([int(k) for k in m.order]):
            u[i] = ca.dot(self.S[i], f[i])
            p = int(m.parent[i])
            if p >= 0:
                f[p] = f[p] + ca.mtimes(X[i].T, f[i])
        return ca.vertcat(*u)

    def mass_quadratic(self, q, w) -> ca.SX:
        """wᵀ M(q) w (scalar) = Σ_i v_iᵀ I_i v_i, v_i the body velocities for joint velocities w."""
        m = self.model
        X = self._transforms(q)
        v = [None] * self.n
        total = 0
        for i in (int(k) for k in m.order):
            p = int(m.parent[i])
            vJ = self.S[i] * w[i]
            v[i] = vJ if p < 0 else ca.mtimes(X[i], v[p]) + vJ
            total = total + ca.dot(v[i], ca.mtimes(self.I[i], v[i]))
        return total

    def functions(self) -> tuple[ca.Function, ca.Function, ca.Function]:
        """(ID(q, dq, ddq) -> u, M(q) -> M, quad(q, w) -> wᵀMw) as CasADi Functions of SX."""
        n = self.n
        q, dq, ddq, w = (ca.SX.sym(s, n) for s in ("q", "dq", "ddq", "w"))
        u = self.inverse_dynamics(q, dq, ddq)
        M = ca.jacobian(self.inverse_dynamics(q, dq, ddq, gravity=False), ddq)
        ID = ca.Function("ID", [q, dq, ddq], [u], ["q", "dq", "ddq"], ["u"])
        MM = ca.Function("M", [q], [ca.substitute(M, ca.vertcat(dq, ddq), ca.SX.zeros(2 * n))], ["q"], ["M"])
        quad = ca.Function("wMw", [q, w], [self.mass_quadratic(q, w)], ["q", "w"], ["wMw"])
        return ID, MM, quad


# --------------------------------------------------------------------------- collocation operators
def collocation(d: int, scheme: str = "radau") -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Collocation points on the unit interval and their operators, in numpy (not
    ``casadi.collocation_points``, whose coefficients lose accuracy from d ≈ 8).

    scheme: ``"radau"`` (flipped Legendre-Gauss-Radau, tau[-1] = 1, quadrature exact to degree 2d − 2)
    or ``"gauss"`` (Legendre-Gauss, interior points, exact to degree 2d − 1).

    Returns tau (d,); D (d, d+1): derivative at tau_j of the degree-d interpolant on the nodes
    {0, tau_1 … tau_d} (barycentric formula); B (d,): quadrature weights on tau; E (d+1,): the
    interpolant's value at 1 from its node values (the interval's end state; e_d for Radau).
    """
    if scheme == "radau":
        c = np.zeros(d + 1)
        c[d], c[d - 1] = 1.0, -1.0  # P_d − P_{d−1}: its roots on [−1, 1] include +1
    elif scheme == "gauss":
        c = np.zeros(d + 1)
        c[d] = 1.0  # P_d
    else:
        raise ValueError(f"unknown collocation scheme {scheme!r} (expected 'radau' or 'gauss')")
    x = np.sort(L.legroots(c))
    dc = L.legder(c)
    for _ in range(3):  # Newton polish of the roots (+1 is exact for Radau)
        inner = np.abs(x - 1.0) > 1e-12
        x[inner] -= L.legval(x[inner], c) / L.legval(x[inner], dc)
    if scheme == "radau":
        x[-1] = 1.0
    tau = 0.5 * (x + 1.0)
    nodes = np.r_[0.0, tau]
    diff = nodes[:, None] - nodes[None, :]
    np.fill_diagonal(diff, 1.0)
    lam = 1.0 / diff.prod(axis=1)
    D = (lam[None, :] / lam[:, None]) / diff
    np.fill_diagonal(D, 0.0)
    np.fill_diagonal(D, -D.sum(axis=1))
    V = np.stack([L.legval(x, np.eye(d)[k]) for k in range(d)])  # V[k, j] = P_k(x_j)
    B = np.linalg.solve(V, np.eye(d)[0] * 2.0) / 2.0  # ∫ P_k over [−1, 1] = 2 δ_k0, mapped to [0, 1]
    if scheme == "radau":
        E = np.eye(d + 1)[d]
    else:  # barycentric formula of the second kind at 1 (no node equals 1)
        r = lam / (1.0 - nodes)
        E = r / r.sum()
    return tau, D[1:], B, E


def radau(d: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(tau, D, B) of ``collocation(d, "radau")``."""
    return collocation(d, "radau")[:3]


def check_dynamics(model, samples: int = 50) -> float:
    """Largest relative difference of the CasADi ID, M and wᵀMw from hoc_cli.dynamics at random states;
    exits (SystemExit) above 1e-10."""
    ID, MM, quad = CasadiRobot(model).functions()
    rng = np.random.default_rng(7)
    n = model.n
    q, dq, ddq, w = (rng.uniform(-lim, lim, (samples, n)) for lim in (3.0, 3.0, 10.0, 1.0))
    u = dynamics.inverse_dynamics(model, q, dq, ddq)
    M = dynamics.mass_matrix(model, q)
    u_c = np.array(ID.map(samples)(q.T, dq.T, ddq.T)).T
    M_c = np.array(MM.map(samples)(q.T)).T.reshape(samples, n, n)
    wMw_c = np.array(quad.map(samples)(q.T, w.T)).ravel()
    wMw = np.einsum("ki,kij,kj->k", w, M, w)
    err = max(np.abs(u_c - u).max() / np.abs(u).max(), np.abs(M_c - M).max() / np.abs(M).max(),
              np.abs(wMw_c - wMw).max() / np.abs(wMw).max())
    if not err <= 1e-10:
        raise SystemExit(f"CasADi dynamics differ from hoc_cli.dynamics by {err:.1e} (relative); expected <= 1e-10")
    return err
