"""``ursa export``: the ONNX policy agrees with the torch modules and the collector's numpy path
(≤ 1e-5) under onnxruntime, over a recurrent rollout, and the command writes it with its JSON."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

from ursa import policy_np
from ursa.config import build_env, preset
from ursa.eval.loading import load_run
from ursa.export import INPUTS, OUTPUTS, OnnxPolicy, build_onnx, main
from ursa.learner import Learner
from ursa.plain import to_plain
from ursa.policy import Policy
from ursa.repertoire import Repertoire


def _trained_like(env: str, preset_name: str) -> tuple[object, Learner, Policy]:
    """A learner, and a collector policy with its weights perturbed away from their initial
    values (so that every layer, LayerNorm scales and shifts included, matters)."""
    cfg = preset(preset_name, env)  # type: ignore[arg-type]
    e = build_env(cfg, seed=0)
    fin = int(e.feature_dims[cfg.feature_input_key])
    learner = Learner(cfg.learner, e.obs_dim, e.act_dim, fin, cfg.skill_dim)
    policy = Policy(cfg.learner, e.obs_dim, e.act_dim, cfg.skill_dim, fin, seed=0)
    policy.load_weights_bytes(learner.policy_weights_bytes(), version=5)
    g = torch.Generator().manual_seed(3)
    with torch.no_grad():
        for mod in (policy.encoder, policy.rssm, policy.actor):
            for prm in mod.parameters():
                prm.add_(0.05 * torch.randn(prm.shape, generator=g))
    policy.params = policy_np.policy_params(policy.encoder, policy.rssm, policy.actor)
    if hasattr(e, "close"):
        e.close()
    return cfg, learner, policy


@pytest.mark.parametrize(("env", "preset_name"), [("point", "tiny"), ("a1", "small")])
def test_onnx_step_matches_torch_and_numpy(env: str, preset_name: str) -> None:
    _, _, pol = _trained_like(env, preset_name)
    model = build_onnx(pol.params, pol.obs_dim, pol.act_dim, pol.skill_dim)
    ort = OnnxPolicy(model)
    p = pol.params
    rng = np.random.default_rng(1)
    b = 3  # a batch of three robots, each with its own state and skill
    h = np.repeat(p.h_init[None], b, 0)
    z = np.repeat(p.z_init[None], b, 0)
    a = np.zeros((b, pol.act_dim), np.float32)
    skill = rng.normal(size=(b, pol.skill_dim)).astype(np.float32)
    th, tz, ta = (torch.from_numpy(x.copy()) for x in (h, z, a))
    worst = 0.0
    for t in range(25):
        obs = (rng.normal(size=(b, pol.obs_dim)) * 2.0).astype(np.float32)
        u = rng.random((b, p.stoch), dtype=np.float32)
        eps = rng.normal(size=(b, pol.act_dim)) if t % 2 else np.zeros((b, pol.act_dim))
        eps = eps.astype(np.float32)
        out = ort.step(obs=obs, h=h, z=z, prev_action=a, skill=skill, u=u, eps=eps)
        assert set(out) == set(OUTPUTS)
        # torch: the modules the learner trains, fed the same state
        with torch.inference_mode():
            th = pol.rssm.core(th, tz, ta)
            probs = pol.rssm.post_probs(th, pol.encoder(torch.from_numpy(obs)))
            tz = torch.from_numpy(policy_np.sample_onehot(probs.numpy(), u)).flatten(-2)
            mean, std = pol.actor(torch.cat([th, tz], -1), torch.from_numpy(skill))
            ta = torch.tanh(mean + std * torch.from_numpy(eps))
        for name, ref in (
            ("h_next", th),
            ("z_next", tz),
            ("mean", mean),
            ("std", std),
            ("action", ta),
        ):
            err = float(np.abs(out[name] - ref.numpy()).max())
            worst = max(worst, err)
            assert err <= 1e-5, (t, name, err)
        # numpy: the collector's path, robot by robot
        for i in range(b):
            hn, zn = policy_np.filter_step(h[i], z[i], a[i], obs[i], u[i], p)
            m, s = policy_np.actor_dist(hn, zn, skill[i], p)
            np.testing.assert_allclose(out["h_next"][i], hn, atol=1e-5)
            np.testing.assert_array_equal(out["z_next"][i], zn)
            np.testing.assert_allclose(np.tanh(m + s * eps[i]), out["action"][i], atol=1e-5)
        # the exported model's own outputs carry the recurrence (no re-sync with torch)
        h, z, a = out["h_next"], out["z_next"], out["action"]
        th, tz, ta = (torch.from_numpy(x.copy()) for x in (h, z, a))
    assert worst > 0.0 or env == "point"  # float rounding differs somewhere, but stays tiny


def test_policy_act_equals_the_onnx_rollout() -> None:
    """Policy.act (what the collector calls) and the ONNX model, fed the same uniforms."""
    _, _, pol = _trained_like("point", "tiny")
    ort = OnnxPolicy(build_onnx(pol.params, pol.obs_dim, pol.act_dim, pol.skill_dim))
    carry = pol.initial_carry()
    h, z, a = carry.h, carry.z, carry.action
    skill = np.array([0.3, -0.2], np.float32)[: pol.skill_dim]
    latent = np.random.default_rng([0, 1])  # the policy's latent_rng, replayed
    rng = np.random.default_rng(9)
    for _ in range(30):
        obs = rng.normal(size=pol.obs_dim).astype(np.float32)
        act, carry = pol.act(carry, obs, skill, explore=False)
        u = latent.random(pol.params.stoch, dtype=np.float32)
        out = ort.step(
            obs=obs[None],
            h=h,
            z=z,
            prev_action=a,
            skill=skill[None],
            u=u[None],
            eps=np.zeros((1, pol.act_dim), np.float32),
        )
        np.testing.assert_allclose(out["action"][0], act, atol=1e-5)
        h, z, a = out["h_next"], out["z_next"], out["action"]
        np.testing.assert_allclose(h, carry.h, atol=1e-5)


def test_export_command_writes_model_and_interface(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cfg, learner, pol = _trained_like("point", "tiny")
    run = tmp_path / "run1"
    (run / "config").mkdir(parents=True)
    (run / "config" / "learner.yaml").write_text(
        yaml.safe_dump({"argv": [], "config": {"core": to_plain(cfg)}})
    )
    (run / "checkpoints").mkdir()
    learner.save_checkpoint(run / "checkpoints" / "learner.pt")
    rep = Repertoire(cfg.repertoire)  # type: ignore[attr-defined]
    zs = np.random.default_rng(0).uniform(-1, 1, (6, pol.skill_dim))
    rep.commit_many(zs)
    (run / "repertoire").mkdir()
    rep.save(run / "repertoire" / "archive.npz")
    sid = int(rep.ids[2])

    assert main([str(run), "--skill", str(sid)]) == 0
    model_path = run / "export" / "policy.onnx"
    info = json.loads(model_path.with_suffix(".json").read_text())
    np.testing.assert_allclose(info["skill"], rep.skills[2], rtol=1e-6)
    assert info["control_hz"] > 0 and info["env"] == "point"
    assert list(info["inputs"]) == list(INPUTS) and info["outputs"] == list(OUTPUTS)
    assert info["inputs"]["obs"] == pol.obs_dim and info["inputs"]["skill"] == pol.skill_dim
    # the file alone (onnxruntime, no URSA code) runs the policy from the JSON's initial state
    import onnxruntime as ort

    sess = ort.InferenceSession(str(model_path), providers=["CPUExecutionProvider"])
    feed = {
        "obs": np.zeros((1, pol.obs_dim), np.float32),
        "h": np.asarray([info["initial_state"]["h"]], np.float32),
        "z": np.asarray([info["initial_state"]["z"]], np.float32),
        "prev_action": np.zeros((1, pol.act_dim), np.float32),
        "skill": np.asarray([info["skill"]], np.float32),
        "u": np.full((1, info["latent"]["stoch"]), 0.5, np.float32),
        "eps": np.zeros((1, pol.act_dim), np.float32),
    }
    action = sess.run(["action"], feed)[0]
    ref = load_run(run).require_policy().params  # the checkpoint's weights
    hn, zn = policy_np.filter_step(
        ref.h_init, ref.z_init, np.zeros(pol.act_dim, np.float32), feed["obs"][0], feed["u"][0], ref
    )
    mean, _ = policy_np.actor_dist(hn, zn, feed["skill"][0], ref)
    np.testing.assert_allclose(action[0], np.tanh(mean), atol=1e-5)

    assert main([str(run), "--z", "0.1", "0.2", "--out", str(tmp_path / "z.onnx")]) == 0
    assert json.loads((tmp_path / "z.json").read_text())["skill"] == pytest.approx([0.1, 0.2])
    assert main([str(run), "--skill", "99999"]) == 2  # no such skill
    assert main([str(run), "--z", "1.0"]) == 2  # wrong skill size
    capsys.readouterr()
    assert main([str(run), "--skill", str(sid), "--z", "0.1", "-0.2"]) == 2  # both
    assert "give --skill or --z, not both" in capsys.readouterr().err
