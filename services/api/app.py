"""The FastAPI app: skills, collectors, stats, health and evaluations of a live URSA run.

Built by :func:`create_app` from an :class:`~services.api.state.ApiState`, so tests can feed it
snapshots and stats without a bus. Status codes: 422 for any invalid input (with the reason, in
FastAPI's validation-error shape), 404 for a skill id that is not in the repertoire, 503 when a
peer is missing (no snapshot yet, no evaluator alive, the repertoire or evaluator not
answering). A client's mistake never gets a 500.

The OpenAPI schema states every bound the routes enforce, so a schema-valid request is never a
422: the request models are built per app from the config (skill dimension and box, damages,
maximum steps and samples), and :func:`create_app` writes into FastAPI's schema what FastAPI
cannot (integer bounds as integers, the count and pattern of ``z``).
"""

# No ``from __future__ import annotations`` here: FastAPI must resolve the request models that
# create_app defines locally (their bounds come from the config).

import math
import re
import time
from typing import Annotated, Any, NoReturn

import numpy as np
from fastapi import FastAPI, HTTPException, Path, Query, Request
from fastapi.exception_handlers import http_exception_handler
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from google.protobuf import json_format
from pydantic import (
    AfterValidator,
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Discriminator,
    Field,
    Tag,
    WithJsonSchema,
)
from starlette.exceptions import HTTPException as StarletteHTTPException

from proto import codec
from proto import ursa_pb2 as pb
from services.api import models as m
from services.api.state import ApiState
from services.common.live import SnapshotView, StatsEntry, finite
from ursa.bounds import Box
from ursa.kde import kde_sample

SERVICES = ("repertoire", "learner", "evaluator", "dashboard", "api")
JOB_STATES = ("mapping", "adapting", "done", "failed", "lost")
MAX_ARRAY_ITEMS = 4096

DESCRIPTION = """\
Query the skills of a live URSA run, list its collectors, read every service's latest stats,
run a skill on the evaluation collector, and adapt to damage (Intelligent Trial and Error over
the repertoire, ``POST /adapt``).

The API is its own process (``python -m services.api``): it keeps the latest repertoire
snapshot and stats from the Zenoh bus, answers reads from them, and forwards
``POST /skills/sample`` to the repertoire's sample queryable, ``POST /evaluate`` and
``POST /adapt`` to the evaluator's. 422: invalid input; 404: unknown skill or job; 409: the
evaluator already runs an adaptation; 503: a peer is missing.

This schema states every bound the API enforces, from the run's config (skill dimension and
box, damages, ranges): a request valid against it is never answered 422.
"""


def invalid(where: tuple[str | int, ...], msg: str, value: Any = None) -> NoReturn:
    """Raise a 422 in FastAPI's own validation-error shape."""
    raise RequestValidationError(
        [{"loc": where, "msg": msg, "type": "value_error", "input": value}]
    )


def unavailable(reason: str) -> NoReturn:
    raise HTTPException(503, detail=reason, headers={"Retry-After": "5"})


def skill_out(snap: SnapshotView, row: int) -> m.Skill:
    return m.Skill(
        id=int(snap.ids[row]),
        z=[float(v) for v in snap.skills[row]],
        age=int(snap.ages[row]),
        nn_distance=finite(float(snap.nn_dist[row])),
    )


def jsonable_array(a: np.ndarray) -> Any:
    """A small array as nested lists (non-finite floats as null); a large one as its shape."""
    if a.size > MAX_ARRAY_ITEMS:
        return {"shape": list(a.shape), "dtype": str(a.dtype), "omitted": True}
    if a.dtype.kind == "f":
        if a.ndim == 0:
            return finite(float(a))
        return [jsonable_array(row) for row in a]
    return a.tolist()


_NUM = r" *[-+]?([0-9]{1,100}(\.[0-9]*)?|\.[0-9]+)([eE](-[0-9]{1,3}|\+?[0-9]{1,2}))? *"
"""One coordinate of ``z``: a decimal number, at most 100 digits before the point and an exponent
of at most 99, so that it is always finite (below 1e200). ASCII digits and spaces only (JSON
Schema's ``\\d`` and ``\\s`` are ASCII, Python's are not)."""
Z_MAX_LENGTH = 4096
"""Longest value of one ``z`` parameter."""
_ONE = re.compile(_NUM)
_MANY = re.compile(f"{_NUM}(,{_NUM})*")


