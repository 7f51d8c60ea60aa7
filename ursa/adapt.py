"""Damage adaptation over a repertoire: Intelligent Trial and Error (Cully et al., Nature 2015).

The repertoire's skills, each with its return on the intact robot, form ITE's *map*. On the
damaged robot, a Gaussian process models the return of every skill as the map's return (the
prior mean) plus a residual: a Matérn 5/2 kernel with a fixed length scale over skill space,
fitted on the trials so far. The next skill to try is the one of highest upper confidence bound
μ + κσ among those not tried yet; adaptation stops once the best return observed reaches α times
the best mean the model still predicts (ITE's stopping rule), when every skill has been tried,
or when the trial budget is spent. The skill kept is the best one tried.

Units. The GP works in whitened skill coordinates (the skills of the map whitened by their own
covariance, so the length scale is in standard deviations of the repertoire) and on returns
divided by the map's range (max − min of the intact returns), so κ, the kernel variance and the
noise are in units of that range, as ITE's parameters are in units of its performance (m/s).
The stopping rule measures returns from ``floor`` (ITE's performance is non-negative; 0 here).

Everything is pure and explicit: the map (:class:`SkillMap`), the parameters
(:class:`ITEParams`) and the observations (:class:`Observations`, frozen; ``add`` returns a new
one) go in, a :class:`Decision` comes out. :func:`ite` and :func:`random_search` drive a trial
function over a budget; ITE uses no randomness (ties go to the lowest row), random search draws
its order from its seed. Also here: the intact-return cache of a run directory (``.npz`` under
``<run>/eval/adapt/``, written atomically).
"""

from __future__ import annotations

import hashlib
import io
import json
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ursa import kde
from ursa.rundir import RunDir, atomic_write

THRESHOLD = "threshold"
"""Stop reason: best observed ≥ α × best predicted (ITE's rule)."""
BUDGET = "budget"
"""Stop reason: the trial budget is spent."""
EXHAUSTED = "exhausted"
"""Stop reason: every skill of the map has been tried."""
STOP_REASONS = (THRESHOLD, BUDGET, EXHAUSTED)


@dataclass(frozen=True)
class ITEParams:
    """Parameters of Intelligent Trial and Error (defaults: the ITE paper's, in map units)."""

    alpha: float = 0.9
    """Stop once the best return observed ≥ α × the best predicted mean (both from ``floor``)."""
    kappa: float = 0.05
    """UCB exploration weight: the next skill maximises μ + κσ."""
    budget: int = 20
    """Most trials on the damaged robot."""
    length_scale: float = 1.0
    """Matérn 5/2 length scale ρ, in standard deviations of the map's skills (whitened)."""
    variance: float = 1.0
    """Kernel variance of the residual, in (map return range)²."""
    noise: float = 1e-3
    """Observation noise variance, in (map return range)² (ITE: 0.001)."""
    floor: float = 0.0
    """Return from which the stopping rule measures (ITE's performance is ≥ 0)."""

    def __post_init__(self) -> None:
        checks = {
            "alpha": self.alpha > 0.0,
            "kappa": self.kappa >= 0.0,
            "budget": self.budget >= 1,
            "length_scale": self.length_scale > 0.0,
            "variance": self.variance > 0.0,
            "noise": self.noise > 0.0,
        }
        for name, ok in checks.items():
            v = getattr(self, name)
            if not ok or not math.isfinite(float(v)):
                raise ValueError(f"ITEParams.{name}={v!r} out of range")
        if not math.isfinite(self.floor):
            raise ValueError("ITEParams.floor must be finite")


