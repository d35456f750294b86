"""Plain option values are converted without pydantic (``hoc_cli.commands.option_values``) to what typer gives."""
from __future__ import annotations

import math
from pathlib import Path

import pytest
import typer
from typer.models import OptionInfo
from typer.testing import CliRunner

from hoc_cli.commands.option_values import Unplain, install, plain_value

PLAIN = {
    int: ["0", "5", "-12", "+5", "-0", "123456789012345678"],
    float: ["0", "5", "-0.0", "1.", ".5", "+.5", "1e5", "1E-8", "+1.5e+3", "2.5e-300", "1e308"],
    str: ["", "x", " padded ", "-", "none", "ünï"],
    Path: ["a.yaml", "dir/b.mcap", "-", " spaced name.csv", "/abs/path"],
}
UNPLAIN = {
    int: ["1_000", " 5", "5 ", "007", "1.0", "abc", "", "1e3", "9" * 40],
    float: ["1_0.0", " 1.0", "inf", "nan", "1e400", "abc", "", "0x10", "1e1000"],
    Path: [""],
}


def typer_value(annotation, value):
    """typer's own conversion of ``value`` (pydantic), the reference."""
    from typer._adapters import try_build_adapter

    if annotation is Path:
        return Path(value)  # typer's path adapter: pydantic's Path, then its checks of the file (none asked here)
    return try_build_adapter(annotation, OptionInfo()).validate_python(value)


@pytest.mark.parametrize("annotation,value", [(a, v) for a, vs in PLAIN.items() for v in vs])
def test_a_plain_value_converts_to_what_typer_gives(annotation, value):
    got, want = plain_value(annotation, value), typer_value(annotation, value)
    assert type(got) is type(want) and got == want
    if annotation is float:
        assert math.copysign(1.0, got) == math.copysign(1.0, want)


@pytest.mark.parametrize("annotation,value", [(a, v) for a, vs in UNPLAIN.items() for v in vs])
def test_any_other_spelling_is_left_to_typer(annotation, value):
    with pytest.raises(Unplain):
        plain_value(annotation, value)


def test_bounds_and_other_types_are_left_to_typer():
    assert plain_value(int, "3", minimum=1) == 3
    with pytest.raises(Unplain):
        plain_value(int, "0", minimum=1)
    with pytest.raises(Unplain):
        plain_value(float, "2.5", maximum=2)
    for annotation in (bool, bytes):
        with pytest.raises(Unplain):
            plain_value(annotation, "1")


def test_a_command_takes_plain_values_directly_and_the_rest_with_typer_s_messages(tmp_path):
    install()
    app = typer.Typer()

    @app.command()
    def main(n: int = typer.Option(1, "-n", min=1), x: float = typer.Option(0.0, "-x"),
             paths: list[Path] = typer.Option([], "-p"), name: str = typer.Option("", "--name"),
             existing: Path = typer.Option(None, "--existing", exists=True)) -> None:
        typer.echo(repr((n, x, paths, name, existing)))

    run = CliRunner().invoke
    r = run(app, ["-n", "3", "-x", "1e-3", "-p", "a.csv", "-p", "b.mcap", "--name", "7"])
    assert r.exit_code == 0 and r.stdout.strip() == repr((3, 1e-3, [Path("a.csv"), Path("b.mcap")], "7", None))
    r = run(app, ["-n", "1_000", "-x", " 2.5"])  # not plain: typer (pydantic) converts them
    assert r.exit_code == 0 and r.stdout.strip() == repr((1000, 2.5, [], "", None))
    for args in (["-n", "0"], ["-n", "abc"], ["-x", "abc"], ["--existing", str(tmp_path / "missing")]):
        r = run(app, args)
        assert r.exit_code == 2, (args, r.output)
    def flat(text: str) -> str:  # typer's message box, its lines wrapped at the terminal's width, as one line
        return " ".join(text.replace("│", " ").split())

    assert "does not exist" in flat(run(app, ["--existing", str(tmp_path / "missing")]).output)
    assert "greater than or equal to 1" in flat(run(app, ["-n", "0"]).output)
