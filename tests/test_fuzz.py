"""Property-based tests: whatever the loaders are fed, they succeed or raise our own ``HocError``.

Random task documents (mutations of a valid one, and random YAML text), random URDF documents
built from ``<link>`` and ``<joint>`` elements with random attributes, and random or damaged CSV
and MCAP files. Any other exception type (KeyError, OverflowError, a third-party parser's own
error...) would reach the user as a traceback, so it fails the test. Each property is bounded
(``max_examples``) so that the whole file runs in well under a minute.
"""
from __future__ import annotations

import io
import math
import os
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from hoc_cli.errors import HocError
from hoc_cli.io.csv import read_csv, write_csv
from hoc_cli.io.task import TOP_KEYS, apply_overrides, load_task, parse_task, resolve
from hoc_cli.model import load_robot, urdf_joint_table, urdf_link_table
from hoc_cli.trajectory import Trajectory

FUZZ = settings(max_examples=int(os.environ.get("HOC_FUZZ_EXAMPLES", "300")), deadline=None, suppress_health_check=[HealthCheck.too_slow])

LINK = """<link name="{n}"><inertial><origin xyz="0 0 0.2"/><mass value="1"/>
<inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial></link>"""
ROBOT = f"""<robot name="r"><link name="base"/>{LINK.format(n="l1")}{LINK.format(n="l2")}
<joint name="a" type="revolute"><parent link="base"/><child link="l1"/><axis xyz="0 1 0"/>
<limit lower="-3" upper="3" effort="10" velocity="5"/></joint>
<joint name="b" type="revolute"><parent link="l1"/><child link="l2"/><origin xyz="0 0 0.4"/><axis xyz="0 1 0"/>
<limit lower="-3" upper="3" effort="10" velocity="5"/></joint></robot>"""


