"""A trained policy as a self-contained ONNX model and a JSON of its interface (``ursa export``).

The model is one control step of what a collector runs (:mod:`ursa.policy_np`): the observation
encoder, the RSSM's filter step (GRU core, posterior, latent sample) and the actor, with the skill
as an input. The recurrent state travels in and out, so a robot's loop is::

    h, z, a = h0, z0, zeros                       # from the JSON
    every 1/control_hz s: obs -> action, h, z, mean, std = run(obs, h, z, a, skill, u, eps)
                          a = action; send joint targets of `action` (the JSON's action mapping)

Inputs (B a batch axis): ``obs`` (B, O), ``h`` (B, deter), ``z`` (B, S·K), ``prev_action`` (B, A)
the action the model returned last step, ``skill`` (B, D) (the exported skill is in the JSON;
any other skill of the repertoire's space works), ``u`` (B, S) uniforms in [0, 1) that draw the
RSSM's latent (DreamerV3 samples it; the actor was trained on samples), ``eps`` (B, A) standard
normal action noise (zeros: the deterministic action tanh(mean)). Outputs: ``action`` (B, A) in
[−1, 1] = tanh(mean + std·eps), ``h_next``, ``z_next``, ``mean``, ``std``.

The graph is built node by node with ``onnx.helper`` from the weights the numpy path computes
with, op for op the same arithmetic, so that onnxruntime agrees with torch and numpy to float
rounding (tested ≤ 1e-5). Needs the ``export`` extra (onnx, onnxruntime).
"""

from __future__ import annotations

import json
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import numpy as np
import tyro

from ursa.plain import to_plain

if TYPE_CHECKING:  # type hints only: policy_np loads torch, which `ursa --help` need not
    from ursa import policy_np
    from ursa.policy import Policy
    from ursa.policy_np import MLPParams, NormLinear, PolicyParams

OPSET = 17
INPUTS = ("obs", "h", "z", "prev_action", "skill", "u", "eps")
OUTPUTS = ("action", "h_next", "z_next", "mean", "std")


