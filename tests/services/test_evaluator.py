"""The evaluation collector: it measures by the core's one evaluation rollout
(``ursa.eval.rollout.run_skill``), validates requests, loads the learner's weights over the bus,
and (slow) a policy trained on the point env reaches a repertoire skill within δ through
``POST /evaluate``."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from fastapi.testclient import TestClient
from safetensors.numpy import load as safetensors_load

from proto import codec
from proto import ursa_pb2 as pb
from services.api.service import ApiArgs, ApiService
from services.common.bus import query_one
from services.common.config import RunConfig, config_hash
from services.evaluator.service import Evaluator, EvaluatorArgs
from services.stack import Stack, running_stack, wait_for
from tests.services._stack import snapshot_msg
from tests.trained import cli_args, point_config
from ursa.config import Config, build_env, preset
from ursa.envs import allowed_damages
from ursa.envs.point import PointEnv
from ursa.eval.loading import read_checkpoint
from ursa.eval.rollout import run_skill
from ursa.learner import Learner
from ursa.policy import Policy, pack_policy_weights
from ursa.repertoire import Repertoire
from ursa.scoring import skill_distance

RUN = "test"
torch.set_num_threads(1)


def _policy(cfg: Config, seed: int = 0) -> Policy:
    env = build_env(cfg)
    return Policy(
        cfg.learner,
        env.obs_dim,
        env.act_dim,
        cfg.skill_dim,
        feat_in_dim=int(env.feature_dims[cfg.feature_input_key]),
        seed=seed,
    )


# ---- the measurement -------------------------------------------------------------------------
def test_mahalanobis_and_damages() -> None:
    assert skill_distance(np.array([1.0, 0.0]), np.zeros(2), np.diag([4.0, 1.0])) == 0.5
    assert allowed_damages("point") == ("", "none")
    a1 = allowed_damages("a1")
    assert "front_hip" in a1 and "back_lower" in a1 and "" in a1


# ---- the service over a real router ------------------------------------------------------------
@pytest.fixture()
def bus_evaluator(tmp_path: Path) -> Iterator[tuple[Stack, Evaluator, Any]]:
    """A router, an in-process evaluator (point env, tiny) and a peer session."""
    with running_stack(tmp_path, run_id=RUN) as st:
        st.start_router()
        cfg = preset("tiny", "point")
        ev = Evaluator(
            EvaluatorArgs(
                core=cfg, bus=st.bus, max_steps=500, run=RunConfig(run_id=RUN, root=st.runs)
            )
        )
        peer = st.session()
        try:
            yield st, ev, peer
        finally:
            peer.close()
            ev.close()


def _request(
    ev: Evaluator, skill: Any, steps: int = 50, damage: str = "", seed: int | None = 1
) -> pb.EvaluateRequest:
    req = pb.EvaluateRequest(
        header=codec.header(RUN, "api/main"),
        steps=steps,
        damage=damage,
        skill=codec.to_array(np.asarray(skill, np.float32)),
    )
    if seed is not None:
        req.has_seed, req.seed = True, seed
    return req


def test_evaluator_validates_and_needs_a_snapshot(
    bus_evaluator: tuple[Stack, Evaluator, Any],
) -> None:
    st, ev, peer = bus_evaluator
    for skill, steps, damage, why in [
        ([0.1, 0.2, 0.3], 50, "", "shape"),
        ([0.1, np.nan], 50, "", "finite"),
        ([0.1, 0.2], 0, "", "steps"),
        ([0.1, 0.2], 501, "", "steps"),
        ([0.1, 0.2], 50, "front_hip", "damage"),
    ]:
        reply = ev.handle(_request(ev, skill, steps, damage))
        assert reply.error.startswith("invalid:") and why in reply.error, reply.error
    reply = ev.handle(_request(ev, [0.1, 0.2]))
    assert reply.error.startswith("unavailable:") and "snapshot" in reply.error
    peer.put(st.topics.snapshot, codec.encode(snapshot_msg(20, d=2, run_id=RUN)))
    wait_for(lambda: ev.snapshot is not None, 10, "the snapshot to reach the evaluator")
    reply = ev.handle(_request(ev, [0.1, 0.2], damage="none"))
    assert not reply.error and reply.steps == 50 and reply.policy_version == 0
    assert reply.delta == pytest.approx(0.3)
    again = ev.handle(_request(ev, [0.1, 0.2]))  # same seed: the same run
    assert again.distance == reply.distance and again.ret == reply.ret


def test_evaluator_serves_queries_and_loads_the_learners_weights(
    bus_evaluator: tuple[Stack, Evaluator, Any],
) -> None:
    st, ev, peer = bus_evaluator
    t = st.topics
    loop = threading.Thread(target=ev.run, daemon=True)
    loop.start()
    try:
        peer.put(t.snapshot, codec.encode(snapshot_msg(20, d=2, run_id=RUN)))
        wait_for(lambda: ev.snapshot is not None, 10, "the snapshot")
        bad = query_one(peer, t.evaluate, pb.EvaluateReply, b"\x00junk", timeout_s=10)
        assert bad is not None and bad.error.startswith("invalid:")
        # weights with another learner config are refused; the matching ones are used
        cfg = ev.cfg
        pol = _policy(cfg, seed=5)
        blob = pack_policy_weights(pol.modules(), version=3, vae_version=0)
        wrong = pb.PolicyWeights(
            header=codec.header(RUN, "learner/main"),
            version=2,
            safetensors=blob,
            config_hash="nope",
        )
        peer.put(t.weights, codec.encode(wrong))
        wait_for(lambda: ev._pending is not None, 10, "the weights to arrive")
        r = query_one(
            peer, t.evaluate, pb.EvaluateReply, codec.encode(_request(ev, [0.2, 0.2])), timeout_s=30
        )
        assert r is not None and not r.error and r.policy_version == 0
        assert ev.rt.drops.counts["config_mismatch"] == 1
        good = pb.PolicyWeights(
            header=codec.header(RUN, "learner/main"),
            version=3,
            safetensors=blob,
            config_hash=config_hash(cfg.learner),
        )
        peer.put(t.weights, codec.encode(good))
        wait_for(lambda: ev._pending is not None, 10, "the weights to arrive")
        r = query_one(
            peer, t.evaluate, pb.EvaluateReply, codec.encode(_request(ev, [0.2, 0.2])), timeout_s=30
        )
        assert r is not None and not r.error and r.policy_version == 3
        expected = run_skill(
            pol,
            build_env(cfg, seed=1),
            np.array([0.2, 0.2]),
            50,
            "position",
            np.eye(2) * 0.05,
            seed=1,
        )
        assert r.distance == pytest.approx(expected.distance, rel=1e-5)
    finally:
        ev.rt.stop.set()
        loop.join(timeout=10)


# ---- a trained policy, end to end ------------------------------------------------------------
@pytest.fixture(scope="module")
def trained_point(point_runs: dict[str, Any]) -> dict[str, Any]:
    """The session's trained point-env URSA run (tests/trained.py): its weights as the learner
    publishes them and its repertoire (skills, ids, ages, NN distances, Σ, δ)."""
    run_dir: Path = point_runs["runs"]["ursa"]
    cfg = point_config("ursa-supervised")
    state = read_checkpoint(run_dir / "checkpoints" / "learner.pt")
    learner = Learner(cfg.learner, PointEnv.obs_dim, PointEnv.act_dim, 2)
    learner.load_state_dict(state)
    rep = Repertoire.load(run_dir / "repertoire" / "archive.npz")
    return {
        "cfg": cfg,
        "weights": learner.policy_weights_bytes(),
        "updates": learner.updates,
        "train_s": point_runs["seconds"]["ursa"],
        "skills": np.asarray(rep.skills),
        "ids": np.asarray(rep.ids),
        "ages": np.asarray(rep.ages),
        "nn": np.asarray(rep.nn_dist),
        "cov": np.asarray(rep.cov),
        "delta": np.float64(rep.delta()),
        "n_z": rep.config.n_z,
    }


def _snapshot_of(tp: dict[str, Any]) -> pb.RepertoireSnapshot:
    return pb.RepertoireSnapshot(
        header=codec.header(RUN, "repertoire/main"),
        version=1,
        skills=codec.to_array(tp["skills"].astype(np.float32)),
        ids=codec.to_array(tp["ids"].astype(np.int64)),
        ages=codec.to_array(tp["ages"].astype(np.int64)),
        nn_dist=codec.to_array(tp["nn"].astype(np.float32)),
        cov=codec.to_array(tp["cov"].astype(np.float64)),
        delta=float(tp["delta"]),
        capacity=len(tp["skills"]),
        n_z=int(tp["n_z"]),
    )


@pytest.mark.slow
@pytest.mark.timeout(3600)
def test_evaluate_trained_point_policy_reaches_a_repertoire_skill(
    tmp_path: Path,
    trained_point: dict[str, Any],
) -> None:
    tp = trained_point
    cfg: Config = tp["cfg"]
    skills, cov, delta = tp["skills"], tp["cov"], float(tp["delta"])
    tensors = safetensors_load(tp["weights"])
    assert all(np.isfinite(v).all() for v in tensors.values()), (
        "the learner produced non-finite weights"
    )
    policy = _policy(cfg)
    policy.load_weights_bytes(tp["weights"], version=7)
    # pick the best-achieved of 32 repertoire skills, measured exactly as the evaluator will
    rng = np.random.default_rng(0)
    rows = rng.choice(len(skills), size=min(32, len(skills)), replace=False)
    measured = []
    for seed, row in enumerate(rows):
        z = skills[row].astype(np.float32)
        r = run_skill(policy, build_env(cfg, seed=seed), z, 250, "position", cov, seed=seed)
        rnd = run_skill(None, build_env(cfg, seed=seed), z, 250, "position", cov, seed=seed)
        measured.append((r.distance, seed, int(row), rnd.distance))
    distances = np.array([m[0] for m in measured])
    random_distances = np.array([m[3] for m in measured])
    print(
        f"trained {tp['updates']} updates in {tp['train_s']:.0f} s; "
        f"δ {delta:.3f}; within δ {np.mean(distances <= delta):.2f}; median distance "
        f"{np.median(distances):.2f} (random policy {np.median(random_distances):.2f})"
    )
    assert np.median(distances) < np.median(random_distances)  # it learned something
    best, seed, row, _ = min(measured)
    skill_id = int(tp["ids"][row])

    with running_stack(tmp_path, run_id=RUN) as st:
        st.start_router()
        ev = st.start(
            "eval", "services.evaluator", "--collector-id", "eval", *cli_args("ursa-supervised")[4:]
        )
        peer = st.session()
        t = st.topics
        weights = codec.encode(
            pb.PolicyWeights(
                header=codec.header(RUN, "learner/main"),
                version=7,
                safetensors=tp["weights"],
                config_hash=config_hash(cfg.learner),
            )
        )
        handles: list[Any] = [
            peer.liveliness().declare_token(t.alive("learner", "main")),
            peer.liveliness().declare_token(t.alive("repertoire", "main")),
            peer.declare_queryable(t.weights, lambda q: q.reply(t.weights, weights)),
            peer.declare_queryable(
                t.snapshot, lambda q: q.reply(t.snapshot, codec.encode(_snapshot_of(tp)))
            ),
        ]
        svc = ApiService(ApiArgs(core=cfg, bus=st.bus, run=RunConfig(run_id=RUN, root=st.runs)))
        try:
            peer.put(t.snapshot, codec.encode(_snapshot_of(tp)))
            with TestClient(svc.app) as client:
                wait_for(lambda: "EVALUATOR READY" in ev.log(), 60, "the evaluator")
                wait_for(
                    lambda: client.get("/health").json()["peers"]["evaluator"],
                    30,
                    "the API to see the evaluator",
                )
                wait_for(
                    lambda: client.get(f"/skills/{skill_id}").status_code == 200,
                    30,
                    "the snapshot to reach the API",
                )
                r = client.post("/evaluate", json={"skill": skill_id, "steps": 250, "seed": seed})
                assert r.status_code == 200, r.json()
                body = r.json()
        finally:
            for h in handles:
                h.undeclare()
            peer.close()
            svc.close()
    assert body["policy_version"] == 7 and body["skill_id"] == skill_id
    assert body["distance"] == pytest.approx(best, rel=1e-4)  # the service measures the same
    assert body["delta"] == pytest.approx(delta)
    assert body["distance"] < body["delta"] and body["within_delta"]
