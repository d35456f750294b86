"""The closed-loop catch (``hoc_cli.realtime.loop``) and ``hoc catch``.

The 20-throw family of the issue (σ = 5 mm at 100 Hz, at least 19 caught) runs here and in
benchmarks/bench_realtime.py (``--family 20``).
"""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from _robots import CATCH_G, CATCH_P0, CATCH_V0, lbr7_catch_problem

import hoc_cli
from hoc_cli.constraints.check import check_limits
from hoc_cli.goals.plan import plan_goals
from hoc_cli.realtime.loop import Cycle, Observer, Throw, run_catch
from hoc_cli.realtime.replanner import Target, goals_with_target
from hoc_cli.realtime.throws import family

G, P0, V0 = CATCH_G, CATCH_P0, CATCH_V0


@pytest.fixture(scope="module")
def catch():
    problem = lbr7_catch_problem()
    return problem, hoc_cli.solve(problem)


def test_the_family_of_20_noisy_throws_is_caught_within_the_limits_in_every_cycle(catch):
    """The issue's test: σ = 5 mm at 100 Hz, at least 19 of the 20 seeded throws caught (flange within 5 mm of the
    true ball at the catch time, relative speed below 0.05 m/s), with configs/catch_throw.yaml's cycle, untimed
    (one SQP step per update, every correction applied: the same on every machine). Every plan the arm executed
    passes the exact limits check. Measured: 19 caught, error median 3.2 mm; the miss (throw 18, 5.3 mm) is the
    ball's estimate, which is 4.9-5.4 mm off at the catch from any observations up to 0-20 ms before it.
    """
    problem, plan = catch
    cycle = Cycle(rate=100.0, budget=1e9, delay=2, steps=1, commit=0.002, fix=0.1, feedback=0.01)
    caught, errors = 0, []
    for k, throw in enumerate(family(P0, V0, 20)):
        run = run_catch(problem, plan, throw, Observer(rate=100.0, noise=0.005, seed=k), cycle, timed=False)
        caught += run.caught
        errors.append(run.position_error)
        assert run.overruns == 0 and run.cycles > 10
        assert any(r.plan.status == "feedback" for r in run.records)
        for _, seg in run.segments[1:]:  # every plan in force, by the exact extrema check
            assert check_limits(problem.system, problem.limits, seg.mesh, seg.coeffs).feasible
    assert caught >= 19
    assert np.median(errors) < 3.5e-3


def test_without_noise_the_final_plan_is_the_cold_plan_of_its_problem(catch):
    """σ = 0: the estimate is the true ball, and the last update's plan agrees with a cold plan (from the
    minimum-jerk guess: ``plan_goals``, the augmented Lagrangian, not the replan's SQP) of the same problem (its start state and time, the true ball, its catch
    time and mesh) to 1e-6 in J.
    """
    problem, plan = catch
    throw = Throw(P0 + [0.01, -0.01, 0.005], V0 + [0.05, 0.05, -0.05])
    run = run_catch(problem, plan, throw, Observer(rate=100.0, noise=0.0, seed=0),
                    Cycle(rate=100.0, budget=10.0, steps=2, commit=0.06))  # 2 steps a cycle, as configs/catch_throw.yaml
    assert run.caught and run.position_error < 1e-4 and run.relative_speed < 1e-3
    final = run.final
    t, q, dq = run.start
    p, v = throw.states(t)
    goals = goals_with_target(problem.goals(), Target(p[0], v[0], G))
    cold = plan_goals(problem.system, final.mesh, q, dq, goals, limits=problem.limits)  # from the minimum-jerk guess
    assert cold.converged
    assert abs(final.J - cold.J) <= 1e-6 * abs(cold.J)


def test_a_throw_out_of_reach_is_reported_with_its_closest_approach(catch):
    problem, plan = catch
    throw = Throw(np.array([1.9, 0.6, 0.2]), np.array([0.6, 0.3, 3.0]))  # 2 m out and moving away
    run = run_catch(problem, plan, throw, Observer(rate=100.0, noise=0.005, seed=0),
                    Cycle(rate=50.0, budget=10.0, steps=1, commit=0.03))
    assert not run.caught and run.status == "unreachable"
    assert np.isfinite(run.closest) and run.closest > 0.5
    for rec in run.records:
        assert check_limits(problem.system, problem.limits, rec.plan.mesh, rec.plan.coeffs).feasible


SCENARIO = """\
task: {root}/configs/catch_ball.yaml
throw: {{position: [0.6825, -0.0475, 0.1296], velocity: [-0.10, 0.30, 3.08]}}
observe: {{rate: 100, noise: 0.002, seed: 3}}
cycle: {{rate: 20, budget: 0.05, steps: 2, commit: 0.03}}
"""


def hoc(*args, cwd=None):
    return subprocess.run([sys.executable, "-c", "from hoc_cli.cli import app; app()", *args], capture_output=True,
                          text=True, cwd=cwd)


