"""The repertoire against a brute-force reference, its δ / entropy bound, validity, persistence."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from numba import njit

from ursa import kde
from ursa import repertoire as rmod
from ursa.bounds import Box
from ursa.repertoire import Repertoire, RepertoireConfig


@njit
def _brute_victim(x: np.ndarray, a: np.ndarray, ids: np.ndarray) -> int:
    """Row of x (n, D) with the smallest NN distance, the largest id among ties.

    Whitens every row and computes every pair from scratch. Whitened coordinates and squared
    distances are summed left to right, as the spec fixes, so distances (and thus ties) have the
    same bits as the incremental implementation's.
    """
    n, d = x.shape
    w = np.empty((n, d))
    for i in range(n):
        for k in range(d):
            acc = a[k, 0] * x[i, 0]
            for j in range(1, d):
                acc += a[k, j] * x[i, j]
            w[i, k] = acc
    nn = np.full(n, np.inf)
    for i in range(n):
        for j in range(i + 1, n):
            acc = 0.0
            for k in range(d):
                t = w[i, k] - w[j, k]
                acc += t * t
            nn[i] = min(nn[i], acc)
            nn[j] = min(nn[j], acc)
    m = nn.min()
    victim = -1
    for i in range(n):
        if nn[i] == m and (victim < 0 or ids[i] > ids[victim]):
            victim = i
    return victim


class BruteRepertoire:
    """Recomputes every pairwise distance on every commit; same removal rule and Σ schedule."""

    def __init__(self, size: int, dim: int, refresh_every: int) -> None:
        self.size, self.dim, self.refresh_every = size, dim, refresh_every
        self.p = np.zeros((0, dim))
        self.ids = np.zeros(0, dtype=np.int64)
        self.next_id = 0
        self.since = 0
        self.a = np.eye(dim)
        self.cov = np.eye(dim)

    def refresh(self) -> None:
        self.cov = kde.kde_covariance(self.p, n=self.size)
        self.a = kde.whitening_matrix(self.cov)
        self.since = 0

    def nn_dist(self) -> np.ndarray:
        x = self.p @ self.a.T
        d2 = ((x[:, None] - x[None]) ** 2).sum(-1)
        np.fill_diagonal(d2, np.inf)
        return np.sqrt(d2.min(1))

    def commit(self, z: np.ndarray) -> bool:
        if len(self.p) < self.size:
            self.p = np.vstack([self.p, z])
            self.ids = np.append(self.ids, self.next_id)
            self.next_id += 1
            if len(self.p) == self.size:
                self.refresh()
            return True
        x = np.vstack([self.p, z])
        victim = _brute_victim(x, self.a, np.append(self.ids, self.next_id))
        accepted = victim != len(self.p)
        if accepted:
            self.p = np.vstack([np.delete(self.p, victim, 0), z])
            self.ids = np.append(np.delete(self.ids, victim), self.next_id)
            self.next_id += 1
        self.since += 1
        if self.refresh_every and self.since == self.refresh_every:
            self.refresh()
        return bool(accepted)


def _stream(rng: np.random.Generator, n: int, d: int) -> np.ndarray:
    """Features from a drifting, anisotropic source with exact repeats (a robot standing still)."""
    t = np.linspace(0.0, 1.0, n)[:, None]
    z = rng.normal(size=(n, d)) * np.linspace(0.5, 2.0, d) + 3.0 * t * np.ones(d)
    z[rng.random(n) < 0.2] *= 3.0
    rep = rng.random(n) < 0.1
    src = np.maximum(np.arange(n) - rng.integers(1, 50, size=n), 0)
    z[rep] = z[src[rep]]
    return z


@pytest.mark.parametrize(
    ("d", "size", "tree"), [(2, 250, False), (3, 200, False), (5, 200, False), (3, 150, True)]
)
def test_matches_brute_force(
    d: int, size: int, tree: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    if tree:  # force the KD-tree path of the refresh at this small size
        monkeypatch.setattr(rmod, "_BRUTE_MAX", 0)
    rng = np.random.default_rng(100 + d)
    z = _stream(rng, 20_000, d)
    refresh = 700
    fast = Repertoire(RepertoireConfig(size=size, dim=d, refresh_every=refresh))
    ref = BruteRepertoire(size, d, refresh)
    # Mixed batch sizes exercise commit and commit_many, and batches that straddle refreshes.
    i = 0
    while i < len(z):
        m = int(rng.choice([1, 3, 64, 500]))
        got = fast.commit(z[i]) if m == 1 else fast.commit_many(z[i : i + m])
        want = sum(ref.commit(x) for x in z[i : i + m])
        assert int(got) == want, f"at commit {i}"
        i += m
    np.testing.assert_array_equal(fast.ids, ref.ids)
    np.testing.assert_array_equal(fast.skills, ref.p)
    np.testing.assert_array_equal(fast.cov, ref.cov)
    np.testing.assert_allclose(fast.nn_dist, ref.nn_dist(), rtol=1e-9)
    assert fast.commits == len(z) and fast.accepted + fast.rejected == len(z)
    assert fast.accepted == ref.next_id
    assert fast.rejected > 0 and fast.accepted > 2 * size


def test_tree_refresh_equals_brute_refresh(monkeypatch: pytest.MonkeyPatch) -> None:
    rng = np.random.default_rng(5)
    rep = Repertoire(RepertoireConfig(size=3000, dim=3))
    rep.commit_many(rng.normal(size=(3000, 3)))
    rep.commit_many(rng.normal(size=(500, 3)))
    monkeypatch.setattr(rmod, "_BRUTE_MAX", 10**9)
    rep.refresh()
    brute = rep.nn_dist
    monkeypatch.setattr(rmod, "_BRUTE_MAX", 0)
    rep.refresh()
    np.testing.assert_array_equal(rep.nn_dist, brute)
    np.testing.assert_allclose(brute, kde.mahalanobis_nn(rep.skills, rep.cov)[0], rtol=1e-9)


def test_square_delta_and_bound_hand_computed() -> None:
    rep = Repertoire(RepertoireConfig(size=4, dim=2, n_z=1))
    rep.commit_many(np.array([[0.0, 0.0], [2.0, 0.0], [0.0, 2.0], [2.0, 2.0]]))
    # Data covariance (4/3)·I (sample variance of 0,2,0,2); Σ = (4/3)·4^(−2/6)·I.
    sigma2 = 4 / 3 * 4 ** (-1 / 3)
    np.testing.assert_allclose(rep.cov, sigma2 * np.eye(2), rtol=1e-14)
    dnn = 2 / math.sqrt(sigma2)  # = √3 · 4^(1/6)
    assert dnn == pytest.approx(math.sqrt(3) * 4 ** (1 / 6))
    np.testing.assert_allclose(rep.nn_dist, [dnn] * 4, rtol=1e-14)
    assert rep.delta() == pytest.approx(math.sqrt(4 / 1) * dnn, rel=1e-14)
    bound = (
        -math.log(1 + 3 * math.exp(-0.5 * dnn**2))
        + 0.5 * math.log(sigma2**2)
        + math.log(2 * math.pi)
        + math.log(4)
    )
    assert rep.entropy_bound() == pytest.approx(bound, rel=1e-13)
    assert rep.entropy_bound() <= rep.entropy_mc()
    # The square's centre is at d_Σ = √2/√σ² from all four corners: the tie goes to the lowest
    # id; it is nearer than any corner is to another, so the new skill is rejected.
    assert rep.nearest(np.array([1.0, 1.0]), 4).tolist() == [0, 1, 2, 3]
    assert not rep.commit(np.array([1.0, 1.0]))
    # (4, 0) is exactly as far from (2, 0) as the corners are from each other: a tie, and the
    # newcomer is the newest.
    assert not rep.commit(np.array([4.0, 0.0]))
    # Far away, the new skill stays; all four corners tie for the smallest NN distance and the
    # newest (id 3) goes.
    assert rep.commit(np.array([20.0, 20.0]))
    assert rep.ids.tolist() == [0, 1, 2, 4]


def test_min_nn_distance_never_decreases_with_fixed_sigma() -> None:
    """With Σ fixed, removal of the least diverse skill keeps min_i d_Σ(z_i, z_i^nn) monotone.

    (If the new skill's NN distance does not exceed the current minimum, it is the one removed;
    otherwise everything left has an NN distance ≥ the old minimum.)
    """
    rng = np.random.default_rng(7)
    rep = Repertoire(RepertoireConfig(size=300, dim=3, refresh_every=0))
    rep.commit_many(rng.normal(size=(300, 3)))
    cov = rep.cov
    prev = rep.nn_dist.min()
    for z in rng.normal(size=(3000, 3)) * 1.5:
        rep.commit(z)
        cur = rep.nn_dist.min()
        assert cur >= prev
        prev = cur
    np.testing.assert_array_equal(rep.cov, cov)


def test_entropy_bound_under_fixed_sigma() -> None:
    """Eq. (1) is a bound, not a quantity each commit improves: §4.2's removal rule may lower it.

    Hand-made case in 1-D (Σ = σ², d_Σ = |Δ|/σ): a close pair (0, 1), a third skill 1.001 from
    the pair and an isolated one at 100. A new skill 1.002 from the isolated one is kept and the
    pair loses its newest member: NN gaps go from (1, 1, 1.001, 97.999) to (1.001, 1.001, 1.002,
    1.002), and the isolated skill's near-zero term in Eq. (1) becomes a large negative one.
    Over a long stream into a full archive the bound still climbs, and stays below Ĥ.
    """
    rep = Repertoire(RepertoireConfig(size=4, dim=1, refresh_every=0))
    rep.commit_many(np.array([[1.0], [0.0], [2.001], [100.0]]))
    sigma = math.sqrt(rep.cov[0, 0])
    np.testing.assert_allclose(rep.nn_dist * sigma, [1.0, 1.0, 1.001, 97.999], rtol=1e-12)
    before = rep.entropy_bound()
    assert rep.commit(np.array([101.002]))
    assert rep.ids.tolist() == [0, 2, 3, 4]
    np.testing.assert_allclose(rep.nn_dist * sigma, [1.001, 1.001, 1.002, 1.002], rtol=1e-12)
    assert rep.entropy_bound() < before

    rng = np.random.default_rng(8)
    rep = Repertoire(RepertoireConfig(size=300, dim=2, refresh_every=0))
    rep.commit_many(rng.normal(size=(300, 2)))
    start = rep.entropy_bound()
    for chunk in np.array_split(rng.normal(size=(6000, 2)) * 2.0, 6):
        rep.commit_many(chunk)
        assert rep.entropy_bound() <= rep.entropy_mc()
    assert rep.entropy_bound() > start + 0.3


def test_invalid_features_are_counted_not_raised() -> None:
    rep = Repertoire(RepertoireConfig(size=10, dim=3))
    assert not rep.commit(np.array([np.nan, 0.0, 0.0]))
    assert not rep.commit(np.array([np.inf, 0.0, 0.0]))
    assert not rep.commit(np.zeros(2))
    assert not rep.commit(np.zeros((1, 3)))
    assert not rep.commit("abc")  # type: ignore[arg-type]
    assert rep.commit_many(np.zeros((4, 2))) == 0
    z = np.arange(15.0).reshape(5, 3)
    z[1, 2] = np.nan
    z[3, 0] = -np.inf
    assert rep.commit_many(z) == 3
    assert rep.commit_many(np.zeros((0, 3))) == 0
    assert rep.rejected_invalid == rep.invalid == 1 + 1 + 1 + 1 + 1 + 4 + 2
    assert rep.commits == rep.accepted == 3 and rep.rejected == 0
    assert rep.ids.tolist() == [0, 1, 2] and rep.ages.tolist() == [0, 1, 2]
    np.testing.assert_array_equal(rep.skills, z[[0, 2, 4]])

    learned = Repertoire(RepertoireConfig(size=10, dim=2, input_dim=4))
    assert not learned.commit(np.zeros(2))  # no input
    assert not learned.commit(np.zeros(2), np.zeros(3))  # wrong input size
    assert not learned.commit(np.zeros(2), np.array([0, 0, np.nan, 0]))
    assert learned.commit(np.zeros(2), np.ones(4))
    assert learned.rejected_invalid == 3 and len(learned) == 1


def test_small_and_degenerate_archives() -> None:
    rng = np.random.default_rng(9)
    rep = Repertoire(RepertoireConfig(size=1, dim=3))
    assert len(rep) == 0 and math.isnan(rep.entropy_bound()) and rep.delta() == math.inf
    assert rep.sample(5, rng).shape == (5, 3)
    np.testing.assert_array_equal(rep.cov, np.eye(3))
    assert rep.commit(np.ones(3))
    assert not rep.commit(np.zeros(3))  # a lone skill always ties with a newcomer
    assert rep.nn_dist.tolist() == [math.inf] and rep.delta() == math.inf
    assert math.isfinite(rep.entropy_bound())
    np.testing.assert_allclose(rep.sample(3, rng), np.ones((3, 3)), atol=1e-3)
    # Fewer points than D + 1, and exact duplicates: the ridge keeps everything finite.
    rep = Repertoire(RepertoireConfig(size=3, dim=5))
    rep.commit_many(np.ones((3, 5)))
    assert np.all(rep.nn_dist == 0.0)
    assert not rep.commit(np.ones(5))
    assert rep.commit(np.full(5, 2.0))
    assert rep.ids.tolist() == [0, 1, 3]
    assert np.all(np.isfinite([rep.entropy_bound(), rep.entropy_mc(), rep.delta()]))


def test_filling_follows_the_archive_then_schedule() -> None:
    rng = np.random.default_rng(11)
    rep = Repertoire(RepertoireConfig(size=50, dim=2, refresh_every=20))
    rep.commit_many(rng.normal(size=(10, 2)))
    np.testing.assert_array_equal(rep.cov, kde.kde_covariance(rep.skills, n=50))
    rep.commit_many(rng.normal(size=(40, 2)) * 3)
    filled = kde.kde_covariance(rep.skills, n=50)
    np.testing.assert_array_equal(rep.cov, filled)
    rep.commit_many(rng.normal(size=(19, 2)) * 5)
    np.testing.assert_array_equal(rep.cov, filled)
    assert rep.since_refresh == 19
    rep.commit(rng.normal(size=2))
    assert rep.since_refresh == 0
    np.testing.assert_array_equal(rep.cov, kde.kde_covariance(rep.skills, n=50))


def test_nearest_and_get() -> None:
    rng = np.random.default_rng(12)
    rep = Repertoire(RepertoireConfig(size=100, dim=3))
    rep.commit_many(rng.normal(size=(250, 3)))
    q = rng.normal(size=3)
    inv = np.linalg.inv(rep.cov)
    diff = rep.skills - q
    order = np.argsort(np.einsum("ij,jk,ik->i", diff, inv, diff))
    np.testing.assert_array_equal(rep.nearest(q, 5), rep.ids[order[:5]])
    np.testing.assert_array_equal(rep.get(rep.ids[[3, 7]]), rep.skills[[3, 7]])
    with pytest.raises(KeyError):
        rep.get(np.array([10**9]))
    nn_ids = rep.nn_ids
    np.testing.assert_array_equal(nn_ids, rep.ids[kde.mahalanobis_nn(rep.skills, rep.cov)[1]])


def test_sample_uses_repertoire_sigma() -> None:
    rng = np.random.default_rng(13)
    rep = Repertoire(RepertoireConfig(size=200, dim=2))
    rep.commit_many(rng.normal(size=(200, 2)) * [1.0, 3.0])
    s = rep.sample(100_000, rng)
    mix_cov = np.cov(rep.skills.T, bias=True) + rep.cov
    np.testing.assert_allclose(np.cov(s.T), mix_cov, rtol=0.03, atol=0.02)
    np.testing.assert_allclose(s.mean(0), rep.skills.mean(0), atol=0.03)
    want = kde.kde_sample(rep.skills, rep.cov, 50, np.random.default_rng(99))
    np.testing.assert_allclose(rep.sample(50, np.random.default_rng(99)), want, rtol=1e-12)


def _continue(rep: Repertoire, z: np.ndarray, inputs: np.ndarray | None) -> list[bool]:
    return [
        rep.commit(x, None if inputs is None else inp)
        for x, inp in zip(z, inputs if inputs is not None else [None] * len(z), strict=True)
    ]


def test_save_load_round_trip(tmp_path: Path) -> None:
    rng = np.random.default_rng(14)
    cfg = RepertoireConfig(size=120, dim=3, n_z=7, refresh_every=50, input_dim=4)
    rep = Repertoire(cfg)
    x = rng.normal(size=(400, 4))
    rep.commit_many(x[:, :3] * 2, x)
    rep.commit(np.array([np.nan, 0, 0]), np.zeros(4))
    rep.encoder_version = 3
    path = tmp_path / "sub" / "rep.npz"
    rep.save(path)
    assert [p.name for p in path.parent.iterdir()] == ["rep.npz"]
    back = Repertoire.load(path)
    assert back.config == cfg
    for key, val in rep.state_dict().items():
        np.testing.assert_array_equal(back.state_dict()[key], val, err_msg=key)
    np.testing.assert_array_equal(back.nn_dist, rep.nn_dist)
    assert back.delta() == rep.delta() and back.entropy_bound() == rep.entropy_bound()
    # Both continue identically, across a Σ refresh.
    more = rng.normal(size=(300, 4))
    assert _continue(back, more[:, :3] * 2, more) == _continue(rep, more[:, :3] * 2, more)
    np.testing.assert_array_equal(back.skills, rep.skills)
    np.testing.assert_array_equal(back.ids, rep.ids)
    # A repertoire saved while filling, with the default schedule.
    small = Repertoire(RepertoireConfig(size=50, dim=2))
    small.commit_many(rng.normal(size=(20, 2)))
    small.save(tmp_path / "small.npz")
    again = Repertoire.load(tmp_path / "small.npz")
    assert again.config == small.config and again.commits == 20
    np.testing.assert_array_equal(again.cov, small.cov)


def test_reencode() -> None:
    rng = np.random.default_rng(15)
    rep = Repertoire(RepertoireConfig(size=100, dim=2, input_dim=3, refresh_every=0))
    x = rng.normal(size=(300, 3))
    rep.commit_many(x[:, :2], x)
    ids, inputs = rep.ids, rep.inputs
    m = np.array([[1.0, 0.5], [0.0, 2.0], [-1.0, 0.3]])

    def enc(v: np.ndarray) -> np.ndarray:
        out = v @ m
        out[np.abs(v[:, 0]) > 2.5] = np.nan  # an encoder that fails on a few inputs
        return out

    bad = int((np.abs(inputs[:, 0]) > 2.5).sum())
    assert rep.reencode(enc, version=2) == bad
    keep = np.abs(inputs[:, 0]) <= 2.5
    assert rep.encoder_version == 2 and len(rep) == 100 - bad
    np.testing.assert_array_equal(rep.ids, ids[keep])
    np.testing.assert_array_equal(rep.inputs, inputs[keep])
    np.testing.assert_allclose(rep.skills, inputs[keep] @ m)
    np.testing.assert_array_equal(rep.cov, kde.kde_covariance(rep.skills, n=100))
    np.testing.assert_allclose(rep.nn_dist, kde.mahalanobis_nn(rep.skills, rep.cov)[0], rtol=1e-9)
    # It refills, then removes by the new metric.
    y = rng.normal(size=(50, 3))
    rep.commit_many(y @ m, y)
    assert len(rep) == 100
    with pytest.raises(ValueError):
        Repertoire(RepertoireConfig(size=5, dim=2)).reencode(enc, 1)


def test_sample_keeps_to_the_archive_support() -> None:
    # safe skills on a ring around an unsafe disc: the support radius keeps draws off the disc
    rng = np.random.default_rng(3)
    ang = rng.uniform(0, 2 * np.pi, 400)
    ring = np.stack([np.cos(ang), np.sin(ang)], 1) * rng.uniform(0.4, 0.9, (400, 1))
    box = Box.uniform(2, -1.0, 1.0)
    cut = Repertoire(RepertoireConfig(size=400, dim=2, support_radius=0.5), bounds=box)
    full = Repertoire(RepertoireConfig(size=400, dim=2, support_radius=None), bounds=box)
    cut.commit_many(ring)
    full.commit_many(ring)
    assert cut.support() == pytest.approx(0.5 * cut.delta())
    assert full.support() is None
    z_cut, z_full = cut.sample(5000, rng), full.sample(5000, rng)
    radius = cut.support()
    assert radius is not None
    assert kde.nearest_distance(cut.skills, cut.cov, z_cut).max() <= radius + 1e-12
    r_cut, r_full = np.linalg.norm(z_cut, axis=1), np.linalg.norm(z_full, axis=1)
    assert (r_full < 0.3).mean() > 0.02 and (r_cut < 0.3).mean() < 0.002
    with pytest.raises(ValueError):
        RepertoireConfig(support_radius=0.0)
