"""Claim: the reset-free A1 env costs little over a bare PyBullet loop (target ratio >= 0.9).

Measures control steps per second of ``ursa.envs.a1.A1Env`` (every reward term, cost, safe flag,
feature and the observation computed) and of a bare PyBullet loop that simulates the same robot
with the same physics settings and the same control: the same URDF, plane, time step, substeps,
action-to-target mapping and PD torque computation at every substep, but nothing else (no
observation, reward, cost, features or contacts). Both run the same random action sequence from
the same standing start (so they simulate identical physics: the script checks it), in the same
process, in alternating blocks of 20 steps. The env runs with rescue off so that both simulate the
same physics; a row with rescue on is printed for information. Each block is timed three times
from the same saved PyBullet state and the best time is kept, as timeit does, because load from
other processes on a shared machine only makes a run slower. Rates and the ratio are per CPU
second of this process; wall-clock rates are printed beside them.

    .venv/bin/python benchmarks/env_throughput.py [--quick] [--physics-hz 500]

The last line is ``RESULT ratio=<env/bare> env_steps_per_s=<env>``.
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np
import pybullet as pb
import pybullet_data

from ursa.envs.a1 import JOINT_NAMES, A1Config, A1Env


class BareA1:
    """The minimal loop a user would write to run the A1 under 20 Hz PD position control."""

    def __init__(self, config: A1Config, standing_height: float) -> None:
        c = config
        self.cid = cid = pb.connect(pb.DIRECT)
        pb.setGravity(0.0, 0.0, -9.8, physicsClientId=cid)
        pb.setTimeStep(1.0 / c.physics_hz, physicsClientId=cid)
        data = pybullet_data.getDataPath()
        pb.loadURDF(f"{data}/plane.urdf", physicsClientId=cid)
        self.robot = robot = pb.loadURDF(
            f"{data}/a1/a1.urdf",
            [0.0, 0.0, 1.0],
            flags=pb.URDF_USE_INERTIA_FROM_FILE,
            physicsClientId=cid,
        )
        names = {
            pb.getJointInfo(robot, i, physicsClientId=cid)[1].decode(): i
            for i in range(pb.getNumJoints(robot, physicsClientId=cid))
        }
        self.ids = [names[n] for n in JOINT_NAMES]
        pb.setJointMotorControlArray(
            robot, self.ids, pb.VELOCITY_CONTROL, forces=[0.0] * 12, physicsClientId=cid
        )
        self.substeps = c.physics_hz // c.control_hz
        self.stand = np.tile(c.standing_pose, 4)
        self.low = np.tile(c.joint_low, 4)
        self.high = np.tile(c.joint_high, 4)
        self.kp = np.tile(c.kp, 4).tolist()
        self.kd = np.tile(c.kd, 4).tolist()
        self.lim = c.torque_limit
        self.config = c
        # Start exactly as A1Env does (same calls in the same order: stand the robot up at the
        # standing height, let it settle), so that both loops simulate identical physics.
        for j, q in zip(self.ids, self.stand, strict=True):
            pb.resetJointState(robot, j, float(q), 0.0, physicsClientId=cid)
        pb.resetBasePositionAndOrientation(
            robot, [0.0, 0.0, standing_height], [0.0, 0.0, 0.0, 1.0], physicsClientId=cid
        )
        pb.resetBaseVelocity(robot, [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], physicsClientId=cid)
        for j, q in zip(self.ids, self.stand, strict=True):
            pb.resetJointState(robot, j, float(q), 0.0, physicsClientId=cid)
        for _ in range(c.settle_steps):
            self.step(np.zeros(12))

    def step(self, action: np.ndarray) -> None:
        a = np.clip(action, -1.0, 1.0)
        targets = self.stand + np.where(
            a >= 0.0, a * (self.high - self.stand), a * (self.stand - self.low)
        )
        tl = targets.tolist()
        cid, robot, ids, kp, kd, lim = self.cid, self.robot, self.ids, self.kp, self.kd, self.lim
        for _ in range(self.substeps):
            st = pb.getJointStates(robot, ids, physicsClientId=cid)
            tau = [
                min(max(p * (t - s[0]) - d * s[1], -lim), lim)
                for p, d, t, s in zip(kp, kd, tl, st, strict=True)
            ]
            pb.setJointMotorControlArray(
                robot, ids, pb.TORQUE_CONTROL, forces=tau, physicsClientId=cid
            )
            pb.stepSimulation(physicsClientId=cid)

    def base_position(self) -> np.ndarray:
        pos, _ = pb.getBasePositionAndOrientation(self.robot, physicsClientId=self.cid)
        return np.asarray(pos)

    def close(self) -> None:
        pb.disconnect(physicsClientId=self.cid)


def timed(loop: object, block: np.ndarray) -> tuple[float, float, int]:
    """(CPU seconds, wall seconds, safe steps) of running ``block`` of actions through ``loop``."""
    w0, c0 = time.perf_counter(), time.process_time()
    safe = 0
    if isinstance(loop, A1Env):
        for a in block:
            safe += loop.step(a)[4]["safe"]
    else:
        assert isinstance(loop, BareA1)
        for a in block:
            loop.step(a)
    return time.process_time() - c0, time.perf_counter() - w0, safe


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="finish within 60 s")
    parser.add_argument("--physics-hz", type=int, default=A1Config.physics_hz)
    parser.add_argument("--steps", type=int, default=None, help="control steps per loop")
    parser.add_argument("--block", type=int, default=20, help="control steps per timed block")
    parser.add_argument("--repeats", type=int, default=3, help="timings of each block (best kept)")
    args = parser.parse_args()
    steps = args.steps or (1000 if args.quick else 5000)
    blocks = max(1, steps // args.block)
    steps = blocks * args.block

    config = A1Config(physics_hz=args.physics_hz, rescue=False, init_yaw=0.0)
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1.0, 1.0, size=(blocks, args.block, 12)).astype(np.float32)

    env = A1Env(config, seed=0)
    env_rescue = A1Env(A1Config(physics_hz=args.physics_hz, init_yaw=0.0), seed=0)
    bare = BareA1(config, env.standing_height)
    keys = ("bare", "env", "env_rescue")
    cpu: dict[str, list[float]] = {k: [] for k in keys}
    wall: dict[str, list[float]] = {k: [] for k in keys}
    safe = 0
    for block in actions:
        # Each block is timed `repeats` times from the same saved physics state and the best
        # time is kept (as timeit does): other processes on a shared machine only ever make a
        # run slower. Blocks alternate between the loops, and CPU time counts this process only.
        saved = {
            "bare": pb.saveState(physicsClientId=bare.cid),
            "env": pb.saveState(physicsClientId=env.client_id),
        }
        best = {k: (math.inf, math.inf) for k in ("bare", "env")}
        for r in range(args.repeats):
            for key, loop, cid in (("bare", bare, bare.cid), ("env", env, env.client_id)):
                if r:
                    pb.restoreState(stateId=saved[key], physicsClientId=cid)
                dc, dw, _ = timed(loop, block)
                best[key] = (min(best[key][0], dc), min(best[key][1], dw))
        pb.removeState(saved["bare"], physicsClientId=bare.cid)
        pb.removeState(saved["env"], physicsClientId=env.client_id)
        dc, dw, n_safe = timed(env_rescue, block)  # once: for information only
        safe += n_safe
        for key in ("bare", "env"):
            cpu[key].append(best[key][0])
            wall[key].append(best[key][1])
        cpu["env_rescue"].append(dc)
        wall["env_rescue"].append(dw)
    same = bool(np.array_equal(bare.base_position(), env.base_pose()[0]))
    rate = {k: steps / float(np.sum(cpu[k])) for k in keys}
    wall_rate = {k: steps / float(np.sum(wall[k])) for k in keys}
    ratio = rate["env"] / rate["bare"]
    block_ratio = float(np.median(np.asarray(cpu["bare"]) / np.asarray(cpu["env"])))

    substeps = config.physics_hz // config.control_hz
    print(
        f"A1 throughput: {steps} control steps per loop, {blocks} blocks of {args.block}, "
        f"best of {args.repeats} per block; physics {config.physics_hz} Hz, {substeps} "
        f"substeps per {config.control_hz} Hz control step; uniform random actions"
    )
    header = ["loop", "steps/s (CPU)", "steps/s (wall)", "ms/step", "vs bare"]
    print(f"{header[0]:<32}{header[1]:>15}{header[2]:>16}{header[3]:>10}{header[4]:>10}")
    rows = [
        ("bare pybullet + PD (reference)", "bare"),
        ("A1Env, rescue off", "env"),
        ("A1Env, rescue on (1 run, info)", "env_rescue"),
    ]
    for label, key in rows:
        print(
            f"{label:<32}{rate[key]:>15.1f}{wall_rate[key]:>16.1f}{1e3 / rate[key]:>10.3f}"
            f"{rate[key] / rate['bare']:>10.3f}"
        )
    overhead = 1e6 * (1.0 / rate["env"] - 1.0 / rate["bare"])
    print(
        f"env overhead per control step: {overhead:.1f} us CPU; median per-block ratio "
        f"{block_ratio:.3f}; wall-clock ratio {wall_rate['env'] / wall_rate['bare']:.3f}; "
        f"identical physics in env and bare loop: {same}; with rescue: "
        f"{env_rescue.rescues} rescues, safe fraction {safe / steps:.3f}"
    )
    env.close()
    env_rescue.close()
    bare.close()
    print(f"RESULT ratio={ratio:.3f} env_steps_per_s={rate['env']:.1f}")


if __name__ == "__main__":
    main()
