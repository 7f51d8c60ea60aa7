"""The HTTP API: every route with good and bad input on a fed state, a schemathesis run against
the OpenAPI spec (the harness of ``tests/services/schema.py``), and the app over a real Zenoh
router on loopback."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from proto import codec
from proto import ursa_pb2 as pb
from proto.topics import Topics
from services.api import models as m
from services.api.app import create_app
from services.api.service import ApiArgs, ApiService
from services.api.state import ApiState
from services.common.config import RunConfig
from services.common.live import LiveState
from services.stack import running_stack, wait_for
from tests.services._stack import snapshot_msg, stats_msg
from tests.services.schema import SETTINGS, call_and_validate, openapi_schema
from ursa.bounds import Box
from ursa.config import preset

RUN = "test"


class FakeBackend:
    """Answers like the repertoire and the evaluator would; records what it was asked."""

    def __init__(self) -> None:
        self.samples: list[tuple[int, int | None]] = []
        self.evaluations: list[pb.EvaluateRequest] = []
        self.sample_reply: str = "ok"  # "ok" | "none" | "error"
        self.eval_reply: str = "ok"  # "ok" | "none" | "invalid" | "unavailable" | "nan"
        self.eval_delay_s = 0.0
        self.running = 0
        self.max_running = 0
        self._lock = threading.Lock()

    def header(self) -> pb.Header:
        return codec.header(RUN, "api/main")

    def sample(self, n: int, seed: int | None, timeout_s: float) -> pb.SkillReply | None:
        self.samples.append((n, seed))
        if self.sample_reply == "none":
            return None
        reply = pb.SkillReply(
            header=codec.header(RUN, "repertoire/main"), delta=0.3, snapshot_version=7
        )
        if self.sample_reply == "error":
            reply.error = "repertoire is empty"
        else:
            rng = np.random.default_rng(seed)
            reply.skills.CopyFrom(codec.to_array(rng.normal(size=(n, 2)).astype(np.float32)))
        return reply

    def evaluate(self, req: pb.EvaluateRequest, timeout_s: float) -> pb.EvaluateReply | None:
        with self._lock:
            self.running += 1
            self.max_running = max(self.max_running, self.running)
        try:
            time.sleep(self.eval_delay_s)
            self.evaluations.append(req)
            if self.eval_reply == "none":
                return None
            reply = pb.EvaluateReply(header=codec.header(RUN, "evaluator/eval"))
            if self.eval_reply in ("invalid", "unavailable"):
                reply.error = f"{self.eval_reply}: because"
                return reply
            z = codec.from_array(req.skill)
            achieved = z + 0.01
            if self.eval_reply == "nan":
                achieved = achieved * np.nan
            reply.achieved.CopyFrom(codec.to_array(achieved.astype(np.float32)))
            reply.distance, reply.delta, reply.ret = 0.1, 0.3, 12.5
            reply.violations, reply.steps, reply.policy_version = 3, req.steps, 4
            return reply
        finally:
            with self._lock:
                self.running -= 1

    def bus_status(self) -> dict[str, Any]:
        return {"connected": True, "router": "tcp/127.0.0.1:7447"}


def _state(alive: dict[str, float], backend: FakeBackend | None = None, **kw: Any) -> ApiState:
    live = LiveState(RUN, alive=lambda: dict(alive))
    # the point env's evaluation box: the arena [-1, 1]² widened by its width on each side
    return ApiState(
        live=live, backend=backend, skill_dim=2, skill_box=Box.uniform(2, -3.0, 3.0), **kw
    )


def _alive(*names: str) -> dict[str, float]:
    t = Topics(RUN)
    return {t.alive(*n.split("/")): time.time() for n in names}


@pytest.fixture()
def fed() -> Iterator[tuple[TestClient, ApiState, FakeBackend, dict[str, float]]]:
    """An app with a 50-skill snapshot (ids 10..59, D=2), two collectors, every peer alive."""
    backend = FakeBackend()
    alive = _alive(
        "repertoire/main", "learner/main", "evaluator/eval", "collector/c0", "collector/c1"
    )
    state = _state(alive, backend, damages=("", "none", "front_hip"))
    state.live.on_snapshot(snapshot_msg(50, d=2, id0=10, run_id=RUN))
    for cid in ("c0", "c1", "gone"):
        state.live.on_stats(
            stats_msg(
                "collector",
                cid,
                {
                    "steps": 1234,
                    "steps_per_s": 99.5,
                    "violation_rate": 0.25,
                    "rescues": 2,
                    "return_mean": 0.5,
                    "policy_version": 6,
                    "weird": float("nan"),
                },
                labels={"damage": "none", "env": "point", "skill_source": "kde"},
                arrays={
                    "skill": np.array([0.1, 0.2], np.float32),
                    "nan_array": np.array([1.0, np.inf]),
                },
                run_id=RUN,
            )
        )
    state.live.on_stats(
        stats_msg(
            "learner", "main", {"loss/world_model": 1.5, "policy_lag": float("inf")}, run_id=RUN
        )
    )
    with TestClient(create_app(state), raise_server_exceptions=False) as client:
        yield client, state, backend, alive


def _detail(r: Any) -> str:
    d = r.json()["detail"]
    return d if isinstance(d, str) else " ".join(e["msg"] for e in d)


# ---- reads -----------------------------------------------------------------------------------
def test_skills_are_paged_by_id(fed: Any) -> None:
    client, *_ = fed
    r = client.get("/skills", params={"offset": 45, "limit": 10})
    assert r.status_code == 200
    body = r.json()
    assert body["total"] == 50 and body["dim"] == 2 and body["snapshot_version"] == 1
    assert [s["id"] for s in body["items"]] == [55, 56, 57, 58, 59]
    assert len(body["items"][0]["z"]) == 2
    assert client.get("/skills").json()["limit"] == 100
    assert client.get("/skills", params={"offset": 10**6}).json()["items"] == []
    for bad in ({"limit": 0}, {"limit": 1001}, {"offset": -1}, {"offset": "x"}):
        assert client.get("/skills", params=bad).status_code == 422, bad


def test_get_skill_by_id_and_missing_ids(fed: Any) -> None:
    client, *_ = fed
    r = client.get("/skills/12")
    assert r.status_code == 200 and r.json()["id"] == 12 and r.json()["age"] == 2
    r = client.get("/skills/9")
    assert r.status_code == 404 and "not in the repertoire" in _detail(r)
    assert client.get("/skills/-3").status_code == 404  # not an id: no such resource
    assert client.get("/skills/abc").status_code == 404
    assert client.get(f"/skills/{2**70}").status_code == 422


def test_nearest_uses_the_repertoire_metric(fed: Any) -> None:
    client, state, *_ = fed
    snap = state.live.latest_snapshot()
    z = snap.skills[5]
    r = client.get("/skills/nearest", params={"z": f"{z[0]},{z[1]}", "k": 3})
    assert r.status_code == 200
    res = r.json()["results"]
    assert res[0]["id"] == 15 and res[0]["distance"] == pytest.approx(0.0, abs=1e-9)
    assert [x["distance"] for x in res] == sorted(x["distance"] for x in res)
    # Σ = 0.05·I: Mahalanobis = Euclidean / sqrt(0.05)
    second = np.asarray(res[1]["z"])
    assert res[1]["distance"] == pytest.approx(np.linalg.norm(second - z) / np.sqrt(0.05))
    r2 = client.get(f"/skills/nearest?z={z[0]}&z={z[1]}&k=3")  # repeated parameters
    assert r2.json()["results"] == res


@pytest.mark.parametrize(
    "query,why",
    [
        ("z=0.1", "coordinates"),
        ("z=0.1,0.2,0.3", "coordinates"),
        ("z=0.1&z=0.2&z=0.3", "coordinates"),
        ("z=0.1,0.2&z=0.3", "coordinates"),
        ("z=a,b", "decimal numbers"),
        ("z=0.1,nan", "decimal numbers"),
        ("z=inf,1", "decimal numbers"),
        ("z=", "decimal numbers"),
        ("z=1e999,1", "decimal numbers"),
        ("z=%D9%A3,1", "decimal numbers"),  # a non-ASCII digit: float() reads it, JSON Schema not
        ("z=0.1%0A,0.2", "decimal numbers"),
        ("z=0.1&z=", "decimal numbers"),
        ("", "Field required"),
        ("z=0.1,0.2&k=0", "greater"),
        ("z=0.1,0.2&k=101", "less"),
        ("z=" + ",".join(["1"] * 65), "coordinates"),
    ],
)
def test_nearest_rejects_bad_input(fed: Any, query: str, why: str) -> None:
    client, *_ = fed
    r = client.get(f"/skills/nearest?{query}")
    assert r.status_code == 422 and why in _detail(r), r.json()


def test_sample_is_forwarded_to_the_repertoire(fed: Any) -> None:
    client, _, backend, _ = fed
    r = client.post("/skills/sample", json={"n": 4, "seed": 3})
    assert r.status_code == 200
    body = r.json()
    assert body["source"] == "repertoire" and len(body["skills"]) == 4
    assert backend.samples == [(4, 3)]
    for bad in ({"n": 0}, {"n": 4097}, {"n": "x"}, {"n": 1, "seed": -1}, {"n": 1, "x": 1}):
        assert client.post("/skills/sample", json=bad).status_code == 422, bad
    assert client.post("/skills/sample", content=b"{not json").status_code == 422
    r = client.post(
        "/skills/sample", content=b"\xff\xfe", headers={"content-type": "application/json"}
    )
    assert r.status_code == 422  # FastAPI's 400 for an unparseable body, made a 422
    assert client.post("/skills/sample", json={"n": "2"}).status_code == 422  # strict types
    assert client.get("/skills/sample").status_code == 405


def test_sample_falls_back_to_the_snapshot_kde(fed: Any) -> None:
    client, state, backend, _ = fed
    backend.sample_reply = "none"  # the repertoire does not answer
    a = client.post("/skills/sample", json={"n": 5, "seed": 11}).json()
    b = client.post("/skills/sample", json={"n": 5, "seed": 11}).json()
    assert a["source"] == "snapshot" and a["skills"] == b["skills"]  # seeded: reproducible
    backend.sample_reply = "error"
    assert client.post("/skills/sample", json={"n": 1}).json()["source"] == "snapshot"
    state.live.snapshot = None
    r = client.post("/skills/sample", json={"n": 1})
    assert r.status_code == 503 and "repertoire is empty" in _detail(r)


def test_collectors_and_stats(fed: Any) -> None:
    client, *_ = fed
    cs = client.get("/collectors").json()
    assert [c["id"] for c in cs] == ["c0", "c1"]  # "gone" has stats but no liveliness token
    c0 = cs[0]
    assert c0["steps"] == 1234 and c0["steps_per_s"] == 99.5 and c0["rescues"] == 2
    assert c0["violation_rate"] == 0.25 and c0["damage"] == "none"
    assert c0["skill"] == pytest.approx([0.1, 0.2]) and c0["policy_version"] == 6
    services = client.get("/stats").json()["services"]
    by = {(s["service"], s["id"]): s for s in services}
    assert by[("collector", "gone")]["alive"] is False and by[("collector", "c0")]["alive"]
    assert by[("collector", "c0")]["scalars"]["weird"] is None  # NaN -> null, never a 500
    assert by[("collector", "c0")]["arrays"]["nan_array"] == [1.0, None]
    assert by[("learner", "main")]["scalars"]["policy_lag"] is None


def test_health_reports_the_bus_and_missing_peers(fed: Any) -> None:
    client, state, _, alive = fed
    h = client.get("/health").json()
    assert h["status"] == "ok" and h["problems"] == [] and h["bus"]["connected"]
    assert h["peers"]["collectors"] == ["c0", "c1"] and h["snapshot"]["size"] == 50
    alive.clear()
    state.live.snapshot = None
    r = client.get("/health")
    assert r.status_code == 200
    h = r.json()
    assert h["status"] == "degraded"
    assert {
        "no learner alive",
        "no repertoire alive",
        "no evaluator alive",
        "no repertoire snapshot yet",
    } <= set(h["problems"])


def test_reads_without_a_snapshot_answer_503() -> None:
    state = _state({}, None)
    with TestClient(create_app(state), raise_server_exceptions=False) as client:
        for path in ("/skills", "/skills/1", "/skills/nearest?z=1,2"):
            r = client.get(path)
            assert r.status_code == 503 and "no repertoire snapshot" in _detail(r), path
        r = client.post("/skills/sample", json={"n": 1})
        assert r.status_code == 503
        assert client.get("/skills/nearest?z=a").status_code == 422  # bad input: 422 first
        h = client.get("/health").json()
        assert not h["bus"]["connected"] and "zenoh router not reachable" in h["problems"]
        assert client.get("/collectors").json() == []
        assert client.get("/docs").status_code == 200
        assert "/evaluate" in client.get("/openapi.json").json()["paths"]


# ---- evaluations -----------------------------------------------------------------------------
def test_evaluate_by_id_and_by_coordinates(fed: Any) -> None:
    client, state, backend, _ = fed
    r = client.post("/evaluate", json={"skill": 12, "steps": 300, "damage": "front_hip", "seed": 5})
    assert r.status_code == 200, r.json()
    body = r.json()
    snap = state.live.latest_snapshot()
    assert body["skill_id"] == 12 and body["target"] == pytest.approx(snap.skills[2].tolist())
    assert body["achieved"] == pytest.approx((snap.skills[2] + 0.01).tolist(), abs=1e-6)
    assert body["within_delta"] and body["violations"] == 3 and body["steps"] == 300
    assert body["violation_rate"] == pytest.approx(0.01) and body["policy_version"] == 4
    req = backend.evaluations[-1]
    assert req.steps == 300 and req.damage == "front_hip" and req.has_seed and req.seed == 5
    r = client.post("/evaluate", json={"skill": [0.5, -0.5]})
    assert r.status_code == 200 and r.json()["skill_id"] is None and r.json()["steps"] == 250
    assert backend.evaluations[-1].damage == "" and not backend.evaluations[-1].has_seed


@pytest.mark.parametrize(
    "body,status,why",
    [
        ({"skill": 9}, 404, "not in the repertoire"),
        ({"skill": [0.1, 0.2, 0.3]}, 422, "at most 2 items"),
        ({"skill": []}, 422, "at least 2 items"),
        ({"skill": [0.1, 3.5]}, 422, "outside [-3, 3]"),
        ({"skill": [0.1, None]}, 422, "valid number"),
        ({"skill": 12, "steps": 0}, 422, "greater"),
        ({"skill": 12, "steps": 5001}, 422, "less than or equal to 5000"),
        ({"skill": 12, "damage": "tail"}, 422, "unknown damage"),
        ({"skill": 12, "seed": -1}, 422, "greater"),
        ({"skill": -1}, 422, ""),
        ({"skill": 1.5}, 422, ""),
        ({"skill": "abc"}, 422, ""),
        ({"steps": 10}, 422, "Field required"),
        ({"skill": 12, "bogus": 1}, 422, "Extra inputs"),
    ],
)
def test_evaluate_rejects_bad_input(fed: Any, body: dict[str, Any], status: int, why: str) -> None:
    client, _, backend, _ = fed
    r = client.post("/evaluate", json=body)
    assert r.status_code == status and why in _detail(r), r.json()
    assert backend.evaluations == []


def test_evaluate_answers_503_when_the_evaluator_is_missing_or_fails(fed: Any) -> None:
    client, state, backend, alive = fed
    for mode, status, why in [
        ("none", 503, "did not answer"),
        ("unavailable", 503, "because"),
        ("invalid", 422, "because"),
        ("nan", 503, "non-finite"),
    ]:
        backend.eval_reply = mode
        r = client.post("/evaluate", json={"skill": 12, "steps": 10})
        assert r.status_code == status and why in _detail(r), (mode, r.json())
    for key in [k for k in alive if "/evaluator/" in k]:
        alive.pop(key)
    r = client.post("/evaluate", json={"skill": 12})
    assert r.status_code == 503 and "no evaluator alive" in _detail(r)
    state.live.snapshot = None
    r = client.post("/evaluate", json={"skill": 12})
    assert r.status_code == 503 and "no repertoire snapshot" in _detail(r)
    no_bus = _state(_alive("evaluator/eval"), None)
    with TestClient(create_app(no_bus)) as c2:
        r = c2.post("/evaluate", json={"skill": [0.0, 0.0]})
        assert r.status_code == 503 and "no bus" in _detail(r)
        assert c2.post("/evaluate", json={"skill": [0.0]}).status_code == 422  # config's D


def test_evaluations_run_one_at_a_time(fed: Any) -> None:
    client, state, backend, _ = fed
    backend.eval_delay_s = 0.2
    codes: list[int] = []

    def one() -> None:
        codes.append(client.post("/evaluate", json={"skill": 12, "steps": 5}).status_code)

    threads = [threading.Thread(target=one) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert codes == [200] * 4 and backend.max_running == 1
    state.eval_wait_s = 0.05
    backend.eval_delay_s = 0.5
    slow = threading.Thread(target=one)
    slow.start()
    time.sleep(0.1)
    r = client.post("/evaluate", json={"skill": 12, "steps": 5})
    slow.join()
    assert r.status_code == 503 and "busy" in _detail(r)


# ---- property-based: no 500 anywhere in the spec -----------------------------------------
def _schemathesis_app() -> Any:
    backend = FakeBackend()
    state = _state(
        _alive("repertoire/main", "evaluator/eval", "collector/c0"),
        backend,
        damages=("", "none", "front_hip"),
    )
    state.live.on_snapshot(snapshot_msg(30, d=2, id0=0, run_id=RUN))
    state.live.on_stats(
        stats_msg(
            "collector",
            "c0",
            {"steps": 1, "x": float("nan")},
            arrays={"skill": np.zeros(2, np.float32)},
            run_id=RUN,
        )
    )
    return create_app(state)


SCHEMA = openapi_schema(_schemathesis_app())


@SCHEMA.parametrize()
@SETTINGS
def test_openapi_property_based_no_server_errors(case: Any) -> None:
    """Every schemathesis check, "schema-valid data is accepted" included (the schema states
    every bound the API enforces: the skill dimension and box of the run, the damages, the
    ranges), and ours: never a 500, and a reason with every 422."""
    call_and_validate(case)


# ---- every bound: just inside is accepted, just outside is a 422 naming the field ------------
_BIG = m.MAX_SEED
_E = {"skill": 12}  # a skill of the fed repertoire


@pytest.mark.parametrize(
    "method,path,inside,outside,field",
    [
        ("GET", "/skills", {"offset": 10**9}, {"offset": 10**9 + 1}, "offset"),
        ("GET", "/skills", {"offset": 0}, {"offset": -1}, "offset"),
        ("GET", "/skills", {"limit": 1}, {"limit": 0}, "limit"),
        ("GET", "/skills", {"limit": 1000}, {"limit": 1001}, "limit"),
        ("GET", f"/skills/{_BIG}", None, None, "skill_id"),  # outside: _BIG + 1 (below)
        ("GET", "/skills/nearest", {"z": "0.1,0.2", "k": 1}, {"z": "0.1,0.2", "k": 0}, "k"),
        ("GET", "/skills/nearest", {"z": "0.1,0.2", "k": 100}, {"z": "0.1,0.2", "k": 101}, "k"),
        ("GET", "/skills/nearest", {"z": ["0.1", "0.2"]}, {"z": ["0.1"]}, "z"),
        ("GET", "/skills/nearest", {"z": "0.1,0.2"}, {"z": "0.1,0.2,0.3"}, "z"),
        ("GET", "/skills/nearest", {"z": "1e99,-1e-999"}, {"z": "1e100,1"}, "z"),
        ("GET", "/skills/nearest", {"z": "9" * 100 + ",1"}, {"z": "9" * 101 + ",1"}, "z"),
        (
            "GET",
            "/skills/nearest",
            {"z": " " * (4096 - 3) + "1,2"},
            {"z": " " * (4096 - 2) + "1,2"},
            "z",
        ),
        ("POST", "/skills/sample", {"n": 1}, {"n": 0}, "n"),
        ("POST", "/skills/sample", {"n": 4096}, {"n": 4097}, "n"),
        ("POST", "/skills/sample", {"seed": 0}, {"seed": -1}, "seed"),
        ("POST", "/skills/sample", {"seed": _BIG}, {"seed": _BIG + 1}, "seed"),
        ("POST", "/evaluate", {**_E, "steps": 1}, {**_E, "steps": 0}, "steps"),
        ("POST", "/evaluate", {**_E, "steps": 5000}, {**_E, "steps": 5001}, "steps"),
        ("POST", "/evaluate", {**_E, "seed": 0}, {**_E, "seed": -1}, "seed"),
        ("POST", "/evaluate", {**_E, "seed": _BIG}, {**_E, "seed": _BIG + 1}, "seed"),
        ("POST", "/evaluate", {"skill": 0}, {"skill": -1}, "skill"),
        ("POST", "/evaluate", {"skill": _BIG}, {"skill": _BIG + 1}, "skill"),
        ("POST", "/evaluate", {"skill": [3.0, -3.0]}, {"skill": [3.0000001, -3.0]}, "skill"),
        ("POST", "/evaluate", {"skill": [-3.0, 3.0]}, {"skill": [-3.0, 3.0000001]}, "skill"),
        ("POST", "/evaluate", {"skill": [0.0, 0.0]}, {"skill": [0.0]}, "skill"),
        ("POST", "/evaluate", {"skill": [0.0, 0.0]}, {"skill": [0.0, 0.0, 0.0]}, "skill"),
        ("POST", "/evaluate", {**_E, "damage": "front_hip"}, {**_E, "damage": "tail"}, "damage"),
        ("POST", "/evaluate", {**_E, "damage": None}, {**_E, "damage": 3}, "damage"),
    ],
)
def test_every_bound_just_inside_and_just_outside(
    fed: Any, method: str, path: str, inside: Any, outside: Any, field: str
) -> None:
    """Just inside a bound is accepted (not 422: a 404 for an id that is valid but absent),
    just outside is a 422 whose reason names the field."""
    client, *_ = fed

    def call(arg: Any, p: str = path) -> Any:
        if method == "GET":
            return client.get(p, params=arg)
        return client.post(p, json=arg)

    if field == "skill_id":
        r_in, r_out = client.get(f"/skills/{_BIG}"), client.get(f"/skills/{_BIG + 1}")
    else:
        r_in, r_out = call(inside), call(outside)
    assert r_in.status_code in (200, 404), (inside, r_in.json())
    assert r_out.status_code == 422, (outside, r_out.json())
    detail = r_out.json()["detail"]
    assert any(field in e["loc"] and e["msg"] for e in detail), detail


def test_the_schema_states_the_bounds(fed: Any) -> None:
    """The bounds the test above probes are the ones the OpenAPI schema states."""
    client, *_ = fed
    spec = client.get("/openapi.json").json()
    body = spec["components"]["schemas"]
    ev = body["EvaluateRequest"]["properties"]
    skill_id, coords = ev["skill"]["oneOf"]
    assert skill_id == {"type": "integer", "minimum": 0, "maximum": _BIG}
    assert coords["minItems"] == coords["maxItems"] == 2 and coords["items"] is False
    assert coords["prefixItems"] == [{"type": "number", "minimum": -3.0, "maximum": 3.0}] * 2
    assert (ev["steps"]["minimum"], ev["steps"]["maximum"]) == (1, 5000)
    assert ev["damage"]["anyOf"][0]["enum"] == ["", "none", "front_hip"]
    assert ev["seed"]["anyOf"][0] == {"type": "integer", "minimum": 0, "maximum": _BIG}
    n = body["SampleRequest"]["properties"]["n"]
    assert (n["minimum"], n["maximum"]) == (1, 4096) and isinstance(n["maximum"], int)
    params = {
        (path, p["name"]): p["schema"]
        for path, ops in spec["paths"].items()
        for op in ops.values()
        for p in op.get("parameters", [])
    }
    repeated, joined = params[("/skills/nearest", "z")]["anyOf"]
    assert repeated["minItems"] == repeated["maxItems"] == 2
    assert joined["minItems"] == joined["maxItems"] == 1 and joined["items"]["maxLength"] == 4096
    assert params[("/skills/{skill_id}", "skill_id")]["maximum"] == _BIG
    assert (params[("/skills", "limit")]["minimum"], params[("/skills", "limit")]["maximum"]) == (
        1,
        1000,
    )


# ---- over a real router ----------------------------------------------------------------------
def test_api_over_a_real_router(tmp_path: Path) -> None:
    """The API's own bus wiring: snapshot and stats arrive, liveliness shows peers, and sample
    and evaluate requests travel as Zenoh queries to whoever serves them."""
    with running_stack(tmp_path, run_id=RUN) as st:
        st.start_router()
        peer = st.session()
        t = st.topics
        # the point env's config: its snapshots (D = 2) pass the API's semantic check at decode
        core = preset("tiny", env="point")
        svc = ApiService(ApiArgs(core=core, bus=st.bus, run=RunConfig(run_id=RUN, root=st.runs)))
        handles: list[Any] = []
        try:
            with TestClient(svc.app) as client:
                r = client.get("/health")
                assert r.status_code == 200 and r.json()["bus"]["connected"]
                assert client.get("/skills").status_code == 503

                handles.append(peer.liveliness().declare_token(t.alive("repertoire", "main")))
                handles.append(peer.liveliness().declare_token(t.alive("evaluator", "eval")))
                handles.append(peer.liveliness().declare_token(t.alive("collector", "c7")))

                def on_sample(q: Any) -> None:
                    req = codec.decode(pb.SkillRequest, q.payload.to_bytes())
                    z = np.full((req.n, 2), 0.5, np.float32)
                    q.reply(
                        t.sample,
                        codec.encode(
                            pb.SkillReply(
                                header=codec.header(RUN, "repertoire/main"),
                                skills=codec.to_array(z),
                                delta=0.3,
                                snapshot_version=1,
                            )
                        ),
                    )

                def on_eval(q: Any) -> None:
                    req = codec.decode(pb.EvaluateRequest, q.payload.to_bytes())
                    q.reply(
                        t.evaluate,
                        codec.encode(
                            pb.EvaluateReply(
                                header=codec.header(RUN, "evaluator/eval"),
                                achieved=req.skill,
                                distance=0.0,
                                delta=0.3,
                                ret=1.0,
                                steps=req.steps,
                            )
                        ),
                    )

                handles.append(peer.declare_queryable(t.sample, on_sample))
                handles.append(peer.declare_queryable(t.evaluate, on_eval))
                peer.put(t.snapshot, codec.encode(snapshot_msg(20, d=2, run_id=RUN)))
                peer.put(
                    t.collector_stats("c7"),
                    codec.encode(
                        stats_msg(
                            "collector", "c7", {"steps": 5, "violation_rate": 0.5}, run_id=RUN
                        )
                    ),
                )
                wait_for(lambda: client.get("/skills").status_code == 200, 10, "the snapshot")
                wait_for(
                    lambda: [c["steps"] for c in client.get("/collectors").json()] == [5],
                    10,
                    "the collector's stats",
                )
                r = client.post("/skills/sample", json={"n": 3})
                assert r.json() == {
                    "skills": [[0.5, 0.5]] * 3,
                    "source": "repertoire",
                    "delta": 0.3,
                    "snapshot_version": 1,
                }
                r = client.post("/evaluate", json={"skill": 3, "steps": 20})
                assert r.status_code == 200 and r.json()["steps"] == 20
                # the schema states the config's skill box (point env: [-3, 3]²)
                spec = client.get("/openapi.json").json()
                coords = spec["components"]["schemas"]["EvaluateRequest"]["properties"]["skill"]
                assert coords["oneOf"][1]["prefixItems"][1] == {
                    "type": "number",
                    "minimum": -3.0,
                    "maximum": 3.0,
                }
                r = client.post("/evaluate", json={"skill": [0.5, 3.5], "steps": 20})
                assert r.status_code == 422 and "skill box" in _detail(r)
                h = client.get("/health").json()
                assert h["peers"]["repertoire"] == ["main"] and h["peers"]["collectors"] == ["c7"]
                # a malformed snapshot is counted and dropped, never served
                peer.put(t.snapshot, b"\x00garbage")
                wait_for(lambda: svc.rt.drops.total >= 1, 10, "the drop to be counted")
                assert client.get("/skills").json()["total"] == 20
        finally:
            for h in handles:
                h.undeclare()
            peer.close()
            svc.close()
