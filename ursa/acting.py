"""A collector's acting loop, one env step at a time: the one owner of how a reset-free robot is
driven and recorded. The collector service and the serial loop (``ursa.serial``) are its users;
they choose the skill (``skill_due``), whether the step acts at random (the prefill, or no
weights yet), and what happens to each finished chunk (published, or added to a replay).

Per step (:meth:`Acting.step`): uniformly random actions, or the policy π(a | s, z) from its
recurrent carry (a new carry when the policy takes over from random acting); non-finite policy
actions are counted and mapped into the action box (a diverged policy must reach neither the
never-reset env nor the replay); the record follows the world model's convention, the
observation after the step with the action that produced it, its reward, cost and safety, the
feature input and the skill. Every ``chunk_len`` records make a :class:`Chunk` carrying the step
index of its first record. A rescue (``info["rescued"]``, the env teleported the robot) ends the
chunk before the rescued record and skips a step index, so that a replay starts a new segment
at the righted robot (also when the rescue falls on a chunk's first step), and starts a new
carry.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ursa.envs.base import ResetFreeEnv
from ursa.policy import Policy, PolicyCarry

RECORD_FIELDS = ("obs", "action", "reward", "cost", "safe", "features", "skill")
"""Fields of every record; ``stamp`` and ``base_pose`` are added with ``ActingConfig.stamps``."""


@dataclass(frozen=True)
class ActingConfig:
    """How a collector acts and records."""

    feature: str
    """Key of ``info["features"]`` recorded as ``features`` (the VAE input with a learned φ, φ
    itself with a provided one); an env without it records a zero."""
    skill_period: int = 250
    """T: env steps between two skills (:meth:`Acting.skill_due`)."""
    chunk_len: int = 50
    """Records per chunk."""
    stamps: bool = False
    """Also record each step's wall-clock time (``stamp``) and, where the env reports it, the
    robot's base pose (``base_pose``: position and orientation quaternion, 7 numbers)."""
    explore: bool = True
    """Sample actions from π (collection explores); False takes the policy's mode."""
    random_scale: float = 1.0
    """Random actions (the prefill) are uniform in [−s, s]^A; 1 is the whole action box."""

    def __post_init__(self) -> None:
        if not 0.0 < self.random_scale <= 1.0:
            raise ValueError(f"random_scale must lie in (0, 1], got {self.random_scale}")


