"""``hoc plan``'s goal summary keys: ``final_q`` and, per link goal or via, the reached pose and its error.

The task's goals are read by ``hoc_cli.io.task.problem`` and solved by ``hoc_cli.solve`` (docs/goals.md).
"""
from __future__ import annotations

import numpy as np

from hoc_cli.dynamics import link_poses, link_velocity
from hoc_cli.goals import (
    FrameResidual,
    Goals,
    JointResidual,
    rotation_angle,
)


def goal_summary(model, result, goals: Goals | None) -> dict:
    """``final_q`` and, per link goal or via, the reached pose and its error (m, rad, m/s)."""
    if goals is None:
        return {}
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
