"""Every process sets its numeric thread pools once (ursa.threads.limit_threads); checked in a
fresh interpreter, whose pools start at the machine's defaults."""

from __future__ import annotations

import json
import os
import subprocess
import sys

CHECK = """
import json, torch, numba
from threadpoolctl import threadpool_info
from ursa.threads import limit_threads
out = limit_threads(torch_threads=2)
blas = [p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"]
print(json.dumps({"out": out, "blas": blas, "torch": torch.get_num_threads(),
                  "numba": numba.get_num_threads()}))
"""


def test_limit_threads_sets_torch_blas_and_numba() -> None:
    env = {k: v for k, v in os.environ.items() if not k.endswith("_NUM_THREADS")}
    res = subprocess.run(
        [sys.executable, "-c", CHECK], capture_output=True, text=True, env=env, timeout=120
    )
    assert res.returncode == 0, res.stderr
    got = json.loads(res.stdout.strip().splitlines()[-1])
    assert got["torch"] == 2 and got["out"]["torch"] == 2
    assert got["numba"] == 1 and got["out"]["numba"] == 1
    assert got["blas"] and all(n == 1 for n in got["blas"]), got
    assert got["out"]["blas"] == 1


def test_without_torch_imported_torch_is_left_alone() -> None:
    code = "import json, sys; from ursa.threads import limit_threads; "
    code += "out = limit_threads(); print(json.dumps([out, 'torch' in sys.modules]))"
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    out, imported = json.loads(res.stdout.strip().splitlines()[-1])
    assert out["torch"] is None and not imported
