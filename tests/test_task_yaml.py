"""Task files are YAML 1.2 (core schema), and hostile YAML gets a clear exit 2, fast (issue 12, items 3-5).

Each case goes through the real CLI (typer's CliRunner) and checks: exit code 2, exactly one line on
standard error naming the file and what is wrong, no traceback, nothing created or changed, within a
time budget. The same reader serves the task attached to a plan's MCAP (``hoc simulate PLAN.mcap``).
"""
from __future__ import annotations

import io
import shutil
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from hoc_cli.cli import app
from hoc_cli.errors import TaskError
from hoc_cli.io.task import load_task, load_yaml
from hoc_cli.io.task.checks import SHOW_CHARS, show
from hoc_cli.io.task.yaml12 import MAX_DEPTH, MAX_VALUES, Yaml12Loader
from hoc_cli.trajectory import Trajectory

ROOT = Path(__file__).resolve().parent.parent
TASK = """\
robot: arm.urdf
x0: {q: [0.0, 0.0]}
x1: {q: [1.2, -0.6]}
T: 1.5
N: 4
"""
SIM_TASK = "robot: arm.urdf\nx0: {q: [0.1, 0.2]}\nT: 1.0\nN: 4\n"
BUDGET_S = 1.0  # measured: ~0.03 s for the reader on the alias bomb and on 20 000 brackets


def bomb(levels: int = 9, width: int = 9) -> str:
    """``[&a0 [1,…], &a1 [*a0,…], …]``: ``width**levels`` values once the aliases are expanded."""
    items = ["&a0 [" + ", ".join(["1"] * width) + "]"]
    items += [f"&a{i} [" + ", ".join([f"*a{i - 1}"] * width) + "]" for i in range(1, levels)]
    return "[" + ", ".join(items) + "]"


@pytest.fixture(scope="module", autouse=True)
def _imported():
    """Import the commands and warm typer up first: the time budget measures the run, not start-up."""
    import hoc_cli.commands.plan
    import hoc_cli.commands.simulate
    import hoc_cli.io.mcap  # noqa: F401

    CliRunner().invoke(app, ["--version"])


@pytest.fixture
def workdir(tmp_path, monkeypatch) -> Path:
    shutil.copy(ROOT / "robots" / "two_link.urdf", tmp_path / "arm.urdf")
    monkeypatch.chdir(tmp_path)
    return tmp_path


def snapshot(d: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(d.iterdir())}


def rejected(d: Path, args: list[str], *needles: str) -> str:
    """Run ``hoc args``: exit 2, one line with every needle, nothing changed, within ``BUDGET_S``; the line."""
    before = snapshot(d)
    start = time.perf_counter()
    r = CliRunner().invoke(app, args)
    elapsed = time.perf_counter() - start
    assert r.exit_code == 2, (r.exit_code, r.stderr, r.exception)
    lines = r.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("hoc: error: "), r.stderr
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])
    assert "Traceback" not in r.output and len(lines[0]) < 400
    assert snapshot(d) == before
    assert elapsed < BUDGET_S, elapsed
    return lines[0]


def plan(d: Path, text: str, *needles: str) -> str:
    (d / "task.yaml").write_text(text)
    return rejected(d, ["plan", "task.yaml", "-o", "out.csv"], "task.yaml", *needles)


# --------------------------------------------------------------------------- item 3: alias bombs
def test_an_alias_bomb_inside_a_real_key_is_refused_within_a_second(workdir):
    plan(workdir, TASK.replace("T: 1.5", "T: " + bomb()), "invalid YAML at line 4", f"more than {MAX_VALUES} values")


def test_a_merge_key_bomb_is_refused_before_any_merge_is_expanded(workdir):
    lines = ["a0: &a0 {k: 1}"] + [f"a{i}: &a{i} {{<<: [{', '.join([f'*a{i - 1}'] * 9)}]}}" for i in range(1, 10)]
    plan(workdir, TASK + "\n".join(lines) + "\n", "invalid YAML", f"more than {MAX_VALUES} values")


