"""Numba kernels of the diversity repertoire (ursa.repertoire): whitening, nearest neighbours,
the removal-candidate segment tree and the commit into a full archive.

Whitened points are stored transposed, wt (D, N_R), so the distance pass vectorizes over skills.
Every d² is ((0 + t_0²) + t_1²) + … and every whitened coordinate a_k0·x_0 + a_k1·x_1 + …, so a
distance has the same bits whichever kernel computes it (removal ties rely on it). No kernel may
use reassociation or contraction (FMA) for that reason.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def whiten_row(x: np.ndarray, a: np.ndarray, out: np.ndarray) -> None:
    """out (D,) = A x for one skill x (D,)."""
    d = x.shape[0]
    for k in range(d):
        acc = a[k, 0] * x[0]
        for j in range(1, d):
            acc += a[k, j] * x[j]
        out[k] = acc


@njit(cache=True)
def whiten_t(x: np.ndarray, a: np.ndarray, wt: np.ndarray) -> None:
    """wt[:, i] = A x_i for the rows of x (n, D)."""
    buf = np.empty(x.shape[1])
    for i in range(x.shape[0]):
        whiten_row(x[i], a, buf)
        wt[:, i] = buf


@njit(cache=True)
def _sqd(wt: np.ndarray, i: int, j: int) -> float:
    acc = 0.0
    for k in range(wt.shape[0]):
        t = wt[k, i] - wt[k, j]
        acc += t * t
    return acc


@njit(cache=True)
def _rescan_fast(wt: np.ndarray, n: int, i: int, buf: np.ndarray) -> tuple[float, int]:
    """Same result as _rescan (nearest other skill, lowest index among ties), vectorized."""
    _dist_pass(wt, wt[:, i].copy(), n, buf, -1.0)
    buf[i] = np.inf
    best = _min8(buf, n)
    if best == np.inf:
        return best, -1
    j = 0
    while buf[j] != best:
        j += 1
    return best, j


@njit(cache=True)
def _dist_pass(wt: np.ndarray, wz: np.ndarray, n: int, dz: np.ndarray, m: float) -> bool:
    """dz[:n] = d² from the whitened new skill wz (D,) to every stored one; True if any ≤ m.

    D = 2 and 3 get one fused loop (t0² + t1² + t2² has the bits of the sequential sum, since
    0 + t0² = t0² exactly); other D sum dimension by dimension. A count, not a min, decides so
    that the loop vectorizes without fast-math flags.
    """
    d = wt.shape[0]
    hits = 0
    if d == 3:
        a0, a1, a2 = wt[0], wt[1], wt[2]
        w0, w1, w2 = wz[0], wz[1], wz[2]
        for i in range(n):
            t0 = a0[i] - w0
            t1 = a1[i] - w1
            t2 = a2[i] - w2
            v = t0 * t0 + t1 * t1 + t2 * t2
            dz[i] = v
            hits += v <= m
    elif d == 2:
        a0, a1 = wt[0], wt[1]
        w0, w1 = wz[0], wz[1]
        for i in range(n):
            t0 = a0[i] - w0
            t1 = a1[i] - w1
            v = t0 * t0 + t1 * t1
            dz[i] = v
            hits += v <= m
    else:
        row = wt[0]
        w0 = wz[0]
        for i in range(n):
            t = row[i] - w0
            dz[i] = t * t
        for k in range(1, d):
            row = wt[k]
            wk = wz[k]
            for i in range(n):
                t = row[i] - wk
                dz[i] += t * t
        for i in range(n):
            hits += dz[i] <= m
    return hits > 0


@njit(cache=True)
def _min8(x: np.ndarray, n: int) -> float:
    """min(x[:n]) with eight independent accumulators (min is exact in any order)."""
    m0 = m1 = m2 = m3 = m4 = m5 = m6 = m7 = np.inf
    i = 0
    while i + 8 <= n:
        m0 = min(m0, x[i])
        m1 = min(m1, x[i + 1])
        m2 = min(m2, x[i + 2])
        m3 = min(m3, x[i + 3])
        m4 = min(m4, x[i + 4])
        m5 = min(m5, x[i + 5])
        m6 = min(m6, x[i + 6])
        m7 = min(m7, x[i + 7])
        i += 8
    while i < n:
        m0 = min(m0, x[i])
        i += 1
    return min(min(min(m0, m1), min(m2, m3)), min(min(m4, m5), min(m6, m7)))


@njit(cache=True)
def all_nn_brute(wt: np.ndarray, n: int, nn: np.ndarray, nn_idx: np.ndarray) -> None:
    """nn[:n], nn_idx[:n] = d² to and index of each skill's nearest other skill, O(n²·D)."""
    for i in range(n):
        nn[i] = np.inf
        nn_idx[i] = -1
    for i in range(n):
        for j in range(i + 1, n):
            dij = _sqd(wt, i, j)
            if dij < nn[i]:
                nn[i] = dij
                nn_idx[i] = j
            if dij < nn[j]:
                nn[j] = dij
                nn_idx[j] = i


