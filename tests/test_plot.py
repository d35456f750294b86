"""`hoc plot`: a CSV or an MCAP becomes a PNG that opens; failures leave no file and exit 2."""
import sys

import numpy as np
import pytest
from typer.testing import CliRunner

from hoc_cli.cli import app
from hoc_cli.elements import HermiteMesh
from hoc_cli.io.csv import write_csv
from hoc_cli.io.mcap import write_mcap
from hoc_cli.trajectory import Trajectory, sample_times

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
JOINTS = ("shoulder", "slider")
URDF = """<robot name="r">
  <link name="base"/><link name="a"/><link name="b"/>
  <joint name="shoulder" type="revolute"><parent link="base"/><child link="a"/><axis xyz="0 0 1"/>
    <limit lower="-1.5" upper="2.0" velocity="3.0" effort="40.0"/></joint>
  <joint name="slider" type="prismatic"><parent link="a"/><child link="b"/><axis xyz="1 0 0"/>
    <limit lower="-0.2" upper="0.3" velocity="0.5" effort="100.0"/></joint>
</robot>
"""


def synthetic(rng: np.random.Generator, T=2.0, N=4) -> Trajectory:
    mesh = HermiteMesh("quintic", T, N)
    C = rng.standard_normal((N + 1, 3, len(JOINTS))) * 0.2
    t = sample_times(T, 50.0)
    q, dq, ddq = mesh.evaluate_all(C, t)
    return Trajectory(JOINTS, t, q, dq, ddq, rng.standard_normal(q.shape) * 20, mesh=mesh, coeffs=C)


@pytest.fixture
def files(tmp_path):
    traj = synthetic(np.random.default_rng(0))
    csv, mcap = tmp_path / "plan.csv", tmp_path / "plan.mcap"
    with open(csv, "wb") as fh:
        write_csv(fh, traj)
    with open(mcap, "wb") as fh:
        write_mcap(fh, traj, urdf_text=URDF, task_text="T: 2.0\n")
    return csv, mcap


def open_png(path):
    image = pytest.importorskip("matplotlib.image")
    assert path.read_bytes()[:8] == PNG_SIGNATURE
    return image.imread(path)


@pytest.mark.parametrize("source", ["csv", "mcap"])
def test_plot_writes_a_png_that_opens(files, tmp_path, source):
    pytest.importorskip("matplotlib")
    src = files[0] if source == "csv" else files[1]
    out = tmp_path / f"{source}.png"
    r = CliRunner().invoke(app, ["plot", str(src), "-o", str(out)])
    assert r.exit_code == 0, r.stderr
    pixels = open_png(out)
    assert pixels.ndim == 3 and pixels.shape[0] > 500 and pixels.shape[1] > 500
    assert pixels[..., :3].std() > 0.05  # not a blank canvas
    assert r.stdout == ""


def test_the_limits_of_an_mcap_come_from_its_attached_urdf(files):
    from hoc_cli.commands.plot import read_for_plot
    from hoc_cli.plotting import JointLimits

    traj, limits = read_for_plot(files[1])
    assert traj.joints == JOINTS
    assert limits == {"shoulder": JointLimits(-1.5, 2.0, 3.0, 40.0, False),
                      "slider": JointLimits(-0.2, 0.3, 0.5, 100.0, True)}
    assert read_for_plot(files[0])[1] == {}


def test_a_limit_near_the_data_is_in_view_and_a_far_one_does_not_flatten_the_curves():
    from hoc_cli.plotting import _view

    lo, hi = _view(np.array([0.0, 1.0]), [1.5, 100.0, -0.5])
    assert lo < -0.5 and 1.5 < hi < 2.0


def test_pdf_and_svg_are_written_too(files, tmp_path):
    pytest.importorskip("matplotlib")
    for ext, magic in (("pdf", b"%PDF"), ("svg", b"<?xml")):
        out = tmp_path / f"fig.{ext}"
        r = CliRunner().invoke(app, ["plot", str(files[0]), "-o", str(out)])
        assert r.exit_code == 0, r.stderr
        assert out.read_bytes().startswith(magic)


def test_without_matplotlib_plot_says_how_to_install_it_and_exits_2(files, tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # makes `import matplotlib` fail
    out = tmp_path / "fig.png"
    r = CliRunner().invoke(app, ["plot", str(files[0]), "-o", str(out)])
    assert r.exit_code == 2
    assert r.stderr.count("\n") == 1 and "pip install 'hoc[plot]'" in r.stderr
    assert not out.exists()


@pytest.mark.parametrize("args, expected", [
    (["nope.csv", "-o", "{tmp}/fig.png"], "file not found"),
    (["{csv}", "-o", "{tmp}/fig.jpg"], "expected .png, .pdf or .svg"),
    (["{csv}", "-o", "{tmp}/no/such/dir/fig.png"], "does not exist"),
])
def test_bad_input_or_output_is_one_line_and_exit_2(files, tmp_path, args, expected):
    args = [a.format(tmp=tmp_path, csv=files[0]) for a in args]
    r = CliRunner().invoke(app, ["plot", *args])
    assert r.exit_code == 2
    assert r.stderr.count("\n") == 1 and expected in r.stderr


def test_a_failure_while_drawing_leaves_an_existing_figure_untouched(files, tmp_path, monkeypatch):
    pytest.importorskip("matplotlib")
    import hoc_cli.plotting

    out = tmp_path / "fig.png"
    out.write_bytes(b"old")

    def boom(traj, fh, **kw):
        fh.write(b"partial")
        raise KeyboardInterrupt

    monkeypatch.setattr(hoc_cli.plotting, "plot_trajectory", boom)
    r = CliRunner().invoke(app, ["plot", str(files[0]), "-o", str(out)])
    assert r.exit_code == 130
    assert out.read_bytes() == b"old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fig.png", "plan.csv", "plan.mcap"]
