"""Learner, policy and serial loop: every mode runs, weights travel as safetensors, checkpoints
resume bit for bit, the VAE's encoder re-encodes a repertoire. Fast (tiny sizes)."""

from __future__ import annotations

import dataclasses
import math
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from tests.ursa.envs.rescued import RescuedPoint
from tests.ursa.test_policy_numpy import TorchUniforms
from ursa import kde
from ursa.envs.point import PointConfig, PointEnv
from ursa.learner import Learner, SkillSnapshot
from ursa.learner_config import LearnerConfig, learner_preset
from ursa.policy import Policy
from ursa.repertoire import Repertoire, RepertoireConfig
from ursa.replay import Replay
from ursa.serial import EvalResult, SerialConfig, SerialLoop, evaluate_skills

torch.set_num_threads(1)

MICRO = LearnerConfig.tiny(
    deter=32,
    hidden=32,
    stoch=4,
    classes=4,
    units=32,
    bins=31,
    batch_size=4,
    seq_len=8,
    imag_horizon=5,
    imag_starts=16,
    vae_batch=32,
    vae_publish_every=3,
)


def _random_replay(steps: int = 600, seed: int = 0, vae_input: bool = False) -> Replay:
    env = PointEnv(seed=seed)
    env.reset()
    rng = np.random.default_rng(seed)
    rows = []
    for _ in range(steps):
        a = rng.uniform(-1, 1, 2)
        obs, r, _, _, info = env.step(a)
        pos = info["features"]["position"]
        rows.append(
            {
                "obs": obs,
                "action": a,
                "reward": r,
                "cost": info["cost"],
                "safe": info["safe"],
                # a 4-dim "VAE input" (position and its square) for the ursa mode
                "features": np.concatenate([pos, pos**2]) if vae_input else pos,
                "skill": np.zeros(3 if vae_input else 2),
            }
        )
    rep = Replay(10_000)
    for s in range(0, steps, 50):
        chunk = {k: np.stack([r[k] for r in rows[s : s + 50]]) for k in rows[0]}
        rep.add("c0", chunk, s)
    return rep


def _snapshot(points: np.ndarray, inputs: np.ndarray | None = None) -> SkillSnapshot:
    rep = Repertoire(
        RepertoireConfig(
            size=200, dim=points.shape[1], n_z=20, input_dim=None if inputs is None else 4
        )
    )
    rep.commit_many(points, inputs)
    return SkillSnapshot.from_repertoire(rep)


@pytest.mark.parametrize("mode", ["ursa-supervised", "ursa", "daydreamer"])
def test_train_step_every_mode(mode: str) -> None:
    cfg = dataclasses.replace(MICRO, mode=mode)  # type: ignore[arg-type]
    vae = mode == "ursa"
    replay = _random_replay(vae_input=vae)
    feat_in = 4 if vae else 2
    learner = Learner(cfg, 6, 2, feat_in)
    rng = np.random.default_rng(0)
    pts = rng.uniform(-1, 1, size=(300, 2))
    snap = None
    if mode == "ursa-supervised":
        snap = _snapshot(pts)
    elif vae:
        inputs = np.concatenate([pts, pts**2], 1)
        snap = _snapshot(learner.encode(inputs), inputs)
    phases = ("wm", "imagination", "actor", "critics", "multipliers", "vae")
    timed = wall = 0.0
    for _ in range(4):
        batch = replay.sample(cfg.batch_size, cfg.seq_len, rng)
        t0 = time.perf_counter()
        m = learner.train_step(batch, snap)
        wall += time.perf_counter() - t0
        timed += sum(m[f"time/{p}"] for p in phases)
        # the phases that always compute take time; each phase is timed from its own start
        assert all(m[f"time/{p}"] > 0.0 for p in ("wm", "imagination", "actor", "critics"))
    # the phases are disjoint slices of the step: together they are at most its wall time, and
    # they are most of it (only the metrics' conversion to floats is outside them)
    assert 0.5 * wall < timed <= wall
    assert all(math.isfinite(v) for v in m.values())
    for key in ("wm/loss", "wm/decoder", "wm/reward", "wm/dyn", "wm/rep", "actor/loss"):
        assert key in m
    if mode == "daydreamer":
        assert learner.skill_dim == 0 and "lambda1/mean" not in m and "wm/cost" not in m
    else:
        for key in ("critic/sf", "critic/cost", "lambda1/mean", "lambda2/mean", "delta", "wm/phi"):
            assert key in m
        assert m["delta"] == pytest.approx(snap.delta if snap else 0.0)
    if vae:
        assert learner.skill_dim == 3 and learner.vae_version == 1  # publish_every = 3
        assert "vae/loss" in m


