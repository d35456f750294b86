"""The closed-loop catch: a thrown ball observed with noise, its ballistic estimate, the plan updated while it runs.

Time t [s] starts at the throw, when the arm starts executing the plan of the task's nominal target (planned
beforehand). Observations of the ball's position arrive at ``Observer.rate`` with Gaussian noise σ [m] per
coordinate (seeded), each ``latency`` [s] after it was taken. Cycle k runs at t_k = k/rate: with the
observations received by t_k it fits the ball (``BallisticFit``; the task's target as a Gaussian prior when
``Observer.prior`` is given, else that target alone until ``MIN_OBSERVATIONS`` have arrived); while the fit's
σ of the ball at the catch exceeds ``GATE`` × σ nothing is updated. Otherwise it updates the plan for the
start t_k + delay/rate from the state the plan in force reaches there (the arm executes the plan in force
meanwhile: the robot's state is the plan's state), so the SQP update has ``delay`` cycles to compute; the next
cycle is then. In the last ``Cycle.fix`` s, with ``Cycle.feedback`` > 0, each cycle instead corrects the plan
to the newest estimate (``feedback.correct``), applied ``feedback`` s after t_k. An update whose wall time
exceeds its budget was not ready at its start: its plan is discarded (the replanner returns to its state
before it) and it counts as an overrun. Nothing starts once less than ``Cycle.commit`` [s] would remain; the
arm then finishes the last plan. At its end (the catch time) the flange's position and velocity are compared
with the true ball's. Pure maths: no I/O.
"""
from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field

import numpy as np

from hoc_cli.dynamics import frame_jacobian, link_poses
from hoc_cli.optimize.blas import one_thread
from hoc_cli.realtime.ballistic import BallisticFit
from hoc_cli.realtime.feedback import correct
from hoc_cli.realtime.replanner import CyclePlan, Replanner, Target

CATCH_POSITION = 5e-3  # [m] the flange within this of the ball at the catch time ...
CATCH_SPEED = 0.05  # [m/s] ... moving with it to within this: caught
MIN_OBSERVATIONS = 3  # without a prior, the fit is used from this many observations on
REACH_SAMPLES = 200  # catch times at which an unreachable ball is confirmed out of the arm's reach
NOISE_FLOOR = 1e-6  # [m] the fit's σ for noise-free observations (their weight stays finite)
GATE = 2.0  # no update while the estimate's σ of a coordinate of the ball at the catch exceeds this × the noise σ
KEPT = ("held", "skipped", "abandoned")  # an update of these statuses leaves the plan in force
SAMPLES_PER_CYCLE = 4  # executed states recorded per cycle (closest approach, the MCAP's /tf)


@dataclass(frozen=True)
class Throw:
    """The true ball: ``position`` (3,) [m] and ``velocity`` (3,) [m/s] at t = 0, ``gravity`` (3,) [m/s²], ``drag``
    k [1/m] of a quadratic drag (acceleration g − k|v|v; 0: a parabola).
    """

    position: np.ndarray
    velocity: np.ndarray
    gravity: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, -9.81]))
    drag: float = 0.0

    def states(self, t) -> tuple[np.ndarray, np.ndarray]:
        """(positions (k, 3) [m], velocities (k, 3) [m/s]) at times t (k,) [s] ≥ 0."""
        t = np.atleast_1d(np.asarray(t, float))
        p0, v0, g = (np.asarray(v, float) for v in (self.position, self.velocity, self.gravity))
        if self.drag == 0.0:
            return p0 + np.outer(t, v0) + 0.5 * np.outer(t**2, g), v0 + np.outer(t, g)
        from scipy.integrate import solve_ivp

        k = self.drag

        def rhs(_, y):
            v = y[3:]
            return np.concatenate([v, g - k * np.linalg.norm(v) * v])

        order = np.argsort(t)
        sol = solve_ivp(rhs, (0.0, max(float(t.max()), 1e-9)), np.concatenate([p0, v0]), t_eval=t[order],
                        rtol=1e-11, atol=1e-12, method="DOP853")
        y = np.empty((t.size, 6))
        y[order] = sol.y.T
        return y[:, :3], y[:, 3:]


@dataclass(frozen=True)
class Observer:
    """Observations: ``rate`` [Hz], ``noise`` σ [m], ``seed``, ``latency`` [s]; ``prior`` (σ_p [m], σ_v [m/s]) of the
    task's target as a prior of the fit, or None.
    """

    rate: float = 100.0
    noise: float = 0.005
    seed: int = 0
    latency: float = 0.0
    prior: tuple[float, float] | None = (0.05, 0.25)


