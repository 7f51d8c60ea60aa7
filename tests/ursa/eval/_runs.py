"""Helpers making small run directories in-process with the SerialLoop (ursa.eval.loading)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import torch

from ursa.config import Config, EnvName, preset
from ursa.eval.loading import SerialRecorder, make_serial_loop, save_serial_run
from ursa.learner_config import Mode

torch.set_num_threads(1)

#: Smaller than ``tiny``: these runs only need a checkpoint with the right layout, not learning.
MICRO = {
    "deter": 32, "hidden": 32, "stoch": 4, "classes": 4, "units": 32, "bins": 31,
    "batch_size": 4, "seq_len": 8, "imag_horizon": 5, "imag_starts": 16, "vae_batch": 32,
    "vae_publish_every": 2, "train_ratio": 2.0,
}  # fmt: skip


def small_config(
    env: EnvName,
    feature: str | None = None,
    mode: Mode | None = None,
    micro: bool = True,
    **repertoire: int,
) -> Config:
    cfg = preset("tiny", env, feature)
    lc = cfg.learner
    if micro:
        lc = dataclasses.replace(lc, **MICRO)  # type: ignore[arg-type]
    if mode is not None:
        lc = dataclasses.replace(lc, mode=mode)
    rep = dataclasses.replace(cfg.repertoire, **repertoire)
    return dataclasses.replace(cfg, learner=lc, repertoire=rep)


def make_run(root: Path, name: str, cfg: Config, steps: int, prefill: int) -> Path:
    loop = make_serial_loop(cfg, prefill=prefill)
    rec = SerialRecorder(loop)
    loop.run(steps, callback=rec, callback_every=max(steps // 8, 1))
    return save_serial_run(loop, cfg, root / name, rec)
