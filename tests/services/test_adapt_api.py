"""``POST /adapt`` and ``GET /adapt/{id}`` on an in-process app with a fake evaluator: what is
forwarded, each refusal's status (422 with the field, 409 busy, 503 missing peer, 404 unknown
job), lost jobs from the run directory, every bound just inside and just outside, the schema
stating them, and a schemathesis run over the two routes (never a 500, every 422 a reason,
schema-valid data accepted; the harness of ``tests/services/schema.py``)."""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient
from google.protobuf import json_format

from proto import codec
from proto import ursa_pb2 as pb
from proto.topics import Topics
from services.api.app import create_app
from services.api.state import ApiState
from services.common.live import LiveState
from tests.services.schema import SETTINGS, call_and_validate, openapi_schema
from ursa.bounds import Box

RUN = "test"
JOB = "00000000000000aa"


class FakeEvaluator:
    """Answers adaptation requests as an evaluator would; records them."""

    def __init__(self) -> None:
        self.requests: list[tuple[pb.AdaptRequest, str]] = []
        self.reply = "ok"  # ok | busy | invalid | unavailable | none
        self.jobs: dict[str, pb.AdaptJob] = {}

    def header(self) -> pb.Header:
        return codec.header(RUN, "api/main")

    def adapt(self, req: pb.AdaptRequest, evaluator: str, timeout_s: float) -> pb.AdaptJob | None:
        self.requests.append((req, evaluator))
        if self.reply == "none":
            return None
        job = pb.AdaptJob(header=codec.header(RUN, f"evaluator/{evaluator}"))
        if self.reply != "ok":
            job.error = f"{self.reply}: because"
            return job
        job.job_id = f"{len(self.requests):016x}"
        job.evaluator_id, job.state = evaluator, "mapping"
        job.request.CopyFrom(req)
        job.request.skills = req.skills or 5
        job.map_skills.CopyFrom(codec.to_array(np.zeros((5, 2), np.float32)))
        job.map_ids.CopyFrom(codec.to_array(np.arange(5, dtype=np.int64)))
        job.chosen_skill_id = job.predicted_best_id = -1
        job.created = job.updated = time.time()
        self.jobs[job.job_id] = job
        return job

    def adapt_job(self, job_id: str, timeout_s: float) -> pb.AdaptJob | None:
        return self.jobs.get(job_id)


def _done_job(eid: str = "eval", state: str = "done") -> pb.AdaptJob:
    job = pb.AdaptJob(
        header=codec.header(RUN, f"evaluator/{eid}"),
        job_id=JOB,
        evaluator_id=eid,
        state=state,
        stop_reason="threshold" if state == "done" else "",
        request=pb.AdaptRequest(budget=3, alpha=0.9, kappa=0.05, length_scale=1, noise=1e-3),
        map_skills=codec.to_array(np.array([[0.0, 0.0], [1.0, 1.0], [2.0, 0.5]], np.float32)),
        map_ids=codec.to_array(np.array([7, 8, 9], np.int64)),
        map_returns=codec.to_array(np.array([1.0, 3.0, 2.0])),
        mapped=3,
        chosen_skill_id=9,
        chosen_return=2.5,
        predicted_best_id=9,
        predicted_best_mean=2.6,
        created=time.time() - 60,
        updated=time.time() - 30,
    )
    for row, sid, ret in ((1, 8, 0.5), (2, 9, 2.5)):
        job.trials.append(
            pb.AdaptJob.Trial(
                row=row,
                skill_id=sid,
                skill=codec.to_array(np.asarray(codec.from_array(job.map_skills))[row]),
                ret=ret,
                achieved=codec.to_array(np.array([0.1, 0.2], np.float32)),
                predicted=3.0,
                predicted_best_id=9,
                predicted_best_mean=2.6,
            )
        )
    return job


def _state(alive: list[str], fake: FakeEvaluator | None, jobs_dir: Path | None) -> ApiState:
    t = Topics(RUN)
    tokens = {t.alive("evaluator", e): time.time() for e in alive}
    return ApiState(
        live=LiveState(RUN, alive=lambda: dict(tokens)),
        skill_dim=2,
        skill_box=Box.uniform(2, -3.0, 3.0),
        env="a1",
        damages=("", "none", "front_hip", "back_lower"),
        adapt_backend=fake,
        joints=12,
        jobs_dir=jobs_dir,
        max_adapt_budget=100,
        max_adapt_skills=1000,
        max_eval_steps=5000,
    )


@pytest.fixture()
def app(tmp_path: Path) -> Iterator[tuple[TestClient, FakeEvaluator, Path]]:
    fake = FakeEvaluator()
    jobs = tmp_path / "jobs"
    with TestClient(
        create_app(_state(["eval", "e2"], fake, jobs)), raise_server_exceptions=False
    ) as client:
        yield client, fake, jobs