@njit(cache=True)
def nn_from_candidates(
    wt: np.ndarray, cand: np.ndarray, nn: np.ndarray, nn_idx: np.ndarray
) -> None:
    # cand (n, k): candidate neighbours per skill from a KD-tree; distances recomputed here so
    # they carry the same bits as the incremental kernel's.
    n = cand.shape[0]
    for i in range(n):
        best = np.inf
        arg = -1
        for c in range(cand.shape[1]):
            j = cand[i, c]
            if j != i and j < n:
                dj = _sqd(wt, i, j)
                if dj < best or (dj == best and j < arg):
                    best = dj
                    arg = j
        nn[i] = best
        nn_idx[i] = arg


# Segment tree over the skills: tree[1] is the removal candidate, the skill with the smallest NN
# distance, the newest (largest id) among ties. Leaves start at tree.shape[0] // 2; −1 = empty.


@njit(cache=True)
def _better(a: int, b: int, nn: np.ndarray, ids: np.ndarray) -> int:
    if a < 0:
        return b
    if b < 0:
        return a
    if nn[a] < nn[b]:
        return a
    if nn[b] < nn[a]:
        return b
    return a if ids[a] > ids[b] else b


@njit(cache=True)
def tree_build(tree: np.ndarray, n: int, nn: np.ndarray, ids: np.ndarray) -> None:
    """Fill the segment tree over the first n skills."""
    half = tree.shape[0] // 2
    for i in range(half):
        tree[half + i] = i if i < n else -1
    for node in range(half - 1, 0, -1):
        tree[node] = _better(tree[2 * node], tree[2 * node + 1], nn, ids)


@njit(cache=True)
def _tree_update(tree: np.ndarray, i: int, nn: np.ndarray, ids: np.ndarray) -> None:
    node = (tree.shape[0] // 2 + i) // 2
    while node >= 1:
        tree[node] = _better(tree[2 * node], tree[2 * node + 1], nn, ids)
        node //= 2


@njit(cache=True)
def commit_full(
    p: np.ndarray,
    wt: np.ndarray,
    nn: np.ndarray,
    nn_idx: np.ndarray,
    ids: np.ndarray,
    ages: np.ndarray,
    inputs: np.ndarray,
    tree: np.ndarray,
    z: np.ndarray,
    zin: np.ndarray,
    a: np.ndarray,
    next_id: int,
    commit0: int,
    dz: np.ndarray,
    wz: np.ndarray,
    changed: np.ndarray,
    buf: np.ndarray,
) -> int:
    """Commit the rows of z (M, D) one by one into the full archive; returns how many stayed.

    In R ∪ {z}, the smallest NN distance is min(min_i nn_i, min_i d(z, z_i)). If the new skill's
    NN distance reaches it, the new skill is (or ties for, and is newest) the least diverse and
    is rejected; otherwise the candidate is the archive's own least diverse skill, tree[1].
    """
    n = p.shape[0]
    accepted = 0
    for r in range(z.shape[0]):
        whiten_row(z[r], a, wz)
        s = tree[1]
        if _dist_pass(wt, wz, n, dz, nn[s]):
            continue
        p[s, :] = z[r]
        wt[:, s] = wz
        ids[s] = next_id + accepted
        ages[s] = commit0 + r
        inputs[s, :] = zin[r]
        # The new skill's neighbour: nearest among the others (the victim's slot excluded).
        dz[s] = np.inf
        nz = _min8(dz, n)
        nz_arg = -1
        if nz < np.inf:
            nz_arg = 0
            while dz[nz_arg] != nz:
                nz_arg += 1
        # Skills that lost their neighbour, or whose nearest is now the new skill (rare).
        nch = 0
        for i in range(n):
            if nn_idx[i] == s or dz[i] < nn[i]:
                changed[nch] = i
                nch += 1
        for q in range(nch):
            i = changed[q]
            if nn_idx[i] == s:
                nn[i], nn_idx[i] = _rescan_fast(wt, n, i, buf)
            else:
                nn[i] = dz[i]
                nn_idx[i] = s
        nn[s] = nz
        nn_idx[s] = nz_arg
        _tree_update(tree, s, nn, ids)
        for q in range(nch):
            _tree_update(tree, changed[q], nn, ids)
        accepted += 1
    return accepted


__all__ = [
    "all_nn_brute",
    "commit_full",
    "nn_from_candidates",
    "tree_build",
    "whiten_row",
    "whiten_t",
]
