"""Trained point-env runs shared by the learning tests (learner, eval suite, evaluator service).

One URSA run (``ursa-supervised``, φ = position) and one DayDreamer run (reward only) with the
same learner recipe, env, budget and seed, trained once per test session, in two processes at
once, by the single-process loop (:class:`ursa.serial.SerialLoop`) and saved as run directories
(:func:`ursa.eval.loading.save_serial_run`), which ``ursa eval`` and the evaluator service read
like runs of the services.

``URSA_TRAINED_POINT_DIR``: keep the runs there and reuse them while their recipe is unchanged
(a ``recipe.json`` beside them says which recipe trained them).
"""

from __future__ import annotations

import dataclasses
import json
import multiprocessing
import os
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

from ursa.config import Config, preset
from ursa.learner_config import LearnerConfig, Mode
from ursa.plain import to_plain

POINT = LearnerConfig.tiny(
    mode="ursa-supervised",
    imag_starts=128,
    model_lr=3e-4,
    actor_lr=1e-4,
    critic_lr=1e-4,
    lagrange_lr=1e-4,
    train_ratio=128.0,
    discount=0.98,
    cost_discount=0.9,
    delta_scale=0.5,
)
"""The learner of the point-env runs: tiny sizes, faster learning rates, shorter horizons
(γ 0.98, cost γ 0.9) so that a few thousand updates suffice, and the skill constraint enforced
at δ/2 (``delta_scale``) so that executed skills land within δ; see docs/learner.md."""
PREFILL = 2000
"""Env steps of uniformly random actions before the first update."""
SKILL_PERIOD = 250
"""T: env steps per skill, in training and in the evaluations."""
REPERTOIRE_SIZE = 1000
"""N_R."""
N_Z = 100
"""N_z (sets δ)."""
ENV_STEPS = 12_000
"""Env steps of each run: the prefill, then 10,000 on-policy steps (train_ratio 128 with
batches of 16 × 32: 3000 updates, 500 of them right after the prefill)."""
SEED = 0


def point_config(mode: Mode) -> Config:
    """The core config of a run: the ``tiny`` point preset with :data:`POINT`'s learner."""
    cfg = preset("tiny", "point")
    lc = dataclasses.replace(POINT, mode=mode, skill_dim=cfg.learner.skill_dim)
    return dataclasses.replace(
        cfg,
        learner=lc,
        repertoire=dataclasses.replace(cfg.repertoire, size=REPERTOIRE_SIZE, n_z=N_Z),
        collector=dataclasses.replace(cfg.collector, skill_period=SKILL_PERIOD),
    )


def recipe() -> dict[str, Any]:
    """Everything that decides what the runs learn (compared with a cache's ``recipe.json``)."""
    modes: tuple[Mode, ...] = ("ursa-supervised", "daydreamer")
    return {
        "config": {m: to_plain(point_config(m)) for m in modes},
        "prefill": PREFILL,
        "env_steps": ENV_STEPS,
        "seed": SEED,
    }


def _train(args: tuple[str, Mode, str]) -> tuple[str, float]:
    """Worker: train one run and save it; returns (run dir, seconds)."""
    import torch

    from ursa.eval.loading import SerialRecorder, make_serial_loop, save_serial_run

    torch.set_num_threads(1)
    root, mode, name = args
    cfg = point_config(mode)
    start = time.perf_counter()
    loop = make_serial_loop(cfg, prefill=PREFILL, seed=SEED)
    rec = SerialRecorder(loop)
    loop.run(ENV_STEPS - loop.env_steps, callback=rec, callback_every=1000)
    run = save_serial_run(loop, cfg, Path(root) / name, rec)
    return str(run), time.perf_counter() - start


def trained_point_runs(root: Path) -> dict[str, Any]:
    """The two runs under ``root`` (``ursa``, ``daydreamer``), trained now unless ``root``
    holds runs of the same recipe. Returns their run dirs and training seconds."""
    root.mkdir(parents=True, exist_ok=True)
    stamp = root / "recipe.json"
    want = json.loads(json.dumps(recipe()))
    names = {"ursa": "ursa-supervised", "daydreamer": "daydreamer"}
    if stamp.exists() and json.loads(stamp.read_text()).get("recipe") == want:
        info = json.loads(stamp.read_text())
        return {"runs": {n: root / n for n in names}, "seconds": info["seconds"], "cached": True}
    jobs = [(str(root), mode, name) for name, mode in names.items()]
    if (os.cpu_count() or 1) >= 2:  # the two trainings share nothing: one process each
        ctx = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(len(jobs), mp_context=ctx) as ex:
            done = list(ex.map(_train, jobs))
    else:
        done = [_train(j) for j in jobs]
    seconds = {name: s for (name, _), (_, s) in zip(names.items(), done, strict=True)}
    stamp.write_text(json.dumps({"recipe": want, "seconds": seconds}))
    return {"runs": {n: root / n for n in names}, "seconds": seconds, "cached": False}


def cli_args(mode: Mode) -> list[str]:
    """Service flags that give a service the config of a run of ``mode``: the preset pickers,
    then a tyro flag for each field that differs from the ``tiny`` point preset."""
    base, cfg = preset("tiny", "point"), point_config(mode)
    args = ["--preset", "tiny", "--env", "point"]
    for part in ("learner", "repertoire", "collector"):
        have, want = getattr(base, part), getattr(cfg, part)
        for f in dataclasses.fields(want):
            v = getattr(want, f.name)
            if getattr(have, f.name) != v:
                args += [f"--core.{part}.{f.name.replace('_', '-')}", str(v)]
    return args
