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

    (lo, hi), shown, off = _view(np.array([0.0, 1.0]), [1.5, 100.0, -0.5])
    assert lo < -0.5 and 1.5 < hi < 2.0
    assert shown == [1.5, -0.5] and off == [100.0]  # named in the panel, not silently left off


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
    (["{csv}", "-o", "{csv}/fig.png"], "is not a directory"),  # as hoc plan's -o says
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

    def boom(runs, fh, **kw):
        fh.write(b"partial")
        raise KeyboardInterrupt

    monkeypatch.setattr(hoc_cli.plotting, "plot_trajectories", boom)
    r = CliRunner().invoke(app, ["plot", str(files[0]), "-o", str(out)])
    assert r.exit_code == 130
    assert out.read_bytes() == b"old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fig.png", "plan.csv", "plan.mcap"]


# --------------------------------------------------------------------------- issue 13 item 4
def figure_of(runs, limits, **kw):
    """The matplotlib Figure hoc plot draws (per-joint or normalised layout)."""
    matplotlib = pytest.importorskip("matplotlib")  # noqa: F841
    from matplotlib.figure import Figure

    from hoc_cli.plotting import _draw_normalised, _draw_per_joint

    draw = _draw_normalised if kw.get("normalized") else _draw_per_joint
    return draw(Figure, runs, list(runs[0][1].joints), limits)


def hlines(ax):
    """y of every horizontal line across an axes (the limits)."""
    return sorted(float(line.get_ydata()[0]) for line in ax.lines
                  if len(line.get_ydata()) == 2 and line.get_ydata()[0] == line.get_ydata()[1])


def test_each_joint_has_its_own_panels_with_only_its_own_limits_and_units(files):
    from hoc_cli.commands.plot import read_for_plot

    traj, limits = read_for_plot(files[1])
    fig = figure_of([("plan.mcap", traj)], limits)
    axes = np.array(fig.axes).reshape(len(JOINTS), 3)
    for i, joint in enumerate(JOINTS):
        L = limits[joint]
        for c, (quantity, expected) in enumerate((("q", [L.lower, L.upper]), ("dq", [-L.velocity, L.velocity]),
                                                  ("u", [-L.effort, L.effort]))):
            ax = axes[i, c]
            drawn = hlines(ax)
            notes = " ".join(t.get_text() for t in ax.texts)
            data = getattr(traj, quantity)[:, i]
            for b in expected:  # every limit is drawn in its own joint's panel, or named there as off scale
                assert b in drawn or f"{abs(b):.4g}" in notes, (joint, quantity, b)
            assert set(drawn) <= set(expected)  # no other joint's limit
            lo, hi = ax.get_ylim()
            assert lo <= data.min() and data.max() <= hi
        units = [ax.get_ylabel() for ax in axes[i]]
        assert units == (["[m]", "[m/s]", "[N]"] if joint == "slider" else ["[rad]", "[rad/s]", "[N·m]"])


def test_a_far_limit_is_named_in_its_panel_with_the_peak_fraction():
    from hoc_cli.plotting import off_scale_note

    assert off_scale_note([-320.0, 320.0], [], np.array([-7.0, 16.0]), "N·m") == "limits ±320 N·m off scale (peak 5 %)"
    assert off_scale_note([-2.0, 3.0], [], np.array([0.0]), "rad") == "limits [-2, 3] rad off scale"


def test_normalised_values_are_plus_minus_one_at_the_limits():
    from hoc_cli.plotting import JointLimits, normalise

    t = np.array([0.0, 1.0, 2.0])
    q = np.array([[-1.5], [0.25], [2.0]])
    traj = Trajectory(("j",), t, q, q * 3.0, q * 0.0, q * 40.0 / 2.0)
    L = JointLimits(-1.5, 2.0, 6.0, 40.0, False)
    np.testing.assert_allclose(normalise(traj, "q", 0, L), [-1.0, 0.0, 1.0])
    np.testing.assert_allclose(normalise(traj, "dq", 0, L), q[:, 0] * 3.0 / 6.0)
    np.testing.assert_allclose(normalise(traj, "u", 0, L), q[:, 0] * 20.0 / 40.0)
    assert normalise(traj, "u", 0, JointLimits(-1.5, 2.0, 6.0, None, False)) is None


def test_from_a_csv_the_figure_says_limits_are_unknown_and_robot_supplies_them(files, tmp_path, monkeypatch):
    pytest.importorskip("matplotlib")
    import hoc_cli.plotting

    seen = {}
    real = hoc_cli.plotting.plot_trajectories

    def spy(runs, fh, **kw):
        seen.update(kw, labels=[label for label, _ in runs])
        return real(runs, fh, **kw)

    monkeypatch.setattr(hoc_cli.plotting, "plot_trajectories", spy)
    assert CliRunner().invoke(app, ["plot", str(files[0]), "-o", str(tmp_path / "a.png")]).exit_code == 0
    assert seen["limits"] is None and "limits unknown" in seen["limits_note"] and "--robot" in seen["limits_note"]
    urdf = tmp_path / "r.urdf"
    urdf.write_text(URDF)
    r = CliRunner().invoke(app, ["plot", str(files[0]), "--robot", str(urdf), "-o", str(tmp_path / "b.png")])
    assert r.exit_code == 0, r.output
    assert seen["limits_note"] is None and seen["limits"]["shoulder"].effort == 40.0


def test_two_files_are_overlaid_with_a_legend_per_file(files, tmp_path):
    pytest.importorskip("matplotlib")
    from hoc_cli.commands.plot import read_for_plot

    other = synthetic(np.random.default_rng(1))
    second = tmp_path / "other.mcap"
    with open(second, "wb") as fh:
        write_mcap(fh, other, urdf_text=URDF, task_text="T: 2.0\n")
    for extra in ([], ["--normalized"]):
        out = tmp_path / f"overlay{len(extra)}.png"
        r = CliRunner().invoke(app, ["plot", str(files[1]), str(second), *extra, "-o", str(out)])
        assert r.exit_code == 0, r.output
        open_png(out)
    traj, limits = read_for_plot(files[1])
    fig = figure_of([("plan.mcap", traj), ("other.mcap", other)], limits)
    legend_texts = [t.get_text() for legend in fig.legends for t in legend.get_texts()]
    assert legend_texts[:2] == ["plan.mcap", "other.mcap"] and "URDF limit" in legend_texts
    assert len(fig.axes[0].lines) >= 2  # both files in the first panel
    fig = figure_of([("plan.mcap", traj), ("other.mcap", other)], limits, normalized=True)
    assert [t.get_text() for t in fig.axes[1].get_legend().get_texts()] == ["plan.mcap", "other.mcap"]


def test_files_of_different_joints_are_refused_with_exit_2(files, tmp_path):
    pytest.importorskip("matplotlib")
    t = sample_times(1.0, 10.0)
    z = np.zeros((t.size, 1))
    csv = tmp_path / "one.csv"
    with open(csv, "wb") as fh:
        write_csv(fh, Trajectory(("elbow",), t, z, z, z, z))
    out = tmp_path / "x.png"
    r = CliRunner().invoke(app, ["plot", str(files[0]), str(csv), "-o", str(out)])
    assert r.exit_code == 2 and "same robot" in r.stderr and r.stderr.count("\n") == 1
    assert not out.exists()
