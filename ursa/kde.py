"""Gaussian KDE over a skill repertoire: bandwidth, sampling, density, δ and the entropy bound.

Pure functions on arrays (paper §4.2 and Appendix A). ``N`` is the number of stored points, ``D``
the skill dimension. The kernel covariance is ``Σ = cov(points) · f²`` with Scott's factor
``f = n^(−1/(D+4))``; with ``n = N`` this is ``scipy.stats.gaussian_kde(points.T).covariance``
(equal to rounding: scipy goes through a weighted ``np.cov``).

Degenerate inputs never raise: fewer than two points give a zero data covariance, and any
covariance that is not safely positive definite (``N < D + 1``, repeated or collinear points)
gets a ridge (see :func:`regularize_cov`). A non-degenerate covariance is only symmetrized, so
results agree with scipy wherever scipy works at all.
"""

from __future__ import annotations

import math
from collections.abc import Iterator

import numpy as np
from scipy.linalg import cholesky, solve_triangular
from scipy.special import logsumexp

RIDGE = 1e-9
"""Relative ridge: a covariance whose smallest eigenvalue is ≤ RIDGE · trace/D gets
(RIDGE · trace/D − min(λ_min, 0)) · I added (trace/D replaced by 1 when it is 0)."""

_CHUNK = 1 << 20
"""Pairs (query × stored point) evaluated at once by the O(M·N) functions (memory bound)."""


def scott_factor(n: int, d: int) -> float:
    """Scott's bandwidth factor ``n^(−1/(d+4))`` (kernel std = factor × data std).

    n: number of points (values below 1 are treated as 1); d: dimension.
    """
    return float(max(int(n), 1) ** (-1.0 / (d + 4)))


def regularize_cov(cov: np.ndarray, ridge: float = RIDGE) -> np.ndarray:
    """A copy of ``cov`` (D, D) that is symmetric positive definite.

    Returned symmetrized (``(Σ + Σᵀ)/2``) when its smallest eigenvalue exceeds ``ridge · s`` with
    ``s = trace/D`` (or 1 where the trace is 0); otherwise ``(ridge · s − min(λ_min, 0)) · I`` is
    added. A non-finite covariance (overflow) is replaced by the identity.
    """
    cov = np.array(cov, dtype=np.float64, copy=True)
    d = cov.shape[0]
    if d == 0:
        return cov
    if not np.all(np.isfinite(cov)):
        return np.eye(d)
    cov = 0.5 * (cov + cov.T)
    scale = float(np.trace(cov)) / d
    if not scale > 0.0:
        scale = 1.0
    lam_min = float(np.linalg.eigvalsh(cov)[0])
    if lam_min > ridge * scale:
        return cov
    return cov + (ridge * scale - min(lam_min, 0.0)) * np.eye(d)


def kde_covariance(points: np.ndarray, n: int | None = None, ridge: float = RIDGE) -> np.ndarray:
    """Kernel covariance Σ (D, D) of a Gaussian KDE on ``points`` (N, D).

    ``Σ = np.cov(points.T) · scott_factor(n, D)²`` with ``n = N`` by default (scipy's
    ``gaussian_kde.covariance``, to rounding); pass ``n = N_R`` for the paper's
    ``N_R^(−2/(D+4))`` scaling. N < 2 gives a zero data covariance; the result goes through
    :func:`regularize_cov`.
    """
    points = np.asarray(points, dtype=np.float64)
    npts, d = points.shape
    nf = npts if n is None else n
    data_cov = np.zeros((d, d)) if npts < 2 else np.atleast_2d(np.cov(points.T))
    return regularize_cov(data_cov * scott_factor(nf, d) ** 2, ridge)


def whitening_matrix(cov: np.ndarray) -> np.ndarray:
    """A (D, D) lower-triangular with ``A Σ Aᵀ = I``: ``A = C⁻¹`` where ``Σ = C Cᵀ`` (Cholesky).

    Whitened points are ``W = X Aᵀ`` (rows), and the Mahalanobis distance is the Euclidean
    distance of whitened points: ``d_Σ(x, y) = ‖A(x − y)‖``. ``cov`` must be positive definite
    (pass it through :func:`regularize_cov` first).
    """
    c = cholesky(np.asarray(cov, dtype=np.float64), lower=True)
    return np.asarray(solve_triangular(c, np.eye(c.shape[0]), lower=True))


def _log_norm_const(cov: np.ndarray) -> float:
    """``log((2π)^(D/2) det(Σ)^(1/2))`` for a positive definite (D, D) Σ."""
    c = cholesky(np.asarray(cov, dtype=np.float64), lower=True)
    return float(np.log(np.diag(c)).sum() + 0.5 * cov.shape[0] * math.log(2.0 * math.pi))


