"""What a collector runs: the world model's filter (encoder + RSSM posterior step) and the actor.

CPU, one observation at a time, in numpy (:mod:`ursa.policy_np`): the torch modules hold the
weights (and validate loaded ones), and every load copies them into float32 arrays that
:meth:`Policy.act` computes with, a few times faster than torch eager at batch 1. The carry holds
the RSSM state and the previous action; a reset-free collector keeps it forever (a fresh
``initial_carry`` only after a restart). Weights travel as safetensors bytes (never pickle):
:func:`pack_policy_weights` writes them (the learner's ``policy_weights_bytes``),
:meth:`Policy.load_weights_bytes` reads them. In ``ursa`` mode the bytes carry the published VAE
encoder too, so that the collector computes φ (the features it commits to the repertoire) with
the same encoder version.
"""

from __future__ import annotations

import json
import struct
from dataclasses import dataclass

import numpy as np
import torch
from safetensors.torch import load as st_load
from safetensors.torch import save as st_save
from torch import nn

from ursa import policy_np
from ursa.agent import Actor
from ursa.learner_config import LearnerConfig
from ursa.vae import VAE
from ursa.world_model import RSSM, Encoder

WEIGHTS_FORMAT = "ursa-policy-1"


@dataclass(frozen=True)
class PolicyCarry:
    """RSSM state h (1, deter), z (1, S·K) and the previous action (1, A), float32 arrays
    (never modified in place)."""

    h: np.ndarray
    z: np.ndarray
    action: np.ndarray


def pack_policy_weights(modules: dict[str, nn.Module], version: int, vae_version: int) -> bytes:
    """safetensors bytes of the named modules' state dicts (keys ``name.param``), with the
    policy ``version`` and the encoder's ``vae_version`` as metadata."""
    tensors = {
        f"{name}.{k}": v.detach().to("cpu").contiguous()
        for name, mod in modules.items()
        for k, v in mod.state_dict().items()
    }
    meta = {"format": WEIGHTS_FORMAT, "version": str(version), "vae_version": str(vae_version)}
    return st_save(tensors, metadata=meta)


