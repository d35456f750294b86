"""Augmented-Lagrangian terms of joint limits: value, exact gradient and Newton blocks.

Symbols
-------
N elements, n joints, m coefficients per node; kinds k = position, velocity, acceleration, jerk
(kinematic: r = k = 0 … 3, ``KINEMATIC``) and effort. Each kind has its own constraint rows per element:
kinematic kinds the Bernstein coefficients of d^r q_h/dt^r (``bernstein_rows``; linear in the
coefficients C, and bounding them bounds q_h^(r) everywhere), effort the torque u = ID(q, q̇, q̈)
at 32 equally spaced points per element (``PointSet``). V_k: (N, R_k, n) or (P, n) values.
σ[k, j] > 0: the size of joint j's limit (``JointLimits.scale_of``); δ: a relative margin. Each
bound gives a dimensionless inequality g ≤ 0:

    g_hi = (V − (hi − δσ)) / σ,        g_lo = ((lo + δσ) − V) / σ.

With multipliers λ ≥ 0 and per-row penalties ρ_w = ρ·w (w [s]: the time a row stands for), the
Powell-Hestenes-Rockafellar augmented Lagrangian adds, summed over rows, joints and sides,

    Φ = (max(0, λ + ρ_w g)² − λ²) / (2 ρ_w),     ∂Φ/∂V = ±μ/σ,  μ = max(0, λ + ρ_w g),

and the multiplier update is λ ← μ (Rockafellar 1973; Nocedal & Wright §17.4). Φ is once
continuously differentiable; its curvature ρ_w/σ² ∇V∇Vᵀ where λ + ρ_w g > 0 is exact for the
kinematic kinds and the Gauss-Newton part for effort (∇u = [∂u/∂q, ∂u/∂q̇, M]).
Only the (kind, joint) pairs of the working set take part; the others cost nothing.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from hoc_cli.constraints.bernstein import bernstein_rows
from hoc_cli.constraints.bounds import EFFORT, KINDS, KINEMATIC, JointLimits
from hoc_cli.constraints.points import PointSet
from hoc_cli.elements import HermiteMesh

EFFORT_POINTS_PER_ELEMENT = 32


def effective_bounds(limits: JointLimits, margin: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(lo, hi, σ), each (K, n) (K = len(KINDS)): the bounds moved inwards by margin·σ, and σ."""
    sig = np.stack([limits.scale_of(k) for k in KINDS])
    lo = np.stack([limits.bounds(k)[0] for k in KINDS]) + margin * sig
    hi = np.stack([limits.bounds(k)[1] for k in KINDS]) - margin * sig
    return lo, hi, sig


