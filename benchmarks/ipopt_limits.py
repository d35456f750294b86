"""CasADi + IPOPT direct collocation of hoc's optimal-control problem WITH joint limits: the
independent reference for hoc's limit enforcement (benchmark-only; casadi is in the ``bench`` extra).

Problem (SI units; n joints; q, q̇, q̈, u (n,) in rad, rad/s, rad/s², N·m — m, m/s, m/s², N for
prismatic joints). From x0 = (q0, q̇0) to x1 = (q1, q̇1), both fixed, in the fixed time T, minimise

    J = ∫₀ᵀ ½ uᵀ M(q)⁻¹ u dt   (cost "covariant")   or   J = ∫₀ᵀ ½ uᵀ u dt   (cost "torque"),
    u = M(q) q̈ + C(q, q̇) q̇ + g(q)   (inverse dynamics, hoc's own model),

subject to box limits per joint: lower ≤ q ≤ upper, |q̇| ≤ v_max, |q̈| ≤ a_max, |u| ≤ u_max.
Defaults come from the URDF ``<limit>`` through hoc's ``RobotModel`` (``Limits.from_model``):
position (revolute, prismatic; none for continuous joints or when lower ≥ upper), velocity and
effort (none when missing, zero or negative); acceleration has no URDF value (none unless given).

Transcription: K intervals of width h = T/K, collocation of degree d per interval (``scheme``
"radau": flipped Legendre-Gauss-Radau; "gauss": Legendre-Gauss), coefficients computed in numpy
(``_casadi_robot.collocation``). Variables: the interval start states S_k = (q, q̇) (k = 0 … K;
S_0 = x0 and S_K = x1 fixed by bounds), the collocation states X_kj, accelerations A_kj and, for the
covariant cost, W_kj. Rows per interval:

    (1/h) Σ_r D_jr q_r = q̇_j,   (1/h) Σ_r D_jr q̇_r = A_j,        (nodes r: S_k, X_k1 … X_kd)
    RNEA(q_j, q̇_j, A_j − W_j) = 0  ⇔  M(q_j) W_j = u_j          (covariant only)
    S_{k+1} = Σ_r E_r x_r                                         (continuity; E = e_d for Radau)
    −u_max ≤ RNEA(q_j, q̇_j, A_j) ≤ u_max                          (effort; joints with a limit only)

    J_h = Σ_k Σ_j h B_j ½ W_jᵀ M(q_j) W_j   or   Σ_k Σ_j h B_j ½ |RNEA(q_j, q̇_j, A_j)|².

Position and velocity bounds hold at every S_k and X_kj, acceleration bounds at every A_kj, effort
bounds at every collocation point: the limits are imposed at the d + 1 nodes of each interval, not
between them; so compare converged values (J as K grows), not single meshes, with hoc.

IPOPT: exact Hessian (CasADi AD of SX, ``expand``), MUMPS, ``bound_relax_factor`` 0 (the bounds hold
exactly at the returned point, no 1e-8 relaxation), tol and constr_viol_tol ``tol`` (1e-10).
Start: the quintic per joint matching x0, x1 and q̈ = 0 at both ends (the minimum-jerk move when
rest to rest); W consistent with it (W = q̈ + M⁻¹h). IPOPT pushes the start inside the bounds.

Time to accuracy: an iteration callback records, at each IPOPT iteration, the wall time since the
solver call, the iterate's objective and its violation (max over the equality rows' |residual|, and
the excess over every bound, both absolute). ``t_to_tol`` is the first recorded time at which
|J_it − J_final| ≤ rtol·|J_final| (rtol 1e-6) and violation ≤ feas_tol (1e-8); ``t_to_tol_stay``
the first time after which that held at every later iteration. The callback's own cost (copying
the iterate into numpy) is inside the timings; it is small against an IPOPT iteration.
"""
from __future__ import annotations

# isort: off
import _blas_threads  # noqa: F401  (before numpy: one BLAS thread, as hoc_cli sets)
# isort: on
import sys
import sysconfig
import time
from dataclasses import dataclass, field
from pathlib import Path

import casadi as ca
import numpy as np

from hoc_cli import dynamics
from hoc_cli.io.task import Task, load_yaml, parse_task, resolve
from hoc_cli.model import load_robot

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _casadi_robot import CasadiRobot, collocation  # noqa: E402

KINDS = ("position", "velocity", "acceleration", "effort")


