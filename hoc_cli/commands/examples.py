"""``hoc examples [NAME]``: list the example tasks shipped with hoc, or copy one with its robot.

Without NAME: one line per example on standard output (name, robot, description). With NAME:
``NAME.yaml`` and its robot's URDF are written into ``--dir`` (default: the current directory), the
task's ``robot:`` naming the URDF beside it, so that ``hoc plan NAME.yaml`` works at once. An
existing file is never replaced without ``--force``; both files are written, or neither.
"""
from __future__ import annotations

import sys
from pathlib import Path

from hoc_cli.commands.common import EXIT_OK
from hoc_cli.errors import HocError, OutputError
from hoc_cli.report.console import stderr_console
from hoc_cli.report.files import atomic_output, output_transaction


def run(name: str | None, directory: Path = Path("."), *, force: bool = False, quiet: bool = False) -> int:
    from hoc_cli.examples import examples, find

    shipped = examples()
    if not shipped:
        raise HocError("no example tasks found in the installed package (a broken install? reinstall hoc)",
                       key="examples")
    if name is None:
        width = max(len(e.name) for e in shipped)
        robots = max(len(e.robot) for e in shipped)
        for e in shipped:
            sys.stdout.write(f"{e.name:<{width}}  {e.robot:<{robots}}  {e.description}\n")
        sys.stdout.flush()
        return EXIT_OK
    example = find(name)
    if example is None:
        raise HocError(f"no example called {name!r} (expected one of: {', '.join(e.name for e in shipped)}; "
                       "'hoc examples' lists them)", key="NAME")
    directory = Path(directory)
    if directory.exists() and not directory.is_dir():
        raise OutputError("is not a directory (expected the folder to copy the example into)", file=directory, key="--dir")
    try:
        directory.mkdir(parents=True, exist_ok=True)  # a new folder, as `git clone URL DIR` makes one
    except OSError as exc:
        raise OutputError(f"cannot be created ({exc.strerror or type(exc).__name__}; expected a folder to copy "
                          "the example into)", file=directory, key="--dir") from None
    task_path, robot_path = directory / f"{example.name}.yaml", directory / example.robot
    if not force:
        for path in (task_path, robot_path):
            if path.exists():
                raise OutputError("exists; hoc examples never replaces a file (expected --force, or another --dir)",
                                  file=path, key="--dir")
    with output_transaction():  # both files, or neither
        for path, text in ((task_path, example.text_beside_robot()), (robot_path, example.robot_text())):
            with atomic_output(path) as fh:
                fh.write(text.encode("utf-8"))
    stderr_console(quiet=quiet).print(
        f"wrote {task_path} and {robot_path}; plan it with: hoc plan {task_path}",
        highlight=False, markup=False, soft_wrap=True)
    return EXIT_OK
