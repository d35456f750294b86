"""Shared helpers for the model and dynamics tests: where the robots are, and a Pinocchio oracle.

Pinocchio (``pin`` on PyPI, a test-only dependency) is the reference implementation; its
continuous joints use two configuration coordinates (cos q, sin q), and joints we lock are removed
with ``buildReducedModel`` at the same locked values.
"""
from __future__ import annotations

import sysconfig
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
ROBOTS = ROOT / "robots"


def task_configs() -> list[Path]:
    """The shipped task files, configs/*.yaml, without the ``hoc catch`` scenarios (a top-level ``throw:``)."""
    return sorted(p for p in (ROOT / "configs").glob("*.yaml")
                  if not any(line.startswith("throw:") for line in p.read_text(encoding="utf-8").splitlines()))

#: the lbr7 catch of the real-time tests: gravity, the ball's start and velocity (m, m/s; URDF root frame)
CATCH_G = np.array([0.0, 0.0, -9.81])
CATCH_P0 = np.array([0.6725, -0.0375, 0.1246])
CATCH_V0 = np.array([-0.15, 0.25, 3.13])


def lbr7_catch_problem(N: int = 8):
    """The lbr7's flange catching the ball (CATCH_P0, CATCH_V0), free T in [0.3, 0.5] s, N elements, URDF limits."""
    from hoc_cli import Free, JointLimits, OptimalControlProblem, RobotSystem, link_goal, load_robot

    lbr = load_robot(str(ROBOTS / "lbr7.urdf"))
    arm = RobotSystem(lbr)
    ball = link_goal(arm, "lbr_flange", position=CATCH_P0, velocity=CATCH_V0, acceleration=CATCH_G,
                     match_velocity=True)
    return OptimalControlProblem(arm, q0=[0.0, 0.6, 0.0, -1.4, 0.0, 0.9, 0.0], dq0=np.zeros(7), link_goal=ball,
                                 time=Free(0.3, 0.5, guess=0.35), N=N, limits=JointLimits.from_model(lbr))


def lbr7_catch_start(N: int = 4, T: float = 0.35):
    """(system, limits, goals, the initial trajectory at T [s] on N elements) of the lbr7 catch (``lbr7_catch_problem``)."""
    from hoc_cli.goals.time_solver import goal_solver

    problem = lbr7_catch_problem(N=N)
    arm, limits = problem.system, problem.limits
    goals = problem.goals()
    start = goal_solver(arm, "quintic", N, problem.q0, problem.dq0, goals, limits=limits).initial(T)
    return arm, limits, goals, start


SHIPPED = ["pendulum.urdf", "two_link.urdf", "lbr7.urdf", "dual_arm.urdf"]
ERD = Path(sysconfig.get_paths()["purelib"]) / "cmeel.prefix" / "share" / "example-robot-data" / "robots"

#: third-party URDFs from example-robot-data: id -> (relative path, load_robot keyword arguments)
THIRD_PARTY = {
    "ur5 (6-DOF arm)": ("ur_description/urdf/ur5_robot.urdf", {}),
    "panda arm, mimic fingers locked (7-DOF)": (
        "panda_description/urdf/panda.urdf",
        {"joints": [f"panda_joint{i}" for i in range(1, 8)], "locked": {"panda_finger_joint1": 0.02}},
    ),
    "panda with a prismatic finger, reordered": (
        "panda_description/urdf/panda.urdf",
        {"joints": ["panda_finger_joint1", "panda_joint4", "panda_joint1", "panda_joint2"],
         "locked": {"panda_joint3": 0.4}},
    ),
    "kinova (continuous joints)": ("kinova_description/robots/kinova.urdf", {}),
    "alex upper body (19 joints, branching)": ("alex_description/urdf/alex_nub_hands.urdf", {}),
    "baxter (branching, mimic grippers locked)": ("baxter_description/urdf/baxter.urdf", {}),
    "xarm7": ("xarm_description/urdf/xarm7.urdf", {}),
    "z1": ("z1_description/urdf/z1.urdf", {}),
    "tiago, no hand (a base-fixed link with a rounding-negative inertia)": (
        "tiago_description/robots/tiago_no_hand.urdf", {}),
}


def random_state(rng: np.random.Generator, K: int, n: int):
    """(q, dq, ddq), each (K, n), spread over ±π rad (or ±π m) and unit-normal rates."""
    q = rng.uniform(-np.pi, np.pi, (K, n))
    return q, rng.standard_normal((K, n)), rng.standard_normal((K, n))


