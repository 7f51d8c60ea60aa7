"""Adaptation jobs (Intelligent Trial and Error) on the evaluator and through the HTTP API, over a
real Zenoh router on loopback (point env, ``tiny``): validation, one job at a time (409), the
job's decisions are the core's (``ursa.adapt``) on the returns it measured, the intact map is
cached in the run directory, jobs persist and survive an API restart, an evaluator that stops
mid-job leaves it ``lost``; the schema states the bounds."""

from __future__ import annotations

import json
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from proto import codec
from proto import ursa_pb2 as pb
from services.api.service import ApiArgs, ApiService
from services.common.config import RunConfig
from services.evaluator.service import DONE, LOST, MAPPING, Evaluator, EvaluatorArgs
from services.stack import Stack, running_stack, wait_for
from tests.services._stack import snapshot_msg
from ursa import adapt
from ursa.adapt import ITEParams, SkillMap
from ursa.config import preset

RUN = "test"
pytestmark = pytest.mark.timeout(300)


def _args(st: Stack) -> EvaluatorArgs:
    return EvaluatorArgs(
        core=preset("tiny", "point"),
        bus=st.bus,
        max_steps=500,
        max_adapt_budget=50,
        run=RunConfig(run_id=RUN, root=st.runs),
    )


@pytest.fixture()
def stack(tmp_path: Path) -> Iterator[tuple[Stack, Any]]:
    with running_stack(tmp_path, run_id=RUN) as st:
        st.start_router()
        peer = st.session()
        try:
            yield st, peer
        finally:
            peer.close()


def _with_snapshot(st: Stack, peer: Any, ev: Evaluator, d: int = 2) -> None:
    msg = codec.encode(snapshot_msg(30, d=d, run_id=RUN))

    def arrived() -> bool:
        # put again until it lands: a subscriber declared just before may not be routed yet
        peer.put(st.topics.snapshot, msg)
        return ev.snapshot is not None

    wait_for(arrived, 20, "the snapshot to reach the evaluator", every=0.5)


def _req(**kw: Any) -> pb.AdaptRequest:
    fields: dict[str, Any] = {
        "budget": 5,
        "alpha": 0.9,
        "kappa": 0.05,
        "length_scale": 1.0,
        "noise": 1e-3,
        "skills": 8,
        "steps": 20,
        "has_seed": True,
        "seed": 3,
    }
    fields.update(kw)
    return pb.AdaptRequest(header=codec.header(RUN, "api/main"), **fields)


def _run_job(ev: Evaluator, limit: int = 200) -> int:
    steps = 0
    while ev.adapt_step():
        steps += 1
        assert steps < limit
    return steps


def test_a_job_follows_the_core_and_caches_its_map(stack: tuple[Stack, Any]) -> None:
    st, peer = stack
    ev = Evaluator(_args(st))
    try:
        cases: list[tuple[dict[str, Any], str]] = [
            ({"budget": 0}, "budget"),
            ({"budget": 51}, "budget"),
            ({"alpha": 0.0}, "alpha"),
            ({"alpha": 1.5}, "alpha"),
            ({"noise": 0.0}, "noise"),
            ({"length_scale": float("nan")}, "length_scale"),
            ({"steps": 501}, "steps"),
            ({"damage": "front_hip"}, "damage"),
            ({"frozen_joints": [1]}, "frozen_joints"),
        ]
        for kw, why in cases:
            r = ev.start_adapt(_req(**kw))
            assert r.error.startswith("invalid:") and why in r.error, (kw, r.error)
        r = ev.start_adapt(_req())
        assert r.error.startswith("unavailable:") and "snapshot" in r.error
        _with_snapshot(st, peer, ev)

        job = ev.start_adapt(_req())
        assert not job.error and job.state == MAPPING and len(job.job_id) == 16
        path = ev.jobs_dir / f"{job.job_id}.json"
        assert path.is_file()
        busy = ev.start_adapt(_req())
        assert busy.error.startswith("busy:") and job.job_id in busy.error
        n_steps = _run_job(ev)
        done = ev.job_state(job.job_id)
        assert done is not None and done.state == DONE
        assert done.stop_reason in adapt.STOP_REASONS
        assert n_steps == 8 + len(done.trials)  # one rollout per map row, then per trial
        assert 1 <= len(done.trials) <= 5
        # the file holds the final state
        saved = json.loads(path.read_text())
        assert saved["state"] == DONE and len(saved["trials"]) == len(done.trials)

        # the job's decisions are the core's on the same map and returns
        skills = codec.from_array(done.map_skills)
        prior = codec.from_array(done.map_returns)
        ids = codec.from_array(done.map_ids)
        assert prior.shape == (8,) and np.all(np.isfinite(prior))
        rets = {int(t.row): t.ret for t in done.trials}
        core = adapt.ite(
            SkillMap(skills, prior, ids), lambda i: rets[i], ITEParams(budget=5, alpha=0.9)
        )
        assert [t.index for t in core.trials] == [int(t.row) for t in done.trials]
        assert core.reason == done.stop_reason
        assert done.chosen_skill_id == core.chosen.skill_id
        assert done.trials[0].skill_id == int(ids[int(np.argmax(prior))])
        for a, b in zip(core.trials, done.trials, strict=True):
            assert b.predicted == pytest.approx(a.predicted)
            assert b.predicted_best_id == int(ids[a.predicted_best])
        # the intact map was written once and is read back by the next job
        assert len(list(adapt.adapt_dir(st.run_dir).glob("intact-*.npz"))) == 1
        again = ev.start_adapt(_req(seed=4))
        assert not again.error
        ev.adapt_step()
        j2 = ev.job_state(again.job_id)
        assert j2 is not None and j2.map_cached and j2.mapped == 8
        np.testing.assert_array_equal(codec.from_array(j2.map_returns), prior)
        _run_job(ev)
    finally:
        ev.close()