def test_delta_scale_tightens_the_skill_constraint() -> None:
    """λ1's labels and the actor's distance term use delta_scale · δ: with the same batch and
    seed, only the threshold differs, so fewer imagined states count as within it."""
    replay = _random_replay()
    snap = _snapshot(np.random.default_rng(0).uniform(-1, 1, size=(300, 2)))
    batch = replay.sample(MICRO.batch_size, MICRO.seq_len, np.random.default_rng(0))
    out = {}
    for scale in (1.0, 0.25):
        # γ 0.5: the imagined (1−γ)ψ follows the predicted φ, so distances spread around δ
        cfg = dataclasses.replace(MICRO, mode="ursa-supervised", discount=0.5, delta_scale=scale)
        learner = Learner(cfg, 6, 2, 2)
        out[scale] = learner.train_step(batch, snap)
    assert out[0.25]["delta"] == pytest.approx(0.25 * snap.delta)
    assert out[1.0]["delta"] == pytest.approx(snap.delta)
    assert out[0.25]["imag/distance"] == pytest.approx(out[1.0]["imag/distance"], rel=1e-5)
    assert out[0.25]["imag/within_delta"] < out[1.0]["imag/within_delta"]
    with pytest.raises(ValueError, match="delta_scale"):
        dataclasses.replace(MICRO, delta_scale=0.0)


def test_lambda2_step_label_adds_unsafe_steps_ahead() -> None:
    """``lambda2_label="step"`` labels a state unsafe when its cost return is positive or an
    imagined step ahead has a positive cost: on the same batch and seed the imagined rollout and
    the returns are the same, and the labelled fraction can only grow; it does here, since the
    untrained model predicts costs of both signs."""
    replay = _random_replay()
    snap = _snapshot(np.random.default_rng(0).uniform(-1, 1, size=(300, 2)))
    batch = replay.sample(MICRO.batch_size, MICRO.seq_len, np.random.default_rng(0))
    out = {}
    for label in ("return", "step"):
        cfg = dataclasses.replace(
            MICRO,
            mode="ursa-supervised",
            lambda2_label=label,  # type: ignore[arg-type]
        )
        out[label] = Learner(cfg, 6, 2, 2).train_step(batch, snap)
    assert out["step"]["imag/cost_return"] == pytest.approx(out["return"]["imag/cost_return"])
    assert out["step"]["lambda2/violated"] > out["return"]["lambda2/violated"]
    assert out["step"]["lambda1/violated"] == pytest.approx(out["return"]["lambda1/violated"])
    with pytest.raises(ValueError, match="lambda2_label"):
        dataclasses.replace(MICRO, lambda2_label="any")  # type: ignore[arg-type]


def test_cost_margin_cap_raises_the_cost_return_only() -> None:
    """``cost_margin_cap`` clips the imagined costs from below: on the same batch and seed (same
    rollout), a cap of 0 removes every negative predicted cost, so the cost return rises and λ2's
    labels can only grow; a cap beyond every predicted margin changes nothing; the skill side
    does not move."""
    replay = _random_replay()
    snap = _snapshot(np.random.default_rng(0).uniform(-1, 1, size=(300, 2)))
    batch = replay.sample(MICRO.batch_size, MICRO.seq_len, np.random.default_rng(0))
    out = {}
    for cap in (None, 0.0, 1e6):
        cfg = dataclasses.replace(MICRO, mode="ursa-supervised", cost_margin_cap=cap)
        out[cap] = Learner(cfg, 6, 2, 2).train_step(batch, snap)
    assert out[0.0]["imag/cost_return"] > out[None]["imag/cost_return"]
    assert out[0.0]["lambda2/violated"] >= out[None]["lambda2/violated"]
    assert out[1e6]["imag/cost_return"] == pytest.approx(out[None]["imag/cost_return"])
    assert out[0.0]["lambda1/violated"] == pytest.approx(out[None]["lambda1/violated"])
    assert out[0.0]["imag/distance"] == pytest.approx(out[None]["imag/distance"], rel=1e-5)
    with pytest.raises(ValueError, match="cost_margin_cap"):
        dataclasses.replace(MICRO, cost_margin_cap=-0.1)


