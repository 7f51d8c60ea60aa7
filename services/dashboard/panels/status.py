"""Markdown text of the dashboard: the run summary, the collectors table, the other services."""

from __future__ import annotations

import time
from collections.abc import Mapping

from services.common.live import CollectorInfo, SnapshotView, StatsEntry


def _num(x: float | None, fmt: str = ".0f") -> str:
    return "–" if x is None else format(x, fmt)


def _skill(c: CollectorInfo) -> str:
    z = c.skill
    if z is None:
        return "–"
    src = c.stats.labels.get("skill_source", "") if c.stats is not None else ""
    coords = ", ".join(f"{v:.2f}" for v in z[:4]) + (", …" if len(z) > 4 else "")
    return f"({coords})" + (" *zero: no skill yet*" if src == "none" else "")


def summary_markdown(
    snap: SnapshotView | None,
    collectors: list[CollectorInfo],
    shown: int,
    clients: int,
    connected: bool,
) -> str:
    """Always-visible summary: repertoire size (the point count), live collector ids, bus."""
    alive = [c.id for c in collectors if c.alive]
    if snap is None:
        rep = "**repertoire:** *no data yet*"
    else:
        rep = (
            f"**repertoire:** {shown} skills shown (size {snap.size}/{snap.capacity}, "
            f"D={snap.dim}, version {snap.version}, δ={snap.delta:.3g}, "
            f"entropy bound {snap.entropy_bound:.3g})"
        )
    col = (
        f"**collectors alive ({len(alive)}):** {', '.join(alive)}"
        if alive
        else "**collectors alive:** *none yet*"
    )
    bus = "" if connected else " · **bus: no router**"
    return f"{rep}  \n{col}  \n*viewers: {clients}*{bus}"


def collectors_markdown(collectors: list[CollectorInfo]) -> str:
    """One item per live collector: steps, steps/s, violation rate, rescues, return, policy
    version, damage and current skill (a list, not a table: it wraps in a narrow panel)."""
    live = [c for c in collectors if c.alive]
    if not live:
        return "*no collector alive yet*"
    rows = []
    for c in live:
        if c.stats is None:
            rows.append(f"- **{c.id}** *no stats yet*")
            continue
        rows.append(
            f"- **{c.id}** · {_num(c.get('steps_per_s'))} steps/s · "
            f"{_num(c.get('steps'))} steps · violation rate "
            f"{_num(c.get('violation_rate'), '.3f')} · rescues {_num(c.get('rescues'))} · "
            f"return {_num(c.get('return_mean'), '.3f')} · policy "
            f"{_num(c.get('policy_version'))} · damage {c.damage or '–'} · skill {_skill(c)}"
        )
    return "\n".join(rows)


_HEADLINE: dict[str, tuple[str, ...]] = {
    "learner": ("replay_steps", "policy_version", "policy_lag", "updates", "loss/world_model"),
    "repertoire": ("size", "delta", "entropy_bound", "commits", "accepted_per_s"),
    "evaluator": ("evaluations", "busy", "policy_version"),
}


def services_markdown(
    stats: Mapping[tuple[str, str], StatsEntry], alive: Mapping[str, Mapping[str, float]]
) -> str:
    """One line per non-collector service: alive or not, age of its stats, a few headline keys."""
    now = time.time()
    names = sorted(
        {svc for svc, _ in stats if svc != "collector"}
        | {svc for svc in alive if svc != "collector"}
    )
    if not names:
        return "*no service seen yet*"
    lines = []
    for svc in names:
        ids = sorted(set(alive.get(svc, {})) | {sid for s, sid in stats if s == svc})
        for sid in ids:
            e = stats.get((svc, sid))
            state = "alive" if sid in alive.get(svc, {}) else "**gone**"
            if e is None:
                lines.append(f"- **{svc}/{sid}** {state}, no stats yet")
                continue
            keys = _HEADLINE.get(svc, ())
            vals = [f"{k} {v:.4g}" for k in keys if (v := e.scalar(k)) is not None]
            lines.append(
                f"- **{svc}/{sid}** {state} · stats {now - e.received:.1f} s old"
                + (" · " + " · ".join(vals) if vals else "")
            )
    return "\n".join(lines)
