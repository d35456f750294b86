"""CasADi + IPOPT direct collocation of hoc's goal problems (free final time, a link-position goal, a
moving-target catch): the independent reference of ``bench_goals.py`` and ``tests/test_goals_ipopt.py``
(benchmark-only; casadi is in the ``bench`` extra).

Problem (SI units; n joints; q, q̇, q̈, u (n,) in rad, rad/s, rad/s², N·m). From x0 = (q0, q̇0) minimise

    J + weight·T,   J = ∫₀ᵀ ½ uᵀ M(q)⁻¹ u dt,   u = M(q) q̈ + C(q, q̇) q̇ + g(q)   (hoc's own model),

with T fixed or a decision variable in [T_min, T_max], and at T one of: a joint state (q1, q̇1); a link
origin at a fixed point p̄ with q̇(T) = 0 (q(T) free); a link origin at a moving target
p̄(T) = p0 + v0 T + ½ a T², optionally with the link origin's linear velocity J_v(q) q̇ = v0 + a T
(q̇(T) free). Box limits as in ``ipopt_limits.py`` (position, velocity at every node, effort at every
collocation point; acceleration none unless given).

Transcription: ``ipopt_limits.py``'s (K intervals of degree d, flipped Radau by default, variables
S_k, X_kj, A_kj, W_kj), with the interval width h = T/K a function of the variable T: the collocation
rows are written as Σ_r D_jr q_r = h q̇_j (no division by T). The link's forward kinematics is the
product of hoc's constant joint-frame poses ``tree_transform`` and the joint rotations (about z) or
translations (along z), then the link's ``link_offset``: ``link_position``, checked against
``hoc_cli.dynamics.link_poses`` by ``check_kinematics``.

IPOPT: exact Hessian, MUMPS, ``bound_relax_factor`` 0, tol 1e-10. ``solve(warm=previous)`` starts
# isort: off
import _blas_threads  # noqa: F401  (before numpy: one BLAS thread, as hoc_cli sets)
# isort: on
from a previous solution's primal and dual values with IPOPT's ``warm_start_init_point``, bound pushes 1e-6, mu_init 1e-9.
"""
from __future__ import annotations

import sys
import time
from dataclasses import dataclass
from pathlib import Path

import casadi as ca
import numpy as np

from hoc_cli import dynamics

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _casadi_robot import CasadiRobot, collocation  # noqa: E402
from ipopt_limits import Limits, quintic_guess  # noqa: E402


# --------------------------------------------------------------------------- forward kinematics
def _joint_pose(joint_type: str, q) -> ca.SX:
    """(4, 4) pose of the moved body in the joint's aligned frame: rotation about z or translation along z."""
    P = ca.SX.eye(4)
    if joint_type == "prismatic":
        P[2, 3] = q
        return P
    c, s = ca.cos(q), ca.sin(q)
    P[0, 0], P[0, 1], P[1, 0], P[1, 1] = c, -s, s, c
    return P


def link_position(model, link: str) -> ca.Function:
    """p(q) -> (3,) the origin of URDF link ``link`` in the root frame [m], an SX Function."""
    k = list(model.link_names).index(link)
    b, offset = int(model.link_body[k]), np.asarray(model.link_offset[k], float)
    q = ca.SX.sym("q", model.n)
    chain = []
    while b >= 0:
        chain.append(b)
        b = int(model.parent[b])
    P = ca.SX.eye(4)
    for i in reversed(chain):
        P = ca.mtimes(ca.mtimes(P, ca.DM(model.tree_transform[i])), _joint_pose(model.joint_types[i], q[i]))
    p = ca.mtimes(P, ca.DM(offset))[0:3, 3]
    return ca.Function("p_" + link, [q], [p], ["q"], ["p"])


