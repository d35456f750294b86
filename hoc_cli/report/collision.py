"""``hoc plan``'s collision checking: the task's scene built against the model, the x0/x1 check, the summary.

The maths (``hoc_cli.collision``) takes arrays; this module reads the task's ``collision:`` section
and the URDF's collision geometry into a ``CollisionScene``, refuses a start or goal state in
collision (exit 2), and certifies a plan's clearance for the JSON summary's ``collision_mode``,
``min_clearance`` and ``collisions`` (docs/collision.md). ``enforce`` plans with the constraint
(``hoc_cli.collision.enforce``); ``check`` plans without it and reports.
"""
from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from hoc_cli.errors import TaskError
from hoc_cli.io.task.checks import join
from hoc_cli.report.console import warn

if TYPE_CHECKING:
    from hoc_cli.collision.scene import CollisionScene

# hoc_cli.collision is imported on use: a task without a collision section does not pay for it at start-up


def task_collision(task, model) -> CollisionScene | None:
    """The pairs to check for ``task`` (None when ``collision.mode`` is off).

    Raises TaskError for a link the robot does not have (``collision.robot``), an obstacle given in
    another frame than the URDF root, or an ``ignore`` name that is neither a link nor an obstacle;
    ModelError (naming the URDF and link) for URDF collision geometry that cannot be read.
    """
    spec = task.collision
    if spec.mode == "off":
        return None
    from hoc_cli.collision.geometry import obstacle_primitive
    from hoc_cli.collision.robot import robot_geometry
    from hoc_cli.collision.scene import Obstacle, collision_scene
    from hoc_cli.io.collision_geometry import read_collision_shapes

    for link in spec.robot:
        if link not in model.link_names:
            raise TaskError(f"no link {link!r} in the URDF (links: {', '.join(model.link_names)})", file=task.path,
                            key=join("collision.robot", link))
    shapes = read_collision_shapes(task.robot, skip=set(spec.robot))
    robot = robot_geometry(model, shapes, {k: list(v) for k, v in spec.robot.items()})
    for name, link in spec.frames.items():
        if link not in model.link_names or model.link_body[model.link_names.index(link)] >= 0:
            raise TaskError(f"{link!r} is not a link fixed to the URDF root (fixed links: "
                            f"{', '.join(_fixed_links(model))})", file=task.path, key=join("collision.frames", name))
    obstacles = []
    for o in spec.obstacles:
        shape = o.shape
        if o.frame not in (None, ""):
            frame = spec.frames.get(o.frame, o.frame.lstrip("/"))
            if frame not in _fixed_links(model):
                raise TaskError(f"frame_id {o.frame!r} is not a link fixed to the URDF root {model.root_link!r} (name "
                                f"the link it stands for under collision.frames: {{{o.frame}: {model.root_link}}})",
                                file=o.file, key=o.key.rsplit(".primitives", 1)[0] + ".header.frame_id")
            offset = model.link_offset[model.link_names.index(frame)]  # the fixed link's pose in the root frame
            shape = replace(shape, pose=offset @ shape.pose)
        obstacles.append(Obstacle(o.name, obstacle_primitive(shape)))
    names = set(model.link_names) | {o.name for o in obstacles}
    for i, pair in enumerate(spec.ignore):
        for k, name in enumerate(pair):
            if name not in names:
                raise TaskError(f"{name!r} is neither a link nor an obstacle", file=task.path,
                                key=f"collision.ignore[{i}][{k}]")
    return collision_scene(model, robot, obstacles, margin=spec.margin, self_collision=spec.self_collision,
                           disabled=spec.disabled + spec.ignore)


def enforced_problem(task, model, scene: CollisionScene | None, problem, *, explicit: bool = False,
                     starts: int = 1, announce: bool = True):
    """(the problem, with the collision constraint when enforced, and the mode in effect).

    ``enforce`` (the section's default) applies in a fixed N with one start (joint or link goals, vias, a fixed or a
    free T); a task with ``N: auto`` or several starts is planned with ``check`` instead when the mode is
    the default, and refused (TaskError, exit 2) when ``enforce`` is asked for (``collision.mode`` or
    ``--collision``: ``explicit``). Without pairs to check there is nothing to enforce: ``check``. With
    ``announce`` the fallback to ``check`` says so in a warning line (``hoc plan``; ``hoc batch`` does not
    announce it: a plan's summary, in its MCAP, names the mode).
    """
    mode = task.collision.mode
    if mode != "enforce":
        return problem, mode
    if problem.N is None or starts > 1:
        why = "N: auto" if problem.N is None else "multi-start"
        if explicit or task.collision.mode_given:
            raise TaskError(f"collision enforcement plans in a fixed N with one start, not {why} "
                            "(use --collision check to plan without it and certify the clearance)",
                            file=task.path, key="collision.mode")
        if announce:
            warn(f"collision enforcement plans in a fixed N with one start, not {why}: planned "
                 "with collision check (the clearance is certified and reported, not imposed)")
        return problem, "check"
    if scene is None or scene.size == 0:  # nothing to impose
        return problem, mode if explicit or task.collision.mode_given else "check"
    from hoc_cli.collision.enforce import CollisionConstraint

    return replace(problem, constraint=CollisionConstraint(model, scene)), mode


