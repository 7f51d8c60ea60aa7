"""The reference learner of ``benchmarks/learner.py``: sheeprl's DreamerV3 at URSA's sizes.

What is measured: sheeprl's own gradient step of DreamerV3 (``sheeprl.algos.dreamer_v3.
dreamer_v3.train``: the world-model update, then behaviour learning, i.e. imagination from every
posterior state of the batch, the actor update and the critic update), preceded by the slow
critic's EMA that sheeprl's training loop does before each step, on synthetic batches shaped like
the URSA benchmark's (obs 46, action 12 continuous, batch 16 × sequence 32, so 512 imagination
starts × 15 steps). sheeprl (``pip install -e '.[reference]'``, sheeprl==0.8.4) is used as a
library: its shipped Hydra configs (``exp=dreamer_v3``) composed with URSA's sizes and constants
as overrides, its ``build_agent``, its optimisers (from the config), its ``Moments`` and its
``train``. No environment is stepped and no replay buffer is sampled: the batch is converted from
numpy to time-major tensors inside the timed step, as URSA's ``train_step`` converts its own.

Sizes are URSA's (``LearnerConfig``): recurrent state ``deter``, the RSSM's internal width
``hidden`` (the input layer of the GRU, prior and posterior), ``stoch`` × ``classes`` discrete
latents, every MLP (encoder, decoder, reward, continue, actor, critic) ``layers`` ×
``units`` with LayerNorm and SiLU, ``bins`` two-hot bins; γ, λ, the KL scales, free nats, unimix,
learning rates, Adam epsilons, gradient clips, actor std bounds and the slow critic's rate are set
from the same config. ``reference_sizes`` reads the sizes back from the built modules.

What differs between the two updates (the work per update is not identical):
- DreamerV3 predicts continuation (a continue head, trained and used to discount imagination);
  URSA has no continue head (reset-free) but a cost head and a φ head in its world model;
- URSA's behaviour learning trains three critics (reward V, successor features ψ, cost C, each
  with a slow copy), two Lagrange multipliers λ1(s, z), λ2(s, z) and a skill-conditioned actor
  (``daydreamer`` mode: the reward critic and the actor only); DreamerV3 trains one critic with
  a target copy and an unconditioned actor;
- URSA (mode ``ursa``) also trains a VAE on repertoire inputs every update;
- the continuous actor: DreamerV3's (sheeprl's ``scaled_normal``: tanh mean, sigmoid-bounded
  std, analytic entropy) against URSA's pre-tanh Gaussian; both backpropagate the returns through
  the dynamics for continuous actions (sheeprl's default ``objective_mix``), as URSA's
  ``actor_grad="dynamics"``;
- sheeprl's Adam is the fused kernel (its shipped config), URSA's the default one; sheeprl
  runs with the process-wide settings its CLI makes (float32 matmul precision ``high``,
  distributions without argument validation, no metrics), applied only around its calls here;
- precision: sheeprl runs in ``bf16-mixed`` where URSA's ``small`` preset resolves to bfloat16
  (``compute_dtype="auto"``) on the device, in ``32-true`` elsewhere.
"""

from __future__ import annotations

import contextlib
import os
import time
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from torch import nn

from ursa.learner_config import LearnerConfig
from ursa.networks import resolve_compute_dtype

OBS, ACT = 46, 12
"""The A1's observation and action sizes (as ``benchmarks/learner.py``)."""
OBS_KEY = "state"
"""The vector observation's key in sheeprl's (dict) observation space."""


def available() -> bool:
    """Whether sheeprl (the optional extra ``reference``) is installed."""
    import importlib.util

    return importlib.util.find_spec("sheeprl") is not None