def check_kinematics(model, link: str, samples: int = 50) -> float:
    """Largest |p_casadi − p_hoc| [m] (and of the velocity J_v q̇ against ``frame_jacobian``) at random q;
    exits (SystemExit) above 1e-12."""
    p = link_position(model, link)
    rng = np.random.default_rng(3)
    q, dq = rng.uniform(-3, 3, (samples, model.n)), rng.uniform(-2, 2, (samples, model.n))
    ref = dynamics.link_poses(model, q)[link][:, :3, 3]
    got = np.array(p.map(samples)(q.T)).T
    qs, dqs = ca.SX.sym("q", model.n), ca.SX.sym("dq", model.n)
    vel = ca.Function("v", [qs, dqs], [ca.mtimes(ca.jacobian(p(qs), qs), dqs)])
    v_ref = np.einsum("kij,kj->ki", dynamics.frame_jacobian(model, q, link)[:, :3], dq)
    v_got = np.array(vel.map(samples)(q.T, dq.T)).T
    err = max(np.abs(got - ref).max(), np.abs(v_got - v_ref).max())
    if not err <= 1e-12:
        raise SystemExit(f"CasADi kinematics of {link} differ from hoc_cli.dynamics by {err:.1e} m; expected <= 1e-12")
    return err


# --------------------------------------------------------------------------- the problem
@dataclass(frozen=True)
class Goal:
    """What holds at T. Joint goal: q1, dq1 (n,). Link goal: link, position p0 [m] (and velocity v0,
    acceleration a [m/s, m/s²] of a moving target; match_velocity); q̇(T) = 0 unless match_velocity."""

    q1: np.ndarray | None = None
    dq1: np.ndarray | None = None
    link: str | None = None
    position: np.ndarray | None = None
    velocity: np.ndarray | None = None
    acceleration: np.ndarray | None = None
    match_velocity: bool = False

    def target(self, T, p0=None):
        """(p̄(T), v̄(T)) of the target, p0 (default ``position``) its position at t = 0."""
        v0 = np.zeros(3) if self.velocity is None else np.asarray(self.velocity, float)
        a = np.zeros(3) if self.acceleration is None else np.asarray(self.acceleration, float)
        p0 = self.position if p0 is None else p0
        return p0 + v0 * T + 0.5 * a * T**2, v0 + a * T


@dataclass
class Solution:
    """One IPOPT solve: J (the integral cost), T [s], objective J + weight·T, final q (n,), q̇ (n,),
    wall [s] (the solver call), iterations, status, the raw primal x and duals lam_x, lam_g."""

    J: float
    T: float
    objective: float
    q1: np.ndarray
    dq1: np.ndarray
    wall: float
    iterations: int
    status: str
    success: bool
    x: np.ndarray
    lam_x: np.ndarray
    lam_g: np.ndarray