@dataclass(frozen=True)
class Cycle:
    """The control cycle: ``rate`` [Hz], ``budget`` [s] of wall time per update, ``steps`` SQP steps per update at
    most, ``delay`` the cycles from an update's start (its observations) to its plan's start (the update computes
    while the arm executes the plan in force: budget ≤ delay/rate), ``commit`` [s]: no update once less than this
    would remain to the catch; ``fix`` [s]: once less than this remains, the updates keep the catch time (a fixed
    T: steps in T are far from linear on a short remaining time); ``feedback`` [s]: when > 0, the updates of that
    last phase are feedback corrections (``feedback.correct``, a few ms) instead of SQP steps, one every cycle,
    each with this budget and its plan starting this long after its observations.
    """

    rate: float = 100.0
    budget: float = 0.01
    steps: int = 2
    commit: float = 0.01
    fix: float = 0.1
    delay: int = 1
    feedback: float = 0.0


@dataclass(frozen=True)
class CycleRecord:
    """One update: the cycle's time t [s] and the plan's start t_start [s], the plan (``CyclePlan``, with steps,
    status, residuals, wall time), the thread CPU time [s] of the update, the estimate (position (3,) [m],
    velocity (3,) [m/s] at t_start, acceleration (3,) [m/s²]) and its error against the true ball [m, m/s], observations used;
    ``budget`` [s] the update's; ``late``: its wall time exceeded it, so its plan was not ready at t_start and was
    discarded (the arm kept the plan in force); ``kind`` "step" (the replanner's SQP update) or "feedback" (a
    ``feedback.correct`` correction).
    """

    t: float
    t_start: float
    plan: CyclePlan
    cpu_s: float
    position: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    position_error: float
    velocity_error: float
    observations: int
    budget: float = math.inf
    late: bool = False
    kind: str = "step"


@dataclass(eq=False)
class CatchRun:
    """The outcome of a closed loop.

    status : "caught" | "unreachable" (the true ball stays beyond the arm's reach at every admissible catch time,
    ``out_of_reach``) | "missed" (not caught otherwise);
    position_error [m], relative_speed [m/s] at the catch time ``T`` [s] (from the throw); closest [m] the smallest
    flange-ball distance along the executed motion and ``closest_t`` [s] where; ``records`` one per update;
    ``segments`` the plans in force, each from its start time (the executed motion); ``target`` the last update's
    target, ``start`` its (t, q, q̇): the problem of the final plan; ``cold`` the first plan.
    """

    status: str
    position_error: float
    relative_speed: float
    T: float
    closest: float
    closest_t: float
    records: list
    segments: list
    target: Target | None
    start: tuple | None
    budget: float

    @property
    def caught(self) -> bool:
        return self.status == "caught"

    @property
    def cycles(self) -> int:
        return len(self.records)

    @property
    def cycle_ms(self) -> dict:
        """Wall time per update [ms]: median, p95, p99, max (NaN without updates)."""
        return _percentiles([1e3 * r.plan.wall_time_s for r in self.records])

    @property
    def cpu_ms(self) -> dict:
        """Thread CPU time per update [ms]: median, p95, p99, max."""
        return _percentiles([1e3 * r.cpu_s for r in self.records])

    @property
    def overruns(self) -> int:
        """Updates whose wall time exceeded their budget (their plans discarded: ``CycleRecord.late``)."""
        return sum(r.late for r in self.records)

    @property
    def skipped(self) -> int:
        """Updates that took no step because the predicted step time did not fit in the budget."""
        return sum(r.plan.status == "skipped" for r in self.records)

    @property
    def abandoned(self) -> int:
        """Updates whose step was stopped where its measured remaining time would have overrun the budget."""
        return sum(r.plan.status == "abandoned" for r in self.records)

    def applied(self) -> list:
        """The records whose plans the arm executed (not late, not held or skipped)."""
        return [r for r in self.records if not r.late and r.plan.status not in KEPT]

    @property
    def final(self) -> CyclePlan:
        return self.segments[-1][1]

    def executed(self, per_cycle: int = SAMPLES_PER_CYCLE, rate: float = 100.0) -> tuple[np.ndarray, ...]:
        """(t (k,) [s], q, q̇, q̈ (k, n)) of the executed motion from 0 to the catch, ``per_cycle`` samples per 1/rate
        (each sample on the plan in force at its time).
        """
        t_end = self.final.t_end
        ts = np.linspace(0.0, t_end, max(int(math.ceil(t_end * rate * per_cycle)), 2) + 1)
        starts = np.array([s for s, _ in self.segments])
        which = np.clip(np.searchsorted(starts, ts, side="right") - 1, 0, len(starts) - 1)
        out = [np.zeros((ts.size, self.final.coeffs.shape[2])) for _ in range(3)]
        for w in np.unique(which):
            sel = which == w
            for d in range(3):
                out[d][sel] = self.segments[w][1].state(ts[sel], d)
        return (ts, *out)

    def estimates(self, t, nominal: Target) -> np.ndarray:
        """The ball's estimated positions (k, 3) [m] at times t (k,) [s]: the estimate of the plan in force (before the
        first update, ``nominal``: its state at t = 0) propagated to t.
        """
        t = np.asarray(t, float)
        starts = np.array([r.t_start for r in self.records])
        which = np.searchsorted(starts, t, side="right") - 1
        out = np.zeros((t.size, 3))
        for i, (ti, w) in enumerate(zip(t, which)):
            if w < 0:
                p, v, a, tau = nominal.position, nominal.velocity, nominal.acceleration, ti
            else:
                r = self.records[w]
                p, v, a, tau = r.position, r.velocity, r.acceleration, ti - r.t_start
            out[i] = p + v * tau + 0.5 * a * tau**2
        return out