# --------------------------------------------------------------------------- limits
@dataclass(frozen=True, eq=False)
class Limits:
    """Box limits per joint, arrays (n,) in the model's joint order; ±inf where there is none.

    lower, upper: rad (m); velocity: rad/s (m/s); acceleration: rad/s² (m/s²); effort: N·m (N).
    """

    lower: np.ndarray
    upper: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    effort: np.ndarray

    @classmethod
    def none(cls, n: int) -> "Limits":
        inf = np.full(n, np.inf)
        return cls(-inf, inf.copy(), inf.copy(), inf.copy(), inf.copy())

    @classmethod
    def from_model(cls, model, *, acceleration=None, scale: dict | None = None,
                   kinds: tuple[str, ...] = KINDS) -> "Limits":
        """The URDF limits of ``model`` (a hoc ``RobotModel``), a missing, zero or negative velocity or
        effort meaning none, lower ≥ upper meaning no position limit; ``acceleration`` a scalar or (n,)
        (none by default); ``scale`` {kind: s} with 0 < s ≤ 1 multiplies velocity, acceleration, effort;
        only the kinds in ``kinds`` are kept."""
        n = model.n

        def positive(a) -> np.ndarray:
            a = np.broadcast_to(np.asarray(np.inf if a is None else a, float), (n,)).copy()
            a[~(a > 0)] = np.inf
            return a

        lower, upper = np.asarray(model.lower, float).copy(), np.asarray(model.upper, float).copy()
        none = ~(lower < upper)
        lower[none], upper[none] = -np.inf, np.inf
        vel, acc, eff = positive(model.velocity_limit), positive(acceleration), positive(model.effort_limit)
        for kind, s in (scale or {}).items():
            if kind not in ("velocity", "acceleration", "effort") or not 0 < s <= 1:
                raise ValueError(f"scale.{kind}: expected velocity/acceleration/effort with 0 < s <= 1, got {s!r}")
            {"velocity": vel, "acceleration": acc, "effort": eff}[kind][:] *= s
        if "position" not in kinds:
            lower[:], upper[:] = -np.inf, np.inf
        for kind, a in (("velocity", vel), ("acceleration", acc), ("effort", eff)):
            if kind not in kinds:
                a[:] = np.inf
        return cls(lower, upper, vel, acc, eff)

    def bounds(self, kind: str) -> tuple[np.ndarray, np.ndarray]:
        """(lo, hi) (n,) of one kind."""
        if kind == "position":
            return self.lower, self.upper
        a = getattr(self, kind)
        return -a, a


# --------------------------------------------------------------------------- result
@dataclass(eq=False)
class Result:
    """One IPOPT solve. Samples at the collocation instants t (K d,): q, dq, ddq, u (K d, n); at the
    interval boundaries t_nodes (K+1,): q_nodes, dq_nodes. Times in s."""

    J: float
    success: bool
    status: str
    iterations: int
    wall: float              # the solver call [s]
    setup: float             # symbolic build + nlpsol construction [s]
    t_to_tol: float          # first time J within rtol of J_final and feasible [s] (nan if never)
    t_to_tol_stay: float     # first time after which that held at every iteration [s]
    it_to_tol: int
    max_violation: float     # final: max equality residual and bound excess (absolute)
    K: int
    d: int
    scheme: str
    cost: str
    t: np.ndarray
    q: np.ndarray
    dq: np.ndarray
    ddq: np.ndarray
    u: np.ndarray
    t_nodes: np.ndarray
    q_nodes: np.ndarray
    dq_nodes: np.ndarray
    active: list = field(default_factory=list)   # [{joint, kind, side, intervals: [[t0, t1], ...]}]
    history: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # (iterations+1, 3): time, J, violation
    n_unknowns: int = 0
    tau: np.ndarray = field(default_factory=lambda: np.zeros(0))  # (d,) collocation points on (0, 1]

    def interpolate(self, t) -> tuple[np.ndarray, np.ndarray]:
        """q, q̇ (m, n) at times t (m,) in [0, T]: the collocation polynomials of degree d through each
        interval's start state and its d collocation states (Lagrange basis)."""
        t = np.asarray(t, float)
        h = self.t_nodes[1] - self.t_nodes[0]
        k = np.clip(np.floor(t / h).astype(int), 0, self.K - 1)
        s = t / h - k
        nodes = np.r_[0.0, self.tau]
        basis = np.ones((t.size, self.d + 1))
        for r in range(self.d + 1):
            for m in range(self.d + 1):
                if m != r:
                    basis[:, r] *= (s - nodes[m]) / (nodes[r] - nodes[m])
        n = self.q.shape[1]
        out = []
        for start, coll in ((self.q_nodes, self.q), (self.dq_nodes, self.dq)):
            V = np.concatenate([start[:-1, None, :], coll.reshape(self.K, self.d, n)], axis=1)  # (K, d+1, n)
            out.append(np.einsum("mr,mrn->mn", basis, V[k]))
        return out[0], out[1]


