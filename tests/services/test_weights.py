"""The one rule by which collectors and the evaluator take the learner's weights."""

from __future__ import annotations

import logging

import numpy as np

from proto import ursa_pb2 as pb
from services.common.bus import DropCounter
from services.common.weights import apply_weights
from ursa.learner_config import learner_preset
from ursa.policy import Policy, pack_policy_weights

CFG = learner_preset("tiny", mode="ursa-supervised")
LOG = logging.getLogger("test")


def _policy(seed: int) -> Policy:
    return Policy(CFG, 6, 2, 2, seed=seed)


def _msg(src: Policy, version: int, config_hash: str = "h") -> pb.PolicyWeights:
    return pb.PolicyWeights(
        version=version,
        safetensors=pack_policy_weights(src.modules(), version=version, vae_version=0),
        config_hash=config_hash,
    )


def test_newer_weights_of_the_same_config_are_applied_others_refused_and_counted() -> None:
    src, dst = _policy(1), _policy(2)
    drops = DropCounter()
    before = [p.detach().clone() for p in dst.actor.parameters()]
    assert any(
        not np.array_equal(a.numpy(), b.numpy())
        for a, b in zip(before, src.actor.parameters(), strict=True)
    )
    v = apply_weights(_msg(src, 3), dst, 0, "h", drops, LOG)
    assert v == 3 and not drops.counts
    for a, b in zip(src.modules().values(), dst.modules().values(), strict=True):
        for pa, pb_ in zip(a.state_dict().values(), b.state_dict().values(), strict=True):
            assert np.array_equal(pa.numpy(), pb_.numpy())
    other = _policy(3)
    assert apply_weights(_msg(other, 3), dst, v, "h", drops, LOG) == 3  # not newer: ignored
    assert apply_weights(None, dst, v, "h", drops, LOG) == 3
    assert apply_weights(_msg(other, 4, "other"), dst, v, "h", drops, LOG) == 3
    assert drops.counts["config_mismatch"] == 1
    bad = pb.PolicyWeights(version=5, safetensors=b"\x00not safetensors", config_hash="h")
    assert apply_weights(bad, dst, v, "h", drops, LOG) == 3
    assert drops.counts["bad_weights"] == 1
    for a, b in zip(
        src.modules().values(), dst.modules().values(), strict=True
    ):  # still the version-3 weights
        for pa, pb_ in zip(a.state_dict().values(), b.state_dict().values(), strict=True):
            assert np.array_equal(pa.numpy(), pb_.numpy())