def test_hoc_catch_prints_its_summary_and_writes_the_run(tmp_path, request):
    root = request.config.rootpath
    sc = tmp_path / "throw.yaml"
    sc.write_text(SCENARIO.format(root=root))
    out = tmp_path / "run.mcap"
    r = hoc("catch", str(sc), "--json", "-o", str(out), "--seed", "4", "--noise", "0.003")
    assert r.returncode in (0, 1), r.stderr
    s = json.loads(r.stdout)
    for key in ("caught", "position_error", "relative_speed", "T", "cycle_ms", "overruns", "skipped", "abandoned", "cycles"):
        assert key in s
    assert set(s["cycle_ms"]) == {"median", "p95", "p99", "max"} and s["seed"] == 4 and s["noise"] == 0.003
    assert r.returncode == (0 if s["caught"] else 1)
    assert len(s["updates"]) == s["cycles"] and all(u["steps"] >= 1 for u in s["updates"] if u["status"] not in ("held", "skipped", "abandoned"))
    assert s["overruns"] == sum(u["late"] for u in s["updates"])
    assert all(u["wall_ms"] > s["budget_ms"] for u in s["updates"] if u["late"])
    from mcap.reader import make_reader

    with open(out, "rb") as fh:
        topics = {ch.topic for _, ch, _ in make_reader(fh).iter_messages()}
    assert {"/tf", "/goal_marker", "/joint_states"} <= topics


@pytest.mark.parametrize("text, key", [
    ("throw: {{position: [0, 0, 0], velocity: [0, 0, 1]}}\n", "task"),
    ("task: {root}/configs/catch_ball.yaml\nthrow: {{position: [0, 0], velocity: [0, 0, 1]}}\n", "throw.position"),
    ("task: {root}/configs/catch_ball.yaml\nthrow: {{position: [0, 0, 0], velocity: [0, 0, 1]}}\ncycle: {{rate: -1}}\n",
     "cycle.rate"),
    ("task: {root}/configs/catch_ball.yaml\nthrow: {{position: [0, 0, 0], velocity: [0, 0, 1]}}\nobserve: {{sede: 1}}\n",
     "observe.sede"),
    ("task: {root}/configs/catch_ball.yaml\nthrow: {{position: [0, 0, 0], velocity: [0, 0, 1]}}\n"
     "cycle: {{rate: 100, budget: 0.02}}\n", "cycle.budget"),  # more than delay/rate
    ("task: {root}/configs/catch_ball.yaml\nthrow: {{position: [0, 0, 0], velocity: [0, 0, 1]}}\n"
     "cycle: {{rate: 100, feedback: 0.02}}\n", "cycle.feedback"),  # more than 1/rate
    ("task: {root}/configs/lbr7_reach.yaml\nthrow: {{position: [0, 0, 0], velocity: [0, 0, 1]}}\n", "task"),
])
def test_a_bad_scenario_is_one_line_naming_the_file_and_the_key(tmp_path, request, text, key):
    sc = tmp_path / "bad.yaml"
    sc.write_text(text.format(root=request.config.rootpath))
    r = hoc("catch", str(sc))
    assert r.returncode == 2 and r.stdout == ""
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"hoc: error: {sc}: {key}:"), r.stderr


def test_a_scenario_takes_its_task_inline_with_the_robot_relative_to_it(tmp_path, request):
    from hoc_cli.io.scenario import load_scenario

    root = request.config.rootpath
    sc = tmp_path / "inline.yaml"
    sc.write_text(f"""\
task:
  robot: {root}/robots/lbr7.urdf
  x0: {{q: [0.0, 0.6, 0.0, -1.4, 0.0, 0.9, 0.0]}}
  x1: {{link: lbr_flange, target: {{position: [0.67, -0.04, 0.12], velocity: [-0.15, 0.25, 3.13],
        acceleration: [0.0, 0.0, -9.81]}}, match_velocity: true}}
  T: {{free: true, min: 0.3, max: 0.5}}
  N: 8
throw: {{position: [0.68, -0.05, 0.13], velocity: [-0.1, 0.3, 3.1], drag: 0.01}}
observe: {{prior: null, latency: 0.02}}
""")
    s = load_scenario(sc)
    assert s.task.N == 8 and s.throw.drag == 0.01 and s.observer.prior is None and s.observer.latency == 0.02
    assert np.allclose(s.throw.gravity, [0.0, 0.0, -9.81])  # the task target's acceleration
    assert s.cycle == Cycle()


def test_a_throw_with_drag_rises_as_the_closed_form_says():
    """Straight up with quadratic drag k: v(t) = √(g/k) tan(atan(v0 √(k/g)) − √(gk) t), z(t) = ln(cos(a − √(gk) t)/cos a)/k."""
    g, k, v0 = 9.81, 0.05, 3.0
    throw = Throw(np.zeros(3), np.array([0.0, 0.0, v0]), np.array([0.0, 0.0, -g]), drag=k)
    t = np.array([0.05, 0.1, 0.2, 0.25])
    p, v = throw.states(t)
    a = np.arctan(v0 * np.sqrt(k / g))
    w = np.sqrt(g * k)
    assert np.abs(v[:, 2] - np.sqrt(g / k) * np.tan(a - w * t)).max() < 1e-9
    assert np.abs(p[:, 2] - np.log(np.cos(a - w * t) / np.cos(a)) / k).max() < 1e-9