def test_lambda2_pos_weight_scales_the_unsafe_labels() -> None:
    """λ2's loss is Σ γ^t [w·y·softplus(−x) + (1 − y)·softplus(x)]: on the same batch and seed
    (same rollout, labels and logits) it is affine in w with a positive slope, and λ1's loss
    does not move."""
    replay = _random_replay()
    snap = _snapshot(np.random.default_rng(0).uniform(-1, 1, size=(300, 2)))
    batch = replay.sample(MICRO.batch_size, MICRO.seq_len, np.random.default_rng(0))
    loss1, loss2 = {}, {}
    for w in (1.0, 2.0, 3.0):
        cfg = dataclasses.replace(MICRO, mode="ursa-supervised", lambda2_pos_weight=w)
        m = Learner(cfg, 6, 2, 2).train_step(batch, snap)
        loss1[w], loss2[w] = m["lambda1/loss"], m["lambda2/loss"]
    assert m["lambda2/violated"] > 0.0
    slope = loss2[2.0] - loss2[1.0]
    assert slope > 0.0
    assert loss2[3.0] - loss2[2.0] == pytest.approx(slope, rel=1e-3)
    assert loss1[1.0] == pytest.approx(loss1[3.0])
    with pytest.raises(ValueError, match="lambda2_pos_weight"):
        dataclasses.replace(MICRO, lambda2_pos_weight=0.0)


@pytest.mark.parametrize("actor_grad", ["dynamics", "reinforce"])
def test_actor_mean_bound_penalises_a_saturated_mean(actor_grad: str) -> None:
    """An actor whose pre-tanh mean is 4 everywhere (output weights 0, bias 4): with
    ``actor_mean_bound`` 1 the actor's loss grows by Σ_a (4 − 1)² = 18 per imagined state,
    weighted by γ^t as the objective is, and nothing else changes (same batch, same seed);
    its first step lowers the mean's bias (the penalty's gradient dominates)."""
    replay = _random_replay()
    snap = _snapshot(np.random.default_rng(0).uniform(-1, 1, size=(300, 2)))
    batch = replay.sample(MICRO.batch_size, MICRO.seq_len, np.random.default_rng(0))
    out, bias = {}, {}
    for bound in (0.0, 1.0):
        cfg = dataclasses.replace(
            MICRO,
            mode="ursa-supervised",
            actor_grad=actor_grad,  # type: ignore[arg-type]
            actor_mean_bound=bound,
        )
        learner = Learner(cfg, 6, 2, 2)
        head = learner.actor.mlp.head
        assert head is not None
        with torch.no_grad():
            head.bias[:2] = 4.0  # the mean's half of the output (its weights start at 0)
        out[bound] = learner.train_step(batch, snap)
        bias[bound] = head.bias[:2].detach().clone()
    g = MICRO.discount ** np.arange(MICRO.imag_horizon)
    penalty = 18.0 * g.mean()
    assert out[1.0]["actor/loss"] - out[0.0]["actor/loss"] == pytest.approx(penalty, rel=1e-4)
    assert out[1.0]["actor/mean_excess"] == pytest.approx(3.0, rel=1e-5)
    assert "actor/mean_excess" not in out[0.0]
    assert torch.all(bias[1.0] < 4.0)
    with pytest.raises(ValueError, match="actor_mean_bound"):
        dataclasses.replace(MICRO, actor_mean_bound=-1.0)


