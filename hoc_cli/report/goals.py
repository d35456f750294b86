"""``hoc plan``'s goal summary keys: ``final_q`` and, per link goal or via, the reached pose and its error;
a missed goal's ``status``/``message``; the message of a free-T plan solved from scratch.

The task's goals are read by ``hoc_cli.io.task.problem`` and solved by ``hoc_cli.solve`` (docs/goals.md).
"""
from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

import numpy as np

from hoc_cli.dynamics import link_poses, link_velocity

if TYPE_CHECKING:  # the goal modules load with a goal: a joint goal in a fixed T needs none (start-up)
    from hoc_cli.goals import FrameResidual, Goals

WARM = "warm replan: "
COLD = "Newton steps in x and T from the plan at the guess: "
#: a goal error in the summary (recomputed from the plan) above this many times ``EQ_ACCEPT`` is a miss
#: (m, rad, m/s): the rows are accepted at ``EQ_ACCEPT``, and recomputing the link pose adds rounding
GOAL_MISS_FACTOR = 10


def cold(result):
    """A free-T plan solved from scratch says so: its last solve's "warm replan" message (the Newton
    steps in x and T reuse the replan) names the steps, not a warm start (there was no --init).
    """
    def retold(message: str) -> str:
        return COLD + message[len(WARM):] if isinstance(message, str) and message.startswith(WARM) else message

    changes = {"optimizer": dataclasses.replace(result.optimizer, message=retold(result.optimizer.message))}
    if result.limits is not None:
        changes["limits"] = dataclasses.replace(result.limits, message=retold(result.limits.message))
    return dataclasses.replace(result, **changes)


def goal_miss(result, summary: dict) -> dict:
    """``status``/``message`` keys for a plan whose goal rows are not met (``GoalResult.violation`` above
    ``EQ_ACCEPT``, or an error in ``summary``'s ``reached`` and ``vias`` above ``GOAL_MISS_FACTOR`` times it): "goal missed
    by X (key)" with the largest error (m, rad, m/s), never the optimiser's "stopping test held", and
    ``converged: false``; {} when every goal is met.
    """
    violation = float(getattr(result, "violation", 0.0))
    candidates = [("x1", summary.get("reached") or {})]
    candidates += [(f"via[{i}]", v) for i, v in enumerate(summary.get("vias") or [])]
    found = [(float(d[k]), label) for label, d in candidates
             for k in ("error", "position_error", "orientation_error", "velocity_error") if d.get(k) is not None]
    if not found and violation <= 0.0:  # no goal rows and no goal errors: nothing to miss
        return {}
    from hoc_cli.goals.plan import EQ_ACCEPT

    worst, key = max(found) if found else (violation, "goals")
    if not (violation > EQ_ACCEPT or worst > GOAL_MISS_FACTOR * EQ_ACCEPT):
        return {}
    worst = max(worst, violation)  # the rows' max |c| and the summary's errors measure the same goals
    message = f"goal missed by {worst:.3g} ({key})"
    if summary.get("status") == "converged":
        return {"status": "goal_missed", "message": message, "converged": False}
    return {"message": f"{message}; {summary.get('message', '')}", "converged": False}


def goal_summary(model, result, goals: Goals | None) -> dict:
    """``final_q`` and, per link goal or via, the reached pose and its error (m, rad, m/s)."""
    if goals is None:
        return {}
    from hoc_cli.goals import JointResidual, rotation_angle

    mesh, C = result.mesh, result.coeffs
    names = list(model.joint_names)
    out: dict = {"final_q": dict(zip(names, (float(v) for v in C[-1, 0])))}

    def reached(res: FrameResidual, q, dq) -> dict:
        P = link_poses(model, q)[res.link]
        p, v = res.target(mesh.T)
        d = {"link": res.link, "position": [float(x) for x in P[:3, 3]],
             "position_error": float(np.max(np.abs(P[:3, 3] - p)))}
        if res.orientation is not None:
            d["orientation_error"] = rotation_angle(P[:3, :3], res.orientation)
        if res.match_velocity:
            V = link_velocity(model, q, dq, res.link)[:3]
            d["velocity"] = [float(x) for x in V]
            d["velocity_error"] = float(np.max(np.abs(V - v)))
        return d

    if goals.final is not None:
        out["reached"] = reached(goals.final, C[-1, 0], C[-1, 1])
    vias = []
    for gp in goals.vias:
        t = gp.s * mesh.T
        q, dq = (mesh.evaluate(C, np.array([t]), r)[0] for r in (0, 1))
        if isinstance(gp.residual, JointResidual):
            err = float(np.max(np.abs(gp.residual(q, dq, mesh.T)[0])))
            vias.append({"t": float(t), "error": err})
        else:
            vias.append({"t": float(t), **reached(gp.residual, q, dq)})
    if vias:
        out["vias"] = vias
    return out
