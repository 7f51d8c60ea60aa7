"""Trained point-env runs shared by the learning tests (learner, eval suite, evaluator service).

Every run is the core's ``point`` preset (``ursa.config.preset("point", "point")``, the recipe
``make run ARGS="--preset point --env point"`` runs), trained by the single-process loop
(:class:`ursa.serial.SerialLoop`) for ``ursa.config.TRAIN_STEPS["point"]`` env steps and saved
as a run directory (:func:`ursa.eval.loading.save_serial_run`), which ``ursa eval`` and the
evaluator service read like runs of the services: URSA (``ursa-supervised``, φ = position) for
each of :data:`SEEDS`, and one DayDreamer run (reward only) with the same recipe and budget.
Beside them, :data:`A1_RUN`: the A1's CPU recipe (preset ``cpu``, URSA with the learned φ)
trained the same way for ``TRAIN_STEPS["cpu"]`` env steps (issue 20's A1 learning test).
They train once per test session, two processes at once: the point runs first, which many
tests wait for, then the A1 run, which only its test waits for (that test runs last, so the A1
run trains beside the tests that use the point runs).

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

from ursa.config import PREFILL, TRAIN_STEPS, Config, PresetName, preset
from ursa.learner_config import Mode
from ursa.plain import to_plain

SEEDS = (0, 1, 2)
"""Seeds of the URSA runs the learning tests judge (median and worst seed)."""
PRESET: PresetName = "point"
PREFILL_STEPS = PREFILL[PRESET]
ENV_STEPS = TRAIN_STEPS[PRESET]


def point_config(mode: Mode, seed: int = 0) -> Config:
    """The core config of a run: the ``point`` preset, ``mode``, the learner seeded ``seed``."""
    cfg = preset(PRESET, "point")
    return dataclasses.replace(cfg, learner=dataclasses.replace(cfg.learner, mode=mode, seed=seed))


SKILL_PERIOD = point_config("ursa-supervised").collector.skill_period
"""T: env steps per skill, in training and in the evaluations."""
N_Z = point_config("ursa-supervised").repertoire.n_z
"""N_z (sets δ)."""

#: Run name -> (mode, seed).
RUNS: dict[str, tuple[Mode, int]] = {
    **{f"ursa-s{s}": ("ursa-supervised", s) for s in SEEDS},
    "daydreamer": ("daydreamer", SEEDS[0]),
}
A1_RUN = "a1-cpu"
"""The A1 run of the CPU recipe (seed 0)."""
A1_PRESET: PresetName = "cpu"


def run_config(name: str) -> Config:
    """The core config of the run ``name`` (:data:`RUNS` or :data:`A1_RUN`)."""
    if name == A1_RUN:
        return preset(A1_PRESET, "a1")
    mode, seed = RUNS[name]
    return point_config(mode, seed)


def run_budget(name: str) -> tuple[int, int]:
    """(prefill, env steps in all) of the run ``name``: its preset's."""
    p = A1_PRESET if name == A1_RUN else PRESET
    return PREFILL[p], TRAIN_STEPS[p]


ALL_RUNS = (*RUNS, A1_RUN)
"""Every run, in the order they start."""


def recipe() -> dict[str, Any]:
    """Everything that decides what the runs learn (compared with a cache's ``recipe.json``)."""
    return {
        "config": {name: to_plain(run_config(name)) for name in ALL_RUNS},
        "budget": {name: run_budget(name) for name in ALL_RUNS},
    }


def _lower_priority() -> None:
    """Worker initialiser: the trainings run beside the rest of the suite and yield to it."""
    os.nice(10)


def _train(args: tuple[str, str]) -> tuple[str, float]:
    """Worker: train one run and save it; returns (run dir, seconds)."""
    import torch  # noqa: F401 - loaded first, so that its pool is set too

    from ursa.eval.loading import SerialRecorder, make_serial_loop, save_serial_run
    from ursa.threads import limit_threads

    limit_threads()
    root, name = args
    cfg = run_config(name)
    prefill, steps = run_budget(name)
    start = time.perf_counter()
    loop = make_serial_loop(cfg, prefill=prefill, seed=cfg.learner.seed)
    rec = SerialRecorder(loop)
    loop.run(steps - loop.env_steps, callback=rec, callback_every=1000)
    run = save_serial_run(loop, cfg, Path(root) / name, rec)
    return str(run), time.perf_counter() - start


