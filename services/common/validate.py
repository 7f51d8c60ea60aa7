"""Semantic checks of decoded bus messages: the values their producer declares, nothing else.

A :class:`Validator` holds the boxes of the run (:func:`ursa.bounds.declared`) and checks each
message type at decode time (``services.common.bus.checked_decode``, which every subscriber,
query and queryable of the services goes through); a failure raises ``OutOfBounds``, which the
bus counts (reason ``out_of_bounds``, per key and publisher) and drops. Without a config (a
process that knows no env) only the checks that need none run: finite values, stats origin.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from google.protobuf.message import Message

from proto import codec
from proto import ursa_pb2 as pb
from proto.topics import COLLECTOR, SERVICES, check_chunk
from ursa import bounds
from ursa.bounds import STAT_BOUND, WEIGHT_BOUND, Box, OutOfBounds
from ursa.config import Config

SCALAR_BOUND = 1e12
"""|x| bound of rewards, costs, distances and other unbounded-by-design scalars."""


def _arr(msg: Message, name: str) -> np.ndarray:
    return codec.from_array(getattr(msg, name))


def _rows(name: str, x: np.ndarray, box: Box | None, ndim: int = 2) -> np.ndarray:
    if x.ndim != ndim:
        raise OutOfBounds(f"{name} of shape {x.shape}: {ndim} axes expected")
    if box is None:
        return bounds.check_finite(name, x, SCALAR_BOUND)
    if x.shape[-1] != box.dim:
        raise OutOfBounds(f"{name} of width {x.shape[-1]}, {box.dim} declared")
    return bounds.check(name, x, box)


def _scalar(name: str, v: float, low: float = -SCALAR_BOUND, high: float = SCALAR_BOUND) -> None:
    if not (np.isfinite(v) and low <= v <= high):
        raise OutOfBounds(f"{name} = {v!r} outside [{low:g}, {high:g}]")


def check_safetensors(name: str, data: bytes) -> None:
    """Every tensor of a safetensors blob finite within ``WEIGHT_BOUND``."""
    from safetensors.numpy import load

    try:
        tensors = load(bytes(data))
    except Exception as e:
        raise OutOfBounds(f"{name}: not safetensors ({e})") from e
    for k, t in tensors.items():
        bounds.check_finite(f"{name}[{k}]", t, WEIGHT_BOUND)


def stats_origin(service: str, sid: str, key: str) -> None:
    """A Stats message names a known service and the service and id its key carries
    (``ursa/{run}/{service}/stats[/{id}]``)."""
    if service not in SERVICES:
        raise OutOfBounds(f"stats from unknown service {service!r}")
    try:
        check_chunk(sid)
    except ValueError as e:
        raise OutOfBounds(f"stats id: {e}") from e
    if key:
        parts = key.split("/")
        if len(parts) < 4 or parts[2] != service or parts[3] != "stats":
            raise OutOfBounds(f"stats of {service!r} on key {key!r}")
        if service == COLLECTOR and parts[4:] != [sid]:
            raise OutOfBounds(f"collector stats of {sid!r} on key {key!r}")


class Validator:
    """Checks of every message type against the boxes of ``cfg`` (None: generic checks)."""

    def __init__(self, cfg: Config | None = None) -> None:
        self.cfg = cfg
        self.declared = bounds.declared(cfg) if cfg is not None else None
        self._checks: dict[type[Message], Callable[[Any, str], None]] = {
            pb.TransitionChunk: self.chunk,
            pb.SafeFeatures: self.features,
            pb.SkillReply: self.skill_reply,
            pb.RepertoireSnapshot: self.snapshot,
            pb.PolicyWeights: self.weights,
            pb.EncoderWeights: self.weights,
            pb.Stats: self.stats,
            pb.EvaluateRequest: self.evaluate_request,
            pb.EvaluateReply: self.evaluate_reply,
        }

    def __call__(self, msg: Message, key: str = "") -> None:
        """Raise ``OutOfBounds`` unless ``msg`` (on ``key``) holds only declared values."""
        check = self._checks.get(type(msg))
        if check is not None:
            check(msg, key)

    def _box(self, name: str) -> Box | None:
        return None if self.declared is None else getattr(self.declared, name)

    def chunk(self, msg: pb.TransitionChunk, key: str = "") -> None:
        obs = _rows("obs", _arr(msg, "obs"), self._box("obs"))
        n = obs.shape[0]
        for name, box in (("action", "action"), ("features", "features"), ("skill", "samples")):
            a = _arr(msg, name)
            if a.size or n:
                _rows(name, a, self._box(box))
        for name in ("reward", "cost"):
            _rows(name, _arr(msg, name), None, ndim=1)

    def features(self, msg: pb.SafeFeatures, key: str = "") -> None:
        _rows("features", _arr(msg, "features"), self._box("features"))

    def skill_reply(self, msg: pb.SkillReply, key: str = "") -> None:
        if msg.error:
            return
        _rows("skills", _arr(msg, "skills"), self._box("samples"))
        _scalar("delta", msg.delta, 0.0)

    def snapshot(self, msg: pb.RepertoireSnapshot, key: str = "") -> None:
        skills = _arr(msg, "skills")
        if skills.size:
            _rows("skills", skills, self._box("skills"))
        n = skills.shape[0] if skills.ndim else 0
        nn = _arr(msg, "nn_dist")
        if nn.shape != (n,):
            raise OutOfBounds(f"nn_dist of shape {nn.shape} for {n} skills")
        with np.errstate(invalid="ignore"):
            if not ((nn >= 0) & ~np.isnan(nn)).all() or (n > 1 and not np.isfinite(nn).all()):
                raise OutOfBounds("nn_dist not finite and ≥ 0")
        for name in ("ids", "ages"):
            if _arr(msg, name).shape != (n,):
                raise OutOfBounds(f"{name} of shape {_arr(msg, name).shape} for {n} skills")
        cov = np.asarray(_arr(msg, "cov"), np.float64)
        d = skills.shape[1] if skills.ndim == 2 else cov.shape[0] if cov.ndim == 2 else 0
        if cov.shape != (d, d) or not np.isfinite(cov).all() or not np.allclose(cov, cov.T):
            raise OutOfBounds(f"cov of shape {cov.shape} not a finite symmetric ({d}, {d})")
        if d and np.linalg.eigvalsh(cov).min() <= 0:
            raise OutOfBounds("cov not positive definite")
        if msg.HasField("inputs") and _arr(msg, "inputs").size:
            _rows("inputs", _arr(msg, "inputs"), self._box("features"))
        _scalar("delta", msg.delta, 0.0)
        _scalar("entropy_bound", msg.entropy_bound)

    def weights(self, msg: pb.PolicyWeights | pb.EncoderWeights, key: str = "") -> None:
        check_safetensors(type(msg).__name__, msg.safetensors)

    def stats(self, msg: pb.Stats, key: str = "") -> None:
        stats_origin(msg.service, msg.id, key)
        for k, v in msg.scalars.items():
            _scalar(f"scalars[{k}]", v, -STAT_BOUND, STAT_BOUND)
        for k, a in msg.arrays.items():
            x = codec.from_array(a)
            if k == "skill" and self.declared is not None and x.ndim == 1:
                bounds.check("arrays[skill]", x, self.declared.samples)
            else:
                bounds.check_finite(f"arrays[{k}]", x, STAT_BOUND)

    def evaluate_request(self, msg: pb.EvaluateRequest, key: str = "") -> None:
        _rows("skill", _arr(msg, "skill"), self._box("samples"), ndim=1)

    def evaluate_reply(self, msg: pb.EvaluateReply, key: str = "") -> None:
        if msg.error:
            return
        _rows("achieved", _arr(msg, "achieved"), self._box("skills"), ndim=1)
        for name in ("distance", "delta", "ret"):
            _scalar(name, getattr(msg, name))
