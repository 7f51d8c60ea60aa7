"""Helpers of the dashboard, API and evaluator tests: fake bus data and a headless browser.

``Browser`` drives Debian's chromium over the Chrome DevTools Protocol with the ``websockets``
package viser already depends on (no Playwright or Selenium; nothing is downloaded).
"""

from __future__ import annotations

import base64
import contextlib
import itertools
import json
import os
import shutil
import subprocess
import tempfile
import time
from pathlib import Path
from typing import Any

import httpx
import numpy as np
from websockets.sync.client import ClientConnection, connect

from proto import codec
from proto import ursa_pb2 as pb
from tests.stack import free_port

CHROMIUM_FLAGS = ("--headless=new", "--enable-unsafe-swiftshader", "--no-sandbox",
                  "--use-angle=swiftshader", "--disable-gpu-sandbox", "--disable-dev-shm-usage",
                  "--no-first-run", "--no-default-browser-check", "--mute-audio",
                  "--window-size=1600,1000", "--disable-background-timer-throttling",
                  "--disable-renderer-backgrounding", "--disable-backgrounding-occluded-windows")


def find_chromium() -> str | None:
    for name in (os.environ.get("URSA_CHROMIUM", ""), "chromium", "chromium-browser",
                 "google-chrome", "google-chrome-stable"):
        if name and (path := shutil.which(name)):
            return path
    return None


def snapshot_msg(n: int = 50, d: int = 2, version: int = 1, run_id: str = "test",
                 seed: int = 0, id0: int = 0) -> pb.RepertoireSnapshot:
    """A repertoire snapshot of n random skills (ids id0, id0+1, ...) with Σ = 0.05·I."""
    rng = np.random.default_rng(seed)
    z = rng.uniform(-1.0, 1.0, size=(n, d)).astype(np.float32)
    nn = rng.uniform(0.1, 0.5, size=n).astype(np.float32)
    if n == 1:
        nn[:] = np.inf
    return pb.RepertoireSnapshot(
        header=codec.header(run_id, "repertoire/main"), version=version,
        skills=codec.to_array(z), ids=codec.to_array(np.arange(id0, id0 + n, dtype=np.int64)),
        ages=codec.to_array(np.arange(n, dtype=np.int64)), nn_dist=codec.to_array(nn),
        cov=codec.to_array(np.eye(d) * 0.05), delta=0.3, entropy_bound=-1.5,
        encoder_version=0, commits=n, capacity=300, n_z=100)


def stats_msg(service: str, sid: str, scalars: dict[str, float], run_id: str = "test",
              labels: dict[str, str] | None = None,
              arrays: dict[str, np.ndarray] | None = None, stamp: float | None = None) -> pb.Stats:
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


class Browser:
    """A headless chromium with one CDP connection per page; a context manager."""

    def __init__(self, executable: str, log_dir: Path) -> None:
        self.port = free_port()
        self.profile = tempfile.mkdtemp(prefix="ursa-chromium-")
        self.log = open(log_dir / "chromium.log", "ab")  # noqa: SIM115 - closed in close()
        self.proc = subprocess.Popen(
            [executable, *CHROMIUM_FLAGS, f"--remote-debugging-port={self.port}",
             f"--user-data-dir={self.profile}", "about:blank"],
            stdout=self.log, stderr=subprocess.STDOUT, start_new_session=True)
        self._ids = itertools.count(1)
        self.pages: list[ClientConnection] = []
        deadline = time.monotonic() + 30.0
        while True:
            try:
                httpx.get(f"http://127.0.0.1:{self.port}/json/version", timeout=1.0)
                break
            except httpx.HTTPError:
                if time.monotonic() > deadline or self.proc.poll() is not None:
                    self.close()
                    raise RuntimeError("chromium did not open its DevTools port") from None
                time.sleep(0.2)

    def new_page(self, url: str) -> ClientConnection:
        """Open ``url`` in a new tab; returns the tab's CDP connection."""
        r = httpx.put(f"http://127.0.0.1:{self.port}/json/new?{url}", timeout=10.0)
        ws = connect(r.json()["webSocketDebuggerUrl"], max_size=64 * 1024 * 1024)
        self.pages.append(ws)
        self.call(ws, "Page.enable")
        return ws

    def call(self, ws: ClientConnection, method: str, **params: Any) -> dict[str, Any]:
        """Send one CDP command and return its result (events in between are skipped)."""
        cid = next(self._ids)
        ws.send(json.dumps({"id": cid, "method": method, "params": params}))
        while True:
            msg = json.loads(ws.recv(timeout=60.0))
            if msg.get("id") == cid:
                if "error" in msg:
                    raise RuntimeError(f"{method}: {msg['error']}")
                return dict(msg.get("result", {}))

    def eval(self, ws: ClientConnection, expr: str) -> Any:
        res = self.call(ws, "Runtime.evaluate", expression=expr, returnByValue=True)
        return res.get("result", {}).get("value")

    def text(self, ws: ClientConnection) -> str:
        return str(self.eval(ws, "document.body ? document.body.innerText : ''") or "")

    def click_text(self, ws: ClientConnection, text: str, selector: str = "[role=tab]") -> bool:
        """Click (real mouse events) the first ``selector`` element whose text is ``text``."""
        rect = self.eval(ws, f"""(() => {{
            const e = Array.from(document.querySelectorAll({json.dumps(selector)}))
                .find(x => x.innerText.trim() === {json.dumps(text)});
            if (!e) return null;
            const r = e.getBoundingClientRect();
            return [r.x + r.width / 2, r.y + r.height / 2];
        }})()""")
        if not rect:
            return False
        x, y = float(rect[0]), float(rect[1])
        self.call(ws, "Page.bringToFront")
        self.call(ws, "Input.dispatchMouseEvent", type="mouseMoved", x=x, y=y)
        for kind in ("mousePressed", "mouseReleased"):
            self.call(ws, "Input.dispatchMouseEvent", type=kind, x=x, y=y, button="left",
                      clickCount=1)
        return True

    def screenshot(self, ws: ClientConnection, path: Path) -> int:
        self.call(ws, "Page.bringToFront")
        data = self.call(ws, "Page.captureScreenshot", format="png")["data"]
        path.parent.mkdir(parents=True, exist_ok=True)
        raw = base64.b64decode(data)
        path.write_bytes(raw)
        return len(raw)

    def close(self) -> None:
        for ws in self.pages:
            with contextlib.suppress(Exception):
                ws.close()
        if self.proc.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(self.proc.pid, 15)
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(self.proc.pid, 9)
                self.proc.wait(timeout=5)
        self.log.close()
        shutil.rmtree(self.profile, ignore_errors=True)

    def __enter__(self) -> Browser:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()
