"""The pairs hoc checks: robot primitive against robot primitive (self-collision) and against obstacles.

Pairs (Q of them) are ordered: self pairs, then capsule, box and half-space obstacles. A self pair
joins two primitives whose links are neither on the same body (welded by fixed or locked joints)
nor on bodies joined by one joint (adjacent), nor disabled (an SRDF's ``<disable_collisions>`` or
the task's ``ignore``). Primitives on the fixed base are not paired with obstacles (neither moves).
"""
from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from hoc_cli.collision.robot import RobotGeometry
from hoc_cli.collision.shapes import Box, Capsule, HalfSpace
from hoc_cli.model.tree import RobotModel

KIND_SELF, KIND_CAPSULE, KIND_BOX, KIND_HALFSPACE = 0, 1, 2, 3


@dataclass(frozen=True, eq=False)
class Obstacle:
    """A named obstacle in the URDF root frame."""

    name: str
    primitive: Capsule | Box | HalfSpace


@dataclass(frozen=True, eq=False)
class CollisionScene:
    """What is checked, as arrays over the Q pairs.

    robot : the robot's primitives; obstacles : the obstacles (O of them); margin : m, the clearance
    required. prim : (Q,) robot primitive of each pair (shape A); other : (Q,) the robot primitive
    (self pairs) or the obstacle index (shape B); kind : (Q,) ``KIND_*``; names : (Q, 2) the link and
    the link or obstacle of each pair.
    """

    robot: RobotGeometry
    obstacles: tuple[Obstacle, ...]
    margin: float
    prim: np.ndarray
    other: np.ndarray
    kind: np.ndarray
    names: tuple[tuple[str, str], ...]

    @property
    def size(self) -> int:
        """Q, the number of pairs."""
        return int(self.prim.size)


def adjacent_bodies(model: RobotModel, b1: int, b2: int) -> bool:
    """Whether links on bodies b1 and b2 never collide by construction: the same body, or parent and child."""
    if b1 == b2:
        return True
    return (b1 >= 0 and int(model.parent[b1]) == b2) or (b2 >= 0 and int(model.parent[b2]) == b1)


def _kind(primitive) -> int:
    if isinstance(primitive, Capsule):
        return KIND_CAPSULE
    if isinstance(primitive, Box):
        return KIND_BOX
    return KIND_HALFSPACE


def collision_scene(model: RobotModel, robot: RobotGeometry, obstacles: Iterable[Obstacle] = (), *,
                    margin: float = 0.01, self_collision: bool = True,
                    disabled: Iterable[tuple[str, str]] = ()) -> CollisionScene:
    """Every pair to check (see the module docstring). ``disabled``: (name, name) pairs of links or of a
    link and an obstacle, either order.
    """
    obstacles = tuple(obstacles)
    off = {frozenset(p) for p in disabled}
    prim, other, kind, names = [], [], [], []
    if self_collision:
        for i in range(robot.size):
            for j in range(i + 1, robot.size):
                a, b = robot.links[i], robot.links[j]
                if a == b or frozenset((a, b)) in off or adjacent_bodies(model, int(robot.body[i]), int(robot.body[j])):
                    continue
                prim.append(i)
                other.append(j)
                kind.append(KIND_SELF)
                names.append((a, b))
    for want in (KIND_CAPSULE, KIND_BOX, KIND_HALFSPACE):
        for o, obstacle in enumerate(obstacles):
            if _kind(obstacle.primitive) != want:
                continue
            for i in range(robot.size):
                if robot.body[i] < 0 or frozenset((robot.links[i], obstacle.name)) in off:
                    continue
                prim.append(i)
                other.append(o)
                kind.append(want)
                names.append((robot.links[i], obstacle.name))
    return CollisionScene(robot=robot, obstacles=obstacles, margin=float(margin), prim=np.array(prim, dtype=int),
                          other=np.array(other, dtype=int), kind=np.array(kind, dtype=int), names=tuple(names))
