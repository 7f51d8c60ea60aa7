"""Load what an evaluation needs from a run directory: config, policy, repertoire, metrics.

A run directory (``runs/<run_id>/``, written by the services, or by :func:`save_serial_run`;
layout in :mod:`ursa.rundir`) holds, among others::

    config/<service>.yaml         {"argv": [...], "config": {"core": <Config as a plain dict>, ...}}
    checkpoints/learner.pt        Learner.save_checkpoint (+ learner_state.json)
    repertoire/archive.npz        Repertoire.save
    metrics/<service>-<id>.jsonl  {"t", "service", "id", "scalars": {...}, "labels": {...}} per line

:func:`load_run` accepts the run directory or its checkpoint file. A bare checkpoint outside a
run directory still loads: the learner config is in the checkpoint, the env follows from the
observation size and the feature function from the learner's mode and input size.

:func:`make_serial_loop` builds a :class:`~ursa.serial.SerialLoop` from a :class:`Config` and
:func:`save_serial_run` writes its state in the layout above, so that tests (and quick
experiments) evaluate a single-process run exactly like a run of the services.
"""

from __future__ import annotations

import dataclasses
import json
import os
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
import yaml

from ursa import bounds
from ursa.config import PROVIDED_FEATURES, Config, build_env, with_feature
from ursa.envs.base import ResetFreeEnv
from ursa.learner import Learner
from ursa.learner_config import LearnerConfig
from ursa.plain import from_plain, to_plain
from ursa.policy import Policy
from ursa.repertoire import Repertoire
from ursa.rundir import RunDir, atomic_write, metrics_row
from ursa.serial import SerialConfig, SerialLoop

#: Resolved configs tried in this order (the learner's holds the learner config of the checkpoint).
CONFIG_PREFERENCE = ("learner", "serial", "repertoire", "evaluator", "collector")


# --- run directories -------------------------------------------------------------------------


def resolve_run_dir(path: str | os.PathLike[str]) -> tuple[Path | None, Path | None]:
    """(run dir, checkpoint file) for a run directory or a checkpoint path (either may be None:
    a run without checkpoint, a bare checkpoint)."""
    p = Path(path)
    if p.is_dir():
        ckpt = RunDir(p).checkpoint
        return p, ckpt if ckpt.exists() else None
    if p.is_file():
        for parent in (p.parent, p.parent.parent):
            if RunDir(parent).config.is_dir():
                return parent, p
        return None, p
    raise FileNotFoundError(f"no run directory or checkpoint at {p}")


def config_files(run_dir: Path) -> list[Path]:
    """Resolved config files of a run, the preferred one first."""
    files = sorted(RunDir(run_dir).config.glob("*.yaml"))

    def rank(f: Path) -> tuple[int, str]:
        stem = f.stem
        for i, name in enumerate(CONFIG_PREFERENCE):
            if stem == name or stem.startswith(name + "-"):
                return i, stem
        return len(CONFIG_PREFERENCE), stem

    return sorted(files, key=rank)


def load_config(run_dir: str | os.PathLike[str]) -> Config:
    """The core :class:`Config` of a run: the ``config.core`` of its preferred resolved config
    (the learner's, whose learner config matches the checkpoint)."""
    for f in config_files(Path(run_dir)):
        doc = yaml.safe_load(f.read_text()) or {}
        tree = doc.get("config", doc)
        if isinstance(tree, dict) and isinstance(tree.get("core"), dict):
            cfg: Config = from_plain(Config, tree["core"])
            return cfg
    raise FileNotFoundError(f"no resolved config with a 'core' section in {run_dir}/config")


def config_from_checkpoint(state: dict[str, Any]) -> Config:
    """A :class:`Config` guessed from a bare checkpoint (learner config and dims inside)."""
    lc: LearnerConfig = from_plain(LearnerConfig, state["config"])
    obs_dim, _act, feat_in, skill_dim = (int(x) for x in state["dims"])
    env = "point" if obs_dim == 6 else "a1"
    if lc.mode == "ursa":
        feature = "vae"
    else:
        dims = PROVIDED_FEATURES[env]
        width = skill_dim or feat_in
        feature = next((k for k, d in dims.items() if d == width), next(iter(dims)))
    cfg = with_feature(Config(env=env, learner=lc), feature)  # type: ignore[arg-type]
    return dataclasses.replace(cfg, learner=lc)


