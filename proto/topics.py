"""Every key expression of the URSA bus, built in one place.

Keys have the form ``ursa/{run}/{producer}/{stream}[/{id}]``. No service writes a key by hand.

| key | message | kind |
|---|---|---|
| ``ursa/{run}/collector/transitions/{cid}`` | TransitionChunk | put, BLOCK (loss-sensitive) |
| ``ursa/{run}/collector/features/{cid}`` | SafeFeatures | put, BLOCK (loss-sensitive) |
| ``ursa/{run}/collector/stats/{cid}`` | Stats | put, may drop |
| ``ursa/{run}/repertoire/sample`` | SkillRequest -> SkillReply | query |
| ``ursa/{run}/repertoire/snapshot`` | RepertoireSnapshot | put (may drop) + query (latest) |
| ``ursa/{run}/repertoire/stats`` | Stats | put, may drop |
| ``ursa/{run}/learner/weights`` | PolicyWeights | put (may drop) + query (latest) |
| ``ursa/{run}/learner/encoder`` | EncoderWeights | put (may drop) + query (latest) |
| ``ursa/{run}/learner/stats`` | Stats | put, may drop |
| ``ursa/{run}/evaluator/evaluate`` | EvaluateRequest -> EvaluateReply | query |
| ``ursa/{run}/evaluator/adapt/{eid}`` | AdaptRequest -> AdaptJob | query (start a job) |
| ``ursa/{run}/evaluator/adapt_job/{eid}`` | AdaptQuery -> AdaptJob | query (a job's state) |
| ``ursa/{run}/evaluator/adapt_state/{eid}`` | AdaptJob | put at every change, may drop |
| ``ursa/{run}/alive/{service}/{id}`` | liveliness token | liveliness |
"""

from __future__ import annotations

import re

_CHUNK = re.compile(r"^[A-Za-z0-9_\-.]+$")

COLLECTOR = "collector"
REPERTOIRE = "repertoire"
LEARNER = "learner"
EVALUATOR = "evaluator"
DASHBOARD = "dashboard"
API = "api"
SERVICES = (COLLECTOR, REPERTOIRE, LEARNER, EVALUATOR, DASHBOARD, API)


def check_chunk(s: str) -> str:
    """Validate one key chunk (run id, service or instance id); returns it."""
    if not _CHUNK.match(s):
        raise ValueError(f"invalid key chunk {s!r}: use letters, digits, '_', '-', '.'")
    return s


class Topics:
    """All keys of one run."""

    def __init__(self, run_id: str) -> None:
        self.run = check_chunk(run_id)
        self.root = f"ursa/{self.run}"

    # collectors
    def transitions(self, cid: str = "*") -> str:
        return f"{self.root}/{COLLECTOR}/transitions/{_id(cid)}"

    def features(self, cid: str = "*") -> str:
        return f"{self.root}/{COLLECTOR}/features/{_id(cid)}"

    def collector_stats(self, cid: str = "*") -> str:
        return f"{self.root}/{COLLECTOR}/stats/{_id(cid)}"

    # repertoire
    @property
    def sample(self) -> str:
        return f"{self.root}/{REPERTOIRE}/sample"

    @property
    def snapshot(self) -> str:
        return f"{self.root}/{REPERTOIRE}/snapshot"

    @property
    def repertoire_stats(self) -> str:
        return f"{self.root}/{REPERTOIRE}/stats"

    # learner
    @property
    def weights(self) -> str:
        return f"{self.root}/{LEARNER}/weights"

    @property
    def encoder(self) -> str:
        return f"{self.root}/{LEARNER}/encoder"

    @property
    def learner_stats(self) -> str:
        return f"{self.root}/{LEARNER}/stats"

    # evaluation
    @property
    def evaluate(self) -> str:
        return f"{self.root}/{EVALUATOR}/evaluate"

    def adapt(self, eid: str = "*") -> str:
        """Start an adaptation job on evaluator ``eid`` (one job at a time per evaluator)."""
        return f"{self.root}/{EVALUATOR}/adapt/{_id(eid)}"

    def adapt_job(self, eid: str = "*") -> str:
        """The state of a job (ask every evaluator with ``*``: the one holding it replies)."""
        return f"{self.root}/{EVALUATOR}/adapt_job/{_id(eid)}"

    def adapt_state(self, eid: str = "*") -> str:
        """Job states as they change (the dashboard's adaptation panel)."""
        return f"{self.root}/{EVALUATOR}/adapt_state/{_id(eid)}"

    def stats(self, service: str = "*", sid: str = "*") -> str:
        """Stats of any service: ``collector`` stats carry an id, the others none."""
        if service == COLLECTOR:
            return self.collector_stats(sid)
        if service == "*":
            return f"{self.root}/*/stats/**"
        return f"{self.root}/{check_chunk(service)}/stats"

    @property
    def all_stats(self) -> str:
        """Matches every service's stats key (collectors' ``.../stats/{id}`` included)."""
        return f"{self.root}/*/stats/**"

    # presence
    def alive(self, service: str = "*", sid: str = "*") -> str:
        svc = service if service == "*" else check_chunk(service)
        return f"{self.root}/alive/{svc}/{_id(sid)}"

    def parse_alive(self, key: str) -> tuple[str, str] | None:
        """``ursa/{run}/alive/{service}/{id}`` -> (service, id); None for other keys."""
        parts = str(key).split("/")
        if len(parts) == 5 and parts[:3] == ["ursa", self.run, "alive"]:
            return parts[3], parts[4]
        return None

    @staticmethod
    def last_chunk(key: str) -> str:
        return str(key).rsplit("/", 1)[-1]


def _id(s: str) -> str:
    return s if s in ("*", "**") else check_chunk(s)
