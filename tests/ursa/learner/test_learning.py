"""Learning on the point env (CPU, a few minutes): URSA agents trained with the provided
feature φ = position (``ursa-supervised``) for each of :data:`tests.trained.SEEDS` and a
DayDreamer agent (reward only), all by the single-process loop with the ``point`` preset
(:mod:`tests.trained`, shared with the eval suite's and the evaluator's tests, trained once per
session), then run in the real env on skills sampled from each URSA repertoire's KDE and scored
by the one rule of :mod:`ursa.scoring`. Claims hold for the median and the worst seed.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch

from tests.trained import SEEDS, SKILL_PERIOD, point_config
from ursa import kde
from ursa.envs.point import PointEnv
from ursa.eval.loading import load_run, read_checkpoint
from ursa.learner import Learner
from ursa.learner_config import LearnerConfig
from ursa.replay import Replay
from ursa.serial import EvalResult, evaluate_skills

pytestmark = [pytest.mark.slow, pytest.mark.timeout(1800)]

EVAL_SKILLS = 60
"""Skills drawn from the URSA repertoire's KDE for the evaluation, T steps each."""
EVAL_T = SKILL_PERIOD
WITHIN_MEDIAN = 0.75
"""Fraction of KDE skills executed within δ: the median over seeds reaches it..."""
WITHIN_WORST = 0.6
"""...and every seed reaches this."""
RANDOM_WITHIN = 0.2
"""Random actions and DayDreamer's policy execute at most this fraction within δ."""


def _heldout(steps: int = 1200, seed: int = 100) -> dict[str, np.ndarray]:
    """A fixed batch (8 × 64) of random-walk data from another env seed (never trained on)."""
    env = PointEnv(seed=seed)
    env.reset()
    rng = np.random.default_rng(seed)
    rows: dict[str, list[Any]] = {k: [] for k in ("obs", "action", "reward", "cost", "safe")}
    rows["features"], rows["skill"] = [], []
    for _ in range(steps):
        a = rng.uniform(-1, 1, 2)
        obs, r, _, _, info = env.step(a)
        for k, v in (("obs", obs), ("action", a), ("reward", r), ("cost", info["cost"])):
            rows[k].append(v)
        rows["safe"].append(info["safe"])
        rows["features"].append(info["features"]["position"])
        rows["skill"].append(np.zeros(2))
    rep = Replay(steps)
    rep.add("heldout", {k: np.asarray(v) for k, v in rows.items()}, 0)
    return rep.sample(8, 64, np.random.default_rng(0))


def _prediction_loss(m: dict[str, float]) -> float:
    return m["wm/decoder"] + m["wm/reward"] + m["wm/cost"] + m["wm/phi"]


def _learner(run_dir: Path | None, lc: LearnerConfig) -> Learner:
    """The learner of config ``lc`` from the run's checkpoint (``None``: the same learner before
    training)."""
    learner = Learner(lc, PointEnv.obs_dim, PointEnv.act_dim, 2)
    if run_dir is not None:
        learner.load_state_dict(read_checkpoint(run_dir / "checkpoints" / "learner.pt"))
    return learner


def assess(run_dir: Path, label: str, recipe: bool = True) -> dict[str, Any]:
    """Evaluate a trained point-env URSA run directory the way these tests judge it: held-out
    prediction loss before and after, and K KDE skills executed in the real env by the trained
    policy and by random actions. ``recipe``: the run must have been trained with the point
    recipe (False: a variant, as ``scripts/point_seeds.py --set`` trains)."""
    torch.set_num_threads(1)
    run = load_run(run_dir)
    seed = run.config.learner.seed
    lc = run.config.learner
    if recipe:
        assert lc == point_config("ursa-supervised", seed).learner, lc
    learner = _learner(run_dir, lc)
    heldout = _heldout()
    initial = _learner(None, lc).world_model_loss(heldout)
    final = learner.world_model_loss(heldout)
    rep = run.require_repertoire()
    skills = rep.sample(EVAL_SKILLS, np.random.default_rng(1))
    cov, delta = rep.cov, rep.delta()
    res = evaluate_skills(run.require_policy(), PointEnv(seed=11), skills, EVAL_T, cov, record=True)
    rnd = evaluate_skills(None, PointEnv(seed=11), skills, EVAL_T, cov, record=True)
    out = {
        "learner": learner,
        "initial": initial,
        "final": final,
        "skills": skills,
        "cov": cov,
        "delta": delta,
        "eval": res,
        "random": rnd,
    }
    print(
        f"\n{label}: {learner.updates} updates; δ = {delta:.3f}; within δ: ursa "
        f"{res.within(delta).mean():.3f}, random {rnd.within(delta).mean():.3f}; violations: "
        f"ursa {res.violation_rate.mean():.4f}, random {rnd.violation_rate.mean():.4f}; "
        f"prediction loss {_prediction_loss(initial):.3f} -> {_prediction_loss(final):.3f}"
    )
    return out


