"""The reset-free A1: standing, safety, velocity gating, damage, rescue, no resets, determinism."""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterator

import gymnasium as gym
import numpy as np
import pybullet as pb
import pytest

from ursa.envs import (
    DAMAGE_SCENARIOS,
    JOINT_NAMES,
    OBS_DIM,
    OBS_LAYOUT,
    A1Config,
    A1Env,
    PointEnv,
    make_env,
    tasks,
)

STAND = np.zeros(12)  # the standing pose in the default stand-centred action mapping
YAW = 0.7


def make(**overrides: object) -> A1Env:
    return A1Env(A1Config(init_yaw=YAW, **overrides), seed=0)  # type: ignore[arg-type]


def upside_down(env: A1Env) -> None:
    pos, _ = env.base_pose()
    env.place(
        position=(float(pos[0]), float(pos[1]), 0.15),
        orientation=pb.getQuaternionFromEuler([math.pi, 0.0, YAW]),
        linear_velocity=(0.0, 0.0, 0.0),
        angular_velocity=(0.0, 0.0, 0.0),
    )


@pytest.fixture(scope="module")
def standing() -> Iterator[A1Env]:
    env = make()
    yield env
    env.close()


def test_observation_layout_and_spaces(standing: A1Env) -> None:
    stops = sorted((s.start, s.stop) for s in OBS_LAYOUT.values())
    assert stops[0][0] == 0 and stops[-1][1] == OBS_DIM
    assert all(a[1] == b[0] for a, b in itertools.pairwise(stops))
    obs, _ = standing.reset()
    assert obs.shape == (OBS_DIM,) and obs.dtype == np.float32
    assert isinstance(standing.observation_space, gym.spaces.Box)
    assert standing.observation_space.contains(obs)
    assert standing.action_space.shape == (12,)
    assert standing.feature_dims == {"vae_input": 13, "velocity": 2, "contacts": 4}
    assert len(JOINT_NAMES) == 12 and JOINT_NAMES[1] == "FR_upper_joint"


def test_standing_pose_is_upright_and_safe(standing: A1Env) -> None:
    obs, reward, terminated, truncated, info = standing.step(STAND)
    terms = info["reward_terms"]
    assert set(terms) == set(tasks.FORWARD_TERMS)
    assert terms["upr"] == pytest.approx(1.0, abs=1e-3)
    assert info["safe"] and not terminated and not truncated
    # standing still: r ≈ r_upr = 1, so the paper's c = 0.7 − r ≈ −0.3
    assert info["cost"] == pytest.approx(0.7 - reward)
    assert info["cost"] == pytest.approx(-0.3, abs=0.05)
    np.testing.assert_allclose(obs[OBS_LAYOUT["gravity"]], [0.0, 0.0, -1.0], atol=0.01)
    np.testing.assert_allclose(
        obs[OBS_LAYOUT["joint_pos"]], np.tile([0.0, 0.9, -1.8], 4), atol=0.06
    )
    assert 0.24 < obs[OBS_LAYOUT["base_height"]][0] < 0.28
    feats = info["features"]
    assert {k: v.shape[0] for k, v in feats.items()} == standing.feature_dims
    assert feats["contacts"].tolist() == [1.0, 1.0, 1.0, 1.0]
    np.testing.assert_allclose(feats["vae_input"][:12], obs[OBS_LAYOUT["joint_pos"]])
    assert feats["vae_input"][12] == pytest.approx(obs[33])
    assert np.abs(feats["velocity"]).max() < 0.05
    # the reward is the paper's formula of the reported terms
    assert reward == pytest.approx(tasks.forward_reward(terms)[0])