def test_vae_encoder_reencodes_repertoire() -> None:
    cfg = dataclasses.replace(MICRO, mode="ursa", vae_publish_every=1000)
    learner = Learner(cfg, 6, 2, 4)
    rng = np.random.default_rng(0)
    pts = rng.uniform(-1, 1, size=(400, 2))
    inputs = np.concatenate([pts, pts**2], 1)
    rep = Repertoire(RepertoireConfig(size=300, dim=3, n_z=20, input_dim=4))
    rep.commit_many(learner.encode(inputs), inputs)
    snap = SkillSnapshot.from_repertoire(rep)
    assert snap.inputs is not None and snap.inputs.shape == (300, 4)
    replay = _random_replay(vae_input=True)
    before = learner.encode(inputs[:5])
    for _ in range(3):
        learner.train_step(replay.sample(4, 8, rng), snap)
    np.testing.assert_array_equal(learner.encode(inputs[:5]), before)  # not published yet
    version = learner.publish_encoder()
    assert version == 1
    rep.reencode(learner.encode, version)
    assert rep.encoder_version == 1
    np.testing.assert_allclose(rep.skills, learner.encode(rep.inputs), rtol=1e-6, atol=1e-7)
    # the collector's policy computes the same φ from the shipped weights
    pol = Policy(cfg, 6, 2, 3, feat_in_dim=4)
    pol.load_weights_bytes(learner.policy_weights_bytes())
    assert pol.vae_version == 1
    np.testing.assert_allclose(pol.features(inputs[:7]), learner.encode(inputs[:7]), rtol=1e-6)


