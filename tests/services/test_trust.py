"""The bus trusts nobody: corrupted-but-parseable messages on every key of a running stack are
all counted and none is accepted; with authentication on, the router refuses clients without
credentials and publications outside a role's keys."""

from __future__ import annotations

import json
import random
import time
from pathlib import Path

import httpx
import numpy as np
import pytest
import zenoh
from google.protobuf.message import Message

from proto import codec
from proto import ursa_pb2 as pb
from services.common import secrets
from services.common.bus import client_config
from services.common.config import BusConfig
from services.stack import StatsWatcher, free_port, running_stack, wait_for, wait_port

pytestmark = pytest.mark.slow

FLIPS = 4
"""Byte-corrupted copies (still parseable protobuf, stale checksum) per key."""


def _flipped(cls: type[Message], payload: bytes, rng: random.Random, n: int) -> list[bytes]:
    """n copies of a framed payload with a few body bytes changed that still parse as cls."""
    f = codec.read_frame(payload)
    prefix = payload[: len(payload) - len(f.body)]
    out: list[bytes] = []
    while len(out) < n:
        body = bytearray(f.body)
        for _ in range(3):
            i = rng.randrange(len(body) // 2, len(body))
            body[i] ^= 1 << rng.randrange(8)
        try:
            cls.FromString(bytes(body))
        except Exception:
            continue
        out.append(prefix + bytes(body))
    return out


def _reframed(msg: Message) -> bytes:
    """An adversary's message with a *valid* checksum (anyone can compute one without a key)."""
    return codec.encode(msg)


def _scale(a: pb.Array, factor: float, nan: bool = False) -> pb.Array:
    x = np.array(codec.from_array(a), copy=True)
    # |x|+1 scaled: out of the declared box whatever the first value was (x·f + f was not: an
    # action of -1 scaled by 5 gave 0, a legitimate value the learner then accepted)
    x.flat[0] = np.nan if nan else (abs(float(x.flat[0])) + 1.0) * factor
    return codec.to_array(x)


def test_corrupted_messages_on_every_key_are_counted_and_never_accepted(tmp_path: Path) -> None:
    api_port = free_port()
    with running_stack(tmp_path) as st:
        st.start_router()
        st.start("repertoire", "services.repertoire")
        st.start("learner", "services.learner")
        st.start("c0", "services.collector", "--collector-id", "c0", "--seed", "0")
        st.start("eval", "services.evaluator", "--collector-id", "eval")
        st.start("api", "services.api", "--port", str(api_port))
        t = st.topics
        session = st.session()
        watcher = StatsWatcher(session, t)
        captured: dict[str, bytes] = {}

        def grab(sample: zenoh.Sample) -> None:
            captured[str(sample.key_expr)] = sample.payload.to_bytes()  # the latest

        sub = session.declare_subscriber(f"{t.root}/**", grab)

        def ready() -> bool:
            rep = watcher.get("repertoire", "main")
            return bool(
                rep
                and rep.scalars["size"] >= 20
                and watcher.get("learner", "main")
                and watcher.get("collector", "c0")
                and watcher.get("evaluator", "eval")
                and watcher.get("api", "main")
                and all(
                    k in captured
                    for k in (
                        t.transitions("c0"),
                        t.features("c0"),
                        t.snapshot,
                        t.collector_stats("c0"),
                    )
                )
                and len(
                    codec.from_array(
                        codec.decode(pb.RepertoireSnapshot, captured[t.snapshot]).skills
                    )
                )
                >= 2
            )

        wait_for(ready, 180, "the stack to run and publish on every key", every=0.5)
        sub.undeclare()

        def scal(service: str, sid: str, name: str) -> float:
            s = watcher.get(service, sid)
            return float(s.scalars.get(name, 0.0)) if s else 0.0

        consumers = [
            ("repertoire", "main"),
            ("learner", "main"),
            ("collector", "c0"),
            ("evaluator", "eval"),
            ("api", "main"),
        ]
        before = {
            c: (scal(*c, "dropped/integrity"), scal(*c, "dropped/out_of_bounds")) for c in consumers
        }
        policy_before = scal("collector", "c0", "policy_version")

        rng = random.Random(0)
        sent_int: dict[tuple[str, str], int] = {c: 0 for c in consumers}
        sent_oob: dict[tuple[str, str], int] = {c: 0 for c in consumers}

        def put(key: str, payloads: list[bytes], to: list[tuple[str, str]], oob: bool) -> None:
            # blocking, as the services' reliable streams publish: a put's default congestion
            # control drops under load, and on a loaded machine (CI) a burst of weight-sized
            # puts was dropped before it reached the collector and the evaluator
            for p in payloads:
                session.put(key, p, congestion_control=zenoh.CongestionControl.BLOCK)
                time.sleep(0.05)
            for c in to:
                (sent_oob if oob else sent_int)[c] += len(payloads)

        rep_, lrn, col, ev, api = consumers
        # transitions -> learner
        chunk = codec.decode(pb.TransitionChunk, captured[t.transitions("c0")])
        put(
            t.transitions("c0"),
            _flipped(pb.TransitionChunk, captured[t.transitions("c0")], rng, FLIPS),
            [lrn],
            oob=False,
        )
        bad_chunks = []
        for field, factor in (
            ("obs", 1e30),
            ("action", 5.0),
            ("features", 1e27),
            ("skill", 1e30),
            ("reward", np.inf),
        ):
            m = pb.TransitionChunk()
            m.CopyFrom(chunk)
            m.header.sender = "collector/evil"
            m.collector_id = "evil"
            getattr(m, field).CopyFrom(_scale(getattr(chunk, field), float(factor)))
            bad_chunks.append(_reframed(m))
        put(t.transitions("evil"), bad_chunks, [lrn], oob=True)
        # features -> repertoire
        feats = codec.decode(pb.SafeFeatures, captured[t.features("c0")])
        put(
            t.features("c0"),
            _flipped(pb.SafeFeatures, captured[t.features("c0")], rng, FLIPS),
            [rep_],
            oob=False,
        )
        bad_feats = []
        for factor, nan in ((4e30, False), (3.0, False), (1.0, True)):
            m = pb.SafeFeatures()
            m.CopyFrom(feats)
            m.features.CopyFrom(_scale(feats.features, factor, nan))
            bad_feats.append(_reframed(m))
        put(t.features("evil"), bad_feats, [rep_], oob=True)
        # snapshots -> learner, evaluator, api
        snap = codec.decode(pb.RepertoireSnapshot, captured[t.snapshot])
        put(
            t.snapshot,
            _flipped(pb.RepertoireSnapshot, captured[t.snapshot], rng, FLIPS),
            [lrn, ev, api],
            oob=False,
        )
        bad_snaps = []
        for field, factor, nan in (
            ("skills", 4e30, False),
            ("skills", 1.0, True),
            ("cov", -1e3, False),
        ):
            m = pb.RepertoireSnapshot()
            m.CopyFrom(snap)
            m.version = 10**9
            getattr(m, field).CopyFrom(_scale(getattr(snap, field), factor, nan))
            bad_snaps.append(_reframed(m))
        put(t.snapshot, bad_snaps, [lrn, ev, api], oob=True)
        # weights -> collector, evaluator (NaN and huge weights; the real ones as template)
        from safetensors.numpy import save

        good_w = captured.get(t.weights)
        tensors = {"w": np.ones((4, 4), np.float32)}
        w_nan = save({"w": np.full((4, 4), np.nan, np.float32)})
        w_huge = save({"w": np.full((4, 4), 1e30, np.float32)})
        bad_w = [
            _reframed(
                pb.PolicyWeights(
                    header=codec.header(st.run_id, "learner/main"),
                    version=10**6,
                    safetensors=b,
                    config_hash="x",
                )
            )
            for b in (w_nan, w_huge, b"\x00not safetensors")
        ]
        template = good_w or codec.encode(
            pb.PolicyWeights(
                header=codec.header(st.run_id, "learner/main"),
                version=1,
                safetensors=save(tensors),
                config_hash="x",
            )
        )
        put(t.weights, _flipped(pb.PolicyWeights, template, rng, FLIPS), [col, ev], oob=False)
        put(t.weights, bad_w, [col, ev], oob=True)
        # stats -> api (a made-up service name, absurd skills, non-finite scalars)
        cstats = codec.decode(pb.Stats, captured[t.collector_stats("c0")])
        put(
            t.collector_stats("c0"),
            _flipped(pb.Stats, captured[t.collector_stats("c0")], rng, FLIPS),
            [api],
            oob=False,
        )
        bad_stats = []
        m = pb.Stats()
        m.CopyFrom(cstats)
        m.service, m.id, m.header.sender = "c-llector", "c9", "c-llector/c9"
        bad_stats.append((t.collector_stats("c9"), _reframed(m)))
        m = pb.Stats()
        m.CopyFrom(cstats)
        m.arrays["skill"].CopyFrom(codec.to_array(np.full(2, 1e27, np.float32)))
        bad_stats.append((t.collector_stats("c0"), _reframed(m)))
        m = pb.Stats()
        m.CopyFrom(cstats)
        m.scalars["steps"] = float("inf")
        bad_stats.append((t.collector_stats("c0"), _reframed(m)))
        m = pb.Stats()
        m.CopyFrom(cstats)  # collector stats claiming another collector's id
        bad_stats.append((t.collector_stats("c1"), _reframed(m)))
        for key, p in bad_stats:
            put(key, [p], [api], oob=True)
        # queries: corrupted sample requests (repertoire) and out-of-bounds evaluations
        req = codec.encode(pb.SkillRequest(header=codec.header(st.run_id, "x/0"), n=2))
        for p in _flipped(pb.SkillRequest, req, rng, FLIPS):
            replies = list(session.get(t.sample, payload=p, timeout=30.0))
            assert all(r.ok is None for r in replies)
        sent_int[rep_] += FLIPS
        for skill in ([1e27, 0.0], [np.nan, 0.0], [3.5, 0.0]):
            ereq = pb.EvaluateRequest(
                header=codec.header(st.run_id, "api/main"),
                skill=codec.to_array(np.asarray(skill, np.float32)),
                steps=10,
            )
            replies = list(session.get(t.evaluate, payload=_reframed(ereq), timeout=30.0))
            back = [
                codec.decode(pb.EvaluateReply, r.ok.payload.to_bytes())
                for r in replies
                if r.ok is not None
            ]
            assert back and all(b.error for b in back), (skill, back, st.logs())
        sent_oob[ev] += 3

        def counted() -> bool:
            return all(
                scal(*c, "dropped/integrity") - before[c][0] >= sent_int[c]
                and scal(*c, "dropped/out_of_bounds") - before[c][1] >= sent_oob[c]
                for c in consumers
            )

        try:
            wait_for(counted, 180, "every corrupted message to be counted")
        except TimeoutError:
            got = {
                c: (
                    scal(*c, "dropped/integrity") - before[c][0],
                    scal(*c, "dropped/out_of_bounds") - before[c][1],
                )
                for c in consumers
            }
            raise AssertionError(
                f"sent {sent_int} / {sent_oob}, counted {got}\n{st.logs()}"
            ) from None
        time.sleep(2.0)  # let later stats show anything that slipped through
        got = {
            c: (
                scal(*c, "dropped/integrity") - before[c][0],
                scal(*c, "dropped/out_of_bounds") - before[c][1],
            )
            for c in consumers
        }
        for c in consumers:  # exactly those, nothing legitimate dropped
            assert got[c] == (sent_int[c], sent_oob[c]), (c, sent_int, sent_oob, got, st.logs())
            s = watcher.get(*c)
            assert s is not None
            by_key = json.loads(s.labels["dropped_by_key"])
            assert sum(by_key.values()) >= sent_int[c] + sent_oob[c], (c, by_key)

        # nothing was accepted: the learner never saw "evil", the collector kept its weights,
        # the repertoire's archive stays inside the arena, the API lists no made-up service
        assert "chunks/evil" not in watcher.get("learner", "main").scalars  # type: ignore[union-attr]
        assert scal("collector", "c0", "policy_version") < 10**6 > policy_before
        assert scal("repertoire", "main", "out_of_bounds") == 0  # none reached the core
        fresh = codec.decode(
            pb.RepertoireSnapshot,
            next(iter(session.get(t.snapshot, timeout=30.0))).ok.payload.to_bytes(),  # type: ignore[union-attr]
        )
        skills = codec.from_array(fresh.skills)
        assert len(skills) >= 20 and np.isfinite(skills).all() and np.abs(skills).max() <= 1.0
        stats = httpx.get(f"http://127.0.0.1:{api_port}/stats", timeout=30).json()
        names = {(e["service"], e["id"]) for e in stats["services"]}
        assert ("collector", "c0") in names and ("c-llector", "c9") not in names
        assert not any(i == "c9" or i == "c1" for _, i in names), names
        for e in stats["services"]:
            values = [v for v in e["scalars"].values() if v is not None]
            values += list(np.ravel(e["arrays"].get("skill", [])))
            assert all(np.isfinite(values)) and max(map(abs, values), default=0) < 1e15, e
            if e["service"] == "collector":
                assert max(map(abs, e["arrays"]["skill"])) <= 3.0
        skills_api = httpx.get(f"http://127.0.0.1:{api_port}/skills", timeout=30).json()
        zs = np.array([s["z"] for s in skills_api["items"]], float)
        assert len(zs) and np.abs(zs).max() <= 1.0
        watcher.close()
        session.close()
        for name, proc in st.procs.items():
            assert proc.alive(), f"{name} died\n{st.logs()}"


def _session(ep: str, creds: secrets.Credentials | None) -> zenoh.Session:
    conf = client_config(BusConfig(router=ep, auth="off"), creds)
    conf.insert_json5("connect/timeout_ms", "3000")
    conf.insert_json5("connect/exit_on_failure", "true")
    return zenoh.open(conf)


def test_authentication_and_access_rules_on_the_router(tmp_path: Path) -> None:
    with running_stack(tmp_path) as st:
        st.procs["router"] = p = __import__("services.stack", fromlist=["Proc"]).Proc(
            "router",
            [
                "-m",
                "services.router",
                "--listen",
                st.endpoint,
                "--auth",
                "on",
                "--run.run-id",
                st.run_id,
                "--run.root",
                str(st.runs),
            ],
            tmp_path / "logs",
        )
        wait_port(st.port)
        d = st.run_dir / "secrets"
        assert {f.name for f in d.iterdir()} >= {
            "bus.key",
            "users",
            "learner.cred",
            "collector.cred",
            "repertoire.cred",
        }
        assert all((f.stat().st_mode & 0o077) == 0 for f in d.iterdir())
        cred = {r: secrets.read_credentials(d / f"{r}.cred") for r in secrets.ROLES}
        t = st.topics

        # no credentials, or wrong ones: no session at all (so no publish, no subscribe)
        for creds in (None, secrets.Credentials("learner", "wrong")):
            with pytest.raises(zenoh.ZError):
                _session(st.endpoint, creds).close()

        learner = _session(st.endpoint, cred["learner"])
        collector = _session(st.endpoint, cred["collector"])
        repertoire = _session(st.endpoint, cred["repertoire"])
        got: list[tuple[str, bytes]] = []
        observer = _session(st.endpoint, cred["dashboard"])
        observer.declare_subscriber(
            f"{t.root}/**", lambda s: got.append((str(s.key_expr), s.payload.to_bytes()))
        )
        time.sleep(1.0)
        collector.put(t.weights, b"collector-weights")
        collector.put(t.snapshot, b"collector-snapshot")
        repertoire.put(t.transitions("c0"), b"repertoire-chunk")
        learner.put(t.weights, b"learner-weights")
        collector.put(t.transitions("c0"), b"collector-chunk")
        collector.put(t.features("c0"), b"collector-features")
        repertoire.put(t.snapshot, b"repertoire-snapshot")
        wait_for(lambda: len(got) >= 4, 10, "the allowed publications")
        time.sleep(1.0)
        assert sorted(p for _, p in got) == [
            b"collector-chunk",
            b"collector-features",
            b"learner-weights",
            b"repertoire-snapshot",
        ]
        # a collector cannot answer weight queries either; the learner can
        collector.declare_queryable(t.weights, lambda q: q.reply(t.weights, b"evil"))
        learner.declare_queryable(t.weights, lambda q: q.reply(t.weights, b"good"))
        time.sleep(0.5)
        answers = [
            r.ok.payload.to_bytes()
            for r in observer.get(t.weights, timeout=3.0)
            if r.ok is not None
        ]
        assert answers == [b"good"]
        # the services' own path: open_session finds the role's credentials in the run dir
        from services.common.bus import open_session
        from services.common.config import RunConfig

        run = RunConfig(run_id=st.run_id, root=st.runs)
        s = open_session(BusConfig(router=st.endpoint, connect_timeout_s=5.0), "learner", run)
        assert codec.run_key() == secrets.read_key(d / "bus.key")
        s.close()
        codec.set_run_key(None)
        for sess in (learner, collector, repertoire, observer):
            sess.close()
        assert p.alive()


def test_auth_defaults_follow_the_endpoints(tmp_path: Path) -> None:
    from services.common.config import RunConfig

    run = RunConfig(run_id="r", root=tmp_path)
    local = BusConfig(router="tcp/127.0.0.1:7447", listen="tcp/127.0.0.1:7447")
    assert secrets.router_auth(local, run) is None
    assert secrets.client_credentials(local, "learner", run) is None
    remote = BusConfig(router="tcp/10.0.0.5:7447", listen="tcp/0.0.0.0:7447")
    with pytest.raises(SystemExit, match="ursa secrets"):
        secrets.client_credentials(remote, "learner", run)
    auth = secrets.router_auth(remote, run)  # generates them
    assert auth is not None and auth.dictionary.exists()
    assert secrets.client_credentials(remote, "learner", run) == secrets.read_credentials(
        tmp_path / "r" / "secrets" / "learner.cred"
    )
    # once a run has secrets, loopback processes of that run use them too
    assert secrets.router_auth(local, run) is not None
    assert secrets.client_credentials(local, "collector", run) is not None
    off = BusConfig(router="tcp/10.0.0.5:7447", auth="off")
    assert secrets.client_credentials(off, "learner", run) is None
    assert secrets.is_loopback("tcp/[::1]:7447") and not secrets.is_loopback("tcp/0.0.0.0:1")
