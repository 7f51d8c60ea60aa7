"""Exact checks of the learner's math on hand-worked values."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from ursa.agent import (
    actor_objective,
    any_ahead,
    cap_safe_margin,
    lambda_return,
    mahalanobis,
    percentile_update,
)
from ursa.distributions import (
    categorical_kl,
    kl_balance,
    sample_onehot_st,
    symexp,
    symexp_bins,
    symlog,
    tanh_normal_sample,
    two_hot,
    two_hot_loss,
    two_hot_loss2,
    two_hot_mean,
    unimix_logits,
    unimix_probs,
)

torch.set_num_threads(1)


def test_symlog_values_and_inverse() -> None:
    x = torch.tensor([-100.0, -1.0, 0.0, 0.5, 1.0, math.e - 1.0, 1e4], dtype=torch.float64)
    expected = torch.tensor(
        [-math.log(101.0), -math.log(2.0), 0.0, math.log(1.5), math.log(2.0), 1.0, math.log(10001)],
        dtype=torch.float64,
    )
    torch.testing.assert_close(symlog(x), expected)
    torch.testing.assert_close(symexp(symlog(x)), x)
    y = torch.linspace(-15, 15, 101, dtype=torch.float64)
    torch.testing.assert_close(symlog(symexp(y)), y)


@pytest.mark.parametrize("n", [255, 63, 64])
def test_symexp_bins_symmetric(n: int) -> None:
    b = symexp_bins(n)
    assert b.shape == (n,)
    assert torch.all(b[1:] > b[:-1])
    torch.testing.assert_close(b, -b.flip(0))
    if n % 2:
        assert b[n // 2] == 0.0
    assert b[-1] == pytest.approx(math.expm1(20.0), rel=1e-6)


def test_two_hot_round_trip_and_weights() -> None:
    bins = torch.tensor([-2.0, -1.0, 0.0, 1.0, 4.0])
    code = two_hot(torch.tensor([0.25, 2.5, -2.0, 4.0, 10.0, -7.0]), bins)
    expected = torch.tensor(
        [
            [0, 0, 0.75, 0.25, 0],
            [0, 0, 0, 0.5, 0.5],
            [1, 0, 0, 0, 0],
            [0, 0, 0, 0, 1],
            [0, 0, 0, 0, 1],  # clipped to the end bins
            [1, 0, 0, 0, 0],
        ]
    )
    torch.testing.assert_close(code, expected)
    big = symexp_bins(255)
    x = torch.tensor(np.random.default_rng(0).normal(0, 300, size=(7, 11)), dtype=torch.float32)
    c = two_hot(x, big)
    torch.testing.assert_close(c.sum(-1), torch.ones_like(x))
    torch.testing.assert_close(c @ big, x, rtol=1e-5, atol=1e-4)
    # a distribution equal to the code decodes to the value and has the smallest loss
    logits = torch.log(c + 1e-12)
    torch.testing.assert_close(two_hot_mean(logits, big), x, rtol=1e-4, atol=1e-3)
    assert torch.all(two_hot_loss(logits, x, big) <= two_hot_loss(torch.zeros_like(logits), x, big))
    # the fused two-target loss equals the sum of the two cross-entropies
    y = x.flip(0)
    rnd = torch.randn(7, 11, 255)
    torch.testing.assert_close(
        two_hot_loss2(rnd, x, y, 0.5, big),
        two_hot_loss(rnd, x, big) + 0.5 * two_hot_loss(rnd, y, big),
        rtol=1e-5,
        atol=1e-4,
    )


def test_lambda_return_hand_worked() -> None:
    # γ = λ = 0.5, rewards r0..r2 = 1, 2, 3 and values v0..v3 = 10, 20, 30, 40:
    # R3 = 40; R2 = 3 + .5(.5·40 + .5·40) = 23; R1 = 2 + .5(.5·30 + .5·23) = 15.25;
    # R0 = 1 + .5(.5·20 + .5·15.25) = 9.8125.
    r = torch.tensor([1.0, 2.0, 3.0])
    v = torch.tensor([10.0, 20.0, 30.0, 40.0])
    torch.testing.assert_close(lambda_return(r, v, 0.5, 0.5), torch.tensor([9.8125, 15.25, 23.0]))
    # λ = 0: one-step TD targets; λ = 1: discounted sum + bootstrap from the last value
    torch.testing.assert_close(lambda_return(r, v, 0.5, 0.0), torch.tensor([11.0, 17.0, 23.0]))
    torch.testing.assert_close(lambda_return(r, v, 0.5, 1.0), torch.tensor([7.75, 13.5, 23.0]))
    # batched trailing axes broadcast the same way
    rb = r[:, None, None].expand(3, 2, 4)
    vb = v[:, None, None].expand(4, 2, 4)
    torch.testing.assert_close(
        lambda_return(rb, vb, 0.5, 0.5)[:, 1, 3], lambda_return(r, v, 0.5, 0.5)
    )


def _logp(p: list[float]) -> torch.Tensor:
    return torch.log(torch.tensor(p, dtype=torch.float64)).reshape(1, -1)


def test_kl_balance_free_nats_and_gradients() -> None:
    # KL([.5, .5] ‖ [.25, .75]) = .5 ln 2 + .5 ln(2/3)
    kl = 0.5 * math.log(2.0) + 0.5 * math.log(2.0 / 3.0)
    post = _logp([0.5, 0.5]).requires_grad_(True)
    prior = _logp([0.25, 0.75]).requires_grad_(True)
    assert float(categorical_kl(post, prior).detach()) == pytest.approx(kl)
    loss, dyn, rep = kl_balance(post, prior, free_nats=0.1, dyn_scale=0.5, rep_scale=0.1)
    assert float(dyn.detach()) == pytest.approx(kl) and float(rep.detach()) == pytest.approx(kl)
    assert float(loss.detach()) == pytest.approx(0.6 * kl)
    # dyn trains only the prior, rep only the posterior
    (g_prior,) = torch.autograd.grad(dyn, prior, retain_graph=True)
    assert torch.autograd.grad(dyn, post, retain_graph=True, allow_unused=True)[0] is None or bool(
        torch.all(torch.autograd.grad(dyn, post, retain_graph=True, allow_unused=True)[0] == 0)
    )
    (g_post_rep,) = torch.autograd.grad(rep, post, retain_graph=True)
    g_prior_rep = torch.autograd.grad(rep, prior, retain_graph=True, allow_unused=True)[0]
    assert g_prior_rep is None or bool(torch.all(g_prior_rep == 0))
    assert torch.any(g_prior != 0) and torch.any(g_post_rep != 0)
    # below the free nats: the value is clipped and there is no gradient at all
    loss, dyn, rep = kl_balance(post, prior, free_nats=1.0, dyn_scale=0.5, rep_scale=0.1)
    assert float(dyn.detach()) == 1.0 and float(rep.detach()) == 1.0
    assert float(loss.detach()) == pytest.approx(0.6)
    g = torch.autograd.grad(loss, [post, prior])
    assert all(bool(torch.all(x == 0)) for x in g)


def test_unimix_and_straight_through_sample() -> None:
    logits = torch.tensor([[[100.0, 0.0, 0.0, 0.0]]])
    p = unimix_logits(logits, 0.01).exp()
    torch.testing.assert_close(p, torch.tensor([[[0.9925, 0.0025, 0.0025, 0.0025]]]))
    gen = torch.Generator().manual_seed(0)
    lp = unimix_probs(torch.zeros(5000, 1, 4), 0.01).requires_grad_(True)
    s = sample_onehot_st(lp, gen)
    assert torch.all(s.detach().sum(-1) == 1.0)
    freq = s.detach().mean(0).squeeze()
    torch.testing.assert_close(freq, torch.full((4,), 0.25), atol=0.03, rtol=0.0)
    (g,) = torch.autograd.grad(s[:, 0, 0].sum(), lp)
    assert torch.any(g != 0)  # straight-through: gradients reach the probabilities


def test_actor_objective_hand_values() -> None:
    v, dist, delta, cost = torch.tensor(2.0), torch.tensor(3.0), 1.0, torch.tensor(-0.5)
    # (1 − .25)(1 − .5)·2 − .25(1 − .5)(3 − 1) − .5·(−.5) = .75 − .25 + .25
    j = actor_objective(v, dist, delta, cost, torch.tensor(0.25), torch.tensor(0.5))
    assert float(j) == pytest.approx(0.75)
    zero, one = torch.tensor(0.0), torch.tensor(1.0)
    assert float(actor_objective(v, dist, delta, cost, zero, zero)) == pytest.approx(2.0)
    assert float(actor_objective(v, dist, delta, cost, one, zero)) == pytest.approx(-2.0)
    assert float(actor_objective(v, dist, delta, cost, zero, one)) == pytest.approx(0.5)
    assert float(actor_objective(v, dist, delta, cost, one, one)) == pytest.approx(0.5)


def test_any_ahead_hand_worked() -> None:
    """Column 0 flags step 2 only: steps 0–2 see it ahead, step 3 does not; column 1 has no
    flag; column 2 flags the last step, which every step sees."""
    flag = torch.tensor(
        [[False, False, False], [False, False, False], [True, False, False], [False, False, True]]
    )
    want = torch.tensor([[1.0, 0.0, 1.0], [1.0, 0.0, 1.0], [1.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    assert torch.equal(any_ahead(flag), want)
    assert any_ahead(flag).dtype == torch.float32


def test_cap_safe_margin_hand_worked() -> None:
    """Cap 0.1: −0.3 and −0.2 (deep inside the safe set) become −0.1; −0.05, 0 and a violation
    of 0.4 pass unchanged, and so does their gradient, while the clipped ones get none."""
    c = torch.tensor([-0.3, -0.2, -0.05, 0.0, 0.4], requires_grad=True)
    out = cap_safe_margin(c, 0.1)
    assert torch.allclose(out, torch.tensor([-0.1, -0.1, -0.05, 0.0, 0.4]))
    out.sum().backward()
    assert c.grad is not None
    assert torch.equal(c.grad, torch.tensor([0.0, 0.0, 1.0, 1.0, 1.0]))


def test_mahalanobis_matches_scipy() -> None:
    from scipy.spatial.distance import mahalanobis as sp_mahal

    from ursa.kde import whitening_matrix

    rng = np.random.default_rng(1)
    a = rng.normal(size=(3, 3))
    cov = a @ a.T + 0.1 * np.eye(3)
    x = rng.normal(size=(5, 3))
    w = torch.as_tensor(whitening_matrix(cov))
    got = mahalanobis(torch.as_tensor(x), w, eps=0.0).numpy()
    want = [sp_mahal(xi, np.zeros(3), np.linalg.inv(cov)) for xi in x]
    np.testing.assert_allclose(got, want, rtol=1e-10)


def test_percentile_update_ema() -> None:
    x = torch.arange(101, dtype=torch.float32)  # P5 = 5, P95 = 95
    low, high = percentile_update(torch.tensor(0.0), torch.tensor(0.0), x, 0.01)
    assert float(low) == pytest.approx(0.05) and float(high) == pytest.approx(0.95)
    low, high = percentile_update(torch.tensor(0.0), torch.tensor(0.0), x, 1.0)
    assert float(low) == pytest.approx(5.0) and float(high) == pytest.approx(95.0)


def test_tanh_normal_log_density() -> None:
    gen = torch.Generator().manual_seed(0)
    mean = torch.full((20000, 1), 0.3, dtype=torch.float64)
    std = torch.full((20000, 1), 0.5, dtype=torch.float64)
    a, logp = tanh_normal_sample(mean, std, gen)
    assert torch.all(a.abs() < 1.0)
    # change of variables: log π(a) = log N(atanh a) − log(1 − a²)
    u = torch.atanh(a)
    ref = torch.distributions.Normal(0.3, 0.5).log_prob(u).sum(-1) - torch.log1p(-a.pow(2)).sum(-1)
    torch.testing.assert_close(logp, ref, rtol=1e-6, atol=1e-6)
