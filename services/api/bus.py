"""The API's link to the bus: forwards sample, evaluate and adaptation requests as Zenoh
queries."""

from __future__ import annotations

from typing import Any

from proto import codec
from proto import ursa_pb2 as pb
from services.common.bus import query_one
from services.common.runtime import ServiceRuntime


class BusBackend:
    """``services.api.state.Backend`` and ``AdaptBackend`` over a service runtime's Zenoh
    session."""

    def __init__(self, rt: ServiceRuntime, router: str) -> None:
        self.rt = rt
        self.router = router

    def header(self) -> pb.Header:
        return self.rt.header()

    def sample(self, n: int, seed: int | None, timeout_s: float) -> pb.SkillReply | None:
        req = pb.SkillRequest(header=self.rt.header(), n=n)
        if seed is not None:
            req.has_seed, req.seed = True, seed
        return query_one(
            self.rt.session,
            self.rt.topics.sample,
            pb.SkillReply,
            codec.encode(req),
            timeout_s=timeout_s,
        )

    def evaluate(self, req: pb.EvaluateRequest, timeout_s: float) -> pb.EvaluateReply | None:
        return query_one(
            self.rt.session,
            self.rt.topics.evaluate,
            pb.EvaluateReply,
            codec.encode(req),
            timeout_s=timeout_s,
        )

    def adapt(self, req: pb.AdaptRequest, evaluator: str, timeout_s: float) -> pb.AdaptJob | None:
        return query_one(
            self.rt.session,
            self.rt.topics.adapt(evaluator),
            pb.AdaptJob,
            codec.encode(req),
            timeout_s=timeout_s,
        )

    def adapt_job(self, job_id: str, timeout_s: float) -> pb.AdaptJob | None:
        req = pb.AdaptQuery(header=self.rt.header(), job_id=job_id)

        def same(msg: pb.AdaptJob) -> None:
            if msg.job_id != job_id:
                raise codec.BadMessage(f"asked for job {job_id}, got {msg.job_id}")

        # every evaluator is asked; only the one holding the job replies
        return query_one(
            self.rt.session,
            self.rt.topics.adapt_job("*"),
            pb.AdaptJob,
            codec.encode(req),
            timeout_s=timeout_s,
            check=same,
        )

    def bus_status(self) -> dict[str, Any]:
        try:
            routers = [str(z) for z in self.rt.session.info.routers_zid()]
        except Exception as e:  # a closed session
            return {"connected": False, "router": self.router, "detail": str(e)}
        return {
            "connected": bool(routers),
            "router": self.router,
            "routers": routers,
            "dropped_messages": self.rt.drops.total,
            "run_id": self.rt.run.run_id,
        }