def kde_sample(
    points: np.ndarray,
    cov: np.ndarray,
    n: int,
    rng: np.random.Generator,
    chol: np.ndarray | None = None,
) -> np.ndarray:
    """n samples (n, D) of ``q = (1/N) Σ_i N(z_i, Σ)``: a stored point drawn uniformly + N(0, Σ).

    points: (N, D); cov: Σ (D, D), regularized if needed; chol: its lower Cholesky factor (D, D)
    when the caller already has it. Draws ``rng.integers`` for the points, then
    ``rng.standard_normal((n, D))``. With N = 0 the kernel sits at the origin (N(0, Σ) samples).
    """
    points = np.asarray(points, dtype=np.float64)
    d = points.shape[1]
    c = cholesky(regularize_cov(cov), lower=True) if chol is None else chol
    centres = points[rng.integers(0, len(points), size=n)] if len(points) else np.zeros((n, d))
    out: np.ndarray = centres + rng.standard_normal((n, d)) @ c.T
    return out


def kde_sample_in_box(
    points: np.ndarray,
    cov: np.ndarray,
    n: int,
    rng: np.random.Generator,
    low: np.ndarray,
    high: np.ndarray,
    tries: int = 20,
    support: float | None = None,
) -> np.ndarray:
    """n samples (n, D) of the KDE truncated to the box [low, high] (D,) each and, with
    ``support``, to the points' support: draws farther than ``support`` (d_Σ) from every stored
    point are drawn again. At most ``tries`` rounds; then a draw still off the support is
    replaced by its kernel's centre, and any draw is clipped into the box.

    A provided feature function has a reachable range (the point env's arena); the kernels of
    the archive's edge points reach past it, and a skill outside it cannot be executed. The
    support radius does the same for the gaps of the archive: the stored skills are features
    the robot reached safely, and a draw more than δ from all of them (in the point env, one
    inside the unsafe disc) asks for a skill no safe execution is known to come within δ of.
    The first round is :func:`kde_sample`'s draw with the same generator calls.
    """
    points = np.asarray(points, dtype=np.float64)
    lo, hi = np.asarray(low, np.float64), np.asarray(high, np.float64)
    c = cholesky(regularize_cov(cov), lower=True)
    d = points.shape[1]
    if len(points) == 0:
        support = None
    idx = rng.integers(0, len(points), size=n) if len(points) else np.zeros(n, np.int64)
    centres = points[idx] if len(points) else np.zeros((n, d))
    out: np.ndarray = centres + rng.standard_normal((n, d)) @ c.T

    def off(x: np.ndarray) -> np.ndarray:
        bad = np.asarray(~((x >= lo) & (x <= hi)).all(axis=1))
        if support is not None and len(x):
            bad |= nearest_distance(points, cov, x) > support
        return bad

    bad = off(out)
    for _ in range(tries):
        if not bad.any():
            break
        k = int(bad.sum())
        j = rng.integers(0, len(points), size=k) if len(points) else np.zeros(k, np.int64)
        idx[bad] = j
        draw = (points[j] if len(points) else np.zeros((k, d))) + rng.standard_normal((k, d)) @ c.T
        out[bad] = draw
        bad[bad] = off(draw)
    if support is not None and bad.any():
        out[bad] = points[idx[bad]]
    return np.clip(out, lo, hi)


def support_radius(factor: float | None, delta: float) -> float | None:
    """The support radius of KDE draws in d_Σ: ``factor`` × δ, or None (no truncation) when no
    factor is set or δ is undefined (inf or nan: fewer than two stored skills)."""
    return factor * delta if factor is not None and math.isfinite(delta) else None


def nearest_distance(points: np.ndarray, cov: np.ndarray, x: np.ndarray) -> np.ndarray:
    """d_Σ from each row of x (M, D) to its nearest row of ``points`` (N, D): (M,); inf when
    N = 0. O(M·N·D), memory bounded by chunking."""
    x = np.asarray(x, dtype=np.float64)
    out = np.full(len(x), np.inf)
    points = np.asarray(points, dtype=np.float64)
    if len(points) == 0:
        return out
    for s, e, d2 in _sq_mahalanobis_chunks(points, regularize_cov(cov), x):
        out[s:e] = np.sqrt(d2.min(axis=1))
    return out