def z_schema(dim: int | None) -> dict[str, Any]:
    """The JSON Schema of ``z`` in ``/skills/nearest``: ``dim`` coordinates, either as ``dim``
    repeated values (``z=0.1&z=0.2``) or as one comma-separated value (``z=0.1,0.2``)."""

    def strings(pattern: str, n_lo: int, n_hi: int | None) -> dict[str, Any]:
        out: dict[str, Any] = {
            "type": "array",
            "items": {"type": "string", "pattern": f"^{pattern}$", "maxLength": Z_MAX_LENGTH},
            "minItems": n_lo,
        }
        if n_hi is not None:
            out["maxItems"] = n_hi
        return out

    if dim is None:  # unknown until a snapshot arrives: any count, checked then
        return strings(f"{_NUM}(,{_NUM})*", 1, None)
    repeated = strings(_NUM, dim, dim)
    if dim == 1:
        return repeated
    return {"anyOf": [repeated, strings(f"{_NUM}(,{_NUM}){{{dim - 1}}}", 1, 1)]}


def parse_z(values: list[str], dim: int | None) -> np.ndarray:
    """``["0.1,0.2"]`` or ``["0.1", "0.2"]`` -> [0.1, 0.2], exactly what :func:`z_schema` states;
    raises a 422 with the reason."""
    single = True
    for v in values:
        if _ONE.fullmatch(v) is None:
            single = False
            if _MANY.fullmatch(v) is None:
                invalid(
                    ("query", "z"), f"{v!r} is not a comma-separated list of decimal numbers", v
                )
    out = [float(p) for v in values for p in v.split(",")]
    if dim is not None:
        if len(out) != dim:
            invalid(("query", "z"), f"z has {len(out)} coordinates, the skills have {dim}", values)
        if len(values) != 1 and not single:
            invalid(
                ("query", "z"),
                f"give z as one comma-separated value or as {dim} repeated values, not a mix",
                values,
            )
    elif len(out) > m.MAX_DIM:
        invalid(("query", "z"), f"{len(out)} coordinates, at most {m.MAX_DIM}", values)
    return np.asarray(out)


def _float32_inside(lo: float, hi: float) -> tuple[float, float]:
    """[lo, hi] shrunk to float32 endpoints: the API sends skills as float32, so a value inside
    these bounds stays inside [lo, hi] once rounded (the evaluator checks the float32 value)."""
    lo32, hi32 = np.float32(lo), np.float32(hi)
    if float(lo32) < lo:
        lo32 = np.nextafter(lo32, np.float32(np.inf))
    if float(hi32) > hi:
        hi32 = np.nextafter(hi32, np.float32(-np.inf))
    return float(lo32), float(hi32)


def coordinates_metadata(
    dim: int | None, box: Box | None
) -> tuple[Any, AfterValidator, WithJsonSchema]:
    """What makes ``list[Coordinate]`` a skill given by coordinates: ``dim`` finite floats
    (1..MAX_DIM when the dimension is unknown), each inside ``box``, and a JSON Schema that says
    so (``prefixItems`` with each coordinate's bounds)."""
    if box is not None and (dim is None or box.dim != dim):
        box = None
    n_lo, n_hi = (1, m.MAX_DIM) if dim is None else (dim, dim)
    bounds = (
        None
        if box is None
        else [_float32_inside(lo, hi) for lo, hi in zip(box.low, box.high, strict=True)]
    )
    schema: dict[str, Any] = {"type": "array", "minItems": n_lo, "maxItems": n_hi}
    if bounds is None:
        schema["items"] = {"type": "number"}
    else:
        schema["prefixItems"] = [
            {"type": "number", "minimum": lo, "maximum": hi} for lo, hi in bounds
        ]
        schema["items"] = False

    def in_box(z: list[float]) -> list[float]:
        for i, (x, (lo, hi)) in enumerate(zip(z, bounds or (), strict=False)):
            if not lo <= x <= hi:
                raise ValueError(
                    f"coordinate {i} = {x!r} is outside [{lo:g}, {hi:g}], the run's skill box"
                )
        return z

    return Field(min_length=n_lo, max_length=n_hi), AfterValidator(in_box), WithJsonSchema(schema)