def _overrides(c: LearnerConfig) -> list[str]:
    """Hydra overrides of sheeprl's ``exp=dreamer_v3`` for URSA's sizes and constants: a vector
    observation through the MLP encoder and decoder only (no CNN), and the env config only for
    the fields ``build_agent`` reads (a dummy env, never stepped)."""
    wm = "algo.world_model"
    return [
        "exp=dreamer_v3",
        "env=dummy",
        "env.num_envs=1",
        "algo.cnn_keys.encoder=[]",
        "algo.cnn_keys.decoder=[]",
        f"algo.mlp_keys.encoder=[{OBS_KEY}]",
        f"algo.mlp_keys.decoder=[{OBS_KEY}]",
        f"algo.per_rank_batch_size={c.batch_size}",
        f"algo.per_rank_sequence_length={c.seq_len}",
        f"algo.horizon={c.imag_horizon}",
        f"algo.gamma={c.discount}",
        f"algo.lmbda={c.return_lambda}",
        f"algo.unimix={c.unimix}",
        # every MLP: encoder, decoder, reward, continue, actor, critic (interpolated from these)
        f"algo.dense_units={c.units}",
        f"algo.mlp_layers={c.layers}",
        f"{wm}.recurrent_model.recurrent_state_size={c.deter}",
        f"{wm}.recurrent_model.dense_units={c.hidden}",
        f"{wm}.transition_model.hidden_size={c.hidden}",
        f"{wm}.representation_model.hidden_size={c.hidden}",
        f"{wm}.stochastic_size={c.stoch}",
        f"{wm}.discrete_size={c.classes}",
        f"{wm}.reward_model.bins={c.bins}",
        f"algo.critic.bins={c.bins}",
        f"{wm}.kl_dynamic={c.kl_dyn}",
        f"{wm}.kl_representation={c.kl_rep}",
        f"{wm}.kl_free_nats={c.free_nats}",
        f"{wm}.clip_gradients={c.model_clip}",
        f"{wm}.optimizer.lr={c.model_lr}",
        f"{wm}.optimizer.eps={c.model_eps}",
        f"algo.actor.optimizer.lr={c.actor_lr}",
        f"algo.actor.optimizer.eps={c.ac_eps}",
        f"algo.actor.clip_gradients={c.ac_clip}",
        f"algo.actor.ent_coef={c.actor_entropy}",
        f"algo.actor.min_std={c.actor_min_std}",
        f"algo.actor.max_std={c.actor_max_std}",
        f"algo.actor.moments.decay={1.0 - c.retnorm_rate}",
        f"algo.actor.moments.max={1.0 / c.retnorm_limit}",  # divides by max(1 / max, P95 - P5)
        f"algo.critic.optimizer.lr={c.critic_lr}",
        f"algo.critic.optimizer.eps={c.ac_eps}",
        f"algo.critic.clip_gradients={c.ac_clip}",
        f"algo.critic.tau={c.slow_critic_fraction}",
        "algo.critic.per_rank_target_network_update_freq=1",
        "algo.compile.enabled=False",
        "metric.log_level=0",
        "model_manager.disabled=True",
    ]


def sheeprl_config(c: LearnerConfig, device: str, precision: str) -> Any:
    """sheeprl's configuration (a resolved ``dotdict``, as its CLI passes to the algorithm)
    composed from its shipped config files with URSA's sizes."""
    from hydra import compose, initialize_config_module
    from omegaconf import OmegaConf
    from sheeprl.utils.utils import dotdict

    accelerator = "cuda" if device.startswith("cuda") else "cpu"
    overrides = [
        *_overrides(c),
        f"fabric.accelerator={accelerator}",
        f"fabric.precision={precision}",
    ]
    with initialize_config_module(config_module="sheeprl.configs", version_base="1.3"):
        cfg = compose(config_name="config", overrides=overrides)
    return dotdict(OmegaConf.to_container(cfg, resolve=True, throw_on_missing=True))


def default_precision(device: str) -> str:
    """sheeprl's Fabric precision matching URSA's ``small`` preset on ``device``."""
    dtype = resolve_compute_dtype(LearnerConfig.small().compute_dtype, torch.device(device))
    return "bf16-mixed" if dtype is torch.bfloat16 else "32-true"


