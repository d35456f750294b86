"""The optimal-control problem as one frozen object: what ``hoc_cli.solve`` and every driver take.

Symbols and units
-----------------
n joints; q [rad or m], q̇ [rad/s or m/s]; T [s]; N elements of a Hermite ``order`` ("cubic" or
"quintic"). The problem is

    min over q(t)   J = ∫₀ᵀ L(q, q̇, q̈) dt  (+ weight·T with a free T)
    subject to      q(0) = q0, q̇(0) = dq0,
                    at T: the joint goal (q1, dq1), or a link goal (a ``FrameResidual``),
                    at fractions s of T: the vias (``GoalPoint`` rows),
                    on [0, T]: the joint limits (``JointLimits``; None: not enforced),
                    and ``constraint`` (e.g. collision avoidance; None: none).

L is the covariant effort ½ uᵀM⁻¹u (``cost="covariant"``) or ½|u|² (``"torque"``), u the inverse
dynamics of ``system``. Time is ``Fixed(T)`` or ``Free(min, max, weight, guess)``: one
representation, whatever the solver. ``N=None`` asks for ``N: auto`` (the mesh refined until the
estimated relative error of J is at most ``accuracy``).

Build one with ``OptimalControlProblem(...)`` directly, or from a task file with
``hoc_cli.io.task.problem_from_task``; goals from Python with ``link_goal`` and ``joint_via`` /
``link_via`` (``hoc_cli.ocp.goals``).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from hoc_cli.constraints.bounds import JointLimits

if TYPE_CHECKING:  # the goal modules load with a goal (``goals()``): a joint goal in a fixed T needs none
    from hoc_cli.goals.plan import Goals
    from hoc_cli.goals.residuals import FrameResidual
    from hoc_cli.goals.terms import GoalPoint

COSTS = ("covariant", "torque")
ORDERS = ("cubic", "quintic")


@dataclass(frozen=True)
class Fixed:
    """A fixed duration T > 0 [s]."""

    T: float

    def __post_init__(self) -> None:
        if not (np.isfinite(self.T) and self.T > 0):
            raise ValueError(f"T must be a finite duration > 0 s, got {self.T!r}")


@dataclass(frozen=True)
class Free:
    """A free final time in [min, max] [s], priced at ``weight`` per second of duration (J + weight·T);
    ``guess`` [s] starts the search (default the geometric mean of min and max).
    """

    min: float
    max: float
    weight: float = 0.0
    guess: float | None = None

    def __post_init__(self) -> None:
        if not (0 < self.min < self.max < np.inf):
            raise ValueError(f"a free T needs 0 < min < max < inf, got [{self.min!r}, {self.max!r}]")
        if self.guess is not None and not self.min <= self.guess <= self.max:
            raise ValueError(f"the guess T = {self.guess!r} s lies outside [{self.min!r}, {self.max!r}]")

    @property
    def start(self) -> float:
        """Where the search starts [s]."""
        return self.guess if self.guess is not None else (self.min * self.max) ** 0.5


@dataclass(frozen=True, eq=False)
class OptimalControlProblem:
    """One planning problem (module docstring). Arrays are (n,) in the system's joint order.

    system : the dynamics (``hoc_cli.RobotSystem`` for a URDF; link goals need one)
    q0, dq0 : the start state; q1, dq1 : the joint goal at T (None with ``link_goal``)
    time : ``Fixed(T)`` or ``Free(min, max, weight, guess)``
    N : elements (None: ``N: auto``, refined to ``accuracy``); order : "cubic" | "quintic"
    cost : "covariant" | "torque"; limits : enforced joint limits, or None (the unconstrained problem)
    link_goal : the pose (and, for a moving target, the velocity) a link must reach at T
    final_dq : with a link goal, "zero" (rest at T) or "free"
    vias : rows to meet at fractions s of T (``hoc_cli.ocp.goals.joint_via``, ``link_via``)
    accuracy : the target relative error of J for ``N=None`` (None: the default)
    constraint : a further constraint imposed by an outer loop of its own around each solve (None:
        none), e.g. ``hoc_cli.collision.enforce.CollisionConstraint``; a fixed T and N only
    """

    system: object
    q0: np.ndarray
    dq0: np.ndarray
    time: Fixed | Free
    q1: np.ndarray | None = None
    dq1: np.ndarray | None = None
    N: int | None = 16
    order: str = "quintic"
    cost: str = "covariant"
    limits: JointLimits | None = None
    link_goal: FrameResidual | None = None
    final_dq: str = "zero"
    vias: tuple[GoalPoint, ...] = field(default_factory=tuple)
    accuracy: float | None = None
    constraint: object | None = None

    def __post_init__(self) -> None:
        n = self.system.n
        for name in ("q0", "dq0", "q1", "dq1"):
            v = getattr(self, name)
            if v is None:
                continue
            a = np.array(v, dtype=float).reshape(-1)
            if a.shape != (n,) or not np.all(np.isfinite(a)):
                raise ValueError(f"{name} must be {n} finite numbers (one per joint), got {v!r}")
            object.__setattr__(self, name, a)
        if (self.q1 is None) == (self.link_goal is None):
            raise ValueError("give exactly one goal at T: a joint state (q1, dq1) or a link goal")
        if self.q1 is not None and self.dq1 is None:
            object.__setattr__(self, "dq1", np.zeros(n))
        if self.order not in ORDERS or self.cost not in COSTS:
            raise ValueError(f"order must be one of {ORDERS} and cost one of {COSTS}")
        if self.N is not None and not (isinstance(self.N, (int, np.integer)) and self.N >= 1):
            raise ValueError(f"N must be an integer >= 1 or None (auto), got {self.N!r}")
        if self.has_goals and self.N is None:
            raise ValueError("goals (a link goal, vias or a free T) need a fixed number of elements N")
        object.__setattr__(self, "vias", tuple(self.vias))

    @property
    def n(self) -> int:
        return self.system.n

    @property
    def T(self) -> float:
        """The duration [s]: the fixed T, or where a free T's search starts."""
        return self.time.T if isinstance(self.time, Fixed) else self.time.start

    @property
    def free_time(self) -> Free | None:
        return self.time if isinstance(self.time, Free) else None

    @property
    def has_goals(self) -> bool:
        """Whether the problem needs the goal solvers: a link goal, vias or a free T."""
        return self.link_goal is not None or bool(self.vias) or isinstance(self.time, Free)

    def goals(self) -> Goals | None:
        """The goal rows as the goal solvers take them (None: a joint goal in a fixed T).

        A link goal's final state for the initial trajectory comes from inverse kinematics at T (from
        q0, within the position limits); with ``match_velocity`` its q̇ is the least-squares joint rate
        of the target's velocity, scaled down into the velocity limits where it breaks them.
        """
        if not self.has_goals:
            return None
        from hoc_cli.goals.plan import Goals, inverse_kinematics

        if self.link_goal is None:
            return Goals(q1=self.q1, dq1=self.dq1, vias=self.vias)
        from hoc_cli.dynamics import frame_jacobian

        model = self.system.model
        g = self.link_goal
        q1 = inverse_kinematics(g, self.q0, self.T, model.lower, model.upper)
        dq1 = None
        if g.match_velocity:
            dq1 = np.linalg.pinv(frame_jacobian(model, q1, g.link)[:3]) @ g.target(self.T)[1]
            if self.limits is not None:  # a guess beyond the velocity limits starts the solve infeasible: scaled in
                with np.errstate(divide="ignore", invalid="ignore"):
                    over = np.max(np.where(np.isfinite(self.limits.velocity), np.abs(dq1) / self.limits.velocity, 0.0))
                if over > 1.0:
                    dq1 = dq1 / over
        return Goals(final=g, final_dq=self.final_dq, vias=self.vias, q1_guess=q1, dq1_guess=dq1)
