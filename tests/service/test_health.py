"""/healthz and /metrics scraped over a real socket from a running pipeline; sd_notify over a real socket."""

import json
import re
import socket
import time
import urllib.error
import urllib.request

import pytest

from tofd.config import Config, config_digest
from tofd.service.health import HealthServer, ServiceMetrics, notify_status, sd_notify, watchdog_interval_s
from tofd.service.pipeline import Pipeline
from tofd.service.pipeline.monitor import PipelineSnapshot
from tofd_testing.pipeline_sources import RenderedSource


def get(url):
    try:
        with urllib.request.urlopen(url, timeout=5) as resp:
            return resp.status, resp.read().decode()
    except urllib.error.HTTPError as exc:
        return exc.code, exc.read().decode()


def metric_values(text, name):
    """{label string: value} of one metric in Prometheus text format."""
    return {m.group(1) or "": float(m.group(2)) for m in re.finditer(rf"^{name}(\{{[^}}]*\}})? (\S+)$", text, re.M)}


@pytest.mark.slow
def test_metrics_and_healthz_of_a_live_run():
    cfg = Config()
    snapshot = []  # the pipeline's, once it exists (the metrics come first: they are one of its sinks)
    metrics = ServiceMetrics(lambda: snapshot[0](), {"model_sha256": "ab" * 32, "config_sha256": config_digest(cfg)})
    pipeline = Pipeline(cfg, "latest", writers=(metrics.observe,))
    snapshot.append(pipeline.snapshot)
    server = HealthServer("127.0.0.1", 0, pipeline.snapshot, lambda: pipeline.running, stale_after_s=2.0,
                          metrics=metrics).start()
    try:
        assert server.bind == "127.0.0.1"
        pipeline.start(RenderedSource(300, fps=30, n_distinct=3))
        deadline = time.monotonic() + 30
        while pipeline.ledger.frames_out < 20 and time.monotonic() < deadline:
            time.sleep(0.05)
        base = f"http://127.0.0.1:{server.port}"
        code, body = get(base + "/healthz")
        assert code == 200 and json.loads(body)["status"] == "ok"
        code, text = get(base + "/metrics")
        assert code == 200
        assert metric_values(text, "tofd_frames_in_total")[""] >= 20
        assert metric_values(text, "tofd_fps")[""] > 0
        stages = metric_values(text, "tofd_stage_duration_rolling_seconds")
        for stage in ("segmentation", "fft", "nfft", "latency"):
            p50, p99 = stages[f'{{quantile="0.5",stage="{stage}"}}'], stages[f'{{quantile="0.99",stage="{stage}"}}']
            assert 0 < p50 <= p99
        assert "# TYPE tofd_stage_duration_seconds histogram" in text
        for stage in ("segmentation", "nfft"):
            count = metric_values(text, "tofd_stage_duration_seconds_count")[f'{{stage="{stage}"}}']
            inf = metric_values(text, "tofd_stage_duration_seconds_bucket")[f'{{le="+Inf",stage="{stage}"}}']
            assert count == inf >= 20 and metric_values(text, "tofd_stage_duration_seconds_sum")[
                f'{{stage="{stage}"}}'] > 0
        build = next(iter(metric_values(text, "tofd_build_info")))
        assert 'version="0.1.0"' in build and f'config_sha256="{config_digest(cfg)}"' in build
        assert metric_values(text, "process_resident_memory_bytes")[""] > 1e6
        head = urllib.request.urlopen(urllib.request.Request(base + "/healthz", method="HEAD"), timeout=5)
        assert head.status == 200 and head.read() == b"" and int(head.headers["Content-Length"]) > 0
        assert set(metric_values(text, "tofd_queue_depth")) == {'{queue="dispatch"}', '{queue="workers"}',
                                                               '{queue="reorder"}', '{queue="sink"}'}
        assert metric_values(text, "tofd_workers_alive")[""] == cfg.pipeline.workers
        assert "# TYPE tofd_frames_dropped_total counter" in text
        assert get(base + "/nope")[0] == 404
        pipeline.stop()
        assert pipeline.wait(30)
        code, body = get(base + "/healthz")
        assert code == 503 and "not running" in body
    finally:
        pipeline.close()
        server.close()


def test_sd_notify_reaches_a_unix_datagram_socket(tmp_path, monkeypatch):
    path = tmp_path / "notify.sock"
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as sock:
        sock.bind(str(path))
        sock.settimeout(2)
        monkeypatch.setenv("NOTIFY_SOCKET", str(path))
        assert sd_notify("READY=1")
        assert sock.recv(100) == b"READY=1"
        snap = PipelineSnapshot(
            frames_in=125, frames_out=120, frames_dropped=5,
            drops={("dispatch", "superseded"): 4, ("sink", "superseded"): 0, ("capture", "invalid"): 1},
            viewer_drops={}, gaps=0, fps=29.96, timings_ms={}, queue_depth={}, workers_alive=2, worker_restarts=0,
            device_events={}, last_delivery_age_s=0.1, error=None, track=None)
        assert notify_status(snap)
        assert sock.recv(200) == b"STATUS=30.0 fps, 120 frames delivered, 5 dropped (invalid 1, superseded 4)"
    monkeypatch.delenv("NOTIFY_SOCKET")
    assert not sd_notify("READY=1")


def test_watchdog_interval_is_half_of_watchdog_usec(monkeypatch):
    monkeypatch.setenv("WATCHDOG_USEC", "3000000")
    monkeypatch.delenv("WATCHDOG_PID", raising=False)
    assert watchdog_interval_s() == 1.5
    monkeypatch.setenv("WATCHDOG_PID", "1")  # meant for another process
    assert watchdog_interval_s() is None


def test_healthz_says_starting_with_503_until_the_first_frame():
    pipeline = Pipeline(Config(), "latest")
    server = HealthServer("127.0.0.1", 0, pipeline.snapshot, lambda: True, stale_after_s=2.0).start()
    try:
        code, body = get(f"http://127.0.0.1:{server.port}/healthz")
        assert code == 503 and json.loads(body)["status"] == "starting", body
    finally:
        pipeline.close()
        server.close()
