"""Clearance certified on the whole continuous trajectory, not only at samples.

For a trajectory q(t) given exactly by its Hermite coefficients, every pair's signed distance d(t)
is Lipschitz on each element e: any point of a primitive p moves at speed at most

    v_p,e = Σ_j max_e |q̇_j| · (R0[p, j] + Σ_k S[p, j, k] max_e |q_k|)        (``reach``)

so d changes at most at the rate V = v_A + v_B (v_B = 0 for an obstacle). On an interval
[t0, t1] of length h with exact values d0 = d(t0) and d1 = d(t1),

    d(t) >= max(d0 − V (t − t0), d1 − V (t1 − t)) >= (d0 + d1 − V h) / 2,

the certified lower bound of the interval. An interval whose bound is below the margin while both
ends are above it is halved (d at the midpoint computed exactly), down to ``max_depth`` halvings;
an interval whose ends are both below the margin is a violation as it stands. The proof that d is
V-Lipschitz for convex solids and rigid motions is in docs/collision.md.

Symbols: N elements, n joints, Q pairs; times in s, distances in m.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from math import comb

import numpy as np

from hoc_cli.collision.evaluate import distances, row_distances
from hoc_cli.collision.robot import reach
from hoc_cli.collision.scene import KIND_SELF, CollisionScene
from hoc_cli.constraints.extrema import element_polynomials, extrema
from hoc_cli.elements import HermiteMesh
from hoc_cli.model.tree import RobotModel

MAX_DEPTH = 16             # halvings of an element at most (h / 65536)
MAX_EVALUATIONS = 2_000_000  # pair-distance evaluations at most; beyond, intervals stay uncertified
SAFETY = 1e-9              # relative slack on the speed bounds (the extrema are exact to rounding)
REFINE_LEAVES = 8          # the intervals with the lowest bounds, resampled to locate the minimum
REFINE_POINTS = 16


@dataclass(frozen=True, eq=False)
class Certificate:
    """The outcome of :func:`certify`.

    margin : m. certified : True when ``lower_bound >= margin`` (proven on the whole trajectory).
    lower_bound : m, a proven lower bound of every pair's signed distance over [0, T] (inf without pairs).
    distance, pair, t : the smallest signed distance evaluated (m), its pair (names) and time (s): an
        attained value, so the true minimum lies in [lower_bound, distance].
    collisions : one dict per pair and time interval where the clearance may be below the margin:
        ``pair`` [a, b], ``interval`` [t0, t1] s, ``distance`` (smallest evaluated, m),
        ``lower_bound`` (m), ``depth`` (penetration max(0, −distance), m), ``certain`` (the distance
        evaluated there is below the margin, not only the bound).
    evaluations : pair-distance evaluations made; speed : (N, Q) the pair speed bounds V, m/s.
    """

    margin: float
    certified: bool
    lower_bound: float
    distance: float
    pair: tuple[str, str] | None
    t: float | None
    collisions: tuple[dict, ...]
    evaluations: int
    speed: np.ndarray

    def summary(self) -> dict:
        """``min_clearance`` and ``collisions`` as the JSON summary reports them."""
        clearance = None if self.pair is None else {
            "distance": self.distance, "pair": list(self.pair), "t": self.t, "lower_bound": self.lower_bound,
            "margin": self.margin, "certified": self.certified}
        return {"min_clearance": clearance, "collisions": [dict(c) for c in self.collisions]}


_REACH: dict = {}  # (id(model), id(geometry)) → (model, geometry, ``reach``'s (R0, S)): constant per robot


def _robot_reach(model: RobotModel, geometry) -> tuple[np.ndarray, np.ndarray]:
    """``robot.reach(model, geometry)``, made once per (model, geometry) pair (read-only arrays)."""
    entry = _REACH.get((id(model), id(geometry)))
    if entry is None or entry[0] is not model or entry[1] is not geometry:
        if len(_REACH) > 16:
            _REACH.clear()
        R0, S = reach(model, geometry)
        R0.flags.writeable = S.flags.writeable = False
        entry = _REACH[(id(model), id(geometry))] = (model, geometry, (R0, S))
    return entry[2]


def _reach_per_element(model: RobotModel, scene: CollisionScene, mesh: HermiteMesh, C: np.ndarray) -> np.ndarray:
    """(N, P, n) bounds on |∂x/∂q_j| for the points x of each primitive on each element (``reach``)."""
    q = extrema(mesh, C, 0)
    qmax = np.maximum(np.abs(q.max), np.abs(q.min)) * (1 + SAFETY)          # (N, n), for prismatic joints
    R0, S = _robot_reach(model, scene.robot)                                 # (P, n), (P, n, n)
    return R0[None] + np.einsum("pjk,ek->epj", S, qmax)


def _speeds(scene: CollisionScene, R: np.ndarray, vmax: np.ndarray, pair: np.ndarray) -> np.ndarray:
    """Pair speed bounds (M,) from reaches R (M, P, n) or (P, n) per row and joint speed bounds vmax (M, n)."""
    prim = scene.prim[pair]
    other = np.where(scene.kind[pair] == KIND_SELF, scene.other[pair], -1)
    rows = np.arange(pair.size)
    V = np.einsum("mj,mj->m", R[rows, prim], vmax)
    both = other >= 0
    V[both] += np.einsum("mj,mj->m", R[rows[both], other[both]], vmax[both])
    return V


def pair_speeds(model: RobotModel, scene: CollisionScene, mesh: HermiteMesh, C: np.ndarray,
                R: np.ndarray | None = None) -> np.ndarray:
    """(N, Q) bounds V on |d/dt| of every pair's signed distance on every element, m/s (module docstring); ``R``:
    ``_reach_per_element`` at C when already made.
    """
    dq = extrema(mesh, C, 1)
    vmax = np.maximum(np.abs(dq.max), np.abs(dq.min)) * (1 + SAFETY)        # (N, n)
    R = _reach_per_element(model, scene, mesh, C) if R is None else R      # (N, P, n)
    N, Q = mesh.N, scene.size
    e, pair = np.repeat(np.arange(N), Q), np.tile(np.arange(Q), N)
    return _speeds(scene, R[e], vmax[e], pair).reshape(N, Q)


@lru_cache(maxsize=8)
def _bernstein(D: int) -> tuple[np.ndarray, np.ndarray]:
    """(C(a, b) (D, D), the power-to-Bernstein map β_i = Σ_k C(i,k)/C(d,k) c_k (D, D)) for D coefficients (d = D − 1);
    read-only, kept.
    """
    j = np.arange(D)
    binom = np.array([[comb(a, b) for b in range(D)] for a in range(D)], dtype=float)  # C(a, b)
    to_bernstein = np.where(j[:, None] >= j[None, :], binom / binom[D - 1][None, :], 0.0)
    binom.flags.writeable = to_bernstein.flags.writeable = False
    return binom, to_bernstein


def velocity_bounds(poly: np.ndarray, e: np.ndarray, s0: np.ndarray, s1: np.ndarray) -> np.ndarray:
    """Bounds (M, n) on |q̇_j| over [s0, s1] ⊂ [0, 1] of elements e (each (M,)), from the power coefficients
    ``poly`` (N, n, D) of q̇ in the local coordinate (``element_polynomials(mesh, C, 1)``).

    The polynomial re-parametrised on the sub-interval, p(s0 + σ(s1 − s0)) for σ ∈ [0, 1], has Bernstein
    coefficients β_i, and |p| <= max_i |β_i| there (the convex-hull property).
    """
    c = poly[e]                                                  # (M, n, D)
    D = c.shape[-1]
    L = (s1 - s0)[:, None]
    j = np.arange(D)
    binom, to_bernstein = _bernstein(D)
    # shifted[k] = Σ_{j >= k} c_j C(j, k) s0^(j−k) L^k
    power = np.where(j[:, None] >= j[None, :], s0[:, None, None] ** np.maximum(j[:, None] - j[None, :], 0), 0.0)
    shift = binom * power * L[:, :, None] ** j[None, None, :]    # (M, D_j, D_k)
    shifted = np.einsum("mij,mjk->mik", c, shift)                # (M, n, D)
    beta = np.einsum("ik,mnk->mni", to_bernstein, shifted)
    return np.abs(beta).max(axis=-1) * (1 + SAFETY)


def certify(model: RobotModel, scene: CollisionScene, mesh: HermiteMesh, C: np.ndarray, *,
            max_depth: int = MAX_DEPTH, max_evaluations: int = MAX_EVALUATIONS) -> Certificate:
    """Prove clearance >= ``scene.margin`` on the whole trajectory, or find where it may fail (module docstring).

    Parameters
    ----------
    model, scene : the robot and the pairs to check.
    mesh, C : the trajectory, Hermite coefficients (N+1, m, n).
    max_depth : halvings of an element at most; max_evaluations : pair distances at most.
    """
    margin = scene.margin
    Q, N = scene.size, mesh.N
    if Q == 0:
        return Certificate(margin, True, np.inf, np.inf, None, None, (), 0, np.zeros((N, 0)))
    nodes = mesh.nodes
    D = distances(model, scene, mesh.evaluate(C, nodes))                    # (N+1, Q)
    R = _reach_per_element(model, scene, mesh, C)                            # (N, P, n)
    V = pair_speeds(model, scene, mesh, C, R)
    poly = element_polynomials(mesh, C, 1)                                   # (N, n, D): q̇ in s
    evaluations = D.size
    e = np.repeat(np.arange(N), Q)
    pair = np.tile(np.arange(Q), N)
    t0, t1 = nodes[e], nodes[e + 1]
    d0, d1 = D[e, pair], D[e + 1, pair]
    speed = V[e, pair]
    depth = np.zeros(e.size, dtype=int)
    best = [float(D.min()), *np.unravel_index(int(np.argmin(D)), D.shape)]
    best_t, best_pair = float(nodes[best[1]]), int(best[2])
    leaves: list[tuple[np.ndarray, ...]] = []
    while True:
        bound = np.minimum((d0 + d1 - speed * (t1 - t0)) / 2, np.minimum(d0, d1))
        ok = bound >= margin
        both = (d0 < margin) & (d1 < margin)
        split = ~ok & ~both & (depth < max_depth)
        if evaluations + int(split.sum()) > max_evaluations:
            split[:] = False
        keep = ~split
        leaves.append((t0[keep], t1[keep], d0[keep], d1[keep], bound[keep], pair[keep]))
        if not split.any():
            break
        t0, t1, d0, d1, speed, pair, depth, e = (x[split] for x in (t0, t1, d0, d1, speed, pair, depth, e))
        tm = (t0 + t1) / 2
        dm = _distances_at(model, scene, mesh, C, tm, pair)
        evaluations += tm.size
        k = int(np.argmin(dm))
        if dm[k] < best[0]:
            best[0], best_t, best_pair = float(dm[k]), float(tm[k]), int(pair[k])
        # each half's speed bound: the parent's, or the Bernstein bound of q̇ on the half if smaller
        start, h = nodes[e], mesh.hs[e]
        s0, sm, s1 = (t0 - start) / h, (tm - start) / h, (t1 - start) / h
        halves = np.concatenate([s0, sm]), np.concatenate([sm, s1])
        ee, pp = np.tile(e, 2), np.tile(pair, 2)
        first, inverse = _distinct(ee, *halves)
        vmax = velocity_bounds(poly, ee[first], halves[0][first], halves[1][first])[inverse]  # rad/s (m/s)
        speed = np.minimum(np.tile(speed, 2), _speeds(scene, R[ee], vmax, pp))
        t0, t1 = np.concatenate([t0, tm]), np.concatenate([tm, t1])
        d0, d1 = np.concatenate([d0, dm]), np.concatenate([dm, d1])
        pair, depth, e = pp, np.tile(depth + 1, 2), ee
    L0, L1, Ld0, Ld1, Lb, Lp = (np.concatenate(x) for x in zip(*leaves))
    # locate the minimum better: resample the intervals with the lowest bounds
    worst = np.argsort(Lb)[:REFINE_LEAVES]
    s = (np.arange(REFINE_POINTS) + 0.5) / REFINE_POINTS
    ts = (L0[worst, None] + s * (L1 - L0)[worst, None]).ravel()
    ps = np.repeat(Lp[worst], REFINE_POINTS)
    dr = _distances_at(model, scene, mesh, C, ts, ps)
    evaluations += ts.size
    if dr.size and dr.min() < best[0]:
        k = int(np.argmin(dr))
        best[0], best_t, best_pair = float(dr[k]), float(ts[k]), int(ps[k])
    lower = float(Lb.min())
    bad = Lb < margin
    collisions = _merge(scene, L0[bad], L1[bad], np.minimum(Ld0, Ld1)[bad], Lb[bad], Lp[bad], margin)
    return Certificate(margin=margin, certified=lower >= margin, lower_bound=lower, distance=best[0],
                       pair=scene.names[best_pair], t=best_t, collisions=collisions, evaluations=int(evaluations),
                       speed=V)


def _distinct(*keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(first, inverse): the index of the first occurrence of each distinct tuple of ``keys`` (each (M,)), in the
    tuples' lexicographic order, and each row's place among them (M,), as ``np.unique(np.stack(keys), axis=1,
    return_index=True, return_inverse=True)`` gives them, by one stable lexicographic sort.
    """
    order = np.lexsort(keys[::-1])
    new = np.ones(order.size, dtype=bool)
    for k in keys:
        sk = k[order]
        new[1:] &= sk[1:] == sk[:-1]
    new = ~new
    new[:1] = True
    group = np.cumsum(new) - 1
    inverse = np.empty(order.size, dtype=int)
    inverse[order] = group
    return order[new], inverse


