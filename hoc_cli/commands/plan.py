"""``hoc plan``: being built (see the issue tracker)."""
from __future__ import annotations

from hoc_cli.errors import HocError
from hoc_cli.io.task import apply_overrides, load_task, resolve


def run(task_path, overrides=None, **kwargs) -> int:
    task = apply_overrides(load_task(task_path), **(overrides or {}))
    if task.joints:
        resolve(task, task.joints)
    raise HocError("'hoc plan' is not available in this build yet", file=task.path)