def test_upside_down_is_unsafe_with_the_paper_cost() -> None:
    env = make(rescue=False)
    upside_down(env)
    for _ in range(3):
        _, reward, _, _, info = env.step(STAND)
    terms = info["reward_terms"]
    assert terms["upr"] < 0.01  # up_z ≈ −1
    assert not info["safe"]
    # gated: r = r_upr − 0.001·(speed + work + smooth); c = 0.7 − r
    reg = 0.001 * (terms["speed"] + terms["work"] + terms["smooth"])
    assert reward == pytest.approx(terms["upr"] - reg)
    assert info["cost"] == pytest.approx(0.7 - terms["upr"] + reg)
    assert 0.69 < info["cost"] < 0.8
    assert info["features"]["contacts"].sum() == 0  # feet in the air
    env.close()


def test_upright_cost_is_read_from_the_env_config() -> None:
    env = make(rescue=False, forward_cost="upright")
    _, reward, _, _, info = env.step(STAND)
    assert info["cost"] == pytest.approx(0.7 - info["reward_terms"]["upr"])
    assert info["cost"] != pytest.approx(0.7 - reward, abs=1e-6)
    upside_down(env)
    for _ in range(3):
        _, _, _, _, info = env.step(STAND)
    assert info["cost"] == pytest.approx(0.7 - info["reward_terms"]["upr"])
    assert not info["safe"] and info["cost"] > 0.69
    env.close()
    with pytest.raises(ValueError, match="forward_cost"):
        A1Config(forward_cost="speed")


def test_forward_velocity_raises_the_reward_only_while_upright() -> None:
    env = make(rescue=False)
    heading = (math.cos(YAW), math.sin(YAW), 0.0)
    fast = tuple(1.0 * h for h in heading)
    env.step(STAND)
    env.place(linear_velocity=fast)
    _, reward, _, _, info = env.step(STAND)
    terms = info["reward_terms"]
    assert info["safe"] and terms["velx"] > 0.5
    assert info["features"]["velocity"][0] > 0.15
    assert reward > terms["upr"] + 5 * terms["velx"] - 1.0
    assert info["cost"] < -2.0
    # backwards while upright: safe, but the paper's cost is positive
    env.place(linear_velocity=tuple(-v for v in fast))
    _, _, _, _, info = env.step(STAND)
    assert info["safe"] and info["reward_terms"]["velx"] < -0.5 and info["cost"] > 0
    # the same push upside down: r_velx is measured but gated out of the reward
    upside_down(env)
    env.step(STAND)
    env.place(linear_velocity=fast)
    _, reward, _, _, info = env.step(STAND)
    terms = info["reward_terms"]
    assert not info["safe"] and terms["velx"] > 0.5
    reg = 0.001 * (terms["speed"] + terms["work"] + terms["smooth"])
    assert reward == pytest.approx(terms["upr"] - reg)
    env.close()


def test_posture_task_standing_is_safe_and_gated() -> None:
    env = make(task="posture", rescue=False)
    _, reward, _, _, info = env.step(STAND)
    terms = info["reward_terms"]
    assert set(terms) == set(tasks.POSTURE_TERMS)
    assert all(terms[k] > 0.9 for k in ("upr", "hip", "upper", "lower"))
    assert info["safe"] and info["cost"] < 0
    assert reward == pytest.approx(3.9, abs=0.1)
    # thighs far from the standing pose: r_upper drops below 0.7, r_lower is gated off
    action = np.tile([0.0, 1.0, 0.0], 4)
    for _ in range(10):
        _, _, _, _, info = env.step(action)
    terms = info["reward_terms"]
    assert terms["upr"] > 0.7 and terms["hip"] > 0.7
    assert terms["upper"] < 0.7 and terms["lower"] == 0.0
    assert not info["safe"] and info["cost"] > 0.7
    env.close()


