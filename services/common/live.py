"""What the dashboard and the HTTP API know about a run: latest stats, snapshot, presence.

Pure (no zenoh, no viser): bus callbacks feed a :class:`LiveState` with decoded messages, and the
dashboard panels and API routes read immutable views out of it. Everything is bounded: one
``StatsEntry`` per (service, id), one snapshot, and a fixed number of history points per series.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import numpy as np

from proto import codec
from proto import ursa_pb2 as pb
from proto.topics import Topics
from services.common.history import DecimatingSeries
from ursa.kde import regularize_cov, whitening_matrix


@dataclass(frozen=True, eq=False)
class SnapshotView:
    """A decoded, validated ``RepertoireSnapshot``; arrays are read-only.

    skills (N, D) float64, ids (N,) int64, ages (N,) int64, nn_dist (N,) float64 (inf for a lone
    skill), cov (D, D) float64.
    """

    version: int
    stamp: float
    received: float
    skills: np.ndarray
    ids: np.ndarray
    ages: np.ndarray
    nn_dist: np.ndarray
    cov: np.ndarray
    delta: float
    entropy_bound: float
    encoder_version: int
    commits: int
    capacity: int
    n_z: int
    sender: str = ""

    @classmethod
    def from_msg(cls, msg: pb.RepertoireSnapshot, received: float | None = None) -> SnapshotView:
        """Decode and check shapes; raises ``codec.BadMessage`` on any inconsistency."""
        skills = codec.from_array(msg.skills)
        if skills.ndim != 2:
            raise codec.BadMessage(f"snapshot skills of shape {skills.shape}, expected (N, D)")
        n, d = skills.shape
        if d == 0 and n > 0:
            raise codec.BadMessage("snapshot skills of dimension 0")

        def vec(a: pb.Array, name: str, dtype: Any) -> np.ndarray:
            if not a.shape and not a.data and n == 0:
                return np.zeros(0, dtype)
            x = codec.from_array(a)
            if x.shape != (n,):
                raise codec.BadMessage(f"snapshot {name} of shape {x.shape}, expected ({n},)")
            return np.asarray(x, dtype)

        ids = vec(msg.ids, "ids", np.int64)
        ages = vec(msg.ages, "ages", np.int64)
        nn = vec(msg.nn_dist, "nn_dist", np.float64)
        if msg.cov.shape or msg.cov.data:
            cov = np.asarray(codec.from_array(msg.cov), np.float64)
            if cov.shape != (d, d):
                raise codec.BadMessage(f"snapshot cov of shape {cov.shape}, expected ({d}, {d})")
        else:
            cov = np.eye(d)
        if not np.all(np.isfinite(skills)):
            raise codec.BadMessage("snapshot skills contain non-finite values")
        if len(np.unique(ids)) != n:
            raise codec.BadMessage("snapshot ids are not unique")
        arrays = [np.asarray(skills, np.float64), ids, ages, nn, cov]
        for a in arrays:
            a.flags.writeable = False
        return cls(
            version=int(msg.version),
            stamp=float(msg.header.stamp),
            received=time.time() if received is None else received,
            skills=arrays[0],
            ids=ids,
            ages=ages,
            nn_dist=nn,
            cov=cov,
            delta=float(msg.delta),
            entropy_bound=float(msg.entropy_bound),
            encoder_version=int(msg.encoder_version),
            commits=int(msg.commits),
            capacity=int(msg.capacity),
            n_z=int(msg.n_z),
            sender=msg.header.sender,
        )

    @property
    def size(self) -> int:
        return int(self.skills.shape[0])

    @property
    def dim(self) -> int:
        return int(self.skills.shape[1])

    @cached_property
    def _order(self) -> np.ndarray:
        return np.argsort(self.ids, kind="stable")

    @cached_property
    def whitener(self) -> np.ndarray:
        """A (D, D) with ``d_Σ(x, y) = ‖A (x − y)‖`` (Σ regularized when singular)."""
        if self.dim == 0:
            return np.zeros((0, 0))
        return whitening_matrix(regularize_cov(self.cov))

    @cached_property
    def _white(self) -> np.ndarray:
        return np.asarray(self.skills @ self.whitener.T)

    def index_of(self, skill_id: int) -> int | None:
        """Row of the skill with this id, or None."""
        if self.size == 0:
            return None
        sorted_ids = self.ids[self._order]
        pos = int(np.searchsorted(sorted_ids, skill_id))
        if pos < self.size and int(sorted_ids[pos]) == skill_id:
            return int(self._order[pos])
        return None

    def page(self, offset: int, limit: int) -> np.ndarray:
        """Rows of the skills ranked ``offset .. offset+limit`` by id."""
        return np.asarray(self._order[offset : offset + limit])

    def mahalanobis(self, z: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
        """Mahalanobis distances (M,) from z (D,) to the skills at ``rows`` (default all)."""
        w = self._white if rows is None else self._white[rows]
        wz = np.asarray(z, np.float64) @ self.whitener.T
        return np.asarray(np.sqrt(((w - wz) ** 2).sum(axis=1)))

    def distance(self, a: np.ndarray, b: np.ndarray) -> float:
        """Mahalanobis distance between two points (D,) in this snapshot's metric."""
        diff = (np.asarray(a, np.float64) - np.asarray(b, np.float64)) @ self.whitener.T
        return float(np.sqrt(diff @ diff))

    def nearest(self, z: np.ndarray, k: int = 1) -> tuple[np.ndarray, np.ndarray]:
        """Rows (k,) and Mahalanobis distances (k,) of the k skills nearest z (D,),
        nearest first (ties: lower id first)."""
        if self.size == 0:
            return np.zeros(0, np.int64), np.zeros(0)
        d = self.mahalanobis(z)
        k = min(k, self.size)
        rows = np.argpartition(d, k - 1)[:k] if k < self.size else np.arange(self.size)
        rows = rows[np.lexsort((self.ids[rows], d[rows]))]
        return rows, d[rows]