class Policy:
    """Skill-conditioned policy of a collector; see the module docstring."""

    def __init__(
        self,
        config: LearnerConfig,
        obs_dim: int,
        act_dim: int,
        skill_dim: int,
        feat_in_dim: int | None = None,
        seed: int = 0,
    ) -> None:
        self.config = config
        self.obs_dim, self.act_dim = obs_dim, act_dim
        self.skill_dim = skill_dim if config.uses_skills else 0
        if config.mode == "ursa" and feat_in_dim is None:
            raise ValueError("ursa mode needs feat_in_dim (the VAE input size)")
        with torch.random.fork_rng(devices=[]):  # seed the initial weights, leave global RNG
            torch.manual_seed(seed)
            self.encoder = Encoder(config, obs_dim)
            self.rssm = RSSM(config, self.encoder.out_dim, act_dim)
            self.actor = Actor(config, self.rssm.feat_dim, self.skill_dim, act_dim)
            self.vae: VAE | None = None
            if config.mode == "ursa" and feat_in_dim is not None:
                self.vae = VAE(feat_in_dim, skill_dim, config.vae_units, config.vae_layers)
        for m in self.modules().values():
            m.eval()
            m.requires_grad_(False)
        self.version = -1
        """Version of the loaded weights (-1: initial weights)."""
        self.vae_version = 0
        self._rng = np.random.default_rng(seed)
        self.latent_rng = np.random.default_rng([seed, 1])
        """Draws the RSSM latents: ``random(S, dtype=np.float32)``, S uniforms per step."""
        self.params = policy_np.policy_params(self.encoder, self.rssm, self.actor)
        """The weights :meth:`act` computes with (copied at every load)."""

    def modules(self) -> dict[str, nn.Module]:
        """The modules whose weights travel, by name."""
        mods: dict[str, nn.Module] = {
            "encoder": self.encoder,
            "rssm": self.rssm,
            "actor": self.actor,
        }
        if self.vae is not None:
            mods["vae"] = self.vae
        return mods

    def load_weights_bytes(self, b: bytes, version: int | None = None) -> None:
        """Load weights written by :func:`pack_policy_weights`; ``version`` overrides the one
        stored in the bytes. Every tensor must match by name and shape, else ValueError and the
        current weights stay untouched (a collector counts and drops such a message)."""
        try:
            tensors = st_load(bytes(b))
            meta = _metadata(b)
        except Exception as e:  # safetensors raises its own error type on garbage
            raise ValueError(f"unreadable policy weights: {e}") from e
        mods = self.modules()
        parts: dict[str, dict[str, torch.Tensor]] = {name: {} for name in mods}
        for key, v in tensors.items():
            name, _, rest = key.partition(".")
            if name not in parts:
                raise ValueError(f"unexpected tensor {key!r} in policy weights")
            parts[name][rest] = v
        for name, mod in mods.items():
            own = mod.state_dict()
            got = parts[name]
            if set(own) != set(got):
                raise ValueError(f"policy weights for {name!r} have other tensors")
            for k, v in own.items():
                if v.shape != got[k].shape or v.dtype != got[k].dtype:
                    raise ValueError(f"{name}.{k}: {tuple(got[k].shape)} != {tuple(v.shape)}")
        for name, mod in mods.items():
            mod.load_state_dict(parts[name], strict=True)
        self.params = policy_np.policy_params(self.encoder, self.rssm, self.actor)
        self.version = int(meta.get("version", -1)) if version is None else int(version)
        self.vae_version = int(meta.get("vae_version", 0))

    def initial_carry(self) -> PolicyCarry:
        """The RSSM's learned initial state and a zero previous action."""
        p = self.params
        return PolicyCarry(
            p.h_init[None].copy(), p.z_init[None].copy(), np.zeros((1, self.act_dim), np.float32)
        )

    def act(
        self,
        carry: PolicyCarry,
        obs: np.ndarray,
        skill: np.ndarray | None,
        explore: bool = True,
        rng: np.random.Generator | None = None,
    ) -> tuple[np.ndarray, PolicyCarry]:
        """Filter ``obs`` (obs_dim,) and choose an action (A,) in [−1, 1] for ``skill`` (D,).

        ``explore``: sample the action instead of taking tanh(mean); the RSSM latent is sampled
        either way (DreamerV3; the actor was trained on samples), with :attr:`latent_rng`.
        ``rng`` draws the action noise (the policy's own generator when None). Returns the
        action and the new carry (which remembers this action as the next step's previous
        action).
        """
        p = self.params
        o = np.asarray(obs, np.float32).reshape(self.obs_dim)
        # latents are always sampled: the actor never saw a posterior mode in training
        u = self.latent_rng.random(p.stoch, dtype=np.float32)
        # single vectors (numpy's fast path); the carry keeps a leading batch axis of 1
        h, z = policy_np.filter_step(carry.h[0], carry.z[0], carry.action[0], o, u, p)
        if self.skill_dim:
            s = np.asarray(skill, np.float32).reshape(self.skill_dim)
        else:
            s = np.zeros(0, np.float32)
        mean, std = policy_np.actor_dist(h, z, s, p)
        if explore:
            eps = (rng or self._rng).standard_normal(self.act_dim).astype(np.float32)
            mean = mean + std * eps
        a = np.tanh(mean)
        return a.astype(np.float64), PolicyCarry(h[None], z[None], a[None])

    def features(self, inputs: np.ndarray) -> np.ndarray:
        """φ (M, D) of feature inputs (M, F): the VAE encoder in ``ursa`` mode, the inputs
        themselves (a provided φ) otherwise."""
        if self.vae is not None:
            return self.vae.encode(inputs)
        return np.asarray(inputs, dtype=np.float64)


def _metadata(b: bytes) -> dict[str, str]:
    """The ``__metadata__`` of safetensors bytes (its JSON header)."""
    (n,) = struct.unpack("<Q", b[:8])
    header = json.loads(b[8 : 8 + n])
    meta = header.get("__metadata__", {})
    return dict(meta) if isinstance(meta, dict) else {}
