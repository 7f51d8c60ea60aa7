"""The critics bundle (``ursa.agent.Critics``): members, what the optimiser trains, the slow
copies' EMA, and one joint input serving every member."""

from __future__ import annotations

import torch

from tests.ursa.learner.test_learner import MICRO
from ursa.agent import Critics, joint_input
from ursa.distributions import symexp_bins

torch.set_num_threads(1)


def _bins() -> torch.Tensor:
    return symexp_bins(MICRO.bins)


def test_members_and_trained_parameters() -> None:
    torch.manual_seed(0)
    full = Critics(MICRO, 10, 2, _bins(), skills=True)
    value_only = Critics(MICRO, 10, 0, _bins(), skills=False)
    assert set(full.members()) == {"value", "value_slow", "sf", "sf_slow", "cost", "cost_slow"}
    assert set(value_only.members()) == {"value", "value_slow"}
    trained = {id(p) for p in full.online_parameters()}
    slow = [p for k, m in full.members().items() if k.endswith("_slow") for p in m.parameters()]
    assert trained.isdisjoint(id(p) for p in slow)
    assert not any(p.requires_grad for p in slow)
    online = [p for m in (full.value, full.sf, full.cost) if m for p in m.parameters()]
    assert trained == {id(p) for p in online}


def test_slow_copies_follow_by_ema_and_predict_like_the_online_ones_at_start() -> None:
    torch.manual_seed(0)
    c = Critics(MICRO, 10, 2, _bins(), skills=True)
    feat, skill = torch.randn(5, 10), torch.randn(5, 2)
    x = joint_input(feat, skill)
    on, sl = c.online(x, skill), c.slow(x, skill)
    assert torch.equal(on.value_logits, sl.value_logits)
    assert on.sf is not None and sl.sf is not None and torch.equal(on.sf, sl.sf)
    # the residual SF critic starts at "the skill is executed"
    assert torch.allclose(on.sf, skill)
    w_fast = c.value.mlp.trunk[0].weight
    w_slow = c.value_slow.mlp.trunk[0].weight
    assert isinstance(w_fast, torch.Tensor) and isinstance(w_slow, torch.Tensor)
    before = w_slow.detach().clone()
    with torch.no_grad():
        w_fast.add_(1.0)
    c.update_slow(0.25)
    assert torch.allclose(w_slow, before + 0.25)