def read_checkpoint(path: str | os.PathLike[str], device: str = "cpu") -> dict[str, Any]:
    """The learner state dict of a checkpoint (``weights_only=True``: no pickle)."""
    state: dict[str, Any] = torch.load(path, map_location=device, weights_only=True)
    if state.get("format") != "ursa-learner-1":
        raise ValueError(f"{path} is not an URSA learner checkpoint")
    return state


@dataclass
class LoadedRun:
    """Everything an evaluation needs from one run."""

    config: Config
    """The run's core config."""
    policy: Policy | None
    """The policy with the checkpoint's weights (None: no checkpoint yet)."""
    repertoire: Repertoire | None
    """The archive (None where the run has none, e.g. a daydreamer serial run)."""
    run_dir: Path | None
    """Where the run lives (None for a bare checkpoint)."""
    updates: int = 0
    """Learner updates of the checkpoint."""
    dims: tuple[int, int, int, int] = (0, 0, 0, 0)
    """obs_dim, act_dim, feat_in_dim, skill_dim of the checkpoint."""
    name: str = ""
    """A short label (the run directory's name)."""
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def mode(self) -> str:
        return self.config.learner.mode

    @property
    def uses_skills(self) -> bool:
        return self.config.learner.uses_skills

    def env(self, seed: int = 0, damage: str | None = None, **a1: Any) -> ResetFreeEnv:
        """A fresh env of the run (``damage`` and A1 overrides such as ``rescue=False``)."""
        cfg = self.config
        if a1 and cfg.env == "a1":
            cfg = dataclasses.replace(cfg, a1=dataclasses.replace(cfg.a1, **a1))
        return build_env(cfg, seed=seed, damage=damage)

    def require_policy(self) -> Policy:
        if self.policy is None:
            raise FileNotFoundError(f"run {self.name!r} has no learner checkpoint")
        return self.policy

    def require_repertoire(self) -> Repertoire:
        if self.repertoire is None or len(self.repertoire) == 0:
            raise FileNotFoundError(f"run {self.name!r} has no (or an empty) repertoire archive")
        return self.repertoire


def load_learner(cfg: Config, state: dict[str, Any]) -> Learner:
    """The :class:`Learner` of a checkpoint state, rebuilt on the CPU with the checkpoint's
    dims (obs, act, feature input, skill)."""
    obs_dim, act_dim, feat_in, skill_dim = (int(x) for x in state["dims"])
    learner = Learner(
        dataclasses.replace(cfg.learner, device="cpu"), obs_dim, act_dim, feat_in, skill_dim
    )
    learner.load_state_dict(state)
    return learner


def load_policy(
    cfg: Config, state: dict[str, Any], seed: int = 0
) -> tuple[Policy, tuple[int, int, int, int]]:
    """A :class:`Policy` with the weights of a learner checkpoint state: the learner is rebuilt
    (:func:`load_learner`), then ships its weights as collectors receive them
    (``policy_weights_bytes`` -> ``load_weights_bytes``)."""
    obs_dim, act_dim, feat_in, skill_dim = (int(x) for x in state["dims"])
    lc = dataclasses.replace(cfg.learner, device="cpu")
    learner = load_learner(cfg, state)
    policy = Policy(lc, obs_dim, act_dim, skill_dim, feat_in, seed=seed)
    policy.load_weights_bytes(learner.policy_weights_bytes())
    return policy, (obs_dim, act_dim, feat_in, skill_dim)


