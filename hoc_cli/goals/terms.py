"""Equality rows of goals in the augmented Lagrangian: value, exact gradient, Newton blocks, ∂/∂T.

A goal point is a residual c(q, q̇, T) (``hoc_cli.goals.residuals``) imposed at the time t = s·T
(s ∈ [0, 1] a fraction of the duration, so it stays put in the s domain when T is free). On a
mesh it lies in one element (``PointSet``), so q, q̇ there are linear in that element's
coefficients and every row adds only to one element block of the banded Newton matrix. With
multipliers λ and a penalty ρ (per unit c², the same for every row) the augmented Lagrangian adds

    Ψ = Σ_rows λ c + ½ ρ c²,     ∂Ψ/∂C = Σ μ ∂c/∂C,   μ = λ + ρ c,

and the first-order update is λ ← μ (Hestenes 1969, Powell 1969; Nocedal & Wright §17.3). The
Newton blocks are ρ Dᵀ D with D = [∂c/∂q, ∂c/∂q̇, 0] (Gauss-Newton: the μ ∂²c terms of a
nonlinear residual are left out; exact for joint residuals). At fixed s-domain coefficients,
q(sT) is unchanged and q̇ scales as 1/T, so ∂c/∂T = ∂c/∂T|explicit − ∂c/∂q̇ · q̇ / T.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from hoc_cli.constraints.points import PointSet
from hoc_cli.elements import HermiteMesh, local_basis
from hoc_cli.goals.residuals import JointResidual


@dataclass(frozen=True, eq=False)
class GoalPoint:
    """A residual imposed at the fraction s ∈ [0, 1] of the duration; ``label`` names it in reports."""

    s: float
    residual: object
    label: str = "goal"


TIME_REL_STEP = 1e-5  # ε/T of ``GoalTerms.time_column``'s central differences along the rescaled family

def point_set(mesh: HermiteMesh, points: list[GoalPoint]) -> PointSet:
    """The mesh points (element, local coordinate) of the goal points' times s·T."""
    s = np.array([p.s for p in points], float)
    if not mesh.uniform:  # the element holding each time (a via on a node: the element it starts)
        e, local = mesh.element_of(s * mesh.T)
        return PointSet.build(mesh, e, local, np.ones(len(points)))
    x = s * mesh.N
    e = np.clip(np.floor(x).astype(int), 0, mesh.N - 1)
    local = x - e
    unit, powers = _unit_values(mesh.order, local.tobytes())  # the h = 1 values, kept: they do not depend on T
    h = mesh.h
    B = np.stack([unit[r] * h ** powers[r] for r in range(3)])  # ``PointSet.build``'s numbers (``HermiteMesh.scale``)
    return PointSet(mesh=mesh, e=e, s=local, B=B, weight=np.ones(len(points)))


def _plus_minus(residual, q: np.ndarray, dq: np.ndarray, dz: tuple, eps: float, T: float) -> tuple:
    """(the residual at (q, q̇, T) + ε·(dz, 1), the same at −ε): with a ``batch`` (``FrameResidual``) both by one pass
    of its forward kinematics, each sample with its own T; the same numbers as two calls (each sample of a batch is
    computed as alone).
    """
    zq, zv = (q + eps * dz[0], q - eps * dz[0]), (dq + eps * dz[1], dq - eps * dz[1])
    if not hasattr(residual, "batch"):
        return residual(zq[0], zv[0], T + eps), residual(zq[1], zv[1], T - eps)
    out = residual.batch(np.stack(zq), np.stack(zv), np.array([T + eps, T - eps]))
    return tuple(tuple(v[i] for v in out) for i in (0, 1))