class _Graph:
    """Nodes and initializers of one ONNX graph, with fresh names."""

    def __init__(self) -> None:
        from onnx import helper, numpy_helper

        self.helper, self.numpy_helper = helper, numpy_helper
        self.nodes: list[Any] = []
        self.inits: list[Any] = []
        self._n = 0

    def name(self, base: str) -> str:
        self._n += 1
        return f"{base}_{self._n}"

    def const(self, value: Any, base: str = "c") -> str:
        arr = np.asarray(value)
        if arr.dtype == np.float64:
            arr = arr.astype(np.float32)
        n = self.name(base)
        self.inits.append(self.numpy_helper.from_array(arr, n))
        return n

    def op(self, kind: str, *inputs: str, out: str | None = None, **attrs: Any) -> str:
        o = out or self.name(kind.lower())
        self.nodes.append(self.helper.make_node(kind, list(inputs), [o], **attrs))
        return o

    def ops(self, kind: str, inputs: list[str], n_out: int, **attrs: Any) -> list[str]:
        outs = [self.name(kind.lower()) for _ in range(n_out)]
        self.nodes.append(self.helper.make_node(kind, inputs, outs, **attrs))
        return outs

    # ---- the blocks of ursa.policy_np -------------------------------------------------------
    def norm_linear(self, x: str, p: NormLinear) -> str:
        # x @ w is already centred (see NormLinear): LayerNorm's own centring subtracts ~0
        y = self.op("MatMul", x, self.const(p.w, "w"))
        return self.op(
            "LayerNormalization",
            y,
            self.const(p.scale, "ln_scale"),
            self.const(p.shift, "ln_shift"),
            axis=-1,
            epsilon=p.eps,
        )

    def silu(self, x: str) -> str:
        return self.op("Mul", x, self.op("Sigmoid", x))

    def mlp(self, x: str, p: MLPParams) -> str:
        for layer in p.trunk:
            x = self.silu(self.norm_linear(x, layer))
        if p.head_w is not None:
            assert p.head_b is not None
            x = self.op(
                "Add",
                self.op("MatMul", x, self.const(p.head_w, "head_w")),
                self.const(p.head_b, "head_b"),
            )
        return x

    def symlog(self, x: str) -> str:
        mag = self.op("Log", self.op("Add", self.op("Abs", x), self.const(np.float32(1.0))))
        return self.op("Mul", self.op("Sign", x), mag)

    def split(self, x: str, sizes: list[int]) -> list[str]:
        return self.ops(
            "Split", [x, self.const(np.asarray(sizes, np.int64), "split")], len(sizes), axis=-1
        )

    def gru(self, x: str, h: str, p: policy_np.GRUParams) -> str:
        parts = self.norm_linear(self.op("Concat", x, h, axis=-1), p.gates)
        n = p.size
        r_in, c_in, u_in = self.split(parts, [n, n, n])
        cand = self.op("Tanh", self.op("Mul", self.op("Sigmoid", r_in), c_in))
        update = self.op("Sigmoid", u_in)  # the −1 is in the shift
        # h + update · (cand − h)
        return self.op("Add", h, self.op("Mul", update, self.op("Sub", cand, h)))

    def sample_onehot(self, probs: str, u: str, k: int) -> str:
        """Inverse-CDF one-hot sample (B, S, K) as :func:`ursa.policy_np.sample_onehot`."""
        from onnx import TensorProto

        cdf = self.op(
            "Cast",
            self.op(
                "CumSum",
                self.op("Cast", probs, to=TensorProto.DOUBLE),
                self.const(np.asarray(-1, np.int64), "axis"),
            ),
            to=TensorProto.FLOAT,
        )
        last = self.const(np.asarray([-1], np.int64), "axes")
        below = self.op("Less", cdf, self.op("Unsqueeze", u, last))
        idx = self.op("ReduceSum", self.op("Cast", below, to=TensorProto.INT64), last, keepdims=0)
        idx = self.op("Min", idx, self.const(np.asarray(k - 1, np.int64), "kmax"))
        return self.op("Gather", self.const(np.eye(k, dtype=np.float32), "eye"), idx, axis=0)


def build_onnx(params: PolicyParams, obs_dim: int, act_dim: int, skill_dim: int) -> Any:
    """The ONNX ``ModelProto`` of one policy step (see the module docstring)."""
    from onnx import TensorProto, checker, helper

    g = _Graph()
    p = params
    s, k = p.stoch, p.classes
    deter = int(p.h_init.shape[0])
    # core: h' = GRU(img_in([z, a]), h)
    x = g.mlp(g.op("Concat", "z", "prev_action", axis=-1), p.img_in)
    h = g.gru(x, "h", p.gru)
    g.op("Identity", h, out="h_next")
    # posterior over (S, K) from [h', encode(obs)], unimix, then the sample with u
    embed = g.mlp(g.symlog("obs"), p.encoder)
    logits = g.mlp(g.op("Concat", h, embed, axis=-1), p.post)
    logits = g.op("Reshape", logits, g.const(np.asarray([-1, s, k], np.int64), "shape"))
    probs = g.op("Softmax", logits, axis=-1)
    if p.unimix > 0.0:
        probs = g.op(
            "Add",
            g.op("Mul", probs, g.const(np.float32(1.0 - p.unimix))),
            g.const(np.float32(p.unimix / k)),
        )
    z = g.sample_onehot(probs, "u", k)
    z = g.op("Reshape", z, g.const(np.asarray([-1, s * k], np.int64), "shape"), out="z_next")
    # actor at [h', z', skill]: mean and std (the +2 of the std is in the head's bias)
    out = g.mlp(g.op("Concat", h, z, "skill", axis=-1), p.actor)
    mean, std_logit = g.split(out, [act_dim, act_dim])
    g.op("Identity", mean, out="mean")
    std = g.op(
        "Add",
        g.op("Mul", g.op("Sigmoid", std_logit), g.const(np.float32(p.max_std - p.min_std))),
        g.const(np.float32(p.min_std)),
        out="std",
    )
    g.op("Tanh", g.op("Add", mean, g.op("Mul", std, "eps")), out="action")

    f = TensorProto.FLOAT
    dims = {
        "obs": obs_dim,
        "h": deter,
        "z": s * k,
        "prev_action": act_dim,
        "skill": skill_dim,
        "u": s,
        "eps": act_dim,
        "action": act_dim,
        "h_next": deter,
        "z_next": s * k,
        "mean": act_dim,
        "std": act_dim,
    }
    graph = helper.make_graph(
        g.nodes,
        "ursa_policy_step",
        [helper.make_tensor_value_info(n, f, ["B", dims[n]]) for n in INPUTS],
        [helper.make_tensor_value_info(n, f, ["B", dims[n]]) for n in OUTPUTS],
        initializer=g.inits,
    )
    model = helper.make_model(
        graph, opset_imports=[helper.make_opsetid("", OPSET)], producer_name="ursa export"
    )
    model.ir_version = 8  # onnxruntime reads IR 8 at opset 17 everywhere
    checker.check_model(model, full_check=True)
    return model