def _fixed_links(model) -> list[str]:
    """The links welded to the URDF root (the root included): their poses are constant."""
    return [name for name, body in zip(model.link_names, model.link_body) if body < 0]


def check_boundary_clearance(task, model, scene: CollisionScene | None, states) -> None:
    """x0 (and a joint goal x1) must keep the margin: TaskError (exit 2) naming the closest pair and its depth."""
    if scene is None or scene.size == 0:
        return
    from hoc_cli.collision.evaluate import distances

    for label, q in (("x0", states.q0), ("x1", states.q1)):
        if q is None:  # a link goal: its final q is planned
            continue
        d = distances(model, scene, q[None, :])[0]
        k = int(np.argmin(d))
        if d[k] >= scene.margin:
            continue
        a, b = scene.names[k]
        how = (f"overlap by {-d[k]:.4g} m" if d[k] < 0 else f"are {d[k]:.4g} m apart")
        raise TaskError(f"{a} and {b} {how} (collision.margin is {scene.margin:g} m; move the state, give the robot's "
                        "SRDF as collision.srdf, add the pair to collision.ignore, or give the links' geometry under "
                        "collision.robot)",
                        file=task.path, key=f"{label}.q")


def collision_summary(model, scene: CollisionScene | None, mode: str, result) -> dict:
    """Summary keys ``collision_mode``, ``min_clearance`` and ``collisions`` (only the mode when off); with
    enforcement also ``collision_enforce`` and, when it did not converge, ``status`` and ``message``.
    """
    if scene is None:
        return {"collision_mode": mode}
    from hoc_cli.collision.certify import certify

    outcome = getattr(result, "constraint", None)
    cert = None if outcome is None else outcome.certificate_of(model, scene, result.mesh, result.coeffs)
    if cert is None:  # every written plan: its own check (the enforcement loop's, when it certified this plan)
        cert = certify(model, scene, result.mesh, result.coeffs)
    out = {"collision_mode": mode, **cert.summary()}
    if outcome is not None:
        out["collision_enforce"] = outcome.summary()
        if outcome.status != "converged":
            out["message"] = outcome.message
            if outcome.status == "infeasible":
                out["status"] = "infeasible"
    return out


def warn_collisions(collisions: list[dict]) -> None:
    """One warning line per pair and interval where the clearance is below the margin (standard error)."""
    for c in collisions:
        a, b = c["pair"]
        t0, t1 = c["interval"]
        what = f"overlap by {c['depth']:.4g} m" if c["depth"] > 0 else f"come within {c['distance']:.4g} m"
        if not c["certain"]:
            what = f"may come within {c['lower_bound']:.4g} m (not proven clear)"
        warn(f"{a} and {b} {what} in t = [{t0:.4g}, {t1:.4g}] s")


def collision_markers(scene: CollisionScene | None, model, targets) -> dict | None:
    """The MCAP's /collision_scene MarkerArray (``hoc_cli.io.mcap_obstacles``) when collisions are checked and an
    MCAP is written; None otherwise.
    """
    if scene is None or not any(t.kind == "mcap" for t in targets):
        return None
    from hoc_cli.io.mcap_obstacles import scene_markers

    return scene_markers(scene, model.root_link)


def sampled_clearance(scene: CollisionScene | None, model, q, targets) -> np.ndarray | None:
    """The MCAP's /collision_clearance: the smallest signed distance (K,) m over the checked pairs at each sample
    q (K, n), when collisions are checked and an MCAP is written; None otherwise.
    """
    if scene is None or not any(t.kind == "mcap" for t in targets):
        return None
    from hoc_cli.collision.evaluate import distances

    d = distances(model, scene, np.asarray(q, dtype=float))
    return d.min(axis=1) if d.shape[1] else np.full(d.shape[0], np.inf)
