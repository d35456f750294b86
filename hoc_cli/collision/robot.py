"""The robot's collision primitives: one capsule (or sphere) per collision shape, in its link frame.

Symbols: P robot primitives, n joints, L URDF links. A link's shapes come from the URDF's
``<collision>`` elements unless the task replaces them (``collision.robot``); links without shapes
are not checked. Each primitive also carries, for the certification, its *reach*: a bound on the
speed of any of its points per unit speed of each joint (:func:`reach`).
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from hoc_cli.collision.geometry import Shape, robot_capsule
from hoc_cli.model.tree import RobotModel


@dataclass(frozen=True, eq=False)
class LinkGeometry:
    """One link's geometry: its shapes as written, the capsules that stand for them (link frame), and
    whether the task replaced the URDF's shapes.
    """

    link: str
    shapes: tuple[Shape, ...]
    capsules: tuple
    from_task: bool

    @property
    def volume(self) -> float:
        """m³ of the shapes as written (meshes: convex hulls), summed."""
        return float(sum(s.volume for s in self.shapes))

    @property
    def capsule_volume(self) -> float:
        """m³ of the capsules, summed."""
        return float(sum(c.volume for c in self.capsules))


@dataclass(frozen=True, eq=False)
class RobotGeometry:
    """Every robot primitive as arrays (P primitives).

    links : (P,) link name of each primitive; link_index : (P,) its index in ``model.link_names``;
    body : (P,) the model body carrying it (-1: the fixed base); a, b : (P, 3) segment ends in the
    link frame, m; radius : (P,) m; per_link : the :class:`LinkGeometry` of every link with geometry.
    """

    links: tuple[str, ...]
    link_index: np.ndarray
    body: np.ndarray
    a: np.ndarray
    b: np.ndarray
    radius: np.ndarray
    per_link: tuple[LinkGeometry, ...]

    @property
    def size(self) -> int:
        """P, the number of primitives."""
        return len(self.links)


def robot_geometry(model: RobotModel, urdf_shapes: Mapping[str, list[Shape]],
                   replaced: Mapping[str, list[Shape]] | None = None) -> RobotGeometry:
    """The primitives of every link of ``model``: ``replaced[link]`` where given, else the URDF's shapes.

    ``replaced`` may name links without URDF geometry; an empty list removes a link's geometry.
    Link names must be links of the model (a KeyError names the first that is not).
    """
    replaced = dict(replaced or {})
    for name in list(urdf_shapes) + list(replaced):
        if name not in model.link_names:
            raise KeyError(name)
    per_link, links, index, body, a, b, radius = [], [], [], [], [], [], []
    for k, name in enumerate(model.link_names):
        from_task = name in replaced
        shapes = tuple(replaced[name] if from_task else urdf_shapes.get(name, ()))
        if not shapes:
            continue
        capsules = tuple(robot_capsule(s) for s in shapes)
        per_link.append(LinkGeometry(link=name, shapes=shapes, capsules=capsules, from_task=from_task))
        for c in capsules:
            links.append(name)
            index.append(k)
            body.append(int(model.link_body[k]))
            a.append(c.a)
            b.append(c.b)
            radius.append(c.radius)
    return RobotGeometry(links=tuple(links), link_index=np.array(index, dtype=int), body=np.array(body, dtype=int),
                         a=np.array(a, dtype=float).reshape(-1, 3), b=np.array(b, dtype=float).reshape(-1, 3),
                         radius=np.array(radius, dtype=float), per_link=tuple(per_link))


def reach(model: RobotModel, geometry: RobotGeometry) -> tuple[np.ndarray, np.ndarray]:
    """Bounds on how fast the points of each primitive move per unit joint speed.

    Returns (R0 (P, n), S (P, n, n)) such that for any configuration q, any point x of primitive p
    and any joint j, |∂x/∂q_j| <= R0[p, j] + Σ_k S[p, j, k] |q_k|.

    For a revolute joint j on the chain root → body(p) (bodies c0 = j, c1, ..., cm = body(p)),
    |∂x/∂q_j| is x's distance from the axis of j, at most |x − o_j| <= Σ_l |o_cl − o_c(l−1)| +
    |x − o_cm|, where o are body-frame origins (on the joint axes). |o_cl − o_c(l−1)| is the length of
    the constant translation of joint cl's frame, plus |q_cl| when cl is prismatic (S); |x − o_cm| is
    at most max(|a|, |b|) + radius in the body frame. A prismatic joint j moves every point at unit
    speed: R0 = 1. Joints not on the chain: 0.
    """
    n = model.n
    P = geometry.size
    R0 = np.zeros((P, n))
    S = np.zeros((P, n, n))
    prismatic = model.is_prismatic
    step = np.linalg.norm(model.tree_transform[:, :3, 3], axis=1)  # |o_i − o_parent(i)| at q_i = 0
    for p in range(P):
        b = int(geometry.body[p])
        if b < 0:
            continue
        offset = model.link_offset[geometry.link_index[p]]
        ends = np.stack([geometry.a[p], geometry.b[p]]) @ offset[:3, :3].T + offset[:3, 3]
        extent = float(np.linalg.norm(ends, axis=1).max() + geometry.radius[p])
        chain = []
        while b >= 0:
            chain.append(b)
            b = int(model.parent[b])
        chain = chain[::-1]  # root first
        for i, j in enumerate(chain):
            if prismatic[j]:
                R0[p, j] = 1.0
                continue
            below = chain[i + 1:]
            R0[p, j] = extent + float(step[below].sum())
            for k in below:
                if prismatic[k]:
                    S[p, j, k] = 1.0
    return R0, S