def test_frozen_joint_keeps_its_angle_under_commands() -> None:
    env = make(frozen_joints=(1,), rescue=False)
    frozen_angle = env.frozen_joints[1]
    assert frozen_angle == pytest.approx(0.9)
    rng = np.random.default_rng(0)
    other = []
    for _ in range(40):
        env.step(rng.uniform(-1.0, 1.0, 12))
        q = env.joint_angles()
        assert q[1] == pytest.approx(frozen_angle, abs=5e-3)
        other.append(q[4])
    assert np.ptp(other) > 0.5  # the intact joints follow the commands
    # freezing at run time holds the joint where it is, not at the standing pose
    for _ in range(5):
        env.step(np.r_[np.zeros(2), 1.0, np.zeros(9)])
    env.freeze_joint(2)
    held = env.frozen_joints[2]
    assert held > -1.5  # calf moved towards joint_high
    for _ in range(10):
        env.step(-np.ones(12))
        assert env.joint_angles()[2] == pytest.approx(held, abs=5e-3)
    env.unfreeze_joint(2)
    env.step(-np.ones(12))
    assert env.joint_angles()[2] < held - 0.2
    env.close()


def test_damage_presets_freeze_one_right_leg_joint() -> None:
    names = {k: JOINT_NAMES[v[0]] for k, v in DAMAGE_SCENARIOS.items()}
    assert names == {
        "front_hip": "FR_hip_joint",
        "front_upper": "FR_upper_joint",
        "front_lower": "FR_lower_joint",
        "back_hip": "RR_hip_joint",
        "back_upper": "RR_upper_joint",
        "back_lower": "RR_lower_joint",
    }
    env = make(damage="back_lower", rescue=False)
    assert set(env.frozen_joints) == {8}
    for _ in range(10):
        env.step(np.ones(12))
    assert env.joint_angles()[8] == pytest.approx(-1.8, abs=5e-3)
    env.close()
    with pytest.raises(ValueError):
        A1Config(damage="left_ear")


def test_rescue_fires_after_the_configured_unsafe_steps_and_is_counted() -> None:
    env = make(rescue_after=5)
    upside_down(env)
    pos_before, _ = env.base_pose()
    for k in range(1, 6):
        obs, _, _, _, info = env.step(STAND)
        assert not info["safe"]  # the step's own state, before the rescue
        assert info["rescued"] == (k == 5)
    assert info["rescues"] == 1 and env.rescues == 1
    # righted in place: same x, y and heading, upright, standing joints
    pos_after, orn_after = env.base_pose()
    assert np.hypot(*(pos_after[:2] - pos_before[:2])) < 0.1
    assert pb.getEulerFromQuaternion(orn_after)[2] == pytest.approx(YAW, abs=0.1)
    np.testing.assert_allclose(obs[OBS_LAYOUT["gravity"]], [0.0, 0.0, -1.0], atol=1e-6)
    np.testing.assert_allclose(
        obs[OBS_LAYOUT["joint_pos"]], np.tile([0.0, 0.9, -1.8], 4), atol=1e-6
    )
    for _ in range(10):
        _, _, _, _, info = env.step(STAND)
        assert info["safe"] and not info["rescued"]
    assert info["rescues"] == 1
    env.close()


def test_rescue_can_be_disabled() -> None:
    env = make(rescue=False, rescue_after=2)
    upside_down(env)
    for _ in range(10):
        _, _, _, _, info = env.step(STAND)
        assert not info["rescued"]
    assert info["rescues"] == 0 and not info["safe"]
    env.close()


def test_no_reset_over_10000_random_steps() -> None:
    env = A1Env(A1Config(), seed=3)
    env.reset()
    start, _ = env.base_pose()
    rng = np.random.default_rng(3)
    path = []
    for t in range(1, 10_001):
        obs, _, terminated, truncated, info = env.step(rng.uniform(-1.0, 1.0, 12))
        assert not terminated and not truncated
        if t % 1000 == 0:
            assert info["step"] == t
            path.append(env.base_pose()[0][:2].copy())
    assert info["step"] == 10_000 and env.steps == 10_000
    assert info["rescues"] > 0  # random actions fall over; the rescues kept it going
    # the base kept moving from where it was: no teleport back to the start between checks
    path_arr = np.asarray(path)
    assert np.linalg.norm(path_arr[-1] - start[:2]) > 0.5
    assert np.all(np.linalg.norm(np.diff(path_arr, axis=0), axis=1) > 0.0)
    # reset() returns the current observation and moves nothing
    pos, orn = env.base_pose()
    obs_r, info_r = env.reset()
    np.testing.assert_array_equal(obs_r, obs)
    assert info_r["step"] == 10_000 and info_r["reset_calls"] == 1
    pos_r, orn_r = env.base_pose()
    np.testing.assert_array_equal(pos_r, pos)
    np.testing.assert_array_equal(orn_r, orn)
    _, _, _, _, info = env.step(np.zeros(12))
    assert info["step"] == 10_001
    assert np.linalg.norm(env.base_pose()[0][:2] - pos[:2]) < 0.2  # continues from there
    env.close()