def test_policy_weights_are_safetensors_and_match() -> None:
    cfg = dataclasses.replace(MICRO, mode="ursa-supervised")
    learner = Learner(cfg, 6, 2, 2)
    replay = _random_replay()
    snap = _snapshot(np.random.default_rng(0).uniform(-1, 1, (300, 2)))
    for _ in range(3):
        learner.train_step(replay.sample(4, 8, np.random.default_rng(1)), snap)
    b = learner.policy_weights_bytes()
    assert not b.startswith(b"\x80")  # not a pickle
    from safetensors.torch import load

    tensors = load(b)
    assert any(k.startswith("actor.") for k in tensors) and any(
        k.startswith("rssm.") for k in tensors
    )
    pol = Policy(cfg, 6, 2, 2)
    pol.load_weights_bytes(b)
    assert pol.version == learner.updates == 3
    for k, v in learner.actor.state_dict().items():
        torch.testing.assert_close(pol.actor.state_dict()[k], v)
    # the policy's deterministic action is the learner's actor at the filtered state, its
    # latent the one the learner's RSSM samples with the same uniforms (the policy's own
    # numpy generator draws them in use; torch's stand in here)
    pol.latent_rng = TorchUniforms(0)  # type: ignore[assignment]
    carry = pol.initial_carry()
    obs = np.array([0.5, 0.5, 0, 0, 0, 0], np.float32)
    a, carry2 = pol.act(carry, obs, np.array([0.2, 0.3]), explore=False)
    with torch.no_grad():
        h0, z0, a0 = (torch.as_tensor(x) for x in (carry.h, carry.z, carry.action))
        h = learner.wm.rssm.core(h0, z0, a0)
        post = learner.wm.rssm.post_probs(h, learner.wm.encoder(torch.as_tensor(obs)[None]))
        z = learner.wm.rssm.sample(post, torch.Generator().manual_seed(0))
        want = learner.actor.mode(torch.cat([h, z], -1), torch.tensor([[0.2, 0.3]]))
    np.testing.assert_allclose(a, want[0].numpy(), rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(carry2.h, h.numpy(), rtol=1e-5, atol=1e-5)
    np.testing.assert_array_equal(carry2.z, z.numpy())
    assert carry2.action.shape == (1, 2)
    with pytest.raises(ValueError):
        Policy(dataclasses.replace(cfg, units=16), 6, 2, 2).load_weights_bytes(b)


def test_untrained_policy_acts_at_random() -> None:
    pol = Policy(MICRO, 6, 2, 2, feat_in_dim=4, seed=3)
    env = PointEnv(seed=0)
    obs, _ = env.reset()
    carry = pol.initial_carry()
    acts = []
    rng = np.random.default_rng(0)
    for _ in range(500):
        a, carry = pol.act(carry, obs, np.zeros(2), explore=True, rng=rng)
        obs, *_ = env.step(a)
        acts.append(a)
    acts_arr = np.array(acts)
    assert acts_arr.shape == (500, 2) and np.all(np.abs(acts_arr) <= 1.0)
    assert np.all(np.abs(acts_arr.mean(0)) < 0.1)
    assert np.all(acts_arr.std(0) > 0.4)  # wide, like uniform actions (std 0.58)
    assert np.abs(np.corrcoef(acts_arr[:-1, 0], acts_arr[1:, 0])[0, 1]) < 0.15
    a0, _ = pol.act(pol.initial_carry(), obs, np.zeros(2), explore=False)
    np.testing.assert_array_equal(a0, np.zeros(2))  # deterministic mode: stand still


def _batches(n: int, seed: int) -> list[dict[str, np.ndarray]]:
    replay = _random_replay(seed=seed)
    rng = np.random.default_rng(seed)
    return [replay.sample(4, 8, rng) for _ in range(n)]


@pytest.mark.parametrize("mode", ["ursa-supervised", "ursa"])
def test_checkpoint_resumes_bit_for_bit(tmp_path: Path, mode: str) -> None:
    cfg = dataclasses.replace(MICRO, mode=mode, vae_publish_every=4)  # type: ignore[arg-type]
    vae = mode == "ursa"
    replay = _random_replay(vae_input=vae)
    rng = np.random.default_rng(0)
    batches = [replay.sample(4, 8, rng) for _ in range(8)]
    pts = rng.uniform(-1, 1, size=(300, 2))
    feat_in = 4 if vae else 2
    a = Learner(cfg, 6, 2, feat_in)
    if vae:
        inputs = np.concatenate([pts, pts**2], 1)
        snap = _snapshot(a.encode(inputs), inputs)
    else:
        snap = _snapshot(pts)
    for b in batches[:3]:
        a.train_step(b, snap)
    path = tmp_path / "learner.pt"
    a.save_checkpoint(path)
    cont = [a.train_step(b, snap) for b in batches[3:]]
    # a fresh learner with another seed, loaded from the checkpoint, continues identically
    other = Learner(dataclasses.replace(cfg, seed=99), 6, 2, feat_in)
    other.load_checkpoint(path)
    again = [other.train_step(b, snap) for b in batches[3:]]
    for m1, m2 in zip(cont, again, strict=True):
        for k in m1:
            if not k.startswith("time/"):
                assert m1[k] == m2[k], k
    for (k, v1), v2 in zip(
        a.actor.state_dict().items(), other.actor.state_dict().values(), strict=True
    ):
        assert torch.equal(v1, v2), k
    assert a.np_rng.random() == other.np_rng.random()
    if vae:
        assert a.vae_version == other.vae_version == 2


def test_checkpoint_rejects_other_dims(tmp_path: Path) -> None:
    a = Learner(MICRO, 6, 2, 4)
    a.save_checkpoint(tmp_path / "c.pt")
    with pytest.raises(ValueError):
        Learner(MICRO, 7, 2, 4).load_checkpoint(tmp_path / "c.pt")


def test_phi_head_error_is_measured_in_the_metric_of_delta() -> None:
    """``phi_metric="skill"``: the world model's φ loss is ‖symexp(head) − φ‖²_Σ with the
    snapshot's Σ (hand-computed from the head's output here), so a repertoire spread 10×
    narrower weighs the same error 100× more; ``symlog`` keeps the squared symlog error,
    whatever Σ."""
    replay = _random_replay()
    batch = replay.sample(MICRO.batch_size, MICRO.seq_len, np.random.default_rng(0))
    wide = _snapshot(np.random.default_rng(0).uniform(-1, 1, size=(300, 2)))
    narrow = dataclasses.replace(wide, cov=wide.cov / 100.0)
    cfg = dataclasses.replace(MICRO, mode="ursa-supervised", phi_metric="skill")

    def phi_loss(config: LearnerConfig, snap: SkillSnapshot) -> float:
        return Learner(config, 6, 2, 2).train_step(batch, snap)["wm/phi"]

    # by hand, with the same initial weights (seeded) and generator
    learner = Learner(cfg, 6, 2, 2)
    data = learner._tensors(batch)
    emb = learner.wm.encoder(data["obs"])
    post = learner.wm.rssm.observe(emb, data["action"], data["is_first"], learner.gen)
    with torch.no_grad():
        pred = learner.wm.predict(learner.wm.feat(post["h"], post["z"]))["phi"].numpy()
    a = kde.whitening_matrix(kde.regularize_cov(wide.cov))
    want = (((pred - batch["features"]) @ a.T) ** 2).sum(-1).mean()
    assert phi_loss(cfg, wide) == pytest.approx(want, rel=1e-4)
    assert phi_loss(cfg, narrow) == pytest.approx(100.0 * want, rel=1e-3)
    sym = dataclasses.replace(cfg, phi_metric="symlog")
    assert LearnerConfig().phi_metric == "symlog"  # the default (the A1 presets' loss)
    assert phi_loss(sym, narrow) == pytest.approx(phi_loss(sym, wide), rel=1e-6)
    assert phi_loss(sym, wide) < want / 10.0  # the features' own scale: a small term
    with pytest.raises(ValueError, match="phi_metric"):
        dataclasses.replace(MICRO, phi_metric="l1")  # type: ignore[arg-type]


def test_presets_change_sizes_only() -> None:
    tiny, small, paper = (learner_preset(n) for n in ("tiny", "small", "paper"))  # type: ignore[arg-type]
    sizes = {
        "deter", "hidden", "stoch", "classes", "units", "layers", "bins", "batch_size",
        "seq_len", "imag_starts", "lagrange_units", "vae_units", "vae_batch",
        "compute_dtype",  # bf16 pays only at sizes whose layers fill the matrix units
    }  # fmt: skip
    for cfg in (tiny, small):
        diff = {
            f.name
            for f in dataclasses.fields(cfg)
            if getattr(cfg, f.name) != getattr(paper, f.name)
        }
        assert diff <= sizes, diff
    assert paper.deter == 512 and paper.stoch == 32 and paper.classes == 32 and paper.bins == 255
    assert paper.discount == 0.995 and paper.imag_horizon == 15 and paper.return_lambda == 0.95
    assert learner_preset("tiny", mode="daydreamer").mode == "daydreamer"
    with pytest.raises(ValueError):
        LearnerConfig(mode="other")  # type: ignore[arg-type]


def test_serial_loop_and_evaluation_smoke() -> None:
    cfg = dataclasses.replace(MICRO, mode="ursa-supervised", train_ratio=4)
    sc = SerialConfig(
        prefill=300, skill_period=100, chunk_len=25, sync_every=2, repertoire_size=200, n_z=20
    )
    loop = SerialLoop(PointEnv(seed=0), cfg, sc)
    loop.run(400)
    assert loop.env_steps == 400 and len(loop.replay) == 400
    assert loop.learner.updates == 400 * 4 // (4 * 8)
    assert loop.policy.version == loop.learner.updates
    assert loop.repertoire is not None and len(loop.repertoire) == 200
    skills = loop.repertoire.sample(3, np.random.default_rng(0))
    res = evaluate_skills(
        loop.policy, PointEnv(seed=1), skills, 20, loop.repertoire.cov, record=True
    )
    assert res.achieved.shape == (3, 2) and res.distance.shape == (3,)
    # reference: the recorded actions replayed in a fresh env of the same seed, without resets
    # (the point env's φ is the position itself in ursa-supervised mode)
    _check_against_replay(res, PointEnv(seed=1), loop.repertoire.cov)
    # random actions in an arena that is mostly unsafe disc: some steps are unsafe, some not
    big = PointConfig(unsafe_radius=0.9)
    rnd = evaluate_skills(None, PointEnv(big, seed=1), skills, 20, loop.repertoire.cov, record=True)
    assert np.any(rnd.violation_rate > 0) and np.any(rnd.violation_rate < 1)
    _check_against_replay(rnd, PointEnv(big, seed=1), loop.repertoire.cov)


def _check_against_replay(res: EvalResult, env: PointEnv, cov: np.ndarray) -> None:
    """``res``'s returns, violation rates, achieved skills and distances equal what stepping
    ``env`` with ``res``'s recorded actions gives, counted here step by step."""
    assert res.actions is not None and res.obs is not None
    k, steps = res.actions.shape[:2]
    env.reset()
    sigma = kde.regularize_cov(cov)
    for i in range(k):
        ret, unsafe, pos = 0.0, 0, []
        for t in range(steps):
            obs, r, _, _, info = env.step(res.actions[i, t])
            # float32 recorded actions: the replay drifts by rounding only
            np.testing.assert_allclose(obs, res.obs[i, t], atol=1e-5)
            ret += r
            unsafe += not info["safe"]
            pos.append(info["features"]["position"])
        assert res.returns[i] == pytest.approx(ret, rel=1e-6)
        assert res.violation_rate[i] == unsafe / steps
        # the scoring rule: φ averaged over the steps after the settle period (20 % of T)
        settle = int(0.2 * steps)
        mean = np.mean(pos[settle:], 0)
        np.testing.assert_allclose(res.achieved[i], mean, atol=1e-5)
        d = mean - res.skills[i]
        assert res.distance[i] == pytest.approx(  # ‖d‖_Σ = sqrt(dᵀ Σ⁻¹ d)
            float(np.sqrt(d @ np.linalg.solve(sigma, d))), rel=1e-4, abs=1e-5
        )


def test_serial_loop_ursa_mode_reencodes() -> None:
    cfg = dataclasses.replace(MICRO, mode="ursa", train_ratio=4, vae_publish_every=5)
    sc = SerialConfig(prefill=200, skill_period=50, chunk_len=25, repertoire_size=100, n_z=10)

    class VaeInputPoint(PointEnv):
        feature_dims = {"position": 2, "vae_input": 4}  # noqa: RUF012

        def step(self, action: np.ndarray):  # type: ignore[no-untyped-def]
            obs, r, te, tr, info = super().step(action)
            p = info["features"]["position"]
            info["features"]["vae_input"] = np.concatenate([p, p**2])
            return obs, r, te, tr, info

    loop = SerialLoop(VaeInputPoint(seed=0), cfg, dataclasses.replace(sc, feature="vae_input"))
    loop.run(300)
    assert loop.learner.vae_version >= 1
    rep = loop.repertoire
    assert rep is not None and rep.encoder_version == loop.learner.vae_version
    np.testing.assert_allclose(rep.skills, loop.learner.encode(rep.inputs), rtol=1e-5, atol=1e-6)


def test_serial_loop_starts_a_new_segment_and_carry_at_every_rescue() -> None:
    # rescues mid-chunk (step 10), on a chunk's first step (35: records 10..34 fill one chunk)
    # and after the prefill (70)
    sc = SerialConfig(prefill=60, skill_period=100, chunk_len=25, repertoire_size=200, n_z=20)
    loop = SerialLoop(RescuedPoint({10, 35, 70}), MICRO, sc)
    carries = []
    orig = loop.policy.initial_carry

    def spy():  # type: ignore[no-untyped-def]
        carries.append(loop.env_steps)
        return orig()

    loop.policy.initial_carry = spy  # type: ignore[method-assign]
    loop.collect(100)
    assert loop.replay.gaps == 3 and len(loop.replay) == 100 - loop.acting.open_records
    s = loop.replay._streams[loop.stream_id]
    firsts = np.flatnonzero(s.is_first[s.start : s.end])
    np.testing.assert_array_equal(firsts, [0, 10, 35, 70])
    assert 70 in carries  # the policy's recurrent state starts over at the rescue after prefill