@pytest.fixture(scope="module")
def workdir(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("fuzz")
    (d / "r.urdf").write_text(ROBOT)
    return d


def expect_hoc_error_or_success(call, *args, **kwargs):
    """Run ``call``; an exception other than HocError fails the test with its type and message."""
    try:
        return call(*args, **kwargs)
    except HocError as exc:
        message = str(exc)
        assert message and "\n" not in message, f"a HocError must be one line: {message!r}"
        return None


# --------------------------------------------------------------------------- task documents
NAMES = st.sampled_from(["a", "b", "c", "base", "l1", "", "q", "dq", "rate", "tol", "method", "max_iter", "zero"])
SCALARS = (
    st.none() | st.booleans() | st.integers(min_value=-10, max_value=10)
    | st.integers(min_value=-(10 ** 400), max_value=10 ** 400)
    | st.floats(allow_nan=True, allow_infinity=True)
    | st.sampled_from(["quintic", "cubic", "covariant", "torque", "pr-cg", "newton", "zero", "r.urdf", ""])
    | st.text(max_size=8)
)
VALUES = st.recursive(
    SCALARS,
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(NAMES | st.integers(-2, 2), inner, max_size=4),
    max_leaves=12,
)
GOOD_DOC = {
    "robot": "r.urdf", "joints": ["a", "b"], "x0": {"q": [0.0, 0.1]}, "x1": {"q": {"a": 1.2, "b": -0.6}},
    "T": 1.5, "N": 4, "torque": [0.0, 0.0],
}


@FUZZ
@given(
    changes=st.dictionaries(st.sampled_from(TOP_KEYS + ("durration", "extra")), VALUES, max_size=4),
    dropped=st.sets(st.sampled_from(sorted(GOOD_DOC))),
    purpose=st.sampled_from(["plan", "simulate"]),
    overrides=st.dictionaries(st.sampled_from(["N", "order", "T", "tol", "max_iter", "method", "cost"]), SCALARS, max_size=2),
)
def test_a_random_task_document_loads_or_raises_a_hoc_error(workdir, changes, dropped, purpose, overrides):
    doc = {k: v for k, v in GOOD_DOC.items() if k not in dropped} | changes
    task = expect_hoc_error_or_success(parse_task, doc, path=workdir / "task.yaml", purpose=purpose)
    if task is None:
        return
    model = expect_hoc_error_or_success(load_robot, task.robot, joints=list(task.joints) if task.joints else None,
                                        locked=task.locked, gravity=task.gravity)
    if model is not None:
        expect_hoc_error_or_success(resolve, task, model.joint_names)
    expect_hoc_error_or_success(apply_overrides, task, **overrides)


YAML_TEXT = st.lists(st.sampled_from(list("robt:xq0T1N- \n\t[]{},'\"!&*#|>?%@`.eE+") + ["r.urdf", "\x00", "é", "robot: ",
                                                                                  "x0: ", "!!python/", "9" * 400]),
                     max_size=40).map("".join)


@FUZZ
@given(text=YAML_TEXT | st.binary(max_size=60).map(lambda b: b.decode("latin-1")))
def test_random_yaml_text_loads_or_raises_a_hoc_error(workdir, text):
    path = workdir / "random.yaml"
    path.write_text(text, encoding="utf-8", errors="surrogateescape")
    expect_hoc_error_or_success(load_task, path, purpose="simulate")


def test_a_robot_path_the_system_cannot_look_up_is_a_task_error(workdir):
    for robot in ("x" * 5000 + ".urdf", "nul\x00.urdf"):
        with pytest.raises(HocError, match="robot"):
            parse_task(GOOD_DOC | {"robot": robot}, path=workdir / "task.yaml")


def test_an_integer_too_large_for_a_double_is_a_task_error_naming_the_key(workdir):
    with pytest.raises(HocError, match="T: expected a duration"):
        parse_task(GOOD_DOC | {"T": 10 ** 400}, path=workdir / "task.yaml")


# --------------------------------------------------------------------------- URDF fragments
NUMBER_TEXT = st.sampled_from(["0", "1", "-1", "0.5", "1e-3", "nan", "inf", "-inf", "abc", "", "1 2", "1e400"])
VECTOR_TEXT = st.lists(NUMBER_TEXT, min_size=0, max_size=4).map(" ".join) | st.sampled_from(["0 0 1", "1 0 0", "0 0 0"])
LINKS = ["base", "a", "b", "c"]
LINK_REF = st.sampled_from(LINKS + ["ghost", ""])


def _attrs(**values) -> str:
    return "".join(f' {k}="{v}"' for k, v in values.items() if v is not None)


@st.composite
def link_xml(draw, name: str) -> str:
    if not draw(st.booleans()):
        return f'<link name="{name}"/>'
    origin = f"<origin{_attrs(xyz=draw(st.none() | VECTOR_TEXT), rpy=draw(st.none() | VECTOR_TEXT))}/>"
    mass = f"<mass{_attrs(value=draw(st.none() | NUMBER_TEXT))}/>" if draw(st.booleans()) else ""
    inertia = "<inertia" + "".join(
        _attrs(**{k: draw(st.none() | NUMBER_TEXT | st.just("0.01"))}) for k in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")
    ) + "/>" if draw(st.booleans()) else ""
    return f'<link name="{name}"><inertial>{origin}{mass}{inertia}</inertial></link>'


@st.composite
def joint_xml(draw, index: int) -> str:
    kind = draw(st.sampled_from(["revolute", "continuous", "prismatic", "fixed", "floating", "planar", "hinge", ""]))
    name = draw(st.sampled_from([f"j{index}", "j0", ""]))
    parts = [f"<parent{_attrs(link=draw(LINK_REF))}/>", f"<child{_attrs(link=draw(LINK_REF))}/>"]
    if draw(st.booleans()):
        parts.append(f"<origin{_attrs(xyz=draw(st.none() | VECTOR_TEXT), rpy=draw(st.none() | VECTOR_TEXT))}/>")
    if draw(st.booleans()):
        parts.append(f"<axis{_attrs(xyz=draw(VECTOR_TEXT))}/>")
    if draw(st.booleans()):
        parts.append("<limit" + "".join(_attrs(**{k: draw(st.none() | NUMBER_TEXT)})
                                        for k in ("lower", "upper", "effort", "velocity")) + "/>")
    if draw(st.booleans()):
        parts.append(f"<mimic{_attrs(joint=draw(st.sampled_from(['j0', 'j1', 'nope'])), multiplier=draw(st.none() | NUMBER_TEXT))}/>")
    return f'<joint{_attrs(name=name, type=kind)}>{"".join(parts)}</joint>'


@st.composite
def urdf_documents(draw) -> str:
    links = [draw(link_xml(n)) for n in LINKS[: draw(st.integers(1, len(LINKS)))]]
    joints = [draw(joint_xml(i)) for i in range(draw(st.integers(0, 4)))]
    body = draw(st.permutations(links + joints))
    return '<?xml version="1.0"?>\n<robot name="fuzz">' + "".join(body) + "</robot>"


@FUZZ
@given(document=urdf_documents(), joints=st.none() | st.lists(st.sampled_from(["j0", "j1", "j2", "a"]), max_size=3),
       gravity=st.sampled_from([(0.0, 0.0, -9.81), (0.0, 0.0), (math.nan, 0.0, 0.0)]))
def test_a_random_urdf_loads_or_raises_a_model_error(workdir, document, joints, gravity):
    path = workdir / "fuzz.urdf"
    path.write_text(document)
    with warnings.catch_warnings(record=True) as caught:  # a warning would be a second line on stderr
        warnings.simplefilter("always")
        model = expect_hoc_error_or_success(load_robot, path, joints=joints, gravity=gravity)
        expect_hoc_error_or_success(urdf_joint_table, path)
        expect_hoc_error_or_success(urdf_link_table, path)
    assert not caught, [str(w.message) for w in caught]
    if model is not None:
        from hoc_cli import dynamics

        M = dynamics.mass_matrix(model, np.zeros((1, model.n)))
        assert np.all(np.isfinite(M))  # a model that loads has a finite mass matrix


@FUZZ
@given(text=st.lists(st.sampled_from(list("<>/=\"' robtlinkjoaupae") + ["<robot>", "</robot>", "<link name='a'/>"]),
                     max_size=40).map("".join))
def test_random_xml_text_is_a_model_error_or_a_robot(workdir, text):
    path = workdir / "text.urdf"
    path.write_text(text)
    expect_hoc_error_or_success(load_robot, path)


# --------------------------------------------------------------------------- CSV and MCAP readers
def _trajectory() -> Trajectory:
    t = np.linspace(0.0, 1.0, 5)
    q = np.stack([np.sin(t), np.cos(t)], axis=1)
    return Trajectory(joints=("a", "b"), t=t, q=q, dq=q * 2, ddq=q * 3, u=q * 4)


def _valid_csv() -> str:
    buf = io.StringIO()
    write_csv(buf, _trajectory())
    return buf.getvalue()


VALID_CSV = _valid_csv()


@FUZZ
@given(
    cuts=st.lists(st.tuples(st.integers(0, len(VALID_CSV)), st.integers(0, 12),
                            st.lists(st.sampled_from(list("0123456789.,-e\nnaif tqu") + ["q.a", "inf"]), max_size=4).map("".join)),
                  max_size=4),
)
def test_a_damaged_csv_reads_or_raises_an_input_file_error(workdir, cuts):
    text = VALID_CSV
    for at, length, insert in cuts:
        text = text[:at] + insert + text[at + length:]
    path = workdir / "damaged.csv"
    path.write_text(text)
    traj = expect_hoc_error_or_success(read_csv, path)
    if traj is not None:
        assert traj.q.shape == (traj.K, len(traj.joints)) and np.all(np.diff(traj.t) > 0)


@FUZZ
@given(data=st.binary(max_size=200))
def test_random_bytes_as_csv_raise_an_input_file_error_or_read(workdir, data):
    path = workdir / "bytes.csv"
    path.write_bytes(data)
    expect_hoc_error_or_success(read_csv, path)


def _valid_mcap() -> bytes:
    from hoc_cli.elements import HermiteMesh
    from hoc_cli.io.mcap import write_mcap

    mesh = HermiteMesh("cubic", 1.0, 2)
    C = np.zeros((3, 2, 2))
    C[:, 0, 0] = [0.0, 0.5, 1.0]
    traj = _trajectory()
    traj = Trajectory(joints=traj.joints, t=traj.t, q=traj.q, dq=traj.dq, ddq=traj.ddq, u=traj.u, mesh=mesh, coeffs=C)
    buf = io.BytesIO()
    write_mcap(buf, traj, urdf_text=ROBOT, task_text="T: 1.0\n")
    return buf.getvalue()


VALID_MCAP = _valid_mcap()


@FUZZ
@given(
    edits=st.lists(st.tuples(st.floats(0, 1), st.integers(0, 255)), min_size=1, max_size=6),
    truncate=st.none() | st.floats(0, 1),
)
def test_a_damaged_mcap_reads_or_raises_an_input_file_error(workdir, edits, truncate):
    from hoc_cli.io.mcap import read_plan

    data = bytearray(VALID_MCAP)
    for where, value in edits:
        data[min(int(where * len(data)), len(data) - 1)] = value
    if truncate is not None:
        data = data[: int(truncate * len(data))]
    path = workdir / "damaged.mcap"
    path.write_bytes(bytes(data))
    expect_hoc_error_or_success(read_plan, path)


@FUZZ
@given(data=st.binary(max_size=300))
def test_random_bytes_as_mcap_raise_an_input_file_error(workdir, data):
    from hoc_cli.io.mcap import read_plan

    assume(not data.startswith(b"\x89MCAP"))
    path = workdir / "bytes.mcap"
    path.write_bytes(data)
    with pytest.raises(HocError):
        read_plan(path)