@dataclass(frozen=True)
class SkillMap:
    """ITE's map: N skills (N, D), their intact returns (N,) and ids (N,)."""

    skills: np.ndarray
    """Skill coordinates (N, D)."""
    prior: np.ndarray
    """Return of each skill on the intact robot (N,): the GP's prior mean."""
    ids: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    """Repertoire ids (N,) (default 0..N-1)."""

    def __post_init__(self) -> None:
        skills = np.array(self.skills, np.float64, ndmin=2)
        prior = np.array(self.prior, np.float64).reshape(-1)
        ids = np.array(self.ids, np.int64).reshape(-1)
        if len(ids) == 0:
            ids = np.arange(len(skills), dtype=np.int64)
        if skills.ndim != 2 or len(skills) == 0:
            raise ValueError(f"skills must be (N, D) with N ≥ 1, got {skills.shape}")
        if prior.shape != (len(skills),) or ids.shape != (len(skills),):
            raise ValueError(
                f"prior {prior.shape} and ids {ids.shape} must be ({len(skills)},) like the skills"
            )
        if not (np.all(np.isfinite(skills)) and np.all(np.isfinite(prior))):
            raise ValueError("skills and prior returns must be finite")
        for name, a in (("skills", skills), ("prior", prior), ("ids", ids)):
            a.setflags(write=False)
            object.__setattr__(self, name, a)
        cov = np.atleast_2d(np.cov(skills.T)) if len(skills) > 1 else np.eye(skills.shape[1])
        w = kde.whitening_matrix(kde.regularize_cov(cov))
        white = skills @ w.T
        white.setflags(write=False)
        object.__setattr__(self, "_white", white)

    def __len__(self) -> int:
        return len(self.skills)

    @property
    def dim(self) -> int:
        return int(self.skills.shape[1])

    @property
    def whitened(self) -> np.ndarray:
        """Skills whitened by their own covariance (N, D): the GP's input space."""
        out: np.ndarray = self._white  # type: ignore[attr-defined]
        return out

    @property
    def scale(self) -> float:
        """The map's return range (max − min; 1 when the returns are all equal)."""
        r = float(self.prior.max() - self.prior.min())
        return r if r > 1e-12 else 1.0


@dataclass(frozen=True)
class Observations:
    """Trials so far: rows of the map tried, in order, and the returns they gave."""

    indices: tuple[int, ...] = ()
    returns: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        if len(self.indices) != len(self.returns):
            raise ValueError("indices and returns must have the same length")

    def add(self, index: int, ret: float) -> Observations:
        """These observations plus one trial (a new object)."""
        if not math.isfinite(float(ret)):
            raise ValueError(f"a trial's return must be finite, got {ret!r}")
        return Observations((*self.indices, int(index)), (*self.returns, float(ret)))

    def __len__(self) -> int:
        return len(self.indices)

    @property
    def best(self) -> int | None:
        """Position (into ``indices``) of the best trial (first among ties), None if none."""
        if not self.returns:
            return None
        return int(np.argmax(np.asarray(self.returns)))

    @property
    def best_return(self) -> float:
        """Best return observed (−inf with no trial)."""
        return max(self.returns) if self.returns else -math.inf

    def to_plain(self) -> dict[str, list[Any]]:
        return {"indices": list(self.indices), "returns": list(self.returns)}

    @classmethod
    def from_plain(cls, d: dict[str, Any]) -> Observations:
        return cls(tuple(int(i) for i in d["indices"]), tuple(float(r) for r in d["returns"]))


@dataclass(frozen=True)
class Posterior:
    """The GP's prediction for every skill of the map."""

    mean: np.ndarray
    """Predicted return on the damaged robot (N,)."""
    std: np.ndarray
    """Its standard deviation (N,) (the latent function's, noise excluded)."""

    @property
    def best(self) -> int:
        """Row of the highest predicted mean (lowest row among ties)."""
        return int(np.argmax(self.mean))


@dataclass(frozen=True)
class Decision:
    """What to do after the observations so far."""

    index: int | None
    """Row of the map to try next (None: stop)."""
    reason: str | None
    """Why to stop (one of ``STOP_REASONS``), None while adapting."""
    posterior: Posterior
    """The model the decision was made on."""
    ucb: float
    """μ + κσ of the chosen row (nan when stopping)."""


def kernel(params: ITEParams) -> Any:
    """The GP's kernel: variance × Matérn 5/2 with length scale ρ, both fixed (not fitted)."""
    # imported on first use: scikit-learn takes about 2 s to import, which every ``ursa eval``
    # command would otherwise pay
    from sklearn.gaussian_process.kernels import ConstantKernel, Matern

    return ConstantKernel(params.variance, "fixed") * Matern(params.length_scale, "fixed", nu=2.5)


