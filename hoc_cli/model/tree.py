"""The frozen kinematic tree that the dynamics kernels read: plain numpy arrays, no URDF objects.

A model has n *bodies*, one per movable joint. Body i is the child link of joint i together with
every link attached below it through fixed or locked joints (their inertias merged into one). Links
attached to the root through fixed or locked joints form the fixed base (body -1) and never move.

Each body frame is the URDF child-link frame of its joint rotated by a constant rotation so that the
joint axis is the body's local z axis. Joint i then reads

    pose of body i in body parent[i] = tree_transform[i] @ J_i(q_i)

with ``J_i`` a rotation about z by q_i (revolute, continuous; rad) or a translation along z by q_i
(prismatic; m). Shapes: n joints, L URDF links.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

JOINT_TYPES = ("revolute", "continuous", "prismatic")


@dataclass(frozen=True, eq=False)
class RobotModel:
    """A fixed-base rigid-body tree ready for batched dynamics (SI units).

    Attributes
    ----------
        name: robot name from the URDF.
        joint_names: (n,) movable joints in model order (= task order; sample arrays ``(K, n)``
            use this column order).
        joint_types: (n,) ``'revolute' | 'continuous' | 'prismatic'``.
        parent: (n,) int, model index of the parent body of body i, -1 for the fixed base. Not
            necessarily ``< i`` (model order is the user's order); traverse with ``order``.
        order: (n,) int, a topological order of the bodies (every parent before its children).
        axis: (n, 3) unit joint axes in the URDF child-link frame (as written, normalised).
        tree_transform: (n, 4, 4) constant pose of joint i's aligned frame in its parent body frame.
        tree_motion: (n, 6, 6) Plücker transform of ``tree_transform`` (parent body → joint frame).
        inertia: (n, 6, 6) spatial inertia of each merged body about its frame origin, body axes.
        body_mass: (n,) kg, mass of each merged body.
        lower, upper: (n,) position limits (rad or m); -inf/+inf where the URDF gives none
            (continuous joints, or no ``<limit>``).
        velocity_limit, effort_limit: (n,) rad/s or m/s, N·m or N; inf where the URDF gives none.
        gravity: (3,) m/s² in the root-link frame.
        urdf_path: the file the model was read from.
        total_mass: kg, every URDF link's mass summed (fixed base included).
        root_link: name of the URDF root link (the frame of every pose and of ``gravity``).
        link_names: (L,) every URDF link, in document order.
        link_body: (L,) int, body that carries each link (-1: the fixed base).
        link_offset: (L, 4, 4) constant pose of each link frame in its body frame.
        locked: name → value (rad or m) of every movable URDF joint that was locked.
    """

    name: str
    joint_names: tuple[str, ...]
    joint_types: tuple[str, ...]
    parent: np.ndarray
    order: np.ndarray
    axis: np.ndarray
    tree_transform: np.ndarray
    tree_motion: np.ndarray
    inertia: np.ndarray
    body_mass: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    velocity_limit: np.ndarray
    effort_limit: np.ndarray
    gravity: np.ndarray
    urdf_path: str
    total_mass: float
    root_link: str
    link_names: tuple[str, ...]
    link_body: np.ndarray
    link_offset: np.ndarray
    locked: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        for name, value in vars(self).items():
            if isinstance(value, np.ndarray):
                value.flags.writeable = False

    @property
    def n(self) -> int:
        """Number of movable joints (degrees of freedom)."""
        return len(self.joint_names)

    @property
    def is_prismatic(self) -> np.ndarray:
        """(n,) bool, True for prismatic joints."""
        return np.array([t == "prismatic" for t in self.joint_types], dtype=bool)

    def index(self, joint: str) -> int:
        """Model index of a movable joint; ``KeyError`` naming the valid joints otherwise."""
        try:
            return self.joint_names.index(joint)
        except ValueError:
            raise KeyError(f"no movable joint {joint!r}; joints are {list(self.joint_names)}") from None

    def with_gravity(self, gravity) -> "RobotModel":
        """A copy of the model with another gravity vector (3,) m/s² in the root frame."""
        g = np.array(gravity, dtype=float).reshape(3)
        values = {k: v for k, v in vars(self).items()}
        values["gravity"] = g
        return RobotModel(**values)
