"""CSV trajectories: the header is the spec's, the last row is T, and values round-trip bit-exactly."""
import io

import numpy as np
import pytest

from hoc_cli.elements import HermiteMesh
from hoc_cli.errors import InputFileError
from hoc_cli.io.csv import read_csv, write_csv
from hoc_cli.trajectory import Trajectory, sample_times

JOINTS = ("shoulder", "elbow", "wrist.roll")


def synthetic(rng: np.random.Generator, T=1.3, N=5, order="quintic", rate=100.0) -> Trajectory:
    """A trajectory from random Hermite coefficients, with random torques (no planner involved)."""
    mesh = HermiteMesh(order, T, N)
    C = rng.standard_normal((N + 1, mesh.m, len(JOINTS)))
    t = sample_times(T, rate)
    q, dq, ddq = mesh.evaluate_all(C, t)
    u = rng.standard_normal(q.shape) * 1e3
    return Trajectory(JOINTS, t, q, dq, ddq, u, mesh=mesh, coeffs=C)


def test_the_header_names_t_then_q_dq_ddq_u_per_joint_in_task_order(tmp_path):
    traj = synthetic(np.random.default_rng(0))
    buf = io.BytesIO()
    write_csv(buf, traj)
    first = buf.getvalue().decode().split("\n", 1)[0]
    assert first == ("t,q.shoulder,q.elbow,q.wrist.roll,dq.shoulder,dq.elbow,dq.wrist.roll,"
                     "ddq.shoulder,ddq.elbow,ddq.wrist.roll,u.shoulder,u.elbow,u.wrist.roll")


def test_there_is_one_row_per_sample_and_the_last_row_is_exactly_T(tmp_path):
    traj = synthetic(np.random.default_rng(1), T=1.37, rate=100.0)
    path = tmp_path / "a.csv"
    with open(path, "wb") as fh:
        write_csv(fh, traj)
    lines = path.read_text().splitlines()
    assert len(lines) == 1 + traj.K
    assert lines[1].split(",")[0] == "0.0"
    assert float(lines[-1].split(",")[0]) == 1.37


def test_values_round_trip_bit_exactly_through_read_csv(tmp_path):
    traj = synthetic(np.random.default_rng(2))
    traj.q[3, 1] = 1e-310  # a subnormal
    traj.u[4, 0] = -0.0
    path = tmp_path / "a.csv"
    with open(path, "wb") as fh:
        write_csv(fh, traj)
    back = read_csv(path)
    assert back.joints == JOINTS
    for name in ("t", "q", "dq", "ddq", "u"):
        a, b = getattr(traj, name), getattr(back, name)
        assert a.shape == b.shape
        assert a.tobytes() == b.tobytes(), name
    assert back.mesh is None and back.coeffs is None


def test_a_text_stream_receives_the_same_characters_as_a_binary_one():
    traj = synthetic(np.random.default_rng(3))
    b, s = io.BytesIO(), io.StringIO()
    write_csv(b, traj)
    write_csv(s, traj)
    assert b.getvalue().decode() == s.getvalue()


def test_a_joint_name_with_a_comma_is_refused():
    traj = synthetic(np.random.default_rng(4))
    traj.joints = ("a,b", "c", "d")
    with pytest.raises(ValueError, match="a,b"):
        write_csv(io.BytesIO(), traj)


@pytest.mark.parametrize("text, message", [
    ("", "empty file"),
    ("time,q.a,dq.a,ddq.a,u.a\n0,1,2,3,4\n", "header starts with 'time'"),
    ("t,q.a,dq.a,ddq.a\n0,1,2,3\n", "4 per joint"),
    ("t,q.a,dq.b,ddq.a,u.a\n0,1,2,3,4\n", "'dq.b' where 'dq.a' was expected"),
    ("t,q.a,dq.a,ddq.a,u.a\n", "no data rows"),
    ("t,q.a,dq.a,ddq.a,u.a\n0,1,2,3\n", "line 2 has 4 values, expected 5"),
    ("t,q.a,dq.a,ddq.a,u.a\n0,1,2,x,4\n", "line 2: 'x' is not a number"),
    ("t,q.a,dq.a,ddq.a,u.a\n0,1,2,3,nan\n", "column u.a"),
    ("t,q.a,dq.a,ddq.a,u.a\n0,1,2,3,4\n0,1,2,3,4\n", "t must increase strictly, but line 3"),
])
def test_a_malformed_file_is_an_input_error_naming_the_file_and_what_was_expected(tmp_path, text, message):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(InputFileError) as err:
        read_csv(path)
    assert str(path) in str(err.value)
    assert message in str(err.value)


def test_a_missing_file_is_an_input_error(tmp_path):
    with pytest.raises(InputFileError, match="file not found"):
        read_csv(tmp_path / "nope.csv")