@dataclass(frozen=True, eq=False)
class LimitRows:
    """Where each kind is imposed on a mesh: Bernstein rows (kinematic) and torque points (effort).

    rows[r] : (R_r, 2m) for r = 0 … KINEMATIC − 1; part[r] : (R_r,) the element part of each row;
    data[r] : (N, R_r) bool, rows fixed by x0/x1 alone (not imposed); points : effort PointSet
    (a property, made on first use).
    scale : None (uniform mesh), or per r the factors h_e^(d_a − r) (N, 2m) of a non-uniform mesh,
    whose rows are those of h = 1 applied to the scaled element coefficients.
    """

    mesh: HermiteMesh
    rows: tuple[np.ndarray, ...]
    part: tuple[np.ndarray, ...]
    data: tuple[np.ndarray, ...]
    pieces: int
    scale: tuple[np.ndarray, ...] | None = None

    @cached_property
    def points(self) -> PointSet:
        """The effort points (made on first use: the kinematic rows do not need them)."""
        return PointSet.uniform(self.mesh, EFFORT_POINTS_PER_ELEMENT)

    @classmethod
    def build(cls, mesh: HermiteMesh, free: np.ndarray, n: int) -> "LimitRows":
        """Rows for ``mesh``; ``free`` (P,) the free mask of the flattened C (N+1, m, n)."""
        from hoc_cli.constraints.bernstein import PIECES

        m = mesh.m
        free_nodes = free.reshape(mesh.N + 1, m, n)[:, :, 0]  # (N+1, m): same for every joint
        free_local = np.concatenate([free_nodes[:-1], free_nodes[1:]], axis=1)  # (N, 2m)
        rows, parts, data = [], [], []
        unit = mesh if mesh.uniform else HermiteMesh(mesh.order, 1.0, 1)  # non-uniform: h = 1 rows, scaled
        for r in range(KINEMATIC):
            R, part = bernstein_rows(unit, r, PIECES)
            rows.append(R)
            parts.append(part)
            data.append(~((np.abs(R)[None, :, :] > 1e-14 * np.abs(R).max()) & free_local[:, None, :]).any(axis=2))
        scale = None if mesh.uniform else tuple(mesh.scales(r) for r in range(KINEMATIC))
        return cls(mesh, tuple(rows), tuple(parts), tuple(data), PIECES, scale)

    def weight(self, k: int) -> float | np.ndarray:
        """Time [s] each row of kind k stands for (non-uniform mesh: per row, broadcastable to its shape)."""
        if not self.mesh.uniform:
            return self.points.weight[:, None] if k == EFFORT else (self.mesh.hs / self.rows[k].shape[0])[:, None, None]
        if k == EFFORT:
            return self.mesh.h / EFFORT_POINTS_PER_ELEMENT
        return self.mesh.h / self.rows[k].shape[0]

    def shape(self, k: int, n: int) -> tuple[int, ...]:
        return (self.points.size, n) if k == EFFORT else (self.mesh.N, self.rows[k].shape[0], n)

    def apply(self, k: int, loc: np.ndarray) -> np.ndarray:
        """Kinematic values (N, R_k, n) of kind k from element coefficients loc (N, 2m, n)."""
        if self.scale is not None:
            loc = loc * self.scale[k][:, :, None]
        return np.einsum("ra,ean->ern", self.rows[k], loc)

    def transpose(self, k: int, dV: np.ndarray) -> np.ndarray:
        """Adjoint of ``apply``: sensitivities dV (N, R_k, n) to element-local gradients (N, 2m, n)."""
        gloc = np.einsum("ra,ern->ean", self.rows[k], dV)
        return gloc if self.scale is None else gloc * self.scale[k][:, :, None]

    def to_coefficients(self, gloc: np.ndarray) -> np.ndarray:
        """Element-local gradients (N, 2m, n) summed onto the nodes: (N+1, m, n)."""
        m = self.mesh.m
        out = np.zeros((self.mesh.N + 1, m, gloc.shape[-1]))
        out[:-1] += gloc[:, :m]
        out[1:] += gloc[:, m:]
        return out


@dataclass(frozen=True, eq=False)
class PenaltyValue:
    """Φ at coefficients C with what the multiplier update and the check need.

    value : Φ; grad : ∂Φ/∂C (N+1, m, n) or None; g_lo, g_hi, mu_lo, mu_hi : per kind, arrays of
    the kind's row shape (g = −inf where the bound is absent, not imposed or fixed by data).
    """

    value: float
    grad: np.ndarray | None
    g_lo: tuple[np.ndarray, ...]
    g_hi: tuple[np.ndarray, ...]
    mu_lo: tuple[np.ndarray, ...]
    mu_hi: tuple[np.ndarray, ...]

    def max_violation(self) -> float:
        """The largest g > 0 over all kinds (0 when none), dimensionless."""
        return max([0.0] + [float(np.max(g, initial=0.0)) for g in self.g_lo + self.g_hi])

    def complementarity(self, slack: float = 1e-8) -> float:
        """Σ μ |g| over the rows more than ``slack`` inside their bound: the cost-units gap left by
        multipliers on rows that are not active (rows within the slack count as active).
        """
        total = 0.0
        for mus, gs in ((self.mu_lo, self.g_lo), (self.mu_hi, self.g_hi)):
            for mu, g in zip(mus, gs):
                inside = np.isfinite(g) & (g < -slack)
                total += float(np.sum(np.where(inside & (mu > 0), mu * np.abs(np.where(inside, g, 0.0)), 0.0)))
        return total


