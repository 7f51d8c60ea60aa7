"""The live dashboard: bounded history, skill picking, the page drawn from fed state, and (slow)
a real stack opened in headless chromium."""

from __future__ import annotations

import re
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import viser

from services.common.history import DecimatingSeries, align
from services.common.live import LiveState, SnapshotView
from services.dashboard.panels.plots import plot_layout
from services.dashboard.panels.repertoire import (
    Frame,
    color_options,
    colormap,
    parse_floats,
    pick_on_ray,
    to3,
)
from services.dashboard.panels.robot import STANDING, robot_pose, xyzw_to_wxyz
from services.dashboard.service import DashboardArgs, DashboardView
from services.stack import ROOT, StatsWatcher, free_port, running_stack, wait_for
from tests.services._stack import find_chromium, headless_chromium, snapshot_msg, stats_msg

ARTIFACTS = ROOT / "test-artifacts"


# ---- pure pieces -----------------------------------------------------------------------------
def test_decimating_series_stays_bounded_and_covers_the_whole_run() -> None:
    s = DecimatingSeries(capacity=64, min_dt=0.0)
    t = np.arange(10_000, dtype=float)  # "10 000 s at 1 Hz"
    for ti in t:
        s.add(ti, 2.0 * ti)
    ts, vs = s.arrays()
    assert len(s) <= 64 and s.compactions > 0
    assert ts[0] < 500 and ts[-1] > 9_500  # the beginning is merged, not dropped
    np.testing.assert_allclose(vs, 2.0 * ts)  # pair means of a line stay on the line
    assert np.all(np.diff(ts) > 0)


def test_decimating_series_rate_limits_and_skips_non_finite() -> None:
    s = DecimatingSeries(capacity=16, min_dt=1.0)
    for ti, v in [(0.0, 1.0), (0.5, 2.0), (1.2, 3.0), (1.3, float("nan")), (0.2, 9.0)]:
        s.add(ti, v)
    ts, vs = s.arrays()
    np.testing.assert_allclose(ts, [0.25, 1.2])  # samples within min_dt are averaged
    np.testing.assert_allclose(vs, [1.5, 3.0])


def test_align_resamples_onto_a_shared_grid_without_gaps() -> None:
    a = (np.arange(0.0, 100.0), np.ones(100))
    b = (np.arange(50.0, 60.0), np.arange(10.0))
    x, (ya, yb) = align([a, b], max_points=20)
    assert len(x) == 20 and np.all(np.diff(x) > 0)
    assert np.all(np.isfinite(ya)) and np.all(np.isfinite(yb))
    np.testing.assert_allclose(ya, 1.0)
    assert yb[0] == 0.0 and yb[-1] == 9.0  # held constant outside its own span
    x1, ys1 = align([(np.array([5.0]), np.array([3.0]))])
    assert x1.tolist() == [5.0] and ys1[0].tolist() == [3.0]
    assert align([])[0].size == 0


def test_frame_fits_skills_in_the_cube_and_pads_low_dimensions() -> None:
    z = np.array([[0.0, 0.0], [2.0, 1.0], [4.0, -1.0]])
    assert to3(z).shape == (3, 3) and np.all(to3(z)[:, 2] == 0)
    assert to3(np.zeros((2, 5))).shape == (2, 3)
    f = Frame.fit(z, origin=(0.0, 2.5, 1.2), half_size=1.0)
    w = f.world(z)
    # x spans 4 (the largest extent) -> [-1, 1]; y spans 2 -> [2.0, 3.0] around y=2.5
    assert np.allclose(w.min(axis=0)[:2], [-1.0, 2.0]) and np.allclose(w.max(axis=0)[:2], [1, 3])
    assert np.allclose(w[:, 2], 1.2)  # the padded coordinate sits in the cube's middle plane
    single = Frame.fit(np.ones((1, 3)), origin=(0.0, 0.0, 0.0), half_size=1.0)
    assert np.allclose(single.world(np.ones(3)), 0.0)


def test_pick_on_ray_selects_the_point_under_the_click() -> None:
    pts = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 0.0, -2.0], [0.0, 1.0, 0.0]])
    down = np.array([0.0, 0.0, -1.0])
    assert pick_on_ray(pts, np.array([1.01, 0.0, 5.0]), down, 0.05) == 1  # nearest the camera
    assert pick_on_ray(pts, np.array([0.0, 0.98, 5.0]), down * 3.0, 0.05) == 3
    assert pick_on_ray(pts, np.array([0.5, 0.5, 5.0]), down, 0.05) is None
    assert pick_on_ray(pts, np.array([0.0, 0.0, -5.0]), down, 0.05) is None  # behind the camera
    assert pick_on_ray(np.zeros((0, 3)), np.zeros(3), down, 1.0) is None


