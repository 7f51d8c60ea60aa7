"""The one evaluation rollout (``ursa.eval.rollout``): what it measures equals stepping the env
by hand with the recorded actions; uniform actions score the provided feature; a rescue starts a
new recurrent state; one skill's evaluation (``run_skill``) is the K = 1 case, seeded."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from tests.ursa.envs.rescued import RescuedPoint
from ursa.config import preset
from ursa.envs.point import PointEnv
from ursa.eval.rollout import execute_skills, run_skill
from ursa.policy import Policy
from ursa.scoring import settle_steps, skill_distance

torch.set_num_threads(1)


def _policy(seed: int = 1) -> Policy:
    cfg = preset("tiny", "point")
    env = PointEnv()
    return Policy(cfg.learner, env.obs_dim, env.act_dim, 2, 2, seed=seed)


@pytest.mark.parametrize("with_policy", [False, True])
def test_rollout_equals_stepping_by_hand(with_policy: bool) -> None:
    skills = np.array([[0.5, -0.4], [-0.3, 0.6]])
    steps = 40
    pol = _policy() if with_policy else None
    r = execute_skills(
        pol,
        PointEnv(seed=3),
        skills,
        steps,
        record=("position",),
        phi_key="position",
        keep_obs=True,
        keep_actions=True,
        seed=9,
        progress=False,
    )
    assert r.actions is not None and r.obs is not None and r.achieved is not None
    assert r.settle == settle_steps(steps) == 8
    env = PointEnv(seed=3)
    env.reset()
    for i in range(len(skills)):
        ret, unsafe, pos = 0.0, 0, []
        for t in range(steps):
            obs, rew, _, _, info = env.step(r.actions[i, t])
            np.testing.assert_allclose(obs, r.obs[i, t], atol=1e-5)
            ret += rew
            unsafe += not info["safe"]
            pos.append(info["features"]["position"])
        assert r.returns[i] == pytest.approx(ret, rel=1e-6)
        assert r.unsafe_steps[i] == unsafe and r.violation_rate[i] == unsafe / steps
        # φ of the point env is the position (provided): its mean after the settle period
        np.testing.assert_allclose(r.achieved[i], np.mean(pos[8:], 0), atol=1e-5)
        np.testing.assert_allclose(r.means["position"][i], np.mean(pos[8:], 0), atol=1e-5)
    if not with_policy:  # uniform actions, drawn from the seed's generator
        draws = np.random.default_rng(9).uniform(-1.0, 1.0, (2 * steps, 2))
        np.testing.assert_allclose(r.actions.reshape(-1, 2), draws, rtol=1e-6)


def test_random_actions_on_a_learned_feature_score_its_encoding_per_step() -> None:
    """Random actions with ``encode`` (a learned φ): the achieved skill is the mean of the
    encoded steps, not the encoding of the mean input (a non-linear encoder differs)."""

    def encode(x: np.ndarray) -> np.ndarray:  # (n, 2) -> (n, 1)
        return x[:, :1] ** 2 * 3.0

    steps = 40
    r = execute_skills(
        None,
        PointEnv(seed=3),
        np.zeros((2, 1)),
        steps,
        phi_key="position",
        keep_actions=True,
        seed=9,
        progress=False,
        encode=encode,
    )
    assert r.actions is not None and r.achieved is not None
    env = PointEnv(seed=3)
    env.reset()
    for i in range(2):
        pos = np.array([env.step(r.actions[i, t])[4]["features"]["position"] for t in range(steps)])
        want = encode(pos[8:]).mean(0)
        np.testing.assert_allclose(r.achieved[i], want, atol=1e-5)
        assert abs(float(encode(pos[8:].mean(0, keepdims=True))[0, 0]) - want[0]) > 1e-3


def test_rollout_depends_on_its_seed_only() -> None:
    pol = _policy()
    z = np.array([[0.2, 0.1]])
    a = execute_skills(pol, PointEnv(seed=1), z, 30, phi_key="position", seed=4, progress=False)
    execute_skills(pol, PointEnv(seed=1), z, 30, phi_key="position", seed=5, progress=False)
    b = execute_skills(pol, PointEnv(seed=1), z, 30, phi_key="position", seed=4, progress=False)
    assert a.achieved is not None and b.achieved is not None
    np.testing.assert_array_equal(a.achieved, b.achieved)  # the call in between changes nothing
    assert a.returns[0] == b.returns[0]


def test_a_rescue_starts_a_new_recurrent_state() -> None:
    pol = _policy()
    orig = pol.initial_carry

    def carry_starts(env: RescuedPoint) -> tuple[list[int], int]:
        """Env steps at which the rollout asked for a fresh carry, and its rescue count."""
        starts: list[int] = []

        def spy():  # type: ignore[no-untyped-def]
            starts.append(env.n)
            return orig()

        pol.initial_carry = spy  # type: ignore[method-assign]
        r = execute_skills(pol, env, np.zeros((2, 2)), 20, phi_key="position", progress=False)
        return starts, r.rescues

    # one carry at the start, and one after each rescue (steps 7 and 30 are the 8th and 31st)
    assert carry_starts(RescuedPoint({7, 30})) == ([0, 8, 31], 2)
    # without rescues the carry runs on across skills (reset-free)
    assert carry_starts(RescuedPoint(set())) == ([0], 0)


def test_run_skill_is_one_seeded_evaluation() -> None:
    cov = np.array([[0.05, 0.01], [0.01, 0.08]])
    z = np.array([0.5, -0.4])
    pol = _policy()
    one = run_skill(pol, PointEnv(seed=4), z, 60, "position", cov, seed=3)
    ref = execute_skills(
        pol, PointEnv(seed=4), z[None], 60, phi_key="position", seed=3, progress=False
    )
    assert ref.achieved is not None
    np.testing.assert_array_equal(one.achieved, ref.achieved[0])
    assert one.distance == pytest.approx(float(skill_distance(ref.achieved[0], z, cov)))
    assert one.ret == ref.returns[0] and one.violations == ref.unsafe_steps[0]
    assert one.steps == 60 and one.elapsed_s > 0
    # the mode and the sampled policy act differently (explore is passed through)
    mode = run_skill(pol, PointEnv(seed=4), z, 60, "position", cov, explore=False, seed=3)
    assert not np.array_equal(mode.achieved, one.achieved)