@dataclass(frozen=True)
class Chunk:
    """Consecutive records of one collector."""

    first_step: int
    """Step index of the first record (indices skip one at every rescue)."""
    data: dict[str, np.ndarray]
    """Each field's records (T, ...): float32 obs, action, reward, cost, features, skill; bool
    safe; float64 stamp."""

    def __len__(self) -> int:
        return len(self.data["obs"])

    @property
    def safe_features(self) -> np.ndarray:
        """The feature inputs of the safe records (M, F)."""
        return self.data["features"][self.data["safe"]]

    def archive_features(self, window: int = 1) -> np.ndarray:
        """What the repertoire may admit (M, F): with ``window`` 1 the feature input of every
        safe record; with W > 1 the mean over each block of W consecutive records (blocks from
        the chunk's first record; a trailing partial block is dropped) whose records are all
        safe. A skill is a sustained mean feature, and the per-step features of a jittering
        robot (an instantaneous yaw rate) span values that no sustained behaviour reaches."""
        if window < 1:
            raise ValueError(f"window must be >= 1, got {window}")
        if window == 1:
            return self.safe_features
        feats, safe = self.data["features"], self.data["safe"]
        n = (len(feats) // window) * window
        blocks = feats[:n].reshape(n // window, window, feats.shape[-1])
        whole = safe[:n].reshape(n // window, window).all(1)
        return blocks[whole].mean(1, dtype=np.float64).astype(feats.dtype)


@dataclass
class StepResult:
    """What one step did."""

    action: np.ndarray
    """The action sent to the env (A,)."""
    reward: float
    info: dict[str, Any]
    """The env's info of the step."""
    chunks: list[Chunk]
    """Chunks this step finished (0, 1, or 2 when a rescue ended one and a full one followed)."""


def sanitise(action: np.ndarray) -> tuple[np.ndarray, bool]:
    """``action`` with NaN mapped to 0 and ±inf to ±1 (the bounds of the action box), and
    whether any entry was not finite."""
    if np.all(np.isfinite(action)):
        return action, False
    return np.nan_to_num(action, nan=0.0, posinf=1.0, neginf=-1.0), True


@dataclass
class Acting:
    """The acting state of one collector: env, policy, carry, current skill, open chunk."""

    env: ResetFreeEnv
    policy: Policy
    config: ActingConfig
    rng: np.random.Generator
    """Random actions and the policy's action noise (the policy's own generator draws its
    RSSM latents)."""
    seed: int | None = None
    """Seed of the env's first reset (None: the env's own)."""
    skill: np.ndarray = field(init=False)
    """The skill being executed (D,); the user sets it (every ``skill_period`` steps)."""
    step_count: int = field(init=False, default=0)
    """Env steps taken."""
    step_offset: int = field(init=False, default=0)
    """Step indices skipped at rescues."""
    nonfinite_actions: int = field(init=False, default=0)
    """Policy actions with a NaN or inf entry (sanitised)."""

    def __post_init__(self) -> None:
        self.obs, _ = self.env.reset(seed=self.seed) if self.seed is not None else self.env.reset()
        self.carry: PolicyCarry = self.policy.initial_carry()
        self.skill = np.zeros(self.policy.skill_dim, np.float32)
        self._random = True
        self._buf: dict[str, list[Any]] = {}
        self._first = 0

    @property
    def open_records(self) -> int:
        """Records in the open chunk (not yet in any :class:`Chunk`)."""
        return len(self._buf.get("obs", ()))

    def skill_due(self) -> bool:
        """Whether this step starts a new skill period."""
        return self.step_count % self.config.skill_period == 0

    def _action(self, random: bool) -> np.ndarray:
        if random:
            self._random = True
            s = self.config.random_scale
            return self.rng.uniform(-s, s, self.env.act_dim)
        if self._random:  # the policy takes over: a carry from its current weights
            self._random = False
            self.carry = self.policy.initial_carry()
        action, self.carry = self.policy.act(
            self.carry, self.obs, self.skill, explore=self.config.explore, rng=self.rng
        )
        action, bad = sanitise(action)
        self.nonfinite_actions += int(bad)
        return action

    def step(self, random: bool = False) -> StepResult:
        """One env step: act (uniformly at random if ``random``), record, close full chunks."""
        action = self._action(random)
        obs, reward, _, _, info = self.env.step(action)
        chunks: list[Chunk] = []
        if info.get("rescued"):
            chunks += self.flush()
            self.step_offset += 1
            self.carry = self.policy.initial_carry()
        if not self._buf:
            self._first = self.step_count + self.step_offset
            self._buf = {k: [] for k in RECORD_FIELDS}
        feats = info["features"].get(self.config.feature)
        rec = self._buf
        rec["obs"].append(np.asarray(obs, np.float32))
        rec["action"].append(np.asarray(action, np.float32))
        rec["reward"].append(np.float32(reward))
        rec["cost"].append(np.float32(info["cost"]))
        rec["safe"].append(bool(info["safe"]))
        rec["features"].append(
            np.asarray(feats if feats is not None else np.zeros(1), np.float32).reshape(-1)
        )
        rec["skill"].append(np.asarray(self.skill, np.float32))
        if self.config.stamps:
            rec.setdefault("stamp", []).append(time.time())
            if "base_position" in info:
                pose = [*info["base_position"], *info["base_orientation"]]
                rec.setdefault("base_pose", []).append(pose)
        self.obs = obs
        self.step_count += 1
        if len(rec["obs"]) >= self.config.chunk_len:
            chunks += self.flush()
        return StepResult(action, float(reward), info, chunks)

    def flush(self) -> list[Chunk]:
        """The open chunk, closed ([] when it is empty)."""
        rec, self._buf = self._buf, {}
        if not rec or not rec["obs"]:
            return []
        n = len(rec["obs"])
        data = {k: np.stack(rec[k]) for k in RECORD_FIELDS}
        data["safe"] = data["safe"].astype(np.bool_)
        if "stamp" in rec:
            data["stamp"] = np.asarray(rec["stamp"], np.float64)
        if len(rec.get("base_pose", ())) == n:  # a pose for every record, or none
            data["base_pose"] = np.asarray(rec["base_pose"], np.float32)
        return [Chunk(self._first, data)]
