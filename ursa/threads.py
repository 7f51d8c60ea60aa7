"""Thread counts of the numeric libraries in one process: torch's intra-op pool, the BLAS and
OpenMP pools numpy and scipy load (through threadpoolctl), and numba's parallel pool.

Every URSA process runs next to others on a few cores (collectors, repertoire, learner, the
router): a pool sized to the machine's cores oversubscribes them, and torch's 2 threads fell to
a tenth of one thread's speed when the collectors held the cores (docs/learner.md, issue 19).
So each process sets its pools once, at start, to what it uses: 1 everywhere by default, and
the learner's torch threads from its config.
"""

from __future__ import annotations

import sys
from typing import Any

_limits: Any = None  # threadpoolctl's limiter, kept alive for the life of the process


def limit_threads(
    torch_threads: int = 1, blas_threads: int = 1, numba_threads: int = 1
) -> dict[str, int | None]:
    """Set the pools of this process and return what each now reports
    (``{"torch": n, "blas": n | None, "numba": n | None}``; None where the library is absent).

    torch is configured only when this process imports it anyway (a service that needs no
    torch does not pay for importing it here)."""
    global _limits
    import numpy  # noqa: F401 - load numpy's BLAS so that the limit reaches it
    from threadpoolctl import threadpool_info, threadpool_limits

    _limits = threadpool_limits(limits=max(1, blas_threads))
    out: dict[str, int | None] = {"torch": None, "blas": None, "numba": None}
    pools = threadpool_info()
    if pools:
        out["blas"] = max(int(p["num_threads"]) for p in pools)
    try:
        import numba
    except ImportError:  # pragma: no cover - numba is a dependency
        pass
    else:
        most = int(numba.config.NUMBA_NUM_THREADS)  # type: ignore[attr-defined]
        numba.set_num_threads(max(1, min(numba_threads, most)))
        out["numba"] = int(numba.get_num_threads())
    if "torch" in sys.modules:
        import torch

        torch.set_num_threads(max(1, torch_threads))
        out["torch"] = int(torch.get_num_threads())
    return out
