"""Repertoire: the diversity archive of safe skills and the KDE that samples from it (§4.2).

Subscribes:  ursa/{run}/collector/features/* (SafeFeatures, BLOCK)
             ursa/{run}/learner/encoder (EncoderWeights; learned phi only)
Queryables:  ursa/{run}/repertoire/sample (SkillRequest -> SkillReply)
             ursa/{run}/repertoire/snapshot (-> RepertoireSnapshot, the latest)
Publishes:   ursa/{run}/repertoire/snapshot (RepertoireSnapshot, a few per second)
             ursa/{run}/repertoire/stats (Stats)
Liveliness:  ursa/{run}/alive/repertoire/main

Trust: features outside the box the env declares for the feature function
(``ursa.bounds.declared``) are counted and dropped at decode; the archive never admits a skill
that is not finite or lies outside the declared skill box, an archive loaded from disk with such
skills is repaired (count in the stats' ``repaired`` and in the log), and KDE draws are clipped
to the declared sample box before they leave.
"""

from __future__ import annotations

import queue
import threading
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
import zenoh

from proto import codec
from proto import ursa_pb2 as pb
from services.common.bus import (
    checked_decode,
    publisher,
    query_one,
    reason_of,
    safe_handler,
    validate_with,
)
from services.common.config import ServiceArgs, save_resolved
from services.common.runtime import ServiceRuntime
from ursa import bounds
from ursa.repertoire import Repertoire
from ursa.rundir import RunDir


@dataclass(frozen=True)
class RepertoireArgs(ServiceArgs):
    """Repertoire service settings."""

    snapshot_hz: float = 2.0
    """How often the snapshot and stats are published."""
    save_every_s: float = 10.0
    """How often the archive is saved to ``<run dir>/repertoire/archive.npz``."""
    max_sample: int = 4096
    """Largest n a sample query may ask for."""
    pending_limit: int = 100_000
    """Learned phi: VAE inputs kept while no encoder has arrived yet (oldest dropped)."""