def interface(policy: Policy, cfg: Any, skill: np.ndarray, meta: dict[str, Any]) -> dict[str, Any]:
    """The JSON-able description of the exported model's inputs, outputs and robot interface."""
    p = policy.params
    env = cfg.env
    if env == "a1":
        from ursa.envs import a1

        layout = {k: [v.start, v.stop] for k, v in a1.OBS_LAYOUT.items()}
        ac = cfg.a1
        action: dict[str, Any] = {
            "joints": list(a1.JOINT_NAMES),
            "mapping": ac.action_mapping,
            "standing_pose_rad": list(ac.standing_pose) * 4,
            "joint_low_rad": list(ac.joint_low) * 4,
            "joint_high_rad": list(ac.joint_high) * 4,
            "filter": (
                {"butterworth_order": 2, "cutoff_hz": ac.action_filter_hz}
                if ac.action_filter_hz is not None
                else None
            ),
            "doc": "stand_centered: 0 is the standing pose, -1/+1 the ends of [low, high], "
            "piecewise linear; linear: -1..1 onto [low, high] (ursa.envs.a1)",
        }
        control_hz = float(ac.control_hz)
    else:
        layout = {"obs": [0, policy.obs_dim]}
        action = {"mapping": f"see ursa.envs.{env}", "dim": policy.act_dim}
        control_hz = float(getattr(getattr(cfg, env, None), "control_hz", 20.0))
    return {
        "format": "ursa-onnx-policy-1",
        "env": env,
        "control_hz": control_hz,
        "inputs": {
            n: dim
            for n, dim in zip(
                INPUTS,
                (
                    policy.obs_dim,
                    int(p.h_init.shape[0]),
                    p.stoch * p.classes,
                    policy.act_dim,
                    policy.skill_dim,
                    p.stoch,
                    policy.act_dim,
                ),
                strict=True,
            )
        },
        "outputs": list(OUTPUTS),
        "observation_layout": layout,
        "action": action,
        "skill": [float(v) for v in np.asarray(skill).reshape(-1)],
        "initial_state": {"h": p.h_init.tolist(), "z": p.z_init.tolist()},
        "latent": {"stoch": p.stoch, "classes": p.classes},
        **meta,
    }


def export_policy(
    policy: Policy, cfg: Any, skill: np.ndarray, out: Path, meta: dict[str, Any] | None = None
) -> tuple[Path, Path]:
    """Write ``out`` (.onnx) and ``out`` with suffix .json; returns both paths."""
    import onnx

    skill = np.asarray(skill, np.float32).reshape(-1)
    if skill.shape != (policy.skill_dim,):
        raise ValueError(f"skill has {skill.size} values, the policy takes {policy.skill_dim}")
    model = build_onnx(policy.params, policy.obs_dim, policy.act_dim, policy.skill_dim)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    onnx.save_model(model, str(out))
    js = out.with_suffix(".json")
    js.write_text(json.dumps(interface(policy, cfg, skill, dict(meta or {})), indent=1) + "\n")
    return out, js