def test_post_forwards_the_request_and_answers_202(app: Any) -> None:
    client, fake, _ = app
    r = client.post(
        "/adapt",
        json={"damage": "front_hip", "frozen_joints": [4, 11], "budget": 7, "alpha": 0.8},
    )
    assert r.status_code == 202, r.json()
    body = r.json()
    assert body["state"] == "mapping" and body["evaluator"] == "e2"  # sorted: "e2" < "eval"
    req, eid = fake.requests[-1]
    assert eid == "e2" and req.damage == "front_hip" and list(req.frozen_joints) == [4, 11]
    assert (req.budget, req.alpha, req.kappa, req.skills, req.steps) == (7, 0.8, 0.05, 0, 0)
    assert not req.has_seed
    r = client.post("/adapt", json={"evaluator": "eval", "seed": 9, "skills": 3, "steps": 40})
    req, eid = fake.requests[-1]
    assert r.status_code == 202 and eid == "eval" and req.seed == 9 and req.has_seed
    assert (req.skills, req.steps) == (3, 40)
    got = client.get(f"/adapt/{body['job_id']}").json()
    assert got["job_id"] == body["job_id"] and got["source"] == "evaluator"


@pytest.mark.parametrize(
    "reply,status", [("busy", 409), ("invalid", 422), ("unavailable", 503), ("none", 503)]
)
def test_refusals(app: Any, reply: str, status: int) -> None:
    client, fake, _ = app
    fake.reply = reply
    r = client.post("/adapt", json={})
    assert r.status_code == status, r.json()
    if status != 422:
        assert r.json()["detail"]


def test_no_evaluator_is_503(tmp_path: Path) -> None:
    with TestClient(create_app(_state([], FakeEvaluator(), None))) as client:
        r = client.post("/adapt", json={})
        assert r.status_code == 503 and "no evaluator" in r.json()["detail"]
        r = client.post("/adapt", json={"evaluator": "eval"})
        assert r.status_code == 503
    with TestClient(create_app(_state(["e2"], FakeEvaluator(), None))) as client:
        r = client.post("/adapt", json={"evaluator": "eval"})
        assert r.status_code == 404 and "not alive" in r.json()["detail"]


def test_a_job_is_read_from_the_run_dir_and_reported_lost_when_its_evaluator_is_gone(
    app: Any,
) -> None:
    client, _, jobs = app
    assert client.get(f"/adapt/{JOB}").status_code == 404
    jobs.mkdir()
    running = _done_job("gone", state="adapting")
    (jobs / f"{JOB}.json").write_text(json_format.MessageToJson(running))
    g = client.get(f"/adapt/{JOB}").json()
    assert g["state"] == "lost" and g["source"] == "run_dir" and "gone" in g["stop_reason"]
    assert g["mapped"] == 3 and [t["ret"] for t in g["trials"]] == [0.5, 2.5]
    # a finished job's file is reported as it is, trials and all
    (jobs / f"{JOB}.json").write_text(json_format.MessageToJson(_done_job("gone")))
    g = client.get(f"/adapt/{JOB}").json()
    assert g["state"] == "done" and g["stop_reason"] == "threshold"
    assert g["chosen"] == {"skill_id": 9, "skill": [2.0, 0.5], "value": 2.5}
    assert g["predicted_best"]["skill_id"] == 9 and g["trials"][1]["trial"] == 2
    assert g["trials"][0]["skill"] == [1.0, 1.0] and g["params"]["budget"] == 3
    # a job of a live evaluator that does not answer is reported as last seen, not lost
    (jobs / f"{JOB}.json").write_text(json_format.MessageToJson(_done_job("eval", "adapting")))
    g = client.get(f"/adapt/{JOB}").json()
    assert g["state"] == "adapting" and g["source"] == "run_dir"


def test_a_corrupt_job_file_is_no_500(app: Any) -> None:
    client, _, jobs = app
    jobs.mkdir()
    job = _done_job("eval")  # alive, but it does not answer for the job: its file is read
    job.state = "dancing"
    job.trials[0].ret = float("nan")
    job.map_skills.data = b"\x00"  # not (3, 2) float32 any more
    (jobs / f"{JOB}.json").write_text(json_format.MessageToJson(job))
    r = client.get(f"/adapt/{JOB}")
    assert r.status_code == 200, r.text
    g = r.json()
    assert g["state"] == "failed" and g["trials"][0]["ret"] is None
    assert g["chosen"]["skill"] == []  # coordinates unknown, the id still reported
    (jobs / f"{JOB}.json").write_text("{not json")
    assert client.get(f"/adapt/{JOB}").status_code == 404


_B = 2**53 - 1


