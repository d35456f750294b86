"""Drake's KinematicTrajectoryOptimization with MinimumDistanceLowerBoundConstraint at sampled points (benchmark-only).

The plant is the URDF without its visual and collision elements, given hoc's capsules as collision
geometry and the scene's boxes, with every pair hoc does not check filtered out (same body, adjacent,
the SRDF's): the same geometry and pairs as hoc's. The program is Drake's own example's: a cubic
B-spline with ``control_points`` control points, the path length as cost, position and velocity
bounds, the duration fixed to T, rest at both ends, the fingers held at their locked value, the
minimum distance imposed at ``samples`` points of the path (influence distance 0.1 m), started from
the straight line; solved by SNOPT. Returns (success, solve time s, q (1 kHz samples, 7), solver).
"""
from __future__ import annotations

import re
import time

import numpy as np
from pydrake.geometry import Box as DBox
from pydrake.geometry import Capsule as DCapsule
from pydrake.geometry import CollisionFilterDeclaration, GeometrySet
from pydrake.geometry import Sphere as DSphere
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.multibody.inverse_kinematics import MinimumDistanceLowerBoundConstraint
from pydrake.multibody.parsing import Parser
from pydrake.multibody.plant import AddMultibodyPlantSceneGraph, CoulombFriction
from pydrake.planning import KinematicTrajectoryOptimization
from pydrake.solvers import Solve
from pydrake.systems.framework import DiagramBuilder
from pydrake.trajectories import BsplineTrajectory


def drake_plan(urdf_text, scene, q0, q1, T, margin, samples=25, control_points=10, locked=0.02):
    builder = DiagramBuilder()
    plant, sg = AddMultibodyPlantSceneGraph(builder, 0.0)
    text = re.sub(r"<collision>.*?</collision>", "", urdf_text, flags=re.S)
    text = re.sub(r"<visual>.*?</visual>", "", text, flags=re.S)
    Parser(plant).AddModelsFromString(text, "urdf")
    plant.WeldFrames(plant.world_frame(), plant.GetFrameByName("panda_link0"))
    robot = scene.robot
    gids = {}
    for p in range(robot.size):
        frame = plant.GetFrameByName(robot.links[p])
        body = frame.body()
        X_BF = frame.GetFixedPoseInBodyFrame()
        a, b, r = robot.a[p], robot.b[p], float(robot.radius[p])
        d = b - a
        L = float(np.linalg.norm(d))
        z = d / L if L > 0 else np.array([0, 0, 1.0])
        x = np.cross(z, [1.0, 0, 0] if abs(z[0]) < 0.9 else [0, 1.0, 0])
        x /= np.linalg.norm(x)
        X_FG = RigidTransform(RotationMatrix(np.stack([x, np.cross(z, x), z], axis=1)), (a + b) / 2)
        shape = DSphere(r) if L == 0 else DCapsule(r, L)
        gids.setdefault(robot.links[p], []).append(
            plant.RegisterCollisionGeometry(body, X_BF @ X_FG, shape, f"{robot.links[p]}{p}", CoulombFriction()))
    for o in scene.obstacles:
        pr = o.primitive
        plant.RegisterCollisionGeometry(plant.world_body(), RigidTransform(RotationMatrix(pr.rotation), pr.center),
                                        DBox(*(2 * pr.half)), o.name, CoulombFriction())
    plant.Finalize()
    # the pairs hoc does not check (same body, adjacent, SRDF): filtered out
    checked = {frozenset(nm) for nm in scene.names}
    links = list(gids)
    decl = CollisionFilterDeclaration()
    for i, la in enumerate(links):
        for lb in links[i + 1:]:
            if frozenset((la, lb)) not in checked:
                decl.ExcludeBetween(GeometrySet(gids[la]), GeometrySet(gids[lb]))
    sg.collision_filter_manager().Apply(decl)
    diagram = builder.Build()
    context = diagram.CreateDefaultContext()
    pctx = plant.GetMyContextFromRoot(context)
    nq = plant.num_positions()
    # finger joints locked
    fixed = np.full(nq, np.nan)
    for name in ("panda_finger_joint1", "panda_finger_joint2"):
        if plant.HasJointNamed(name):
            fixed[plant.GetJointByName(name).position_start()] = locked
    arm = [plant.GetJointByName(f"panda_joint{i}").position_start() for i in range(1, 8)]
    def full(q):
        out = np.where(np.isnan(fixed), 0.0, fixed)
        out[arm] = q
        return out
    trajopt = KinematicTrajectoryOptimization(nq, control_points, spline_order=4)
    prog = trajopt.get_mutable_prog()
    trajopt.AddDurationCost(0.0)
    trajopt.AddPathLengthCost(1.0)
    trajopt.AddPositionBounds(plant.GetPositionLowerLimits(), plant.GetPositionUpperLimits())
    trajopt.AddVelocityBounds(plant.GetVelocityLowerLimits(), plant.GetVelocityUpperLimits())
    trajopt.AddDurationConstraint(T, T)
    a0, a1 = full(q0), full(q1)
    trajopt.AddPathPositionConstraint(a0, a0, 0)
    trajopt.AddPathPositionConstraint(a1, a1, 1)
    trajopt.AddPathVelocityConstraint(np.zeros(nq), np.zeros(nq), 0)
    trajopt.AddPathVelocityConstraint(np.zeros(nq), np.zeros(nq), 1)
    for k in range(nq):  # the locked fingers stay put
        if not np.isnan(fixed[k]):
            prog.AddBoundingBoxConstraint(fixed[k], fixed[k], trajopt.control_points()[k, :])
    # initial guess: the straight line (as Drake's example)
    basis = trajopt.basis()
    guess = np.linspace(a0, a1, control_points).T
    trajopt.SetInitialGuess(BsplineTrajectory(basis, [guess[:, [i]] for i in range(control_points)]))
    con = MinimumDistanceLowerBoundConstraint(plant, margin, pctx, None, 0.1)
    for s in np.linspace(0, 1, samples):
        trajopt.AddPathPositionConstraint(con, s)
    t = time.perf_counter()
    result = Solve(prog)
    elapsed = time.perf_counter() - t
    traj = trajopt.ReconstructTrajectory(result)
    tt = np.linspace(traj.start_time(), traj.end_time(), int(round(T * 1000)) + 1)
    Q = np.array([traj.value(x).ravel()[arm] for x in tt])
    return result.is_success(), elapsed, Q, str(result.get_solver_id().name())
