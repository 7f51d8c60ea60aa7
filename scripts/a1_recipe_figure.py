"""Plot the A1 CPU recipe's measurements (docs/results/a1_cpu_recipe.json, written from the
runs of scripts/a1_serial.py): violation rate of the acting policy against updates, per
variant and seed, with uniformly random actions' rate as the reference.

    .venv/bin/python scripts/a1_recipe_figure.py  # -> docs/figures/a1_cpu_recipe.png
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", type=Path, default=ROOT / "docs/results/a1_cpu_recipe.json")
    ap.add_argument("--out", type=Path, default=ROOT / "docs/figures/a1_cpu_recipe.png")
    a = ap.parse_args()
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    data = json.loads(a.data.read_text())
    variants = sorted({r["variant"] for r in data["runs"]})
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.2), sharey=True, constrained_layout=True)
    groups = [
        ("the cpu recipe (no SF residual) and the residual prior", ("cpu", "residual")),
        ("rejected variants", ("x3", "0.95", "std", "float32")),
    ]
    cmap = plt.get_cmap("tab10")
    colours = {v: cmap(i % 10) for i, v in enumerate(variants)}
    for ax, (title, keys) in zip(axes, groups, strict=True):
        for r in data["runs"]:
            v = r["variant"]
            first = v.split(",")[-1] if ax is axes[0] else v
            if ax is axes[0] and not (v.startswith("cpu") or v == "128 starts, residual"):
                continue
            if ax is axes[1] and not any(k in v for k in keys):
                continue
            rows = [x for x in r["rows"] if x["updates"] > 0]
            ax.plot(
                [x["updates"] for x in rows],
                [x["violation_rate"] for x in rows],
                color=colours[v],
                ls=("-", "--", "-.")[r["seed"] % 3],
                marker="o",
                ms=3,
                lw=1.2,
                label=f"{first.strip()} (seed {r['seed']})",
            )
        ax.axhline(data["random_violation_rate"], color="k", ls="--", lw=1, label="random actions")
        ax.axhline(data["random_violation_rate"] / 2, color="grey", ls=":", lw=1, label="CI bar")
        ax.set_title(title, fontsize=10)
        ax.set_xlabel("learner updates (16 env steps each; 2000 random prefill steps first)")
        ax.legend(fontsize=7)
    axes[0].set_ylabel("violation rate per 1000 env steps")
    fig.suptitle("A1, forward task, learned φ, small sizes, 128 imagination starts, bf16, 1 thread")
    a.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(a.out, dpi=110)
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