def test_colours_and_parsing() -> None:
    c = colormap(np.array([0.0, 1.0, np.nan, 2.0]))
    assert c.shape == (4, 3) and c.dtype == np.uint8
    assert not np.array_equal(c[0], c[3])
    assert color_options(2) == ("age", "nn distance", "z[0]", "z[1]")
    np.testing.assert_allclose(parse_floats("0.1, -2;3e-1"), [0.1, -2.0, 0.3])
    for bad in ("", "a,b", "1,nan"):
        with pytest.raises(ValueError):
            parse_floats(bad)


def test_plot_layout_groups_keys_generically() -> None:
    keys = [
        ("collector", "c0", "violation_rate"),
        ("collector", "c1", "violation_rate"),
        ("collector", "c0", "uptime_s"),
        ("learner", "main", "loss/world_model"),
        ("learner", "main", "loss/actor"),
        ("learner", "main", "lambda1_mean"),
        ("learner", "main", "lambda2_mean"),
        ("learner", "main", "replay_steps"),
        ("repertoire", "main", "delta"),
    ]
    layout = plot_layout(keys)
    assert [lbl for lbl, _ in layout[("collector", "violation_rate")]] == ["c0", "c1"]
    assert ("collector", "uptime_s") not in layout
    assert {lbl for lbl, _ in layout[("learner", "loss")]} == {"world_model", "actor"}
    assert len(layout[("learner", "λ1 / λ2 mean")]) == 2
    assert ("learner", "replay_steps") in layout and ("repertoire", "δ") in layout
    assert next(iter(layout))[0] == "collector"  # collectors first
    assert len(plot_layout(keys, max_plots=2)) == 2


def test_robot_pose_from_collector_stats() -> None:
    assert xyzw_to_wxyz(np.array([0.0, 0.0, 0.0, 2.0])) == (1.0, 0.0, 0.0, 0.0)
    w, _x, _y, z = xyzw_to_wxyz(np.array([0.0, 0.0, np.sin(0.25), np.cos(0.25)]))
    assert np.isclose(w, np.cos(0.25)) and np.isclose(z, np.sin(0.25))
    assert xyzw_to_wxyz(np.zeros(4)) == (1.0, 0.0, 0.0, 0.0)
    q, pos, _ = robot_pose(None, follow=True)
    assert q is None and pos[2] > 0
    e = LiveState("test")
    e.on_stats(
        stats_msg(
            "collector",
            "c0",
            {"steps": 1},
            arrays={
                "joint_angles": STANDING + 0.1,
                "base_position": np.array([3.0, 4.0, 0.25]),
                "base_orientation": np.array([0.0, 0.0, 0.0, 1.0]),
            },
        )
    )
    st = e.stats_of("collector", "c0")
    q, pos, wxyz = robot_pose(st, follow=True)
    assert q is not None and np.allclose(q, STANDING + 0.1)
    assert pos == (0.0, 0.0, 0.25) and wxyz == (1.0, 0.0, 0.0, 0.0)
    assert robot_pose(st, follow=False)[1] == (3.0, 4.0, 0.25)
    e.on_stats(stats_msg("collector", "c0", {"steps": 2}, arrays={"joint_angles": np.ones(5)}))
    assert robot_pose(e.stats_of("collector", "c0"), follow=True)[0] is None


def test_live_state_keeps_the_newest_snapshot_and_bounded_history() -> None:
    st = LiveState("test", history_capacity=32)
    st.on_snapshot(snapshot_msg(10, version=5))
    late = snapshot_msg(20, version=4)
    late.header.stamp -= 1.0  # an older snapshot delivered late: ignored
    st.on_snapshot(late)
    snap = st.latest_snapshot()
    assert snap is not None and snap.size == 10
    restarted = snapshot_msg(30, version=1)
    restarted.header.stamp = time.time() + 10  # a restarted repertoire counts from 1 again
    st.on_snapshot(restarted)
    assert st.latest_snapshot().size == 30  # type: ignore[union-attr]
    t0 = time.time()
    for i in range(5000):
        st.on_stats(stats_msg("collector", "c0", {"violation_rate": i % 7}, stamp=t0 + i))
    t, _v = st.series()[("collector", "c0", "violation_rate")]
    assert len(t) <= 32 and t[-1] - t[0] > 4000


