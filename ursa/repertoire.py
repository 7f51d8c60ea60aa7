"""The diversity repertoire R (paper §4.2): a fixed-size archive of skills with KDE sampling.

Every committed feature is added; once the archive holds ``size`` = N_R skills, a commit removes
the skill with the smallest Mahalanobis nearest-neighbour distance d_Σ among the archive plus the
new skill (possibly the new one itself: a rejection). Ties are broken by removing the newest skill
(largest id; the new skill counts as newest). Nearest neighbours are maintained incrementally on
whitened points (``w = A z`` with ``A Σ Aᵀ = I``, so d_Σ is Euclidean there): a commit costs
O(N_R·D) plus a rescan for each skill whose neighbour was removed.

Σ schedule: while the archive is filling, Σ is always that of the current archive (computed
lazily when something needs it). On the commit that fills it, Σ is refreshed; then again after
every ``refresh_every`` commits into the full archive (accepted or rejected), after ``reencode``,
never otherwise. Σ = ``np.cov`` of the archive, rows in id order, × scott_factor(N_R, D)², N_R
being the configured size (the paper's N_R^(−2/(D+4))), with the ridge of :mod:`ursa.kde`. A
refresh re-whitens the archive and recomputes every nearest neighbour.

See docs/repertoire.md for the algorithm, its complexity and measured speed.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from ursa import kde
from ursa.bounds import Box
from ursa.repertoire_kernels import (
    all_nn_brute,
    commit_full,
    nn_from_candidates,
    tree_build,
    whiten_row,
    whiten_t,
)
from ursa.rundir import atomic_write


@dataclass(frozen=True)
class RepertoireConfig:
    """Size and schedule of the skill repertoire."""

    size: int = 5000
    """N_R: number of skills the archive holds."""
    dim: int = 3
    """D: skill (feature) dimension."""
    n_z: int = 100
    """N_z: number of distinct skills the robot should tell apart; sets δ."""
    refresh_every: int | None = None
    """Recompute Σ (and all nearest neighbours) after this many commits into the full archive;
    None: every ``size`` commits; 0: never (Σ stays as it was when the archive filled, until
    ``reencode``)."""
    input_dim: int | None = None
    """F: size of the learned feature function's input (the VAE input) stored with each skill;
    None for a provided feature function (no inputs stored)."""
    ridge: float = kde.RIDGE
    """Relative ridge added to a degenerate Σ (see ursa.kde.regularize_cov)."""
    support_radius: float | None = 0.5
    """Skills are sampled from the KDE truncated to the archive's support: a draw farther than
    ``support_radius`` × δ (d_Σ) from every stored skill is drawn again (kde.kde_sample_in_box),
    in the collectors', the learner's and the evaluations' draws alike. The stored skills are
    features reached safely and δ is the tolerance of execution: at δ/2 a draw leaves half of
    δ to the execution's error. None: the whole KDE."""

    def __post_init__(self) -> None:
        if self.support_radius is not None and not self.support_radius > 0:
            raise ValueError(f"support_radius must be None or > 0, got {self.support_radius}")
        if self.size < 1 or self.dim < 1 or self.n_z < 1 or self.refresh_period < 0:
            raise ValueError(f"invalid RepertoireConfig {self}")
        if self.input_dim is not None and self.input_dim < 1:
            raise ValueError(f"input_dim must be None or ≥ 1, got {self.input_dim}")

    @property
    def refresh_period(self) -> int:
        """Commits into the full archive between two Σ refreshes (0: never)."""
        return self.size if self.refresh_every is None else self.refresh_every


_BRUTE_MAX = 1024
"""Archives up to this size recompute all nearest neighbours by brute force at a refresh; larger
ones take candidates from a KD-tree (O(N log N)) and recompute their distances exactly."""


