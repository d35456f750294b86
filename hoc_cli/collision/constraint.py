"""The collision constraint d ≥ bound at points of the mesh, as augmented-Lagrangian (PHR) terms.

Symbols: N elements, m coefficients per node, n joints; P points (``PointSet``: element e, local
s); Q pairs of the scene; M imposed rows, each a (point, pair) with signed distance d_r (m).

The constraint of row r is c_r = bound − d_r ≤ 0 (bound = margin + inflation, m). With the
multiplier λ_r ≥ 0 and the penalty per row ρ_r = ρ·w_r (w_r the time the point stands for, s;
ρ in cost units per m² per s), the Powell-Hestenes-Rockafellar term is

    Φ = Σ_r (max(0, λ_r + ρ_r c_r)² − λ_r²) / (2 ρ_r),     μ_r = max(0, λ_r + ρ_r c_r),

with ∂Φ/∂d_r = −μ_r and the multiplier update λ ← μ (Nocedal & Wright §17.4). The gradient in
the coefficients is Σ_r −μ_r (∂d_r/∂q)ᵀ mapped through the Hermite values at the point
(``PointSet.transpose``); ∂d/∂q is exact through the frame Jacobians (``evaluate.pair_gradient``).
Φ's Hessian on the rows with λ_r + ρ_r c_r > 0 is Σ_r ρ_r ∇d_r ∇d_rᵀ − μ_r ∇²d_r: the first
(Gauss-Newton, positive semi-definite) part is ``newton_blocks``, the second, the distances' own
curvature (``evaluate.pair_hessian``; indefinite), ``curvature_blocks`` (with ``curvature``: the
collision loop asks it on the levels it certifies). Each lies in the element of its point, so the
Newton matrix stays block-banded (``q_blocks``).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from hoc_cli.collision.distance import Contact
from hoc_cli.collision.evaluate import pair_gradient_geometry, pair_hessian, row_distances
from hoc_cli.collision.robot import RobotGeometry, reach
from hoc_cli.collision.scene import KIND_SELF, CollisionScene
from hoc_cli.constraints.points import PointSet
from hoc_cli.model.tree import RobotModel

PRUNE_SLACK = 1e-9    # relative and absolute (m) slack of the test that skips a row (rounding of d0 and the bound)
SPHERE_PADDING = 2e-3  # m: how far the spheres standing for a capsule against obstacles may reach beyond it


def sphere_rows_scene(scene: CollisionScene, padding: float = SPHERE_PADDING) -> CollisionScene:
    """The pairs the penalty imposes: ``scene``'s self pairs as they are, and each capsule–obstacle pair as
    pairs of spheres along the capsule against that obstacle.

    A capsule of length L and radius r is covered by K spheres centred at a + i/(K−1)·(b − a) with radius
    R = √(r² + (L/(2(K−1)))²) (each sphere holds the capsule's slice out to the spacing's half), K the smallest
    with R − r ≤ ``padding``: every sphere pair's distance is at most the capsule's, and at least it minus
    ``padding``. Each sphere's distance to an obstacle is continuously differentiable while its centre is
    outside the obstacle; a capsule's is not where its witness point jumps (a capsule parallel to a box face
    or a capsule: the two ends equally near), and an inner solve whose optimum sits on such a kink crawls.
    The primitives of ``scene`` keep their indices (the self pairs use them); the spheres follow them.
    """
    robot = scene.robot
    P = robot.size
    obstacle_pairs = scene.kind != KIND_SELF
    used = np.unique(scene.prim[obstacle_pairs])
    links, index, body = list(robot.links), list(robot.link_index), list(robot.body)
    a, b, radius = list(robot.a), list(robot.b), list(robot.radius)
    spheres: dict[int, list[int]] = {}
    for p in used:
        r = float(robot.radius[p])
        L = float(np.linalg.norm(robot.b[p] - robot.a[p]))
        half = np.sqrt(padding * (2 * r + padding))      # the half spacing whose R − r is the padding
        K = 1 if L == 0 else max(2, int(np.ceil(L / (2 * half))) + 1)
        R = r if K == 1 else float(np.sqrt(r * r + (L / (2 * (K - 1))) ** 2))
        spheres[int(p)] = []
        for i in range(K):
            c = robot.a[p] + (i / max(K - 1, 1)) * (robot.b[p] - robot.a[p])
            spheres[int(p)].append(len(links))
            links.append(robot.links[p])
            index.append(robot.link_index[p])
            body.append(robot.body[p])
            a.append(c)
            b.append(c)
            radius.append(R)
    prim, other, kind, names = [], [], [], []
    for k in range(scene.size):
        targets = [int(scene.prim[k])] if not obstacle_pairs[k] else spheres[int(scene.prim[k])]
        for t in targets:
            prim.append(t)
            other.append(int(scene.other[k]))
            kind.append(int(scene.kind[k]))
            names.append(scene.names[k])
    geometry = RobotGeometry(links=tuple(links), link_index=np.array(index, dtype=int), body=np.array(body, dtype=int),
                             a=np.array(a, dtype=float).reshape(-1, 3), b=np.array(b, dtype=float).reshape(-1, 3),
                             radius=np.array(radius, dtype=float), per_link=robot.per_link)
    assert geometry.size >= P
    return CollisionScene(robot=geometry, obstacles=scene.obstacles, margin=scene.margin,
                          prim=np.array(prim, dtype=int), other=np.array(other, dtype=int),
                          kind=np.array(kind, dtype=int), names=tuple(names))


def group_sum(index: np.ndarray, values: np.ndarray, size: int) -> np.ndarray:
    """(size, ...) the sums of ``values`` (M, ...) by ``index`` (M,) in [0, size) (``np.add.at`` into zeros, by one
    sort and ``np.add.reduceat``: a fraction of its time on these small arrays).
    """
    out = np.zeros((size,) + values.shape[1:])
    if index.size == 0:
        return out
    order = np.argsort(index, kind="stable")
    idx = index[order]
    starts = np.flatnonzero(np.concatenate([[True], idx[1:] != idx[:-1]]))
    out[idx[starts]] = np.add.reduceat(values[order], starts, axis=0)
    return out


def q_blocks(points: PointSet, Hq: np.ndarray, which: np.ndarray) -> np.ndarray:
    """Element blocks (N, 2mn, 2mn) of per-point Hessians Hq (P', n, n) in q alone at the points ``which`` (P',):
    ``PointSet.sample_blocks`` of (3n, 3n) Hessians whose q̇ and q̈ rows and columns are zero, without them.
    """
    mesh = points.mesh
    N, m, n = mesh.N, mesh.m, Hq.shape[-1]
    B = points.B[0, which]                                               # (P', 2m)
    per = (B[:, :, None, None, None] * Hq[:, None, :, None, :]) * B[:, None, None, :, None]  # (P', 2m, n, 2m, n)
    return group_sum(points.e[which], per, N).reshape(N, 2 * m * n, 2 * m * n)


def point_configurations(points: PointSet, C: np.ndarray) -> np.ndarray:
    """The configurations q (P, n) at the points for coefficients C (N+1, m, n)."""
    loc = points.mesh.local_coefficients(points.mesh.check_coefficients(C))[points.e]  # (P, 2m, n)
    return np.einsum("pa,pan->pn", points.B[0], loc)


@dataclass(frozen=True, eq=False)
class RowStart:
    """Where an inner solve starts, for skipping rows that cannot reach their bound (``CollisionTerms``).

    q0 : (P, n) the configurations at the points; d0 : (M,) m the rows' distances there; reach : (M, n) m per
    rad, per row the sum over its moving primitives of ``robot.reach``'s R0 (revolute joints only: a row of a
    primitive moved by a prismatic joint is never skipped, reach = inf).
    """

    q0: np.ndarray
    d0: np.ndarray
    reach: np.ndarray


def row_reach(model: RobotModel, scene: CollisionScene, pairs: np.ndarray) -> np.ndarray:
    """(M, n) m per rad: the ``RowStart.reach`` of the rows of ``pairs`` (M,)."""
    R0, S = reach(model, scene.robot)
    moved_by_slide = S.any(axis=(1, 2)) | (R0[:, np.asarray(model.is_prismatic, dtype=bool)] > 0).any(axis=1)
    R = np.where(moved_by_slide[:, None], np.inf, R0)                          # (P, n)
    out = R[scene.prim[pairs]]
    self_rows = scene.kind[pairs] == KIND_SELF
    out[self_rows] += R[scene.other[pairs[self_rows]]]
    return out


@dataclass(frozen=True, eq=False)
class CollisionTerms:
    """Φ for one inner minimisation (fixed rows, λ and ρ): see the module docstring.

    model, scene : the robot and the pairs; points : where the rows sit; rows, pairs : (M,) the
    point and the pair of each row; lam : (M,) ≥ 0; rho : cost units / (m²·s); bound : m.

    start (optional): the rows' distances where the inner solve starts. Any point of a primitive moves at
    most Σ_j R0_j |q_j − q0_j| from q0 to q (``robot.reach``; the straight path in joint space), so a row
    with λ = 0 and d0 − Σ_j reach_j |q_j − q0_j| ≥ bound has d ≥ bound at q: μ = 0, and it adds nothing
    to Φ, its gradient or its curvature. Such rows are not evaluated (their distance is reported as +inf).
    Each row's bound starts from where it was last evaluated: an evaluated row's (q, d) there replaces its
    (q0, d0) (the line search's trials lie near the last ones), while the rows skipped keep theirs.

    curvature : whether ``curvature_blocks`` gives −Σ μ_r ∇²d_r (else None: the Gauss-Newton matrix alone).
    """

    model: RobotModel
    scene: CollisionScene
    points: PointSet
    rows: np.ndarray
    pairs: np.ndarray
    lam: np.ndarray
    rho: float
    bound: float
    start: RowStart | None = None
    curvature: bool = False
    _last: list = field(default_factory=list, repr=False)  # [C, d, ∂d/∂q, placed] of the last gradient evaluation
    _anchor: list = field(default_factory=list, repr=False)  # [q (M, n), d (M,)]: where each row was last evaluated

    @cached_property
    def _row_groups(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``group_sum``'s grouping of the rows by point: (the stable sort of ``rows``, each group's start in it, its
        point).
        """
        order = np.argsort(self.rows, kind="stable")
        idx = self.rows[order]
        starts = np.flatnonzero(np.concatenate([[True], idx[1:] != idx[:-1]]))
        return order, starts, idx[starts]

    @cached_property
    def _used(self) -> tuple[np.ndarray, np.ndarray]:
        """(the points the rows use (U,), each row's index among them (M,))."""
        return np.unique(self.rows, return_inverse=True)

    def _gradient(self, C: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(d (M,), ∂d/∂q (M, n)) of the rows at C; the Newton matrix at the point just evaluated reuses them."""
        if self._last and np.array_equal(self._last[0], C):
            return self._last[1], self._last[2]
        q = point_configurations(self.points, C)
        used, inverse = self._used
        live = self._live(q)
        if live is None:
            d, dd, placed = pair_gradient_geometry(self.model, self.scene, q[used], inverse, self.pairs)
            placed = None if placed is None else (placed[0], inverse, np.arange(self.rows.size), placed[1])
        else:
            d, dd = np.full(self.rows.size, np.inf), np.zeros((self.rows.size, C.shape[-1]))
            placed = None
            if live.any():  # only the configurations the live rows use are placed
                at, local = np.unique(inverse[live], return_inverse=True)
                d[live], dd[live], got = pair_gradient_geometry(self.model, self.scene, q[used[at]], local, self.pairs[live])
                if got is not None:  # per row: its sample in the poses, its index in the contacts (−1: not placed)
                    sample, where = np.full(self.rows.size, -1), np.full(self.rows.size, -1)
                    sample[live], where[live] = local, np.arange(local.size)
                    placed = (got[0], sample, where, got[1])
        self._anchor_at(q, d, live)
        self._last[:] = [np.array(C), d, dd, placed]
        return d, dd

    def _placed(self, C: np.ndarray, on: np.ndarray) -> tuple[np.ndarray, np.ndarray, Contact] | None:
        """For the rows ``on`` (evaluated at C, the last gradient evaluation): (body poses T (K, n+1, 4, 4), each
        row's sample in T (len(on),), their contacts), as ``_gradient`` placed them; None when not kept.
        """
        if not (self._last and np.array_equal(self._last[0], C)) or self._last[3] is None:
            return None
        T, sample, where, c = self._last[3]
        k = where[on]
        return T, sample[on], Contact(distance=c.distance[k], normal=c.normal[k], point_a=c.point_a[k],
                                      point_b=c.point_b[k])

    def _anchor_at(self, q: np.ndarray, d: np.ndarray, live: np.ndarray | None) -> None:
        """The rows ``live`` (None: every row) were evaluated at configurations q (P, n) of the points, their distances
        in d (M,): each one's next moves are bounded from here.
        """
        if self.start is None:
            return
        if not self._anchor:  # per row: the configuration at its point (M, n) and its distance there (M,)
            self._anchor[:] = [self.start.q0[self.rows].copy(), self.start.d0.copy()]
        q_anchor, d_anchor = self._anchor
        if live is None:
            q_anchor[:], d_anchor[:] = q[self.rows], d
        else:
            q_anchor[live], d_anchor[live] = q[self.rows[live]], d[live]

    def _live(self, q: np.ndarray) -> np.ndarray | None:
        """(M,) bool: the rows that may reach their bound at configurations q (P, n) of the points, from where each was
        last evaluated (None: every row).
        """
        if self.start is None:
            return None
        if self._anchor:
            q_anchor, d_anchor = self._anchor
        else:
            q_anchor, d_anchor = self.start.q0[self.rows], self.start.d0
        with np.errstate(invalid="ignore"):  # inf · 0 (a prismatic joint that did not move): NaN, kept as a live row
            move = np.einsum("mj,mj->m", self.start.reach, np.abs(q[self.rows] - q_anchor))
        move = np.where(np.isnan(move), np.inf, move)
        live = (self.lam > 0) | (d_anchor - move * (1 + PRUNE_SLACK) - PRUNE_SLACK < self.bound)
        return None if live.all() else live

    @cached_property
    def rho_rows(self) -> np.ndarray:
        """ρ_r = ρ·w_r (M,), cost units / m²."""
        return self.rho * self.points.weight[self.rows]

    def multipliers(self, d: np.ndarray) -> np.ndarray:
        """μ (M,) for distances d (M,) of the rows."""
        return np.maximum(0.0, self.lam + self.rho_rows * (self.bound - d))

    def distances(self, C: np.ndarray) -> np.ndarray:
        """Distances d (M,) m of the rows at coefficients C (+inf for a row ``start`` shows cannot reach its bound)."""
        if self.rows.size == 0:
            return np.zeros(0)
        used, inverse = self._used
        q = point_configurations(self.points, C)
        live = self._live(q)
        if live is None:
            d = row_distances(self.model, self.scene, q[used], inverse, self.pairs)
        else:
            d = np.full(self.rows.size, np.inf)
            if live.any():
                at, local = np.unique(inverse[live], return_inverse=True)
                d[live] = row_distances(self.model, self.scene, q[used[at]], local, self.pairs[live])
        self._anchor_at(q, d, live)
        return d

    def evaluate(self, C: np.ndarray, grad: bool = True) -> tuple[float, np.ndarray | None]:
        """(Φ, ∂Φ/∂C (N+1, m, n) or None) at coefficients C (N+1, m, n)."""
        if self.rows.size == 0:
            return 0.0, (np.zeros_like(C) if grad else None)
        if grad:
            d, dd = self._gradient(C)
        else:
            d = self.distances(C)
        rr = self.rho_rows
        mu = self.multipliers(d)
        value = float(np.sum((mu ** 2 - self.lam ** 2) / (2 * rr)))
        if not grad:
            return value, None
        order, starts, ids = self._row_groups
        Gq = np.zeros((self.points.size, dd.shape[-1]))
        Gq[ids] = np.add.reduceat((-mu[:, None] * dd)[order], starts, axis=0)  # ``group_sum`` by point, its sort kept
        at = np.unique(self.rows[mu > 0])  # points without a row of μ > 0 add nothing
        return value, self.points.transpose_q(Gq[at], at)

    def step_rows(self, C: np.ndarray, dC: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The rows' PHR arguments along C + α dC (dC (N+1, m, n)), linearised (``step.model_step``): (a (M,) =
        λ/ρ_r + bound − d in m, b (M,) = −∂d/∂α in m, ρ_r (M,)); rows skipped at C (d = +inf) have a = −inf.
        """
        d, dd = self._gradient(C)
        rr = self.rho_rows
        dq = point_configurations(self.points, dC)
        with np.errstate(invalid="ignore"):
            a = self.lam / rr + self.bound - d
        b = np.zeros(self.rows.size)
        on = np.flatnonzero(np.isfinite(d))  # rows skipped at C take no part in the step's model
        b[on] = -np.einsum("mj,mj->m", dd[on], dq[self.rows[on]])
        return a, b, rr

    def curvature_blocks(self, C: np.ndarray) -> np.ndarray | None:
        """Element blocks (N, 2mn, 2mn) of −Σ_r μ_r ∇²d_r over the rows with μ_r > 0 and d_r > 0 at C (None without
        ``curvature`` or such rows): the part of Φ's Hessian the Gauss-Newton matrix leaves out, where a contact is
        an edge, a corner or two capsules, and the kinematics' own curvature (``evaluate.pair_hessian``; indefinite).
        """
        if not self.curvature or self.rows.size == 0:
            return None
        d, _ = self._gradient(C)
        mu = self.multipliers(d)
        on = np.flatnonzero((mu > 0) & (d > 0))
        if on.size == 0:
            return None
        used, inverse = self._used
        placed = self._placed(C, on)
        if placed is None:
            q = point_configurations(self.points, C)[used]
            H = pair_hessian(self.model, self.scene, q, inverse[on], self.pairs[on])
        else:  # the poses and contacts of the gradient at C
            T, sample, c = placed
            H = pair_hessian(self.model, self.scene, None, sample, self.pairs[on], placed=(T, c))
        Hq = group_sum(inverse[on], -mu[on, None, None] * H, used.size)
        which = np.unique(inverse[on])
        return q_blocks(self.points, Hq[which], used[which])

    def newton_blocks(self, C: np.ndarray) -> np.ndarray:
        """Element blocks (N, 2mn, 2mn) of Φ's Gauss-Newton Hessian at C."""
        mesh, n = self.points.mesh, C.shape[-1]
        size = 2 * mesh.m * n
        if self.rows.size == 0:
            return np.zeros((mesh.N, size, size))
        used, inverse = self._used
        d, dd = self._gradient(C)
        rr = self.rho_rows
        on = self.lam + rr * (self.bound - d) > 0
        if not on.any():
            return np.zeros((mesh.N, size, size))
        Hq = group_sum(inverse[on], rr[on, None, None] * dd[on, :, None] * dd[on, None, :], used.size)
        which = np.flatnonzero(np.abs(Hq).sum(axis=(1, 2)) > 0)
        return q_blocks(self.points, Hq[which], used[which])