@pytest.fixture(scope="module")
def ursa_runs(point_runs: dict[str, Any]) -> list[dict[str, Any]]:
    secs = point_runs["seconds"]
    return [
        assess(point_runs["runs"][f"ursa-s{s}"], f"URSA serial run, seed {s} ({secs} s)")
        for s in SEEDS
    ]


@pytest.fixture(scope="module")
def ursa_run(ursa_runs: list[dict[str, Any]]) -> dict[str, Any]:
    return ursa_runs[0]


@pytest.fixture(scope="module")
def daydreamer_eval(point_runs: dict[str, Any], ursa_run: dict[str, Any]) -> EvalResult:
    torch.set_num_threads(1)
    run = load_run(point_runs["runs"]["daydreamer"])
    assert run.mode == "daydreamer"
    res = evaluate_skills(
        run.require_policy(), PointEnv(seed=11), ursa_run["skills"], EVAL_T, ursa_run["cov"]
    )
    print(
        f"\nDayDreamer run: {run.updates} updates; within δ "
        f"{res.within(ursa_run['delta']).mean():.3f}, violations "
        f"{res.violation_rate.mean():.4f}, return {res.returns.mean():.1f}"
    )
    return res


def test_world_model_heldout_prediction_loss_falls(ursa_run: dict[str, Any]) -> None:
    before, after = _prediction_loss(ursa_run["initial"]), _prediction_loss(ursa_run["final"])
    assert after < 0.35 * before, (before, after)
    assert ursa_run["final"]["wm/decoder"] < 0.1 * ursa_run["initial"]["wm/decoder"]


def test_skills_executed_within_delta(ursa_run: dict[str, Any]) -> None:
    delta = ursa_run["delta"]
    assert ursa_run["eval"].within(delta).mean() >= WITHIN_WORST
    assert ursa_run["random"].within(delta).mean() <= RANDOM_WITHIN


def test_skills_executed_within_delta_across_seeds(ursa_runs: list[dict[str, Any]]) -> None:
    within = np.array([r["eval"].within(r["delta"]).mean() for r in ursa_runs])
    rnd = np.array([r["random"].within(r["delta"]).mean() for r in ursa_runs])
    print(
        f"\nwithin δ by seed {dict(zip(SEEDS, within.round(3), strict=True))}; "
        f"random {rnd.round(3).tolist()}"
    )
    assert np.median(within) >= WITHIN_MEDIAN, within
    assert within.min() >= WITHIN_WORST, within
    assert rnd.max() <= RANDOM_WITHIN, rnd


def test_safety_violations_below_a_third_of_random_every_seed(
    ursa_runs: list[dict[str, Any]],
) -> None:
    rates = [
        (r["eval"].violation_rate.mean(), r["random"].violation_rate.mean()) for r in ursa_runs
    ]
    print(f"\nviolation rate (ursa, random) by seed: {rates}")
    for ursa_rate, random_rate in rates:
        assert ursa_rate < random_rate / 3.0, rates


def test_daydreamer_does_not_execute_skills(
    ursa_run: dict[str, Any], daydreamer_eval: EvalResult
) -> None:
    assert daydreamer_eval.within(ursa_run["delta"]).mean() <= RANDOM_WITHIN
    # it maximises the reward instead (the corner (0.8, 0.8)): more return than the URSA agent
    assert daydreamer_eval.returns.mean() > ursa_run["eval"].returns.mean()


def test_safety_violations_below_a_third_of_random(ursa_run: dict[str, Any]) -> None:
    ursa_rate = ursa_run["eval"].violation_rate.mean()
    random_rate = ursa_run["random"].violation_rate.mean()
    assert ursa_rate < random_rate / 3.0, (ursa_rate, random_rate)