def test_snapshot_view_lookups_and_metric() -> None:
    view = SnapshotView.from_msg(snapshot_msg(40, d=3, id0=100))
    assert view.dim == 3 and view.index_of(100) == 0 and view.index_of(99) is None
    assert view.index_of(139) == 39 and view.index_of(140) is None
    rows, d = view.nearest(view.skills[7], k=3)
    assert rows[0] == 7 and d[0] == 0 and np.all(np.diff(d) >= 0)
    # Σ = 0.05·I: the Mahalanobis distance is the Euclidean one / sqrt(0.05)
    a, b = view.skills[0], view.skills[1]
    assert np.isclose(view.distance(a, b), np.linalg.norm(a - b) / np.sqrt(0.05))
    assert list(view.ids[view.page(38, 10)]) == [138, 139]


# ---- the page, fed without a bus ----------------------------------------------------------
@pytest.fixture()
def view() -> Iterator[tuple[DashboardView, LiveState, dict[str, float]]]:
    alive: dict[str, float] = {}
    state = LiveState("test", alive=lambda: alive, history_capacity=128)
    server = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    try:
        yield DashboardView(server, state, DashboardArgs(robot=True)), state, alive
    finally:
        server.stop()


def test_page_shows_no_data_yet_then_the_run(
    view: tuple[DashboardView, LiveState, dict[str, float]],
) -> None:
    v, state, alive = view
    v.refresh()
    assert "no data yet" in v.summary.content and "none yet" in v.summary.content
    assert v.refresh_plots() == 0 and v.plots.empty.visible
    assert "default pose" in v.robot.note.content  # type: ignore[union-attr]

    state.on_snapshot(snapshot_msg(50, d=2))
    now = time.time()
    for cid in ("c0", "c1"):
        alive[f"ursa/test/alive/collector/{cid}"] = now
        for i in range(10):
            state.on_stats(
                stats_msg(
                    "collector",
                    cid,
                    {
                        "steps": 100 * i,
                        "steps_per_s": 50.0,
                        "violation_rate": 0.1,
                        "rescues": 2,
                        "policy_version": 3,
                    },
                    labels={"damage": "front_hip", "env": "point", "skill_source": "kde"},
                    arrays={"skill": np.array([0.25, -0.5], np.float32)},
                    stamp=now - 10 + i,
                )
            )
    state.on_stats(
        stats_msg("learner", "main", {"loss/world_model": 1.0, "lambda1_mean": 0.2}, stamp=now)
    )
    v.refresh()
    assert "50 skills shown" in v.summary.content and "c0, c1" in v.summary.content
    assert "front_hip" in v.collectors_md.content and "(0.25, -0.50)" in v.collectors_md.content
    cloud = v.repertoire.cloud
    assert cloud.visible and cloud.points.shape == (50, 3)
    assert np.allclose(cloud.points[:, 2], v.repertoire.origin[2], atol=1e-2)  # D=2: padded
    assert set(v.repertoire._markers) == {"c0", "c1"}
    assert v.refresh_plots() >= 4
    assert ("collector", "violation_rate") in v.plots.plots
    labels, handle = v.plots.plots[("collector", "violation_rate")]
    assert labels == ("c0", "c1") and len(handle.data) == 3

    # the A1 mirrors the selected collector, and says why it is in its default pose
    assert v.refresh_robot()
    assert "reports no joint angles" in v.robot.note.content  # type: ignore[union-attr]
    assert not v.refresh_robot()  # nothing new: no update sent

    # a click whose ray passes through a displayed skill selects it
    target = v.repertoire.world[3]
    sid = v.repertoire.on_ray(target + np.array([0.0, 0.0, 4.0]), np.array([0.0, 0.0, -1.0]))
    snap = state.latest_snapshot()
    assert snap is not None and sid is not None
    assert np.allclose(v.repertoire.world[snap.index_of(sid)][:2], target[:2], atol=0.1)
    info = v.repertoire.info.content
    assert f"skill {sid}" in info and "c0 (" in info and "c1 (" in info
    assert v.repertoire.selected_marker.visible
    assert v.repertoire.select_nearest(snap.skills[7]) == int(snap.ids[7])
    assert v.repertoire.select_nearest(np.zeros(3)) is None  # wrong dimension: a note
    assert "needs 2 coordinates" in v.repertoire.info.content

    # a new snapshot without the selected skill keeps the page consistent
    state.on_snapshot(snapshot_msg(5, d=2, version=2, id0=1000))
    v.refresh()
    assert "5 skills shown" in v.summary.content
    assert "is not in the repertoire" in v.repertoire.info.content
    assert not v.repertoire.selected_marker.visible

    # a collector that leaves loses its marker and its row
    alive.pop("ursa/test/alive/collector/c1")
    v.refresh()
    assert set(v.repertoire._markers) == {"c0"} and "c1" not in v.summary.content


