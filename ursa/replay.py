"""In-memory replay of reset-free transition streams, one stream per collector.

Each record is one env step (see ``ursa.world_model`` for the time convention): ``obs``
(obs_dim) after the step, the ``action`` (act_dim) that produced it, its ``reward``, ``cost``,
``safe``, ``features`` (F: the φ input, i.e. the VAE input or a provided φ) and the ``skill``
(D) the collector was executing. Any other consistent set of fields works too.

Collectors send chunks stamped with the step index of their first record. A chunk whose first
step is not the one expected after the stream's last record (a lost chunk, a restarted
collector, the first chunk of a stream) starts a new *segment*: its first record gets
``is_first = True`` and the world model re-initialises its state there. There are no episodes
otherwise. Sampled sequences may cross segment boundaries (the flag marks them), and every
sampled sequence starts with ``is_first = True`` since the learner filters it from the
initial state.

Capacity is counted in records over all streams; the oldest records (by insertion) go first.
Stream ids are kept as strings.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class _Stream:
    data: dict[str, np.ndarray]
    is_first: np.ndarray
    order: np.ndarray
    start: int = 0
    end: int = 0
    next_step: int = -1

    def __len__(self) -> int:
        return self.end - self.start

    def head_order(self) -> int:
        return int(self.order[self.start]) if len(self) else np.iinfo(np.int64).max


def _locate(counts: np.ndarray, picks: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Indices into the concatenation of groups of ``counts`` (G,) items -> (group, index in
    the group), each (N,) for ``picks`` (N,)."""
    cum = np.cumsum(counts)
    which = np.searchsorted(cum, picks, side="right")
    return which, picks - (cum[which] - counts[which])