def _states(ursa_run: dict[str, Any], which: str = "eval") -> tuple[torch.Tensor, np.ndarray]:
    """Model states (N, F) and positions (N, 2) along the evaluation trajectories of the trained
    policy (``eval``) or of random actions (``random``)."""
    res: EvalResult = ursa_run[which]
    assert res.obs is not None and res.actions is not None
    k, t = res.obs.shape[:2]
    first = np.zeros((k, t), bool)
    first[:, 0] = True
    learner: Learner = ursa_run["learner"]
    feat = learner.posterior_feats({"obs": res.obs, "action": res.actions, "is_first": first})
    return feat[:, 20:].reshape(-1, feat.shape[-1]), res.obs[:, 20:, :2].reshape(-1, 2)


def test_multipliers(ursa_runs: list[dict[str, Any]]) -> None:
    """λ2 on every seed; λ1's rise with the state–skill distance on the median seed, its sign
    on every seed (as the other claims: median and worst seed)."""
    rises = [_check_multipliers(ursa_run) for ursa_run in ursa_runs]
    assert float(np.median(rises)) > 0.02, rises


def _check_multipliers(ursa_run: dict[str, Any]) -> float:
    """Assert λ2's and λ1's per-seed claims; returns λ1's rise from the nearest to the farthest
    quarter of (state, skill) pairs."""
    learner: Learner = ursa_run["learner"]
    # λ2 predicts whether the cost constraint is violated from a state: inside the unsafe disc
    # (radius 0.35) the discounted cost is positive whatever the policy does next, far from it
    # it is not. The trained policy keeps out of the disc (and the skills it is asked for lie
    # in the archive's support, all safe), so its own states never violate the constraint and
    # λ2 falls everywhere along them; the disc's inside is seen along random actions (the
    # prefill of the replay holds such states, and imagination starts there).
    feat, pos = _states(ursa_run, "random")
    rng = np.random.default_rng(3)
    kde_skills = ursa_run["skills"][rng.integers(0, len(ursa_run["skills"]), len(pos))]
    _, lam2 = learner.multipliers(feat, kde_skills)
    radius = np.linalg.norm(pos, axis=-1)
    inside, far = radius < 0.35, radius > 0.8
    assert inside.sum() > 20 and far.sum() > 20
    seed = learner.config.seed
    l2_in, l2_far = float(lam2[inside].mean()), float(lam2[far].mean())
    print(f"\nseed {seed}: λ2 inside the disc {l2_in:.3f}, far from it {l2_far:.3f}")
    assert l2_in > 2.0 * l2_far and l2_in > l2_far + 0.05, (seed, l2_in, l2_far)
    # λ1 predicts whether the skill constraint is violated from (s, z): where it holds (the
    # nearest quarter of (state, KDE skill) pairs in δ's metric, along the states the agent
    # visits) it has fallen below its initial 0.5, and it is higher for the farthest quarter.
    # The trend is weak: λ1 learns slowly and at 3000 updates still follows the falling rate of
    # imagined violations (0.99 at 500 updates, 0.35 at 3000; docs/NOTES.md) more than its
    # dependence on (s, z). On the EPYC of 2026-12-03 seed 0 (0.967 of its skills within δ)
    # rose by 0.012 only (0.345 to 0.357, Spearman 0.08), seeds 1 and 2 by 0.147 and 0.176:
    # the rise's size is a claim about the median seed, its sign about every seed. Its mean
    # over all pairs is no claim: most random pairs violate the constraint, so a well-trained
    # λ1 is high there (0.508 on a distributed run of 2026-12-03, near 0.330, far 0.631).
    feat, pos = _states(ursa_run)
    lam1, _ = learner.multipliers(feat, kde_skills[: len(pos)])
    whiten = kde.whitening_matrix(kde.regularize_cov(ursa_run["cov"]))
    dist = np.linalg.norm((kde_skills[: len(pos)] - pos) @ whiten.T, axis=-1)
    near_q, far_q = np.quantile(dist, [0.25, 0.75])
    l1_near, l1_far = float(lam1[dist <= near_q].mean()), float(lam1[dist >= far_q].mean())
    print(f"seed {seed}: λ1 {lam1.mean():.3f}; near skills {l1_near:.3f}, far ones {l1_far:.3f}")
    assert l1_near < 0.5, (seed, l1_near)
    assert l1_far > l1_near, (seed, l1_near, l1_far)
    return l1_far - l1_near
