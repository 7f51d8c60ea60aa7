"""The dashboard's adaptation panel: a job's tried skills drawn on the skill cloud where the
repertoire's skills are, coloured by return; the chosen skill and the predicted best marked;
the markdown and the chart follow the job; newest job wins; and the panel is fed from the bus."""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import viser

from proto import codec
from proto import ursa_pb2 as pb
from services.common.config import RunConfig
from services.common.live import LiveState
from services.dashboard.panels.adapt import JobView, job_markdown
from services.dashboard.panels.repertoire import colormap
from services.dashboard.service import Dashboard, DashboardArgs, DashboardView
from services.stack import free_port, running_stack, wait_for
from tests.services._stack import snapshot_msg

RUN = "test"


def _job(
    n_trials: int, job_id: str = "00000000000000ab", created: float = 100.0, state: str = "adapting"
) -> pb.AdaptJob:
    snap = snapshot_msg(30, d=2, run_id=RUN)
    skills = np.asarray(codec.from_array(snap.skills))[:6]
    ids = np.arange(6, dtype=np.int64)
    job = pb.AdaptJob(
        header=codec.header(RUN, "evaluator/eval"),
        job_id=job_id,
        evaluator_id="eval",
        state=state,
        request=pb.AdaptRequest(damage="front_hip", frozen_joints=[4], budget=10),
        map_skills=codec.to_array(skills.astype(np.float32)),
        map_ids=codec.to_array(ids),
        map_returns=codec.to_array(np.linspace(1.0, 6.0, 6)),
        mapped=6,
        chosen_skill_id=-1,
        predicted_best_id=-1,
        created=created,
        updated=created + n_trials,
    )
    rets = [2.0, 5.0, 3.0, 4.0][:n_trials]
    for k, r in enumerate(rets):
        row = 5 - k
        job.trials.append(
            pb.AdaptJob.Trial(
                row=row,
                skill_id=row,
                skill=codec.to_array(skills[row].astype(np.float32)),
                ret=r,
                predicted=6.0 - k,
                predicted_best_id=1,
                predicted_best_mean=4.5,
            )
        )
    if rets:
        best = int(np.argmax(rets))
        job.chosen_skill_id, job.chosen_return = 5 - best, rets[best]
        job.predicted_best_id, job.predicted_best_mean = 1, 4.5
    return job


@pytest.fixture()
def view() -> Iterator[tuple[DashboardView, LiveState]]:
    state = LiveState(RUN, alive=lambda: {}, history_capacity=64)
    server = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    try:
        yield DashboardView(server, state, DashboardArgs(robot=False)), state
    finally:
        server.stop()


def test_job_view_and_markdown() -> None:
    assert "no adaptation yet" in job_markdown(None)
    jv = JobView.from_msg(_job(3))
    assert jv.tried.shape == (3, 2) and list(jv.tried_ids) == [5, 4, 3]
    np.testing.assert_array_equal(jv.best_so_far, [2.0, 5.0, 5.0])
    md = job_markdown(jv)
    for part in ("00000000000000ab", "adapting", "front_hip", "[4]", "6/6", "3/10", "skill 4"):
        assert part in md, (part, md)
    assert "predicted best:** skill 1" in md
    done = JobView.from_msg(_job(4, state="done"))
    assert "4/10" in job_markdown(done)


def test_panel_draws_the_tried_skills_on_the_skill_cloud(
    view: tuple[DashboardView, LiveState],
) -> None:
    v, state = view
    v.refresh()
    assert "no adaptation yet" in v.adapt.info.content
    state.on_snapshot(snapshot_msg(30, d=2, run_id=RUN))
    v.adapt.on_job(_job(0))
    v.refresh()
    assert v.adapt.job is not None and not v.adapt.tried_cloud.visible
    assert v.adapt.chart is None and not v.adapt.best_marker.visible
    v.adapt.on_job(_job(3))
    v.refresh()
    job = v.adapt.job
    assert job is not None and len(job.returns) == 3
    frame = v.repertoire.frame
    # the tried skills sit on the repertoire's own points (same skills, same frame)
    np.testing.assert_allclose(v.adapt.world, frame.world(job.tried))
    np.testing.assert_allclose(v.adapt.world, v.repertoire.world[[5, 4, 3]], rtol=1e-5, atol=1e-5)
    # (viser keeps the points as float16)
    np.testing.assert_allclose(v.adapt.tried_cloud.points, v.adapt.world, atol=2e-3)
    np.testing.assert_array_equal(v.adapt.tried_cloud.colors, colormap(job.returns))
    assert v.adapt.tried_cloud.visible and v.adapt.chosen_marker.visible
    np.testing.assert_allclose(v.adapt.chosen_marker.position, frame.world(job.tried[1]))
    np.testing.assert_allclose(v.adapt.best_marker.position, frame.world(job.map_skills[1]))
    assert v.adapt.chart is not None
    x, ret, best, pred = (np.asarray(a) for a in v.adapt.chart.data)
    np.testing.assert_array_equal(x, [1, 2, 3])
    np.testing.assert_array_equal(ret, [2.0, 5.0, 3.0])
    np.testing.assert_array_equal(best, [2.0, 5.0, 5.0])
    np.testing.assert_array_equal(pred, [6.0, 5.0, 4.0])
    assert "3/10" in v.adapt.info.content
    # an older state of the same job, or an older job, does not replace it
    v.adapt.on_job(_job(2))
    v.adapt.on_job(_job(4, job_id="00000000000000ac", created=50.0))
    v.refresh()
    assert v.adapt.job.job_id == "00000000000000ab" and len(v.adapt.job.returns) == 3
    # a newer job does
    v.adapt.on_job(_job(1, job_id="00000000000000ad", created=200.0))
    v.refresh()
    assert v.adapt.job.job_id == "00000000000000ad" and "1/10" in v.adapt.info.content
    assert not v.adapt.update()  # nothing new: nothing redrawn


def test_panel_is_fed_from_the_bus(tmp_path: Path) -> None:
    with running_stack(tmp_path, run_id=RUN) as st:
        st.start_router()
        dash = Dashboard(
            DashboardArgs(
                bus=st.bus, run=RunConfig(run_id=RUN, root=st.runs), port=free_port(), robot=False
            )
        )
        peer = st.session()
        try:
            job = _job(2)
            job.updated = time.time()

            def arrived() -> Any:
                peer.put(st.topics.adapt_state("eval"), codec.encode(job))
                return dash.view.adapt.update()

            wait_for(arrived, 20, "the job to reach the dashboard", every=0.5)
            assert dash.view.adapt.job is not None
            assert list(dash.view.adapt.job.returns) == [2.0, 5.0]
        finally:
            peer.close()
            dash.close()