class OnnxPolicy:
    """An exported model run by onnxruntime, with the :class:`ursa.policy.Policy` carry."""

    def __init__(self, model: Any, threads: int = 1) -> None:
        import onnxruntime as ort

        opts = ort.SessionOptions()
        opts.intra_op_num_threads = threads
        opts.inter_op_num_threads = 1
        blob = model if isinstance(model, bytes) else model.SerializeToString()
        self.session = ort.InferenceSession(blob, opts, providers=["CPUExecutionProvider"])

    def step(self, **inputs: np.ndarray) -> dict[str, np.ndarray]:
        """One step: the INPUTS as float32 arrays (B, ·) -> the OUTPUTS by name."""
        feed = {n: np.asarray(inputs[n], np.float32) for n in INPUTS}
        return dict(zip(OUTPUTS, self.session.run(list(OUTPUTS), feed), strict=True))


def export_run(
    run: str | Path, out: Path, skill_id: int | None = None, z: Sequence[float] | None = None
) -> tuple[Path, Path]:
    """Export the latest checkpoint of a run with a repertoire skill (by id) or a given z."""
    from ursa.eval.loading import load_run

    loaded = load_run(run)
    policy = loaded.require_policy()
    meta: dict[str, Any] = {
        "run": loaded.name,
        "updates": loaded.updates,
        "mode": loaded.mode,
        "policy_version": policy.version,
    }
    if z is not None:
        skill = np.asarray(z, np.float32)
        meta["skill_source"] = "z"
    elif skill_id is not None:
        rep = loaded.require_repertoire()
        hit = np.flatnonzero(rep.ids == skill_id)
        if not len(hit):
            raise ValueError(f"no skill {skill_id} in the repertoire ({len(rep)} skills)")
        skill = rep.skills[hit[0]].astype(np.float32)
        meta["skill_source"] = f"repertoire id {skill_id}"
    elif policy.skill_dim == 0:
        skill = np.zeros(0, np.float32)
        meta["skill_source"] = "none (no skill input)"
    else:
        raise ValueError("give --skill ID or --z ...")
    meta["learner_config"] = to_plain(loaded.config.learner)
    return export_policy(policy, loaded.config, skill, out, meta)


@dataclass(frozen=True, kw_only=True)
class ExportArgs:
    """Write a run's policy as ONNX with a JSON of its interface (give --skill or --z)."""

    run: Annotated[str, tyro.conf.Positional, tyro.conf.arg(metavar="RUN")]
    """run directory (or a learner checkpoint file)"""
    skill: Annotated[int | None, tyro.conf.arg(metavar="ID")] = None
    """id of a repertoire skill to execute (not with --z)"""
    z: Annotated[tuple[float, ...] | None, tyro.conf.arg(metavar="Z [Z ...]")] = None
    """the skill vector itself (not with --skill)"""
    out: Annotated[
        Path | None,
        tyro.conf.arg(metavar="FILE", help_behavior_hint="(default: <run>/export/policy.onnx)"),
    ] = None
    """output .onnx; the JSON goes beside"""


def export_command(a: ExportArgs) -> int:
    """Run ``ursa export``; returns the exit status (2 with a message on stderr when the skill is
    missing, given twice or not in the run)."""
    if a.skill is not None and a.z is not None:
        print("ursa export: give --skill or --z, not both", file=sys.stderr)
        return 2
    run_dir = Path(a.run) if Path(a.run).is_dir() else Path(a.run).parent
    out = a.out or run_dir / "export" / "policy.onnx"
    try:
        model, js = export_run(a.run, out, skill_id=a.skill, z=a.z)
    except (ValueError, FileNotFoundError) as e:
        print(f"ursa export: {e}", file=sys.stderr)
        return 2
    print(f"wrote {model} ({model.stat().st_size} bytes) and {js}")
    return 0


def main(argv: list[str] | None = None) -> int:
    """``ursa export RUN (--skill ID | --z Z1 Z2 ...) [--out FILE]``; returns the exit status."""
    a = tyro.cli(ExportArgs, args=sys.argv[1:] if argv is None else argv, prog="ursa export")
    return export_command(a)


if __name__ == "__main__":
    raise SystemExit(main())