class RepertoireService:
    def __init__(self, args: RepertoireArgs) -> None:
        self.args = args
        self.cfg = args.core
        self.rt = ServiceRuntime("repertoire", "main", args.bus, args.run)
        self.log = self.rt.log
        save_resolved(args, args.run, "repertoire")
        self.learned = self.cfg.feature == "vae"
        self.declared = bounds.declared(self.cfg)
        validate_with(self.cfg)
        self.path = RunDir(args.run.dir).archive
        self.lock = threading.Lock()
        self.rep = self._restore()
        self.encoder: Any = None
        self.pending: list[np.ndarray] = []
        self.inbox: queue.Queue[np.ndarray] = queue.Queue()
        self.version = 0
        self.commits_window: list[tuple[float, int, int]] = []
        self._snapshot_bytes: bytes | None = None

        t = self.rt.topics
        self.pub_snapshot = publisher(self.rt.session, t.snapshot, reliable=False)
        self.subs = [
            self.rt.session.declare_subscriber(
                t.features(),
                safe_handler(pb.SafeFeatures, self._on_features, self.rt.drops, args.run.run_id),
            )
        ]
        if self.learned:
            self.subs.append(
                self.rt.session.declare_subscriber(
                    t.encoder,
                    safe_handler(
                        pb.EncoderWeights, self._on_encoder, self.rt.drops, args.run.run_id
                    ),
                )
            )
        self.queryables = [
            self.rt.session.declare_queryable(t.sample, self._on_sample),
            self.rt.session.declare_queryable(t.snapshot, self._on_snapshot_query),
        ]

    # ---- persistence ---------------------------------------------------------------------
    def _restore(self) -> Repertoire:
        box = self.declared.skills
        if self.path.exists():
            try:
                rep = Repertoire.load(self.path, bounds=box)
                self.log.info("restored %d skills from %s", len(rep.skills), self.path)
                if rep.repaired:
                    self.log.warning(
                        "repaired %s: dropped %d skills not finite or outside %s",
                        self.path,
                        rep.repaired,
                        box,
                    )
                return rep
            except Exception:
                self.log.exception("cannot restore %s; starting empty", self.path)
        return Repertoire(self.cfg.repertoire, bounds=box)

    def save(self) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        with self.lock:
            self.rep.save(self.path)

    # ---- inputs ----------------------------------------------------------------------------
    def _on_features(self, msg: pb.SafeFeatures, key: str) -> None:
        # values were checked against the declared feature box at decode (checked_decode)
        feats = codec.from_array(msg.features)
        want = self.cfg.repertoire.input_dim if self.learned else self.cfg.repertoire.dim
        if feats.ndim != 2 or (want and feats.shape[1] != want):
            raise codec.BadMessage(f"features of shape {feats.shape}, expected (N, {want})")
        self.inbox.put(np.asarray(feats, np.float32))

    def _on_encoder(self, msg: pb.EncoderWeights, key: str) -> None:
        from safetensors.torch import load as st_load

        from ursa.vae import VAE  # torch only where phi is learned

        with self.lock:
            current = self.rep.encoder_version
        if self.encoder is not None and msg.version <= current:
            return
        c, lc = self.cfg.repertoire, self.cfg.learner
        assert c.input_dim is not None
        enc = VAE(c.input_dim, c.dim, lc.vae_units, lc.vae_layers)
        try:
            enc.load_state_dict(st_load(msg.safetensors), strict=True)
        except Exception as e:
            raise codec.BadMessage(f"encoder weights {msg.version} do not fit: {e}") from e
        enc.eval()
        self.encoder = enc
        with self.lock:
            self.rep.reencode(enc.encode, int(msg.version))
        self.log.info("re-encoded the archive with encoder version %d", msg.version)

    def _commit(self, feats: np.ndarray) -> None:
        if self.learned:
            if self.encoder is None:
                self.pending.append(feats)
                total = sum(len(p) for p in self.pending)
                while total > self.args.pending_limit and self.pending:
                    total -= len(self.pending.pop(0))
                return
            batches, self.pending = [*self.pending, feats], []
            for b in batches:
                z = self.encoder.encode(b)
                with self.lock:
                    self.rep.commit_many(z, b)
        else:
            with self.lock:
                self.rep.commit_many(feats, None)

    # ---- queries ---------------------------------------------------------------------------
    def _on_sample(self, query: zenoh.Query) -> None:
        try:
            payload = query.payload.to_bytes() if query.payload is not None else b""
            req = checked_decode(pb.SkillRequest, payload, key=self.rt.topics.sample)
            if req.n == 0 or req.n > self.args.max_sample:
                raise codec.BadMessage(f"n={req.n} outside 1..{self.args.max_sample}")
        except codec.BadMessage as e:
            self.rt.drops.add(reason_of(e), self.rt.topics.sample, codec.claimed_sender(payload))
            query.reply_err(str(e).encode())
            return
        rng = np.random.default_rng(req.seed if req.has_seed else None)
        reply = pb.SkillReply(header=self.rt.header(), snapshot_version=self.version)
        with self.lock:
            if len(self.rep.skills) == 0:
                reply.error = "repertoire is empty"
            else:
                # the KDE's Gaussian tails reach past any box: clip to the declared one
                draws = self.declared.samples.clip(self.rep.sample(int(req.n), rng))
                reply.skills.CopyFrom(codec.to_array(draws.astype(np.float32)))
                reply.delta = float(self.rep.delta())
                reply.encoder_version = int(self.rep.encoder_version)
        query.reply(self.rt.topics.sample, codec.encode(reply))

    def _on_snapshot_query(self, query: zenoh.Query) -> None:
        data = self._snapshot_bytes or codec.encode(self.snapshot())
        query.reply(self.rt.topics.snapshot, data)

    def snapshot(self) -> pb.RepertoireSnapshot:
        with self.lock:
            rep = self.rep
            msg = pb.RepertoireSnapshot(
                header=self.rt.header(),
                version=self.version,
                skills=codec.to_array(rep.skills.astype(np.float32)),
                ids=codec.to_array(np.asarray(rep.ids, np.int64)),
                ages=codec.to_array(np.asarray(rep.ages, np.int64)),
                nn_dist=codec.to_array(np.asarray(rep.nn_dist, np.float32)),
                cov=codec.to_array(np.asarray(rep.cov, np.float64)),
                delta=float(rep.delta()) if len(rep.skills) > 1 else 0.0,
                entropy_bound=float(rep.entropy_bound()) if len(rep.skills) > 1 else 0.0,
                encoder_version=int(rep.encoder_version),
                commits=int(rep.commits),
                capacity=int(self.cfg.repertoire.size),
                n_z=int(self.cfg.repertoire.n_z),
            )
            if self.learned and rep.inputs is not None:
                msg.inputs.CopyFrom(codec.to_array(np.asarray(rep.inputs, np.float32)))
        return msg

    # ---- loop ------------------------------------------------------------------------------
    def run(self) -> None:
        t = self.rt.topics
        if self.learned:
            latest = query_one(self.rt.session, t.encoder, pb.EncoderWeights, timeout_s=1.0)
            if latest is not None:
                self._on_encoder(latest, t.encoder)
        period = 1.0 / self.args.snapshot_hz
        last_pub = last_save = 0.0
        while not self.rt.stop.is_set():
            self._drain(budget_s=0.2)
            now = time.monotonic()
            if now - last_pub >= period:
                self.version += 1
                snap = self.snapshot()
                self._snapshot_bytes = codec.encode(snap)
                self.pub_snapshot.put(self._snapshot_bytes)
                self._publish_stats(snap)
                last_pub = now
            if now - last_save >= self.args.save_every_s:
                self.save()
                last_save = now

    def _drain(self, budget_s: float) -> None:
        """Commit what arrived, in batches, for at most ``budget_s`` so that snapshots and stats
        keep their schedule however fast the collectors are (the rest waits in the inbox)."""
        deadline = time.monotonic() + budget_s
        try:
            batch = [self.inbox.get(timeout=0.05)]
        except queue.Empty:
            return
        while True:
            while len(batch) < 64:
                try:
                    batch.append(self.inbox.get_nowait())
                except queue.Empty:
                    break
            self._commit(np.concatenate(batch))
            if self.inbox.empty() or time.monotonic() > deadline:
                return
            batch = []

    def _publish_stats(self, snap: pb.RepertoireSnapshot) -> None:
        with self.lock:
            rep = self.rep
            now = time.monotonic()
            self.commits_window.append((now, int(rep.accepted), int(rep.rejected)))
            self.commits_window = [w for w in self.commits_window if now - w[0] <= 5.0]
            t0, a0, r0 = self.commits_window[0]
            dt = max(now - t0, 1e-9)
            scalars = {
                "size": len(rep.skills),
                "capacity": self.cfg.repertoire.size,
                "delta": snap.delta,
                "entropy_bound": snap.entropy_bound,
                "commits": rep.commits,
                "accepted": rep.accepted,
                "rejected": rep.rejected,
                "invalid": rep.invalid,
                "encoder_version": rep.encoder_version,
                "out_of_bounds": rep.rejected_out_of_bounds,
                "repaired": rep.repaired,
                "accepted_per_s": (rep.accepted - a0) / dt if len(self.commits_window) > 1 else 0,
                "rejected_per_s": (rep.rejected - r0) / dt if len(self.commits_window) > 1 else 0,
                "pending_inputs": sum(len(p) for p in self.pending),
                "inbox": self.inbox.qsize(),
            }
        self.rt.publish_stats(scalars)

    def close(self) -> None:
        for h in (*self.subs, *self.queryables, self.pub_snapshot):
            try:
                h.undeclare()
            except Exception:
                pass
        while not self.inbox.empty():
            self._commit(self.inbox.get_nowait())
        self.save()
        self.rt.close()