def posterior(m: SkillMap, obs: Observations, params: ITEParams) -> Posterior:
    """GP posterior over the map's skills given the trials (shapes (N,)).

    μ(x) = P(x) + s · k(x, X) [K + σ_n² I]⁻¹ (y − P(X)) / s and
    σ²(x) = s² (k(x, x) − k(x, X) [K + σ_n² I]⁻¹ k(X, x)), with P the map's intact returns,
    s its return range, X the whitened skills tried and y their returns. With no trial the
    posterior is the prior: μ = P, σ = s √variance.
    """
    s = m.scale
    if len(obs) == 0:
        return Posterior(m.prior.copy(), np.full(len(m), s * math.sqrt(params.variance)))
    idx = np.asarray(obs.indices, np.int64)
    if idx.min() < 0 or idx.max() >= len(m):
        raise ValueError(f"observed rows must be in 0..{len(m) - 1}")
    from sklearn.gaussian_process import GaussianProcessRegressor

    resid = (np.asarray(obs.returns, np.float64) - m.prior[idx]) / s
    gp = GaussianProcessRegressor(
        kernel(params), alpha=params.noise, optimizer=None, normalize_y=False
    )
    gp.fit(m.whitened[idx], resid)
    mu, sd = gp.predict(m.whitened, return_std=True)
    return Posterior(m.prior + s * np.asarray(mu, np.float64), s * np.asarray(sd, np.float64))


def stop_reason(
    m: SkillMap, obs: Observations, params: ITEParams, post: Posterior | None = None
) -> str | None:
    """Why adaptation stops now, or None to go on.

    ``threshold``: best observed − floor ≥ α (max μ − floor), or the best observed is at least
    the best predicted (nothing better is expected; this also covers returns below ``floor``);
    ``budget``: ``params.budget`` trials done; ``exhausted``: every skill tried. The threshold is
    checked first, then the budget.
    """
    if len(obs):
        post = posterior(m, obs, params) if post is None else post
        best, top = obs.best_return, float(post.mean.max())
        f = params.floor
        if best - f >= params.alpha * (top - f) or best >= top:
            return THRESHOLD
    if len(obs) >= params.budget:
        return BUDGET
    if len(set(obs.indices)) >= len(m):
        return EXHAUSTED
    return None


def decide(m: SkillMap, obs: Observations, params: ITEParams) -> Decision:
    """The next skill to try (UCB over the skills not tried yet), or why to stop."""
    post = posterior(m, obs, params)
    reason = stop_reason(m, obs, params, post)
    if reason is not None:
        return Decision(None, reason, post, math.nan)
    score = post.mean + params.kappa * post.std
    score[np.asarray(obs.indices, np.int64)] = -np.inf
    i = int(np.argmax(score))
    return Decision(i, None, post, float(score[i]))


@dataclass(frozen=True)
class Trial:
    """One trial on the damaged robot."""

    index: int
    """Row of the map."""
    skill_id: int
    ret: float
    """Return on the damaged robot."""
    predicted: float
    """Mean the model predicted for it before the trial (nan for random search)."""
    predicted_best: int
    """Row of the highest predicted mean after the trial (−1 for random search)."""
    predicted_best_mean: float
    """That mean (nan for random search)."""


@dataclass(frozen=True)
class AdaptResult:
    """A whole adaptation."""

    method: str
    """``ite`` or ``random``."""
    trials: tuple[Trial, ...]
    reason: str
    """Why it stopped (``STOP_REASONS``)."""

    @property
    def returns(self) -> np.ndarray:
        """Return of each trial (n,)."""
        return np.asarray([t.ret for t in self.trials], np.float64)

    @property
    def chosen(self) -> Trial:
        """The best trial (the skill the robot keeps; first among ties)."""
        return self.trials[int(np.argmax(self.returns))]


TrialFn = Callable[[int], float]
"""Runs the skill of a map row on the damaged robot; returns its return."""


