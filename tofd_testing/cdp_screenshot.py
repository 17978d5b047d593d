"""Screenshots of a page in headless Chromium via the DevTools protocol, taken until one shows what a test waits for.

The Rerun web viewer is a wasm app that needs real time to start; `chromium --screenshot` with virtual
time captures only its loading screen (the wasm viewer needs real seconds to start). Outbound DNS is
blocked (the viewer's fonts/analytics requests fail harmlessly); software WebGL via SwiftShader. The Runtime
domain stays disabled: reporting every console message of the viewer to the client slows its start-up many times.
"""

from __future__ import annotations

import base64
import io
import json
import shutil
import socket
import subprocess
import tempfile
import time
import urllib.request
from collections.abc import Callable
from pathlib import Path

import numpy as np
import websocket
from PIL import Image

FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--enable-unsafe-swiftshader", "--disable-quic",
         "--no-first-run", "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--window-size=1100,700", "--host-resolver-rules=MAP * ~NOTFOUND , EXCLUDE 127.0.0.1"]


def chromium() -> str | None:
    return shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def screenshot(url: str, out: Path, shows: Callable[[np.ndarray], bool], timeout_s: float,
               every_s: float = 2.0) -> str:
    """Open `url` and take a screenshot every `every_s` seconds until `shows(rgb (H, W, 3) uint8)` is true or
    `timeout_s` passed (a guard against hangs, not a speed check); the last one is saved as a PNG to `out`.
    Returns the page's visible text then (what a failing test shows)."""
    port, profile = free_port(), tempfile.mkdtemp(prefix="tofd-chromium-")
    proc = subprocess.Popen([chromium(), *FLAGS, f"--user-data-dir={profile}", f"--remote-debugging-port={port}",
                             "about:blank"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        tabs = None
        for _ in range(600):
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{port}/json", timeout=1) as resp:
                    tabs = json.load(resp)
                break
            except OSError:
                time.sleep(0.1)
        if tabs is None:
            raise RuntimeError("chromium's DevTools endpoint did not come up")
        page = next(t for t in tabs if t["type"] == "page")
        # no Origin header: Chromium refuses DevTools connections from origins not named by --remote-allow-origins
        ws = websocket.create_connection(page["webSocketDebuggerUrl"], timeout=120, suppress_origin=True)
        counter = iter(range(1, 1 << 30))

        def call(method: str, **params: object) -> dict:
            mid = next(counter)
            ws.send(json.dumps({"id": mid, "method": method, "params": params}))
            while True:
                msg = json.loads(ws.recv())
                if msg.get("id") == mid:
                    return msg.get("result", msg)

        call("Page.enable")
        call("Page.navigate", url=url)
        deadline = time.monotonic() + timeout_s
        while True:
            shot = call("Page.captureScreenshot", format="png", optimizeForSpeed=True)
            if "data" in shot:  # else an error while the page changes its renderer: try again
                png = base64.b64decode(shot["data"])
                if shows(np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))) or time.monotonic() > deadline:
                    break
            elif time.monotonic() > deadline:
                raise RuntimeError(f"no screenshot of {url}: {shot}")
            time.sleep(every_s)
        out.write_bytes(png)
        text = call("Runtime.evaluate", expression="document.body ? document.body.innerText : ''")
        ws.close()
        return str(text.get("result", {}).get("value", text))[-500:]
    finally:
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
        shutil.rmtree(profile, ignore_errors=True)
