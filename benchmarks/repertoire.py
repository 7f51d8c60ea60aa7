"""Repertoire commits per second and KDE sampling time, against what a user would write with scipy.

Claim: at N_R = 5000, D = 3, on one core, the incremental repertoire takes ≥ 50,000 commits/s and
is ≥ 100× faster than rebuilding a ``scipy.spatial.cKDTree`` on the whitened archive at every
commit (same removal rule, same Σ), measured in this run. Also: drawing 1024 skills against
``scipy.stats.gaussian_kde.resample`` on the same archive.

Times are CPU time of this process (``time.process_time``), single-threaded (BLAS pinned to one
thread), so that other load on a shared machine does not count; wall-clock rates are printed too.

    .venv/bin/python benchmarks/repertoire.py [--quick]
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
from scipy.spatial import cKDTree  # noqa: E402
from scipy.stats import gaussian_kde  # noqa: E402

from ursa import kde  # noqa: E402
from ursa.repertoire import Repertoire, RepertoireConfig  # noqa: E402


class KDTreeRepertoire:
    """The library way: rebuild a cKDTree over the whitened archive plus the new skill, query
    every NN, remove the smallest (newest among ties). Σ held fixed, as between two refreshes."""

    def __init__(self, skills: np.ndarray, ids: np.ndarray, cov: np.ndarray) -> None:
        self.a = kde.whitening_matrix(cov)
        self.w = skills @ self.a.T
        self.ids = ids.copy()
        self.next_id = int(ids.max()) + 1

    def commit(self, z: np.ndarray) -> bool:
        x = np.vstack([self.w, self.a @ z])
        d, _ = cKDTree(x).query(x, k=2)
        nn = d[:, 1]
        all_ids = np.append(self.ids, self.next_id)
        cand = np.flatnonzero(nn == nn.min())
        victim = cand[np.argmax(all_ids[cand])]
        if victim == len(self.w):
            return False
        self.w[victim] = x[-1]
        self.ids[victim] = self.next_id
        self.next_id += 1
        return True


def _clock() -> tuple[float, float]:
    return time.process_time(), time.perf_counter()


def bench_commits(rep: Repertoire, z: np.ndarray, batch: int) -> tuple[float, float, int]:
    """(CPU s, wall s, accepted) for committing z in batches of ``batch`` (1: single commits)."""
    acc = 0
    c0, w0 = _clock()
    if batch == 1:
        for x in z:
            acc += rep.commit(x)
    else:
        for i in range(0, len(z), batch):
            acc += rep.commit_many(z[i : i + batch])
    c1, w1 = _clock()
    return c1 - c0, w1 - w0, acc


def best_time(fn, repeats: int) -> float:  # type: ignore[no-untyped-def]
    """Smallest CPU time of ``repeats`` calls of fn()."""
    best = float("inf")
    for _ in range(repeats):
        c0 = time.process_time()
        fn()
        best = min(best, time.process_time() - c0)
    return best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="fewer commits (< 60 s)")
    ap.add_argument("--size", type=int, default=5000)
    ap.add_argument("--dim", type=int, default=3)
    args = ap.parse_args()
    n_head = 40_000  # the headline workload is the same in both modes
    n_long = 0 if args.quick else 400_000
    n_tree = 50 if args.quick else 200
    size, dim = args.size, args.dim
    rng = np.random.default_rng(0)

    # JIT warm-up (compiled once, then cached on disk).
    for warm_size in (64, 2048):  # brute-force and KD-tree refresh paths
        warm = Repertoire(RepertoireConfig(size=warm_size, dim=dim))
        warm.commit_many(rng.normal(size=(warm_size + 200, dim)))
        warm.commit(rng.normal(size=dim))

    cfg = RepertoireConfig(size=size, dim=dim)  # default Σ schedule: refresh every N_R commits
    rows: list[tuple[str, str, str, str]] = []

    def commit_row(label: str, rep: Repertoire, z: np.ndarray, batch: int) -> float:
        cpu, wall, acc = bench_commits(rep, z, batch)
        rate = len(z) / cpu
        rows.append(
            (label, f"{rate:,.0f}/s", f"{len(z) / wall:,.0f}/s", f"{acc / len(z):.1%} kept")
        )
        return rate

    rep = Repertoire(cfg)
    c0, w0 = _clock()
    rep.commit_many(rng.normal(size=(size, dim)))
    c1, w1 = _clock()
    rows.append(("fill (N_R commits + first Σ/NN)", f"{(c1 - c0) * 1e3:.1f} ms", "", ""))

    # Headline: an N(0, I) stream into the archive just filled from N(0, I).
    rate = commit_row(
        f"incremental, batches of 1000, {n_head:,} N(0,I)",
        rep,
        rng.normal(size=(n_head, dim)),
        1000,
    )
    # A wider source: most commits accepted (the expensive path).
    commit_row(
        "incremental, batches of 1000, 10,000 3·N(0,I)",
        rep,
        rng.normal(size=(10_000, dim)) * 3.0,
        1000,
    )
    single = commit_row(
        "incremental, one commit() each, 5,000 N(0,I)", rep, rng.normal(size=(5000, dim)), 1
    )
    if n_long:
        commit_row(
            f"incremental, batches of 1000, {n_long:,} more N(0,I)",
            rep,
            rng.normal(size=(n_long, dim)),
            1000,
        )
    c0, w0 = _clock()
    for _ in range(5):
        rep.refresh()
    c1, w1 = _clock()
    rows.append(("Σ refresh (re-whiten + all NN)", f"{(c1 - c0) / 5 * 1e3:.2f} ms", "", ""))

    # Reference: rebuild a cKDTree at every commit, on the archive as it is now.
    ref = KDTreeRepertoire(rep.skills, rep.ids, rep.cov)
    zt = rng.normal(size=(n_tree, dim))
    c0, w0 = _clock()
    acc_t = sum(ref.commit(x) for x in zt)
    c1, w1 = _clock()
    tree_rate = n_tree / (c1 - c0)
    rows.append(
        (
            f"cKDTree rebuilt per commit ({n_tree} commits)",
            f"{tree_rate:,.0f}/s",
            f"{n_tree / (w1 - w0):,.0f}/s",
            f"{acc_t / n_tree:.1%} kept",
        )
    )

    # Sampling 1024 skills from the KDE of the archive.
    skills = rep.skills
    ours = best_time(lambda: rep.sample(1024, rng), 50)
    gk = gaussian_kde(skills.T)
    theirs = best_time(lambda: gk.resample(1024, seed=rng), 50)
    build = best_time(lambda: gaussian_kde(skills.T), 20)
    rows.append(("sample 1024: Repertoire.sample", f"{ours * 1e6:.0f} µs", "", ""))
    rows.append(("sample 1024: gaussian_kde.resample", f"{theirs * 1e6:.0f} µs", "", ""))
    rows.append(("  (+ gaussian_kde construction)", f"{build * 1e6:.0f} µs", "", ""))

    speedup = rate / tree_rate
    print(f"Repertoire benchmark: N_R={size}, D={dim}, refresh every {cfg.refresh_period} commits")
    print(f"{'what':<48} {'CPU rate/time':>14} {'wall rate':>12} {'':>12}")
    for r in rows:
        print(f"{r[0]:<48} {r[1]:>14} {r[2]:>12} {r[3]:>12}")
    print(f"commit speedup vs cKDTree rebuild: {speedup:,.0f}x (target ≥ 100x)")
    print(f"  one commit() per call vs cKDTree rebuild: {single / tree_rate:,.0f}x")
    print(f"sampling speedup vs gaussian_kde.resample: {theirs / ours:,.1f}x")
    print(f"target ≥ 50,000 commits/s: {'met' if rate >= 50_000 else 'NOT met'}")
    print(f"RESULT commits_per_s={rate:.0f} speedup={speedup:.0f}")


if __name__ == "__main__":
    main()