class _Recorder(ca.Callback):
    """IPOPT iteration callback: appends (time since ``start``, f, violation) per iteration."""

    def __init__(self, nx: int, ng: int, lbx, ubx, lbg, ubg, eq: np.ndarray) -> None:
        ca.Callback.__init__(self)
        self.nx, self.ng = nx, ng
        self.lbx, self.ubx, self.lbg, self.ubg, self.eq = lbx, ubx, lbg, ubg, eq
        self.start = 0.0
        self.rows: list[tuple[float, float, float]] = []
        self.construct("recorder", {})

    def get_n_in(self) -> int:
        return ca.nlpsol_n_out()

    def get_n_out(self) -> int:
        return 1

    def get_name_in(self, i: int) -> str:
        return ca.nlpsol_out(i)

    def get_name_out(self, i: int) -> str:
        return "ret"

    def get_sparsity_in(self, i: int) -> ca.Sparsity:
        name = ca.nlpsol_out(i)
        if name == "f":
            return ca.Sparsity.scalar()
        if name in ("x", "lam_x"):
            return ca.Sparsity.dense(self.nx)
        if name in ("g", "lam_g"):
            return ca.Sparsity.dense(self.ng)
        return ca.Sparsity(0, 0)

    def eval(self, arg):
        now = time.perf_counter() - self.start
        x = np.asarray(arg[0]).ravel()
        f = float(arg[1])
        g = np.asarray(arg[2]).ravel()
        self.rows.append((now, f, violation(x, g, self.lbx, self.ubx, self.lbg, self.ubg, self.eq)))
        return [0]


def violation(x, g, lbx, ubx, lbg, ubg, eq) -> float:
    """max(|g_eq|, bound excesses of x and of the inequality rows) — absolute units."""
    v = 0.0
    if eq.any():
        v = float(np.abs(g[eq] - lbg[eq]).max())
    if (~eq).any():
        v = max(v, float(np.maximum(lbg[~eq] - g[~eq], g[~eq] - ubg[~eq]).max()))
    return max(v, float(np.maximum(lbx - x, x - ubx).max()))


# --------------------------------------------------------------------------- the NLP
def quintic_guess(T: float, q0, dq0, q1, dq1):
    """q_of_t(t, k): k-th derivative (K, n) of the quintic per joint with q, q̇ from x0, x1, q̈ = 0 at
    both ends."""
    # q(s) = Σ c_p s^p, s = t/T; conditions at s = 0, 1 on q, q' = T q̇, q'' = 0
    rows = [[1, 0, 0, 0, 0, 0], [0, 1, 0, 0, 0, 0], [0, 0, 2, 0, 0, 0],
            [1, 1, 1, 1, 1, 1], [0, 1, 2, 3, 4, 5], [0, 0, 2, 6, 12, 20]]
    rhs = np.stack([q0, T * dq0, 0 * q0, q1, T * dq1, 0 * q1])
    c = np.linalg.solve(np.array(rows, float), rhs)  # (6, n)

    def q_of_t(t, k):
        s = np.asarray(t, float)[:, None] / T
        out = 0.0
        for p in range(k, 6):
            fall = np.prod(np.arange(p - k + 1, p + 1)) if k else 1.0
            out = out + fall * c[p] * s ** (p - k)
        return np.broadcast_to(out, (s.shape[0], c.shape[1])) / T**k

    return q_of_t


