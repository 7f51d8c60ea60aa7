"""The collector's numpy inference path (ursa/policy_np.py) computes what the torch modules
compute: encoder, RSSM filter step, posterior, latent sample and actor, for the tiny and small
presets in every mode, with random (perturbed) weights that travel as safetensors bytes. Fast."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from ursa import policy_np
from ursa.learner_config import LearnerConfig, learner_preset
from ursa.policy import Policy, pack_policy_weights

torch.set_num_threads(1)

OBS, ACT, SKILL, FEAT_IN = 11, 4, 3, 5
CASES = [(p, m) for p in ("tiny", "small") for m in ("ursa", "ursa-supervised", "daydreamer")]


class TorchUniforms:
    """Stands in for ``Policy.latent_rng``: the uniforms that ``RSSM.obs_step`` draws with a
    ``torch.Generator().manual_seed(seed)``, so that the policy samples the same latents."""

    def __init__(self, seed: int) -> None:
        self.gen = torch.Generator().manual_seed(seed)

    def random(self, size: int, dtype: type = np.float64) -> np.ndarray:
        # the same shape as the torch sampler's draw for a (1, S, K) posterior
        return torch.rand((1, size, 1), generator=self.gen).numpy().reshape(size).astype(dtype)


def _config(preset: str, mode: str) -> LearnerConfig:
    return learner_preset(preset, mode=mode)  # type: ignore[arg-type]


def _policy(cfg: LearnerConfig, seed: int) -> Policy:
    feat_in = FEAT_IN if cfg.mode == "ursa" else None
    return Policy(cfg, OBS, ACT, SKILL, feat_in_dim=feat_in, seed=seed)


def _perturbed(cfg: LearnerConfig, seed: int = 1) -> Policy:
    """A policy whose torch modules have random weights: every parameter (LayerNorm scales and
    shifts, the zero-initialised actor head and the initial state included) moved by noise."""
    pol = _policy(cfg, seed)
    gen = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for mod in pol.modules().values():
            for p in mod.parameters():
                p.add_(0.3 * torch.randn(p.shape, generator=gen))
    return pol


def _loaded(src: Policy, seed: int = 7) -> Policy:
    """A fresh policy (other initial weights) that loads ``src``'s weights as bytes."""
    pol = _policy(src.config, seed)
    pol.load_weights_bytes(pack_policy_weights(src.modules(), version=5, vae_version=2))
    assert pol.version == 5
    return pol


def _close(got: np.ndarray, want: np.ndarray) -> None:
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-5)


def _t(x: np.ndarray) -> torch.Tensor:
    return torch.as_tensor(np.asarray(x, np.float32))


def _states(cfg: LearnerConfig, n: int, seed: int) -> dict[str, np.ndarray]:
    """n random inputs of a filter step: obs (wide range, for symlog), h, one-hot z, action,
    skill."""
    rng = np.random.default_rng(seed)
    k = cfg.classes
    z = np.eye(k, dtype=np.float32)[rng.integers(0, k, (n, cfg.stoch))].reshape(n, -1)
    return {
        "obs": (rng.normal(size=(n, OBS)) * rng.choice([0.1, 1.0, 30.0], (n, OBS))).astype(
            np.float32
        ),
        "h": np.tanh(rng.normal(size=(n, cfg.deter))).astype(np.float32),
        "z": z,
        "action": rng.uniform(-1, 1, (n, ACT)).astype(np.float32),
        "skill": rng.normal(size=(n, SKILL if cfg.uses_skills else 0)).astype(np.float32),
    }


@pytest.mark.parametrize(("preset", "mode"), CASES)
def test_deterministic_parts_match_torch(preset: str, mode: str) -> None:
    cfg = _config(preset, mode)
    src = _perturbed(cfg)
    p = _loaded(src).params
    x = _states(cfg, 6, seed=0)
    with torch.no_grad():
        h0, z0 = src.rssm.initial(1)
        embed = src.encoder(_t(x["obs"]))
        h = src.rssm.core(_t(x["h"]), _t(x["z"]), _t(x["action"]))
        post = src.rssm.post_probs(h, embed)
        mean, std = src.actor(torch.cat([h, _t(x["z"])], -1), _t(x["skill"]))
    _close(p.h_init, h0[0].numpy())
    _close(p.z_init, z0[0].numpy())
    # batched and single vectors (the policy's fast path) alike
    got_embed = policy_np.encode(x["obs"], p)
    got_h = policy_np.core(x["h"], x["z"], x["action"], p)
    got_post = policy_np.post_probs(h.numpy(), embed.numpy(), p)
    got_mean, got_std = policy_np.actor_dist(h.numpy(), x["z"], x["skill"], p)
    for i in range(len(x["obs"])):
        _close(policy_np.encode(x["obs"][i], p), got_embed[i])
        _close(policy_np.core(x["h"][i], x["z"][i], x["action"][i], p), got_h[i])
        _close(policy_np.post_probs(h[i].numpy(), embed[i].numpy(), p), got_post[i])
        m, s = policy_np.actor_dist(h[i].numpy(), x["z"][i], x["skill"][i], p)
        _close(m, got_mean[i])
        _close(s, got_std[i])
    _close(got_embed, embed.numpy())
    _close(got_h, h.numpy())
    _close(got_post, post.numpy())
    _close(got_mean, mean.numpy())
    _close(got_std, std.numpy())
    for arr in (got_embed, got_h, got_post, got_mean, got_std):
        assert arr.dtype == np.float32
    # the weights are far from trivial: the outputs vary with the inputs
    assert got_h.std(0).mean() > 0.05 and got_mean.std(0).mean() > 0.05
    assert np.all(got_std >= cfg.actor_min_std) and np.all(got_std <= cfg.actor_max_std)


