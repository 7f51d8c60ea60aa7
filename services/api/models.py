"""Response bodies of the HTTP API and the types its requests share (what ``/docs`` shows).

The request bodies are built by ``services.api.app.create_app``: their bounds (skill dimension and
box, damages, maximum steps and samples) come from the run's config."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import BaseModel, BeforeValidator, Field

MAX_DIM = 64
"""Longest skill vector the API accepts (skills have D = 2..4 in practice)."""
MAX_SEED = 2**53 - 1
"""Largest seed or skill id: the largest integer a JSON number (a double) holds exactly, so every
client reads the same value and the bound written in the OpenAPI schema is exact (2**63 - 1
becomes 2**63 there, and a validator comparing doubles then accepts seeds the API refuses)."""


def integral(v: Any) -> Any:
    """An integral float (4095.0) as the integer it is: JSON Schema's ``integer`` includes it, so
    a strict body must too (strings and booleans stay refused)."""
    if isinstance(v, float) and v.is_integer():
        return int(v)
    return v


integral_v = BeforeValidator(integral)
"""``integral`` as an annotation (after any ``Field`` bounds, so the schema states them)."""
Coordinate = Annotated[float, Field(allow_inf_nan=False)]
Integer = Annotated[int, BeforeValidator(integral)]
"""An integer field of a request body (strict, but 12.0 reads as 12)."""
Seed = Annotated[int, Field(ge=0, le=MAX_SEED), BeforeValidator(integral)]


class Error(BaseModel):
    """Why a request failed (404: missing resource; 503: a missing peer)."""

    detail: str


class Skill(BaseModel):
    id: int = Field(description="Stable skill id (assigned when the skill entered)")
    z: list[float] = Field(description="Coordinates in skill space (D,)")
    age: int = Field(description="Commit index at which the skill entered the repertoire")
    nn_distance: float | None = Field(
        description="Mahalanobis distance to its nearest neighbour (null for a lone skill)"
    )


class SkillPage(BaseModel):
    items: list[Skill]
    total: int = Field(description="Skills in the repertoire")
    offset: int
    limit: int
    dim: int
    snapshot_version: int
    delta: float | None
    entropy_bound: float | None


class SampleReply(BaseModel):
    skills: list[list[float]] = Field(description="(n, D) skills drawn from the KDE")
    source: Literal["repertoire", "snapshot"] = Field(
        description="repertoire: drawn by the repertoire service; snapshot: drawn here with "
        "ursa.kde.kde_sample from the latest snapshot (repertoire not answering)"
    )
    delta: float | None
    snapshot_version: int


class Neighbour(BaseModel):
    id: int
    z: list[float]
    distance: float = Field(description="Mahalanobis distance (the repertoire's Σ)")


class NearestReply(BaseModel):
    query: list[float]
    k: int
    results: list[Neighbour]
    delta: float | None
    snapshot_version: int


class Collector(BaseModel):
    id: str
    alive: bool
    steps: int | None
    steps_per_s: float | None
    violation_rate: float | None
    rescues: int | None
    return_mean: float | None
    damage: str | None
    env: str | None
    skill: list[float] | None = Field(description="The skill it is executing")
    skill_source: str | None
    policy_version: int | None
    stats_age_s: float | None = Field(description="Seconds since its latest stats arrived")


class ServiceStats(BaseModel):
    service: str
    id: str
    alive: bool
    stamp: float
    age_s: float
    scalars: dict[str, float | None]
    labels: dict[str, str]
    arrays: dict[str, Any]


class StatsReply(BaseModel):
    services: list[ServiceStats]


class Health(BaseModel):
    status: Literal["ok", "degraded"]
    problems: list[str]
    bus: dict[str, Any]
    peers: dict[str, Any]
    snapshot: dict[str, Any] | None
    uptime_s: float


class EvaluateReply(BaseModel):
    skill_id: int | None = Field(description="Id of the target skill (if given by id)")
    target: list[float]
    achieved: list[float] = Field(description="Mean φ over the run, in skill space")
    distance: float = Field(description="Mahalanobis distance achieved-target (Σ of δ)")
    delta: float
    within_delta: bool
    ret: float = Field(description="Undiscounted return")
    violations: int = Field(description="Unsafe steps")
    violation_rate: float
    steps: int
    damage: str
    policy_version: int = Field(description="Weights used (0: none yet, random actions)")
    elapsed_s: float


class AdaptParams(BaseModel):
    budget: int = Field(description="Most trials on the damaged robot")
    alpha: float = Field(description="Stop once best observed ≥ alpha × best predicted")
    kappa: float = Field(description="UCB exploration weight (mean + kappa × std)")
    length_scale: float = Field(description="Matérn 5/2 length scale, in skill standard deviations")
    noise: float = Field(description="GP noise variance, in (map return range)²")


class AdaptTrial(BaseModel):
    trial: int = Field(description="1-based trial number")
    skill_id: int
    skill: list[float] = Field(description="The skill tried (D,)")
    ret: float | None = Field(description="Return on the damaged robot")
    achieved: list[float] = Field(description="Mean φ over the trial (D,)")
    violations: int = Field(description="Unsafe steps")
    predicted: float | None = Field(description="Return the model predicted before the trial")
    predicted_best_id: int = Field(description="Skill of the highest predicted mean after it")
    predicted_best_mean: float | None


class AdaptSkill(BaseModel):
    skill_id: int
    skill: list[float]
    value: float | None = Field(description="Its return (chosen) or predicted mean (best)")


class AdaptJob(BaseModel):
    job_id: str
    evaluator: str = Field(description="The evaluator running it")
    state: Literal["mapping", "adapting", "done", "failed", "lost"] = Field(
        description="mapping: measuring the intact returns (ITE's map); adapting: trials on the "
        "damaged robot; done: stopped (see stop_reason); failed; lost: its evaluator stopped"
    )
    stop_reason: str = Field(
        description="threshold (ITE's rule), budget, exhausted (every skill tried), or why it "
        "failed or was lost; empty while running"
    )
    source: Literal["evaluator", "bus", "run_dir"] = Field(
        description="evaluator: its own answer; bus: the latest state it published; run_dir: "
        "the job's file (no evaluator answered)"
    )
    damage: str
    frozen_joints: list[int]
    params: AdaptParams
    skills: int = Field(description="Skills in the map (most distinct of the repertoire)")
    steps: int = Field(description="Control steps per trial")
    seed: int
    mapped: int = Field(description="Map skills measured on the intact robot so far")
    map_cached: bool = Field(description="The map was read from the run directory")
    policy_version: int
    trials: list[AdaptTrial]
    chosen: AdaptSkill | None = Field(description="The best trial so far (the skill kept)")
    predicted_best: AdaptSkill | None = Field(description="The highest predicted mean")
    created: float | None = Field(description="Seconds since the Unix epoch")
    updated: float | None