def test_an_alias_cycle_is_refused(workdir):
    plan(workdir, TASK.replace("T: 1.5", "T: &a [1, *a]"), "invalid YAML at line 4", "cycle")


def test_a_large_aliased_value_below_the_bound_is_shown_in_a_bounded_message(workdir):
    # about 91 000 values once expanded: loads, then T's error message shows a few items, not all of them.
    text = TASK.replace("T: 1.5", "T: [&a [" + ", ".join(["1.5"] * 100) + "]" + ", *a" * 899 + "]")
    line = plan(workdir, text, "T: expected a duration T > 0 in seconds, got [[1.5, 1.5, 1.5, 1.5, ...")
    assert len(line) < 200 + len(str(workdir))



@pytest.mark.parametrize("where", ["x1: {q: {NAME: 1.2, elbow: -0.6}}", "x1: {q: [1.2, -0.6], NAME: 1}",
                                   "x1: {q: [1.2, -0.6]}\nlimits: {velocity: {NAME: 1.0}}",
                                   "x1: {q: [1.2, -0.6]}\njoints: [NAME, NAME]"])
def test_a_huge_name_from_the_file_is_cut_in_the_error_message(workdir, where):
    name = "j" * 1000  # a YAML simple key is at most 1024 characters
    plan(workdir, TASK.replace("x1: {q: [1.2, -0.6]}", where.replace("NAME", name)), "jjj...")

def test_show_is_bounded_in_time_and_length_for_a_value_expanding_to_billions_of_items():
    value: list = [1.0] * 9
    for _ in range(12):  # 9**13 items if written out; shared references here, as aliases build them
        value = [value] * 9
    start = time.perf_counter()
    text = show(value)
    assert time.perf_counter() - start < 0.1 and len(text) <= SHOW_CHARS
    assert len(show("x" * 10**7)) <= SHOW_CHARS and len(show(10**4000)) <= SHOW_CHARS


def test_an_alias_bomb_in_a_plans_attached_task_is_refused_by_simulate(workdir):
    from hoc_cli.io.mcap import write_mcap

    t = np.linspace(0.0, 1.0, 11)
    q = np.stack([0.1 * t, -0.2 * t], axis=1)
    traj = Trajectory(joints=("shoulder", "elbow"), t=t, q=q, dq=q, ddq=q, u=np.ones_like(q))
    buf = io.BytesIO()
    write_mcap(buf, traj, urdf_text=(workdir / "arm.urdf").read_text(),
               task_text=SIM_TASK.replace("T: 1.0", "T: " + bomb()))
    (workdir / "p.mcap").write_bytes(buf.getvalue())
    rejected(workdir, ["simulate", "p.mcap", "-o", "sim.csv"], "p.mcap", "not valid YAML",
             f"more than {MAX_VALUES} values")


# --------------------------------------------------------------------------- item 4: deep nesting
@pytest.mark.parametrize("opening,closing", [("[", "]"), ("{a: ", "}")], ids=["brackets", "braces"])
def test_20000_nested_collections_exit_2_not_a_recursion_error(workdir, opening, closing):
    n = 20_000
    plan(workdir, TASK.replace("T: 1.5", "T: " + opening * n + "1" + closing * n),
         "invalid YAML at line 4", f"nested deeper than {MAX_DEPTH} levels")


def test_nesting_within_the_bound_loads_and_is_refused_by_the_key_check(workdir):
    depth = MAX_DEPTH - 2  # the top-level mapping and T's list count too
    plan(workdir, TASK.replace("T: 1.5", "T: " + "[" * depth + "1" + "]" * depth), "T: expected a duration")


def test_deep_block_nesting_exits_2(workdir):
    text = "".join(" " * i + "- \n" for i in range(0, 3000, 1))
    plan(workdir, TASK.replace("T: 1.5", "T:\n" + text), "invalid YAML")