def _percentiles(values: list) -> dict:
    if not values:
        return {"median": math.nan, "p95": math.nan, "p99": math.nan, "max": math.nan}
    v = np.asarray(values, float)
    return {"median": float(np.median(v)), "p95": float(np.percentile(v, 95)), "p99": float(np.percentile(v, 99)),
            "max": float(v.max())}


def observations(throw: Throw, observer: Observer, t_max: float) -> tuple[np.ndarray, np.ndarray]:
    """(times (k,) [s], noisy positions (k, 3) [m]) of the observations taken in [0, t_max], seeded by ``observer.seed``."""
    t = np.arange(0.0, t_max + 1e-12, 1.0 / observer.rate)
    p, _ = throw.states(t)
    rng = np.random.default_rng(observer.seed)
    return t, p + rng.normal(0.0, observer.noise, p.shape)


def run_catch(problem, plan, throw: Throw, observer: Observer, cycle: Cycle, *,
              on_cycle=None, replanner: Replanner | None = None, timed: bool = True) -> CatchRun:
    """Simulate the closed loop (module docstring) from ``plan`` (``hoc_cli.solve`` of ``problem``: the task's
    nominal target) for the true ``throw``. ``on_cycle`` is called with each ``CycleRecord``. ``timed`` False: no
    update is judged late on its wall time (a reproducible run; give a large ``cycle.budget`` too).
    """
    with one_thread():  # (the corrections' solves too: see ``Replanner.update``)
        return _run(problem, plan, throw, observer, cycle, on_cycle, replanner, timed)