@contextlib.contextmanager
def _sheeprl_globals(cfg: Any) -> Iterator[None]:
    """The process-wide settings sheeprl's CLI makes before a run (float32 matmul precision,
    distributions' argument validation, metrics off at ``metric.log_level=0``, which also skips
    the posterior and prior entropies that only feed the logs), restored on exit so that URSA's
    runs interleaved with the reference's keep theirs. Torch's thread count is left as the
    caller set it."""
    from sheeprl.utils.metric import MetricAggregator
    from torch.distributions import Distribution

    matmul = torch.get_float32_matmul_precision()
    validate = Distribution._validate_args
    metrics_off = MetricAggregator.disabled
    threads = torch.get_num_threads()
    torch.set_float32_matmul_precision(cfg.float32_matmul_precision)
    Distribution.set_default_validate_args(cfg.distribution.validate_args)
    MetricAggregator.disabled = cfg.metric.log_level == 0
    try:
        yield
    finally:
        torch.set_float32_matmul_precision(matmul)
        Distribution.set_default_validate_args(validate)
        MetricAggregator.disabled = metrics_off
        if torch.get_num_threads() != threads:
            torch.set_num_threads(threads)


@dataclass
class ReferenceAgent:
    """sheeprl's DreamerV3 learner, built by sheeprl, and one timed update of it."""

    config: LearnerConfig
    cfg: Any
    fabric: Any
    world_model: nn.Module
    actor: nn.Module
    critic: nn.Module
    target_critic: nn.Module
    world_optimizer: Any
    actor_optimizer: Any
    critic_optimizer: Any
    moments: nn.Module
    act_dim: int
    updates: int = 0

    @classmethod
    def build(
        cls,
        config: LearnerConfig | None = None,
        device: str = "cpu",
        precision: str | None = None,
        obs_dim: int = OBS,
        act_dim: int = ACT,
    ) -> ReferenceAgent:
        """sheeprl's ``build_agent``, optimisers and return normalisation at ``config``'s sizes
        (URSA ``small`` by default) on ``device``."""
        import gymnasium as gym
        import hydra
        from lightning.fabric import Fabric
        from sheeprl.algos.dreamer_v3.agent import build_agent
        from sheeprl.algos.dreamer_v3.utils import Moments

        c = config or LearnerConfig.small()
        prec = precision or default_precision(device)
        cfg = sheeprl_config(c, device, prec)
        with _sheeprl_globals(cfg):
            fabric = Fabric(
                accelerator=cfg.fabric.accelerator,
                devices=[torch.device(device).index or 0] if device.startswith("cuda") else 1,
                num_nodes=1,
                strategy="auto",
                precision=cfg.fabric.precision,
            )
            obs_space = gym.spaces.Dict(
                {OBS_KEY: gym.spaces.Box(-np.inf, np.inf, (obs_dim,), np.float32)}
            )
            with torch.random.fork_rng(devices=[]):
                torch.manual_seed(c.seed)
                world_model, actor, critic, target_critic, _player = build_agent(
                    fabric, (act_dim,), True, cfg, obs_space
                )
            opt = cfg.algo

            def make(section: Any, module: nn.Module) -> Any:
                return hydra.utils.instantiate(
                    section.optimizer, params=module.parameters(), _convert_="all"
                )

            optimizers: Any = fabric.setup_optimizers(  # one per module, in this order
                make(opt.world_model, world_model),
                make(opt.actor, actor),
                make(opt.critic, critic),
            )
            wm_opt, actor_opt, critic_opt = optimizers
            m = opt.actor.moments
            moments = Moments(m.decay, m.max, m.percentile.low, m.percentile.high)
        return cls(
            c,
            cfg,
            fabric,
            world_model,
            actor,
            critic,
            target_critic,
            wm_opt,
            actor_opt,
            critic_opt,
            moments,
            act_dim,
        )

    def _tensors(self, batch: dict[str, np.ndarray]) -> dict[str, torch.Tensor]:
        """URSA's batch-major numpy batch as the time-major float tensors sheeprl samples."""
        dev = self.fabric.device
        b, t = batch["reward"].shape

        def tm(x: np.ndarray) -> torch.Tensor:
            return torch.as_tensor(np.asarray(x, np.float32), device=dev).transpose(0, 1)

        return {
            OBS_KEY: tm(batch["obs"]),
            "actions": tm(batch["action"]),
            "rewards": tm(batch["reward"][..., None]),
            "is_first": tm(batch["is_first"][..., None]),
            "terminated": torch.zeros((t, b, 1), device=dev),
            "truncated": torch.zeros((t, b, 1), device=dev),
        }

    def train_step(self, batch: dict[str, np.ndarray]) -> None:
        """One gradient step as sheeprl's training loop does it: the target critic's EMA (a
        copy at the first step), then ``train`` (world model, then actor and critic)."""
        from sheeprl.algos.dreamer_v3.dreamer_v3 import train

        cfg = self.cfg
        with _sheeprl_globals(cfg):
            if self.updates % cfg.algo.critic.per_rank_target_network_update_freq == 0:
                tau = 1.0 if self.updates == 0 else cfg.algo.critic.tau
                with torch.no_grad():
                    for p, tp in zip(
                        self.critic.parameters(), self.target_critic.parameters(), strict=True
                    ):
                        tp.lerp_(p, tau)
            train(
                self.fabric,
                self.world_model,
                self.actor,
                self.critic,
                self.target_critic,
                self.world_optimizer,
                self.actor_optimizer,
                self.critic_optimizer,
                self._tensors(batch),
                None,
                cfg,
                True,
                (self.act_dim,),
                self.moments,
            )
        self.updates += 1

    def sizes(self) -> dict[str, int]:
        """The sizes of the built modules, read back from their layers (not from the config)."""
        return read_sizes(self.world_model, self.actor, self.critic, self.target_critic)