def _api(st: Stack) -> ApiService:
    return ApiService(
        ApiArgs(
            core=preset("tiny", "point"),
            bus=st.bus,
            run=RunConfig(run_id=RUN, root=st.runs),
            max_adapt_budget=50,
            adapt_timeout_s=5.0,
        )
    )


def test_adapt_over_http_survives_an_api_restart(stack: tuple[Stack, Any]) -> None:
    st, peer = stack
    ev = Evaluator(_args(st))
    loop = threading.Thread(target=ev.run, daemon=True)
    loop.start()
    api = _api(st)
    try:
        _with_snapshot(st, peer, ev)
        with TestClient(api.app) as client:
            wait_for(
                lambda: client.get("/health").json()["peers"]["evaluator"], 20, "the evaluator"
            )
            body = {"budget": 4, "skills": 6, "steps": 20, "seed": 5}
            r = client.post("/adapt", json=body)
            assert r.status_code == 202, r.json()
            job = r.json()
            assert job["state"] == "mapping" and job["evaluator"] == "eval"
            assert job["params"]["budget"] == 4 and job["skills"] == 6 and job["damage"] == "none"
            second = client.post("/adapt", json=body)
            if second.status_code != 409:  # the first may already be done on a fast machine
                assert second.status_code == 202, second.json()
                job = second.json()
            else:
                assert "one adaptation at a time" in second.json()["detail"]
            jid = job["job_id"]

            def finished() -> dict[str, Any] | None:
                g = client.get(f"/adapt/{jid}").json()
                return g if g["state"] == "done" else None

            got = wait_for(finished, 60, "the job to finish")
            assert got["source"] == "evaluator"
            assert 1 <= len(got["trials"]) <= 4 and got["mapped"] == 6
            rets = [t["ret"] for t in got["trials"]]
            assert got["chosen"]["value"] == max(rets)
            assert got["chosen"]["skill_id"] == got["trials"][int(np.argmax(rets))]["skill_id"]
            assert len(got["chosen"]["skill"]) == 2 and len(got["trials"][0]["achieved"]) == 2
            assert got["predicted_best"]["skill_id"] >= 0
            assert got["stop_reason"] in adapt.STOP_REASONS
            # the dashboard's stream carried it too
            wait_for(lambda: api.state.cached_job(jid) is not None, 10, "the published state")
            # bad input: 422 with the field; unknown and malformed ids
            for bad, field in [
                ({"budget": 0}, "budget"),
                ({"budget": 51}, "budget"),
                ({"alpha": 1.01}, "alpha"),
                ({"alpha": 0}, "alpha"),
                ({"noise": 0}, "noise"),
                ({"frozen_joints": [0]}, "frozen_joints"),  # point env: no joints
                ({"damage": "front_hip"}, "damage"),
                ({"steps": 5001}, "steps"),
                ({"skills": 0}, "skills"),
                ({"evaluator": "a/b"}, "evaluator"),
                ({"nope": 1}, "nope"),
            ]:
                rb = client.post("/adapt", json=bad)
                assert rb.status_code == 422, (bad, rb.json())
                assert any(field in e["loc"] for e in rb.json()["detail"]), rb.json()
            assert client.get("/adapt/0123456789abcdef").status_code == 404
            assert client.get("/adapt/xyz").status_code == 422
            r = client.post("/adapt", json={**body, "evaluator": "other"})
            assert r.status_code == 404 and "not alive" in r.json()["detail"]
            spec = client.get("/openapi.json").json()
            props = spec["components"]["schemas"]["AdaptRequest"]["properties"]
            assert (props["budget"]["minimum"], props["budget"]["maximum"]) == (1, 50)
            assert props["alpha"]["exclusiveMinimum"] == 0 and props["alpha"]["maximum"] == 1
            assert props["frozen_joints"]["maxItems"] == 0
            assert "409" in spec["paths"]["/adapt"]["post"]["responses"]
        api.close()
        # a new API process knows nothing of the job but finds it
        api = _api(st)
        with TestClient(api.app) as client:
            wait_for(
                lambda: client.get("/health").json()["peers"]["evaluator"], 20, "the evaluator"
            )
            g = client.get(f"/adapt/{jid}").json()
            assert g["state"] == "done" and g["source"] == "evaluator"
            assert [t["ret"] for t in g["trials"]] == rets
    finally:
        api.close()
        ev.rt.stop.set()
        loop.join(timeout=20)
        ev.close()