def load_run(path: str | os.PathLike[str], seed: int = 0) -> LoadedRun:
    """Load a run directory (or a checkpoint file): config, policy and repertoire."""
    run_dir, ckpt = resolve_run_dir(path)
    state = read_checkpoint(ckpt) if ckpt is not None else None
    if run_dir is not None:
        cfg = load_config(run_dir)
        if state is not None:
            # the checkpoint's learner config is the truth about the weights' sizes
            ck_lc: LearnerConfig = from_plain(LearnerConfig, state["config"])
            cfg = dataclasses.replace(cfg, learner=ck_lc)
    elif state is not None:
        cfg = config_from_checkpoint(state)
    else:  # pragma: no cover - resolve_run_dir raises first
        raise FileNotFoundError(path)
    policy = None
    dims = (0, 0, 0, 0)
    if state is not None:
        policy, dims = load_policy(cfg, state, seed=seed)
    repertoire = None
    extra: dict[str, Any] = {}
    if run_dir is not None and RunDir(run_dir).archive.exists():
        repertoire = Repertoire.load(RunDir(run_dir).archive, bounds.declared(cfg).skills)
        if (
            policy is not None
            and policy.vae is not None
            and repertoire.config.input_dim
            and repertoire.encoder_version != policy.vae_version
            and len(repertoire)
        ):
            # the archive and the checkpoint are saved at different times: put the skills in
            # the space of the policy's encoder, the one its skill input was trained with
            extra["reencoded_from"] = repertoire.encoder_version
            repertoire.reencode(policy.features, policy.vae_version)
    name = run_dir.name if run_dir is not None else Path(path).stem
    return LoadedRun(
        config=cfg,
        policy=policy,
        repertoire=repertoire,
        run_dir=run_dir,
        updates=int(state["updates"]) if state is not None else 0,
        dims=dims,
        name=name,
        extra=extra,
    )


def default_out(path: str | os.PathLike[str], out: str | os.PathLike[str] | None) -> Path:
    """``out``, or ``<run>/eval`` (``<checkpoint dir>/eval`` for a bare checkpoint)."""
    if out is not None:
        return Path(out)
    run_dir, ckpt = resolve_run_dir(path)
    base = run_dir if run_dir is not None else Path(ckpt or path).parent
    return RunDir(base).eval


# --- metrics ---------------------------------------------------------------------------------


def iter_metrics(run_dir: str | os.PathLike[str]) -> Iterator[dict[str, Any]]:
    """Rows of every ``metrics/*.jsonl`` of a run (bad lines skipped: a service killed
    mid-write leaves a partial last line)."""
    for f in sorted(RunDir(run_dir).metrics.glob("*.jsonl")):
        with open(f) as fh:
            for line in fh:
                line = line.strip()
                if not line:
                    continue
                try:
                    row = json.loads(line)
                except json.JSONDecodeError:
                    continue
                if isinstance(row, dict) and isinstance(row.get("scalars"), dict):
                    row.setdefault("service", f.stem.split("-", 1)[0])
                    row.setdefault("id", f.stem.split("-", 1)[-1])
                    yield row


# --- single-process runs in the run-dir layout -----------------------------------------------


def serial_config(
    cfg: Config, prefill: int = 2000, seed: int = 0, **overrides: Any
) -> SerialConfig:
    """The :class:`SerialConfig` that runs ``cfg`` as the services would (same feature input,
    skill period, chunk length, N_R and N_z)."""
    base = SerialConfig(
        feature=cfg.feature_input_key,
        prefill=prefill,
        skill_period=cfg.collector.skill_period,
        chunk_len=cfg.collector.chunk_len,
        random_scale=cfg.collector.random_scale,
        archive_window=cfg.collector.archive_window,
        repertoire_size=cfg.repertoire.size,
        n_z=cfg.repertoire.n_z,
        seed=seed,
    )
    return dataclasses.replace(base, **overrides)


def make_serial_loop(
    cfg: Config, prefill: int = 2000, seed: int = 0, env_seed: int = 0, **overrides: Any
) -> SerialLoop:
    """A :class:`SerialLoop` on ``build_env(cfg)`` with the settings of ``cfg``."""
    return SerialLoop(
        build_env(cfg, seed=env_seed),
        cfg.learner,
        serial_config(cfg, prefill, seed, **overrides),
        skill_box=bounds.declared(cfg).skills,
    )


class _RewardTap:
    """Forwards everything to the env and sums the rewards of its steps."""

    def __init__(self, env: ResetFreeEnv) -> None:
        self.inner = env
        self.reward_sum = 0.0
        self.reward_steps = 0

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        out = self.inner.step(action)
        self.reward_sum += float(out[1])
        self.reward_steps += 1
        return out

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)


