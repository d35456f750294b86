"""``hoc plan``'s limits: the task's limits from URDF and ``limits:``, the x0/x1 check, the summary keys.

The maths (``hoc_cli.constraints``) takes arrays; this module reads the task and the model into
a ``JointLimits`` and turns an ``EnforceResult`` into the JSON summary's ``limits_mode``,
``active_limits``, ``limit_violations``, ``status`` and ``message`` (docs/limits.md).
"""
from __future__ import annotations

import numpy as np

from hoc_cli.constraints import JointLimits, check_limits, shortest_duration
from hoc_cli.constraints.feasibility import Bound, Pinned, infeasibility
from hoc_cli.errors import Infeasible, TaskError
from hoc_cli.planner import PlanResult


def check_boundary_states(task, limits: JointLimits, states) -> None:
    """In enforce mode x0, x1 and every joint via must lie within the position and velocity limits,
    and every locked joint within its URDF position limits (TaskError naming the key and the limit, exit 2).
    """
    points = [("x0", states.q0, states.dq0), ("x1", states.q1, states.dq1)]
    points += [(v.key, v.q, v.dq) for v in getattr(states, "vias", ())]
    for label, q, dq in points:
        if q is None:  # a link goal or link via: its q is planned within the limits
            continue
        for i, name in enumerate(limits.joints):
            lo, hi = limits.lower[i], limits.upper[i]
            if not lo <= q[i] <= hi:
                raise TaskError(f"{name} = {float(q[i]):g} is outside its position limits [{lo:g}, {hi:g}] "
                                "(limits are enforced; widen them under limits.position or use --limits report)",
                                file=task.path, key=f"{label}.q.{name}")
            v = limits.velocity[i]
            if dq is not None and abs(dq[i]) > v:
                raise TaskError(f"{name} = {float(dq[i]):g} exceeds its velocity limit {v:g} "
                                "(limits are enforced; raise it under limits.velocity or use --limits report)",
                                file=task.path, key=f"{label}.dq.{name}")
    for name, value, lo, hi in locked_outside(task):
        raise TaskError(f"{name} = {value:g} is outside its URDF position limits [{lo:g}, {hi:g}] (limits are "
                        "enforced; lock it within them, or use --limits report)", file=task.path, key=f"locked.{name}")


def warn_outside_limits(console, task, model, states) -> None:
    """With limits reported, not enforced: one ``hoc: warning:`` line on ``console`` for each of x0.q, x1.q
    and ``locked:`` outside the URDF position limits.
    """
    for label, q in (("x0.q", states.q0), ("x1.q", states.q1)):
        if q is None:  # a link goal
            continue
        for i, name in enumerate(model.joint_names):
            if q[i] < model.lower[i] or q[i] > model.upper[i]:
                console.print(f"hoc: warning: {task.path}: {label}.{name} = {q[i]:g} is outside the URDF limits "
                              f"[{model.lower[i]:g}, {model.upper[i]:g}]", highlight=False, markup=False, soft_wrap=True)
    for name, value, lo, hi in locked_outside(task):
        console.print(f"hoc: warning: {task.path}: locked.{name} = {value:g} is outside the URDF limits [{lo:g}, {hi:g}]",
                      highlight=False, markup=False, soft_wrap=True)


def locked_outside(task) -> list[tuple[str, float, float, float]]:
    """(joint, value, lower, upper) of every ``locked:`` value outside its joint's URDF position limits."""
    if not task.locked:
        return []
    from hoc_cli.model import urdf_joint_table

    rows = {r["name"]: r for r in urdf_joint_table(task.robot)}
    out = []
    for name, value in task.locked.items():
        row = rows.get(name)
        if row is None:
            continue  # an unknown joint is reported by load_model
        lo = -np.inf if row["lower"] is None else row["lower"]
        hi = np.inf if row["upper"] is None else row["upper"]
        if not lo <= value <= hi:
            out.append((name, float(value), float(lo), float(hi)))
    return out


def feasibility_proof(task, system, limits: JointLimits, states) -> tuple[Bound, str, str] | None:
    """(bound, key, one-line message) when ``hoc_cli.constraints.feasibility`` proves the task infeasible
    within ``limits`` before any solve (x0, a joint goal x1 and the joint vias are the pinned states), else None.
    """
    pinned = [Pinned(0.0, states.q0, states.dq0, "x0 (t = 0)")]
    if states.q1 is not None:
        pinned.append(Pinned(1.0, states.q1, states.dq1, "x1 (t = T)"))
    pinned += [Pinned(v.s, v.q, v.dq, v.key) for v in getattr(states, "vias", ()) if v.q is not None]
    free = task.time.free
    T_max = task.T if free is None else free.max
    bound = infeasibility(system, limits, pinned, T_max)
    if bound is None:
        return None
    if bound.T_min == np.inf:
        return bound, "limits", f"infeasible: {bound.why}; no duration T helps (limits are enforced)"
    what = f"T = {T_max:.6g} s" if free is None else f"T.max = {T_max:.6g} s"
    return bound, "T" if free is None else "T.max", (
        f"infeasible: {what} is shorter than {bound.T_min:.6g} s, the shortest duration allowed by {bound.why} "
        f"(expected T >= {bound.T_min:.6g} s, or wider limits)")


