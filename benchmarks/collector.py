"""Collector throughput against the bare environment, measured in the same run.

A real collector (policy inference with the published weights, chunk and feature publishing over
a real Zenoh router, stats) runs for a fixed number of control steps; the bare environment does
the same number of steps with random actions. Prints a table and the ratio (target ≥ 0.8).
It also times the policy's two inference paths per step, in the same process: the numpy path the
collector runs (``Policy.act``) and the exported ONNX model under onnxruntime (``ursa export``);
the collector keeps the faster one (numpy: see docs/export.md).

    .venv/bin/python benchmarks/collector.py [--quick] [--preset small] [--env a1]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from services.collector.service import Collector, CollectorArgs  # noqa: E402
from services.common.config import BusConfig, RunConfig  # noqa: E402
from services.stack import free_port, wait_port  # noqa: E402
from ursa.config import build_env, preset  # noqa: E402
from ursa.learner import Learner  # noqa: E402


def bare(cfg, steps: int) -> float:  # type: ignore[no-untyped-def]
    env = build_env(cfg, seed=0)
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    t0 = time.perf_counter()
    for _ in range(steps):
        env.step(rng.uniform(-1, 1, env.act_dim).astype(np.float32))
    dt = time.perf_counter() - t0
    env.close()
    return steps / dt


def inference_times(
    policy,
    obs: np.ndarray,
    skill: np.ndarray,
    n: int = 200,  # type: ignore[no-untyped-def]
    rounds: int = 5,
) -> tuple[float, float]:
    """Seconds per step (best of ``rounds`` alternating blocks of ``n``: the machine is shared)
    of the policy's two inference paths, one thread, batch 1, both drawing the latent uniforms
    and the action noise: ``Policy.act`` (numpy, what the collector runs) and the exported ONNX
    model (``ursa export``) under onnxruntime."""
    from ursa.export import OnnxPolicy, build_onnx

    p = policy.params
    ort = OnnxPolicy(build_onnx(p, policy.obs_dim, policy.act_dim, policy.skill_dim))
    o1 = np.asarray(obs, np.float32)
    o = o1[None]
    s1 = np.asarray(skill, np.float32).reshape(-1)
    s = s1[None]
    rng = np.random.default_rng(0)
    best_np = best_ort = float("inf")
    for _ in range(rounds):
        carry = policy.initial_carry()
        t0 = time.perf_counter()
        for _ in range(n):
            _, carry = policy.act(carry, o1, s1, explore=True, rng=rng)
        best_np = min(best_np, (time.perf_counter() - t0) / n)
        c0 = policy.initial_carry()
        h, z, a = c0.h, c0.z, c0.action
        t0 = time.perf_counter()
        for _ in range(n):
            u = policy.latent_rng.random((1, p.stoch), dtype=np.float32)
            eps = rng.standard_normal((1, policy.act_dim)).astype(np.float32)
            out = ort.step(obs=o, h=h, z=z, prev_action=a, skill=s, u=u, eps=eps)
            h, z, a = out["h_next"], out["z_next"], out["action"]
        best_ort = min(best_ort, (time.perf_counter() - t0) / n)
    return best_np, best_ort


def collector(cfg, steps: int, router: str, runs: Path) -> tuple[float, float, float]:  # type: ignore[no-untyped-def]
    args = CollectorArgs(
        core=cfg,
        bus=BusConfig(router=router),
        run=RunConfig("bench", runs),
        collector_id="bench",
        max_steps=steps,
    )
    c = Collector(args)
    env = c.env
    learner = Learner(
        cfg.learner,
        env.obs_dim,
        env.act_dim,
        int(env.feature_dims[cfg.feature_input_key]),
        cfg.skill_dim,
    )
    c.policy.load_weights_bytes(learner.policy_weights_bytes(), version=1)
    c.policy_version = 1  # act with the policy from the first step (no random prefill)
    obs, _ = env.reset()
    inference, inference_onnx = inference_times(c.policy, obs, c.skill)
    t0 = time.perf_counter()
    c.run()
    dt = time.perf_counter() - t0
    c.close()
    return steps / dt, inference, inference_onnx


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--quick", action="store_true", help="finish within 60 s")
    ap.add_argument("--preset", default="small", choices=["tiny", "point", "small", "cpu", "paper"])
    ap.add_argument("--env", default="a1", choices=["a1", "point"])
    a = ap.parse_args()
    torch.set_num_threads(1)
    cfg = preset(a.preset, a.env)  # type: ignore[arg-type]
    steps = 1000 if a.quick else 5000
    if a.env == "point":
        steps *= 10
    port = free_port()
    router = f"tcp/127.0.0.1:{port}"
    proc = subprocess.Popen(
        [sys.executable, "-m", "services.router", "--listen", router],
        cwd=ROOT,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        wait_port(port)
        with tempfile.TemporaryDirectory() as tmp:
            bare_sps = bare(cfg, steps)
            coll_sps, inference, inference_onnx = collector(cfg, steps, router, Path(tmp))
            bare_sps2 = bare(cfg, steps)  # bracket the collector: the machine is shared
    finally:
        proc.terminate()
        proc.wait(10)
    ref = (bare_sps + bare_sps2) / 2
    ratio = coll_sps / ref
    print(f"{'what':<34}{'steps/s':>12}")
    print(f"{'bare env (random actions)':<34}{ref:>12.1f}")
    print(f"{'collector (policy + publishing)':<34}{coll_sps:>12.1f}")
    print(f"{'policy inference per step (ms)':<34}{'':>12}")
    print(f"{'  numpy (the collector uses it)':<34}{inference * 1e3:>12.3f}")
    print(f"{'  onnxruntime (ursa export)':<34}{inference_onnx * 1e3:>12.3f}")
    print(f"env={a.env} preset={a.preset} steps={steps}")
    print(
        f"RESULT ratio={ratio:.3f} collector_steps_per_s={coll_sps:.1f} "
        f"numpy_ms={inference * 1e3:.3f} onnx_ms={inference_onnx * 1e3:.3f} "
        f"onnx_over_numpy={inference_onnx / inference:.2f}"
    )


if __name__ == "__main__":
    main()