def ite(m: SkillMap, trial: TrialFn, params: ITEParams) -> AdaptResult:
    """Intelligent Trial and Error: ``decide``, run the trial, add it, until a stop reason."""
    obs = Observations()
    trials: list[Trial] = []
    while True:
        d = decide(m, obs, params)
        if d.index is None:
            assert d.reason is not None
            return AdaptResult("ite", tuple(trials), d.reason)
        ret = float(trial(d.index))
        obs = obs.add(d.index, ret)
        after = posterior(m, obs, params)
        trials.append(
            Trial(
                d.index,
                int(m.ids[d.index]),
                ret,
                float(d.posterior.mean[d.index]),
                after.best,
                float(after.mean[after.best]),
            )
        )


def random_order(n: int, budget: int, seed: int) -> np.ndarray:
    """The rows (min(budget, n),) random search tries: a permutation drawn from ``seed``."""
    return np.random.default_rng(seed).permutation(n)[: min(int(budget), n)]


def random_search(m: SkillMap, trial: TrialFn, budget: int, seed: int) -> AdaptResult:
    """The baseline: ``budget`` distinct skills of the map in a random order (no model, no early
    stop); keeps the best."""
    rows = random_order(len(m), budget, seed)
    trials = tuple(
        Trial(int(i), int(m.ids[i]), float(trial(int(i))), math.nan, -1, math.nan) for i in rows
    )
    return AdaptResult("random", trials, BUDGET if len(rows) == budget else EXHAUSTED)


def best_so_far(returns: np.ndarray, length: int) -> np.ndarray:
    """Best return up to each trial (length,): a result that stopped early keeps its best
    (the robot keeps the chosen skill); nan before any trial."""
    r = np.asarray(returns, np.float64)
    out = np.full(length, np.nan)
    if len(r):
        acc = np.maximum.accumulate(r[:length])
        out[: len(acc)] = acc
        out[len(acc) :] = acc[-1]
    return out


def trials_to_reach(returns: np.ndarray, target: float) -> int | None:
    """1-based number of the first trial whose return ≥ ``target`` (None: never)."""
    hit = np.flatnonzero(np.asarray(returns, np.float64) >= target)
    return int(hit[0]) + 1 if len(hit) else None


# ---- the intact-return cache of a run directory ---------------------------------------------
def adapt_dir(run_dir: str | Path) -> Path:
    """``<run>/eval/adapt``: intact maps and adaptation jobs of a run."""
    return RunDir(run_dir).eval / "adapt"


def map_key(**fields: Any) -> str:
    """Short hash naming a map: of everything its returns depend on (policy, skills, T, seed)."""
    h = hashlib.sha256()
    for k in sorted(fields):
        v = fields[k]
        if isinstance(v, np.ndarray):
            h.update(f"{k}:{v.dtype}:{v.shape}:".encode() + np.ascontiguousarray(v).tobytes())
        else:
            h.update(f"{k}={json.dumps(v, sort_keys=True, default=str)};".encode())
    return h.hexdigest()[:16]


def map_path(run_dir: str | Path, key: str) -> Path:
    return adapt_dir(run_dir) / f"intact-{key}.npz"


def save_map(path: str | Path, m: SkillMap, meta: dict[str, Any]) -> Path:
    """Write a map and its metadata (JSON) atomically."""
    buf = io.BytesIO()
    np.savez(buf, skills=m.skills, prior=m.prior, ids=m.ids, meta=np.asarray(json.dumps(meta)))
    return atomic_write(path, buf.getvalue())


def load_map(path: str | Path) -> tuple[SkillMap, dict[str, Any]] | None:
    """A map saved by :func:`save_map`, None when absent or unreadable."""
    try:
        with np.load(Path(path), allow_pickle=False) as z:
            m = SkillMap(z["skills"], z["prior"], z["ids"])
            meta = json.loads(str(z["meta"]))
    except (OSError, KeyError, ValueError):
        return None
    return m, meta


__all__ = [
    "BUDGET",
    "EXHAUSTED",
    "THRESHOLD",
    "AdaptResult",
    "Decision",
    "ITEParams",
    "Observations",
    "Posterior",
    "SkillMap",
    "Trial",
    "best_so_far",
    "decide",
    "ite",
    "load_map",
    "map_key",
    "posterior",
    "random_search",
    "save_map",
    "stop_reason",
    "trials_to_reach",
]