def test_same_seed_and_actions_give_the_same_trajectory() -> None:
    rng = np.random.default_rng(7)
    actions = rng.uniform(-1.0, 1.0, size=(150, 12))

    def run(seed: int, env_b: A1Env | None = None) -> tuple[np.ndarray, np.ndarray]:
        env = A1Env(A1Config(rescue_after=10), seed=seed)
        obs, rews = [], []
        for a in actions:
            o, r, _, _, info = env.step(a)
            obs.append(o)
            rews.append((r, info["cost"], info["rescues"]))
        env.close()
        return np.asarray(obs), np.asarray(rews)

    # two envs alive in one process at the same time (own PyBullet clients)
    other = A1Env(A1Config(), seed=99)
    other.step(np.ones(12))
    obs_a, rew_a = run(5)
    obs_b, rew_b = run(5)
    other.close()
    np.testing.assert_array_equal(obs_a, obs_b)
    np.testing.assert_array_equal(rew_a, rew_b)
    obs_c, _ = run(6)  # another seed, another initial heading
    assert not np.array_equal(obs_a, obs_c)


def test_action_mapping_and_filter() -> None:
    lin = make(action_mapping="linear", joint_low=(-0.8, -1.0, -2.7), joint_high=(0.8, 3.0, -0.9))
    obs, _ = lin.reset()
    # prev_action starts at the action of the standing pose: (0, −0.05, 0) in normalised units
    np.testing.assert_allclose(
        obs[OBS_LAYOUT["prev_action"]], np.tile([0.0, -0.05, 0.0], 4), atol=1e-6
    )
    lin.close()
    env_f = make(action_filter_hz=1.5, rescue=False)
    env_u = make(rescue=False)
    a = np.tile([0.0, 0.0, 1.0], 4)  # calves to joint_high
    start_f, start_u = env_f.joint_angles()[2], env_u.joint_angles()[2]
    for _ in range(3):
        env_f.step(a)
        env_u.step(a)
    moved_f = env_f.joint_angles()[2] - start_f
    moved_u = env_u.joint_angles()[2] - start_u
    assert 0.0 < moved_f < 0.5 * moved_u  # the 1.5 Hz low-pass slows the target down
    env_f.close()
    env_u.close()


def test_make_env() -> None:
    env = make_env("a1", seed=1, task="posture", rescue=False)
    assert isinstance(env, A1Env) and env.config.task == "posture" and not env.config.rescue
    env.close()
    point = make_env("point", seed=2, max_speed=0.05)
    assert isinstance(point, PointEnv) and point.config.max_speed == 0.05
    with pytest.raises(ValueError):
        make_env("cartpole")
    with pytest.raises(ValueError):
        make_env("a1", task="backflip")


def test_actions_are_clipped_and_nan_is_neutral() -> None:
    env = make(rescue=False)
    obs, _, _, _, info = env.step(np.full(12, 5.0))
    np.testing.assert_array_equal(obs[OBS_LAYOUT["prev_action"]], np.ones(12))
    assert info["reward_terms"]["smooth"] == pytest.approx(12.0)  # from the standing action 0
    action = np.zeros(12)
    action[3] = np.nan  # a broken policy must not corrupt a simulation that is never reset
    for _ in range(5):
        obs, reward, _, _, info = env.step(action)
    assert np.isfinite(obs).all() and math.isfinite(reward)
    assert obs[OBS_LAYOUT["prev_action"]][3] == 0.0
    env.close()
