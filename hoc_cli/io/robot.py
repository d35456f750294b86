"""A task's robot: its URDF read into a ``RobotModel`` with the task's joint selection, locks and gravity.

``load_model`` blames the task's key (``joints``, ``locked.<joint>``, ``gravity``) for a misfit between
the task and the URDF, so the one ``hoc: error:`` line names the task file rather than the URDF.
"""
from __future__ import annotations

from hoc_cli.errors import JointSelectionError, TaskError


def load_model(task, *, urdf_label: str | None = None, task_label: str | None = None):
    """``load_robot`` for a task; a ``joints``/``locked``/``gravity`` misfit blames the task key.

    ``urdf_label`` and ``task_label`` are what messages call the URDF and the task file (default:
    their paths), e.g. ``plan.mcap: attachment robot.urdf`` for a plan's attached files.
    """
    from hoc_cli.model import load_robot

    try:
        return load_robot(task.robot, joints=list(task.joints) if task.joints else None, locked=task.locked,
                          gravity=task.gravity, label=urdf_label)
    except JointSelectionError as exc:
        named = exc.key == exc.task_key or exc.task_key.startswith("locked.")  # the key names the joint
        raise TaskError(exc.detail if named else f"{exc.key}: {exc.detail}",
                        file=task_label or task.path, key=exc.task_key) from None