def test_sample_matches_torch_sampler() -> None:
    cfg = _config("small", "ursa-supervised")
    rssm = _perturbed(cfg).rssm
    gen = torch.Generator().manual_seed(3)
    logits = 3.0 * torch.randn(200, cfg.stoch, cfg.classes, generator=gen)
    # some latents nearly deterministic, some near uniform
    logits[:50] *= 10.0
    logits[50:100] *= 0.01
    probs = policy_np.unimix_probs(logits.numpy(), cfg.unimix)
    for seed in range(3):
        u = torch.rand((200, cfg.stoch, 1), generator=torch.Generator().manual_seed(seed))
        want = rssm.sample(torch.as_tensor(probs), torch.Generator().manual_seed(seed))
        got = policy_np.sample_onehot(probs, u.numpy()[..., 0])
        np.testing.assert_array_equal(got.reshape(200, -1), want.numpy())
    # draws follow the probabilities
    rng = np.random.default_rng(0)
    p1 = probs[60]  # (S, K)
    counts = sum(policy_np.sample_onehot(p1, rng.random(cfg.stoch)) for _ in range(4000))
    np.testing.assert_allclose(counts / 4000, p1, atol=0.035)


@pytest.mark.parametrize(("preset", "mode"), CASES)
def test_act_matches_torch_modules(preset: str, mode: str) -> None:
    """A few steps of Policy.act against the torch modules, with the same latent draws."""
    cfg = _config(preset, mode)
    src = _perturbed(cfg)
    pol = _loaded(src)
    pol.latent_rng = TorchUniforms(11)  # type: ignore[assignment]
    gen = torch.Generator().manual_seed(11)
    x = _states(cfg, 5, seed=1)
    carry = pol.initial_carry()
    with torch.no_grad():
        h, z = src.rssm.initial(1)
    a_prev = torch.zeros(1, ACT)
    for t in range(5):
        skill = x["skill"][t] if cfg.uses_skills else None
        explore = t % 2 == 1
        eps_rng = np.random.default_rng(100 + t)
        a, carry = pol.act(carry, x["obs"][t], skill, explore=explore, rng=eps_rng)
        with torch.no_grad():
            embed = src.encoder(_t(x["obs"][t])[None])
            h, z = src.rssm.obs_step(h, z, a_prev, embed, gen)
            mean, std = src.actor(torch.cat([h, z], -1), _t(x["skill"][t])[None])
            u = mean
            if explore:
                eps = np.random.default_rng(100 + t).standard_normal(ACT).astype(np.float32)
                u = mean + std * torch.as_tensor(eps)
            a_prev = torch.tanh(u)
        assert a.shape == (ACT,) and a.dtype == np.float64
        _close(a, a_prev[0].numpy())
        _close(carry.h, h.numpy())
        np.testing.assert_array_equal(carry.z, z.numpy())
        assert carry.h.shape == (1, cfg.deter) and carry.z.shape == (1, cfg.stoch * cfg.classes)
        assert carry.action.shape == (1, ACT)
        _close(carry.action, a_prev.numpy())
        a_prev = torch.as_tensor(carry.action)  # follow the policy's own previous action


def test_latents_are_drawn_from_the_policy_seed() -> None:
    cfg = _config("tiny", "ursa-supervised")
    src = _perturbed(cfg)
    runs = []
    for seed in (7, 7, 8):
        pol = _loaded(src, seed=seed)
        carry = pol.initial_carry()
        zs = []
        for t in range(20):
            _, carry = pol.act(carry, np.full(OBS, 0.1 * t, np.float32), np.zeros(SKILL), False)
            zs.append(carry.z)
        runs.append(np.concatenate(zs))
    np.testing.assert_array_equal(runs[0], runs[1])
    assert not np.array_equal(runs[0], runs[2])


def test_bad_weights_keep_the_numpy_weights() -> None:
    cfg = _config("tiny", "ursa")
    pol = _loaded(_perturbed(cfg))
    before = pol.params
    other = _perturbed(dataclasses.replace(cfg, units=32))
    with pytest.raises(ValueError):
        pol.load_weights_bytes(pack_policy_weights(other.modules(), 1, 1))
    assert pol.params is before
    # features (the VAE encoder) still work
    phi = pol.features(np.zeros((3, FEAT_IN)))
    assert phi.shape == (3, SKILL) and phi.dtype == np.float64


def test_carry_is_not_modified_in_place() -> None:
    cfg = _config("tiny", "daydreamer")
    pol = _loaded(_perturbed(cfg))
    carry = pol.initial_carry()
    saved = [f.copy() for f in (carry.h, carry.z, carry.action)]
    for _ in range(3):
        pol.act(carry, np.ones(OBS, np.float32), None, explore=True)
    for f, s in zip((carry.h, carry.z, carry.action), saved, strict=True):
        np.testing.assert_array_equal(f, s)
    np.testing.assert_array_equal(pol.initial_carry().h, saved[0])