class Replay:
    """Capacity-bounded FIFO replay of per-collector streams; see the module docstring."""

    def __init__(self, capacity: int) -> None:
        if capacity < 1:
            raise ValueError("capacity must be positive")
        self.capacity = int(capacity)
        self._streams: dict[str, _Stream] = {}
        self._schema: dict[str, tuple[tuple[int, ...], np.dtype]] | None = None
        self._size = 0
        self._counter = 0
        self.gaps = 0
        """Chunks that started a new segment in an existing stream."""
        self.inserted = 0
        """Records ever added (evicted ones included): the env-step count of the train ratio."""

    def __len__(self) -> int:
        return self._size

    @property
    def streams(self) -> list[str]:
        """Ids of the streams seen so far."""
        return list(self._streams)

    def _check(self, chunk: dict[str, np.ndarray]) -> tuple[dict[str, np.ndarray], int]:
        arrays = {k: np.asarray(v) for k, v in chunk.items()}
        if not arrays:
            raise ValueError("empty chunk")
        lens = {a.shape[0] if a.ndim else -1 for a in arrays.values()}
        if len(lens) != 1 or -1 in lens:
            raise ValueError(f"chunk fields must share their first axis, got {lens}")
        n = lens.pop()
        if self._schema is None:
            self._schema = {
                k: (a.shape[1:], np.dtype(np.float32) if a.dtype.kind == "f" else a.dtype)
                for k, a in arrays.items()
            }
        if set(arrays) != set(self._schema):
            raise ValueError(f"chunk fields {sorted(arrays)} != {sorted(self._schema)}")
        for k, (shape, _) in self._schema.items():
            if arrays[k].shape[1:] != shape:
                raise ValueError(f"field {k}: shape {arrays[k].shape[1:]} != {shape}")
        return arrays, n

    def _new_stream(self, cap: int) -> _Stream:
        assert self._schema is not None
        data = {k: np.zeros((cap, *shape), dtype) for k, (shape, dtype) in self._schema.items()}
        return _Stream(data, np.zeros(cap, bool), np.zeros(cap, np.int64))

    @staticmethod
    def _reserve(s: _Stream, n: int) -> None:
        """Make room for n more records at the end of s (compacting or growing)."""
        cap = len(s.order)
        if s.end + n <= cap:
            return
        length = len(s)
        new_cap = max(cap, 16)
        while length + n > new_cap:
            new_cap *= 2
        if new_cap == cap and s.start == 0:
            new_cap *= 2
        sl = slice(s.start, s.end)

        def move(a: np.ndarray) -> np.ndarray:
            out = np.zeros((new_cap, *a.shape[1:]), a.dtype)
            out[:length] = a[sl]
            return out

        s.data = {k: move(a) for k, a in s.data.items()}
        s.is_first = move(s.is_first)
        s.order = move(s.order)
        s.start, s.end = 0, length

    def add(self, stream_id: str | int, chunk: dict[str, np.ndarray], first_step: int) -> int:
        """Append a chunk (dict of arrays (T, ...)) to a stream; returns T.

        ``first_step`` is the collector's step index of the chunk's first record; a mismatch
        with the stream's next expected step starts a new segment (``is_first``).
        """
        arrays, n = self._check(chunk)
        if n == 0:
            return 0
        sid = str(stream_id)
        s = self._streams.get(sid)
        if s is None:
            s = self._streams[sid] = self._new_stream(max(16, n))
            gap = True
        else:
            gap = s.next_step != int(first_step)
            self.gaps += int(gap)
        self._reserve(s, n)
        sl = slice(s.end, s.end + n)
        for k, a in arrays.items():
            s.data[k][sl] = a
        s.is_first[sl] = False
        s.is_first[s.end] = gap or len(s) == 0
        s.order[sl] = np.arange(self._counter, self._counter + n)
        self._counter += n
        s.end += n
        s.next_step = int(first_step) + n
        self._size += n
        self.inserted += n
        self._evict()
        return n

    def _evict(self) -> None:
        while self._size > self.capacity:
            need = self._size - self.capacity
            heads = sorted((s.head_order(), sid) for sid, s in self._streams.items() if len(s))
            s = self._streams[heads[0][1]]
            limit = heads[1][0] if len(heads) > 1 else np.iinfo(np.int64).max
            older = int(np.searchsorted(s.order[s.start : s.end], limit))
            k = max(1, min(need, older))
            s.start += k
            self._size -= k

    def sample(
        self,
        batch: int,
        seq_len: int,
        rng: np.random.Generator,
        unsafe_fraction: float = 0.0,
    ) -> dict[str, np.ndarray]:
        """``batch`` sequences of ``seq_len`` consecutive records of one stream each: dict of
        arrays (B, T, ...) plus ``is_first`` (B, T).

        The first ``round(unsafe_fraction · batch)`` sequences each hold an unsafe record
        (``safe`` false), drawn uniformly over the unsafe records and then over the windows
        that contain it; the rest (all of them without an unsafe record in any full window)
        are uniform over all valid start records.
        """
        if not 0.0 <= unsafe_fraction <= 1.0:
            raise ValueError(f"unsafe_fraction must lie in [0, 1], got {unsafe_fraction}")
        sids = list(self._streams)
        valid = np.array([max(0, len(self._streams[k]) - seq_len + 1) for k in sids], np.int64)
        total = int(valid.sum())
        if total == 0:
            raise ValueError(f"no stream holds {seq_len} records yet")
        assert self._schema is not None
        starts: list[tuple[int, int]] = self._unsafe_starts(
            sids, valid, seq_len, round(unsafe_fraction * batch), rng
        )
        which, offs = _locate(valid, rng.integers(0, total, size=batch - len(starts)))
        starts += [(int(w), int(o)) for w, o in zip(which, offs, strict=True)]
        out = {
            k: np.zeros((batch, seq_len, *shape), dtype)
            for k, (shape, dtype) in self._schema.items()
        }
        first = np.zeros((batch, seq_len), bool)
        for b, (w, off) in enumerate(starts):
            s = self._streams[sids[w]]
            sl = slice(s.start + off, s.start + off + seq_len)
            for k in out:
                out[k][b] = s.data[k][sl]
            first[b] = s.is_first[sl]
        first[:, 0] = True
        out["is_first"] = first
        return out

    def _unsafe_starts(
        self,
        sids: list[str],
        valid: np.ndarray,
        seq_len: int,
        n: int,
        rng: np.random.Generator,
    ) -> list[tuple[int, int]]:
        """(stream row, start offset) of n windows around uniformly drawn unsafe records;
        fewer (none) when no stream of ``seq_len`` records holds one."""
        if n <= 0 or "safe" not in (self._schema or {}):
            return []
        unsafe: list[np.ndarray] = [
            np.flatnonzero(~s.data["safe"][s.start : s.end].astype(bool))
            if v > 0
            else np.zeros(0, np.int64)
            for s, v in zip((self._streams[k] for k in sids), valid, strict=True)
        ]
        counts = np.array([len(u) for u in unsafe], np.int64)
        if counts.sum() == 0:
            return []
        which, rows = _locate(counts, rng.integers(0, int(counts.sum()), size=n))
        out = []
        for w, p in zip(which, rows, strict=True):
            i = int(unsafe[w][p])
            lo, hi = max(0, i - seq_len + 1), min(i, int(valid[w]) - 1)
            out.append((int(w), int(rng.integers(lo, hi + 1))))
        return out

    # --- persistence ---------------------------------------------------------------------------

    def state_dict(self) -> dict[str, np.ndarray]:
        """Everything needed to rebuild the replay exactly, as numpy arrays only."""
        sids = list(self._streams)
        out: dict[str, np.ndarray] = {
            "capacity": np.asarray(self.capacity, np.int64),
            "counter": np.asarray(self._counter, np.int64),
            "gaps": np.asarray(self.gaps, np.int64),
            "inserted": np.asarray(self.inserted, np.int64),
            "streams": np.asarray(sids, dtype=np.str_),
            "fields": np.asarray(list(self._schema or {}), dtype=np.str_),
        }
        for k, (shape, dtype) in (self._schema or {}).items():
            out[f"schema/{k}"] = np.zeros((0, *shape), dtype)
        for i, sid in enumerate(sids):
            s = self._streams[sid]
            sl = slice(s.start, s.end)
            for k, a in s.data.items():
                out[f"s{i}/data/{k}"] = a[sl].copy()
            out[f"s{i}/is_first"] = s.is_first[sl].copy()
            out[f"s{i}/order"] = s.order[sl].copy()
            out[f"s{i}/next_step"] = np.asarray(s.next_step, np.int64)
        return out

    @classmethod
    def from_state_dict(cls, state: dict[str, np.ndarray]) -> Replay:
        """Rebuild a replay saved by :meth:`state_dict` (e.g. read back from an npz)."""
        rep = cls(int(state["capacity"]))
        rep._counter = int(state["counter"])
        rep.gaps = int(state["gaps"])
        rep.inserted = int(state["inserted"])
        fields = [str(f) for f in np.asarray(state["fields"]).reshape(-1)]
        sids = [str(s) for s in np.asarray(state["streams"]).reshape(-1)]
        if fields:
            rep._schema = {
                f: (state[f"schema/{f}"].shape[1:], state[f"schema/{f}"].dtype) for f in fields
            }
        for i, sid in enumerate(sids):
            order = np.asarray(state[f"s{i}/order"], np.int64)
            n = len(order)
            data = {f: np.array(state[f"s{i}/data/{f}"]) for f in fields}
            s = _Stream(data, np.array(state[f"s{i}/is_first"], bool), order.copy(), 0, n)
            s.next_step = int(state[f"s{i}/next_step"])
            rep._streams[sid] = s
            rep._size += n
        return rep