def test_a_job_whose_evaluator_stops_is_lost(stack: tuple[Stack, Any]) -> None:
    st, peer = stack
    ev = Evaluator(_args(st))
    _with_snapshot(st, peer, ev)
    job = ev.start_adapt(_req(skills=6, budget=4))
    assert not job.error
    ev.adapt_step()  # one map row measured, then the evaluator stops
    ev.close()
    api = _api(st)
    try:
        with TestClient(api.app) as client:
            wait_for(
                lambda: not client.get("/health").json()["peers"]["evaluator"], 20, "no evaluator"
            )
            g = client.get(f"/adapt/{job.job_id}").json()
            assert g["state"] == "lost" and g["source"] == "run_dir"
            assert "gone" in g["stop_reason"] and g["mapped"] == 1
            # a restarted evaluator marks it lost in the run directory, and answers for it
            ev2 = Evaluator(_args(st))
            loop = threading.Thread(target=ev2.run, daemon=True)
            try:
                assert ev2.lost_jobs == 1
                saved = json.loads((ev2.jobs_dir / f"{job.job_id}.json").read_text())
                assert saved["state"] == LOST and "restarted" in saved["stop_reason"]
                loop.start()
                wait_for(
                    lambda: client.get("/health").json()["peers"]["evaluator"], 20, "evaluator"
                )
                g2 = client.get(f"/adapt/{job.job_id}").json()
                assert g2["state"] == "lost" and g2["source"] == "evaluator"
                assert "restarted" in g2["stop_reason"]
                # and takes new jobs
                _with_snapshot(st, peer, ev2)
                r = client.post("/adapt", json={"budget": 2, "skills": 4, "steps": 10})
                assert r.status_code == 202, r.json()
            finally:
                ev2.rt.stop.set()
                loop.join(timeout=20)
                ev2.close()
    finally:
        api.close()


def test_a1_job_with_any_frozen_joints(stack: tuple[Stack, Any]) -> None:
    """On the A1, a preset damage plus more frozen joints reach the trials' env, with the
    rescue off; the intact map is measured on the undamaged robot."""
    st, peer = stack
    cfg = preset("tiny", "a1")
    args = EvaluatorArgs(
        core=cfg, bus=st.bus, max_steps=500, run=RunConfig(run_id=RUN, root=st.runs)
    )
    ev = Evaluator(args)
    try:
        _with_snapshot(st, peer, ev, d=cfg.skill_dim)
        assert ev.start_adapt(_req(frozen_joints=[12])).error.startswith("invalid:")
        assert ev.start_adapt(_req(frozen_joints=[3, 3])).error.startswith("invalid:")
        job = ev.start_adapt(_req(damage="front_upper", frozen_joints=[10, 4], skills=3))
        assert not job.error, job.error
        assert list(job.request.frozen_joints) == [4, 10] and job.request.damage == "front_upper"
        run = ev.job
        assert run is not None
        env = ev._job_env(run, 0)
        try:
            frozen = env.frozen_joints  # type: ignore[attr-defined]
            assert sorted(frozen) == [1, 4, 10] and not env.config.rescue  # type: ignore[attr-defined]
        finally:
            env.close()
        intact = ev._job_env(None, 0)
        try:
            assert intact.frozen_joints == {}  # type: ignore[attr-defined]
        finally:
            intact.close()
        _run_job(ev)
        done = ev.job_state(job.job_id)
        assert done is not None and done.state == DONE and len(done.trials) >= 1
        assert all(np.isfinite(t.ret) for t in done.trials)
    finally:
        ev.close()
