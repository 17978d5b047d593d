"""The web viewer on a live `tofd run --emulate --rerun web`, opened at the address the README gives (the same
address serves a saved .rrd through `rerun --serve-web`), rendered in headless Chromium and screenshotted."""

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from tofd.service.viewer.blueprint import COLUMN_SHARES
from tofd_testing.cdp_screenshot import chromium, free_port, screenshot
from tofd_testing.pipeline_sources import write_config

ROOT = Path(__file__).resolve().parents[2]
pytestmark = [pytest.mark.browser, pytest.mark.slow,
              pytest.mark.skipif(chromium() is None, reason="chromium is not installed (apt-get install -y chromium)")]


def listening_addresses(port: int) -> set[str]:
    """Local addresses of the TCP sockets listening on `port` (from /proc/net/tcp and tcp6)."""
    found = set()
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        for line in Path(table).read_text().splitlines()[1:]:
            local, state = line.split()[1], line.split()[3]
            addr, port_hex = local.split(":")
            if state == "0A" and int(port_hex, 16) == port:
                found.add(addr)
    return found


def colour_variety(img: np.ndarray) -> int:
    """Distinct colours after quantising each channel to 16 levels."""
    q = (img[..., :3] // 16).astype(np.int32)
    return len(np.unique(q[..., 0] * 256 + q[..., 1] * 16 + q[..., 2]))


def thirds_variety(img: np.ndarray) -> list[int]:
    """colour_variety of the left, middle and right thirds of the page below its top bar and above its bottom.

    The loading screen / an empty viewer is a few flat colours; views with a turbo range image, a red mask,
    viridis feature maps and a coloured point cloud are not."""
    h, w, _ = img.shape
    body = img[60:h - 60]
    return [colour_variety(t) for t in (body[:, : w // 3], body[:, w // 3: 2 * w // 3], body[:, 2 * w // 3:])]


def feature_maps_variety(img: np.ndarray) -> int:
    """colour_variety of the feature maps' column (blueprint.COLUMN_SHARES) below the page's top bar: viridis maps,
    or (as when Rerun's viewer would not play the maps' images) grey panels and loading dots, about 20."""
    h, w, _ = img.shape
    left, width, total = COLUMN_SHARES[0], COLUMN_SHARES[1], sum(COLUMN_SHARES)
    return colour_variety(img[60:h - 60, w * left // total: w * (left + width) // total])


def views_shown(img: np.ndarray) -> bool:
    return min(thirds_variety(img)) >= 40 and feature_maps_variety(img) >= 40


def readme_viewer_url() -> str:
    """The viewer address the README gives (web viewer on port 9090, recording served on 9876)."""
    text = (ROOT / "README.md").read_text()
    (url,) = set(re.findall(r"http://127\.0\.0\.1:9090/\?url=\S+?(?=[\s)])", text))
    return url


def test_web_viewer_shows_the_views_of_a_live_run(tmp_path):
    grpc_port, web_port = free_port(), free_port()
    # a slower camera (INT_TIME code 255: ~4.7 fps) and one worker leave CPU for the software-rendered viewer
    config = write_config(tmp_path, rerun={"sink": "web", "grpc_port": grpc_port, "web_port": web_port},
                          camera={"int_time_code": 255}, pipeline={"workers": 1})
    proc = subprocess.Popen([sys.executable, "-m", "tofd", "run", "--emulate", "--config", str(config),
                             "--health-port", "0"], cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            text=True, env={**os.environ, "RUST_LOG": "error"})
    try:
        deadline = time.monotonic() + 180  # a guard against hangs (tofd and rerun start in seconds)
        while not listening_addresses(web_port) and time.monotonic() < deadline:
            assert proc.poll() is None, proc.stderr.read()
            time.sleep(0.2)
        # served on 127.0.0.1 only (0100007F in /proc/net/tcp), nothing on other interfaces
        assert listening_addresses(web_port) == {"0100007F"}
        assert listening_addresses(grpc_port) == {"0100007F"}
        url = readme_viewer_url().replace(":9090/", f":{web_port}/").replace(":9876/", f":{grpc_port}/")
        png = tmp_path / "viewer.png"
        page_text = screenshot(url, png, views_shown, timeout_s=300)
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            _, err = proc.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()
            raise
    assert proc.returncode == 0, err
    img = np.asarray(Image.open(png).convert("RGB"))
    assert views_shown(img), (thirds_variety(img), feature_maps_variety(img), url, str(png), page_text)