def _sq_mahalanobis_chunks(
    points: np.ndarray, cov: np.ndarray, x: np.ndarray
) -> Iterator[tuple[int, int, np.ndarray]]:
    """Yield ``(start, stop, d²)``, d² (stop − start, N) squared Mahalanobis distances x→points.

    Differences are whitened directly (no ‖a‖² + ‖b‖² − 2ab expansion, which cancels badly for
    close points far from the origin).
    """
    a = whitening_matrix(cov)
    wp = points @ a.T
    wx = x @ a.T
    step = max(1, _CHUNK // max(len(points), 1))
    for s in range(0, len(x), step):
        diff = wx[s : s + step, None, :] - wp[None, :, :]
        yield s, s + diff.shape[0], np.einsum("ijk,ijk->ij", diff, diff)


def kde_logpdf(points: np.ndarray, cov: np.ndarray, x: np.ndarray) -> np.ndarray:
    """log q(x) (M,) of the KDE on ``points`` (N, D) with kernel covariance Σ (D, D), at x (M, D).

    ``log q(x) = LSE_j(−½ d_Σ(x, z_j)²) − log N − ½ log det(2πΣ)``; −inf everywhere when N = 0.
    O(M·N·D) time, memory bounded by chunking.
    """
    points = np.asarray(points, dtype=np.float64)
    x = np.asarray(x, dtype=np.float64)
    out = np.full(len(x), -np.inf)
    if len(points) == 0:
        return out
    cov = regularize_cov(cov)
    const = math.log(len(points)) + _log_norm_const(cov)
    for s, e, d2 in _sq_mahalanobis_chunks(points, cov, x):
        out[s:e] = logsumexp(-0.5 * d2, axis=1) - const
    return out


def mahalanobis_nn(points: np.ndarray, cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Brute-force Mahalanobis nearest neighbour of every point (reference helper, O(N²·D)).

    points: (N, D); cov: Σ (D, D). Returns ``dist`` (N,) = d_Σ(z_i, z_i^nn) and ``idx`` (N,) the
    neighbour's row (lowest row among equal distances); a lone point gets ``inf`` and −1.
    """
    points = np.asarray(points, dtype=np.float64)
    n = len(points)
    dist = np.full(n, np.inf)
    idx = np.full(n, -1, dtype=np.int64)
    if n < 2:
        return dist, idx
    cov = regularize_cov(cov)
    for s, e, d2 in _sq_mahalanobis_chunks(points, cov, points):
        d2[np.arange(e - s), np.arange(s, e)] = np.inf
        j = np.argmin(d2, axis=1)
        idx[s:e] = j
        dist[s:e] = np.sqrt(d2[np.arange(e - s), j])
    return dist, idx


def delta(nn_dist: np.ndarray, n_r: int, n_z: int, d: int) -> float:
    """Dynamic threshold ``δ = (N_R / N_z)^(1/D) · mean_i d_Σ(z_i, z_i^nn)`` (paper §4.2).

    nn_dist: (N,) Mahalanobis NN distances; n_r: repertoire size the distances come from; n_z:
    number of distinct skills wanted; d: D. The mean NN distance of n uniform points scales as
    n^(−1/D), hence the factor. Returns inf when there are no finite distances (N < 2).
    """
    nn_dist = np.asarray(nn_dist, dtype=np.float64)
    finite = nn_dist[np.isfinite(nn_dist)]
    if len(finite) == 0:
        return math.inf
    return float((n_r / n_z) ** (1.0 / d) * finite.mean())


def entropy_lower_bound(nn_dist: np.ndarray, cov: np.ndarray, n_r: int | None = None) -> float:
    """Lower bound on Ĥ(q), Eq. (1) with its constant written out (Appendix A).

    ``−(1/N) Σ_i log(1 + (N−1) e^(−½ d_i²)) + ½ log det Σ + (D/2) log 2π + log N``, with
    d_i = d_Σ(z_i, z_i^nn) (N,) and N = ``n_r`` (default ``len(nn_dist)``; it must be the number
    of points the distances come from for the inequality to hold). nan when N = 0.
    """
    nn_dist = np.asarray(nn_dist, dtype=np.float64)
    n = len(nn_dist) if n_r is None else int(n_r)
    if n == 0 or len(nn_dist) == 0:
        return math.nan
    cov = regularize_cov(cov)
    d = cov.shape[0]
    # log(1 + (N−1)e^(−d²/2)) via logaddexp stays finite for d = 0 and d = inf alike.
    terms = np.logaddexp(0.0, math.log(n - 1) - 0.5 * nn_dist**2) if n > 1 else np.zeros(1)
    c = cholesky(cov, lower=True)
    half_logdet = float(np.log(np.diag(c)).sum())
    return float(-terms.mean() + half_logdet + 0.5 * d * math.log(2.0 * math.pi) + math.log(n))


def entropy_mc(points: np.ndarray, cov: np.ndarray) -> float:
    """Monte-Carlo entropy estimate ``Ĥ(q) = −(1/N) Σ_i log q(z_i)`` (N,D) points, Σ (D, D).

    Follows Appendix A; §4.2's display writes ``q log q`` inside the sum, a typo. O(N²·D); nan
    when N = 0.
    """
    points = np.asarray(points, dtype=np.float64)
    if len(points) == 0:
        return math.nan
    return float(-kde_logpdf(points, cov, points).mean())
