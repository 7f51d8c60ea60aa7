"""Configuration of the URSA learner (world model, critics, multipliers, actor, VAE).

One frozen dataclass; the presets ``tiny`` (tests), ``small`` (a CPU) and ``paper`` (the paper's
and QDAC-MB's sizes) change sizes only, never code paths. Algorithm constants (γ, λ, KL scales,
free nats, slow-critic rate, return normalisation) are the same in every preset; a test or an
experiment that needs another value replaces the field explicitly (``dataclasses.replace``) and
says why. See docs/learner.md for the reasons behind each default.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Literal

Mode = Literal["ursa", "ursa-supervised", "daydreamer"]
ActorGrad = Literal["dynamics", "reinforce"]
ComputeDtype = Literal["float32", "bfloat16", "auto"]
PhiMetric = Literal["skill", "symlog"]
Lambda2Label = Literal["return", "step"]
LearnerPresetName = Literal["tiny", "point", "small", "cpu", "paper"]


@dataclass(frozen=True)
class LearnerConfig:
    """Everything the learner needs; sizes come from a preset."""

    mode: Mode = "ursa"
    """``ursa``: φ is a VAE encoder trained on the repertoire's inputs; ``ursa-supervised``: φ is
    a provided feature (the replay's ``features`` field); ``daydreamer``: reward only (no skills,
    no successor features, no multipliers, no safety critic)."""
    device: str = "cpu"
    """Torch device of the learner (``cpu``, ``cuda``, ``cuda:1``...)."""
    compute_dtype: ComputeDtype = "float32"
    """Precision of the networks' layers during an update: ``float32``; ``bfloat16`` (autocast:
    weights, optimiser states, losses and returns stay float32); ``auto``: bfloat16 where the
    device multiplies it natively (CUDA with bf16, CPUs with AMX-BF16 or AVX512-BF16), float32
    elsewhere. The ``small`` and ``paper`` presets use ``auto``; at ``tiny`` sizes bf16 is
    slower (the layers are too small for the matrix units to pay for the casts).
    docs/learner.md."""
    seed: int = 0
    """Seed of the learner's torch and numpy generators (and of the initial weights)."""

    # --- world model sizes ---------------------------------------------------------------------
    deter: int = 256
    """Size of the RSSM's deterministic (GRU) state h."""
    hidden: int = 256
    """Width of the RSSM's internal layers (input, prior and posterior MLPs)."""
    stoch: int = 16
    """Number of categorical latent variables of the RSSM."""
    classes: int = 16
    """Classes per categorical latent variable."""
    units: int = 256
    """Width of every MLP (encoder, decoder, heads, actor, critics)."""
    layers: int = 2
    """Hidden layers of every MLP."""
    bins: int = 255
    """Two-hot bins of the reward, cost, value and cost-critic heads (symexp-spaced)."""
    unimix: float = 0.01
    """Uniform mixture of the latent categoricals (and of their KL)."""

    # --- world-model loss ----------------------------------------------------------------------
    kl_dyn: float = 0.5
    """Scale of the dynamics loss KL(sg(post) ‖ prior) (QDAC-MB's value; DreamerV3 uses 1.0)."""
    kl_rep: float = 0.1
    """Scale of the representation loss KL(post ‖ sg(prior))."""
    free_nats: float = 1.0
    """Each KL term is clipped below at this value (per time step), so it has no gradient there."""
    phi_metric: PhiMetric = "symlog"
    """Loss of the world model's φ head: ``symlog``, the squared error of symlog(φ)
    (DreamerV3's vector-decoder loss), whose scale is the features' own; ``skill``, the squared
    error ‖φ̂ − φ‖²_Σ in the metric of δ (Σ the repertoire's KDE covariance, as the SF critic's
    loss), which trains the model to place φ to a fraction of δ. The point recipe uses ``skill``
    with ``replay_unsafe`` (alone it let the model forget the unsafe disc, which only the
    prefill visits; docs/learner.md); the A1 presets keep ``symlog``."""

    # --- batches -------------------------------------------------------------------------------
    batch_size: int = 16
    """B: replayed sequences per update."""
    seq_len: int = 64
    """T: steps per replayed sequence."""
    imag_horizon: int = 15
    """H: imagined steps from every start state."""
    imag_starts: int = 0
    """Start states of the imagination per update, drawn without replacement from the B·T
    posterior states; 0 uses all of them (DreamerV3)."""
    replay_unsafe: float = 0.0
    """Fraction of the B replayed sequences that each hold an unsafe step (``Replay.sample``'s
    ``unsafe_fraction``): unsafe states grow rare once the policy is safe, and a world model
    that sees them only at their share of the data forgets them (docs/learner.md)."""
    train_ratio: float = 32.0
    """Replayed steps per collected env step (B·T per update); drives the serial loop and the
    learner service."""

    # --- returns and critics -------------------------------------------------------------------
    discount: float = 0.995
    """γ of V, ψ and C (paper §5.1)."""
    cost_discount: float = 0.0
    """γ of the cost critic C; 0 means ``discount``. See docs/learner.md (point-env tests)."""
    cost_margin_cap: float | None = None
    """None: off (the paper). Otherwise the imagined per-step cost enters C's return as
    max(c, −cap): a state deeper than ``cap`` inside the safe set costs no less than one at
    ``cap``. With a cost that is negative on safe states (the A1's upright margin), −λ2·C else
    keeps paying for more margin. Measured on the A1 with λ2's floor (docs/learner.md): at 0.1
    the forward task stays safe but its skills are no better followed, and the posture task's
    policy stops following its velocity skills (0–2 of 50 within δ), so no preset uses it."""
    delta_scale: float = 1.0
    """The actor and λ1 enforce ‖(1−γ)ψ − z‖ ≤ ``delta_scale`` · δ. Below 1 it keeps a margin:
    the reward term pulls the actor to the constraint's boundary, so model error and the
    transit to a new skill land about half the executed skills outside δ when the margin is 0."""
    sf_residual: bool = True
    """Parameterise the SF critic as m = z + MLP(s, z) ("the skill is executed" is the initial
    guess) instead of m = MLP(s, z) (0 at initialisation)."""
    return_lambda: float = 0.95
    """λ of the TD(λ) returns."""
    slow_critic_fraction: float = 0.02
    """EMA rate of the slow critics, updated after every critic step."""
    slow_critic_reg: float = 1.0
    """Weight of the loss pulling each critic towards its slow copy's output (DreamerV3's
    ``critic_slowreg``); the returns themselves bootstrap from the online critics."""
    retnorm_rate: float = 0.01
    """EMA rate of the 5th/95th return percentiles (DreamerV3 return normalisation)."""
    retnorm_limit: float = 1.0
    """Returns are divided by max(limit, P95 − P5)."""

    # --- actor ---------------------------------------------------------------------------------
    actor_grad: ActorGrad = "dynamics"
    """How the actor's gradient is estimated: ``dynamics`` backpropagates J through the imagined
    dynamics (DreamerV1/2, QDAC-MB); ``reinforce`` rolls the model out without gradients and
    weights log π(a | s, z) by the advantage J(returns) − J(critics at s) (DreamerV3's default),
    which costs a fraction of the update (docs/learner.md)."""
    actor_entropy: float = 3e-4
    """Entropy bonus of the actor (on the normalised objective)."""
    actor_min_std: float = 0.1
    """Smallest std of the actor's pre-tanh Gaussian."""
    actor_max_std: float = 1.0
    """Largest std of the actor's pre-tanh Gaussian."""
    actor_mean_bound: float = 0.0
    """0: off. Otherwise the actor's loss adds Σ_a max(|μ_a| − bound, 0)² of its pre-tanh mean
    at the imagined states, so that the mean cannot drift into tanh's saturation (|tanh μ| → 1,
    where the objective's gradient vanishes). Measured on the A1 (docs/learner.md): at 1 the
    policy stops at the bound in the same low pose it takes at the joint limits without it, so
    no preset uses it."""

    # --- Lagrange multipliers ------------------------------------------------------------------
    lagrange_units: int = 64
    """Width of the single hidden layer of λ1(s, z) and λ2(s, z)."""
    lambda2_label: Lambda2Label = "return"
    """What λ2(s, z) is trained to predict at an imagined state: ``return`` (QDAC-MB), that the
    λ-return of the cost from there is positive; ``step``, that it is positive or that any
    imagined step from there to the horizon has a positive cost. With a cost that is negative on
    safe states (the A1 tasks), safe margins pay for violations in the return, and the
    ``return`` label stays 0 on starts that fall within the horizon (docs/learner.md). For tasks
    whose cost is positive only when unsafe (the posture task, the point env)."""
    lambda2_pos_weight: float = 1.0
    """Weight of λ2's positive (unsafe) labels in its cross-entropy (``pos_weight``): λ2 then
    settles at w·p / (w·p + 1 − p) instead of p, the probability of its label. Once the policy
    is safe, p falls and λ2 with it (measured on the A1, docs/learner.md); w > 1 keeps the
    safety term's weight up at a low p. 1: QDAC-MB's rule."""
    lambda2_floor_lr: float = 0.0
    """Step of an integrating floor under λ2 (a classic Lagrange multiplier on the acting
    policy's real violation rate): each update, floor ← clip(floor + η·(rate − target), 0,
    ``lambda2_floor_max``), and the actor weighs the cost with max(λ2(s, z), floor). A
    cross-entropy λ2 estimates P(violation | s, z), which a safe policy drives down, so it lets
    go once the robot is safe; the floor only falls while the real rate stays under the target.
    0: off (QDAC-MB)."""
    lambda2_floor_target: float = 0.02
    """The violation rate (unsafe steps per env step of the acting policy) the floor aims at."""
    lambda2_floor_max: float = 1.0
    """Upper bound of the floor."""
    lambda2_floor_window: int = 1000
    """Env steps of the exponential average of the acting policy's violation rate that drives
    the floor (time constant; collectors pooled)."""

    # --- optimisers ----------------------------------------------------------------------------
    model_lr: float = 1e-4
    """Adam learning rate of the world model."""
    model_eps: float = 1e-8
    """Adam epsilon of the world model."""
    model_clip: float = 1000.0
    """Global gradient-norm clip of the world model."""
    actor_lr: float = 3e-5
    """Adam learning rate of the actor."""
    critic_lr: float = 3e-5
    """Adam learning rate of V, ψ and C."""
    lagrange_lr: float = 3e-5
    """Adam learning rate of λ1 and λ2."""
    ac_eps: float = 1e-5
    """Adam epsilon of actor, critics and multipliers."""
    ac_clip: float = 100.0
    """Global gradient-norm clip of actor, critics and multipliers (each separately)."""

    # --- VAE (mode ``ursa``) -------------------------------------------------------------------
    skill_dim: int = 3
    """D: latent size of the VAE, i.e. the skill dimension in ``ursa`` mode."""
    vae_units: int = 128
    """Width of the VAE's MLPs."""
    vae_layers: int = 2
    """Hidden layers of the VAE's encoder and decoder."""
    vae_lr: float = 3e-4
    """Adam learning rate of the VAE."""
    vae_beta: float = 1.0
    """Weight of the KL term of the ELBO."""
    vae_batch: int = 256
    """Repertoire inputs per VAE step."""
    vae_publish_every: int = 500
    """Updates between two published encoder versions (the repertoire re-encodes on each)."""

    def __post_init__(self) -> None:
        if self.mode not in ("ursa", "ursa-supervised", "daydreamer"):
            raise ValueError(f"unknown mode {self.mode!r}")
        if min(self.deter, self.hidden, self.stoch, self.classes, self.units, self.layers) < 1:
            raise ValueError("network sizes must be positive")
        if self.bins < 2 or self.batch_size < 1 or self.seq_len < 1 or self.imag_horizon < 1:
            raise ValueError("bins ≥ 2 and batch_size, seq_len, imag_horizon ≥ 1 are required")
        if not 0.0 < self.discount < 1.0 or not 0.0 <= self.cost_discount < 1.0:
            raise ValueError("discounts must lie in (0, 1)")
        if self.actor_grad not in ("dynamics", "reinforce"):
            raise ValueError(f"unknown actor_grad {self.actor_grad!r}")
        if self.compute_dtype not in ("float32", "bfloat16", "auto"):
            raise ValueError(f"unknown compute_dtype {self.compute_dtype!r}")
        if self.phi_metric not in ("skill", "symlog"):
            raise ValueError(f"unknown phi_metric {self.phi_metric!r}")
        if not 0.0 < self.delta_scale <= 1.0:
            raise ValueError("delta_scale must lie in (0, 1]")
        if not 0.0 <= self.replay_unsafe <= 1.0:
            raise ValueError("replay_unsafe must lie in [0, 1]")
        if self.lambda2_label not in ("return", "step"):
            raise ValueError(f"unknown lambda2_label {self.lambda2_label!r}")
        if not self.lambda2_pos_weight > 0.0:
            raise ValueError("lambda2_pos_weight must be > 0")
        if self.lambda2_floor_lr < 0.0:
            raise ValueError("lambda2_floor_lr must be ≥ 0 (0: off)")
        if not 0.0 <= self.lambda2_floor_target < 1.0:
            raise ValueError("lambda2_floor_target must be in [0, 1)")
        if not 0.0 <= self.lambda2_floor_max <= 1.0:
            raise ValueError("lambda2_floor_max must be in [0, 1]")
        if self.lambda2_floor_window < 1:
            raise ValueError("lambda2_floor_window must be ≥ 1")
        if self.cost_margin_cap is not None and not self.cost_margin_cap >= 0.0:
            raise ValueError("cost_margin_cap must be ≥ 0 (None: off)")
        if self.actor_mean_bound < 0.0:
            raise ValueError("actor_mean_bound must be ≥ 0 (0: off)")

    @property
    def gamma_cost(self) -> float:
        """γ of the cost critic (``cost_discount`` or ``discount``)."""
        return self.cost_discount or self.discount

    @property
    def uses_skills(self) -> bool:
        """Whether the policy is skill-conditioned (every mode but ``daydreamer``)."""
        return self.mode != "daydreamer"

    @classmethod
    def tiny(cls, **overrides: object) -> LearnerConfig:
        """Sizes for the tests on the point env (a few minutes of CPU)."""
        base = cls(
            deter=64,
            hidden=64,
            stoch=8,
            classes=8,
            units=64,
            layers=2,
            bins=255,
            batch_size=16,
            seq_len=32,
            imag_starts=256,
            lagrange_units=32,
            vae_units=32,
            vae_batch=128,
        )
        return dataclasses.replace(base, **overrides)  # type: ignore[arg-type]

    @classmethod
    def point(cls, **overrides: object) -> LearnerConfig:
        """The point-env learning recipe (the learning tests' and ``--preset point``): ``tiny``
        sizes with faster learning rates, 128 imagination starts, a high replay ratio, shorter
        horizons (γ 0.98, cost γ 0.9) so that 3000 updates suffice and the skill constraint
        enforced at δ/4; a world model that learns position fast (lr 1e-3, φ loss in δ's
        metric) and keeps the unsafe disc (1 in 10 replayed sequences holds an unsafe step);
        docs/learner.md gives the measurements behind each."""
        base = cls.tiny(
            imag_starts=128,
            model_lr=1e-3,
            phi_metric="skill",
            replay_unsafe=0.1,
            actor_lr=1e-4,
            critic_lr=1e-4,
            lagrange_lr=1e-4,
            train_ratio=128.0,
            discount=0.98,
            cost_discount=0.9,
            delta_scale=0.25,
        )
        return dataclasses.replace(base, **overrides)  # type: ignore[arg-type]

    @classmethod
    def small(cls, **overrides: object) -> LearnerConfig:
        """Sizes for one CPU (the DayDreamer-like A1 setting, scaled down)."""
        base = cls(
            deter=256,
            hidden=256,
            stoch=16,
            classes=16,
            units=256,
            layers=2,
            bins=255,
            batch_size=16,
            seq_len=32,
            imag_starts=0,
            lagrange_units=64,
            compute_dtype="auto",
        )
        return dataclasses.replace(base, **overrides)  # type: ignore[arg-type]

    @classmethod
    def cpu(cls, **overrides: object) -> LearnerConfig:
        """The A1's CPU recipe (``make run`` without a GPU): ``small`` sizes with 128
        imagination starts per update and an SF critic without the residual prior, which made
        imagination read every skill as executed on the A1 (docs/learner.md: safe from a
        median of 750 updates over 3 seeds, against ~1100 with the prior and never within 1068
        at 512 starts)."""
        base = cls.small(imag_starts=128, sf_residual=False)
        return dataclasses.replace(base, **overrides)  # type: ignore[arg-type]

    @classmethod
    def paper(cls, **overrides: object) -> LearnerConfig:
        """QDAC-MB's sizes (RSSM 512, stoch 32×32, MLPs 2×512, batch 16×64, 255 bins)."""
        base = cls(
            deter=512,
            hidden=512,
            stoch=32,
            classes=32,
            units=512,
            layers=2,
            bins=255,
            batch_size=16,
            seq_len=64,
            imag_starts=0,
            lagrange_units=64,
            compute_dtype="auto",
            vae_units=256,
        )
        return dataclasses.replace(base, **overrides)  # type: ignore[arg-type]


def learner_preset(name: LearnerPresetName, **overrides: object) -> LearnerConfig:
    """The learner config of a preset, with optional field overrides."""
    factory = {
        "tiny": LearnerConfig.tiny,
        "point": LearnerConfig.point,
        "small": LearnerConfig.small,
        "cpu": LearnerConfig.cpu,
        "paper": LearnerConfig.paper,
    }
    if name not in factory:
        raise ValueError(f"unknown preset {name!r}")
    return factory[name](**overrides)