def _exact_integer_bounds(schema: Any) -> None:
    """FastAPI's OpenAPI model writes the bounds of body fields as floats (4096.0); write those
    of integer fields as the integers they are."""
    if isinstance(schema, dict):
        if schema.get("type") == "integer":
            for key in ("minimum", "maximum", "exclusiveMinimum", "exclusiveMaximum"):
                v = schema.get(key)
                if isinstance(v, float) and v.is_integer():
                    schema[key] = int(v)
        for v in schema.values():
            _exact_integer_bounds(v)
    elif isinstance(schema, list):
        for v in schema:
            _exact_integer_bounds(v)


def create_app(state: ApiState) -> FastAPI:
    """The app over ``state``; see the module docstring."""
    app = FastAPI(title="URSA skills API", version="1.0.0", description=DESCRIPTION)
    live = state.live
    e503: dict[int | str, dict[str, Any]] = {
        503: {"model": m.Error, "description": "A peer is missing"}
    }

    dim = state.skill_dim
    coord_len, coord_box, coord_schema = coordinates_metadata(dim, state.skill_box)
    damages = tuple(state.damages)

    def known_damage(d: str) -> str:
        if d not in damages:
            named = ", ".join(repr(x) for x in damages if x)
            raise ValueError(f"unknown damage {d!r}; one of: {named} (or null)")
        return d

    def skill_kind(v: Any) -> str:
        return "coordinates" if isinstance(v, list) else "id"

    class SampleRequest(BaseModel):
        model_config = ConfigDict(extra="forbid", strict=True)
        n: m.Integer = Field(
            1,
            ge=1,
            le=state.max_sample,
            description="How many skills to draw from the repertoire's KDE",
        )
        seed: m.Seed | None = Field(None, description="Seed of the draw (fresh if absent)")

    class EvaluateRequest(BaseModel):
        model_config = ConfigDict(extra="forbid", strict=True)
        skill: Annotated[
            Annotated[m.Seed, Tag("id")]
            | Annotated[list[m.Coordinate], coord_len, coord_box, coord_schema, Tag("coordinates")],
            Discriminator(skill_kind),
        ] = Field(
            description="A skill id from the repertoire (0..2**53-1), or coordinates in skill "
            "space (D,), each inside the run's skill box"
        )
        steps: m.Integer = Field(
            250, ge=1, le=state.max_eval_steps, description="Control steps to run the skill for"
        )
        damage: (
            Annotated[
                str,
                AfterValidator(known_damage),
                WithJsonSchema({"type": "string", "enum": list(damages)}),
            ]
            | None
        ) = Field(None, description="Damage scenario (A1); null/''/'none': intact")
        seed: m.Seed | None = Field(None, description="Seed of the environment")

    n_joints = state.joints

    def distinct_joints(v: list[int]) -> list[int]:
        if len(set(v)) != len(v):
            raise ValueError(f"frozen_joints {v} repeat a joint")
        return v

    Joint = Annotated[int, Field(ge=0, le=max(n_joints - 1, 0)), BeforeValidator(m.integral)]
    Positive = Annotated[float, Field(allow_inf_nan=False)]

    class AdaptRequest(BaseModel):
        model_config = ConfigDict(extra="forbid", strict=True)
        damage: (
            Annotated[
                str,
                AfterValidator(known_damage),
                WithJsonSchema({"type": "string", "enum": list(damages)}),
            ]
            | None
        ) = Field(None, description="Damage preset (A1); null/''/'none': none")
        frozen_joints: Annotated[
            list[Joint],
            Field(max_length=n_joints),
            AfterValidator(distinct_joints),
            WithJsonSchema(
                {
                    "type": "array",
                    "items": {"type": "integer", "minimum": 0, "maximum": max(n_joints - 1, 0)},
                    "maxItems": n_joints,
                    "uniqueItems": True,
                }
            ),
        ] = Field(
            default_factory=list,
            description="More frozen joints (indices into ursa.envs.a1.JOINT_NAMES: FR, FL, RR, "
            "RL × hip, upper, lower), each held at its standing angle; any set of joints",
        )
        budget: m.Integer = Field(
            20, ge=1, le=state.max_adapt_budget, description="Most trials on the damaged robot"
        )
        alpha: Positive = Field(
            0.9, gt=0.0, le=1.0, description="Stop once best observed ≥ alpha × best predicted"
        )
        kappa: Positive = Field(0.05, ge=0.0, le=100.0, description="UCB exploration weight")
        length_scale: Positive = Field(
            1.0, gt=0.0, le=1000.0, description="Matérn 5/2 length scale (skill std units)"
        )
        noise: Positive = Field(
            1e-3, gt=0.0, le=1000.0, description="GP noise variance ((map return range)²)"
        )
        skills: Annotated[int, Field(ge=1, le=state.max_adapt_skills), m.integral_v] | None = Field(
            None, description="Map size: the most distinct skills of the repertoire (default N_z)"
        )
        steps: Annotated[int, Field(ge=1, le=state.max_eval_steps), m.integral_v] | None = Field(
            None, description="Control steps per trial (default: the run's skill period)"
        )
        seed: m.Seed | None = Field(None, description="Seed of the trials' environments")
        evaluator: (
            Annotated[str, Field(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.\-]+$")] | None
        ) = Field(None, description="Evaluator id (default: the first alive)")

    base_openapi = app.openapi

    def openapi() -> dict[str, Any]:
        """FastAPI's schema with the bounds it cannot write itself: integer bounds as integers,
        and ``z`` of ``/skills/nearest`` with its count and per-value pattern."""
        if app.openapi_schema is None:
            schema = base_openapi()
            _exact_integer_bounds(schema)
            for p in schema["paths"]["/skills/nearest"]["get"]["parameters"]:
                if p["name"] == "z":
                    p["schema"] = {**z_schema(dim), "title": "Z", "description": p["description"]}
            app.openapi_schema = schema
        return app.openapi_schema

    app.openapi = openapi  # type: ignore[method-assign]

    def need_snapshot() -> SnapshotView:
        snap = live.latest_snapshot()
        if snap is None:
            unavailable("no repertoire snapshot yet (is the repertoire running?)")
        return snap

    @app.middleware("http")
    async def count_requests(request: Request, call_next: Any) -> Any:
        response = await call_next(request)
        state.count(response.status_code)
        return response

    @app.exception_handler(StarletteHTTPException)
    async def http_error(request: Request, exc: StarletteHTTPException) -> Any:
        # FastAPI answers 400 to a body it cannot parse (e.g. not UTF-8): a client's mistake
        # like any other invalid input, so 422 with the reason
        if exc.status_code == 400:
            return JSONResponse(
                {"detail": [{"loc": ["body"], "msg": str(exc.detail), "type": "value_error"}]},
                status_code=422,
            )
        return await http_exception_handler(request, exc)

    @app.exception_handler(Exception)
    async def internal_error(request: Request, exc: Exception) -> JSONResponse:
        # only a bug gets here; keep the reason for the log, not the client
        return JSONResponse({"detail": f"internal error: {type(exc).__name__}"}, status_code=500)

    @app.get("/skills", response_model=m.SkillPage, responses=e503, tags=["skills"])
    def list_skills(
        offset: Annotated[int, Query(ge=0, le=10**9, description="Skills to skip (by id)")] = 0,
        limit: Annotated[int, Query(ge=1, le=1000, description="Page size")] = 100,
    ) -> m.SkillPage:
        """The skills of the latest repertoire snapshot, ordered by id."""
        snap = need_snapshot()
        rows = snap.page(offset, limit)
        return m.SkillPage(
            items=[skill_out(snap, int(r)) for r in rows],
            total=snap.size,
            offset=offset,
            limit=limit,
            dim=snap.dim,
            snapshot_version=snap.version,
            delta=finite(snap.delta),
            entropy_bound=finite(snap.entropy_bound),
        )

    @app.get("/skills/nearest", response_model=m.NearestReply, responses=e503, tags=["skills"])
    def nearest(
        z: Annotated[
            list[Annotated[str, Field(max_length=Z_MAX_LENGTH)]],
            Query(
                description="The D coordinates: one comma-separated value (z=0.1,0.2) or D "
                "repeated values (z=0.1&z=0.2)"
            ),
        ],
        k: Annotated[int, Query(ge=1, le=100, description="How many neighbours")] = 1,
    ) -> m.NearestReply:
        """The k skills nearest z in the repertoire's Mahalanobis metric (Σ of the snapshot)."""
        q = parse_z(z, dim)
        snap = need_snapshot()
        if dim is None and len(q) != snap.dim:
            invalid(("query", "z"), f"z has {len(q)} coordinates, the skills have {snap.dim}", z)
        if len(q) != snap.dim:
            unavailable(f"the snapshot's skills have dimension {snap.dim}, the run's {dim}")
        rows, dist = snap.nearest(q, k)
        return m.NearestReply(
            query=q.tolist(),
            k=k,
            delta=finite(snap.delta),
            snapshot_version=snap.version,
            results=[
                m.Neighbour(id=int(snap.ids[r]), z=snap.skills[r].tolist(), distance=float(d))
                for r, d in zip(rows, dist, strict=True)
            ],
        )

    @app.post("/skills/sample", response_model=m.SampleReply, responses=e503, tags=["skills"])
    def sample(body: SampleRequest) -> m.SampleReply:
        """n skills from the repertoire's KDE (forwarded to the repertoire; drawn here from the
        latest snapshot with ``ursa.kde.kde_sample`` if the repertoire does not answer)."""
        snap = live.latest_snapshot()
        reply = None
        if state.backend is not None and live.alive_ids("repertoire"):
            reply = state.backend.sample(body.n, body.seed, state.sample_timeout_s)
        if reply is not None and not reply.error:
            try:
                skills = np.asarray(codec.from_array(reply.skills), np.float64)
            except codec.BadMessage:
                skills = np.zeros((0, 0))
            if skills.ndim == 2 and len(skills) == body.n and np.all(np.isfinite(skills)):
                return m.SampleReply(
                    skills=skills.tolist(),
                    source="repertoire",
                    delta=finite(reply.delta),
                    snapshot_version=int(reply.snapshot_version),
                )
        if snap is None or snap.size == 0:
            why = (
                reply.error
                if reply is not None and reply.error
                else ("no repertoire snapshot yet" if snap is None else "the repertoire is empty")
            )
            unavailable(f"cannot sample: {why}")
        rng = np.random.default_rng(body.seed)
        skills = kde_sample(snap.skills, snap.cov, body.n, rng)
        return m.SampleReply(
            skills=skills.tolist(),
            source="snapshot",
            delta=finite(snap.delta),
            snapshot_version=snap.version,
        )

    # ":int": only digits match, so "/skills/sample" and "/skills/nearest" never reach it
    @app.get(
        "/skills/{skill_id:int}",
        response_model=m.Skill,
        tags=["skills"],
        responses={404: {"model": m.Error, "description": "No such skill"}, **e503},
    )
    def get_skill(skill_id: Annotated[int, Path(ge=0, le=m.MAX_SEED)]) -> m.Skill:
        """One skill of the latest snapshot by id."""
        snap = need_snapshot()
        row = snap.index_of(skill_id)
        if row is None:
            raise HTTPException(
                404,
                detail=f"skill {skill_id} is not in the repertoire "
                f"(snapshot version {snap.version})",
            )
        return skill_out(snap, row)

    @app.get("/collectors", response_model=list[m.Collector], tags=["collectors"])
    def collectors() -> list[m.Collector]:
        """The live collectors with their latest stats."""
        now = time.time()
        out = []
        for c in live.collectors():
            s = c.stats
            steps, rescues, pv = c.get("steps"), c.get("rescues"), c.get("policy_version")
            out.append(
                m.Collector(
                    id=c.id,
                    alive=c.alive,
                    steps=None if steps is None else int(steps),
                    steps_per_s=c.get("steps_per_s"),
                    violation_rate=c.get("violation_rate"),
                    rescues=None if rescues is None else int(rescues),
                    return_mean=c.get("return_mean"),
                    damage=c.damage,
                    env=s.labels.get("env") if s else None,
                    skill=None if c.skill is None else c.skill.tolist(),
                    skill_source=s.labels.get("skill_source") if s else None,
                    policy_version=None if pv is None else int(pv),
                    stats_age_s=None if s is None else max(0.0, now - s.received),
                )
            )
        return out

    def service_stats(e: StatsEntry, alive: bool, now: float) -> m.ServiceStats:
        return m.ServiceStats(
            service=e.service,
            id=e.sid,
            alive=alive,
            stamp=e.stamp,
            age_s=max(0.0, now - e.received),
            scalars={k: finite(v) for k, v in sorted(e.scalars.items())},
            labels=dict(e.labels),
            arrays={k: jsonable_array(a) for k, a in sorted(e.arrays.items())},
        )

    @app.get("/stats", response_model=m.StatsReply, tags=["run"])
    def stats() -> m.StatsReply:
        """The latest stats of every service seen (gone ones too, marked ``alive: false``)."""
        now = time.time()
        alive: dict[str, dict[str, float]] = {}
        out = []
        for (svc, sid), e in sorted(live.all_stats().items()):
            if svc not in alive:
                alive[svc] = live.alive_ids(svc)
            out.append(service_stats(e, sid in alive[svc], now))
        return m.StatsReply(services=out)

    @app.get("/health", response_model=m.Health, tags=["run"])
    def health() -> m.Health:
        """Always 200: whether the router is reachable, which peers are alive, the snapshot."""
        bus = (
            state.backend.bus_status()
            if state.backend is not None
            else {"connected": False, "router": None, "detail": "no bus (in-process app)"}
        )
        peers: dict[str, Any] = {svc: sorted(live.alive_ids(svc)) for svc in SERVICES}
        peers["collectors"] = sorted(live.alive_ids("collector"))
        snap = live.latest_snapshot()
        problems = []
        if not bus.get("connected"):
            problems.append("zenoh router not reachable")
        for svc in ("repertoire", "learner", "evaluator"):
            if not peers[svc]:
                problems.append(f"no {svc} alive")
        if not peers["collectors"]:
            problems.append("no collector alive")
        if snap is None:
            problems.append("no repertoire snapshot yet")
        snap_info = (
            None
            if snap is None
            else {
                "version": snap.version,
                "size": snap.size,
                "dim": snap.dim,
                "delta": finite(snap.delta),
                "age_s": max(0.0, time.time() - snap.received),
            }
        )
        return m.Health(
            status="degraded" if problems else "ok",
            problems=problems,
            bus=bus,
            peers=peers,
            snapshot=snap_info,
            uptime_s=time.time() - state.started,
        )

    @app.post(
        "/evaluate",
        response_model=m.EvaluateReply,
        tags=["evaluate"],
        responses={404: {"model": m.Error, "description": "No such skill"}, **e503},
    )
    def evaluate(body: EvaluateRequest) -> m.EvaluateReply:
        """Run a skill on the evaluation collector for ``steps`` control steps (one evaluation
        at a time; later requests wait) and return what it achieved."""
        snap = live.latest_snapshot()
        skill_id: int | None = None
        if isinstance(body.skill, int):
            if snap is None:
                unavailable("no repertoire snapshot yet: cannot look up a skill id")
            row = snap.index_of(body.skill)
            if row is None:
                raise HTTPException(404, detail=f"skill {body.skill} is not in the repertoire")
            skill_id, target = body.skill, np.asarray(snap.skills[row])
        else:
            target = np.asarray(body.skill, np.float64)
            if dim is None and snap is not None and len(target) != snap.dim:
                # no config: the snapshot's dimension is the only one known
                invalid(
                    ("body", "skill"),
                    f"skill has {len(target)} coordinates, the skills have {snap.dim}",
                    body.skill,
                )
        damage = body.damage or ""
        if state.backend is None:
            unavailable("no bus: evaluations need the evaluator service")
        if not live.alive_ids("evaluator"):
            unavailable("no evaluator alive (start python -m services.evaluator)")
        req = pb.EvaluateRequest(
            header=state.backend.header(),
            steps=body.steps,
            damage=damage,
            skill=codec.to_array(target.astype(np.float32)),
        )
        if body.seed is not None:
            req.has_seed, req.seed = True, body.seed
        timeout = state.eval_timeout_s + state.eval_timeout_per_step_s * body.steps
        t0 = time.perf_counter()
        if not state.eval_lock.acquire(timeout=state.eval_wait_s):
            unavailable("the evaluator is busy (evaluations run one at a time)")
        try:
            reply = state.backend.evaluate(req, timeout)
        finally:
            state.eval_lock.release()
        if reply is None:
            unavailable(f"the evaluator did not answer within {timeout:.0f} s")
        if reply.error.startswith("invalid:"):
            invalid(("body",), reply.error.removeprefix("invalid:").strip())
        if reply.error:
            unavailable(reply.error.removeprefix("unavailable:").strip())
        try:
            achieved = np.asarray(codec.from_array(reply.achieved), np.float64)
        except codec.BadMessage as e:
            unavailable(f"malformed evaluator reply: {e}")
        nums = [reply.distance, reply.delta, reply.ret, *achieved.tolist()]
        if not all(math.isfinite(v) for v in nums):
            unavailable("the evaluator replied with non-finite numbers")
        steps = max(int(reply.steps), 1)
        return m.EvaluateReply(
            skill_id=skill_id,
            target=target.tolist(),
            achieved=achieved.tolist(),
            distance=reply.distance,
            delta=reply.delta,
            within_delta=bool(reply.distance <= reply.delta),
            ret=reply.ret,
            violations=int(reply.violations),
            violation_rate=reply.violations / steps,
            steps=int(reply.steps),
            damage=damage or "none",
            policy_version=int(reply.policy_version),
            elapsed_s=time.perf_counter() - t0,
        )

    # ---- adaptation ------------------------------------------------------------------------
    # only where jobs can be forwarded (the service always can; an app built in-process
    # without an adaptation backend has no /adapt routes rather than routes that answer 503)
    def add_adapt_routes() -> None:
        e404: dict[int | str, dict[str, Any]] = {
            404: {"model": m.Error, "description": "No such job"}
        }

        def job_out(job: pb.AdaptJob, source: str) -> m.AdaptJob:
            def arr(a: pb.Array) -> np.ndarray:
                try:
                    return np.asarray(codec.from_array(a), np.float64)
                except codec.BadMessage:
                    return np.zeros(0)

            skills = arr(job.map_skills)
            ids = [int(i) for i in arr(job.map_ids)]

            def coords(skill_id: int) -> list[float]:
                if skill_id in ids and skills.ndim == 2:
                    return [float(v) for v in skills[ids.index(skill_id)]]
                return []

            r = job.request
            trials = [
                m.AdaptTrial(
                    trial=k,
                    skill_id=int(t.skill_id),
                    skill=[float(v) for v in arr(t.skill)],
                    ret=finite(t.ret),
                    achieved=[float(v) for v in arr(t.achieved)],
                    violations=int(t.violations),
                    predicted=finite(t.predicted),
                    predicted_best_id=int(t.predicted_best_id),
                    predicted_best_mean=finite(t.predicted_best_mean),
                )
                for k, t in enumerate(job.trials, 1)
            ]
            chosen = (
                m.AdaptSkill(
                    skill_id=int(job.chosen_skill_id),
                    skill=coords(int(job.chosen_skill_id)),
                    value=finite(job.chosen_return),
                )
                if job.chosen_skill_id >= 0
                else None
            )
            best = (
                m.AdaptSkill(
                    skill_id=int(job.predicted_best_id),
                    skill=coords(int(job.predicted_best_id)),
                    value=finite(job.predicted_best_mean),
                )
                if job.predicted_best_id >= 0
                else None
            )
            return m.AdaptJob(
                job_id=job.job_id,
                evaluator=job.evaluator_id,
                # a state this API does not know (a newer evaluator, an edited file): failed
                state=job.state if job.state in JOB_STATES else "failed",  # type: ignore[arg-type]
                stop_reason=job.stop_reason,
                source=source,  # type: ignore[arg-type]
                damage=r.damage or "none",
                frozen_joints=[int(j) for j in r.frozen_joints],
                params=m.AdaptParams(
                    budget=int(r.budget),
                    alpha=r.alpha,
                    kappa=r.kappa,
                    length_scale=r.length_scale,
                    noise=r.noise,
                ),
                skills=len(ids),
                steps=int(r.steps),
                seed=int(r.seed),
                mapped=int(job.mapped),
                map_cached=bool(job.map_cached),
                policy_version=int(job.policy_version),
                trials=trials,
                chosen=chosen,
                predicted_best=best,
                created=finite(job.created),
                updated=finite(job.updated),
            )

        @app.post(
            "/adapt",
            status_code=202,
            response_model=m.AdaptJob,
            tags=["adapt"],
            responses={
                404: {"model": m.Error, "description": "No such evaluator alive"},
                409: {"model": m.Error, "description": "The evaluator already runs a job"},
                **e503,
            },
        )
        def start_adapt(body: AdaptRequest) -> m.AdaptJob:
            """Start adapting to a damage on an evaluator: Intelligent Trial and Error over the
            repertoire's most distinct skills (their intact returns are the model's prior). Returns
            the job at once (202); follow it with ``GET /adapt/{job_id}``. One job at a time per
            evaluator: another is refused with 409."""
            backend = state.adapt_backend
            if backend is None:
                unavailable("no bus: adaptation needs the evaluator service")
            alive = sorted(live.alive_ids("evaluator"))
            if not alive:
                unavailable("no evaluator alive (start python -m services.evaluator)")
            eid = body.evaluator or alive[0]
            if eid not in alive:
                raise HTTPException(
                    404, detail=f"evaluator {eid!r} is not alive (alive: {', '.join(alive)})"
                )
            req = pb.AdaptRequest(
                header=backend.header(),
                damage=body.damage or "",
                frozen_joints=body.frozen_joints,
                budget=body.budget,
                alpha=body.alpha,
                kappa=body.kappa,
                length_scale=body.length_scale,
                noise=body.noise,
                skills=body.skills or 0,
                steps=body.steps or 0,
            )
            if body.seed is not None:
                req.has_seed, req.seed = True, body.seed
            reply = backend.adapt(req, eid, state.adapt_timeout_s)
            if reply is None:
                unavailable(f"evaluator {eid} did not answer within {state.adapt_timeout_s:.0f} s")
            if reply.error.startswith("invalid:"):
                invalid(("body",), reply.error.removeprefix("invalid:").strip())
            if reply.error.startswith("busy:"):
                raise HTTPException(409, detail=reply.error.removeprefix("busy:").strip())
            if reply.error:
                unavailable(reply.error.removeprefix("unavailable:").strip())
            state.on_adapt_state(reply)
            return job_out(reply, "evaluator")

        def job_file(job_id: str) -> pb.AdaptJob | None:
            if state.jobs_dir is None:
                return None
            try:
                text = (state.jobs_dir / f"{job_id}.json").read_text()
                return json_format.Parse(text, pb.AdaptJob())
            except (OSError, json_format.ParseError):
                return None

        @app.get(
            "/adapt/{job_id}",
            response_model=m.AdaptJob,
            tags=["adapt"],
            responses={**e404, **e503},
        )
        def get_adapt(
            job_id: Annotated[
                str, Path(pattern="^[0-9a-f]{16}$", description="Job id (16 hex digits)")
            ],
        ) -> m.AdaptJob:
            """A job's state, each trial (skill, return, achieved features), the chosen skill, the
            model's predicted best and the stop reason. Asked of the evaluators; when none answers,
            the latest state seen on the bus or the job's file in the run directory, marked
            ``lost`` if its evaluator is gone before it finished."""
            alive = live.alive_ids("evaluator")
            if state.adapt_backend is not None and alive:
                job = state.adapt_backend.adapt_job(job_id, state.adapt_timeout_s)
                if job is not None:
                    state.on_adapt_state(job)
                    return job_out(job, "evaluator")
            candidates = ((state.cached_job(job_id), "bus"), (job_file(job_id), "run_dir"))
            found = [(j, src) for j, src in candidates if j is not None]
            if not found:
                raise HTTPException(404, detail=f"no adaptation job {job_id}")
            job, source = max(found, key=lambda js: js[0].updated)
            if job.state not in ("done", "failed", "lost") and job.evaluator_id not in alive:
                gone = pb.AdaptJob()
                gone.CopyFrom(job)
                gone.state = "lost"
                gone.stop_reason = (
                    f"lost: evaluator {job.evaluator_id} is gone; the job was {job.state} "
                    f"{max(0.0, time.time() - job.updated):.0f} s ago"
                )
                job = gone
            return job_out(job, source)

    if state.adapt_backend is not None:
        add_adapt_routes()

    return app