# --------------------------------------------------------------------------- item 5: YAML 1.2 scalars
@pytest.mark.parametrize("key,old,new", [
    ("T", "T: 1.5", "T: 1:30"),  # YAML 1.1: 90 (sexagesimal)
    ("N", "N: 4", "N: 010"),  # YAML 1.1: 8 (octal); YAML 1.2: 10; refused as ambiguous
    ("T", "T: 1.5", "T: 1_5"),  # YAML 1.1: 15
    ("N", "N: 4", "N: 0b100"),  # YAML 1.1: 4 (binary)
    ("N", "N: 4", "N: +0x10"),  # YAML 1.2 hex has no sign
])
def test_yaml_1_1_only_numbers_are_text_and_the_numeric_key_says_so(workdir, key, old, new):
    value = new.split(": ")[1]
    plan(workdir, TASK.replace(old, new), f"{key}: expected", f"got {value!r}", "YAML 1.2")


def test_yaml_1_2_core_numbers_are_read_as_numbers(workdir):
    text = TASK.replace("N: 4", "N: 0o10").replace("T: 1.5", "T: 15e-1") + "solver: {max_iter: 0x1F, tol: 1.E-8}\n"
    (workdir / "t.yaml").write_text(text)
    task = load_task(workdir / "t.yaml")
    assert (task.N, task.T, task.max_iter, task.tol) == (8, 1.5, 31, 1e-8)


@pytest.mark.parametrize("text,expected", [
    ("a: 1:30", "1:30"), ("a: 010", "010"), ("a: 1_5", "1_5"), ("a: 0o17", 15), ("a: 0x1f", 31), ("a: -12", -12),
    ("a: 0", 0), ("a: 1e3", 1000.0), ("a: .5", 0.5), ("a: 1.", 1.0), ("a: -.INF", -np.inf), ("a: 00.5", 0.5),
    ("a: yes", "yes"), ("a: On", "On"), ("a: TRUE", True), ("a: false", False), ("a: Null", None), ("a:", None),
    ("a: ~", None), ("a: 2024-01-01", "2024-01-01"), ("a: !!int 010", 10), ("a: !!float 2", 2.0),
    ("a: !!str 12", "12"), ("on: 1", None),
])
def test_core_schema_scalars(text, expected):
    doc = load_yaml(text)
    if text.startswith("on"):
        assert doc == {"on": 1}  # YAML 1.1 would make the key True
    else:
        assert doc["a"] == expected and type(doc["a"]) is type(expected)


def test_a_nan_is_read_as_a_float():
    assert np.isnan(load_yaml("a: .NaN")["a"])


@pytest.mark.parametrize("text,problem", [
    ("a: !!python/object/apply:os.system ['true']", "unsupported tag"),
    ("a: !!binary aGk=", "unsupported tag"),
    ("a: !!timestamp 2024-01-01", "unsupported tag"),
    ("a: !!int 1_5", "not a YAML 1.2 integer"),
    ("a: !!float 1:30", "not a YAML 1.2 float"),
    ("a: !!bool yes", "not a YAML 1.2 boolean"),
    ("a: 1" + "0" * 2000, "more than 1000 digits"),
    ("{[1]: 2}", "mapping key must be a scalar"),
])
def test_tags_and_values_outside_the_core_schema_are_yaml_errors(text, problem):
    with pytest.raises(yaml.YAMLError, match=problem):
        load_yaml(text)


# --------------------------------------------------------------------------- merge keys
def test_merge_keys_are_accepted_with_explicit_keys_winning_and_earlier_merges_first():
    doc = load_yaml("x0: &base {q: [0.0, 0.0], dq: [0.5, 0.5]}\nx1: {<<: [{q: [1.2, -0.6]}, *base]}\n")
    assert doc["x1"] == {"q": [1.2, -0.6], "dq": [0.5, 0.5]}  # earlier mapping in the list wins
    doc = load_yaml("a: &a {x: 1, y: 2}\nb: {<<: *a, y: 3}")
    assert doc["b"] == {"x": 1, "y": 3}  # an explicit key wins over a merged one