class LimitedCollocation:
    """The NLP for K intervals of degree d, built once (symbolic setup), solved from a guess."""

    def __init__(self, model, T: float, q0, dq0, q1, dq1, K: int, d: int = 3, *, limits: Limits | None = None,
                 cost: str = "covariant", scheme: str = "radau", tol: float = 1e-10,
                 ipopt: dict | None = None, expand: bool = True) -> None:
        if cost not in ("covariant", "torque"):
            raise ValueError(f"cost: expected 'covariant' or 'torque', got {cost!r}")
        started = time.perf_counter()
        n = model.n
        lim = limits if limits is not None else Limits.none(n)
        for name, x, lo, hi in (("x0.q", q0, lim.lower, lim.upper), ("x1.q", q1, lim.lower, lim.upper),
                                ("x0.dq", dq0, -lim.velocity, lim.velocity), ("x1.dq", dq1, -lim.velocity,
                                                                              lim.velocity)):
            bad = np.flatnonzero((x < lo) | (x > hi))
            if bad.size:
                i = int(bad[0])
                raise ValueError(f"{name}: joint {model.joint_names[i]} = {x[i]} is outside its limit [{lo[i]}, {hi[i]}]")
        self.model, self.T, self.K, self.d, self.n = model, T, K, d, n
        self.limits, self.cost, self.scheme = lim, cost, scheme
        self.x0, self.x1 = np.r_[q0, dq0], np.r_[q1, dq1]
        h = T / K
        tau, D, B, E = collocation(d, scheme)
        self.tau = tau
        self.times = (np.arange(K)[:, None] + tau[None, :]).ravel() * h  # (K d,)
        self.t_nodes = np.arange(K + 1) * h
        ID, _, quad = CasadiRobot(model).functions()
        eff_rows = np.flatnonzero(np.isfinite(lim.effort))
        cov = cost == "covariant"

        # one interval
        s0, s1 = ca.SX.sym("s0", 2 * n), ca.SX.sym("s1", 2 * n)
        Xc, A = ca.SX.sym("X", 2 * n, d), ca.SX.sym("A", n, d)
        W = ca.SX.sym("W", n, d) if cov else ca.SX.zeros(n, d)
        Xall = ca.horzcat(s0, Xc)
        dX = ca.mtimes(Xall, ca.DM(D.T)) / h
        eq = [ca.vec(dX[:n, :] - Xc[n:, :]), ca.vec(dX[n:, :] - A)]
        ineq, J = [], 0
        for j in range(d):
            q, dq = Xc[:n, j], Xc[n:, j]
            u = ID(q, dq, A[:, j])
            if cov:
                eq.append(ID(q, dq, A[:, j] - W[:, j]))
                J += 0.5 * h * B[j] * quad(q, W[:, j])
            else:
                J += 0.5 * h * B[j] * ca.dot(u, u)
            if eff_rows.size:
                ineq.append(u[[int(i) for i in eff_rows]])
        eq.append(s1 - ca.mtimes(Xall, ca.DM(E)))
        args = [s0, Xc, A] + ([W] if cov else []) + [s1]
        interval = ca.Function("interval", args, [ca.vertcat(*eq), ca.vertcat(*ineq) if ineq else ca.SX(0, 1), J])

        # the horizon
        S = ca.MX.sym("S", 2 * n, K + 1)
        Xs, As = ca.MX.sym("X", 2 * n, K * d), ca.MX.sym("A", n, K * d)
        Ws = ca.MX.sym("W", n, K * d) if cov else None
        margs = [S[:, :K], Xs, As] + ([Ws] if cov else []) + [S[:, 1:]]
        Geq, Gin, C = interval.map(K)(*margs)
        parts = [ca.vec(S), ca.vec(Xs), ca.vec(As)] + ([ca.vec(Ws)] if cov else [])
        self.x = ca.vertcat(*parts)
        g = ca.vertcat(ca.vec(Geq), ca.vec(Gin))
        n_eq, n_in = int(Geq.numel()), int(Gin.numel())
        self.nlp = {"x": self.x, "f": ca.sum2(C), "g": g}
        self.sizes = dict(S=2 * n * (K + 1), X=2 * n * K * d, A=n * K * d, W=n * K * d if cov else 0)

        # bounds
        state_lo, state_hi = np.r_[lim.lower, -lim.velocity], np.r_[lim.upper, lim.velocity]
        lbS, ubS = np.tile(state_lo, K + 1), np.tile(state_hi, K + 1)
        lbS[:2 * n] = ubS[:2 * n] = self.x0
        lbS[-2 * n:] = ubS[-2 * n:] = self.x1
        self.lbx = np.r_[lbS, np.tile(state_lo, K * d), np.tile(-lim.acceleration, K * d), -np.inf * np.ones(self.sizes["W"])]
        self.ubx = np.r_[ubS, np.tile(state_hi, K * d), np.tile(lim.acceleration, K * d), np.inf * np.ones(self.sizes["W"])]
        e = lim.effort[eff_rows]
        self.lbg = np.r_[np.zeros(n_eq), np.tile(-e, K * d)]
        self.ubg = np.r_[np.zeros(n_eq), np.tile(e, K * d)]
        self.eq = np.r_[np.ones(n_eq, bool), np.zeros(n_in, bool)]
        self.recorder = _Recorder(self.x.shape[0], int(g.shape[0]), self.lbx, self.ubx, self.lbg, self.ubg, self.eq)
        opts = {"expand": expand, "print_time": False, "iteration_callback": self.recorder,
                "ipopt": {"tol": tol, "constr_viol_tol": tol, "linear_solver": "mumps", "print_level": 0,
                          "hessian_approximation": "exact", "max_iter": 3000, "sb": "yes",
                          "bound_relax_factor": 0.0, **(ipopt or {})}}
        self.solver = ca.nlpsol("ipopt", "ipopt", self.nlp, opts)
        self.n_unknowns = int(self.x.shape[0]) - 4 * n
        self.guess = self.guess_from(quintic_guess(T, q0, dq0, q1, dq1))
        self.setup = time.perf_counter() - started

    def guess_from(self, q_of_t) -> np.ndarray:
        """Initial guess from a trajectory: q_of_t(t, k) gives the k-th derivative (m, n) at times t (m,)."""
        qn, dqn = q_of_t(self.t_nodes, 0), q_of_t(self.t_nodes, 1)
        q, dq, ddq = (q_of_t(self.times, k) for k in range(3))
        parts = [np.hstack([qn, dqn]).ravel(), np.hstack([q, dq]).ravel(), ddq.ravel()]
        if self.cost == "covariant":
            parts.append((ddq - dynamics.forward_dynamics(self.model, q, dq, np.zeros_like(q))).ravel())
        x = np.concatenate(parts)
        x[:2 * self.n], x[self.sizes["S"] - 2 * self.n: self.sizes["S"]] = self.x0, self.x1
        return x

    def unpack(self, x: np.ndarray) -> dict:
        n, K, Kd = self.n, self.K, self.K * self.d
        o = np.cumsum([0, self.sizes["S"], self.sizes["X"], self.sizes["A"]])
        S = x[o[0]:o[1]].reshape(K + 1, 2 * n)
        X = x[o[1]:o[2]].reshape(Kd, 2 * n)
        A = x[o[2]:o[3]].reshape(Kd, n)
        return dict(q_nodes=S[:, :n], dq_nodes=S[:, n:], q=X[:, :n], dq=X[:, n:], ddq=A)

    def solve(self, guess: np.ndarray | None = None, *, rtol: float = 1e-6, feas_tol: float = 1e-8) -> Result:
        """One IPOPT solve from the quintic (or ``guess``); the wall clock of the solver call alone."""
        self.recorder.rows = []
        self.recorder.start = started = time.perf_counter()
        sol = self.solver(x0=self.guess if guess is None else guess, lbx=self.lbx, ubx=self.ubx,
                          lbg=self.lbg, ubg=self.ubg)
        wall = time.perf_counter() - started
        st = self.solver.stats()
        x, g = np.array(sol["x"]).ravel(), np.array(sol["g"]).ravel()
        J = float(sol["f"])
        hist = np.array(self.recorder.rows, float).reshape(-1, 3)
        ok = (np.abs(hist[:, 1] - J) <= rtol * abs(J)) & (hist[:, 2] <= feas_tol)
        first = int(np.argmax(ok)) if ok.any() else -1
        stay = -1  # the first index of the final run of True
        if ok.size and ok[-1]:
            stay = int(np.flatnonzero(~ok)[-1]) + 1 if (~ok).any() else 0
        p = self.unpack(x)
        u = dynamics.inverse_dynamics(self.model, p["q"], p["dq"], p["ddq"])
        res = Result(J=J, success=bool(st["success"]), status=st["return_status"], iterations=int(st["iter_count"]),
                     wall=wall, setup=self.setup, t_to_tol=float(hist[first, 0]) if first >= 0 else np.nan,
                     t_to_tol_stay=float(hist[stay, 0]) if stay >= 0 else np.nan, it_to_tol=first,
                     max_violation=violation(x, g, self.lbx, self.ubx, self.lbg, self.ubg, self.eq),
                     K=self.K, d=self.d, scheme=self.scheme, cost=self.cost, t=self.times, u=u,
                     t_nodes=self.t_nodes, history=hist, n_unknowns=self.n_unknowns, tau=self.tau, **p)
        res.active = active_limits(self.model.joint_names, self.limits, res)
        return res


