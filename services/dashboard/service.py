"""Dashboard: a viser web page showing the run live. Read-only: it owns no state of the run.

Subscribes:  ursa/{run}/*/stats/** (Stats of every service)
             ursa/{run}/repertoire/snapshot (RepertoireSnapshot; also queried at start)
             ursa/{run}/evaluator/adapt_state/* (AdaptJob: damage adaptation, the Adapt tab)
Liveliness:  watches ursa/{run}/alive/*/*; declares ursa/{run}/alive/dashboard/main
Publishes:   ursa/{run}/dashboard/stats (Stats: viewers, skills shown, plots, frame time)

Bus callbacks only store decoded messages in a :class:`LiveState`; a page loop redraws from it
at ``refresh_hz`` (plots at ``plot_hz``, the robot at ``robot_hz``), batching each redraw in
``server.atomic()``. Every viewer (browser tab) shares the same page state.
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass
from typing import Any

import viser

from proto import ursa_pb2 as pb
from services.common.bus import Presence, query_one, safe_handler, validate_with
from services.common.config import ServiceArgs, env_field, save_resolved
from services.common.live import LiveState
from services.common.runtime import ServiceRuntime
from services.dashboard.panels.adapt import AdaptPanel
from services.dashboard.panels.plots import PlotsPanel
from services.dashboard.panels.repertoire import RepertoirePanel
from services.dashboard.panels.robot import RobotPanel
from services.dashboard.panels.status import (
    collectors_markdown,
    services_markdown,
    summary_markdown,
)

log = logging.getLogger("dashboard")


@dataclass(frozen=True)
class DashboardArgs(ServiceArgs):
    """Dashboard service settings."""

    host: str = env_field("URSA_DASHBOARD_HOST", "127.0.0.1")
    """Address the web server binds to (env URSA_DASHBOARD_HOST)."""
    port: int = env_field("URSA_DASHBOARD_PORT", "8080", int)
    """Port of the web page (env URSA_DASHBOARD_PORT)."""
    refresh_hz: float = 4.0
    """How often the tables, the point cloud and the collector markers are updated."""
    plot_hz: float = 1.0
    """How often the time plots are re-sent."""
    robot_hz: float = 20.0
    """How often the A1 model is moved to the selected collector's latest pose."""
    history_points: int = 2048
    """Points kept per plotted scalar (older ones are merged pairwise: bounded for any run)."""
    plot_points: int = 400
    """Points sent per plotted line."""
    max_cloud_points: int = 20000
    """Most skills drawn (the newest); the repertoire is 5000 in the paper preset."""
    robot: bool = True
    """Show the live A1 model (needs ``yourdfpy`` and ``pybullet_data``)."""


class DashboardView:
    """The page: every panel, drawn from a :class:`LiveState`. Needs no bus (tests feed it)."""

    def __init__(
        self,
        server: viser.ViserServer,
        state: LiveState,
        args: DashboardArgs,
        connected: Any = lambda: True,
    ) -> None:
        self.server = server
        self.state = state
        self.args = args
        self.connected = connected
        self._clients_lock = threading.Lock()
        self.clients: set[int] = set()
        self.clients_seen = 0
        self.frame_ms = 0.0

        server.initial_camera.position = (2.6, -2.2, 3.6)
        server.initial_camera.look_at = (0.0, 1.3, 0.6)
        gui = server.gui
        gui.configure_theme(control_width="large", dark_mode=False, show_share_button=False)
        gui.add_markdown(f"## URSA · run `{state.run_id}`")
        self.summary = gui.add_markdown(
            "**repertoire:** *no data yet*  \n**collectors alive:** *none yet*"
        )
        tabs = gui.add_tab_group()
        with tabs.add_tab("Run"):
            self.collectors_md = gui.add_markdown("*no collector alive yet*")
            self.services_md = gui.add_markdown("*no service seen yet*")
        with tabs.add_tab("Skills"):
            self.repertoire = RepertoirePanel(server, max_points=args.max_cloud_points)
        with tabs.add_tab("Robot"):
            self.robot = RobotPanel(server, load_meshes=True) if args.robot else None
            if self.robot is None:
                gui.add_markdown("*robot view disabled (`--no-robot`)*")
        with tabs.add_tab("Adapt"):
            self.adapt = AdaptPanel(server, self.repertoire)
        plots_tab = tabs.add_tab("Plots")
        with plots_tab:
            self.plots = PlotsPanel(server, plots_tab, max_points=args.plot_points)

        server.on_client_connect(self._on_connect)
        server.on_client_disconnect(self._on_disconnect)

    def _on_connect(self, client: viser.ClientHandle) -> None:
        with self._clients_lock:
            self.clients.add(client.client_id)
            self.clients_seen += 1
            n = len(self.clients)
        log.info("viewer connected: client %d (viewers: %d)", client.client_id, n)

    def _on_disconnect(self, client: viser.ClientHandle) -> None:
        with self._clients_lock:
            self.clients.discard(client.client_id)
            n = len(self.clients)
        log.info("viewer left: client %d (viewers: %d)", client.client_id, n)

    @property
    def viewers(self) -> int:
        return len(self.server.get_clients())

    def refresh(self) -> None:
        """One page update (not the plots or the robot)."""
        t0 = time.perf_counter()
        snap = self.state.latest_snapshot()
        collectors = self.state.collectors()
        self.repertoire.update(snap, collectors)
        self.adapt.update()
        alive = {
            svc: self.state.alive_ids(svc)
            for svc in ("learner", "repertoire", "evaluator", "dashboard", "api")
        }
        summary = summary_markdown(
            snap, collectors, self.repertoire.shown, self.viewers, bool(self.connected())
        )
        table = collectors_markdown(collectors)
        services = services_markdown(self.state.all_stats(), alive)
        with self.server.atomic():
            for handle, content in (
                (self.summary, summary),
                (self.collectors_md, table),
                (self.services_md, services),
            ):
                if handle.content != content:
                    handle.content = content
        self.frame_ms = 1000.0 * (time.perf_counter() - t0)

    def refresh_plots(self) -> int:
        return self.plots.update(self.state.series())

    def refresh_robot(self) -> bool:
        return self.robot.update(self.state.collectors()) if self.robot is not None else False