def _linears(module: nn.Module) -> list[nn.Linear]:
    return [m for m in module.modules() if isinstance(m, nn.Linear)]


def _norms(module: nn.Module) -> list[nn.LayerNorm]:
    return [m for m in module.modules() if isinstance(m, nn.LayerNorm)]


def _unwrap(module: nn.Module) -> Any:
    """The module Fabric wraps (``_FabricModule.module``), or ``module`` itself."""
    inner = getattr(module, "module", module)
    return inner if isinstance(inner, nn.Module) else module


def _action_dim(actor: nn.Module) -> int:
    return int(_linears(_unwrap(actor).mlp_heads)[0].out_features // 2)


def _mlp_shape(module: nn.Module) -> tuple[int, int]:
    """(width, hidden layers) of a sheeprl MLP (Linear → LayerNorm → SiLU per hidden layer)."""
    norms = _norms(module)
    widths = {int(n.normalized_shape[0]) for n in norms}
    return (widths.pop() if len(widths) == 1 else 0), len(norms)


def _count(module: nn.Module) -> int:
    return sum(p.numel() for p in _unwrap(module).parameters())


def read_sizes(
    world_model: nn.Module, actor: nn.Module, critic: nn.Module, target_critic: nn.Module
) -> dict[str, int]:
    """Sizes and parameter counts read from sheeprl's built modules.

    ``units`` and ``layers`` are those shared by every MLP (encoder, decoder, reward, continue,
    actor trunk, critic); 0 (units) or -1 (layers) when they differ. ``hidden`` is the width of
    the RSSM's three internal layers, 0 when they differ."""
    wm: Any = world_model
    rssm = wm.rssm
    rec = _unwrap(rssm.recurrent_model)
    trans = _unwrap(rssm.transition_model)
    rep = _unwrap(rssm.representation_model)
    gru_norm = _norms(rec.rnn)[0]
    deter = int(gru_norm.normalized_shape[0]) // 3
    discrete = int(rssm.discrete)
    zdim = int(_linears(trans)[-1].out_features)
    hidden = {_mlp_shape(rec.mlp)[0], _mlp_shape(trans)[0], _mlp_shape(rep)[0]}
    enc = _unwrap(wm.encoder).mlp_encoder
    dec = _unwrap(wm.observation_model).mlp_decoder
    mlps = [
        enc.model,
        dec.model,
        _unwrap(wm.reward_model),
        _unwrap(wm.continue_model),
        _unwrap(actor).model,
        _unwrap(critic),
    ]
    shapes = {_mlp_shape(m) for m in mlps}
    units, layers = shapes.pop() if len(shapes) == 1 else (0, -1)
    bins = {int(_linears(_unwrap(m))[-1].out_features) for m in (wm.reward_model, critic)}
    return {
        "obs": int(_linears(enc)[0].in_features),
        "action": _action_dim(actor),
        "deter": deter,
        "hidden": hidden.pop() if len(hidden) == 1 else 0,
        "stoch": zdim // discrete,
        "classes": discrete,
        "units": units,
        "layers": layers,
        "bins": bins.pop() if len(bins) == 1 else 0,
        "params_world_model": _count(world_model),
        "params_actor": _count(actor),
        "params_critic": _count(critic),
        "params_target_critic": _count(target_critic),
    }


def expected_sizes(config: LearnerConfig, obs_dim: int = OBS, act_dim: int = ACT) -> dict[str, int]:
    """The sizes ``read_sizes`` must find for ``config`` (those of URSA's learner)."""
    c = config
    return {
        "obs": obs_dim,
        "action": act_dim,
        "deter": c.deter,
        "hidden": c.hidden,
        "stoch": c.stoch,
        "classes": c.classes,
        "units": c.units,
        "layers": c.layers,
        "bins": c.bins,
    }


def reference_sizes(config: LearnerConfig | None = None, device: str = "cpu") -> dict[str, int]:
    """The sizes of sheeprl's DreamerV3 built at ``config``'s sizes (URSA ``small`` by default),
    read back from its modules, with their parameter counts."""
    return ReferenceAgent.build(config, device).sizes()


def synthetic_batch(c: LearnerConfig, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """A synthetic A1-shaped batch (B, T, ...) of the fields both learners read: obs, action,
    reward, is_first (``benchmarks/learner.py`` adds URSA's cost and features)."""
    b, t = c.batch_size, c.seq_len
    first = np.zeros((b, t), bool)
    first[:, 0] = True
    return {
        "obs": rng.normal(size=(b, t, OBS)).astype(np.float32),
        "action": rng.uniform(-1, 1, size=(b, t, ACT)).astype(np.float32),
        "reward": rng.normal(size=(b, t)).astype(np.float32),
        "is_first": first,
    }


def measure_reference(
    updates: int,
    warmup: int,
    device: str,
    config: LearnerConfig | None = None,
    precision: str | None = None,
) -> dict[str, float]:
    """Updates per second of sheeprl's DreamerV3 at ``config``'s sizes (URSA ``small`` by
    default) on ``device``, with the caller's torch thread count."""
    c = config or LearnerConfig.small()
    cuda = device.startswith("cuda")
    rng = np.random.default_rng(0)
    batches = [synthetic_batch(c, rng) for _ in range(min(updates + warmup, 4))]
    devices = [torch.device(device).index or 0] if cuda else []
    with torch.random.fork_rng(devices=devices):
        torch.manual_seed(c.seed)
        agent = ReferenceAgent.build(c, device, precision)
        for i in range(warmup):
            agent.train_step(batches[i % len(batches)])
        if cuda:
            torch.cuda.synchronize(device)
        start = time.perf_counter()
        for i in range(updates):
            agent.train_step(batches[i % len(batches)])
        if cuda:
            torch.cuda.synchronize(device)
        total = time.perf_counter() - start
    return {"updates_per_s": updates / total, "s_per_update": total / updates}


def main() -> None:
    """``make bench`` runs every benchmark: this one times the reference alone."""
    import argparse

    from ursa.threads import limit_threads

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    ap.add_argument("--updates", type=int, default=0, help="timed updates (0: 3 quick, else 20)")
    ap.add_argument(
        "--threads", type=int, default=0, help="torch threads (0: URSA_TORCH_THREADS or 1)"
    )
    ap.add_argument("--quick", action="store_true", help="few updates, < 30 s on a CPU")
    args = ap.parse_args()
    if not available():
        print("sheeprl is not installed: pip install -e '.[reference]'")
        return
    limit_threads(torch_threads=args.threads or int(os.environ.get("URSA_TORCH_THREADS", "1")))
    config = LearnerConfig.small(device=args.device)
    print(f"sizes: {reference_sizes(config, args.device)}")
    n = args.updates or (3 if args.quick else 20)
    r = measure_reference(n, 1 if args.quick else 3, args.device, config)
    print(
        f"sheeprl DreamerV3 at URSA small sizes on {args.device}, torch threads "
        f"{torch.get_num_threads()}: {r['updates_per_s']:.3f} updates/s"
    )


if __name__ == "__main__":
    main()
