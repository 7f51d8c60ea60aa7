"""Reset-free Unitree A1 in PyBullet with the URSA paper's tasks, safe set, features and damage.

The A1 (``pybullet_data/a1/a1.urdf``) stands on a plane. Physics runs at ``physics_hz``
(default 500 Hz); a PD controller, computed in Python as joint torques at every physics substep
(as motion_imitation and DayDreamer do), tracks joint targets that the policy sets at
``control_hz`` (20 Hz). The simulation is never reset after construction; see ``ursa.envs.base``.

Joint order (12): legs FR, FL, RR, RL (front-right, front-left, rear-right, rear-left), each
(hip, upper, lower) = (abduction, thigh, calf); see ``JOINT_NAMES``.

Observation layout (46,) float32, also given as slices by ``OBS_LAYOUT``:

====  ================  ===  ===========================================================
 idx  name              dim  content
====  ================  ===  ===========================================================
0:12  joint_pos          12  joint angles (rad)
12:24 joint_vel          12  joint velocities (rad/s)
24:27 gravity            3   unit gravity direction in the base frame ((0, 0, -1) upright)
27:30 base_ang_vel       3   base angular velocity in the base frame (rad/s)
30:33 base_lin_vel       3   base linear velocity in the base frame (m/s)
33:34 base_height        1   base (trunk centre of mass) height above the ground (m)
34:46 prev_action        12  the previous (clipped) action in [-1, 1]
====  ================  ===  ===========================================================

Action (12,) in [-1, 1]: joint targets. ``stand_centered`` mapping (default): 0 is the
standing pose, -1 and +1 the ends of ``[joint_low, joint_high]``, piecewise linear in between;
``linear`` mapping (DayDreamer): -1..1 maps linearly onto ``[joint_low, joint_high]``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from operator import itemgetter, mul
from typing import Any

import gymnasium as gym
import numpy as np
import pybullet as pb
import pybullet_data
from scipy import signal

from ursa.envs import tasks

JOINT_NAMES: tuple[str, ...] = tuple(
    f"{leg}_{part}_joint" for leg in ("FR", "FL", "RR", "RL") for part in ("hip", "upper", "lower")
)
"""The 12 actuated joints in observation/action order."""
FOOT_LINKS: tuple[str, ...] = ("FR_toe", "FL_toe", "RR_toe", "RL_toe")
"""Foot links in the order of the ``contacts`` feature."""

OBS_LAYOUT: dict[str, slice] = {
    "joint_pos": slice(0, 12),
    "joint_vel": slice(12, 24),
    "gravity": slice(24, 27),
    "base_ang_vel": slice(27, 30),
    "base_lin_vel": slice(30, 33),
    "base_height": slice(33, 34),
    "prev_action": slice(34, 46),
}
"""Slices of the observation vector; see the module docstring."""
OBS_DIM = 46
ACT_DIM = 12
FEATURE_DIMS: dict[str, int] = {"vae_input": 13, "velocity": 2, "contacts": 4}
"""Features in ``info["features"]``: ``vae_input`` = 12 joint angles + base height (input of the
learned VAE feature function), ``velocity`` = (forward velocity in the heading frame, yaw rate),
``contacts`` = FR, FL, RR, RL foot touching the ground (0/1)."""

DAMAGE_SCENARIOS: dict[str, tuple[int, ...]] = {
    "front_hip": (0,),
    "front_upper": (1,),
    "front_lower": (2,),
    "back_hip": (6,),
    "back_upper": (7,),
    "back_lower": (8,),
}
"""The six damage scenarios of §5.2: one frozen joint on the front-right (FR) or rear-right (RR)
leg. Values are indices into ``JOINT_NAMES``."""

_angle = itemgetter(0)  # fields of a getJointStates entry
_velocity = itemgetter(1)
_FOOT_RADIUS = 0.02  # collision sphere of the toe links in a1.urdf
_FREEZE_FORCE = 1000.0  # N·m; far above what gravity and the other motors can apply


@dataclass(frozen=True)
class A1Config:
    """Settings of the reset-free A1 environment (see ``docs/env.md`` for the choices)."""

    task: str = "forward"
    """Reward/cost/safe set: ``forward`` (§5.2) or ``posture`` (§5.3)."""
    forward_cost: str = "paper"
    """Cost of the forward task: ``paper`` (c = 0.7 − r, §5.2) or ``upright`` (c = 0.7 − r_upr,
    the safe set's margin; see ``tasks.forward_reward``). The posture task ignores it."""
    physics_hz: int = 500
    """Physics rate (Hz); must be a multiple of ``control_hz``. DayDreamer used 1000."""
    control_hz: int = 20
    """Rate at which the policy sets joint targets (Hz); the paper's 20 Hz."""
    kp: tuple[float, float, float] = (100.0, 100.0, 100.0)
    """PD proportional gains (N·m/rad) for (hip, upper, lower), as in motion_imitation."""
    kd: tuple[float, float, float] = (1.0, 2.0, 2.0)
    """PD derivative gains (N·m·s/rad) for (hip, upper, lower), as in motion_imitation."""
    torque_limit: float = 33.5
    """Symmetric torque limit of every motor (N·m), motion_imitation's A1 motor limit."""
    standing_pose: tuple[float, float, float] = (0.0, 0.9, -1.8)
    """Standing joint angles (rad) for (hip, upper, lower), motion_imitation's initial pose."""
    joint_low: tuple[float, float, float] = (-0.8, -1.0, -2.68)
    """Lower end of the commandable joint range (rad) for (hip, upper, lower)."""
    joint_high: tuple[float, float, float] = (0.8, 2.8, -0.92)
    """Upper end of the commandable joint range (rad) for (hip, upper, lower)."""
    action_mapping: str = "stand_centered"
    """``stand_centered`` (0 = standing pose) or ``linear`` (DayDreamer: onto [low, high])."""
    action_filter_hz: float | None = None
    """Cut-off (Hz) of a 2nd-order Butterworth low-pass on the joint targets; None: off.
    DayDreamer used 1.5 Hz; off by default because its state is not in the observation."""
    target_speed: float = 0.3
    """Speed (m/s) at which r_velx saturates at 1 and r_vely at 1 (DayDreamer's 0.3)."""
    yaw_rate_scale: float = 1.0
    """Yaw rate (rad/s) at which r_yaw saturates at 1."""
    rescue: bool = True
    """Right the robot in place after ``rescue_after`` consecutive unsafe steps."""
    rescue_after: int = 50
    """Consecutive unsafe control steps (2.5 s at 20 Hz) before a rescue."""
    rescue_on: str = "unsafe"
    """What counts towards a rescue: ``unsafe`` (the task's safe flag) or ``fallen``
    (r_upr <= 0.7, the same as ``unsafe`` for the forward task)."""
    frozen_joints: tuple[int, ...] = ()
    """Indices into ``JOINT_NAMES`` frozen at their initial (standing) angle."""
    damage: str | None = None
    """Name of a ``DAMAGE_SCENARIOS`` preset, added to ``frozen_joints``."""
    init_yaw: float | None = None
    """Initial heading (rad); None: drawn uniformly from the seed."""
    settle_steps: int = 40
    """Control steps of standing still simulated at construction (not counted), long enough
    for the fore-aft rocking after the drop onto the feet to die out (about 2 s)."""
    self_collision: bool = False
    """Enable collisions between the robot's own links (off in motion_imitation by default)."""

    def __post_init__(self) -> None:
        if self.task not in tasks.TASKS:
            raise ValueError(f"task must be one of {tasks.TASKS}, got {self.task!r}")
        if self.forward_cost not in tasks.FORWARD_COSTS:
            raise ValueError(
                f"forward_cost must be one of {tasks.FORWARD_COSTS}, got {self.forward_cost!r}"
            )
        if self.physics_hz % self.control_hz != 0 or self.physics_hz < 500:
            raise ValueError("physics_hz must be >= 500 and a multiple of control_hz")
        if self.action_mapping not in ("stand_centered", "linear"):
            raise ValueError(f"unknown action_mapping {self.action_mapping!r}")
        if self.rescue_on not in ("unsafe", "fallen"):
            raise ValueError(f"unknown rescue_on {self.rescue_on!r}")
        if self.damage is not None and self.damage not in DAMAGE_SCENARIOS:
            raise ValueError(f"damage must be one of {sorted(DAMAGE_SCENARIOS)} or None")
        if any(not 0 <= j < 12 for j in self.frozen_joints):
            raise ValueError("frozen_joints are indices in 0..11")
        for lo, st, hi in zip(self.joint_low, self.standing_pose, self.joint_high, strict=True):
            if not lo < st < hi:
                raise ValueError("need joint_low < standing_pose < joint_high per joint type")
        if self.rescue_after < 1:
            raise ValueError("rescue_after must be >= 1")


def butterworth2(cutoff_hz: float, sample_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """Coefficients (b (3,), a (3,), a[0] = 1) of a 2nd-order Butterworth low-pass (bilinear,
    pre-warped at the cutoff): ``scipy.signal.butter``."""
    b, a = signal.butter(2, cutoff_hz, btype="low", fs=sample_hz)
    return np.asarray(b, float), np.asarray(a, float)


class A1Env(gym.Env[np.ndarray, np.ndarray]):
    """Reset-free A1; see the module docstring. Implements ``ursa.envs.base.ResetFreeEnv``.

    Each PyBullet instance is its own DIRECT client, so many envs can live in one process.
    """

    obs_dim = OBS_DIM
    act_dim = ACT_DIM
    feature_dims: dict[str, int]
    """Dimension of each feature in ``info["features"]`` (a copy of ``FEATURE_DIMS``)."""

    def __init__(self, config: A1Config | None = None, seed: int = 0) -> None:
        self.config = c = config or A1Config()
        self.feature_dims = dict(FEATURE_DIMS)
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (OBS_DIM,), np.float32)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (ACT_DIM,), np.float32)
        self._rng = np.random.default_rng(seed)
        self._dt = 1.0 / c.physics_hz
        self._substeps = c.physics_hz // c.control_hz

        self._stand = np.tile(np.asarray(c.standing_pose, dtype=np.float64), 4)
        self._low = np.tile(np.asarray(c.joint_low, dtype=np.float64), 4)
        self._high = np.tile(np.asarray(c.joint_high, dtype=np.float64), 4)
        self._kp = np.tile(np.asarray(c.kp, dtype=np.float64), 4)
        self._kd = np.tile(np.asarray(c.kd, dtype=np.float64), 4)
        # plain-float copies for the per-step action mapping (cheaper than numpy on 12 floats)
        self._stand_l: list[float] = self._stand.tolist()
        self._up_l: list[float] = (self._high - self._stand).tolist()
        self._down_l: list[float] = (self._stand - self._low).tolist()
        self._low_l: list[float] = self._low.tolist()
        self._range_l: list[float] = (self._high - self._low).tolist()
        if c.action_mapping == "linear":
            self._stand_action = 2.0 * (self._stand - self._low) / (self._high - self._low) - 1.0
        else:
            self._stand_action = np.zeros(ACT_DIM)

        self._cid = cid = pb.connect(pb.DIRECT)
        self._closed = False
        pb.setGravity(0.0, 0.0, -9.8, physicsClientId=cid)
        pb.setTimeStep(self._dt, physicsClientId=cid)
        data = pybullet_data.getDataPath()
        self._plane = pb.loadURDF(f"{data}/plane.urdf", physicsClientId=cid)
        flags = pb.URDF_USE_INERTIA_FROM_FILE
        if c.self_collision:
            flags |= pb.URDF_USE_SELF_COLLISION
        self._robot = robot = pb.loadURDF(
            f"{data}/a1/a1.urdf", [0.0, 0.0, 1.0], flags=flags, physicsClientId=cid
        )
        by_name = {
            pb.getJointInfo(robot, i, physicsClientId=cid)[1].decode(): i
            for i in range(pb.getNumJoints(robot, physicsClientId=cid))
        }
        links = {
            pb.getJointInfo(robot, i, physicsClientId=cid)[12].decode(): i
            for i in range(pb.getNumJoints(robot, physicsClientId=cid))
        }
        self._joint_ids = [by_name[n] for n in JOINT_NAMES]
        self._foot_ids = [links[n] for n in FOOT_LINKS]
        self._foot_slot = {link: k for k, link in enumerate(self._foot_ids)}
        # Disable the default velocity motors so that only our PD torques drive the joints.
        pb.setJointMotorControlArray(
            robot, self._joint_ids, pb.VELOCITY_CONTROL, forces=[0.0] * 12, physicsClientId=cid
        )

        # Standing height from the kinematics: base at z=1, standing joints, lowest foot.
        for j, q in zip(self._joint_ids, self._stand, strict=True):
            pb.resetJointState(robot, j, float(q), 0.0, physicsClientId=cid)
        feet_z = [pb.getLinkState(robot, f, physicsClientId=cid)[0][2] for f in self._foot_ids]
        self._stand_height = 1.0 - min(feet_z) + _FOOT_RADIUS + 0.005

        self._frozen: dict[int, float] = {}
        self._active: list[int] = list(range(12))
        self._refresh_active()

        self._filter_b: np.ndarray | None = None
        self._filter_a: np.ndarray | None = None
        if c.action_filter_hz is not None:
            self._filter_b, self._filter_a = butterworth2(c.action_filter_hz, c.control_hz)
        self._reset_filter()

        self._prev_action: list[float] = self._stand_action.tolist()
        self._steps = 0
        self._reset_calls = 0
        self._rescues = 0
        self._unsafe_run = 0

        yaw = c.init_yaw if c.init_yaw is not None else float(self._rng.uniform(-np.pi, np.pi))
        self._place_standing(0.0, 0.0, yaw)
        frozen = set(c.frozen_joints)
        if c.damage is not None:
            frozen.update(DAMAGE_SCENARIOS[c.damage])
        for j in sorted(frozen):
            self.freeze_joint(j)
        for _ in range(c.settle_steps):
            self._simulate(self._stand_l)
        self._read_state()

    # ------------------------------------------------------------------ simulation

    def _refresh_active(self) -> None:
        self._active = [i for i in range(12) if i not in self._frozen]
        self._act_ids = [self._joint_ids[i] for i in self._active]
        self._act_kp = self._kp[self._active].tolist()
        self._act_kd = self._kd[self._active].tolist()

    def _reset_filter(self) -> None:
        # the filter's state (2, 12) at the standing pose's steady state
        self._fz: np.ndarray | None = None
        if self._filter_b is not None and self._filter_a is not None:
            zi = signal.lfilter_zi(self._filter_b, self._filter_a)
            self._fz = zi[:, None] * self._stand[None, :]

    def _simulate(self, joint_targets: list[float]) -> float:
        """Run one control step of PD torque control; returns r_work (J) of the step.

        ``joint_targets`` (12,) in rad; frozen joints' entries are ignored. This loop is the
        env's hot path: one getJointStates, one setJointMotorControlArray and one
        stepSimulation per substep.
        """
        cid, robot, ids = self._cid, self._robot, self._act_ids
        active = self._active
        targets = joint_targets if len(active) == 12 else [joint_targets[i] for i in active]
        kp, kd, lim = self._act_kp, self._act_kd, self.config.torque_limit
        get_states, set_control, step_sim = (
            pb.getJointStates,
            pb.setJointMotorControlArray,
            pb.stepSimulation,
        )
        torque_mode = pb.TORQUE_CONTROL
        if not ids:  # every joint frozen: nothing to control
            for _ in range(self._substeps):
                step_sim(physicsClientId=cid)
            return 0.0
        power = 0.0
        for _ in range(self._substeps):
            st = get_states(robot, ids, physicsClientId=cid)
            tau = [
                min(max(p * (t - s[0]) - d * s[1], -lim), lim)
                for p, d, t, s in zip(kp, kd, targets, st, strict=True)
            ]
            set_control(robot, ids, torque_mode, forces=tau, physicsClientId=cid)
            step_sim(physicsClientId=cid)
            # r_work: sum |tau * qd| while tau and st are hot in the cache (measured cheaper
            # than one pass over all substeps at the end, and than numpy on 12 floats)
            power += sum(map(abs, map(mul, tau, map(_velocity, st))))
        return power * self._dt

    def _read_state(self) -> None:
        """Read the simulator once (batched calls) and cache what obs, rewards and features use.

        The cache holds plain Python floats: for 3- to 12-vectors that is several times cheaper
        than numpy, and this runs every control step.
        """
        cid, robot = self._cid, self._robot
        st = pb.getJointStates(robot, self._joint_ids, physicsClientId=cid)
        self._q: list[float] = list(map(_angle, st))
        self._qd: list[float] = list(map(_velocity, st))
        self._pos, self._orn = pb.getBasePositionAndOrientation(robot, physicsClientId=cid)
        self._lin, self._ang = pb.getBaseVelocity(robot, physicsClientId=cid)
        # body-to-world rotation, row-major: column k (m[k], m[3+k], m[6+k]) is body axis k
        self._m = pb.getMatrixFromQuaternion(self._orn)
        contacts = [0.0, 0.0, 0.0, 0.0]
        slot = self._foot_slot
        for cp in pb.getContactPoints(robot, self._plane, physicsClientId=cid):
            k = slot.get(cp[3])
            if k is not None:
                contacts[k] = 1.0
        self._contacts = contacts

    def _obs(self) -> np.ndarray:
        m = self._m
        ax, ay, az = self._ang
        lx, ly, lz = self._lin
        # gravity in the base frame is R^T (0, 0, -1); velocities are rotated by R^T
        base = [
            -m[6],
            -m[7],
            -m[8],
            m[0] * ax + m[3] * ay + m[6] * az,
            m[1] * ax + m[4] * ay + m[7] * az,
            m[2] * ax + m[5] * ay + m[8] * az,
            m[0] * lx + m[3] * ly + m[6] * lz,
            m[1] * lx + m[4] * ly + m[7] * lz,
            m[2] * lx + m[5] * ly + m[8] * lz,
            self._pos[2],
        ]
        return np.array(self._q + self._qd + base + self._prev_action, dtype=np.float32)

    def _joint_targets(self, a: list[float]) -> list[float]:
        """Joint targets (12,) in rad for a clipped action a (12,): mapping, then the filter."""
        if self.config.action_mapping == "linear":
            q = [
                lo + 0.5 * (x + 1.0) * r
                for lo, x, r in zip(self._low_l, a, self._range_l, strict=True)
            ]
        else:
            q = [
                s + x * (u if x >= 0.0 else d)
                for s, x, u, d in zip(self._stand_l, a, self._up_l, self._down_l, strict=True)
            ]
        fb, fa = self._filter_b, self._filter_a
        if fb is None or fa is None:
            return q
        y, self._fz = signal.lfilter(fb, fa, np.asarray(q)[None], axis=0, zi=self._fz)
        return list(y[0].tolist())

    def _place_standing(self, x: float, y: float, yaw: float) -> None:
        """Put the robot upright at standing height with standing joints (frozen joints keep
        their frozen angle) and zero velocity at (x, y) facing ``yaw``."""
        cid, robot = self._cid, self._robot
        quat = pb.getQuaternionFromEuler([0.0, 0.0, yaw])
        pb.resetBasePositionAndOrientation(
            robot, [x, y, self._stand_height], quat, physicsClientId=cid
        )
        pb.resetBaseVelocity(robot, [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], physicsClientId=cid)
        for i, j in enumerate(self._joint_ids):
            q = self._frozen.get(i, float(self._stand[i]))
            pb.resetJointState(robot, j, q, 0.0, physicsClientId=cid)
        self._reset_filter()

    # ------------------------------------------------------------------ gymnasium API

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Return the current observation; the simulation is never reset (``ursa.envs.base``).

        ``seed`` only seeds gymnasium's ``self.np_random``, which the simulation does not use:
        the env is seeded once, at construction.
        """
        super().reset(seed=seed)
        self._reset_calls += 1
        info = {"reset_calls": self._reset_calls - 1, "step": self._steps, "rescues": self._rescues}
        return self._obs(), info

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        c = self.config
        # clip to [-1, 1]; NaN becomes 0: one NaN torque would corrupt a simulation that is
        # never reset
        a = [
            -1.0 if x < -1.0 else 1.0 if x > 1.0 else x if x == x else 0.0
            for x in np.asarray(action, dtype=np.float64).reshape(ACT_DIM).tolist()
        ]
        r_work = self._simulate(self._joint_targets(a))
        self._read_state()
        self._steps += 1

        m = self._m
        r_upr = tasks.upright_reward(m[8])
        v_fwd, v_lat, yaw_rate = tasks.heading_velocity((m[0], m[3], m[6]), self._lin, self._ang[2])
        terms: dict[str, float] = {"upr": r_upr}
        if c.task == "forward":
            terms["velx"], terms["vely"], terms["yaw"] = tasks.velocity_terms(
                v_fwd, v_lat, yaw_rate, c.target_speed, c.yaw_rate_scale
            )
        else:
            dev = tasks.posture_deviation(np.array(self._q), self._stand, self._low, self._high)
            terms["hip"], terms["upper"], terms["lower"] = tasks.posture_terms(r_upr, dev)
        terms["speed"] = tasks.speed_penalty(self._qd)
        terms["work"] = r_work
        terms["smooth"] = tasks.smooth_penalty(a, self._prev_action)
        if c.task == "forward":
            reward, cost, safe = tasks.forward_reward(terms, c.forward_cost)
        else:
            reward, cost, safe = tasks.posture_reward(terms)
        self._prev_action = a

        features = {
            "vae_input": np.array([*self._q, self._pos[2]], dtype=np.float32),
            "velocity": np.array([v_fwd, yaw_rate], dtype=np.float32),
            "contacts": np.array(self._contacts, dtype=np.float32),
        }

        bad = (not safe) if c.rescue_on == "unsafe" else r_upr <= tasks.GATE
        self._unsafe_run = self._unsafe_run + 1 if bad else 0
        rescued = False
        if c.rescue and self._unsafe_run >= c.rescue_after:
            self._rescue()
            rescued = True

        info: dict[str, Any] = {
            "reward_terms": terms,
            "cost": cost,
            "safe": safe,
            "features": features,
            "rescues": self._rescues,
            "rescued": rescued,
            "step": self._steps,
            # for live views (after a rescue: the righted pose)
            "joint_angles": np.array(self._q),
            "base_position": np.asarray(self._pos),
            "base_orientation": np.asarray(self._orn),
        }
        return self._obs(), reward, False, False, info

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            pb.disconnect(physicsClientId=self._cid)

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:
            pass  # interpreter shutdown: pybullet may already be gone

    # ------------------------------------------------------------------ rescue, damage, probes

    def _rescue(self) -> None:
        """Right the robot in place: keep x, y and heading, stand it up, zero its velocity."""
        yaw = math.atan2(self._m[3], self._m[0])
        self._place_standing(float(self._pos[0]), float(self._pos[1]), yaw)
        self._rescues += 1
        self._unsafe_run = 0
        self._read_state()

    def freeze_joint(self, index: int, angle: float | None = None) -> None:
        """Freeze joint ``index`` (into ``JOINT_NAMES``) at ``angle`` (default: its current angle).

        The joint is held by a stiff PyBullet position motor (solved implicitly by the
        constraint solver, so it is stable and costs nothing per substep) and ignores actions.
        """
        if not 0 <= index < 12:
            raise ValueError("joint index must be in 0..11")
        jid = self._joint_ids[index]
        if angle is None:
            angle = pb.getJointState(self._robot, jid, physicsClientId=self._cid)[0]
        self._frozen[index] = float(angle)
        pb.setJointMotorControl2(
            self._robot,
            jid,
            pb.POSITION_CONTROL,
            targetPosition=float(angle),
            targetVelocity=0.0,
            positionGain=1.0,
            velocityGain=1.0,
            force=_FREEZE_FORCE,
            physicsClientId=self._cid,
        )
        self._refresh_active()

    def unfreeze_joint(self, index: int) -> None:
        """Repair joint ``index``: it follows the PD controller again."""
        if self._frozen.pop(index, None) is None:
            return
        pb.setJointMotorControl2(
            self._robot,
            self._joint_ids[index],
            pb.VELOCITY_CONTROL,
            force=0.0,
            physicsClientId=self._cid,
        )
        self._refresh_active()

    @property
    def frozen_joints(self) -> dict[int, float]:
        """Frozen joint index -> the angle it is held at."""
        return dict(self._frozen)

    @property
    def rescues(self) -> int:
        return self._rescues

    @property
    def steps(self) -> int:
        return self._steps

    @property
    def standing_height(self) -> float:
        """Base height (m) at which the robot is placed standing (construction, rescue)."""
        return self._stand_height

    @property
    def client_id(self) -> int:
        """The PyBullet client id of this env's simulation."""
        return self._cid

    @property
    def robot_id(self) -> int:
        return self._robot

    def base_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """World base position (3,) and orientation quaternion (x, y, z, w) (4,) after the
        last step, e.g. for visualisation."""
        return np.asarray(self._pos), np.asarray(self._orn)

    def joint_angles(self) -> np.ndarray:
        """The 12 joint angles (rad) after the last step."""
        return np.array(self._q)

    def place(
        self,
        position: Sequence[float] | None = None,
        orientation: Sequence[float] | None = None,
        linear_velocity: Sequence[float] | None = None,
        angular_velocity: Sequence[float] | None = None,
        joint_angles: Sequence[float] | np.ndarray | None = None,
    ) -> np.ndarray:
        """Move the robot (tests, evaluations, demos); what is None is kept. Returns the obs.

        position (3,) m and orientation (x, y, z, w) of the base, velocities (3,) in the world
        frame, joint_angles (12,) rad (frozen joints keep their angle).

        This is not a reset: counters, the previous action and damage are untouched.
        """
        cid, robot = self._cid, self._robot
        if position is not None or orientation is not None:
            pb.resetBasePositionAndOrientation(
                robot,
                list(position) if position is not None else list(self._pos),
                list(orientation) if orientation is not None else list(self._orn),
                physicsClientId=cid,
            )
        if linear_velocity is not None or angular_velocity is not None:
            lin = linear_velocity if linear_velocity is not None else self._lin
            ang = angular_velocity if angular_velocity is not None else self._ang
            pb.resetBaseVelocity(robot, list(lin), list(ang), physicsClientId=cid)
        if joint_angles is not None:
            for i, (j, q) in enumerate(zip(self._joint_ids, joint_angles, strict=True)):
                if i not in self._frozen:
                    pb.resetJointState(robot, j, float(q), 0.0, physicsClientId=cid)
        self._read_state()
        return self._obs()
