"""Repository contract: CI runs exactly the README's test command; the package installs a `hoc` script."""
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def test_ci_runs_exactly_the_test_command_printed_in_the_readme():
    ci_lines = [ln for ln in (ROOT / ".ci" / "run").read_text().splitlines() if "pytest" in ln]
    assert len(ci_lines) == 1
    assert ci_lines[0].strip() in (ROOT / "README.md").read_text()


def test_hoc_version_and_help_work_through_the_cli():
    from typer.testing import CliRunner

    from hoc_cli import __version__
    from hoc_cli.cli import app

    r = CliRunner().invoke(app, ["--version"])
    assert r.exit_code == 0 and __version__ in r.stdout
    r = CliRunner().invoke(app, ["--help"])
    assert r.exit_code == 0
    for command in ("plan", "simulate", "inspect", "verify", "plot"):
        assert command in r.stdout


def test_every_public_name_exists_and_importing_the_package_does_not_load_yourdfpy():
    import subprocess
    import sys

    code = ("import sys, hoc_cli; missing = [n for n in hoc_cli.__all__ if not hasattr(hoc_cli, n)]; "
            "print(missing, 'yourdfpy' in sys.modules, 'typer' in sys.modules, 'mcap' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert out == "[] False False False"
