"""The ``ursa`` command (``services/cli.py``): one tyro command line over ``up``,
``eval <command>``, ``export`` and ``secrets``, with the flag spellings of the docs."""

from __future__ import annotations

from pathlib import Path

import pytest
import tyro

from services import cli
from ursa.eval.cli import AdaptArgs, AllArgs, DamageArgs, DiversityArgs, EmbeddingArgs, parse
from ursa.export import ExportArgs


def test_help_lists_every_command(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as e:
        cli.main(["--help"])
    assert e.value.code == 0
    out = capsys.readouterr().out
    for name in ("up", "eval", "export", "secrets"):
        assert name in out
    with pytest.raises(SystemExit) as e:
        cli.main(["eval", "--help"])
    assert e.value.code == 0
    out = capsys.readouterr().out
    for name in ("diversity", "damage", "velocity", "embedding", "curves", "adapt", "all"):
        assert name in out
    with pytest.raises(SystemExit) as e:
        cli.main(["nope"])
    assert e.value.code == 2


def test_documented_spellings_parse() -> None:
    a = parse(["diversity", "r", "--baseline", "b", "--skills", "3", "--steps", "20", "--mode"])
    assert a == DiversityArgs(run="r", baseline="b", skills=3, steps=20, mode=True)
    assert not a.explore and DiversityArgs(run="r").explore  # sampled actions by default
    a = parse(["damage", "u1", "u2", "--baseline", "d1", "d2", "--scenarios", "intact"])
    assert a == DamageArgs(run=("u1", "u2"), baseline=("d1", "d2"), scenarios=("intact",))
    a = parse(["adapt", "r", "--scenarios", "front_upper", "FL_lower+RR_hip", "--no-reference"])
    assert isinstance(a, AdaptArgs) and a.scenarios == ("front_upper", "FL_lower+RR_hip")
    assert a.no_reference and not a.rescue and a.baseline == ()
    a = parse(["embedding", "r", "--method", "pca", "--no-progress", "--threads", "2"])
    assert a == EmbeddingArgs(run="r", method="pca", no_progress=True, threads=2)
    a = parse(["all", "r", "--baseline", "d", "--out", "o", "--seed", "3"])
    assert a == AllArgs(run="r", baseline="d", out=Path("o"), seed=3)
    with pytest.raises(SystemExit):
        parse(["embedding", "r", "--method", "tsne"])


def test_commands_report_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # a run the command does not fit: 1 and a message; export's exclusive options: 2
    assert cli.main(["eval", "curves", str(tmp_path / "missing"), "--no-progress"]) == 1
    assert "ursa eval curves:" in capsys.readouterr().err
    assert cli.main(["eval", "damage", "--no-progress"]) == 1
    assert "at least one run" in capsys.readouterr().err
    assert cli.main(["export", str(tmp_path), "--skill", "1", "--z", "0.4", "-0.1"]) == 2
    assert "not both" in capsys.readouterr().err


def test_export_arguments() -> None:
    a = tyro.cli(ExportArgs, args=["r", "--z", "0.4", "-0.1", "0.2", "--out", "a.onnx"])
    assert a == ExportArgs(run="r", z=(0.4, -0.1, 0.2), out=Path("a.onnx"))
    assert tyro.cli(ExportArgs, args=["r", "--skill", "123"]) == ExportArgs(run="r", skill=123)


def test_up_and_secrets_parse(tmp_path: Path) -> None:
    from services.common.secrets import SecretsArgs
    from services.launcher import UpArgs

    a = tyro.cli(cli.Command, args=["up", "--env", "point", "--preset", "tiny", "--no-dashboard"])
    assert a == UpArgs(env="point", preset="tiny", dashboard=False)
    a = tyro.cli(cli.Command, args=["secrets", "--run.run-id", "r1", "--run.root", str(tmp_path)])
    assert isinstance(a, SecretsArgs) and a.run.run_id == "r1" and a.run.root == tmp_path
    e = tyro.cli(cli.Command, args=["eval", "curves", "r", "--window", "100"])
    assert isinstance(e, cli.EvalCli) and e.command.command == "curves"


def test_up_passes_service_flags_after_double_dash() -> None:
    from services.launcher import UpArgs

    a = cli.parse(["up", "--collectors", "1", "--", "--core.learner.imag-starts", "128"])
    assert a == UpArgs(collectors=1, extra=("--core.learner.imag-starts", "128"))
    with pytest.raises(SystemExit):  # without "--", tyro cannot tell them from up's own
        cli.parse(["up", "--core.learner.imag-starts", "128"])
    e = cli.parse(["eval", "curves", "r"])  # "--" is up's only
    assert isinstance(e, cli.EvalCli)


def test_up_auto_preset() -> None:
    from services.launcher import UpArgs, resolve_preset

    assert resolve_preset("auto", "a1", cuda=False) == ("cpu", [])
    assert resolve_preset("auto", "a1", cuda=True) == ("paper", ["--core.learner.device", "cuda"])
    assert resolve_preset("auto", "point", cuda=True) == ("point", [])
    assert resolve_preset("small", "a1", cuda=True) == ("small", [])
    assert cli.parse(["up"]) == UpArgs(preset="auto")


def test_up_learner_threads() -> None:
    from services.launcher import learner_threads

    # paced collectors (the default) leave the cores to the learner
    assert learner_threads(0, (), {}, cores=2) == 2
    assert learner_threads(0, ("--core.learner.imag-starts", "128"), {}, cores=8) == 8
    # free collectors hold cores: one thread (torch's threads collapse beside them)
    assert learner_threads(0, ("--core.collector.pace", "free"), {}, cores=8) == 1
    assert learner_threads(0, ("--core.collector.pace=free",), {}, cores=8) == 1
    assert learner_threads(0, ("--core.collector.pace", "wait"), {}, cores=4) == 4
    # the environment, then the flag, win
    assert learner_threads(0, (), {"URSA_TORCH_THREADS": "3"}, cores=8) == 3
    assert (
        learner_threads(5, ("--core.collector.pace", "free"), {"URSA_TORCH_THREADS": "3"}, 8) == 5
    )


def test_up_restarts_a_service_that_exits_then_gives_up(tmp_path: Path) -> None:
    """A service that exits is started again after 1, 2, ... backoff units; once it has used
    its restarts the next exit is the stack's stop reason. Real processes: each start appends
    a line to a file and exits with code 3."""
    import os
    import sys
    import time

    from services.launcher import Child, supervise

    log = tmp_path / "starts"
    crash = f"open({str(log)!r}, 'a').write('x\\n'); raise SystemExit(3)"
    steady = "import time; time.sleep(60)"
    env = dict(os.environ)
    bad = Child("bad", [sys.executable, "-c", crash], env, "31")
    good = Child("good", [sys.executable, "-c", steady], env, "32")
    try:
        t = 0.0
        reason = None
        for _ in range(400):
            reason = supervise([good, bad], max_restarts=2, backoff_s=0.05, now=t)
            if reason is not None:
                break
            time.sleep(0.02)
            t += 0.02
        assert reason is not None and reason.startswith("bad exited with code 3 after 2"), reason
        assert bad.restarts == 2 and log.read_text().count("x") == 3  # 1 start + 2 restarts
        assert good.restarts == 0 and good.proc.poll() is None  # the others keep running
        assert t >= 0.05 + 0.1  # the backoff doubled
        # 0 restarts: the first exit is already fatal
        once = Child("once", [sys.executable, "-c", crash], env, "33")
        once.proc.wait(timeout=30)
        assert supervise([once], max_restarts=0, backoff_s=1.0, now=0.0) is not None
    finally:
        good.signal(15)
        good.proc.wait(timeout=10)


def test_up_forgives_a_restart_after_the_service_has_run_long_enough(tmp_path: Path) -> None:
    """A service that crashed once and then ran ``reset_after_s`` has its restart count back
    at 0: with max_restarts=1 a second crash, later, is restarted rather than stopping the
    stack; a second crash inside the window stops it. Real processes; the clock is ``now``."""
    import os
    import sys
    import time
    from collections.abc import Callable

    from services.launcher import Child, supervise

    flag = tmp_path / "crash"
    flag.write_text("1")
    # exits with code 3 while the flag file exists, else runs until killed
    body = (
        f"import os, time\nif os.path.exists({str(flag)!r}): raise SystemExit(3)\ntime.sleep(60)\n"
    )
    env = dict(os.environ)

    def run_until(
        c: Child, t: float, cond: Callable[[Child], bool], limit: int = 500
    ) -> tuple[float, str | None]:
        reason = None
        for _ in range(limit):
            reason = supervise([c], max_restarts=1, backoff_s=0.01, now=t, reset_after_s=5.0)
            if reason is not None or cond(c):
                break
            time.sleep(0.02)
            t += 0.02
        return t, reason

    for late in (True, False):
        flag.write_text("1")
        c = Child("svc", [sys.executable, "-c", body], env, "31")
        try:
            c.proc.wait(timeout=30)
            flag.unlink()  # the restart runs
            t, reason = run_until(c, 0.0, lambda s: s.restarts == 1 and s.proc.poll() is None)
            assert reason is None and c.restarts == 1
            t, _ = run_until(c, t, lambda s: s.up_since is not None)
            t += 6.0 if late else 1.0
            supervise([c], max_restarts=1, backoff_s=0.01, now=t, reset_after_s=5.0)
            assert c.restarts == (0 if late else 1)
            flag.write_text("1")  # its next start crashes again
            c.signal(9)
            c.proc.wait(timeout=10)
            t, reason = run_until(c, t, lambda s: s.restarts >= 1 and s.restart_at is None)
            if late:
                assert reason is None and c.restarts == 1  # restarted, not given up on
            else:
                assert reason is not None and "after 1 restarts" in reason
        finally:
            if c.proc.poll() is None:
                c.signal(9)
                c.proc.wait(timeout=10)