@dataclass(frozen=True, eq=False)
class StatsEntry:
    """The latest ``Stats`` of one (service, id), decoded (undecodable arrays left out)."""

    service: str
    sid: str
    stamp: float
    received: float
    scalars: Mapping[str, float]
    labels: Mapping[str, str]
    arrays: Mapping[str, np.ndarray]

    @classmethod
    def from_msg(cls, msg: pb.Stats, received: float | None = None) -> StatsEntry:
        arrays: dict[str, np.ndarray] = {}
        for k, a in msg.arrays.items():
            try:
                arrays[k] = np.asarray(codec.from_array(a))
            except codec.BadMessage:
                continue
        return cls(
            service=msg.service,
            sid=msg.id,
            stamp=float(msg.header.stamp),
            received=time.time() if received is None else received,
            scalars=dict(msg.scalars),
            labels=dict(msg.labels),
            arrays=arrays,
        )

    def scalar(self, key: str) -> float | None:
        v = self.scalars.get(key)
        return float(v) if v is not None and math.isfinite(v) else None


@dataclass(frozen=True)
class CollectorInfo:
    """One collector as the dashboard and ``GET /collectors`` show it."""

    id: str
    alive: bool
    since: float | None
    stats: StatsEntry | None

    def get(self, key: str) -> float | None:
        return None if self.stats is None else self.stats.scalar(key)

    @property
    def skill(self) -> np.ndarray | None:
        if self.stats is None:
            return None
        z = self.stats.arrays.get("skill")
        if z is None or z.ndim != 1 or not np.all(np.isfinite(z)):
            return None
        return np.asarray(z, np.float64)

    @property
    def damage(self) -> str | None:
        return None if self.stats is None else self.stats.labels.get("damage")


def finite(x: float | None) -> float | None:
    """x if it is a finite number, else None (JSON has no inf/nan)."""
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


def finite_list(a: Iterable[float]) -> list[float | None]:
    return [finite(float(v)) for v in a]


@dataclass
class LiveState:
    """Thread-safe latest view of a run, fed by bus callbacks (or by tests directly).

    ``alive`` returns the live liveliness keys (``Presence.alive``); ``history_capacity`` > 0 keeps
    a bounded time series of every scalar of every (service, id) (the dashboard's plots).
    """

    run_id: str = "default"
    alive: Callable[[], Mapping[str, float]] = dict
    history_capacity: int = 0
    history_min_dt: float = 0.25
    max_series: int = 4000
    topics: Topics = field(init=False)
    stats: dict[tuple[str, str], StatsEntry] = field(default_factory=dict)
    snapshot: SnapshotView | None = None
    history: dict[tuple[str, str, str], DecimatingSeries] = field(default_factory=dict)
    rejected: int = 0
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    def __post_init__(self) -> None:
        self.topics = Topics(self.run_id)

    # ---- inputs -------------------------------------------------------------------------
    def on_stats(self, msg: pb.Stats, key: str = "") -> None:
        entry = StatsEntry.from_msg(msg)
        with self._lock:
            self.stats[(entry.service, entry.sid)] = entry
            if self.history_capacity > 0:
                self._record(entry)

    def _record(self, e: StatsEntry) -> None:
        for k, v in e.scalars.items():
            if not math.isfinite(v):
                continue
            series = self.history.get((e.service, e.sid, k))
            if series is None:
                if len(self.history) >= self.max_series:
                    continue
                series = DecimatingSeries(self.history_capacity, self.history_min_dt)
                self.history[(e.service, e.sid, k)] = series
            series.add(e.stamp, v)

    def on_snapshot(self, msg: pb.RepertoireSnapshot, key: str = "") -> None:
        """Keep the snapshot if it is newer (by version, or a restarted repertoire by stamp)."""
        view = SnapshotView.from_msg(msg)
        with self._lock:
            cur = self.snapshot
            if cur is None or view.version > cur.version or view.stamp > cur.stamp:
                self.snapshot = view

    # ---- reads ---------------------------------------------------------------------------
    def latest_snapshot(self) -> SnapshotView | None:
        with self._lock:
            return self.snapshot

    def all_stats(self) -> dict[tuple[str, str], StatsEntry]:
        with self._lock:
            return dict(self.stats)

    def stats_of(self, service: str, sid: str) -> StatsEntry | None:
        with self._lock:
            return self.stats.get((service, sid))

    def series(self) -> dict[tuple[str, str, str], tuple[np.ndarray, np.ndarray]]:
        """Copies of every history series: (service, id, key) -> (t (n,), v (n,))."""
        with self._lock:
            return {k: s.arrays() for k, s in self.history.items()}

    def alive_ids(self, service: str) -> dict[str, float]:
        """Ids of the live instances of ``service`` with the time each was first seen."""
        out: dict[str, float] = {}
        for key, since in self.alive().items():
            parsed = self.topics.parse_alive(key)
            if parsed is not None and parsed[0] == service:
                out[parsed[1]] = since
        return out

    def collectors(self, include_dead: bool = False) -> list[CollectorInfo]:
        """Live collectors (and, with ``include_dead``, those with stats only), sorted by id."""
        alive = self.alive_ids("collector")
        stats = self.all_stats()
        ids = set(alive)
        if include_dead:
            ids |= {sid for (svc, sid) in stats if svc == "collector"}
        return [
            CollectorInfo(cid, cid in alive, alive.get(cid), stats.get(("collector", cid)))
            for cid in sorted(ids)
        ]
