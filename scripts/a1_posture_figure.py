"""Figure of the long A1 posture-task runs (docs/learner.md, "Five thousand updates"): per seed
the violation rate and the imagined fraction of skills within δ against updates, and the
commanded against the achieved mean forward speed and yaw rate of 50 KDE skills.

    .venv/bin/python scripts/a1_posture_figure.py docs/results/a1_posture_long.json \
        docs/figures/a1_posture_long.png
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("results", type=Path)
    ap.add_argument("out", type=Path)
    a = ap.parse_args()

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    runs = json.loads(a.results.read_text())["runs"]
    fig, ax = plt.subplots(1, 3, figsize=(15, 4.2))
    for run in runs.values():
        curve = [r for r in run["curve"] if r["updates"] > 0]
        up = [r["updates"] for r in curve]
        label = f"seed {run['seed']}, window {run['collector_overrides'].get('archive_window', 1)}"
        if run["learner_overrides"]:
            label += ", " + ", ".join(f"{k}={v}" for k, v in run["learner_overrides"].items())
        (line,) = ax[0].plot(up, [r["violation_rate"] for r in curve], label=label)
        ax[0].plot(up, [r["within_delta"] for r in curve], color=line.get_color(), linestyle=":")
        ev = run.get("skills_eval")
        if ev:
            z, got = np.array(ev["skill_values"]), np.array(ev["achieved_values"])
            for d in range(2):
                ax[1 + d].scatter(z[:, d], got[:, d], s=12, color=line.get_color(), label=label)
    ax[0].axhline(0.088, color="k", linewidth=0.8, linestyle="--")
    ax[0].set(
        xlabel="updates",
        ylabel="violation rate (solid), imagined within δ (dotted)",
        title="posture task, 1000-step windows (dashed: the bar 0.088)",
    )
    for d, name in enumerate(("forward speed (m/s)", "yaw rate (rad/s)")):
        lo = min(ax[1 + d].get_xlim()[0], ax[1 + d].get_ylim()[0])
        hi = max(ax[1 + d].get_xlim()[1], ax[1 + d].get_ylim()[1])
        ax[1 + d].plot([lo, hi], [lo, hi], color="k", linewidth=0.8)
        ax[1 + d].set(
            xlabel=f"commanded {name}",
            ylabel=f"achieved mean {name}",
            title="50 KDE skills, 250 steps each",
        )
    ax[0].legend(fontsize=7)
    ax[1].legend(fontsize=7)
    fig.tight_layout()
    a.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(a.out, dpi=110)
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
