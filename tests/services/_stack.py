"""Helpers of the dashboard, API and evaluator tests: fake bus data and a headless browser.

:func:`headless_chromium` drives Debian's chromium (``apt-get install chromium``, ``make
system-deps``) through Playwright, launched from its executable path: Playwright never downloads
a browser here.
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np
from playwright.sync_api import Browser, sync_playwright

from proto import codec
from proto import ursa_pb2 as pb

CHROMIUM_FLAGS = (
    "--enable-unsafe-swiftshader",
    "--no-sandbox",
    "--use-angle=swiftshader",
    "--disable-gpu-sandbox",
    "--disable-dev-shm-usage",
    "--no-first-run",
    "--no-default-browser-check",
    "--mute-audio",
    "--window-size=1600,1000",
    "--disable-background-timer-throttling",
    "--disable-renderer-backgrounding",
    "--disable-backgrounding-occluded-windows",
)


def find_chromium() -> str | None:
    """Debian's chromium (``URSA_CHROMIUM`` names another executable); None when absent."""
    return shutil.which(os.environ.get("URSA_CHROMIUM") or "chromium")


def snapshot_msg(
    n: int = 50, d: int = 2, version: int = 1, run_id: str = "test", seed: int = 0, id0: int = 0
) -> pb.RepertoireSnapshot:
    """A repertoire snapshot of n random skills (ids id0, id0+1, ...) with Σ = 0.05·I."""
    rng = np.random.default_rng(seed)
    z = rng.uniform(-1.0, 1.0, size=(n, d)).astype(np.float32)
    nn = rng.uniform(0.1, 0.5, size=n).astype(np.float32)
    if n == 1:
        nn[:] = np.inf
    return pb.RepertoireSnapshot(
        header=codec.header(run_id, "repertoire/main"),
        version=version,
        skills=codec.to_array(z),
        ids=codec.to_array(np.arange(id0, id0 + n, dtype=np.int64)),
        ages=codec.to_array(np.arange(n, dtype=np.int64)),
        nn_dist=codec.to_array(nn),
        cov=codec.to_array(np.eye(d) * 0.05),
        delta=0.3,
        entropy_bound=-1.5,
        encoder_version=0,
        commits=n,
        capacity=300,
        n_z=100,
    )


def stats_msg(
    service: str,
    sid: str,
    scalars: dict[str, float],
    run_id: str = "test",
    labels: dict[str, str] | None = None,
    arrays: dict[str, np.ndarray] | None = None,
    stamp: float | None = None,
) -> pb.Stats:
    msg = pb.Stats(header=codec.header(run_id, f"{service}/{sid}"), service=service, id=sid)
    if stamp is not None:
        msg.header.stamp = stamp
    for k, v in scalars.items():
        msg.scalars[k] = float(v)
    for k, s in (labels or {}).items():
        msg.labels[k] = s
    for k, a in (arrays or {}).items():
        msg.arrays[k].CopyFrom(codec.to_array(np.asarray(a)))
    return msg


@contextmanager
def headless_chromium(executable: str) -> Iterator[Browser]:
    """A headless chromium driven by Playwright (software WebGL for viser's 3-D canvas)."""
    with sync_playwright() as pw:
        browser = pw.chromium.launch(
            executable_path=executable, headless=True, args=list(CHROMIUM_FLAGS)
        )
        try:
            yield browser
        finally:
            browser.close()