def _distances_at(model: RobotModel, scene: CollisionScene, mesh: HermiteMesh, C: np.ndarray, t: np.ndarray,
                  pair: np.ndarray) -> np.ndarray:
    """Signed distances (M,) m of pair ``pair[i]`` at time ``t[i]`` (each (M,)): the primitives placed once per
    distinct time (many pairs share an interval's midpoint).
    """
    times, inverse = np.unique(t, return_inverse=True)
    return row_distances(model, scene, mesh.evaluate(C, times), inverse.ravel(), pair)


def _merge(scene: CollisionScene, t0, t1, d, lb, pair, margin: float) -> tuple[dict, ...]:
    """Violating intervals of the same pair of names joined where they touch or overlap, by pair then time."""
    names = [scene.names[p] for p in pair]
    order = sorted(range(len(names)), key=lambda i: (names[i], t0[i]))
    out: list[dict] = []
    for i in order:
        last = out[-1] if out else None
        if last is not None and tuple(last["pair"]) == names[i] and t0[i] <= last["interval"][1]:
            last["interval"][1] = max(last["interval"][1], float(t1[i]))
            last["distance"] = min(last["distance"], float(d[i]))
            last["lower_bound"] = min(last["lower_bound"], float(lb[i]))
        else:
            out.append({"pair": list(names[i]), "interval": [float(t0[i]), float(t1[i])], "distance": float(d[i]),
                        "lower_bound": float(lb[i])})
    for c in out:
        c["depth"] = max(0.0, -c["distance"])
        c["certain"] = c["distance"] < margin
    return tuple(out)