@dataclass(frozen=True, eq=False)
class LimitTerms:
    """The augmented-Lagrangian terms for one inner minimisation (fixed λ, ρ, rows, working set).

    system : the dynamics (for effort); limits : JointLimits; rows : LimitRows;
    working : (K, n) bool; lam_lo, lam_hi : per kind ≥ 0, the kind's row shape;
    rho : penalty per unit time [cost units / s]; margin : δ.

    The last ``CACHE`` evaluations are kept by their coefficients: an inner iteration asks Φ at its accepted
    point for the gradient, the Newton blocks and the first step's rows (``collision.step.limit_rows``), and
    the collision loop's update asks it once more; each is evaluated once (the same numbers).
    """

    system: object
    limits: JointLimits
    rows: LimitRows
    working: np.ndarray
    lam_lo: tuple[np.ndarray, ...]
    lam_hi: tuple[np.ndarray, ...]
    rho: float
    margin: float
    _cache: list = field(default_factory=list, init=False, repr=False)  # [[C, PenaltyValue, without gradient]], newest last
    _kinematic_kept: list = field(default_factory=list, init=False, repr=False)  # [active rows' key, kinematic Newton blocks]
    _offs: dict = field(default_factory=dict, init=False, repr=False)  # kind → ``_off``'s masks

    CACHE = 2

    @property
    def empty(self) -> bool:
        return not bool(self.working.any())

    @cached_property
    def _bounds(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return effective_bounds(self.limits, self.margin)

    @property
    def sigma(self) -> np.ndarray:
        """σ (K, n): the size of each kind's limit per joint (``effective_bounds``), kept with the terms."""
        return self._bounds[2]

    def _values(self, C: np.ndarray):
        """(the values of each kind at its rows (None: not imposed), the effort points' (q, q̇, q̈) or None, and what
        ``_effort_vjp`` takes to reuse the torques' Newton-Euler pass).
        """
        mesh = self.rows.mesh
        loc = mesh.local_coefficients(C)
        V = [self.rows.apply(k, loc) if self.working[k].any() else None for k in range(KINEMATIC)]
        X = kept = None
        if self.working[EFFORT].any():
            X = self.rows.points.apply(C)
            if hasattr(self.system, "inverse_dynamics_kept"):
                u, kept = self.system.inverse_dynamics_kept(X[0], X[1], X[2])
            else:
                u = self.system.inverse_dynamics(X[0], X[1], X[2])
            V.append(u)
        else:
            V.append(None)
        return V, X, kept

    def _effort_points(self, C: np.ndarray) -> np.ndarray:
        """The effort points' (q, q̇, q̈) (3, P, n) at C: an evaluation's at C when kept (the same numbers)."""
        for entry in self._cache:
            if entry[3][1] is not None and np.array_equal(entry[0], C):
                return entry[3][1]
        return self.rows.points.apply(C)

    def _effort_vjp(self, X: np.ndarray, kept, lam: np.ndarray) -> tuple[np.ndarray, ...]:
        """``system.id_vjp`` at the effort points' X (3, P, n) with weights lam (P, n), from the pass ``kept`` of their
        torques when the system keeps one (the same numbers).
        """
        if kept is not None:
            return self.system.id_vjp_kept(kept, lam)
        return self.system.id_vjp(X[0], X[1], X[2], lam)

    def _residual(self, k: int, V: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        n = self.limits.n
        shape = self.rows.shape(k, n)
        if V is None:
            off = np.full(shape, -np.inf)
            return off, off
        lo, hi, sig = self._bounds
        g_hi = (V - hi[k]) / sig[k]
        g_lo = (lo[k] - V) / sig[k]
        off_lo, off_hi = self._off(k)
        g_hi = np.where(off_hi, -np.inf, g_hi)
        g_lo = np.where(off_lo, -np.inf, g_lo)
        return g_lo, g_hi

    def _off(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """Kind k's rows that are not constraints (the kind's row shape, bool): of the lower and of the upper bounds
        (a joint not in the working set, a bound that is infinite; q and q̇ rows set by x0, x1 alone are data), the
        same at every C: made once per kind.
        """
        got = self._offs.get(k)
        if got is None:
            lo, hi, _ = self._bounds
            off = ~self.working[k] | np.zeros(self.rows.shape(k, self.limits.n), bool)
            if k < 2:  # q and q̇ rows set by x0, x1 alone are data, not constraints
                off = off | self.rows.data[k][:, :, None]
            got = self._offs[k] = (off | ~np.isfinite(lo[k]), off | ~np.isfinite(hi[k]))
        return got

    def evaluate(self, C: np.ndarray, grad: bool = True) -> PenaltyValue:
        """Φ and (optionally) ∂Φ/∂C (N+1, m, n) at coefficients C."""
        for entry in self._cache:  # [C, PenaltyValue, the same without its gradient or None, ``_values`` at C]
            pv = entry[1]
            if (not grad or pv.grad is not None) and np.array_equal(entry[0], C):
                if grad or pv.grad is None:
                    return pv
                if entry[2] is None:
                    entry[2] = dataclasses.replace(pv, grad=None)
                return entry[2]
        # the gradient at a point evaluated without it (the first step's secant point, the line search's unit trial):
        # its values, torques' pass and Φ taken from there
        known = next((entry for entry in self._cache if np.array_equal(entry[0], C)), None)
        pv, made = self._evaluate(C, grad, None if known is None else (known[3], known[1]))
        self._cache.append([np.array(C), pv, None, made])
        del self._cache[:-self.CACHE]
        return pv

    def _evaluate(self, C: np.ndarray, grad: bool, known: tuple | None = None) -> tuple[PenaltyValue, tuple]:
        """``evaluate`` without the cache: (the PenaltyValue, ``_values``' (V, X, kept)). ``known``: (``_values`` at C,
        the PenaltyValue at C without its gradient), taken as they are.
        """
        made = self._values(C) if known is None else known[0]
        V, X, kept = made
        _, _, sig = self._bounds
        if known is None:
            value = 0.0
            g_lo, g_hi, mu_lo, mu_hi = [], [], [], []
            for k in range(len(KINDS)):
                gl, gh, ml, mh, part = self._kind(k, V[k]) if V[k] is not None else self._idle[k]
                value += part
                g_lo.append(gl), g_hi.append(gh), mu_lo.append(ml), mu_hi.append(mh)
            pv = PenaltyValue(value, None, tuple(g_lo), tuple(g_hi), tuple(mu_lo), tuple(mu_hi))
        else:
            pv = known[1]
        if not grad:
            return pv, made
        gloc = np.zeros((self.rows.mesh.N, 2 * self.rows.mesh.m, self.limits.n))
        G = None
        for k in range(len(KINDS)):
            if V[k] is not None:
                dV = (pv.mu_hi[k] - pv.mu_lo[k]) / sig[k]
                if k < KINEMATIC:
                    gloc += self.rows.transpose(k, dV)
                elif np.any(dV):
                    _, gq, gdq, gddq = self._effort_vjp(X, kept, dV)
                    G = self.rows.points.transpose(np.stack([gq, gdq, gddq]))
        Gk = self.rows.to_coefficients(gloc)
        G = Gk if G is None else G + Gk
        return dataclasses.replace(pv, grad=G), made

    def _kind(self, k: int, V: np.ndarray | None) -> tuple:
        """Kind k's (g_lo, g_hi, μ_lo, μ_hi, its part of Φ) from its values V (None: not imposed)."""
        gl, gh = self._residual(k, V)
        rw = self.rho * self.rows.weight(k)
        ml = np.maximum(0.0, self.lam_lo[k] + rw * gl)
        mh = np.maximum(0.0, self.lam_hi[k] + rw * gh)
        if np.ndim(rw):  # non-uniform mesh: a weight per row
            part = float(np.sum((ml**2 - self.lam_lo[k] ** 2 + mh**2 - self.lam_hi[k] ** 2) / (2 * rw)))
        else:
            part = float(np.sum(ml**2 - self.lam_lo[k] ** 2 + mh**2 - self.lam_hi[k] ** 2)) / (2 * rw)
        return gl, gh, ml, mh, part

    @cached_property
    def _idle(self) -> dict:
        """``_kind`` of the kinds no joint imposes (the same at every C), kept: {k: (g_lo, g_hi, μ_lo, μ_hi, part)}."""
        return {k: self._kind(k, None) for k in range(len(KINDS)) if not self.working[k].any()}

    def newton_blocks(self, C: np.ndarray, pv: PenaltyValue | None = None) -> np.ndarray:
        """Element blocks (N, 2mn, 2mn) of Φ's (Gauss-Newton) Hessian at C (``pv``: these terms at C, if known)."""
        mesh, n = self.rows.mesh, self.limits.n
        N, m = mesh.N, mesh.m
        pv = self.evaluate(C, grad=False) if pv is None else pv
        _, _, sig = self._bounds
        actives = []
        for k in range(len(KINDS)):
            rw = self.rho * self.rows.weight(k)
            actives.append((self.lam_lo[k] + rw * pv.g_lo[k] > 0) | (self.lam_hi[k] + rw * pv.g_hi[k] > 0))
        # the kinematic kinds' blocks depend on C through the active rows alone: kept for the next call with the same
        key = b"".join(a.tobytes() for a in actives[:KINEMATIC])
        kept = self._kinematic_kept
        if kept and kept[0] == key:
            out = kept[1]
        else:
            blocks = np.zeros((N, 2 * m, n, 2 * m, n))
            for k in range(KINEMATIC):
                if not actives[k].any():
                    continue
                rw = self.rho * self.rows.weight(k)
                c = np.where(actives[k], rw / sig[k] ** 2, 0.0)
                R = self.rows.rows[k]
                W = np.einsum("erj,ra,rb->ejab", c, R, R)  # (N, n, 2m, 2m)
                if self.rows.scale is not None:
                    S = self.rows.scale[k]
                    W = W * (S[:, None, :, None] * S[:, None, None, :])
                for j in range(n):
                    blocks[:, :, j, :, j] += W[:, j]
            out = blocks.reshape(N, 2 * m * n, 2 * m * n)
            out.flags.writeable = False
            self._kinematic_kept[:] = [key, out]
        eff = None
        if actives[EFFORT].any():
            eff = np.where(actives[EFFORT], self.rho * self.rows.weight(EFFORT) / sig[EFFORT] ** 2, 0.0)
        if eff is not None:
            which = np.flatnonzero(eff.any(axis=1))
            X = self._effort_points(C)[:, which]
            _, Jq, Jv, M = self.system.id_derivatives(X[0], X[1], X[2])
            D = np.concatenate([Jq, Jv, M], axis=2)  # (P', n, 3n)
            Hs = np.einsum("pia,pi,pib->pab", D, eff[which], D)
            out = out + self.rows.points.sample_blocks(Hs, which)
        return out


@dataclass(frozen=True, eq=False)
class LimitObjective:
    """``terms`` as an objective term (``hoc_cli.problem``, "Hooks"; ``auglag.Penalized``): Φ with ∂Φ/∂C, its blocks."""

    terms: LimitTerms

    def evaluate(self, C: np.ndarray, grad: bool = True) -> tuple[float, np.ndarray | None]:
        pv = self.terms.evaluate(C, grad=grad)
        return pv.value, pv.grad

    def newton_blocks(self, C: np.ndarray) -> np.ndarray:
        return self.terms.newton_blocks(C)
