"""Applying the learner's published policy weights to an acting policy (collectors and the
evaluator): newer versions only, the learner's config must match, corrupt bytes keep the
current policy."""

from __future__ import annotations

import logging

from proto import ursa_pb2 as pb
from services.common.bus import DropCounter
from ursa.policy import Policy


def apply_weights(
    msg: pb.PolicyWeights | None,
    policy: Policy,
    version: int,
    config_hash: str,
    drops: DropCounter,
    log: logging.Logger,
) -> int:
    """Load ``msg`` into ``policy`` when it is newer than ``version`` and was trained with the
    config of ``config_hash``; returns the policy's version afterwards. A refusal is counted in
    ``drops`` (``config_mismatch`` or ``bad_weights``) and logged."""
    if msg is None or msg.version <= version:
        return version
    if msg.config_hash != config_hash:
        drops.add("config_mismatch")
        log.warning(
            "refused weights %d: learner config %s, mine %s",
            msg.version,
            msg.config_hash,
            config_hash,
        )
        return version
    try:
        policy.load_weights_bytes(msg.safetensors, version=int(msg.version))
    except Exception as e:  # wrong shapes or corrupt bytes: keep the current policy
        drops.add("bad_weights")
        log.warning("refused weights %d: %s", msg.version, e)
        return version
    log.info("policy weights version %d", msg.version)
    return int(msg.version)