class Repertoire:
    """Fixed-size archive of skills (N_R, D) with incremental Mahalanobis nearest neighbours.

    Arrays handed out (``skills``, ``ids``, ``ages``, ``inputs``, ``nn_dist``) are copies in id
    order. ``ages`` holds the commit index (0-based count of valid commits) at which each skill
    was committed. Counters: ``commits`` (valid commits) = ``accepted`` + ``rejected``;
    ``rejected_invalid`` counts features refused for NaN/inf values, a wrong shape or (with
    ``bounds``) a value outside the declared skill box (never raised), ``rejected_out_of_bounds``
    the last kind alone; ``repaired`` the skills dropped when the archive was loaded.
    """

    def __init__(self, config: RepertoireConfig | None = None, bounds: Box | None = None) -> None:
        self.config = config if config is not None else RepertoireConfig()
        if bounds is not None and bounds.dim != self.config.dim:
            raise ValueError(f"bounds of dimension {bounds.dim} for skills of {self.config.dim}")
        self.bounds = bounds
        """The declared skill box (ursa.bounds): no skill outside it is ever admitted."""
        c = self.config
        self._f = c.input_dim or 0
        self._p = np.zeros((c.size, c.dim))
        self._wt = np.zeros((c.dim, c.size))
        self._tree = np.full(2 * _pow2(c.size), -1, dtype=np.int64)
        self._nn = np.full(c.size, np.inf)
        self._nn_idx = np.full(c.size, -1, dtype=np.int64)
        self._ids = np.zeros(c.size, dtype=np.int64)
        self._ages = np.zeros(c.size, dtype=np.int64)
        self._inputs = np.zeros((c.size, self._f))
        self._n = 0
        self._cov = np.eye(c.dim)
        self._a = np.eye(c.dim)
        self._chol = np.eye(c.dim)
        self._stale = True
        """Σ, whitened points and NN lag behind the archive (only ever while it fills)."""
        self._order: np.ndarray | None = None
        self._dz = np.zeros(c.size)
        self._buf = np.zeros(c.size)
        self._wz = np.zeros(c.dim)
        self._changed = np.zeros(c.size, dtype=np.int64)
        self.next_id = 0
        self.since_refresh = 0
        """Commits into the full archive since Σ was last refreshed."""
        self.commits = 0
        self.accepted = 0
        self.rejected = 0
        self.rejected_invalid = 0
        self.rejected_out_of_bounds = 0
        self.repaired = 0
        self.encoder_version = 0

    # --- commits -------------------------------------------------------------------------------

    def commit(self, z: np.ndarray, input: np.ndarray | None = None) -> bool:
        """Commit one feature z (D,) (with the VAE input (F,) for a learned φ); True if stored."""
        try:
            zz = np.asarray(z, dtype=np.float64)
            ii = None if input is None else np.asarray(input, dtype=np.float64)
        except (TypeError, ValueError):
            self.rejected_invalid += 1
            return False
        if zz.shape != (self.config.dim,) or (ii is not None and ii.ndim != 1):
            self.rejected_invalid += 1
            return False
        return self.commit_many(zz[None, :], None if ii is None else ii[None, :]) == 1

    def commit_many(self, z: np.ndarray, inputs: np.ndarray | None = None) -> int:
        """Commit the rows of z (M, D) in order (inputs (M, F) for a learned φ); returns how many
        were stored. Rows with NaN/inf (in z or inputs), a wrong width, or a missing input when
        ``input_dim`` is set are counted in ``rejected_invalid``; inputs are ignored when it is
        not set."""
        c = self.config
        try:
            zz = np.asarray(z, dtype=np.float64)
            ii = None if inputs is None else np.asarray(inputs, dtype=np.float64)
        except (TypeError, ValueError):
            self.rejected_invalid += _rows(z)
            return 0
        if zz.ndim != 2 or zz.shape[1] != c.dim:
            self.rejected_invalid += _rows(z)
            return 0
        m = zz.shape[0]
        ok = np.isfinite(zz).all(axis=1)
        if self.bounds is not None:
            out = ok & ~self.bounds.contains(zz)
            self.rejected_out_of_bounds += int(out.sum())
            ok &= ~out
        if self._f:
            if ii is None or ii.shape != (m, self._f):
                self.rejected_invalid += m
                return 0
            ok &= np.isfinite(ii).all(axis=1)
        else:
            ii = None
        if not ok.all():
            self.rejected_invalid += int(m - ok.sum())
            zz = zz[ok]
            ii = None if ii is None else ii[ok]
        zz = np.ascontiguousarray(zz)
        zin = np.ascontiguousarray(ii) if ii is not None else np.zeros((len(zz), 0))
        return self._commit_valid(zz, zin)

    def _commit_valid(self, z: np.ndarray, zin: np.ndarray) -> int:
        c = self.config
        m = len(z)
        done = 0
        stored = 0
        while done < m:
            if self._n < c.size:
                k = min(c.size - self._n, m - done)
                sl = slice(self._n, self._n + k)
                self._p[sl] = z[done : done + k]
                self._inputs[sl] = zin[done : done + k]
                self._ids[sl] = np.arange(self.next_id, self.next_id + k)
                self._ages[sl] = np.arange(self.commits, self.commits + k)
                self._n += k
                self.next_id += k
                self.commits += k
                self.accepted += k
                stored += k
                done += k
                self._order = None
                self._stale = True
                if self._n == c.size:
                    self.refresh()
                continue
            k = m - done
            period = c.refresh_period
            if period:
                if self.since_refresh >= period:
                    self.refresh()
                k = min(k, period - self.since_refresh)
            acc = int(
                commit_full(
                    self._p,
                    self._wt,
                    self._nn,
                    self._nn_idx,
                    self._ids,
                    self._ages,
                    self._inputs,
                    self._tree,
                    z[done : done + k],
                    zin[done : done + k],
                    self._a,
                    self.next_id,
                    self.commits,
                    self._dz,
                    self._wz,
                    self._changed,
                    self._buf,
                )
            )
            self.next_id += acc
            self.commits += k
            self.accepted += acc
            self.rejected += k - acc
            stored += acc
            done += k
            if acc:
                self._order = None
            self.since_refresh += k
            if period and self.since_refresh >= period:
                self.refresh()
        return stored

    # --- Σ and nearest neighbours --------------------------------------------------------------

    def refresh(self) -> None:
        """Recompute Σ from the archive, re-whiten it and recompute every nearest neighbour."""
        n = self._n
        order = self._id_order()
        if n == 0:
            self._cov = np.eye(self.config.dim)
        else:
            self._cov = kde.kde_covariance(
                self._p[order], n=self.config.size, ridge=self.config.ridge
            )
        self._set_cov(self._cov)
        self._rebuild_nn()
        self.since_refresh = 0

    def _set_cov(self, cov: np.ndarray) -> None:
        self._cov = cov
        self._chol = np.linalg.cholesky(cov)
        self._a = np.ascontiguousarray(kde.whitening_matrix(cov))

    def _rebuild_nn(self) -> None:
        n = self._n
        whiten_t(self._p[:n], self._a, self._wt)
        self._nn[:] = np.inf
        self._nn_idx[:] = -1
        if n <= _BRUTE_MAX:
            all_nn_brute(self._wt, n, self._nn, self._nn_idx)
        elif n > 1:
            k = 2
            pts = self._wt[:, :n].T
            _, cand = cKDTree(pts).query(pts, k=k)
            nn_from_candidates(
                self._wt, np.ascontiguousarray(cand, dtype=np.int64), self._nn, self._nn_idx
            )
        tree_build(self._tree, n, self._nn, self._ids)
        self._stale = False

    def _fresh(self) -> None:
        if self._stale:
            self.refresh()

    def _id_order(self) -> np.ndarray:
        if self._order is None:
            self._order = np.argsort(self._ids[: self._n], kind="stable")
        return self._order

    # --- views ---------------------------------------------------------------------------------

    def __len__(self) -> int:
        return self._n

    @property
    def skills(self) -> np.ndarray:
        """Stored skills (n, D), id order."""
        return self._p[self._id_order()]

    @property
    def ids(self) -> np.ndarray:
        """Stable skill ids (n,), ascending (a counter over stored skills)."""
        return self._ids[self._id_order()]

    @property
    def ages(self) -> np.ndarray:
        """Commit index at which each skill arrived (n,), id order."""
        return self._ages[self._id_order()]

    @property
    def inputs(self) -> np.ndarray:
        """Stored VAE inputs (n, F) (F = 0 without ``input_dim``), id order."""
        return self._inputs[self._id_order()]

    @property
    def nn_dist(self) -> np.ndarray:
        """d_Σ(z_i, z_i^nn) (n,), id order; inf for a lone skill."""
        self._fresh()
        return np.sqrt(self._nn[self._id_order()])

    @property
    def nn_ids(self) -> np.ndarray:
        """Id of each skill's nearest neighbour (n,), id order; −1 for a lone skill."""
        self._fresh()
        idx = self._nn_idx[self._id_order()]
        return np.where(idx >= 0, self._ids[np.maximum(idx, 0)], -1)

    @property
    def cov(self) -> np.ndarray:
        """Σ (D, D) in use: identity when empty."""
        self._fresh()
        return self._cov.copy()

    @property
    def full(self) -> bool:
        return self._n == self.config.size

    @property
    def invalid(self) -> int:
        """Alias of ``rejected_invalid``."""
        return self.rejected_invalid

    def delta(self) -> float:
        """δ = (n/N_z)^(1/D) · mean d_Σ(z_i, z_i^nn), n the skills stored (N_R once full)."""
        return kde.delta(self.nn_dist, self._n, self.config.n_z, self.config.dim)

    def support(self) -> float | None:
        """The support radius of the KDE draws in d_Σ (``support_radius`` × δ), or None (no
        truncation: no radius configured, or fewer than two skills, where δ is undefined)."""
        return kde.support_radius(self.config.support_radius, self.delta())

    def entropy_bound(self) -> float:
        """Eq. (1) lower bound on Ĥ(q) over the n stored skills (nan when empty)."""
        return kde.entropy_lower_bound(self.nn_dist, self.cov, self._n)

    def entropy_mc(self) -> float:
        """Ĥ(q) = −(1/n) Σ_i log q(z_i), O(n²·D) (nan when empty)."""
        return kde.entropy_mc(self.skills, self.cov)

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """n skills (n, D) from q = KDE(R) with the current Σ; N(0, I) while empty.

        Without ``bounds``: the same draws as ``kde.kde_sample(self.skills, self.cov, n, rng)``,
        without copying the archive or factorizing Σ again. With ``bounds``: the KDE truncated
        to the skill box (``kde.kde_sample_in_box``): a skill outside the range of the feature
        function cannot be executed; and, with ``config.support_radius``, to the archive's
        support (:meth:`support`)."""
        self._fresh()
        if self.bounds is not None:
            return kde.kde_sample_in_box(
                self.skills,
                self._cov,
                n,
                rng,
                np.asarray(self.bounds.low),
                np.asarray(self.bounds.high),
                support=self.support(),
            )
        if self._n == 0:
            return kde.kde_sample(np.zeros((0, self.config.dim)), self._cov, n, rng, self._chol)
        centres = self._p[self._id_order()[rng.integers(0, self._n, size=n)]]
        out: np.ndarray = centres + rng.standard_normal((n, self.config.dim)) @ self._chol.T
        return out

    def nearest(self, z: np.ndarray, k: int = 1) -> np.ndarray:
        """Ids (≤ k,) of the stored skills nearest to z (D,) in d_Σ, closest first (ties: lower
        id first)."""
        self._fresh()
        zz = np.asarray(z, dtype=np.float64).reshape(self.config.dim)
        n = self._n
        wz = np.zeros(self.config.dim)
        whiten_row(zz, self._a, wz)
        diff = self._wt[:, :n].T - wz
        d2 = np.einsum("ij,ij->i", diff, diff)
        sel = np.lexsort((self._ids[:n], d2))[:k]
        return self._ids[sel].copy()

    def get(self, ids: np.ndarray) -> np.ndarray:
        """Skills (k, D) with the given ids (k,); KeyError for an id not stored."""
        order = self._id_order()
        sorted_ids = self._ids[order]
        q = np.asarray(ids, dtype=np.int64).reshape(-1)
        pos = np.searchsorted(sorted_ids, q)
        pos_c = np.minimum(pos, max(len(sorted_ids) - 1, 0))
        if len(sorted_ids) == 0 or not np.array_equal(sorted_ids[pos_c], q):
            raise KeyError(f"ids not in the repertoire: {q}")
        return self._p[order[pos_c]]

    # --- learned feature function --------------------------------------------------------------

    def reencode(self, encode_fn: Callable[[np.ndarray], np.ndarray], version: int) -> int:
        """Re-encode every stored input with a new encoder ((M, F) -> (M, D)), set
        ``encoder_version`` and refresh Σ and all nearest neighbours. Skills whose new feature
        is not finite are dropped; returns how many were dropped. Ids, ages and order are kept."""
        if not self._f:
            raise ValueError("reencode needs a repertoire with input_dim set")
        n = self._n
        order = self._id_order()
        new = np.asarray(encode_fn(self._inputs[order].copy()), dtype=np.float64)
        if new.shape != (n, self.config.dim):
            raise ValueError(f"encoder returned {new.shape}, expected {(n, self.config.dim)}")
        keep = self._admissible(new)
        ids, ages, inputs = self._ids[order], self._ages[order], self._inputs[order]
        m = int(keep.sum())
        self._p[:m] = new[keep]
        self._ids[:m] = ids[keep]
        self._ages[:m] = ages[keep]
        self._inputs[:m] = inputs[keep]
        self._n = m
        self._order = None
        self.encoder_version = int(version)
        self.refresh()
        return n - m

    def _admissible(self, z: np.ndarray) -> np.ndarray:
        """Mask (n,) of the rows of z (n, D) that are finite and inside ``bounds``."""
        ok = np.isfinite(z).all(axis=1)
        return ok & self.bounds.contains(z) if self.bounds is not None else ok

    # --- persistence ---------------------------------------------------------------------------

    def state_dict(self) -> dict[str, np.ndarray | int | float]:
        """Everything needed to restore the repertoire exactly (arrays in id order)."""
        c = self.config
        self._fresh()
        return {
            "skills": self.skills,
            "ids": self.ids,
            "ages": self.ages,
            "inputs": self.inputs,
            "cov": self._cov.copy(),
            "size": c.size,
            "dim": c.dim,
            "n_z": c.n_z,
            "refresh_every": -1 if c.refresh_every is None else c.refresh_every,
            "input_dim": -1 if c.input_dim is None else c.input_dim,
            "ridge": c.ridge,
            "next_id": self.next_id,
            "since_refresh": self.since_refresh,
            "commits": self.commits,
            "accepted": self.accepted,
            "rejected": self.rejected,
            "rejected_invalid": self.rejected_invalid,
            "rejected_out_of_bounds": self.rejected_out_of_bounds,
            "encoder_version": self.encoder_version,
        }

    @classmethod
    def from_state_dict(
        cls, state: dict[str, np.ndarray | int | float], bounds: Box | None = None
    ) -> Repertoire:
        """Rebuild a repertoire from :meth:`state_dict` (or a loaded npz): same config,
        archive, Σ, nearest neighbours and counters.

        Repair: stored skills that are not finite, lie outside ``bounds`` or carry a
        non-finite input (a corrupted file, or an archive written before the bounds were
        enforced) are dropped and counted in ``repaired``; Σ and the nearest neighbours are
        then recomputed from what is left."""

        def i(key: str) -> int:
            return int(np.asarray(state[key]))

        input_dim = i("input_dim")
        cfg = RepertoireConfig(
            size=i("size"),
            dim=i("dim"),
            n_z=i("n_z"),
            refresh_every=None if i("refresh_every") < 0 else i("refresh_every"),
            input_dim=None if input_dim < 0 else input_dim,
            ridge=float(np.asarray(state["ridge"])),
        )
        rep = cls(cfg, bounds)
        skills = np.asarray(state["skills"], dtype=np.float64).reshape(-1, cfg.dim)
        n = len(skills)
        if n > cfg.size:
            raise ValueError(f"{n} skills in a repertoire of size {cfg.size}")
        ids = np.asarray(state["ids"], dtype=np.int64).reshape(n)
        ages = np.asarray(state["ages"], dtype=np.int64).reshape(n)
        inputs = np.asarray(state["inputs"], dtype=np.float64).reshape(n, rep._f)
        keep = rep._admissible(skills) & np.isfinite(inputs).all(axis=1)
        rep.repaired = int(n - keep.sum())
        skills, ids, ages, inputs = skills[keep], ids[keep], ages[keep], inputs[keep]
        n = len(skills)
        rep._p[:n] = skills
        rep._ids[:n] = ids
        rep._ages[:n] = ages
        rep._inputs[:n] = inputs
        rep._n = n
        for key in ("next_id", "since_refresh", "commits", "accepted", "rejected"):
            setattr(rep, key, i(key))
        rep.rejected_invalid = i("rejected_invalid")
        if "rejected_out_of_bounds" in state:
            rep.rejected_out_of_bounds = i("rejected_out_of_bounds")
        rep.encoder_version = i("encoder_version")
        if rep.repaired:
            rep.since_refresh = 0
        if n < cfg.size:
            rep._stale = True  # filling: Σ follows the archive
        else:
            rep._set_cov(
                np.asarray(state["cov"], dtype=np.float64).reshape(cfg.dim, cfg.dim).copy()
            )
            rep._rebuild_nn()
        return rep

    def save(self, path: str | os.PathLike[str]) -> None:
        """Write :meth:`state_dict` to ``path`` as npz (:func:`ursa.rundir.atomic_write`)."""
        arrays: dict[str, Any] = {k: np.asarray(v) for k, v in self.state_dict().items()}
        atomic_write(path, lambda f: np.savez(f, **arrays))

    @classmethod
    def load(cls, path: str | os.PathLike[str], bounds: Box | None = None) -> Repertoire:
        """Read a repertoire written by :meth:`save` (no pickle), repaired against ``bounds``
        (see :meth:`from_state_dict`)."""
        with np.load(path, allow_pickle=False) as data:
            return cls.from_state_dict({k: data[k] for k in data.files}, bounds)


def _pow2(n: int) -> int:
    """Smallest power of two ≥ n."""
    return 1 << max(int(n) - 1, 0).bit_length()


def _rows(z: object) -> int:
    """How many features an unusable commit_many argument counts as (rows, at least 1)."""
    shape = getattr(z, "shape", None)
    if isinstance(shape, tuple) and len(shape) == 2:
        return max(int(shape[0]), 1)
    try:
        return max(len(z), 1)  # type: ignore[arg-type]
    except TypeError:
        return 1


__all__ = ["Repertoire", "RepertoireConfig"]
