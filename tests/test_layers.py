"""The package's layers, read from the source (docs/design.md, "Layers").

Maths modules (elements, dynamics, problem, constraints, solvers, drivers, goals, simulator) never
import the CLI, the terminal or file formats (``commands/``, ``io/``, ``batch/``, ``report/``, ``cli``,
``plotting``), not even inside a function; ``report/`` (what ``hoc plan`` and ``hoc batch`` both
report and write) imports neither front end (``commands/``, ``batch/``, ``cli``), and ``batch/``
imports nothing from ``commands/``; no module imports another module's private name (the
private modules of a package, such as ``dynamics/_passes``, share theirs within it); maths
modules do not print and build no ``SimpleNamespace`` stand-ins; and a plain ``hoc plan -o none -q`` loads
nothing it does not use (scipy.optimize, Dask, pyarrow, matplotlib, pydantic through typer, rich, the
file writers, the simulator).
"""
from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "hoc_cli"
OUTER = ("hoc_cli.commands", "hoc_cli.io", "hoc_cli.batch", "hoc_cli.report", "hoc_cli.cli", "hoc_cli.plotting",
         "hoc_cli.examples")
#: what a package of the front ends may not import (not even inside a function): the layer above it or beside it
FORBIDDEN = {
    "hoc_cli.report": ("hoc_cli.commands", "hoc_cli.batch", "hoc_cli.cli"),
    "hoc_cli.batch": ("hoc_cli.commands", "hoc_cli.cli"),
}


def module_name(path: Path) -> str:
    parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def within(name: str, packages) -> bool:
    return any(name == o or name.startswith(o + ".") for o in packages)


def is_outer(name: str) -> bool:
    return within(name, OUTER)


MODULES = {module_name(p): ast.parse(p.read_text(encoding="utf-8")) for p in sorted(PACKAGE.rglob("*.py"))}
PACKAGES = {module_name(p) for p in PACKAGE.rglob("__init__.py")}
MATHS = sorted(m for m in MODULES if not is_outer(m) and m != "hoc_cli")


def imports(tree: ast.AST, here: str):
    """(module imported, names taken) for every import statement, module level or inside functions."""
    package = here if here in PACKAGES else here.rsplit(".", 1)[0]
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                yield a.name, ()
        elif isinstance(node, ast.ImportFrom):
            mod = node.module or ""
            if node.level:  # relative: resolve against this module's package
                base = package.rsplit(".", node.level - 1)[0] if node.level > 1 else package
                mod = f"{base}.{mod}" if mod else base
            yield mod, tuple(a.name for a in node.names)


def test_the_layer_checks_see_the_modules_they_are_about():
    assert {"hoc_cli.planner", "hoc_cli.constraints.penalty", "hoc_cli.goals.replan"} <= set(MATHS)
    assert "hoc_cli.commands.plan" in MODULES and not set(MATHS) & {"hoc_cli.commands.plan", "hoc_cli.io.mcap"}


@pytest.mark.parametrize("module", MATHS)
def test_a_maths_module_imports_nothing_from_the_cli_or_file_layers(module):
    bad = [mod for mod, _ in imports(MODULES[module], module) if is_outer(mod)]
    assert bad == [], f"{module} imports {bad}"


def reaching_across(module: str, tree: ast.AST) -> list[str]:
    """The imports of ``module`` that ``FORBIDDEN`` refuses (e.g. ``batch/`` taking a name from ``commands/``)."""
    refused = [bad for package, bad in FORBIDDEN.items() if within(module, (package,))]
    return [mod for mod, _ in imports(tree, module) for bad in refused if within(mod, bad)]


@pytest.mark.parametrize("module", sorted(m for m in MODULES if within(m, FORBIDDEN)))
def test_batch_imports_nothing_from_commands_and_report_neither_front_end(module):
    assert reaching_across(module, MODULES[module]) == []


def test_the_layer_test_catches_batch_importing_from_commands():
    assert {"hoc_cli.batch.job", "hoc_cli.report.summary"} <= set(MODULES)
    tree = ast.parse("def solve():\n    from hoc_cli.commands.plan import summarise\n")
    assert reaching_across("hoc_cli.batch.job", tree) == ["hoc_cli.commands.plan"]
    tree = ast.parse("from ..commands import common\n")
    assert reaching_across("hoc_cli.batch.spec", tree) == ["hoc_cli.commands"]
    tree = ast.parse("import hoc_cli.batch.engine\n")
    assert reaching_across("hoc_cli.report.files", tree) == ["hoc_cli.batch.engine"]
    assert reaching_across("hoc_cli.commands.plan", ast.parse("import hoc_cli.batch\n")) == []


def package_internal(importer: str, source: str) -> bool:
    """A private module's names belong to its package: ``dynamics/_passes`` may take ``_layout._consts``."""
    if "." not in source:
        return False
    package, leaf = source.rsplit(".", 1)
    own = importer if importer in PACKAGES else importer.rsplit(".", 1)[0]
    return leaf.startswith("_") and own == package