# --------------------------------------------------------------------------- reporting
def active_limits(joints, limits: Limits, r: Result, rtol: float = 1e-6) -> list[dict]:
    """Where each limit is active at the solution: samples within rtol·max(1, |limit|) of it, grouped
    into time intervals [first, last sample] of consecutive active samples."""
    t_state = np.r_[r.t_nodes, r.t]
    order = np.argsort(t_state, kind="stable")
    series = {"position": (t_state[order], np.vstack([r.q_nodes, r.q])[order]),
              "velocity": (t_state[order], np.vstack([r.dq_nodes, r.dq])[order]),
              "acceleration": (r.t, r.ddq), "effort": (r.t, r.u)}
    out = []
    for kind in KINDS:
        t, X = series[kind]
        lo, hi = limits.bounds(kind)
        for i, name in enumerate(joints):
            for side, b in (("lower", lo[i]), ("upper", hi[i])):
                if not np.isfinite(b):
                    continue
                on = np.abs(X[:, i] - b) <= rtol * max(1.0, abs(b))
                if not on.any():
                    continue
                idx = np.flatnonzero(on)
                breaks = np.flatnonzero(np.diff(idx) > 1)
                starts, ends = np.r_[idx[0], idx[breaks + 1]], np.r_[idx[breaks], idx[-1]]
                out.append({"joint": name, "kind": kind, "side": side, "limit": float(b),
                            "intervals": [[float(t[a]), float(t[e])] for a, e in zip(starts, ends)]})
    return out