def test_observations_count_only_once_they_have_arrived(catch):
    """With a latency of 50 ms, cycle k (t_k = k/20 s) fits the observations taken at 100 Hz up to t_k − 0.05."""
    problem, plan = catch
    throw = Throw(P0 + [0.005, 0.0, 0.0], V0)
    run = run_catch(problem, plan, throw, Observer(rate=100.0, noise=0.001, seed=1, latency=0.05),
                    Cycle(rate=20.0, budget=10.0, steps=1, commit=0.03))  # σ = 1 mm: updates from the first cycles
    assert run.cycles >= 3
    for rec in run.records:
        assert rec.observations == max(int(np.floor(round((rec.t - 0.05) * 100, 9))) + 1, 0)


def test_an_update_over_its_budget_is_discarded_and_counted(catch):
    """A budget no step fits. Without measured times (no warm-up) the first update runs to its end: late, its plan
    discarded. Then the measured times stop the others: skipped (the predicted first step does not fit) or
    abandoned (the measured rest of the step from a checkpoint does not fit). With the warm-up's times no update
    overruns. The arm stays on the first
    plan, and every such update is counted.
    """
    from hoc_cli.realtime.replanner import Replanner

    problem, plan = catch
    throw = Throw(P0 + [0.01, 0.0, 0.0], V0)
    observer, cycle = Observer(rate=100.0, noise=0.0, seed=0), Cycle(rate=20.0, budget=1e-5, steps=1, commit=0.03)
    cold = run_catch(problem, plan, throw, observer, cycle, replanner=Replanner(problem, plan, max_steps=1, warm_up=False))
    warm = run_catch(problem, plan, throw, observer, cycle)
    for run in (cold, warm):
        assert run.cycles >= 3 and run.overruns + run.skipped + run.abandoned == run.cycles
        assert len(run.segments) == 1 and run.final is run.segments[0][1] and run.final.status == "cold"
        assert all(r.late == (r.plan.status not in ("skipped", "abandoned") and r.plan.wall_time_s > 1e-5) for r in run.records)
    assert cold.records[0].late and cold.skipped >= 1 and cold.abandoned >= 1
    assert warm.overruns == 0 and warm.records[0].plan.status == "skipped" and warm.abandoned >= 1
    untimed = run_catch(problem, plan, throw, observer, Cycle(rate=20.0, budget=1e9, steps=1, commit=0.03), timed=False)
    assert untimed.overruns == 0 and len(untimed.segments) == untimed.cycles + 1


def test_an_update_computes_while_the_plan_in_force_runs_for_delay_cycles(catch):
    """delay = 2: the update from the observations at t_k starts its plan at t_k + 2/rate; the next update is then."""
    problem, plan = catch
    run = run_catch(problem, plan, Throw(P0, V0), Observer(rate=100.0, noise=0.005, seed=2),
                    Cycle(rate=100.0, budget=1e9, steps=1, commit=0.05, delay=2), timed=False)
    t = np.array([r.t for r in run.records])
    assert np.allclose(np.diff(t), 0.02) and np.allclose([r.t_start for r in run.records], t + 0.02)
    assert all(r.observations == int(round(r.t * 100)) + 1 for r in run.records)


def test_no_update_while_the_estimate_does_not_know_the_catch_within_the_gate(catch):
    """The first update waits until the fit's σ of the ball at the catch is within ``GATE`` × the noise σ in every
    coordinate (1 cm at σ = 5 mm).
    """
    from hoc_cli.realtime.ballistic import BallisticFit
    from hoc_cli.realtime.loop import GATE, observations

    problem, plan = catch
    throw, obs = Throw(P0, V0), Observer(rate=100.0, noise=0.005, seed=2)
    run = run_catch(problem, plan, throw, obs, Cycle(rate=100.0, budget=1e9, steps=1, commit=0.05), timed=False)
    t, y = observations(throw, obs, 1.0)
    fit = BallisticFit(G, 0.005, prior=(np.concatenate([P0, V0]), np.array([0.05, 0.25])))
    first = run.records[0]
    for ti, yi in zip(t[:first.observations], y[:first.observations]):
        fit.add(ti, yi)
    sd = lambda f: np.sqrt(np.diag(f.estimate(plan.T).covariance)[:3]).max()  # noqa: E731
    assert sd(fit) <= GATE * 0.005
    fit2 = BallisticFit(G, 0.005, prior=(np.concatenate([P0, V0]), np.array([0.05, 0.25])))
    for ti, yi in zip(t[:first.observations - 1], y[:first.observations - 1]):
        fit2.add(ti, yi)
    assert sd(fit2) > GATE * 0.005  # one observation fewer: not yet
