"""What a collector runs: the world model's filter (encoder + RSSM posterior step) and the actor.

CPU, torch inference mode, one observation at a time. The carry holds the RSSM state and the
previous action; a reset-free collector keeps it forever (a fresh ``initial_carry`` only after a
restart). Weights travel as safetensors bytes (never pickle): :func:`pack_policy_weights`
writes them (the learner's ``policy_weights_bytes``), :meth:`Policy.load_weights_bytes` reads
them. In ``ursa`` mode the bytes carry the published VAE encoder too, so that the collector
computes φ (the features it commits to the repertoire) with the same encoder version.
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

from ursa.agent import Actor
from ursa.learner_config import LearnerConfig
from ursa.vae import VAE
from ursa.world_model import RSSM, Encoder

WEIGHTS_FORMAT = "ursa-policy-1"


@dataclass(frozen=True)
class PolicyCarry:
    """RSSM state h (1, deter), z (1, S·K) and the previous action (1, A)."""

    h: torch.Tensor
    z: torch.Tensor
    action: torch.Tensor


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
        self._gen = torch.Generator().manual_seed(seed)

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
        self.version = int(meta.get("version", -1)) if version is None else int(version)
        self.vae_version = int(meta.get("vae_version", 0))

    def initial_carry(self) -> PolicyCarry:
        """The RSSM's learned initial state and a zero previous action."""
        with torch.inference_mode():
            h, z = self.rssm.initial(1)
            return PolicyCarry(h.clone(), z.clone(), torch.zeros(1, self.act_dim))

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
        either way (DreamerV3; the actor was trained on samples). ``rng`` draws the action noise
        (the policy's own generator when None). Returns the action and
        the new carry (which remembers this action as the next step's previous action).
        """
        with torch.inference_mode():
            o = torch.as_tensor(np.asarray(obs, np.float32).reshape(1, self.obs_dim))
            embed = self.encoder(o)
            # latents are always sampled: the actor never saw a posterior mode in training
            h, z = self.rssm.obs_step(carry.h, carry.z, carry.action, embed, self._gen)
            feat = torch.cat([h, z], -1)
            if self.skill_dim:
                s = torch.as_tensor(np.asarray(skill, np.float32).reshape(1, self.skill_dim))
            else:
                s = torch.zeros(1, 0)
            mean, std = self.actor(feat, s)
            if explore:
                eps = (rng or self._rng).standard_normal(self.act_dim).astype(np.float32)
                u = mean + std * torch.as_tensor(eps)
            else:
                u = mean
            a = torch.tanh(u)
            return a[0].numpy().astype(np.float64), PolicyCarry(h, z, a)

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