#: example-robot-data's robots/ directory (``pip install example-robot-data``: URDFs only)
ERD = Path(sysconfig.get_paths()["purelib"]) / "cmeel.prefix" / "share" / "example-robot-data" / "robots"


def load_task(path: str | Path) -> Task:
    """A task file, its relative ``robot:`` path tried next to the file first, then under ``ERD``
    (benchmarks/tasks/ur5_limits.yaml names ``ur_description/urdf/ur5_robot.urdf``)."""
    path = Path(path)
    text = path.read_text()
    doc = load_yaml(text)
    robot = doc.get("robot") if isinstance(doc, dict) else None
    if isinstance(robot, str) and not Path(robot).is_absolute() and not (path.parent / robot).is_file():
        if not (ERD / robot).is_file():
            raise FileNotFoundError(f"{path}: robot {robot!r} is neither next to the file nor in {ERD} "
                                    "(pip install example-robot-data)")
        doc["robot"] = str(ERD / robot)
    return parse_task(doc, path=path, text=text)


def load(task: str | Path | Task):
    """(task, model, states) for a task file (see ``load_task``) or a loaded Task."""
    if not isinstance(task, Task):
        task = load_task(task)
    model = load_robot(task.robot, joints=list(task.joints) if task.joints else None,
                       locked=task.locked, gravity=task.gravity)
    return task, model, resolve(task, model.joint_names)


def solve(task: str | Path | Task, N: int, *, limits: Limits | str | None = "urdf", d: int = 3,
          scheme: str = "radau", cost: str | None = None, acceleration=None, scale: dict | None = None,
          tol: float = 1e-10, guess=None, rtol: float = 1e-6, feas_tol: float = 1e-8, repeat: int = 1) -> Result:
    """IPOPT collocation of ``task`` on N intervals of degree d.

    limits: ``"urdf"`` (the model's URDF limits, with ``acceleration`` and ``scale`` as in
    ``Limits.from_model``), a ``Limits``, or None (the unconstrained problem). cost: the task's by
    default. guess: None (the quintic) or q_of_t(t, k) -> (m, n). repeat: solves from the same guess
    after one symbolic setup; the fastest is returned (timings on a shared machine are noisy).
    """
    task, model, st = load(task)
    if limits == "urdf":
        limits = Limits.from_model(model, acceleration=acceleration, scale=scale)
    c = LimitedCollocation(model, task.T, st.q0, st.dq0, st.q1, st.dq1, N, d, limits=limits,
                           cost=cost or task.cost, scheme=scheme, tol=tol)
    x0 = None if guess is None else c.guess_from(guess)
    return min((c.solve(x0, rtol=rtol, feas_tol=feas_tol) for _ in range(max(repeat, 1))), key=lambda r: r.wall)