def _run(problem, plan, throw: Throw, observer: Observer, cycle: Cycle, on_cycle, replanner, timed: bool) -> CatchRun:
    rp = replanner if replanner is not None else Replanner(problem, plan, max_steps=cycle.steps)
    goal = problem.link_goal
    p_nom, v_nom = np.asarray(goal.position, float), np.zeros(3) if goal.velocity is None else np.asarray(goal.velocity, float)
    g = np.asarray(throw.gravity, float)
    prior = None
    if observer.prior is not None:
        prior = (np.concatenate([p_nom, v_nom]), np.array(observer.prior, float))
    fit = BallisticFit(g, max(observer.noise, NOISE_FLOOR), prior=prior)
    t_obs, y_obs = observations(throw, observer, problem.time.max + 1.0)
    arrived = t_obs + observer.latency
    used = 0
    dt = 1.0 / cycle.rate
    records: list[CycleRecord] = []
    segments = [(0.0, rp.current)]
    target = start = None
    k = 0
    while True:
        t_k = k * dt
        cur = rp.current
        fixed = cur.t_end - (t_k + cycle.delay * dt) < cycle.fix
        feedback = fixed and cycle.feedback > 0.0
        t_next = t_k + (cycle.feedback if feedback else cycle.delay * dt)
        budget = cycle.feedback if feedback else cycle.budget
        if cur.t_end - t_next < cycle.commit:
            break
        while used < t_obs.size and arrived[used] <= t_k + 1e-12:
            fit.add(t_obs[used], y_obs[used])
            used += 1
        if prior is not None or used >= MIN_OBSERVATIONS:
            est = fit.estimate(t_next)
            p, v = est.position, est.velocity
            if math.sqrt(np.max(np.diag(est.at(cur.t_end).covariance)[:3])) > GATE * max(observer.noise, NOISE_FLOOR):
                k += 1  # the estimate does not know the ball at the catch better than this yet: no update
                continue
        else:
            p, v = p_nom + v_nom * t_next + 0.5 * g * t_next**2, v_nom + g * t_next
        x = (cur.state(t_next)[0], cur.state(t_next, 1)[0])
        saved = rp.state()
        c0 = time.thread_time()
        if feedback:
            w0, tau = time.perf_counter(), cur.t_end - t_next
            new = correct(problem.system, problem.limits, goal.link, cur, t_next, p + v * tau + 0.5 * g * tau**2, v + g * tau)
            new = dataclasses.replace(cur if new is None else new, wall_time_s=time.perf_counter() - w0,
                                      **({"steps": 0, "status": "held"} if new is None else {}))
        else:
            new = rp.update(t_next, x, Target(p, v, g), budget, free_time=not fixed)
        cpu = time.thread_time() - c0
        late = timed and new.status not in KEPT and new.wall_time_s > budget
        if late:  # not ready at t_next: the arm keeps the plan in force
            rp.restore(saved)
        elif new.status not in KEPT:
            if feedback:
                rp.current = new
            segments.append((t_next, new))
            target, start = Target(p, v, g), (t_next, x[0], x[1])
        p_true, v_true = throw.states(t_next)
        rec = CycleRecord(t=t_k, t_start=t_next, plan=new, cpu_s=cpu, position=p, velocity=v, acceleration=g,
                          position_error=float(np.linalg.norm(p - p_true[0])),
                          velocity_error=float(np.linalg.norm(v - v_true[0])), observations=used, budget=budget,
                          late=late, kind="feedback" if feedback else "step")
        records.append(rec)
        if on_cycle is not None:
            on_cycle(rec)
        k += 1 if feedback else cycle.delay
    return _outcome(problem, throw, records, segments, target, start, cycle.budget)


def flange_states(model, link: str, q: np.ndarray, dq: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(positions (k, 3) [m], linear velocities (k, 3) [m/s]) of ``link``'s origin at joint states q, q̇ (k, n)."""
    q, dq = np.atleast_2d(q), np.atleast_2d(dq)
    P = link_poses(model, q)[link][:, :3, 3]
    J = frame_jacobian(model, q, link)[:, :3]
    return P, np.einsum("kij,kj->ki", J, dq)


def _outcome(problem, throw: Throw, records, segments, target, start, budget: float) -> CatchRun:
    model, link = problem.system.model, problem.link_goal.link
    final = segments[-1][1]
    t_c = final.t_end
    pf, vf = flange_states(model, link, final.state(t_c), final.state(t_c, 1))
    pb, vb = throw.states(t_c)
    pos_err = float(np.linalg.norm(pf[0] - pb[0]))
    speed = float(np.linalg.norm(vf[0] - vb[0]))
    run = CatchRun(status="", position_error=pos_err, relative_speed=speed, T=t_c, closest=math.nan,
                   closest_t=math.nan, records=records, segments=segments, target=target, start=start, budget=budget)
    ts, q, _, _ = run.executed()
    P, _ = flange_states(model, link, q, np.zeros_like(q))
    B, _ = throw.states(ts)
    d = np.linalg.norm(P - B, axis=1)
    i = int(np.argmin(d))
    run.closest, run.closest_t = float(d[i]), float(ts[i])
    if pos_err <= CATCH_POSITION and speed < CATCH_SPEED:
        run.status = "caught"
    elif out_of_reach(model, link, throw, problem.time.min, problem.time.max):
        run.status = "unreachable"
    else:
        run.status = "missed"
    return run


def out_of_reach(model, link: str, throw: Throw, t_min: float, t_max: float, samples: int = REACH_SAMPLES) -> bool:
    """Whether the true ball stays beyond the reach of ``link``'s chain (``hoc_cli.goals.residuals.reach``: the
    ball about the chain's first joint whose radius is the sum of its link lengths) at every catch time in
    [t_min, t_max] [s] (``samples`` times); False when the chain has no such bound (a prismatic joint).
    """
    from hoc_cli.goals.residuals import reach

    ball = reach(model, link)
    if ball is None:
        return False
    o, radius = ball
    p, _ = throw.states(np.linspace(t_min, t_max, samples))
    return bool(np.all(np.linalg.norm(p - o, axis=1) > radius))