class SerialRecorder:
    """``SerialLoop.run`` callback recording the services' metrics (collector, repertoire,
    learner rows) so that ``ursa eval curves`` reads a serial run like a stack run.

    Construction taps the loop's env (a transparent proxy that sums rewards). The collector's
    ``violation_rate`` is over the steps since the previous call (the services use a sliding
    window) and ``return_mean`` is the mean reward since then × T (a skill period's return, as
    the collector reports it); ``rescues`` is the env's counter. ``t`` is wall time, as the
    services stamp it.
    """

    def __init__(self, loop: SerialLoop) -> None:
        self.rows: list[dict[str, Any]] = []
        self._tap = _RewardTap(loop.env)
        loop.env = self._tap  # type: ignore[assignment]
        self._steps = loop.env_steps
        self._unsafe = loop.unsafe_steps
        self._history = len(loop.history)

    def __call__(self, loop: SerialLoop) -> None:
        now = time.time()
        n = max(loop.env_steps - self._steps, 1)
        viol = (loop.unsafe_steps - self._unsafe) / n
        tap = self._tap
        ret = tap.reward_sum / max(tap.reward_steps, 1) * loop.config.skill_period
        tap.reward_sum, tap.reward_steps = 0.0, 0
        rescues = int(getattr(tap.inner, "rescues", 0))
        self.rows.append(
            metrics_row(
                now,
                "collector",
                "serial",
                {
                    "steps": loop.env_steps,
                    "violation_rate": viol,
                    "rescues": rescues,
                    "return_mean": ret,
                    "unsafe_total": loop.unsafe_steps,
                    "policy_version": loop.policy.version,
                },
            )
        )
        rep = loop.repertoire
        if rep is not None and len(rep) > 1:
            self.rows.append(
                metrics_row(
                    now,
                    "repertoire",
                    "serial",
                    {
                        "size": len(rep),
                        "capacity": rep.config.size,
                        "delta": rep.delta(),
                        "entropy_bound": rep.entropy_bound(),
                        "commits": rep.commits,
                        "accepted": rep.accepted,
                        "rejected": rep.rejected,
                    },
                )
            )
        scalars: dict[str, float] = {
            "updates": loop.learner.updates,
            "replay_steps": len(loop.replay),
        }
        for m in loop.history[self._history :][-1:]:
            scalars.update({k: v for k, v in m.items() if np.isfinite(v)})
        self.rows.append(metrics_row(now, "learner", "serial", scalars))
        self._steps, self._unsafe = loop.env_steps, loop.unsafe_steps
        self._history = len(loop.history)


def save_serial_run(
    loop: SerialLoop,
    cfg: Config,
    run_dir: str | os.PathLike[str],
    recorder: SerialRecorder | None = None,
) -> Path:
    """Write a :class:`SerialLoop`'s state as a run directory (config, checkpoint, archive,
    metrics); returns the run directory."""
    run = RunDir(run_dir)
    doc = {"argv": [], "config": {"core": to_plain(cfg), "serial": to_plain(loop.config)}}
    atomic_write(run.config_file("serial"), yaml.safe_dump(doc, sort_keys=False))
    loop.learner.save_checkpoint(run.checkpoint)
    state = {
        "samples": loop.learner.updates * cfg.learner.batch_size * cfg.learner.seq_len,
        "weights_version": loop.policy.version,
        "updates": loop.learner.updates,
        "stamp": time.time(),
    }
    atomic_write(run.learner_state, json.dumps(state))
    if loop.repertoire is not None:
        loop.repertoire.save(run.archive)
    if recorder is not None and recorder.rows:
        by_file: dict[Path, list[dict[str, Any]]] = {}
        for row in recorder.rows:
            by_file.setdefault(run.metrics_file(row["service"], row["id"]), []).append(row)
        for path, rows in by_file.items():
            text = "".join(json.dumps(r) + "\n" for r in rows)
            atomic_write(path, text)
    return run.root


__all__ = [
    "LoadedRun",
    "SerialRecorder",
    "config_from_checkpoint",
    "default_out",
    "from_plain",
    "iter_metrics",
    "load_config",
    "load_policy",
    "load_run",
    "make_serial_loop",
    "save_serial_run",
    "serial_config",
    "to_plain",
]