def test_a_task_using_a_merge_key_plans(workdir):
    text = TASK.replace("x1: {q: [1.2, -0.6]}", "x1: {<<: &goal {q: [1.2, -0.6]}, dq: [0.0, 0.0]}")
    (workdir / "task.yaml").write_text(text)
    task = load_task(workdir / "task.yaml")
    assert task.x1.q == [1.2, -0.6] and task.x1.dq == [0.0, 0.0]


@pytest.mark.parametrize("text,problem", [
    ("a: {<<: 1}", "merge key << expects a mapping or a list of mappings"),
    ("a: {<<: [1]}", "merge key << expects a mapping or a list of mappings"),
    ("a: {<<: {x: 1}, <<: {y: 1}}", "duplicate merge key"),
    ("a: {x: 1, x: 2}", "duplicate key 'x'"),
])
def test_malformed_merges_and_duplicates_are_yaml_errors(text, problem):
    with pytest.raises(yaml.YAMLError, match=problem):
        load_yaml(text)


def test_a_quoted_merge_key_is_an_ordinary_unknown_key(workdir):
    plan(workdir, TASK.replace("x1: {q: [1.2, -0.6]}", "x1: {'<<': {q: [1.2, -0.6]}}"), "x1.<<: unknown key '<<'")


def test_errors_from_the_reader_are_task_errors_naming_line_and_column(workdir):
    (workdir / "task.yaml").write_text(TASK + "x: !!binary aGk=\n")
    with pytest.raises(TaskError, match=r"invalid YAML at line 6, column 4: unsupported tag"):
        load_task(workdir / "task.yaml")


# --------------------------------------------------------------------------- the faster simple-key scan
class _PyYamlScan(Yaml12Loader):
    """The same loader with PyYAML's own simple-key bookkeeping (the reference for the faster one)."""

    stale_possible_simple_keys = yaml.scanner.Scanner.stale_possible_simple_keys
    next_possible_simple_key = yaml.scanner.Scanner.next_possible_simple_key


def _scan(text: str, loader: type) -> list:
    """Every token (type, position, value), or the error (type, problem, position) where scanning stops."""
    out: list = []
    try:
        for token in yaml.scan(text, Loader=loader):
            out.append((type(token).__name__, token.start_mark.index, getattr(token, "value", None)))
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        out.append((type(exc).__name__, exc.problem, mark.index if mark else None))
    return out


YAMLISH = st.lists(st.sampled_from(list("[]{}:,-? \n'\"#&*!ab1") + ["a: ", "- ", "[a, ", "{a: ", "  ", "\n  ",
                                                                   "x" * 1030]), max_size=60).map("".join)
SCAN_CASES = [
    *(p.read_text() for p in sorted((ROOT / "configs").glob("*.yaml"))),
    TASK, bomb(3, 3), "[" * 300 + "]" * 300, "{a: " * 300 + "1" + "}" * 300, "[" * 50 + "x" * 1100 + ": 1",
    "{" + "a" * 1100 + ": 1}", "[a, [b, {c: d}], e]: f", "? [a]\n: b\n", "a:\n  - [b, c]: d\n  - {e: [f, g]}\n",
    "[a\n, b]: c", "- [\n  a, b\n  ]\n- {x:\n  1}\n",
]


@pytest.mark.parametrize("text", SCAN_CASES, ids=range(len(SCAN_CASES)))
def test_the_faster_simple_key_scan_gives_pyyamls_tokens(text):
    assert _scan(text, Yaml12Loader) == _scan(text, _PyYamlScan)


@settings(max_examples=300, deadline=None)
@given(text=YAMLISH)
def test_the_faster_simple_key_scan_gives_pyyamls_tokens_on_random_text(text):
    assert _scan(text, Yaml12Loader) == _scan(text, _PyYamlScan)