class Training:
    """The runs ``names`` (default: all of :data:`ALL_RUNS`) under ``root``, training in the
    background (two processes at a lowered priority, so that the tests collected beside them
    keep the CPU they need) unless ``root`` already holds runs of the same recipe;
    :meth:`result` waits for the ones a test needs (starting any not started yet)."""

    def __init__(self, root: Path, names: tuple[str, ...] = ALL_RUNS) -> None:
        self.root = root
        root.mkdir(parents=True, exist_ok=True)
        self.stamp = root / "recipe.json"
        self.want = json.loads(json.dumps(recipe()))
        self.started = time.perf_counter()
        self._ex: ProcessPoolExecutor | None = None
        self._jobs: dict[str, Any] = {}
        self._seconds: dict[str, float] = {}
        if self.cached():
            return
        workers = min(len(ALL_RUNS), max(1, os.cpu_count() or 1))
        ctx = multiprocessing.get_context("spawn")
        self._ex = ProcessPoolExecutor(workers, mp_context=ctx, initializer=_lower_priority)
        # the point runs first (URSA, then the cheaper daydreamer run), the A1 run last
        for name in ALL_RUNS:
            if name in names:
                self._submit(name)

    def _submit(self, name: str) -> None:
        assert self._ex is not None
        self._jobs[name] = self._ex.submit(_train, (str(self.root), name))

    def cached(self) -> bool:
        return self.stamp.exists() and json.loads(self.stamp.read_text()).get("recipe") == self.want

    def result(self, names: tuple[str, ...] = tuple(RUNS)) -> dict[str, Any]:
        """Run dirs of every run (plus ``ursa``: the first seed's), seconds per run and whether
        cached, once the runs ``names`` are trained (default: the point runs)."""
        runs: dict[str, Path] = {name: self.root / name for name in ALL_RUNS}
        runs["ursa"] = runs[f"ursa-s{SEEDS[0]}"]
        if self._ex is None and not self._jobs:
            info = json.loads(self.stamp.read_text())
            return {"runs": runs, "seconds": info["seconds"], "cached": True}
        for name in names:
            if name not in self._jobs:  # not collected at the start: train it now
                self._submit(name)
        for name in names:
            if name not in self._seconds:
                self._seconds[name] = self._jobs[name].result()[1]
        seconds = dict(self._seconds)
        if f"ursa-s{SEEDS[0]}" in seconds:
            seconds["ursa"] = seconds[f"ursa-s{SEEDS[0]}"]
        seconds["wall"] = time.perf_counter() - self.started
        if all(name in self._seconds for name in ALL_RUNS) and self._ex is not None:
            self._ex.shutdown(wait=True, cancel_futures=True)
            self._ex = None
            self.stamp.write_text(json.dumps({"recipe": self.want, "seconds": seconds}))
        return {"runs": runs, "seconds": seconds, "cached": False}

    def cancel(self) -> None:
        """Stop trainings nobody waited for (the session ended first): their workers are
        terminated, so that the interpreter does not wait for them at exit."""
        if self._ex is not None:
            procs = list(getattr(self._ex, "_processes", {}).values())
            self._ex.shutdown(wait=False, cancel_futures=True)
            for proc in procs:
                proc.terminate()
            self._ex = None


def trained_point_runs(root: Path) -> dict[str, Any]:
    """The runs of :data:`RUNS` under ``root``, trained now unless cached (see
    :class:`Training`)."""
    return Training(root).result()


def cli_args(mode: Mode, seed: int = 0) -> list[str]:
    """Service flags that give a service the config of a run of ``mode``: the preset pickers,
    then a tyro flag for each field that differs from the ``tiny`` point preset (the test
    stacks start services with ``--preset tiny --env point``)."""
    base, cfg = preset("tiny", "point"), point_config(mode, seed)
    args = ["--preset", "tiny", "--env", "point"]
    for part in ("learner", "repertoire", "collector"):
        have, want = getattr(base, part), getattr(cfg, part)
        for f in dataclasses.fields(want):
            v = getattr(want, f.name)
            if getattr(have, f.name) != v:
                args += [f"--core.{part}.{f.name.replace('_', '-')}", str(v)]
    return args
