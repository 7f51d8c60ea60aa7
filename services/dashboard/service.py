"""Dashboard: a viser web page showing the run live. Read-only: it owns no state of the run.

Subscribes:  ursa/{run}/*/stats/** (Stats of every service)
Liveliness:  watches ursa/{run}/alive/**; declares ursa/{run}/alive/dashboard/{id}
"""

from __future__ import annotations

import os
import threading
import time
from dataclasses import dataclass, field

import viser

from proto import ursa_pb2 as pb
from services.common.bus import Presence, safe_handler
from services.common.config import BusConfig, RunConfig, save_resolved
from services.common.runtime import ServiceRuntime
from ursa.config import Config


@dataclass(frozen=True)
class DashboardArgs:
    """Dashboard service settings."""

    core: Config = field(default_factory=Config)
    bus: BusConfig = field(default_factory=BusConfig)
    run: RunConfig = field(default_factory=RunConfig)
    host: str = os.environ.get("URSA_DASHBOARD_HOST", "127.0.0.1")
    """Address the web server binds to (env URSA_DASHBOARD_HOST)."""
    port: int = int(os.environ.get("URSA_DASHBOARD_PORT", "8080"))
    """Port of the web page (env URSA_DASHBOARD_PORT)."""
    refresh_hz: float = 4.0
    """How often the page is updated."""


class Dashboard:
    def __init__(self, args: DashboardArgs) -> None:
        self.args = args
        self.rt = ServiceRuntime("dashboard", "main", args.bus, args.run)
        save_resolved(args, args.run, "dashboard")
        self._lock = threading.Lock()
        self.stats: dict[tuple[str, str], pb.Stats] = {}
        self.presence = Presence(self.rt.session, self.rt.topics.alive())
        self.sub = self.rt.session.declare_subscriber(
            self.rt.topics.all_stats,
            safe_handler(pb.Stats, self._on_stats, self.rt.drops, args.run.run_id),
        )
        self.server = viser.ViserServer(host=args.host, port=args.port, label="URSA")
        self.server.gui.add_markdown(f"# URSA\nrun `{args.run.run_id}`")
        self.status = self.server.gui.add_markdown("*no data yet*")

    def _on_stats(self, msg: pb.Stats, key: str) -> None:
        with self._lock:
            self.stats[(msg.service, msg.id)] = msg

    def render(self) -> str:
        with self._lock:
            stats = dict(self.stats)
        alive = self.presence.alive()
        collectors = sorted(
            sid for key in alive if (p := self.rt.topics.parse_alive(key)) and
            (sid := p[1]) and p[0] == "collector"
        )
        lines = [f"**collectors alive:** {len(collectors)}", ""]
        if collectors:
            lines += ["| collector | steps | steps/s | violation rate |", "|---|---|---|---|"]
            for cid in collectors:
                s = stats.get(("collector", cid))
                if s is None:
                    lines.append(f"| {cid} | – | – | – |")
                else:
                    sc = s.scalars
                    lines.append(f"| {cid} | {sc['steps']:.0f} | {sc['steps_per_s']:.0f} | "
                                 f"{sc['violation_rate']:.3f} |")
        learner = stats.get(("learner", "main"))
        if learner is not None:
            lines += ["", f"**learner replay steps:** {learner.scalars['replay_steps']:.0f}"]
        if not stats and not collectors:
            return "*no data yet*"
        return "\n".join(lines)

    def run(self) -> None:
        print(f"DASHBOARD READY http://{self.args.host}:{self.args.port}", flush=True)
        period = 1.0 / self.args.refresh_hz
        while not self.rt.stop.is_set():
            self.status.content = self.render()
            time.sleep(period)

    def close(self) -> None:
        self.server.stop()
        self.presence.undeclare()
        self.sub.undeclare()
        self.rt.close()
