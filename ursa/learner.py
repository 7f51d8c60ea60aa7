"""The URSA learner (paper Alg. 2): world model, then imagination with V, ψ, C, λ1, λ2 and π,
then the VAE (``ursa`` mode). Pure core code: a service feeds it replay batches and repertoire
snapshots, and ships :meth:`Learner.policy_weights_bytes` to collectors.

One ``train_step``:

1. World model on the replayed batch (B, T): KL-balanced RSSM, decoder, reward, cost, φ heads.
   φ targets are the replay's ``features`` (``ursa-supervised``) or the published VAE encoder
   applied to them (``ursa``).
2. Imagination: from the B·T posterior states (or ``imag_starts`` of them), each with its own
   skill z drawn from the repertoire's KDE, H steps of the actor in the model.
3. λ-returns of the reward (V), of (1 − γ)·φ (m = (1 − γ)ψ) and of the cost (C), bootstrapped
   from the online critics (the slow critics regularise them, as in DreamerV3 and QDAC-MB).
   The actor maximises J_π (§4.1) by backpropagating through the dynamics; the critics
   regress the returns; λ1 and λ2 are trained by binary cross-entropy to predict whether
   ‖m − z‖_Σ > δ and C > 0.
4. ``ursa`` mode: one VAE step on the repertoire's stored inputs; a new encoder version is
   published every ``vae_publish_every`` updates.

See docs/learner.md for the choices and their reasons.
"""

from __future__ import annotations

import contextlib
import os
import time
from collections.abc import Iterator, Mapping
from dataclasses import asdict, dataclass
from typing import Any, Protocol

import numpy as np
import torch
from torch import nn

from ursa import kde
from ursa.agent import (
    Actor,
    Critics,
    Multiplier,
    ReturnNorm,
    actor_objective,
    any_ahead,
    cap_safe_margin,
    frozen_copy,
    joint_input,
    lambda_return,
    mahalanobis,
    whitened_sq,
)
from ursa.distributions import normal_entropy, tanh_normal_logp, two_hot_loss2, two_hot_mean
from ursa.learner_config import LearnerConfig
from ursa.networks import compute_dtype, resolve_compute_dtype, weight_casts_cached
from ursa.policy import pack_policy_weights
from ursa.rundir import atomic_write
from ursa.safety_floor import floor_step
from ursa.vae import VAE
from ursa.world_model import WorldModel


class _RepertoireLike(Protocol):
    encoder_version: int

    @property
    def skills(self) -> np.ndarray: ...
    @property
    def inputs(self) -> np.ndarray: ...
    @property
    def cov(self) -> np.ndarray: ...

    def delta(self) -> float: ...
    def support(self) -> float | None: ...


@dataclass(frozen=True)
class SkillSnapshot:
    """What the learner needs from the repertoire: the KDE (points + Σ), δ and, for a learned
    φ, the stored VAE inputs."""

    skills: np.ndarray
    """Stored skills (N, D)."""
    cov: np.ndarray
    """KDE kernel covariance Σ (D, D); also the metric of the skill distance and of δ."""
    delta: float
    """δ in that metric."""
    inputs: np.ndarray | None = None
    """VAE inputs (N, F) of the stored skills (``ursa`` mode), else None."""
    version: int = 0
    """Encoder version the skills are encoded with."""
    box: tuple[np.ndarray, np.ndarray] | None = None
    """(low, high) (D,) each: the skill box of the feature function (``ursa.bounds``); KDE
    draws are truncated to it. None: the untruncated KDE."""
    support: float | None = None
    """KDE draws are truncated to within this d_Σ of a stored skill (``Repertoire.support``,
    applied with ``box``). None: no support truncation."""

    @classmethod
    def from_repertoire(cls, rep: _RepertoireLike) -> SkillSnapshot:
        """Snapshot of an ``ursa.repertoire.Repertoire`` (its ``bounds`` become ``box``)."""
        inputs = rep.inputs
        bounds = getattr(rep, "bounds", None)
        return cls(
            skills=np.asarray(rep.skills, np.float64),
            cov=np.asarray(rep.cov, np.float64),
            delta=float(rep.delta()),
            inputs=np.asarray(inputs, np.float64) if inputs.shape[-1] else None,
            version=int(rep.encoder_version),
            box=None if bounds is None else (np.asarray(bounds.low), np.asarray(bounds.high)),
            support=rep.support(),
        )


