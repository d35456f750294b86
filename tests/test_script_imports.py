"""Every name the scripts of docs/ and benchmarks/ import from hoc_cli exists (a module moved under them
is caught here, not when a figure or a benchmark is next regenerated)."""
from __future__ import annotations

import ast
import importlib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPTS = sorted([*ROOT.glob("docs/*.py"), *ROOT.glob("benchmarks/*.py")])


def hoc_imports(path: Path) -> list[tuple[str, str]]:
    """(module, name) of every ``from hoc_cli… import name`` in ``path``, at any depth."""
    out = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and (node.module or "").split(".")[0] == "hoc_cli":
            out += [(node.module, alias.name) for alias in node.names]
    return out


def resolves(module: str, name: str) -> bool:
    try:
        mod = importlib.import_module(module)
    except ImportError:
        return False
    if hasattr(mod, name):
        return True
    try:
        importlib.import_module(f"{module}.{name}")
    except ImportError:
        return False
    return True


def test_the_scripts_are_found():
    assert any(p.name == "figures.py" for p in SCRIPTS) and any(p.name == "bench_plan.py" for p in SCRIPTS)


@pytest.mark.parametrize("path", SCRIPTS, ids=lambda p: f"{p.parent.name}/{p.name}")
def test_every_hoc_cli_name_a_script_imports_exists(path):
    missing = [f"{m}.{n}" for m, n in hoc_imports(path) if not resolves(m, n)]
    assert not missing, f"{path.name} imports names hoc_cli no longer has: {missing}"


def test_the_check_catches_a_moved_name():
    assert not resolves("hoc_cli.commands.common", "load_model")
    assert resolves("hoc_cli.io.robot", "load_model")