@pytest.mark.parametrize(
    "inside,outside,field",
    [
        ({"budget": 1}, {"budget": 0}, "budget"),
        ({"budget": 100}, {"budget": 101}, "budget"),
        ({"alpha": 1.0}, {"alpha": 1.0000001}, "alpha"),
        ({"alpha": 1e-9}, {"alpha": 0.0}, "alpha"),
        ({"kappa": 0.0}, {"kappa": -1e-9}, "kappa"),
        ({"kappa": 100.0}, {"kappa": 100.1}, "kappa"),
        ({"length_scale": 1e-9}, {"length_scale": 0.0}, "length_scale"),
        ({"length_scale": 1000.0}, {"length_scale": 1000.1}, "length_scale"),
        ({"noise": 1e-12}, {"noise": 0.0}, "noise"),
        ({"noise": 1000.0}, {"noise": 1001.0}, "noise"),
        ({"skills": 1}, {"skills": 0}, "skills"),
        ({"skills": 1000}, {"skills": 1001}, "skills"),
        ({"steps": 1}, {"steps": 0}, "steps"),
        ({"steps": 5000}, {"steps": 5001}, "steps"),
        ({"seed": _B}, {"seed": _B + 1}, "seed"),
        ({"seed": 0}, {"seed": -1}, "seed"),
        ({"frozen_joints": [0, 11]}, {"frozen_joints": [12]}, "frozen_joints"),
        ({"frozen_joints": [3]}, {"frozen_joints": [3, 3]}, "frozen_joints"),
        ({"frozen_joints": list(range(12))}, {"frozen_joints": [-1]}, "frozen_joints"),
        ({"damage": "back_lower"}, {"damage": "tail"}, "damage"),
        ({"damage": None}, {"damage": 1}, "damage"),
        ({"evaluator": "eval"}, {"evaluator": "e/v"}, "evaluator"),
        ({"budget": 5}, {"budget": "5"}, "budget"),
        ({}, {"extra": 1}, "extra"),
    ],
)
def test_every_bound_just_inside_and_just_outside(
    app: Any, inside: dict[str, Any], outside: dict[str, Any], field: str
) -> None:
    client, *_ = app
    r_in, r_out = client.post("/adapt", json=inside), client.post("/adapt", json=outside)
    assert r_in.status_code == 202, (inside, r_in.json())
    assert r_out.status_code == 422, (outside, r_out.json())
    assert any(field in e["loc"] and e["msg"] for e in r_out.json()["detail"]), r_out.json()


def test_malformed_job_ids_are_422(app: Any) -> None:
    client, *_ = app
    for bad in ("xyz", "0" * 15, "0" * 17, "ABCDEF0123456789"):
        r = client.get(f"/adapt/{bad}")
        assert r.status_code == 422 and r.json()["detail"][0]["loc"][-1] == "job_id", bad


def test_the_schema_states_the_bounds(app: Any) -> None:
    client, *_ = app
    spec = client.get("/openapi.json").json()
    p = spec["components"]["schemas"]["AdaptRequest"]["properties"]
    assert (p["budget"]["minimum"], p["budget"]["maximum"]) == (1, 100)
    assert p["alpha"]["exclusiveMinimum"] == 0 and p["alpha"]["maximum"] == 1
    assert p["noise"]["exclusiveMinimum"] == 0 and p["length_scale"]["maximum"] == 1000
    assert p["frozen_joints"] == {
        "type": "array",
        "items": {"type": "integer", "minimum": 0, "maximum": 11},
        "maxItems": 12,
        "uniqueItems": True,
        "description": p["frozen_joints"]["description"],
        "title": "Frozen Joints",
    }
    assert p["damage"]["anyOf"][0]["enum"] == ["", "none", "front_hip", "back_lower"]
    assert p["skills"]["anyOf"][0] == {"type": "integer", "minimum": 1, "maximum": 1000}
    post = spec["paths"]["/adapt"]["post"]
    assert {"202", "404", "409", "422", "503"} <= set(post["responses"])
    get = spec["paths"]["/adapt/{job_id}"]["get"]
    assert get["parameters"][0]["schema"]["pattern"] == "^[0-9a-f]{16}$"


def test_without_an_adaptation_backend_there_are_no_adapt_routes() -> None:
    with TestClient(create_app(_state(["eval"], None, None))) as client:
        assert "/adapt" not in client.get("/openapi.json").json()["paths"]


def _schemathesis_app() -> Any:
    fake = FakeEvaluator()
    fake.jobs[JOB] = _done_job()
    return create_app(_state(["eval"], fake, None))


SCHEMA = openapi_schema(_schemathesis_app(), path_regex="^/adapt")


@SCHEMA.parametrize()
@SETTINGS
def test_openapi_property_based_adapt_routes(case: Any) -> None:
    call_and_validate(case)
