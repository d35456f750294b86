"""A task made ready to solve: what ``hoc plan`` and ``hoc batch`` both do between reading the task and
``hoc_cli.solve``, and after it.

``prepare`` loads the robot, checks that every requested output can be written, resolves the boundary
states, reads the limits (x0/x1 within them when enforced), checks the collision scene and builds the
``OptimalControlProblem`` (``hoc_cli.io.task.problem``), in that order, so both front ends refuse a bad
task with the same ``hoc: error:`` line. The ``Prepared`` it returns gives the solve's options, the
feasibility proof before the solve, the report after it (``plan_report``) and the plan's outputs.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import TYPE_CHECKING, Any

from hoc_cli.io.robot import load_model
from hoc_cli.io.task import resolve
from hoc_cli.io.task.problem import check_jerk_order, problem_from_task, task_limits
from hoc_cli.report.collision import check_boundary_clearance, enforced_problem, task_collision
from hoc_cli.report.files import OutputTarget
from hoc_cli.report.inputs import check_columns, check_sample_times, read_urdf_text
from hoc_cli.report.limits import check_boundary_states, refuse_infeasible, warn_outside_limits

if TYPE_CHECKING:
    from hoc_cli.collision.scene import CollisionScene
    from hoc_cli.constraints.bounds import JointLimits
    from hoc_cli.io.task import ResolvedStates, Task
    from hoc_cli.ocp.problem import OptimalControlProblem
    from hoc_cli.report.summary import PlanReport
    from hoc_cli.strategy import Plan, SolveOptions
    from hoc_cli.system import RobotSystem
    from hoc_cli.trajectory import Trajectory


@dataclass(frozen=True, eq=False)
class Prepared:
    """A task with its robot, states, limits, collision scene and problem, every input check passed.

    ``limits`` are the ``JointLimits`` checked (and imposed on ``problem`` when ``task.limits.mode`` is
    "enforce"); ``collision`` the scene (None when ``collision.mode`` is off) and ``collision_mode`` the
    mode in effect; ``urdf_text`` the URDF document when an MCAP output is asked for, else "".
    """

    task: Task
    model: Any  # hoc_cli.model.RobotModel
    states: ResolvedStates
    limits: JointLimits
    problem: OptimalControlProblem
    collision: CollisionScene | None
    collision_mode: str
    urdf_text: str

    @property
    def enforced(self) -> bool:
        """Whether the limits are imposed on the plan (``limits.mode: enforce``) rather than reported."""
        return self.task.limits.mode == "enforce"

    @cached_property
    def system(self) -> RobotSystem:
        """The robot's dynamics (``hoc_cli.system.RobotSystem``)."""
        from hoc_cli.system import RobotSystem

        return RobotSystem(self.model)

    def refuse_infeasible(self) -> None:
        """With enforced limits, ``Infeasible`` (exit 1) for a task no trajectory within them can meet."""
        if self.enforced:
            refuse_infeasible(self.task, self.system, self.limits, self.states)

    def options(self, *, starts: int, seed: int, **how) -> SolveOptions:
        """The task's solver settings (method, tol, max_iter) with ``starts``, ``seed`` and ``how``
        (``estimate_error``, the callbacks, the starts' client: ``hoc_cli.strategy.SolveOptions``).
        """
        from hoc_cli.strategy import SolveOptions

        task = self.task
        return SolveOptions(method=task.method, tol=task.tol, max_iter=task.max_iter, starts=starts, seed=seed, **how)

    def report(self, planned: Plan, *, seed: int, warm: bool = False) -> PlanReport:
        """``plan_report`` of the solved ``planned`` (``warm``: the solve was warm-started by --init)."""
        from hoc_cli.report.summary import plan_report

        return plan_report(self.task, self.model, planned, self.states, limits=self.limits, collision=self.collision,
                           collision_mode=self.collision_mode, seed=seed, warm=warm)

    def sample(self, reported: PlanReport) -> Trajectory:
        """The reported plan at the task's output rate (``hoc_cli.report.outputs.sample_plan``)."""
        from hoc_cli.report.outputs import sample_plan

        return sample_plan(self.system, reported.result, self.model.joint_names, self.task.rate)

    def write(self, targets: list[OutputTarget], traj: Trajectory, summary: dict, goals, *, scene=None,
              clearance=None) -> list:
        """``write_outputs`` of ``traj`` with the task, its URDF and the reproducible part of ``summary``
        (``scene``, ``clearance``: the MCAP's collision markers and clearance samples, or None); the labels of
        the files written.
        """
        from hoc_cli.report.outputs import summary_metadata, write_outputs
        from hoc_cli.report.summary import reproducible_summary

        return write_outputs(targets, traj, model=self.model, urdf_text=self.urdf_text, task_text=self.task.text,
                             metadata=summary_metadata(reproducible_summary(summary)), goals=goals, scene=scene,
                             clearance=clearance)


def prepare(task: Task, targets: list[OutputTarget], *, starts: int, explicit_collision: bool = False,
            console=None) -> Prepared:
    """``task`` made ready to solve for ``targets``, or the first ``HocError`` of its inputs.

    ``starts``: the number of starts (collision enforcement takes one); ``explicit_collision``: the
    collision mode was given on the command line (``--collision``); ``console``: where the warnings
    about x0/x1 outside the URDF limits go when the limits are reported (None: not warned).
    """
    check_sample_times(targets, task.T if task.time.free is None else task.time.free.max, task.rate, file=task.path)
    model = load_model(task)
    check_columns(targets, model.joint_names)
    urdf_text = read_urdf_text(task.robot) if any(t.kind == "mcap" for t in targets) else ""  # stored in MCAPs
    states = resolve(task, model.joint_names)
    limits = task_limits(model, states.limits)
    enforce = task.limits.mode == "enforce"
    check_jerk_order(task, limits, task.order)
    if enforce:
        check_boundary_states(task, limits, states)
    elif console is not None:
        warn_outside_limits(console, task, model, states)
    scene = task_collision(task, model)  # None: collision.mode off (docs/collision.md)
    check_boundary_clearance(task, model, scene, states)
    problem = problem_from_task(task, model, states, limits if enforce else None)
    problem, mode = enforced_problem(task, model, scene, problem, starts=starts, explicit=explicit_collision,
                                     announce=console is not None)
    return Prepared(task=task, model=model, states=states, limits=limits, problem=problem, collision=scene,
                    collision_mode=mode, urdf_text=urdf_text)