class Dashboard:
    """The dashboard process: bus session + :class:`DashboardView` + its update loops."""

    def __init__(self, args: DashboardArgs) -> None:
        self.args = args
        validate_with(args.core)  # every message decoded is checked against the run's bounds
        self.rt = ServiceRuntime("dashboard", "main", args.bus, args.run)
        save_resolved(args, args.run, "dashboard")
        t = self.rt.topics
        self.presence = Presence(self.rt.session, t.alive())
        self.state = LiveState(
            args.run.run_id, alive=self.presence.alive, history_capacity=args.history_points
        )
        drops = self.rt.drops
        self.subs = [
            self.rt.session.declare_subscriber(
                t.all_stats, safe_handler(pb.Stats, self.state.on_stats, drops, args.run.run_id)
            ),
            self.rt.session.declare_subscriber(
                t.snapshot,
                safe_handler(pb.RepertoireSnapshot, self.state.on_snapshot, drops, args.run.run_id),
            ),
        ]
        self.server = viser.ViserServer(host=args.host, port=args.port, label="URSA", verbose=False)
        self.view = DashboardView(self.server, self.state, args, connected=self.connected)
        self.subs.append(
            self.rt.session.declare_subscriber(
                t.adapt_state("*"),
                safe_handler(
                    pb.AdaptJob, lambda m, _k: self.view.adapt.on_job(m), drops, args.run.run_id
                ),
            )
        )
        self._robot_thread = threading.Thread(
            target=self._robot_loop, daemon=True, name="dashboard-robot"
        )

    def connected(self) -> bool:
        try:
            return bool(self.rt.session.info.routers_zid())
        except Exception:
            return False

    def _query_snapshot(self) -> None:
        msg = query_one(
            self.rt.session, self.rt.topics.snapshot, pb.RepertoireSnapshot, timeout_s=1.0
        )
        if msg is not None:
            try:
                self.state.on_snapshot(msg)
            except Exception as e:  # a malformed reply is counted like a malformed sample
                self.rt.drops.add("malformed")
                log.warning("bad snapshot reply: %s", e)

    def _robot_loop(self) -> None:
        period = 1.0 / self.args.robot_hz
        while not self.rt.stop.is_set():
            t0 = time.monotonic()
            try:
                self.view.refresh_robot()
            except Exception:
                log.exception("robot update failed")
            self.rt.stop.wait(max(0.0, period - (time.monotonic() - t0)))

    def run(self) -> None:
        self._query_snapshot()
        self._robot_thread.start()
        print(f"DASHBOARD READY http://{self.args.host}:{self.server.get_port()}", flush=True)
        period = 1.0 / self.args.refresh_hz
        last_plot = last_stats = last_query = 0.0
        nplots = 0
        while not self.rt.stop.is_set():
            t0 = time.monotonic()
            try:
                if self.state.latest_snapshot() is None and t0 - last_query > 3.0:
                    self._query_snapshot()
                    last_query = t0
                self.view.refresh()
                if t0 - last_plot >= 1.0 / self.args.plot_hz:
                    nplots = self.view.refresh_plots()
                    last_plot = t0
                if t0 - last_stats >= 1.0:
                    self._publish_stats(nplots)
                    last_stats = t0
            except Exception:  # one bad frame must not stop the page
                log.exception("dashboard refresh failed")
            self.rt.stop.wait(max(0.0, period - (time.monotonic() - t0)))

    def _publish_stats(self, nplots: int) -> None:
        v = self.view
        self.rt.publish_stats(
            {
                "viewers": v.viewers,
                "viewers_seen": v.clients_seen,
                "skills_shown": v.repertoire.shown,
                "collectors_alive": len(self.state.alive_ids("collector")),
                "plots": nplots,
                "frame_ms": v.frame_ms,
                "robot_updates": v.robot.updates if v.robot is not None else 0,
            }
        )

    def close(self) -> None:
        self.rt.stop.set()
        if self._robot_thread.is_alive():
            self._robot_thread.join(timeout=2.0)
        self.server.stop()
        self.presence.undeclare()
        for s in self.subs:
            try:
                s.undeclare()
            except Exception:
                pass
        self.rt.close()
