"""Screenshot of a page in headless Chromium via the DevTools protocol, after waiting real seconds.

The Rerun web viewer is a wasm app that needs real time to start; `chromium --screenshot` with virtual
time captures only its loading screen (the wasm viewer needs real seconds to start). Outbound DNS is
blocked (the viewer's fonts/analytics requests fail harmlessly); software WebGL via SwiftShader.
"""

from __future__ import annotations

import base64
import json
import shutil
import socket
import subprocess
import tempfile
import time
import urllib.request
from pathlib import Path

import websocket

FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--enable-unsafe-swiftshader", "--disable-quic",
         "--no-first-run", "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--window-size=1100,700", "--host-resolver-rules=MAP * ~NOTFOUND , EXCLUDE 127.0.0.1"]


def chromium() -> str | None:
    return shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def screenshot(url: str, out: Path, wait_s: float) -> list[str]:
    """Open `url`, wait `wait_s` real seconds, save a PNG of the page to `out`; the console messages.

    A software-rendered viewer busy with a fast live stream can take a minute to produce the frame to capture.
    """
    port, profile = free_port(), tempfile.mkdtemp(prefix="tofd-chromium-")
    proc = subprocess.Popen([chromium(), *FLAGS, f"--user-data-dir={profile}", f"--remote-debugging-port={port}",
                             "about:blank"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        tabs = None
        for _ in range(200):
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{port}/json", timeout=1) as resp:
                    tabs = json.load(resp)
                break
            except OSError:
                time.sleep(0.1)
        if tabs is None:
            raise RuntimeError("chromium's DevTools endpoint did not come up")
        page = next(t for t in tabs if t["type"] == "page")
        # no Origin header: Chromium refuses DevTools connections from an origin not allowed by a flag
        ws = websocket.create_connection(page["webSocketDebuggerUrl"], timeout=60, suppress_origin=True)
        events: list[dict] = []
        counter = iter(range(1, 1 << 30))

        def call(method: str, **params: object) -> dict:
            mid = next(counter)
            ws.send(json.dumps({"id": mid, "method": method, "params": params}))
            while True:
                msg = json.loads(ws.recv())
                if msg.get("id") == mid:
                    return msg.get("result", msg)
                events.append(msg)

        call("Runtime.enable")
        call("Page.enable")
        call("Page.navigate", url=url)
        end = time.monotonic() + wait_s
        ws.settimeout(0.5)
        while time.monotonic() < end:
            try:
                events.append(json.loads(ws.recv()))
            except websocket.WebSocketTimeoutException:
                pass
        ws.settimeout(60)
        shot = call("Page.captureScreenshot", format="png", optimizeForSpeed=True)
        out.write_bytes(base64.b64decode(shot["data"]))
        ws.close()
        return [" ".join(str(a.get("value", a.get("description", "")))[:200] for a in e["params"]["args"])
                for e in events if e.get("method") == "Runtime.consoleAPICalled"]
    finally:
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
        shutil.rmtree(profile, ignore_errors=True)
