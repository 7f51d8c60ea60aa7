"""KDE bandwidth, density, sampling, δ and the entropy bound: scipy and hand-worked values."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import gaussian_kde

from ursa import kde


@pytest.mark.parametrize("d", [1, 2, 3, 5])
def test_bandwidth_and_logpdf_match_scipy(d: int) -> None:
    rng = np.random.default_rng(d)
    pts = rng.normal(size=(400, d)) * rng.uniform(0.5, 3.0, size=d) + rng.normal(size=d)
    ref = gaussian_kde(pts.T)
    assert kde.scott_factor(400, d) == pytest.approx(ref.factor, rel=1e-15)
    cov = kde.kde_covariance(pts)
    np.testing.assert_allclose(cov, ref.covariance, rtol=1e-12, atol=1e-15)
    x = np.concatenate([pts[:20], rng.normal(size=(50, d)) * 3.0])
    np.testing.assert_allclose(kde.kde_logpdf(pts, cov, x), ref.logpdf(x.T), rtol=1e-10)


def test_covariance_with_nr_scaling() -> None:
    pts = np.random.default_rng(0).normal(size=(50, 3))
    cov = kde.kde_covariance(pts, n=5000)
    np.testing.assert_allclose(cov, np.cov(pts.T) * 5000 ** (-2 / 7), rtol=1e-14)


def test_samples_have_mixture_moments() -> None:
    rng = np.random.default_rng(1)
    pts = rng.normal(size=(60, 3)) * [1.0, 2.0, 0.5]
    cov = kde.kde_covariance(pts)
    n = 200_000
    s = kde.kde_sample(pts, cov, n, rng)
    assert s.shape == (n, 3)
    mix_cov = np.cov(pts.T, bias=True) + cov
    se = np.sqrt(np.diag(mix_cov) / n)
    assert np.all(np.abs(s.mean(0) - pts.mean(0)) < 5 * se)
    # Entry (i, j) of a sample covariance has variance ≈ (Σ_ii Σ_jj + Σ_ij²) / n.
    se_cov = np.sqrt((np.outer(np.diag(mix_cov), np.diag(mix_cov)) + mix_cov**2) / n)
    assert np.all(np.abs(np.cov(s.T) - mix_cov) < 5 * se_cov)


def test_degenerate_inputs_do_not_crash() -> None:
    rng = np.random.default_rng(2)
    for pts in (np.zeros((0, 3)), np.ones((1, 3)), np.ones((5, 3)), rng.normal(size=(3, 3))):
        cov = kde.kde_covariance(pts)
        assert np.all(np.linalg.eigvalsh(cov) > 0)
        assert kde.kde_sample(pts, cov, 7, rng).shape == (7, 3)
        lp = kde.kde_logpdf(pts, cov, rng.normal(size=(4, 3)))
        assert lp.shape == (4,) and not np.any(np.isnan(lp))
        dist, idx = kde.mahalanobis_nn(pts, cov)
        assert dist.shape == idx.shape == (len(pts),)
    # Collinear points: rank-deficient covariance gets the ridge, the rest is usable.
    line = np.outer(np.arange(10.0), [1.0, 2.0, 3.0])
    cov = kde.kde_covariance(line)
    assert np.all(np.isfinite(kde.mahalanobis_nn(line, cov)[0]))
    assert math.isfinite(kde.entropy_lower_bound(kde.mahalanobis_nn(line, cov)[0], cov))
    assert math.isnan(kde.entropy_lower_bound(np.zeros(0), np.eye(2)))
    assert kde.delta(np.array([np.inf]), 1, 1, 3) == math.inf


def test_ridge_only_touches_degenerate_covariances() -> None:
    c = np.array([[2.0, 0.3], [0.3, 1.0]])
    np.testing.assert_array_equal(kde.regularize_cov(c), c)
    z = kde.regularize_cov(np.zeros((2, 2)))
    np.testing.assert_array_equal(z, kde.RIDGE * np.eye(2))
    s = kde.regularize_cov(np.diag([4.0, 0.0]))
    np.testing.assert_allclose(s, np.diag([4.0 + 2e-9, 2e-9]))


def test_square_hand_computed() -> None:
    # 4 points on a square of side 2 with Σ = diag(4, 1): horizontal neighbours are at
    # d_Σ = 2/2 = 1, vertical ones at 2/1 = 2, so every NN distance is 1.
    pts = np.array([[0.0, 0.0], [2.0, 0.0], [0.0, 2.0], [2.0, 2.0]])
    cov = np.diag([4.0, 1.0])
    dist, idx = kde.mahalanobis_nn(pts, cov)
    np.testing.assert_allclose(dist, [1.0, 1.0, 1.0, 1.0])
    np.testing.assert_array_equal(idx, [1, 0, 3, 2])
    # δ = (N_R/N_z)^(1/D) · mean = (4/1)^(1/2) · 1 = 2
    assert kde.delta(dist, 4, 1, 2) == pytest.approx(2.0)
    assert kde.delta(dist, 4, 4, 2) == pytest.approx(1.0)
    # Eq. (1): −log(1 + 3 e^(−1/2)) + ½ log 4 + log 2π + log 4
    expected = -math.log(1 + 3 * math.exp(-0.5)) + math.log(2) + math.log(2 * math.pi) + math.log(4)
    assert kde.entropy_lower_bound(dist, cov) == pytest.approx(expected, rel=1e-13)
    # Ĥ = −mean log q(z_i); by symmetry every z_i has the same density:
    # q = (1/4)·(1 + e^(−1/2) + e^(−2) + e^(−5/2)) / (2π·√det Σ) with √det Σ = 2.
    q = 0.25 * (1 + math.exp(-0.5) + math.exp(-2) + math.exp(-2.5)) / (2 * math.pi * 2)
    assert kde.entropy_mc(pts, cov) == pytest.approx(-math.log(q), rel=1e-13)


@pytest.mark.parametrize("d", [1, 2, 3, 5])
def test_bound_below_monte_carlo(d: int) -> None:
    rng = np.random.default_rng(10 + d)
    for n in (2, 5, 40, 300):
        pts = rng.standard_t(3, size=(n, d)) * rng.uniform(0.1, 5, size=d)
        cov = kde.kde_covariance(pts)
        dist, _ = kde.mahalanobis_nn(pts, cov)
        assert kde.entropy_lower_bound(dist, cov) <= kde.entropy_mc(pts, cov) + 1e-12


def test_mahalanobis_nn_matches_direct() -> None:
    rng = np.random.default_rng(3)
    pts = rng.normal(size=(80, 3))
    cov = kde.kde_covariance(pts)
    inv = np.linalg.inv(cov)
    diff = pts[:, None] - pts[None]
    d2 = np.einsum("ijk,kl,ijl->ij", diff, inv, diff)
    np.fill_diagonal(d2, np.inf)
    dist, idx = kde.mahalanobis_nn(pts, cov)
    np.testing.assert_array_equal(idx, d2.argmin(1))
    np.testing.assert_allclose(dist, np.sqrt(d2.min(1)), rtol=1e-12)


def test_nearest_distance_matches_scipy_mahalanobis() -> None:
    from scipy.spatial.distance import cdist

    rng = np.random.default_rng(4)
    pts = rng.normal(size=(300, 3))
    cov = np.array([[0.5, 0.1, 0.0], [0.1, 0.3, 0.05], [0.0, 0.05, 0.2]])
    x = rng.normal(size=(40, 3)) * 2.0
    ref = cdist(x, pts, "mahalanobis", VI=np.linalg.inv(cov)).min(axis=1)
    np.testing.assert_allclose(kde.nearest_distance(pts, cov, x), ref, rtol=1e-10)
    assert np.isinf(kde.nearest_distance(np.zeros((0, 3)), cov, x)).all()


def test_support_radius_rule() -> None:
    assert kde.support_radius(0.5, 0.8) == pytest.approx(0.4)
    assert kde.support_radius(None, 0.8) is None
    assert kde.support_radius(0.5, math.inf) is None
    assert kde.support_radius(0.5, math.nan) is None


def test_box_sampling_without_support_is_the_plain_kde_when_nothing_leaves_the_box() -> None:
    pts = np.random.default_rng(1).uniform(-0.5, 0.5, size=(50, 2))
    cov = np.eye(2) * 1e-4
    lo, hi = np.full(2, -10.0), np.full(2, 10.0)
    a = kde.kde_sample_in_box(pts, cov, 500, np.random.default_rng(7), lo, hi)
    b = kde.kde_sample(pts, cov, 500, np.random.default_rng(7))
    np.testing.assert_array_equal(a, b)


def test_support_truncation_keeps_draws_near_stored_points() -> None:
    # two clusters 4 kernel widths apart: the plain KDE puts draws in the gap, the truncated
    # one keeps every draw within the radius of a stored point, in both clusters alike
    rng = np.random.default_rng(0)
    pts = np.concatenate(
        [rng.normal((-1.0, 0.0), 0.02, (20, 2)), rng.normal((1.0, 0.0), 0.02, (20, 2))]
    )
    cov = np.eye(2) * 0.25  # kernel std 0.5
    lo, hi = np.full(2, -3.0), np.full(2, 3.0)
    plain = kde.kde_sample_in_box(pts, cov, 4000, np.random.default_rng(1), lo, hi)
    cut = kde.kde_sample_in_box(
        pts, cov, 4000, np.random.default_rng(1), lo, hi, tries=200, support=0.4
    )
    assert (kde.nearest_distance(pts, cov, plain) > 0.4).mean() > 0.8  # P(χ²₂ > 0.16) ≈ 0.92
    d = kde.nearest_distance(pts, cov, cut)
    assert d.max() <= 0.4 + 1e-12
    assert (np.abs(cut[:, 0]) < 0.5).sum() == 0  # nothing in the gap
    assert 0.45 < (cut[:, 0] < 0).mean() < 0.55
    # accepted draws spread over the kernels' truncated discs (‖u‖ ≈ (2/3)·0.4 on average for a
    # uniform disc), not piled on the centres, which only a draw that never met the radius gets
    assert (d < 1e-9).mean() < 0.01
    assert d.mean() > 0.2
    # a radius no draw can meet falls back to the kernels' centres: stored points
    tiny = kde.kde_sample_in_box(
        pts, cov, 50, np.random.default_rng(1), lo, hi, support=1e-9, tries=2
    )
    assert kde.nearest_distance(pts, cov, tiny).max() < 1e-9
