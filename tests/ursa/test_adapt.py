"""Intelligent Trial and Error (ursa.adapt): GP posterior against the direct formula, the
stopping rule, and ITE against random search on a hand-made map whose best skill after a
synthetic damage is known."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from ursa import adapt
from ursa.adapt import ITEParams, Observations, SkillMap


def matern52(a: np.ndarray, b: np.ndarray, rho: float, var: float) -> np.ndarray:
    r = np.linalg.norm(a[:, None, :] - b[None, :, :], axis=-1) / rho
    return var * (1.0 + math.sqrt(5.0) * r + 5.0 * r**2 / 3.0) * np.exp(-math.sqrt(5.0) * r)


def test_posterior_matches_the_direct_formula() -> None:
    skills = np.array([[0.0, 0.0], [1.0, 0.2], [0.3, 1.5], [-0.7, 0.4], [2.0, -1.0]])
    prior = np.array([1.0, 3.0, 2.0, 0.5, 4.0])
    m = SkillMap(skills, prior)
    p = ITEParams(length_scale=0.8, variance=1.3, noise=0.01)
    obs = Observations().add(1, 0.5).add(4, 3.5).add(0, 1.2)
    post = adapt.posterior(m, obs, p)

    # whitening by hand: A = L⁻¹ with L Lᵀ = cov of the skills
    cov = np.cov(skills.T)
    white = skills @ np.linalg.inv(np.linalg.cholesky(cov)).T
    s = prior.max() - prior.min()
    x = white[[1, 4, 0]]
    y = (np.array([0.5, 3.5, 1.2]) - prior[[1, 4, 0]]) / s
    kxx = matern52(x, x, 0.8, 1.3) + 0.01 * np.eye(3)
    ks = matern52(white, x, 0.8, 1.3)
    mean = prior + s * ks @ np.linalg.solve(kxx, y)
    var = 1.3 - np.einsum("ij,ji->i", ks, np.linalg.solve(kxx, ks.T))
    np.testing.assert_allclose(post.mean, mean, atol=1e-10)
    np.testing.assert_allclose(post.std, s * np.sqrt(var), atol=1e-10)
    # hand-checked numbers: the observed skill's mean sits between prior and observation
    assert prior[1] > post.mean[1] > 0.5
    assert post.std[1] < post.std[2]


def test_posterior_without_trials_is_the_prior() -> None:
    m = SkillMap(np.array([[0.0], [1.0], [3.0]]), np.array([2.0, -1.0, 5.0]))
    post = adapt.posterior(m, Observations(), ITEParams(variance=4.0))
    np.testing.assert_array_equal(post.mean, [2.0, -1.0, 5.0])
    np.testing.assert_allclose(post.std, 6.0 * 2.0)  # range 6, √variance 2


def test_first_choice_is_the_best_intact_skill_and_tried_skills_are_skipped() -> None:
    m = SkillMap(np.array([[0.0], [1.0], [2.0], [3.0]]), np.array([1.0, 4.0, 2.0, 3.0]))
    p = ITEParams(budget=10)
    d = adapt.decide(m, Observations(), p)
    assert d.index == 1 and d.reason is None
    # skill 1 is far worse than expected: the next is not 1 again
    d2 = adapt.decide(m, Observations().add(1, -5.0), p)
    assert d2.index is not None and d2.index != 1


def test_stopping_rule() -> None:
    m = SkillMap(np.array([[0.0], [5.0], [10.0]]), np.array([10.0, 8.0, 1.0]))
    p = ITEParams(alpha=0.9, budget=3, length_scale=0.1)
    # skill 0 gave 9.5: far skills keep their prior (8 and 1), max μ ≈ 9.5 -> 9.5 ≥ 0.9 × 9.5
    assert adapt.stop_reason(m, Observations().add(0, 9.5), p) == adapt.THRESHOLD
    # skill 0 gave 5: skill 1 still predicts ≈ 8 and 5 < 0.9 × 8: go on
    assert adapt.stop_reason(m, Observations().add(0, 5.0), p) is None
    # 7.3 ≥ 0.9 × 8 = 7.2 (stop) but 7.1 is not
    assert adapt.stop_reason(m, Observations().add(0, 7.3), p) == adapt.THRESHOLD
    assert adapt.stop_reason(m, Observations().add(0, 7.1), p) is None
    # budget: bad trials everywhere; each observed row's mean sits a hair above its return,
    # towards its higher prior (by (P − y)·σ_n²/(1 + σ_n²) ≈ 0.01 at skill 0), so "best ≥ max μ"
    # does not fire, nor does α = 0.99 (0.1 < 0.99 × 0.1099)
    o = Observations().add(0, 0.1).add(1, 0.1)
    assert adapt.stop_reason(m, o, p) is None
    far = ITEParams(budget=2, length_scale=0.1)
    assert adapt.stop_reason(m, o, far) == adapt.BUDGET
    assert adapt.stop_reason(
        m, o.add(2, 0.1), ITEParams(budget=3, length_scale=0.1, alpha=0.99)
    ) == (adapt.BUDGET)
    # every skill tried before the budget
    assert adapt.stop_reason(
        m, o.add(2, 0.1), ITEParams(budget=10, length_scale=0.1, alpha=0.99)
    ) == (adapt.EXHAUSTED)
    # with negative returns the alpha rule alone would never fire; best ≥ max μ still stops
    neg = SkillMap(np.array([[0.0], [9.0]]), np.array([-1.0, -3.0]))
    assert adapt.stop_reason(neg, Observations().add(0, -1.0), ITEParams()) == adapt.THRESHOLD
    assert adapt.stop_reason(neg, Observations().add(0, -8.0), ITEParams()) is None


def test_exhausted_when_every_skill_is_tried_and_a_better_one_is_still_predicted() -> None:
    m = SkillMap(np.array([[0.0], [40.0]]), np.array([1.0, 1.0]))
    # noisy observations (noise = kernel variance): the model halves the way to the data, so it
    # still predicts ≈ 0.5 where 0.0 and 0.1 were observed
    p = ITEParams(budget=5, noise=1.0, length_scale=0.1)
    o = Observations().add(0, 0.0).add(1, 0.1)
    post = adapt.posterior(m, o, p)
    np.testing.assert_allclose(post.mean, [0.5, 0.55], atol=1e-6)
    assert adapt.stop_reason(m, o, p) == adapt.EXHAUSTED
    assert adapt.stop_reason(m, o, ITEParams(budget=2, noise=1.0, length_scale=0.1)) == adapt.BUDGET
    assert adapt.decide(m, o, p).index is None


# ---- a hand-made map with a synthetic damage ----------------------------------------------
GRID = np.stack(np.meshgrid(np.linspace(-1, 1, 15), np.linspace(-1, 1, 15)), -1).reshape(-1, 2)
A = np.array([0.6, 0.6])  # the intact optimum
B = np.array([-0.6, -0.2])  # a modest hill the damage spares: the best after damage
C = np.array([0.5, -0.7])  # the intact runner-up, ruined by the damage too


def _sq(z: np.ndarray, c: np.ndarray) -> np.ndarray:
    return np.asarray(np.sum((z - c) ** 2, -1))


def intact_returns(z: np.ndarray) -> np.ndarray:
    return (
        1.0
        + 3.0 * np.exp(-_sq(z, A) / 0.5)
        + 1.5 * np.exp(-_sq(z, C) / 0.2)
        + 0.8 * np.exp(-_sq(z, B) / 0.3)
    )


def damaged_returns(z: np.ndarray) -> np.ndarray:
    """The damage ruins the skills near A and C (a leg they rely on)."""
    keep = (1.0 - 0.85 * np.exp(-_sq(z, A) / 0.8)) * (1.0 - 0.8 * np.exp(-_sq(z, C) / 0.3))
    return intact_returns(z) * keep


def test_hand_made_map_has_a_known_best_after_damage() -> None:
    intact, damaged = intact_returns(GRID), damaged_returns(GRID)
    best = int(np.argmax(damaged))
    assert np.linalg.norm(GRID[best] - B) < 0.15
    # the damaged best is a middling skill on the intact robot: the map alone does not find it
    assert (intact > intact[best]).sum() > 100
    assert np.sort(damaged)[-2] < damaged[best] - 1e-6  # unique


def _trial_fn(seed: int) -> adapt.TrialFn:
    truth = damaged_returns(GRID)
    noise = np.random.default_rng(seed).normal(0.0, 0.02, len(GRID))  # per skill, per seed
    return lambda i: float(truth[i] + noise[i])


def _first(rows: list[int], target: float) -> int:
    """Trials until one whose (noise-free) damaged return ≥ target; len + 1 if none."""
    truth = damaged_returns(GRID)
    hit = [n for n, i in enumerate(rows, 1) if truth[i] >= target]
    return hit[0] if hit else len(GRID) + 1


def test_ite_finds_the_best_damaged_skill_in_fewer_trials_than_random_search() -> None:
    m = SkillMap(GRID, intact_returns(GRID))
    truth = damaged_returns(GRID)
    top = float(truth.max())
    ite_n, rnd_n, chosen_ok = [], [], 0
    for seed in range(12):
        fn = _trial_fn(seed)
        # α = 1: stop only when nothing better than the best tried is predicted
        r = adapt.ite(m, fn, ITEParams(alpha=1.0, budget=len(GRID)))
        ite_n.append(_first([t.index for t in r.trials], 0.99 * top))
        chosen_ok += int(np.linalg.norm(GRID[r.chosen.index] - B) < 0.3)
        rr = adapt.random_search(m, fn, len(GRID), seed)
        rnd_n.append(_first([t.index for t in rr.trials], 0.99 * top))
    wins = sum(a < b for a, b in zip(ite_n, rnd_n, strict=True))
    assert wins >= 9, (ite_n, rnd_n)
    assert chosen_ok >= 10
    assert np.median(ite_n) <= 10 < np.median(rnd_n), (ite_n, rnd_n)
    # the map's order alone (best intact first, no model of the damage) is far slower
    prior_order = list(np.argsort(-intact_returns(GRID), kind="stable"))
    assert _first(prior_order, 0.99 * top) > 50


def test_ite_with_its_stopping_rule_recovers_90_percent_quickly() -> None:
    m = SkillMap(GRID, intact_returns(GRID))
    top = float(damaged_returns(GRID).max())
    p = ITEParams(alpha=0.9, budget=20)
    ite_n, rnd_n = [], []
    for seed in range(10):
        fn = _trial_fn(seed)
        r = adapt.ite(m, fn, p)
        assert r.reason in (adapt.THRESHOLD, adapt.BUDGET)
        assert len(r.trials) <= 20
        ite_n.append(adapt.trials_to_reach(r.returns, 0.9 * top) or 21)
        rnd = adapt.random_search(m, fn, 20, seed)
        rnd_n.append(adapt.trials_to_reach(rnd.returns, 0.9 * top) or 21)
        if r.reason == adapt.THRESHOLD:
            # the rule fired: the best tried is within α of what the model expects
            assert r.chosen.ret >= 0.9 * r.trials[-1].predicted_best_mean - 1e-9
            assert r.chosen.ret >= 0.9 * top - 0.05
    assert sum(a < b for a, b in zip(ite_n, rnd_n, strict=True)) >= 7, (ite_n, rnd_n)
    assert np.median(ite_n) <= 5 and np.median(ite_n) < np.median(rnd_n), (ite_n, rnd_n)


def test_ite_is_deterministic_and_random_search_follows_its_seed() -> None:
    m = SkillMap(GRID, intact_returns(GRID))
    fn = _trial_fn(3)
    a = adapt.ite(m, fn, ITEParams())
    b = adapt.ite(m, fn, ITEParams())
    assert a == b
    r1 = adapt.random_search(m, fn, 20, seed=1)
    r2 = adapt.random_search(m, fn, 20, seed=1)
    r3 = adapt.random_search(m, fn, 20, seed=2)
    assert r1 == r2 and r1 != r3
    rows = [t.index for t in r1.trials]
    assert len(set(rows)) == 20 and r1.reason == adapt.BUDGET


def test_best_so_far_and_trials_to_reach() -> None:
    np.testing.assert_array_equal(
        adapt.best_so_far(np.array([1.0, 0.5, 3.0]), 5), [1.0, 1.0, 3.0, 3.0, 3.0]
    )
    assert np.isnan(adapt.best_so_far(np.zeros(0), 2)).all()
    assert adapt.trials_to_reach(np.array([1.0, 2.0, 3.0]), 2.0) == 2
    assert adapt.trials_to_reach(np.array([1.0]), 2.0) is None


def test_inputs_are_checked() -> None:
    with pytest.raises(ValueError):
        SkillMap(np.zeros((3, 2)), np.zeros(2))
    with pytest.raises(ValueError):
        SkillMap(np.array([[np.nan, 0.0]]), np.zeros(1))
    with pytest.raises(ValueError):
        ITEParams(budget=0)
    with pytest.raises(ValueError):
        ITEParams(length_scale=-1.0)
    with pytest.raises(ValueError):
        Observations().add(0, math.inf)
    m = SkillMap(np.array([[0.0], [1.0]]), np.zeros(2))
    with pytest.raises(ValueError):
        adapt.posterior(m, Observations().add(5, 1.0), ITEParams())


def test_map_cache_round_trip(tmp_path: Path) -> None:
    m = SkillMap(GRID[:7], intact_returns(GRID[:7]), np.arange(10, 17))
    key = adapt.map_key(skills=m.skills, steps=250, policy="abc")
    assert key != adapt.map_key(skills=m.skills, steps=251, policy="abc")
    path = adapt.map_path(tmp_path, key)
    assert path.parent == tmp_path / "eval" / "adapt"
    assert adapt.load_map(path) is None
    adapt.save_map(path, m, {"steps": 250})
    got = adapt.load_map(path)
    assert got is not None
    m2, meta = got
    np.testing.assert_array_equal(m2.skills, m.skills)
    np.testing.assert_array_equal(m2.prior, m.prior)
    np.testing.assert_array_equal(m2.ids, m.ids)
    assert meta == {"steps": 250}