def test_colour_choice_follows_the_skill_dimension(
    view: tuple[DashboardView, LiveState, dict[str, float]],
) -> None:
    v, state, _ = view
    state.on_snapshot(snapshot_msg(30, d=4))
    v.refresh()
    assert v.repertoire.color_by.options == color_options(4)
    before = v.repertoire.cloud.colors.copy()
    v.repertoire.color_by.value = "z[3]"  # type: ignore[misc]
    v.refresh()
    assert not np.array_equal(before, v.repertoire.cloud.colors)


# ---- a real stack in a real browser ----------------------------------------------------------
@pytest.mark.slow
def test_dashboard_in_headless_chromium(tmp_path: Path) -> None:
    """Debian's chromium, driven by Playwright: the page shows the live run, its 3-D view and
    plots render, and a second tab counts as a second viewer."""
    chromium = find_chromium()
    if chromium is None:  # fails under URSA_STRICT=1 (tests/strict.py), as in CI
        pytest.skip("chromium not found (make system-deps, or apt-get install chromium)")
    port = free_port()
    url = f"http://127.0.0.1:{port}/"
    with running_stack(tmp_path) as st:
        st.start_router()
        st.start("repertoire", "services.repertoire")
        st.start_collectors(2, "--realtime-factor", "5")
        dash = st.start("dashboard", "services.dashboard", "--port", str(port))
        session = st.session()
        watch = StatsWatcher(session, st.topics)
        try:
            wait_for(lambda: "DASHBOARD READY" in dash.log(), 60, "the dashboard to start")

            def dash_stat(key: str) -> float:
                s = watch.get("dashboard", "main")
                return float(s.scalars[key]) if s is not None and key in s.scalars else -1.0

            wait_for(
                lambda: dash_stat("skills_shown") > 0 and dash_stat("collectors_alive") == 2,
                90,
                "skills and both collectors on the dashboard",
                0.5,
            )
            with headless_chromium(chromium) as browser:
                ctx = browser.new_context(viewport={"width": 1600, "height": 1000})
                page = ctx.new_page()
                page.goto(url)

                def page_ready() -> str | None:
                    text = page.inner_text("body")
                    m = re.search(r"(\d+) skills shown", text)
                    ok = m and int(m.group(1)) > 0 and "c0" in text and "c1" in text
                    return text if ok else None

                text = wait_for(page_ready, 90, "the page to show skills and collectors", 0.5)
                wait_for(lambda: dash_stat("viewers") >= 1, 30, "the server to see the viewer")
                assert re.search(r"collectors alive \(2\): c0, c1", text)
                # viser keeps its canvas at 5 % opacity until its environment map is decoded
                # (slow in software WebGL), then fades it in
                page.wait_for_function(
                    "document.querySelectorAll('canvas').length > 0 && Math.min(...Array.from("
                    "document.querySelectorAll('canvas')).map(c => parseFloat(c.style.opacity "
                    "|| '1'))) >= 1.0",
                    timeout=120_000,
                    polling=500,
                )
                ARTIFACTS.mkdir(parents=True, exist_ok=True)
                # the fade-in has ended: the shot shows the drawn scene, not a blank canvas
                shot = page.screenshot(path=ARTIFACTS / "dashboard.png")
                assert len(shot) > 10_000
                # the plots tab renders its uPlot charts (a real click on the tab)
                page.get_by_role("tab", name="Plots").click()
                page.wait_for_selector(".uplot", timeout=30_000)
                page.screenshot(path=ARTIFACTS / "dashboard-plots.png")
                # a second tab sees the same page, and the server counts both viewers
                second = ctx.new_page()
                second.goto(url)
                second.get_by_text(re.compile(r"\d+ skills shown")).first.wait_for(timeout=60_000)
                wait_for(lambda: dash_stat("viewers") >= 2, 30, "the server to see two viewers")
                ctx.close()
            assert "viewer connected" in dash.log()
            assert dash.alive()
        except BaseException:
            print(st.logs())
            raise
        finally:
            watch.close()
            session.close()