@dataclass(frozen=True)
class _SkillContext:
    """The skills of one imagination: z (N, D), the whitening A (D, D) of δ's metric and the
    enforced δ (``delta_scale`` · δ)."""

    skill: torch.Tensor
    whiten: torch.Tensor
    delta: float


@dataclass(frozen=True)
class _Losses:
    """The losses of one imagination, each minimised by its own optimiser step."""

    actor: torch.Tensor
    critic: torch.Tensor
    multipliers: torch.Tensor | None


def _clip_step(opt: torch.optim.Optimizer, params: list[nn.Parameter], clip: float) -> float:
    norm = float(torch.nn.utils.clip_grad_norm_(params, clip))
    opt.step()
    return norm


class Learner:
    """World model + actor-critic + multipliers (+ VAE); see the module docstring.

    obs_dim, act_dim: env sizes. feat_in_dim: F, the width of the replay's ``features`` (the
    VAE input in ``ursa`` mode, φ itself in ``ursa-supervised``; ignored by ``daydreamer``).
    skill_dim: D; defaults to F (supervised), ``config.skill_dim`` (ursa), 0 (daydreamer).
    """

    def __init__(
        self,
        config: LearnerConfig,
        obs_dim: int,
        act_dim: int,
        feat_in_dim: int,
        skill_dim: int | None = None,
    ) -> None:
        c = config
        self.config = c
        self.obs_dim, self.act_dim, self.feat_in_dim = obs_dim, act_dim, feat_in_dim
        if not c.uses_skills:
            skill_dim = 0
        elif skill_dim is None:
            skill_dim = c.skill_dim if c.mode == "ursa" else feat_in_dim
        self.skill_dim = int(skill_dim)
        self.device = torch.device(c.device)
        self.compute = resolve_compute_dtype(c.compute_dtype, self.device)
        """The dtype the networks' layers run in during an update (None: float32)."""
        self.profile = False
        """Synchronise the device around each timed phase (accurate GPU timings, slower)."""
        dev = self.device
        skills_on = c.uses_skills
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(c.seed)
            self.wm = WorldModel(c, obs_dim, act_dim, self.skill_dim, cost_head=skills_on).to(dev)
            f, d = self.wm.feat_dim, self.skill_dim
            self.actor = Actor(c, f, d, act_dim).to(dev)
            self.critics = Critics(c, f, d, self.wm.bins, skills=skills_on).to(dev)
            self.lam1: Multiplier | None = None
            self.lam2: Multiplier | None = None
            if skills_on:
                self.lam1 = Multiplier(c, f, d).to(dev)
                self.lam2 = Multiplier(c, f, d).to(dev)
            self.vae: VAE | None = None
            self.vae_pub: VAE | None = None
            if c.mode == "ursa":
                self.vae = VAE(feat_in_dim, d, c.vae_units, c.vae_layers).to(dev)
                self.vae_pub = frozen_copy(self.vae)
        self.retnorm_v = ReturnNorm(c.retnorm_rate, c.retnorm_limit).to(dev)
        self.retnorm_c = ReturnNorm(c.retnorm_rate, c.retnorm_limit).to(dev)

        def adam(mods: list[nn.Module], lr: float, eps: float) -> torch.optim.Adam:
            return torch.optim.Adam([p for m in mods for p in m.parameters()], lr=lr, eps=eps)

        self.model_opt = adam([self.wm], c.model_lr, c.model_eps)
        self.actor_opt = adam([self.actor], c.actor_lr, c.ac_eps)
        self.critic_opt = torch.optim.Adam(
            self.critics.online_parameters(), lr=c.critic_lr, eps=c.ac_eps
        )
        self.lagrange_opt = (
            adam([self.lam1, self.lam2], c.lagrange_lr, c.ac_eps)  # type: ignore[list-item]
            if self.lam1 is not None
            else None
        )
        self.vae_opt = adam([self.vae], c.vae_lr, c.model_eps) if self.vae is not None else None
        # None at w = 1: the plain cross-entropy, without a per-update tensor or multiply
        self._lam2_pos_weight = (
            None if c.lambda2_pos_weight == 1.0 else torch.tensor(c.lambda2_pos_weight, device=dev)
        )
        self.gen = torch.Generator(device=dev).manual_seed(c.seed)
        self.np_rng = np.random.default_rng(c.seed)
        self.updates = 0
        """Train steps done."""
        self.vae_version = 0
        """Published encoder versions (0: the initial encoder)."""
        self.lam2_floor = 0.0
        """The integrating floor under λ2 (``lambda2_floor_lr``; 0 while it is off)."""

    # --- helpers -------------------------------------------------------------------------------

    def _sync(self) -> None:
        if self.profile and self.device.type == "cuda":
            torch.cuda.synchronize(self.device)

    def _tensors(self, batch: dict[str, np.ndarray]) -> dict[str, torch.Tensor]:
        dev = self.device
        out = {
            k: torch.as_tensor(np.asarray(batch[k], np.float32), device=dev)
            for k in ("obs", "action", "reward")
        }
        b, t = out["reward"].shape
        out["cost"] = torch.as_tensor(
            np.asarray(batch["cost"], np.float32)
            if "cost" in batch
            else np.zeros((b, t), np.float32),
            device=dev,
        )
        out["is_first"] = torch.as_tensor(np.asarray(batch["is_first"], bool), device=dev)
        if self.config.uses_skills and "features" in batch:
            out["features"] = torch.as_tensor(np.asarray(batch["features"], np.float32), device=dev)
        return out

    def _phi_targets(self, data: dict[str, torch.Tensor]) -> torch.Tensor | None:
        if self.config.mode == "ursa-supervised":
            return data["features"]
        if self.vae_pub is not None:
            with torch.no_grad():
                return self.vae_pub(data["features"])
        return None

    # --- training ------------------------------------------------------------------------------

    @contextlib.contextmanager
    def _phase(self, name: str, times: dict[str, float]) -> Iterator[None]:
        """Time one phase of the update (synchronising the device when profiling)."""
        t0 = time.perf_counter()
        yield
        self._sync()
        times[name] = time.perf_counter() - t0

    def train_step(
        self,
        batch: dict[str, np.ndarray],
        skills: SkillSnapshot | None = None,
        violation_rate: float | None = None,
    ) -> dict[str, float]:
        """One update on a replay batch (dict of (B, T, ...) arrays with ``is_first``) with the
        repertoire snapshot ``skills`` (required unless ``daydreamer``). ``violation_rate``: the
        acting policy's recent real violation rate (``ursa.safety_floor.ema_rate``), which
        moves λ2's floor when ``lambda2_floor_lr`` > 0 (None: the floor stays). Returns scalar
        metrics, including the seconds spent in each phase (``time/*``).

        Each phase owns its loss and its optimiser step: world model, imagination (returns and
        the losses of actor, critics and multipliers), actor, critics, multipliers, VAE.
        """
        c = self.config
        if c.uses_skills and skills is None:
            raise ValueError(f"mode {c.mode!r} needs a SkillSnapshot")
        times: dict[str, float] = {}
        metrics: dict[str, torch.Tensor | float] = {}
        if c.lambda2_floor_lr > 0.0 and c.uses_skills:
            if violation_rate is not None:
                self.lam2_floor = floor_step(
                    self.lam2_floor,
                    violation_rate,
                    c.lambda2_floor_target,
                    c.lambda2_floor_lr,
                    c.lambda2_floor_max,
                )
                metrics["lambda2/real_rate"] = float(violation_rate)
            metrics["lambda2/floor"] = self.lam2_floor
        with compute_dtype(self.compute):
            with self._phase("wm", times), weight_casts_cached(self.device):
                h, z = self._world_model_step(self._tensors(batch), metrics, skills)
            with self._phase("imagination", times), weight_casts_cached(self.device):
                ctx = self._skill_context(h.shape[0], skills)
                losses = self._imagination_losses(h, z, ctx, metrics)
            with self._phase("actor", times):
                self._actor_step(losses.actor, metrics)
            with self._phase("critics", times):
                self._critic_step(losses.critic)
            with self._phase("multipliers", times):
                self._multiplier_step(losses.multipliers)
        with self._phase("vae", times):
            if self.vae is not None and skills is not None and skills.inputs is not None:
                metrics.update(self._vae_step(skills.inputs))
        self.updates += 1
        if self.vae is not None and self.updates % c.vae_publish_every == 0:
            self.publish_encoder()
        out = {k: float(v) for k, v in metrics.items()}
        out.update({f"time/{k}": v for k, v in times.items()})
        out["updates"] = float(self.updates)
        out["vae_version"] = float(self.vae_version)
        return out

    def _world_model_step(
        self,
        data: dict[str, torch.Tensor],
        metrics: dict[str, torch.Tensor | float],
        skills: SkillSnapshot | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """World-model loss and step on the batch (the φ head's error in the metric of the
        snapshot's Σ when ``phi_metric`` is ``skill``); returns the imagination's start states
        h (N, deter), z (N, S·K): all B·T posterior states, or ``imag_starts`` of them."""
        c = self.config
        whiten = None
        if c.phi_metric == "skill" and skills is not None and self.skill_dim:
            whiten = self._whitening(skills)
        wm_loss, wm_metrics, post = self.wm.loss(data, self._phi_targets(data), self.gen, whiten)
        self.model_opt.zero_grad(set_to_none=True)
        wm_loss.backward()
        metrics["wm/grad_norm"] = _clip_step(
            self.model_opt, list(self.wm.parameters()), c.model_clip
        )
        metrics.update(wm_metrics)
        h = post["h"].detach().flatten(0, 1)
        z = post["z"].detach().flatten(0, 1)
        n = h.shape[0]
        if 0 < c.imag_starts < n:
            idx = torch.randperm(n, generator=self.gen, device=self.device)[: c.imag_starts]
            h, z = h[idx], z[idx]
        return h, z

    def _skill_context(self, n: int, skills: SkillSnapshot | None) -> _SkillContext:
        """One KDE skill per start state, the whitening of δ's metric and the enforced δ."""
        c = self.config
        if not self.skill_dim:
            return _SkillContext(
                torch.zeros(n, 0, device=self.device), torch.zeros(0, 0, device=self.device), 0.0
            )
        assert skills is not None
        if skills.box is None:
            zs = kde.kde_sample(skills.skills, skills.cov, n, self.np_rng)
        else:
            zs = kde.kde_sample_in_box(
                skills.skills, skills.cov, n, self.np_rng, *skills.box, support=skills.support
            )
        return _SkillContext(
            torch.as_tensor(zs, dtype=torch.float32, device=self.device),
            self._whitening(skills),
            c.delta_scale * float(skills.delta),
        )

    def _whitening(self, skills: SkillSnapshot) -> torch.Tensor:
        """A (D, D) with A Σ Aᵀ = I for the snapshot's Σ: the metric of δ."""
        a = kde.whitening_matrix(kde.regularize_cov(skills.cov))
        return torch.as_tensor(a, dtype=torch.float32, device=self.device)

    def _imagination_losses(
        self,
        h: torch.Tensor,
        z: torch.Tensor,
        ctx: _SkillContext,
        metrics: dict[str, torch.Tensor | float],
    ) -> _Losses:
        """Imagine H steps from (h, z) with one skill each, compute the λ-returns of V, ψ and C
        and the losses of the actor, the critics and the multipliers.

        ``actor_grad="dynamics"``: the rollout keeps its graph and the actor's loss is −J, whose
        gradient reaches the actions through the model and the online critics.
        ``"reinforce"``: the rollout and the returns carry no graph; the actor's loss is
        −log π(a | s, z) · sg(J(returns) − J(critics at s)), the baseline being J of the online
        critics' predictions at the same state with the same λs.
        """
        c = self.config
        reinforce = c.actor_grad == "reinforce"
        skill, whiten, delta = ctx.skill, ctx.whiten, ctx.delta
        hor, bins = c.imag_horizon, self.wm.bins

        def act(feat: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
            return self.actor.sample(feat, skill, self.gen)

        with torch.no_grad() if reinforce else contextlib.nullcontext():
            traj = self.wm.imagine(h, z, act, hor, self.gen)
            pred = self.wm.predict(traj.feat[1:])
        feat = traj.feat
        sk = skill.unsqueeze(0).expand(hor + 1, -1, -1)
        fd, skd = feat[:-1].detach(), sk[:-1]

        def grad_or_not(x: torch.Tensor) -> torch.Tensor:
            # REINFORCE's returns are targets only; through the dynamics they are the objective
            return x.detach() if reinforce else x

        # Returns bootstrap from the online critics (DreamerV3, QDAC-MB); the slow critics only
        # regularise the critics' outputs. One critic forward serves the returns and the critic
        # losses.
        x = joint_input(feat, sk)  # (H + 1, N, F + D), one cast for every critic
        xd = x[:-1].detach()
        online = self.critics.online(x, sk)
        slow = self.critics.slow(xd, skd)
        v_logits = online.value_logits
        v_all = two_hot_mean(v_logits, bins)
        ret_v = lambda_return(pred["reward"], grad_or_not(v_all), c.discount, c.return_lambda)
        self.retnorm_v.update(ret_v)
        scale_v = self.retnorm_v.scale()
        objective = ret_v / scale_v
        baseline = v_all[:-1].detach() / scale_v
        slow_v = two_hot_mean(slow.value_logits, bins)
        critic_loss = two_hot_loss2(v_logits[:-1], ret_v, slow_v, c.slow_critic_reg, bins)
        weight = c.discount ** torch.arange(hor, device=self.device, dtype=torch.float32)
        weight = weight.unsqueeze(1)
        metrics["critic/value"] = (weight * critic_loss).mean().detach()
        lam_loss: torch.Tensor | None = None
        if online.sf is not None and online.cost_logits is not None:
            assert self.lam1 is not None and self.lam2 is not None
            assert slow.sf is not None and slow.cost_logits is not None
            m_all = online.sf
            ret_m = lambda_return(
                (1.0 - c.discount) * pred["phi"], grad_or_not(m_all), c.discount, c.return_lambda
            )
            dist = mahalanobis(ret_m - skill, whiten)
            c_logits = online.cost_logits
            c_all = two_hot_mean(c_logits, bins)
            cost = pred["cost"]
            if c.cost_margin_cap is not None:
                cost = cap_safe_margin(cost, c.cost_margin_cap)
            ret_c = lambda_return(cost, grad_or_not(c_all), c.gamma_cost, c.return_lambda)
            self.retnorm_c.update(ret_c)
            scale_c = self.retnorm_c.scale()
            logit1 = self.lam1.logit(xd)
            logit2 = self.lam2.logit(xd)
            lam1, lam2 = torch.sigmoid(logit1).detach(), torch.sigmoid(logit2).detach()
            lam2_net = lam2
            if self.lam2_floor > 0.0:
                # the actor's weight of the cost; λ2's own loss still trains the network
                lam2 = lam2.clamp(min=self.lam2_floor)
            objective = actor_objective(objective, dist, delta, ret_c / scale_c, lam1, lam2)
            if reinforce:
                with torch.no_grad():
                    base_dist = mahalanobis(m_all[:-1] - skill, whiten)
                baseline = actor_objective(
                    baseline, base_dist, delta, c_all[:-1].detach() / scale_c, lam1, lam2
                )
            slow_m, slow_c = slow.sf, two_hot_mean(slow.cost_logits, bins)
            # squared errors in the whitened metric of δ: invariant to the features' scale
            sf_loss = whitened_sq(m_all[:-1] - ret_m.detach(), whiten) + (
                c.slow_critic_reg * whitened_sq(m_all[:-1] - slow_m, whiten)
            )
            cost_loss = two_hot_loss2(c_logits[:-1], ret_c, slow_c, c.slow_critic_reg, bins)
            critic_loss = critic_loss + sf_loss + cost_loss
            # multipliers rise where their constraint is violated and fall where it holds
            viol1 = (dist.detach() > delta).float()
            viol2 = (ret_c.detach() > 0.0).float()
            if c.lambda2_label == "step":
                viol2 = torch.maximum(viol2, any_ahead(cost.detach() > 0.0))
            bce = nn.functional.binary_cross_entropy_with_logits
            l1 = (weight * bce(logit1, viol1, reduction="none")).mean()
            pw2 = self._lam2_pos_weight
            l2 = (weight * bce(logit2, viol2, reduction="none", pos_weight=pw2)).mean()
            lam_loss = l1 + l2
            metrics.update(
                {
                    "critic/sf": (weight * sf_loss).mean().detach(),
                    "critic/cost": (weight * cost_loss).mean().detach(),
                    "lambda1/mean": lam1.mean(),
                    "lambda2/mean": lam2_net.mean(),
                    "lambda2/actor_weight": lam2.mean(),
                    "lambda1/loss": l1.detach(),
                    "lambda2/loss": l2.detach(),
                    "lambda1/violated": viol1.mean(),
                    "lambda2/violated": viol2.mean(),
                    "imag/distance": dist.detach().mean(),
                    "imag/within_delta": 1.0 - viol1.mean(),
                    "imag/cost_return": ret_c.detach().mean(),
                    "ret/cost_scale": scale_c,
                    "delta": delta,
                }
            )
        if reinforce:
            mean, std = self.actor(fd, skd)
            logp = tanh_normal_logp(mean, std, traj.pre)
            adv = (objective - baseline).detach()
            entropy_reg = normal_entropy(std)
            actor_loss = -(weight * logp * adv).mean()
            metrics["actor/advantage"] = adv.abs().mean()
            entropy = -logp.detach()
        else:
            entropy = -traj.logp
            entropy_reg = entropy
            actor_loss = -(weight * objective).mean()
        actor_loss = actor_loss - c.actor_entropy * (weight * entropy_reg).mean()
        if c.actor_mean_bound > 0.0:
            # a pre-tanh mean past the bound saturates tanh, where the objective's gradient
            # vanishes: the mean drifts there in flat regions and cannot come back
            mu = mean if reinforce else self.actor(fd, skd)[0]
            excess = (mu.abs() - c.actor_mean_bound).clamp(min=0.0)
            sat = excess.pow(2).sum(-1)
            actor_loss = actor_loss + (weight * sat).mean()
            metrics["actor/mean_excess"] = excess.detach().mean()
        metrics["actor/loss"] = actor_loss.detach()
        metrics["actor/entropy"] = entropy.detach().mean()
        metrics["ret/value"] = ret_v.detach().mean()
        metrics["ret/value_scale"] = scale_v
        return _Losses(actor_loss, (weight * critic_loss).mean(), lam_loss)

    def _actor_step(self, loss: torch.Tensor, metrics: dict[str, torch.Tensor | float]) -> None:
        """Actor step: only the actor's parameters get gradients (the critics' and multipliers'
        graphs are kept for their own steps)."""
        params = list(self.actor.parameters())
        grads = torch.autograd.grad(loss, params, retain_graph=True)
        for p, g in zip(params, grads, strict=True):
            p.grad = g
        metrics["actor/grad_norm"] = _clip_step(self.actor_opt, params, self.config.ac_clip)
        self.actor_opt.zero_grad(set_to_none=True)

    def _critic_step(self, loss: torch.Tensor) -> None:
        """V, ψ, C step (gradients to their own weights only); the slow copies follow by EMA."""
        c = self.config
        cparams = self.critics.online_parameters()
        grads = torch.autograd.grad(loss, cparams)
        for p, g in zip(cparams, grads, strict=True):
            p.grad = g
        _clip_step(self.critic_opt, cparams, c.ac_clip)
        self.critic_opt.zero_grad(set_to_none=True)
        self.critics.update_slow(c.slow_critic_fraction)

    def _multiplier_step(self, loss: torch.Tensor | None) -> None:
        """λ1, λ2 step (their inputs are detached: the graph holds only their own weights)."""
        if loss is None or self.lagrange_opt is None:
            return
        self.lagrange_opt.zero_grad(set_to_none=True)
        loss.backward()
        lam_params = [p for m in (self.lam1, self.lam2) if m for p in m.parameters()]
        _clip_step(self.lagrange_opt, lam_params, self.config.ac_clip)

    def _vae_step(self, inputs: np.ndarray) -> dict[str, torch.Tensor]:
        assert self.vae is not None and self.vae_opt is not None
        c = self.config
        if len(inputs) == 0:
            return {}
        rows = self.np_rng.integers(0, len(inputs), size=min(c.vae_batch, len(inputs)))
        x = torch.as_tensor(inputs[rows], dtype=torch.float32, device=self.device)
        self.vae.update_stats(x)
        loss, metrics = self.vae.loss(x, c.vae_beta, self.gen)
        self.vae_opt.zero_grad(set_to_none=True)
        loss.backward()
        _clip_step(self.vae_opt, list(self.vae.parameters()), c.model_clip)
        metrics["vae/loss"] = loss.detach()
        return metrics

    def publish_encoder(self) -> int:
        """Copy the training VAE into the published encoder; returns the new version."""
        if self.vae is None or self.vae_pub is None:
            raise ValueError("only the ursa mode has an encoder")
        self.vae_pub.load_state_dict(self.vae.state_dict())
        self.vae_version += 1
        return self.vae_version

    # --- inference helpers ---------------------------------------------------------------------

    def encode(self, inputs: np.ndarray) -> np.ndarray:
        """φ (M, D) of VAE inputs (M, F) with the published encoder (``Repertoire.reencode``)."""
        if self.vae_pub is None:
            return np.asarray(inputs, dtype=np.float64)
        return self.vae_pub.encode(inputs)

    @torch.no_grad()
    def posterior_feats(self, batch: dict[str, np.ndarray]) -> torch.Tensor:
        """Model states s (B, T, F) of a replay-like batch (obs, action, is_first)."""
        data = self._tensors({**batch, "reward": np.zeros(np.shape(batch["is_first"]))})
        embed = self.wm.encoder(data["obs"])
        gen = torch.Generator(device=self.device).manual_seed(0)  # leave training's RNG alone
        post = self.wm.rssm.observe(embed, data["action"], data["is_first"], gen)
        return self.wm.feat(post["h"], post["z"])

    @torch.no_grad()
    def multipliers(self, feat: torch.Tensor, skill: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """λ1, λ2 (...) at model states feat (..., F) for skills (..., D) (broadcast)."""
        if self.lam1 is None or self.lam2 is None:
            raise ValueError("daydreamer has no multipliers")
        s = torch.as_tensor(np.asarray(skill, np.float32), device=self.device)
        x = joint_input(feat, s.expand(*feat.shape[:-1], self.skill_dim))
        return self.lam1(x).cpu().numpy(), self.lam2(x).cpu().numpy()

    @torch.no_grad()
    def critic_values(self, feat: torch.Tensor, skill: np.ndarray) -> dict[str, np.ndarray]:
        """V (...), m = (1 − γ)ψ (..., D) and C (...) of the online critics at (feat, skill)."""
        s = torch.as_tensor(np.asarray(skill, np.float32), device=self.device)
        s = s.expand(*feat.shape[:-1], self.skill_dim)
        pred = self.critics.online(joint_input(feat, s), s)
        bins = self.wm.bins
        out = {"value": two_hot_mean(pred.value_logits, bins).cpu().numpy()}
        if pred.sf is not None and pred.cost_logits is not None:
            out["sf"] = pred.sf.cpu().numpy()
            out["cost"] = two_hot_mean(pred.cost_logits, bins).cpu().numpy()
        return out

    @torch.no_grad()
    def world_model_loss(self, batch: dict[str, np.ndarray]) -> dict[str, float]:
        """World-model losses on a batch without training (held-out evaluation)."""
        data = self._tensors(batch)
        gen = torch.Generator(device=self.device).manual_seed(12345)
        _, metrics, _ = self.wm.loss(data, self._phi_targets(data), gen)
        return {k: float(v) for k, v in metrics.items()}

    def policy_weights_bytes(self) -> bytes:
        """safetensors bytes for :meth:`ursa.policy.Policy.load_weights_bytes` (version =
        ``updates``)."""
        mods: dict[str, nn.Module] = {
            "encoder": self.wm.encoder,
            "rssm": self.wm.rssm,
            "actor": self.actor,
        }
        if self.vae_pub is not None:
            mods["vae"] = self.vae_pub
        return pack_policy_weights(mods, self.updates, self.vae_version)

    # --- checkpoints ---------------------------------------------------------------------------

    def _named_modules(self) -> dict[str, nn.Module]:
        mods: dict[str, nn.Module | None] = {
            "wm": self.wm,
            "actor": self.actor,
            **self.critics.members(),
            "lam1": self.lam1,
            "lam2": self.lam2,
            "vae": self.vae,
            "vae_pub": self.vae_pub,
            "retnorm_v": self.retnorm_v,
            "retnorm_c": self.retnorm_c,
        }
        return {k: m for k, m in mods.items() if m is not None}

    def _optimizers(self) -> dict[str, torch.optim.Optimizer]:
        opts: dict[str, torch.optim.Optimizer | None] = {
            "model": self.model_opt,
            "actor": self.actor_opt,
            "critic": self.critic_opt,
            "lagrange": self.lagrange_opt,
            "vae": self.vae_opt,
        }
        return {k: o for k, o in opts.items() if o is not None}

    def state_dict(self) -> dict[str, Any]:
        """Everything needed to resume exactly (tensors, numbers, strings only)."""
        return {
            "format": "ursa-learner-1",
            "config": asdict(self.config),
            "dims": [self.obs_dim, self.act_dim, self.feat_in_dim, self.skill_dim],
            "modules": {k: m.state_dict() for k, m in self._named_modules().items()},
            "optimizers": {k: o.state_dict() for k, o in self._optimizers().items()},
            "updates": self.updates,
            "vae_version": self.vae_version,
            "lam2_floor": self.lam2_floor,
            "torch_generator": self.gen.get_state(),
            "numpy_rng": _np_state_to_plain(self.np_rng.bit_generator.state),
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore :meth:`state_dict` (same config sizes and dims required)."""
        if state.get("format") != "ursa-learner-1":
            raise ValueError("not an URSA learner checkpoint")
        dims = [self.obs_dim, self.act_dim, self.feat_in_dim, self.skill_dim]
        if list(state["dims"]) != dims:
            raise ValueError(f"checkpoint dims {state['dims']} != learner dims {dims}")
        mods = self._named_modules()
        if set(state["modules"]) != set(mods):
            raise ValueError(f"checkpoint modules {sorted(state['modules'])} != {sorted(mods)}")
        for k, m in mods.items():
            m.load_state_dict(state["modules"][k])
        for k, o in self._optimizers().items():
            o.load_state_dict(state["optimizers"][k])
        self.updates = int(state["updates"])
        self.vae_version = int(state["vae_version"])
        self.lam2_floor = float(state.get("lam2_floor", 0.0))  # absent before the floor
        self.gen.set_state(state["torch_generator"].cpu())
        self.np_rng.bit_generator.state = _np_state_from_plain(state["numpy_rng"])

    def save_checkpoint(self, path: str | os.PathLike[str]) -> None:
        """Write the checkpoint (:func:`ursa.rundir.atomic_write`); torch format, tensors only."""
        state = self.state_dict()
        atomic_write(path, lambda f: torch.save(state, f))

    def load_checkpoint(self, path: str | os.PathLike[str]) -> None:
        """Load a checkpoint written by :meth:`save_checkpoint` (``weights_only=True``)."""
        state = torch.load(path, map_location=self.device, weights_only=True)
        self.load_state_dict(state)


def _np_state_to_plain(state: Mapping[str, Any]) -> dict[str, Any]:
    """numpy bit-generator state with its 128-bit integers as decimal strings (so that
    ``torch.load(weights_only=True)`` reads it back without custom classes)."""

    def conv(v: Any) -> Any:
        if isinstance(v, dict):
            return {k: conv(x) for k, x in v.items()}
        if isinstance(v, (int, np.integer)) and not isinstance(v, bool):
            return str(int(v))
        return v

    return conv(state)  # type: ignore[no-any-return]


def _np_state_from_plain(state: dict[str, Any]) -> dict[str, Any]:
    def conv(k: str, v: Any) -> Any:
        if isinstance(v, dict):
            return {kk: conv(kk, x) for kk, x in v.items()}
        if k != "bit_generator" and isinstance(v, str):
            return int(v)
        return v

    return {k: conv(k, v) for k, v in state.items()}
