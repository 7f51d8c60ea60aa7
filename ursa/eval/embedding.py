"""``ursa eval embedding``: 2-D embedding of state trajectories coloured by skill (paper Figure 1).

K distinct skills (farthest-point sampling in the metric of δ) are executed for T steps each;
every observation of every trajectory becomes a point, standardized per observation dimension,
embedded in 2-D by UMAP (``umap-learn``, as in the paper) when it is installed, else by PCA
(numpy SVD), and coloured by the skill it was executed under. Distinct skills that produce
distinct behaviours show up as separate clusters or trajectories; a single-skill policy
(``daydreamer``) as one.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ursa import scoring
from ursa.eval.common import distinct_skills, pyplot, save_figure, write_csv, write_json
from ursa.eval.loading import LoadedRun
from ursa.eval.rollout import Rollouts, execute_skills


@dataclass
class Embedding:
    points: np.ndarray
    """(M, 2) embedded observations."""
    method: str
    """``umap`` or ``pca``."""
    explained: list[float]
    """PCA: fraction of the variance of each of the two components (empty for UMAP)."""


def pca_2d(x: np.ndarray) -> Embedding:
    """Project rows of ``x`` (M, F) on their two principal components (centred; SVD)."""
    xc = np.asarray(x, np.float64) - np.mean(x, axis=0)
    _, s, vt = np.linalg.svd(xc, full_matrices=False)
    comps = vt[:2]
    proj = xc @ comps.T
    if proj.shape[1] < 2:
        proj = np.pad(proj, ((0, 0), (0, 2 - proj.shape[1])))
    var = s**2
    total = float(var.sum()) or 1.0
    explained = [float(v / total) for v in var[:2]]
    # a deterministic sign: the largest-magnitude loading of each component positive
    for k in range(min(2, comps.shape[0])):
        if comps[k][np.argmax(np.abs(comps[k]))] < 0:
            proj[:, k] = -proj[:, k]
    return Embedding(proj, "pca", explained)


def embed_2d(x: np.ndarray, method: str = "auto", seed: int = 0) -> Embedding:
    """2-D embedding of rows of ``x`` (M, F), each column standardized first. ``auto``: UMAP if
    ``umap`` imports, else PCA."""
    x = np.asarray(x, np.float64)
    std = x.std(0)
    z = (x - x.mean(0)) / np.where(std > 1e-12, std, 1.0)
    if method in ("auto", "umap"):
        try:
            import umap  # type: ignore[import-not-found]
        except ImportError:
            if method == "umap":
                raise
        else:
            reducer = umap.UMAP(n_components=2, random_state=seed)
            return Embedding(np.asarray(reducer.fit_transform(z)), "umap", [])
    return pca_2d(z)


def run_embedding(
    run: LoadedRun,
    n_skills: int = 10,
    steps: int | None = None,
    method: str = "auto",
    seed: int = 0,
    explore: bool = scoring.EXPLORE,
    progress: bool = True,
) -> tuple[Rollouts, Embedding, np.ndarray]:
    """Execute ``n_skills`` distinct skills (repetitions of the policy without skills) and
    embed their observations; returns the rollouts, the embedding and the skill ids."""
    cfg = run.config
    policy = run.require_policy()
    if run.uses_skills:
        skills, ids = distinct_skills(run, n_skills)
    else:
        skills, ids = np.zeros((max(n_skills, 1), 0)), np.arange(max(n_skills, 1))
    t = cfg.collector.skill_period if steps is None else steps
    env = run.env(seed=seed)
    try:
        r = execute_skills(
            policy,
            env,
            skills,
            t,
            keep_obs=True,
            explore=explore,
            seed=seed,
            progress=progress,
            desc="embedding",
        )
    finally:
        env.close()
    assert r.obs is not None
    emb = embed_2d(r.obs.reshape(-1, r.obs.shape[-1]), method, seed)
    return r, emb, ids


def write_embedding(
    run: LoadedRun, r: Rollouts, emb: Embedding, ids: np.ndarray, out: Path
) -> dict[str, Any]:
    """embedding.json, embedding.csv and embedding.png; returns the JSON summary."""
    assert r.obs is not None
    k, t = r.obs.shape[:2]
    pts = emb.points.reshape(k, t, 2)
    centroids = pts.mean(1)
    spread = float(np.mean(np.linalg.norm(pts - centroids[:, None], axis=-1)))
    between = (
        float(
            np.mean(
                np.linalg.norm(centroids[:, None] - centroids[None], axis=-1)[
                    ~np.eye(k, dtype=bool)
                ]
            )
        )
        if k > 1
        else 0.0
    )
    summary: dict[str, Any] = {
        "figure": "Figure 1: 2-D embedding of state trajectories, coloured by skill",
        "run": run.name,
        "mode": run.mode,
        "method": emb.method,
        "explained_variance": emb.explained,
        "skills": k,
        "steps": t,
        "skill_ids": ids,
        "within_skill_spread": spread,
        "between_skill_distance": between,
        "return_mean": float(np.mean(r.returns)),
        "nonfinite_actions": r.nonfinite_actions,
    }
    write_json(out / "embedding.json", summary)
    rows = []
    for i in range(k):
        for s in range(t):
            rows.append([i, int(ids[i]), s, pts[i, s, 0], pts[i, s, 1]])
    write_csv(out / "embedding.csv", ["index", "skill_id", "step", "x", "y"], rows)

    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6, 5))
    cmap = plt.get_cmap("tab10" if k <= 10 else "turbo")
    for i in range(k):
        color = cmap(i % 10) if k <= 10 else cmap(i / max(k - 1, 1))
        ax.plot(pts[i, :, 0], pts[i, :, 1], "-", lw=0.5, color=color, alpha=0.5)
        ax.scatter(
            pts[i, :, 0],
            pts[i, :, 1],
            s=4,
            color=color,
            alpha=0.7,
            label=f"skill {int(ids[i])}" if k <= 10 else None,
        )
    if k <= 10:
        ax.legend(fontsize=7, markerscale=2)
    var = f" ({100 * sum(emb.explained):.0f}% of the variance)" if emb.explained else ""
    ax.set_title(f"{emb.method.upper()} of the observations{var}, {run.mode}", fontsize=10)
    ax.set_xlabel(f"{emb.method} 1")
    ax.set_ylabel(f"{emb.method} 2")
    save_figure(fig, out / "embedding.png")
    return summary