@lru_cache(maxsize=64)
def _unit_values(order: str, local: bytes) -> tuple[np.ndarray, np.ndarray]:
    """(the shape functions' s-derivatives of orders r = 0, 1, 2 at the local coordinates ``local`` (float64 bytes, (P,)),
    (3, P, 2m); the powers d − r (3, 2m) of h that ``HermiteMesh.shape_values`` scales them by): the same products, in
    the same order.
    """
    s = np.frombuffer(local, float)
    powers = s[:, None] ** np.arange(6)[None, :]  # (P, 6)
    out = np.stack([powers @ local_basis(order)[r].T for r in range(3)])
    d = np.tile(np.arange(out.shape[-1] // 2), 2)
    scale = np.stack([(d - r).astype(float) for r in range(3)])
    out.flags.writeable = scale.flags.writeable = False
    return out, scale


def _perturbed(q: np.ndarray, dq: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(X (2n, 2n), steps (2n,)): x = (q, q̇) moved by steps 1e-7·(1 + |x|) along each coordinate, one per row (the
    forward differences of ``GoalTerms.newton_parts``).
    """
    x = np.concatenate([q, dq])
    steps = 1e-7 * (1.0 + np.abs(x))
    return x[None, :] + np.diag(steps), steps


@dataclass(frozen=True, eq=False)
class GoalTerms:
    """The equality rows of ``points`` on ``mesh`` with multipliers ``lam`` (one array per point) and ρ."""

    mesh: HermiteMesh
    points: list[GoalPoint]
    lam: list[np.ndarray]
    rho: float
    where: PointSet | None = None  # the points' PointSet on ``mesh`` when known (built on demand otherwise)

    @classmethod
    def start(cls, mesh: HermiteMesh, points: list[GoalPoint], rho: float = 1.0) -> "GoalTerms":
        return cls(mesh, points, [np.zeros(p.residual.size) for p in points], rho)

    def on(self, mesh: HermiteMesh) -> "GoalTerms":
        """The same rows and multipliers on another mesh (the points are fractions of T)."""
        return GoalTerms(mesh, self.points, self.lam, self.rho)

    @property
    def empty(self) -> bool:
        return not self.points

    def _where(self) -> PointSet:
        return self.where if self.where is not None else point_set(self.mesh, self.points)

    def residuals(self, C: np.ndarray) -> list[tuple[np.ndarray, ...]]:
        """(c, ∂c/∂q, ∂c/∂q̇, ∂c/∂T, q, q̇) of every point at coefficients C (N+1, m, n)."""
        X = self._where().apply(C)
        T = self.mesh.T
        return [(*gp.residual(X[0, i], X[1, i], T), X[0, i], X[1, i]) for i, gp in enumerate(self.points)]

    def residuals_with_samples(self, C: np.ndarray, V1: np.ndarray | None = None,
                               rel_step: float = TIME_REL_STEP) -> tuple[list, list]:
        """(``residuals(C)``, per point the residual's (∂c/∂q, ∂c/∂q̇) (2n, r, n) at the 2n points ``newton_parts``
        perturbs (None for joint residuals)): each point and its perturbations in one pass of the kinematics (the
        same numbers as ``residuals`` and ``newton_parts``' own pass), for a point where a Newton matrix is made.
        ``V1`` (N+1, m, n): the fixed coefficients' motion along the rescaled family (``free_time.fixed_coefficient_motion``),
        for a free T: each point's samples then also hold the residual at (q, q̇, T) ± ε·δ that ``time_column`` differences
        (ε = ``rel_step``·T; its ``_plus_minus``' numbers), in the same pass.
        """
        X = self._where().apply(C)
        T = self.mesh.T
        Y1 = None if V1 is None else self._where().apply(V1)
        eps = rel_step * T
        res, samples = [], []
        for i, gp in enumerate(self.points):
            q, dq = X[0, i], X[1, i]
            if isinstance(gp.residual, JointResidual):
                res.append((*gp.residual(q, dq, T), q, dq))
                samples.append(None)
                continue
            P = _perturbed(q, dq)[0]
            n = q.size
            if Y1 is None:
                c, cq, cv, cT = gp.residual.batch(np.vstack([q[None], P[:, :n]]), np.vstack([dq[None], P[:, n:]]), T)
                res.append((c[0], cq[0], cv[0], cT, q, dq))
                samples.append((cq[1:], cv[1:]))
                continue
            dz = (Y1[0, i], Y1[1, i] - dq / T)  # ``time_column``'s δ, and its two points at T ± ε
            Q = np.vstack([q[None], P[:, :n], (q + eps * dz[0])[None], (q - eps * dz[0])[None]])
            V = np.vstack([dq[None], P[:, n:], (dq + eps * dz[1])[None], (dq - eps * dz[1])[None]])
            times = np.full(Q.shape[0], T)
            times[-2], times[-1] = T + eps, T - eps
            out = gp.residual.batch(Q, V, times)
            c, cq, cv, cT = out
            res.append((c[0], cq[0], cv[0], cT[0], q, dq))
            samples.append((cq[1:-2], cv[1:-2], tuple(v[-2] for v in out), tuple(v[-1] for v in out)))
        return res, samples

    def violation(self, C: np.ndarray) -> float:
        """The largest |c| over every row (0 without rows); units of the rows (m, rad, m/s)."""
        return max([0.0] + [float(np.max(np.abs(r[0]), initial=0.0)) for r in self.residuals(C)])

    def multipliers(self, C: np.ndarray) -> list[np.ndarray]:
        """μ = λ + ρ c per point: the updated multipliers."""
        return [lam + self.rho * r[0] for lam, r in zip(self.lam, self.residuals(C))]

    def evaluate(self, C: np.ndarray, grad: bool = True) -> tuple[float, np.ndarray | None]:
        """(Ψ, ∂Ψ/∂C (N+1, m, n) or None) at coefficients C."""
        res = self.residuals(C)
        value = sum(float(lam @ r[0]) + 0.5 * self.rho * float(r[0] @ r[0]) for lam, r in zip(self.lam, res))
        if not grad:
            return value, None
        return value, self._gradient(C, res, [lam + self.rho * r[0] for lam, r in zip(self.lam, res)])

    def _gradient(self, C, res, mu) -> np.ndarray:
        where = self._where()
        n = C.shape[-1]
        S = np.zeros((3, len(self.points), n))
        for i, (r, m) in enumerate(zip(res, mu)):
            S[0, i] = r[1].T @ m
            S[1, i] = r[2].T @ m
        return where.transpose(S)

    def jacobian(self, C: np.ndarray, res: list | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(c (r,), ∂c/∂C (r, N+1, m, n)): every row (the points' rows in order) and its gradient
        (``res``: ``residuals(C)`` when already known).
        """
        res = self.residuals(C) if res is None else res
        where = self._where()
        m = C.shape[1]
        c = np.concatenate([r[0] for r in res]) if res else np.zeros(0)
        out = np.zeros((c.size,) + C.shape)
        k = 0
        for i, r in enumerate(res):  # a row of point i: its element's shape functions times (∂c/∂q, ∂c/∂q̇)
            rows = slice(k, k + r[0].size)
            loc = where.B[0, i][None, :, None] * r[1][:, None, :] + where.B[1, i][None, :, None] * r[2][:, None, :]
            out[rows, where.e[i]] += loc[:, :m]
            out[rows, where.e[i] + 1] += loc[:, m:]
            k += r[0].size
        return c, out

    def newton_blocks(self, C: np.ndarray, curvature: bool = True, indefinite: bool = False,
                      res: list | None = None, parts: list | None = None, samples: list | None = None) -> np.ndarray:
        """Element blocks (N, 2mn, 2mn) of ρ Dᵀ D, plus with ``curvature`` the positive part of Σ μ ∇²c.

        The second-order part in (q, q̇) is the forward difference (step 1e-7·(1 + |x|)) of the vector
        Dᵀ μ at fixed μ, symmetrised, its negative eigenvalues dropped unless ``indefinite`` (measured on the lbr7 catch:
        half the inner iterations of the blocks without it, and fewer than with the indefinite part). ``parts``: a list
        that keeps ``newton_parts`` (filled on the first call, read on the next: the blocks with and without the
        negative part from one set of differences). ``samples``: ``residuals_with_samples``' second output at C.
        """
        if parts is None or not parts:
            found = self.newton_parts(C, curvature, res, samples)
            if parts is not None:
                parts.append(found)
        else:
            found = parts[0]
        Hs, curvatures = found
        Hs = Hs.copy()
        n = C.shape[-1]
        for i, H in curvatures:
            if not indefinite:
                ev, V = np.linalg.eigh(H)
                H = (V * np.maximum(ev, 0.0)) @ V.T
            Hs[i, :2 * n, :2 * n] += H
        return self._where().sample_blocks(Hs)

    def newton_parts(self, C: np.ndarray, curvature: bool = True, res: list | None = None,
                     samples: list | None = None) -> tuple:
        """(ρ DᵀD per point (points, 3n, 3n), [(point, Σ μ ∇²c in (q, q̇) (2n, 2n), symmetrised)]) of ``newton_blocks``
        (``samples``: the residuals' derivatives at the perturbed points when known, ``residuals_with_samples``).
        """
        n = C.shape[-1]
        T = self.mesh.T
        Hs = np.zeros((len(self.points), 3 * n, 3 * n))
        curvatures = []
        for i, r in enumerate(self.residuals(C) if res is None else res):
            D = np.hstack([r[1], r[2], np.zeros_like(r[1])])
            Hs[i] = self.rho * D.T @ D
            if curvature and not isinstance(self.points[i].residual, JointResidual):
                mu = self.lam[i] + self.rho * r[0]
                base = D[:, :2 * n].T @ mu
                X, steps = _perturbed(r[4], r[5])
                if samples is not None and samples[i] is not None:
                    cq, cv = samples[i][:2]
                else:
                    _, cq, cv, _ = self.points[i].residual.batch(X[:, :n], X[:, n:], T)
                H = ((np.concatenate([cq, cv], axis=2).transpose(0, 2, 1) @ mu) - base).T / steps
                curvatures.append((i, 0.5 * (H + H.T)))
        return Hs, curvatures

    def time_slopes(self, C: np.ndarray, T: float, V1: np.ndarray, res: list | None = None) -> np.ndarray:
        """The rows' T derivatives c' (r,) along the rescaled family (``time_column``'s first part, exact)."""
        res = self.residuals(C) if res is None else res
        Y1 = self._where().apply(V1)
        rows = [r[1] @ Y1[0, i] + r[2] @ (Y1[1, i] - r[5] / T) + r[3] for i, r in enumerate(res)]
        return np.concatenate(rows) if rows else np.zeros(0)

    def time_column(self, C: np.ndarray, T: float, V1: np.ndarray, V2: np.ndarray, res: list | None = None,
                    rel_step: float = TIME_REL_STEP, samples: list | None = None) -> tuple[np.ndarray, np.ndarray, float]:
        """(c' (r,), ∂/∂T of ∂Λ/∂C (N+1, m, n), Λ'') of Λ = Σ λ·c (the multipliers as they are, ρ's part not
        included) along the rescaled family (``free_time.rescale``; V1, V2 the fixed coefficients' motion,
        ``free_time.fixed_coefficient_motion``).

        At a point, q is fixed in the s domain and q̇ = q̃'(s)/T: (q, q̇, T) moves by δ = (P(V1)_q, P(V1)_q̇ − q̇/T, 1)
        and its second derivative is (P(V2)_q, P(V2)_q̇ − 2P(V1)_q̇/T + 2q̇/T², 0) (P: the points' shape functions), so
        c' = ∂c/∂(q, q̇)·δ + ∂c/∂T (exact). With Γ = (∂c/∂qᵀλ, ∂c/∂q̇ᵀλ, λ·∂c/∂T), the column is Pᵀ(Γ'_q, Γ'_q̇ − Γ_q̇/T)
        and Λ'' = Γ'·δ + Γ·(the second derivative), where Γ' = ∇Γ·δ, the residual's second derivatives along δ, is a
        central difference of the residual's exact first derivatives at (q, q̇, T) ± ε·δ, ε = ``rel_step``·T (the
        goal rows alone, no dynamics: two residual evaluations per point, one pass of the kinematics where the residual has
        ``batch``; ~1e-10 relative). ``samples``: ``residuals_with_samples(C, V1, rel_step)``' second output, whose
        points at ± ε are used where it holds them.
        """
        res = self.residuals(C) if res is None else res
        where = self._where()
        Y1, Y2 = where.apply(V1), where.apply(V2)
        n = C.shape[-1]
        S = np.zeros((3, len(self.points), n))
        rows, second = [], 0.0
        eps = rel_step * T
        for i, (gp, lam, r) in enumerate(zip(self.points, self.lam, res)):
            q, dq = r[4], r[5]
            dz = (Y1[0, i], Y1[1, i] - dq / T)
            rows.append(r[1] @ dz[0] + r[2] @ dz[1] + r[3])
            kept = samples[i] if samples is not None else None
            plus, minus = kept[2:] if kept is not None and len(kept) == 4 else _plus_minus(gp.residual, q, dq, dz, eps, T)
            d_q = (plus[1].T @ lam - minus[1].T @ lam) / (2.0 * eps)
            d_v = (plus[2].T @ lam - minus[2].T @ lam) / (2.0 * eps)
            d_T = float(lam @ (plus[3] - minus[3])) / (2.0 * eps)
            g_v = r[2].T @ lam
            S[0, i], S[1, i] = d_q, d_v - g_v / T
            curve_v = Y2[1, i] - 2.0 * Y1[1, i] / T + 2.0 * dq / T**2
            second += float(d_q @ dz[0] + d_v @ dz[1] + d_T + (r[1].T @ lam) @ Y2[0, i] + g_v @ curve_v)
        c_T = np.concatenate(rows) if rows else np.zeros(0)
        return c_T, where.transpose(S), second

    def time_derivative(self, C: np.ndarray, T: float, res: list | None = None) -> tuple[float, np.ndarray]:
        """(Σ μ·∂c/∂T at fixed s-domain coefficients, Σ μ ∂c/∂C (N+1, m, n)), μ = λ + ρ c."""
        res = self.residuals(C) if res is None else res
        mu = [lam + self.rho * r[0] for lam, r in zip(self.lam, res)]
        dT = sum(float(m @ (r[3] - r[2] @ r[5] / T)) for m, r in zip(mu, res))
        return dT, self._gradient(C, res, mu)