def test_no_module_imports_a_private_name_of_another_module():
    bad = []
    for module, tree in MODULES.items():
        for mod, names in imports(tree, module):
            if mod.startswith("hoc_cli") and mod != module and not package_internal(module, mod):
                bad += [f"{module}: {mod}.{n}" for n in names if n.startswith("_") and not n.startswith("__")]
    assert bad == []


def test_maths_modules_do_not_print_and_build_no_simple_namespaces():
    bad = []
    for module in MATHS:
        for node in ast.walk(MODULES[module]):
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "print":
                bad.append(f"{module}:{node.lineno} print")
            if isinstance(node, (ast.Name, ast.Attribute)) and getattr(node, "id", getattr(node, "attr", "")) == "SimpleNamespace":
                bad.append(f"{module}:{node.lineno} SimpleNamespace")
    assert bad == []


def test_the_layer_test_catches_a_maths_module_that_reaches_up():
    tree = ast.parse("def f():\n    from hoc_cli.commands.common import load_model\n")
    assert [m for m, _ in imports(tree, "hoc_cli.planner") if is_outer(m)] == ["hoc_cli.commands.common"]
    tree = ast.parse("from ..io import mcap\n")
    assert [m for m, _ in imports(tree, "hoc_cli.goals.plan") if is_outer(m)] == ["hoc_cli.io"]


def test_a_fixed_time_plan_loads_no_module_it_does_not_use(tmp_path):
    root = PACKAGE.parent
    code = (
        "import sys\n"
        "from hoc_cli.cli import app\n"
        "try:\n"
        f"    app(['plan', {str(root / 'configs' / 'lbr7_reach.yaml')!r}, '-o', 'none', '-q'])\n"
        "except SystemExit as e:\n"
        "    assert e.code == 0, e.code\n"
        "heavy = ('scipy.optimize', 'scipy.sparse', 'dask', 'distributed', 'pyarrow', 'matplotlib', 'yourdfpy',\n"
        "         'pinocchio', 'pydantic', 'rich', 'hoc_cli.io.mcap', 'hoc_cli.io.csv', 'hoc_cli.simulate',\n"
        "         'hoc_cli.goals', 'hoc_cli.constraints.sqp', 'hoc_cli.constraints.qp', 'hoc_cli.constraints.prolong')\n"
        "print(sorted(m for m in heavy if m in sys.modules))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]"


#: what makes a task ready to solve: ``hoc_cli.report.prepare`` does it for both front ends
PREPARATION = {"load_model", "resolve", "task_limits", "check_jerk_order", "check_boundary_states", "task_collision",
               "check_boundary_clearance", "enforced_problem", "problem_from_task", "refuse_infeasible", "plan_report",
               "sample_plan", "write_outputs", "SolveOptions"}


def preparation_taken(module: str, tree: ast.AST) -> set[str]:
    """The names of ``PREPARATION`` that ``module`` imports from the package (it should call ``prepare``)."""
    return {n for mod, names in imports(tree, module) if mod.startswith("hoc_cli") for n in names} & PREPARATION


@pytest.mark.parametrize("module", ["hoc_cli.commands.plan", "hoc_cli.batch.job"])
def test_hoc_plan_and_hoc_batch_prepare_a_task_through_report_prepare(module):
    assert preparation_taken(module, MODULES[module]) == set()
    assert any(mod == "hoc_cli.report.prepare" for mod, _ in imports(MODULES[module], module))


def test_the_preparation_check_sees_a_front_end_building_its_own_problem():
    tree = ast.parse("def _solve():\n    from hoc_cli.io.task.problem import problem_from_task, task_limits\n")
    assert preparation_taken("hoc_cli.batch.job", tree) == {"problem_from_task", "task_limits"}


def re_exports(source: str) -> list[int]:
    """The lines of ``source`` whose ``from … import`` is kept only by a ``noqa: F401`` (names imported to be
    taken from here by other modules: a shim)."""
    lines = source.splitlines()
    out = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.ImportFrom) and node.module != "__future__":
            if any("noqa: F401" in lines[k] for k in range(node.lineno - 1, node.end_lineno)):
                out.append(node.lineno)
    return out


def test_no_module_re_exports_names_from_another():
    """Every module imports a name from where it is defined: no shims left by moves (issue 23's migration)."""
    bad = [(str(p.relative_to(PACKAGE.parent)), line) for p in sorted(PACKAGE.rglob("*.py"))
           for line in re_exports(p.read_text(encoding="utf-8"))]
    assert bad == []


def test_the_re_export_check_sees_a_shim():
    assert re_exports("from hoc_cli.report.console import (  # noqa: F401  (re-exported)\n    warn,\n)\n") == [1]
    assert re_exports("import matplotlib  # noqa: F401  (installed?)\nfrom a import b\n") == []