def refuse_infeasible(task, system, limits: JointLimits, states) -> None:
    """``Infeasible`` (exit 1) when ``feasibility_proof`` finds a proof; its JSON summary is the error's ``summary``."""
    proof = feasibility_proof(task, system, limits, states)
    if proof is None:
        return None
    bound, key, message = proof
    raise Infeasible(message, file=task.path, key=key, summary={
        "status": "infeasible", "converged": False, "message": message, "limits_mode": "enforce",
        "T_min": None if bound.T_min == np.inf else bound.T_min, "binding": {"kind": bound.kind, "joint": bound.joint},
        "outputs": []})


def reduced_gradient_norm(limits: JointLimits, result: PlanResult) -> float | None:
    """‖g − Dᵀw‖∞ for a plan the SQP decided (``EnforceResult.sqp == "converged"``): the cost gradient g (on
    the free coefficients) minus its least-squares fit by the gradients D of the kinematic rows active at the
    plan (positive multiplier), as ``hoc_cli.goals.replan`` reports a replan's; zero at a constrained
    optimum, where g alone is not. None for other plans (an augmented-Lagrangian plan already reports
    the gradient of I + Φ, whose multiplier terms play Dᵀw's part; goal plans report their own).
    """
    er = result.limits
    if er is None or er.sqp != "converged" or er.penalty is None or not er.working.any():
        return None
    from hoc_cli.constraints.qp import QPRows  # the QP loads only for a plan the SQP decided (start-up)
    from hoc_cli.problem import ControlProblem

    problem = result.problem
    if type(problem) is not ControlProblem:  # a goal plan's problem has its own rows
        return None
    x = problem.layout.pack(result.coeffs)
    g = problem.evaluate(x).grad
    rows = QPRows.build(er.rows, limits, er.working, problem.layout.free, 0.0)
    active = rows.gather(er.penalty.mu_lo, er.penalty.mu_hi) > 0
    if not active.any():
        return float(np.max(np.abs(g), initial=0.0))
    D = rows.A[active].toarray()
    w = np.linalg.lstsq(D.T, g, rcond=None)[0]
    return float(np.max(np.abs(g - D.T @ w), initial=0.0))


def limits_summary(mode: str, limits: JointLimits, system, result: PlanResult, states) -> dict:
    """Summary keys: ``limits_mode``, ``limit_violations`` (exact check), ``active_limits``, and for an
    infeasible task ``status: infeasible`` with a message naming the binding joint and kind.
    """
    check = (result.limits.check if result.limits is not None
             else check_limits(system, limits, result.mesh, result.coeffs))
    out: dict = {"limits_mode": mode, "limit_violations": check.violations(),
                 "active_limits": result.limits.active_limits() if result.limits is not None else []}
    reduced = reduced_gradient_norm(limits, result)
    if reduced is not None:  # the SQP's g is the cost's alone: its active rows' part removed
        out["grad_norm"] = reduced
    er = result.limits
    if er is not None and er.status == "infeasible":
        out["status"] = "infeasible"
        out["message"] = infeasible_message(limits, check, result, states)
    elif er is not None:
        out["message"] = er.message
    return out


def infeasible_message(limits: JointLimits, check, result: PlanResult, states) -> str:
    """Which joint and kind bind (the largest relative excess) and, where known, the shortest T."""
    rel = check.relative_excess()  # (K, n)
    k, j = np.unravel_index(int(np.nanargmax(np.where(np.isfinite(rel), rel, -np.inf))), rel.shape)
    from hoc_cli.constraints import KINDS

    msg = (f"no trajectory within the limits was found in T = {result.mesh.T:g} s: {limits.joints[j]} "
           f"{KINDS[k]} binds")
    bound = None if states.q1 is None else shortest_duration(limits, states.q0, states.dq0, states.q1, states.dq1)
    if bound is not None and bound[0] >= result.mesh.T:
        msg += f" (T >= {bound[0]:.6g} s is needed for {bound[1]} {bound[2]})"
    return msg