class PinocchioOracle:
    """Pinocchio's model of the same URDF, reduced to ``model``'s joints, gravity matched."""

    def __init__(self, model):
        import pinocchio as pin

        self.pin = pin
        full = pin.buildModelFromUrdf(str(model.urdf_path))
        locked_ids = [full.getJointId(name) for name in model.locked if full.existJointName(name)]
        if locked_ids:
            q_ref = pin.neutral(full)
            for name, value in model.locked.items():
                joint = full.joints[full.getJointId(name)]
                if joint.nq == 2:
                    q_ref[joint.idx_q:joint.idx_q + 2] = (np.cos(value), np.sin(value))
                else:
                    q_ref[joint.idx_q] = value
            full = pin.buildReducedModel(full, locked_ids, q_ref)
        full.gravity.linear[:] = model.gravity
        self.pm = full
        self.pd = full.createData()
        self.model = model
        joints = [full.joints[full.getJointId(name)] for name in model.joint_names]
        self.idx_q = [(j.idx_q, j.nq) for j in joints]
        self.idx_v = np.array([j.idx_v for j in joints])
        assert full.nv == model.n

    def config(self, q):
        out = np.zeros(self.pm.nq)
        for value, (iq, nq) in zip(q, self.idx_q):
            if nq == 2:
                out[iq:iq + 2] = (np.cos(value), np.sin(value))
            else:
                out[iq] = value
        return out

    def velocity(self, v):
        out = np.zeros(self.pm.nv)
        out[self.idx_v] = v
        return out

    def rnea(self, q, dq, ddq):
        tau = self.pin.rnea(self.pm, self.pd, self.config(q), self.velocity(dq), self.velocity(ddq))
        return tau[self.idx_v]

    def crba(self, q):
        M = self.pin.crba(self.pm, self.pd, self.config(q))
        M = np.triu(M) + np.triu(M, 1).T
        return M[np.ix_(self.idx_v, self.idx_v)]

    def rnea_derivatives(self, q, dq, ddq):
        """(∂τ/∂q, ∂τ/∂q̇, ∂τ/∂q̈) in model joint order."""
        dq_, dv_, da_ = self.pin.computeRNEADerivatives(
            self.pm, self.pd, self.config(q), self.velocity(dq), self.velocity(ddq))
        ix = np.ix_(self.idx_v, self.idx_v)
        da_ = np.triu(da_) + np.triu(da_, 1).T
        return dq_[ix], dv_[ix], da_[ix]

    def link_pose(self, q, link: str) -> np.ndarray:
        """(4, 4) pose of a URDF link (a Pinocchio BODY frame) in the root frame."""
        pin = self.pin
        pin.framesForwardKinematics(self.pm, self.pd, self.config(q))
        return self.pd.oMf[self.pm.getFrameId(link, pin.BODY)].homogeneous


def random_tree_urdf(rng: np.random.Generator, n_joints: int = 7) -> str:
    """A random tree URDF: each joint hangs off a random earlier link, with a random type
    (revolute, continuous, prismatic or fixed), a random axis (also ±x/±y/±z), a random origin with
    rpy, and a random physically valid inertia (principal moments from a random box, rotated)."""
    axes = [(0, 0, 1), (0, 0, -1), (1, 0, 0), (0, -1, 0)]
    links = ['<link name="l0"/>']
    joints = []
    for k in range(1, n_joints + 1):
        a, b, c = rng.uniform(0.05, 0.4, 3)
        m = rng.uniform(0.2, 3.0)
        moments = m / 12 * np.array([b * b + c * c, a * a + c * c, a * a + b * b])
        rpy = rng.uniform(-np.pi, np.pi, 3)
        cr, sr, cp, sp, cy, sy = np.cos(rpy[0]), np.sin(rpy[0]), np.cos(rpy[1]), np.sin(rpy[1]), np.cos(rpy[2]), np.sin(rpy[2])
        R = np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                      [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                      [-sp, cp * sr, cp * cr]])
        I = R @ np.diag(moments) @ R.T
        com = " ".join(f"{x:.17g}" for x in rng.uniform(-0.2, 0.2, 3))
        links.append(
            f'<link name="l{k}"><inertial><origin xyz="{com}" rpy="0 0 0"/><mass value="{m:.17g}"/>'
            f'<inertia ixx="{I[0, 0]:.17g}" ixy="{I[0, 1]:.17g}" ixz="{I[0, 2]:.17g}" iyy="{I[1, 1]:.17g}" '
            f'iyz="{I[1, 2]:.17g}" izz="{I[2, 2]:.17g}"/></inertial></link>')
        kind = rng.choice(["revolute", "revolute", "continuous", "prismatic", "fixed"])
        axis = axes[rng.integers(len(axes))] if rng.random() < 0.4 else rng.standard_normal(3)
        xyz = " ".join(f"{x:.17g}" for x in rng.uniform(-0.3, 0.3, 3))
        rpy_j = " ".join(f"{x:.17g}" for x in rng.uniform(-np.pi, np.pi, 3))
        joints.append(
            f'<joint name="j{k}" type="{kind}"><parent link="l{rng.integers(k)}"/><child link="l{k}"/>'
            f'<origin xyz="{xyz}" rpy="{rpy_j}"/><axis xyz="{" ".join(f"{x:.17g}" for x in axis)}"/>'
            '<limit lower="-1" upper="1" effort="10" velocity="2"/></joint>')
    return '<?xml version="1.0"?>\n<robot name="random">' + "".join(links + joints) + "</robot>"


def steps_on_mesh(monkeypatch, N: int) -> list:
    """A list that collects the steps of every replan ``hoc_cli.goals.free_time_sqp`` runs on a mesh of N elements
    from now on (the plan's own ``iterations`` total the coarse stage's steps too)."""
    import hoc_cli.goals.free_time_sqp as fts

    steps: list = []
    run = fts._run

    def spy(record, *args, **options):
        r = run(record, *args, **options)
        if r.plan.mesh.N == N:
            steps.append(r.plan.optimizer.iterations)
        return r

    monkeypatch.setattr(fts, "_run", spy)
    return steps