class GoalCollocation:
    """The NLP for K intervals of degree d with T fixed (``T`` a float) or free (``T`` = (min, max)).

    model: hoc ``RobotModel``; q0, dq0 (n,); goal: ``Goal``; weight: the price of time (free T);
    limits: ``ipopt_limits.Limits`` (none by default).
    """

    def __init__(self, model, q0, dq0, goal: Goal, T, K: int, d: int = 3, *, weight: float = 0.0,
                 limits: Limits | None = None, tol: float = 1e-10, ipopt: dict | None = None) -> None:
        n = model.n
        self.model, self.K, self.d, self.n, self.goal, self.weight = model, K, d, n, goal, weight
        self.free = not np.isscalar(T)
        self.T_range = (float(T[0]), float(T[1])) if self.free else (float(T), float(T))
        self.q0, self.dq0 = np.asarray(q0, float), np.asarray(dq0, float)
        lim = limits if limits is not None else Limits.none(n)
        tau, D, B, E = collocation(d, "radau")
        self.tau = tau
        ID, _, quad = CasadiRobot(model).functions()
        eff_rows = [int(i) for i in np.flatnonzero(np.isfinite(lim.effort))]

        # one interval, its width h an input
        s0, s1 = ca.SX.sym("s0", 2 * n), ca.SX.sym("s1", 2 * n)
        Xc, A, W, h = ca.SX.sym("X", 2 * n, d), ca.SX.sym("A", n, d), ca.SX.sym("W", n, d), ca.SX.sym("h")
        Xall = ca.horzcat(s0, Xc)
        dX = ca.mtimes(Xall, ca.DM(D.T))
        eq = [ca.vec(dX[:n, :] - h * Xc[n:, :]), ca.vec(dX[n:, :] - h * A)]
        ineq, J = [], 0
        for j in range(d):
            q, dq = Xc[:n, j], Xc[n:, j]
            eq.append(ID(q, dq, A[:, j] - W[:, j]))
            J += 0.5 * h * B[j] * quad(q, W[:, j])
            if eff_rows:
                ineq.append(ID(q, dq, A[:, j])[eff_rows])
        eq.append(s1 - ca.mtimes(Xall, ca.DM(E)))
        interval = ca.Function("interval", [s0, Xc, A, W, s1, h],
                               [ca.vertcat(*eq), ca.vertcat(*ineq) if ineq else ca.SX(0, 1), J])

        # the horizon
        S = ca.MX.sym("S", 2 * n, K + 1)
        Xs, As, Ws = ca.MX.sym("X", 2 * n, K * d), ca.MX.sym("A", n, K * d), ca.MX.sym("W", n, K * d)
        Tv, P0 = ca.MX.sym("T"), ca.MX.sym("p0", 3)  # p0: the link target's position at t = 0 (a parameter)
        self.p0 = np.zeros(3) if goal.position is None else np.asarray(goal.position, float)
        Geq, Gin, C = interval.map(K)(S[:, :K], Xs, As, Ws, S[:, 1:], ca.repmat(Tv / K, 1, K))
        self.x = ca.vertcat(ca.vec(S), ca.vec(Xs), ca.vec(As), ca.vec(Ws), Tv)
        qT, dqT = S[:n, K], S[n:, K]
        goal_rows = []
        fixed_end = goal.link is None
        if goal.link is not None:
            p = link_position(model, goal.link)
            pbar, vbar = goal.target(Tv, P0)
            goal_rows.append(p(qT) - pbar)
            if goal.match_velocity:
                qs = ca.SX.sym("q", n)
                Jv = ca.Function("Jv", [qs], [ca.jacobian(p(qs), qs)])
                goal_rows.append(ca.mtimes(Jv(qT), dqT) - vbar)
        goal_g = ca.vertcat(*goal_rows) if goal_rows else ca.MX(0, 1)
        self.J_expr = ca.sum2(C)
        g = ca.vertcat(ca.vec(Geq), goal_g, ca.vec(Gin))
        n_eq = int(Geq.numel()) + int(goal_g.numel())
        self.nlp = {"x": self.x, "p": P0, "f": self.J_expr + weight * Tv, "g": g}
        self.Jf = ca.Function("J", [self.x], [self.J_expr])
        self.sizes = dict(S=2 * n * (K + 1), X=2 * n * K * d, A=n * K * d, W=n * K * d)

        # bounds
        state_lo, state_hi = np.r_[lim.lower, -lim.velocity], np.r_[lim.upper, lim.velocity]
        lbS, ubS = np.tile(state_lo, K + 1), np.tile(state_hi, K + 1)
        lbS[:2 * n] = ubS[:2 * n] = np.r_[self.q0, self.dq0]
        if fixed_end:
            lbS[-2 * n:] = ubS[-2 * n:] = np.r_[goal.q1, goal.dq1]
        elif not goal.match_velocity:
            lbS[-n:] = ubS[-n:] = 0.0  # dq: zero
        inf = np.full(n * K * d, np.inf)
        self.lbx = np.r_[lbS, np.tile(state_lo, K * d), np.tile(-lim.acceleration, K * d), -inf, self.T_range[0]]
        self.ubx = np.r_[ubS, np.tile(state_hi, K * d), np.tile(lim.acceleration, K * d), inf, self.T_range[1]]
        e = lim.effort[eff_rows]
        self.lbg = np.r_[np.zeros(n_eq), np.tile(-e, K * d)]
        self.ubg = np.r_[np.zeros(n_eq), np.tile(e, K * d)]
        self.opts = {"expand": True, "print_time": False,
                     "ipopt": {"tol": tol, "constr_viol_tol": tol, "linear_solver": "mumps", "print_level": 0,
                               "hessian_approximation": "exact", "max_iter": 3000, "sb": "yes",
                               "bound_relax_factor": 0.0, **(ipopt or {})}}
        self.solver = ca.nlpsol("ipopt", "ipopt", self.nlp, self.opts)
        self.warm_solver = None

    def guess(self, T: float, q1, dq1=None) -> np.ndarray:
        """The quintic from x0 to (q1, dq1) (rest by default) in T, W consistent with it."""
        n, K = self.n, self.K
        dq1 = np.zeros(n) if dq1 is None else dq1
        f = quintic_guess(T, self.q0, self.dq0, np.asarray(q1, float), np.asarray(dq1, float))
        h = T / K
        tn = np.arange(K + 1) * h
        tc = (np.arange(K)[:, None] + self.tau[None, :]).ravel() * h
        q, dq, ddq = (f(tc, k) for k in range(3))
        w = ddq - dynamics.forward_dynamics(self.model, q, dq, np.zeros_like(q))
        return np.concatenate([np.hstack([f(tn, 0), f(tn, 1)]).ravel(), np.hstack([q, dq]).ravel(), ddq.ravel(),
                               w.ravel(), [T]])

    def _result(self, solver, sol, wall) -> Solution:
        st = solver.stats()
        x = np.array(sol["x"]).ravel()
        n, K = self.n, self.K
        S = x[:self.sizes["S"]].reshape(K + 1, 2 * n)
        J = float(self.Jf(x))
        return Solution(J=J, T=float(x[-1]), objective=float(sol["f"]), q1=S[K, :n].copy(), dq1=S[K, n:].copy(),
                        wall=wall, iterations=int(st["iter_count"]), status=st["return_status"],
                        success=bool(st["success"]), x=x, lam_x=np.array(sol["lam_x"]).ravel(),
                        lam_g=np.array(sol["lam_g"]).ravel())

    def solve(self, x0: np.ndarray | None = None, *, warm: Solution | None = None, p0=None) -> Solution:
        """Cold from x0 (the primal guess), or warm from ``warm`` (primal and duals, IPOPT's
        warm_start_init_point, bound pushes 1e-6, mu_init 1e-9); p0 (3,) the link target's position at t = 0
        (default the goal's); the wall time of the solver call alone."""
        if warm is None:
            solver, args = self.solver, {"x0": x0}
        else:
            if self.warm_solver is None:
                opts = dict(self.opts)
                # the pushes and mu_init that took fewest iterations on the catch (mu_init 1e-9, 1e-7, 1e-5 ×
                # pushes 1e-9, 1e-6: 7 iterations here against 6 to 13)
                push = 1e-6
                opts["ipopt"] = {**self.opts["ipopt"], "warm_start_init_point": "yes",
                                 "warm_start_bound_push": push, "warm_start_bound_frac": push,
                                 "warm_start_slack_bound_push": push, "warm_start_slack_bound_frac": push,
                                 "warm_start_mult_bound_push": push, "mu_init": 1e-9}
                self.warm_solver = ca.nlpsol("ipopt_warm", "ipopt", self.nlp, opts)
            solver, args = self.warm_solver, {"x0": warm.x, "lam_x0": warm.lam_x, "lam_g0": warm.lam_g}
        start = time.perf_counter()
        p = self.p0 if p0 is None else np.asarray(p0, float)
        sol = solver(p=p, lbx=self.lbx, ubx=self.ubx, lbg=self.lbg, ubg=self.ubg, **args)
        return self._result(solver, sol, time.perf_counter() - start)
