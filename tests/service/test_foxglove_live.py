"""The live Foxglove sink through real processes and sockets: `tofd replay/run --foxglove` serve the Foxglove
WebSocket protocol on loopback; a plain WebSocket client (foxglove_client.py) subscribes, decodes and checks."""

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import psutil
import pytest

from tests.service.test_track_reporting import result
from tofd.config import Config, ConfigError
from tofd.drivers.recording.reader import read_recording_info
from tofd.drivers.recording.replay import iter_frames
from tofd.service.foxglove import topics as t
from tofd.service.foxglove.spec import parse_foxglove_spec
from tofd.service.viewer.encoding import unpng
from tofd.service.viewer.pixels import cloud_pixels
from tofd_testing.foxglove_client import SUBPROTOCOL, Client, wait_for_url
from tofd_testing.pipeline_sources import PATIENT_VIEWER, write_config
from tofd_testing.rrd_helpers import check_amplitude

ROOT = Path(__file__).resolve().parents[2]
CLIP = ROOT / "replay_data" / "emulated_face_035_070.mcap"


def tofd(*args):
    return subprocess.Popen([sys.executable, "-m", "tofd", *map(str, args)], cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env={**os.environ, "RUST_LOG": "error"})


def by_stamp(messages):
    return {(m.timestamp.seconds, m.timestamp.nanos): m for _, m in messages}


def test_foxglove_spec_defaults_to_loopback_and_names_a_bad_value():
    cfg = parse_foxglove_spec("9000", Config())
    assert (cfg.foxglove.enabled, cfg.foxglove.bind, cfg.foxglove.port) == (True, "127.0.0.1", 9000)
    cfg = parse_foxglove_spec("0.0.0.0:0", Config())
    assert (cfg.foxglove.bind, cfg.foxglove.port) == ("0.0.0.0", 0)
    assert parse_foxglove_spec("on", Config()).foxglove.port == 8765
    assert not parse_foxglove_spec("none", cfg).foxglove.enabled
    with pytest.raises(ConfigError, match="--foxglove: 'localhost:http'"):
        parse_foxglove_spec("localhost:http", Config())


@pytest.mark.slow
def test_replay_streams_every_topic_to_a_plain_websocket_client(tmp_path):
    info = read_recording_info(CLIP)
    intr = info.intrinsics
    proc = tofd("replay", CLIP, "--out", tmp_path, "--config", write_config(tmp_path, pipeline=PATIENT_VIEWER),
                "--foxglove", "127.0.0.1:0")
    try:
        url, _ = wait_for_url(proc.stderr)
        assert url.startswith("ws://127.0.0.1:")
        client = Client(url)
        assert client.subprotocol == SUBPROTOCOL
        # the server listens once every channel is open (the range's at the first frame): a client that connects
        # at once is told of them all in its first advertisement, and no subscription of it is refused (read)
        advertised = {c["topic"]: c for c in client.channels.values()}
        assert set(advertised) == set(t.SCHEMAS)
        for topic, schemas in t.SCHEMAS.items():
            schema = advertised[topic]["schemaName"]
            assert schema in schemas.split(" | ")
            if topic in t.JSON_TOPICS:
                assert advertised[topic]["encoding"] == "json"
                continue
            assert advertised[topic]["encoding"] == "protobuf" and schema in client.schema_names(topic)
        # the SR3000's range: a PNG of its own radial codes, their unit in the channel's metadata
        assert advertised[t.RANGE]["schemaName"] == "foxglove.CompressedImage"
        range_meta = advertised[t.RANGE]["metadata"]
        assert range_meta["depth"] == "radial"
        assert float(range_meta["unit_m"]) == pytest.approx(7.4948 / 65535, rel=1e-4)  # 20 MHz
        client.subscribe()
        got = client.read(60)  # until the replay ends and the server closes
        client.close()
        err = proc.stderr.read()
        proc.wait(60)
    finally:
        proc.kill()
    assert proc.returncode == 0, err
    stem = CLIP.name.split(".")[0]
    summary = json.loads((tmp_path / f"{stem}.summary.json").read_text())
    results = {x["frame_counter"]: x for x in map(json.loads, (tmp_path / f"{stem}.results.jsonl").open())}
    assert summary["foxglove"]["exit"] == "clean"
    # every delivered frame was published or ledgered as a Foxglove drop; the client missed at most the first ones
    fox_drops = summary["viewer_dropped_by_reason"].get("foxglove_blocked", 0)
    assert summary["foxglove"]["frames"] + fox_drops == summary["frames_out"] == len(results)
    nose = got[t.NOSE]
    assert 0 < len(nose) <= summary["foxglove"]["frames"]
    # every topic came; a frame may arrive in part (published while the subscriptions were taken, or a message
    # dropped from the client's full backlog while the client lagged)
    counts = {topic: len(got[topic]) for topic in t.SCHEMAS}
    assert min(counts.values()) >= max(counts.values()) // 2, counts

    ranges = got[t.RANGE]
    for _, image in ranges:
        assert image.format == "png" and image.frame_id == t.CAMERA_FRAME
    assert [log_ns for log_ns, _ in ranges] == sorted(log_ns for log_ns, _ in ranges)
    # each range image is exactly the recorded frame's codes (the frame's counter: its nose message's metadata)
    counters = {stamp: int({kv.key: kv.value for kv in a.metadata}["frame_counter"])
                for stamp, a in by_stamp(got[t.NOSE]).items()}
    recorded = {f.frame_counter: f for f in iter_frames(CLIP)}
    unit = float(range_meta["unit_m"])
    compared = 0
    for stamp, image in list(by_stamp(ranges).items())[-5:]:
        codes = unpng(image.data)
        assert codes.dtype == np.uint16 and codes.shape == (144, 176)
        if stamp in counters:
            want = np.nan_to_num(recorded[counters[stamp]].range_m, nan=0.0) / unit
            np.testing.assert_array_equal(codes, np.rint(want))
            assert np.max(np.abs(codes - want)) < 0.01  # whole codes: the source's own
            compared += 1
    assert compared
    assert 0.2 < unit * codes[codes > 0].min() < unit * codes.max() < 3.0  # metres
    # the amplitude for viewing: a JPEG of the recorded amplitude's 8-bit levels at the scale sent beside it
    scales = {(m["timestamp"]["sec"], m["timestamp"]["nsec"]): m["units_per_level"] for _, m in got[t.AMPLITUDE_SCALE]}
    shown = 0
    for stamp, image in by_stamp(got[t.AMPLITUDE]).items():
        assert image.format == "jpeg" and image.frame_id == t.CAMERA_FRAME
        if stamp in counters and stamp in scales:
            check_amplitude(unpng(image.data), scales[stamp], recorded[counters[stamp]].amplitude)
            shown += 1
    assert shown

    calibration = got[t.CALIBRATION][-1][1]
    assert list(calibration.K) == pytest.approx([intr.fx, 0, intr.cx, 0, intr.fy, intr.cy, 0, 0, 1])
    assert (calibration.width, calibration.height, calibration.frame_id) == (176, 144, t.CAMERA_FRAME)

    checked = 0
    for _, annotations in nose:
        counter = int({kv.key: kv.value for kv in annotations.metadata}["frame_counter"])
        want = results[counter]["tip_px"] or results[counter]["nose_px"]  # the tip where it was refined
        if want is None:
            assert not annotations.points
            continue
        (point,) = annotations.points[0].points  # Foxglove's origin: the top-left pixel's corner
        assert (point.x, point.y) == pytest.approx((want[0] + 0.5, want[1] + 0.5), abs=0.006)  # results: 2 decimals
        checked += 1
    assert checked > 0
    tracked = [a for _, a in got[t.NOSE_TRACK] if a.points]
    assert tracked and all(len(a.points[0].points) == 4 and a.texts[0].text.startswith("track ") for a in tracked)

    # the foreground cloud of a frame has one point per mask pixel, in front of the camera, with its eps0
    masks, clouds = by_stamp(got[t.MASK]), by_stamp(got[t.FOREGROUND])
    both = sorted(set(masks) & set(clouds))  # a frame's messages share its timestamp
    assert len(both) >= len(clouds) // 2
    for stamp, cloud in [(s, clouds[s]) for s in both[-5:]]:
        assert [f.name for f in cloud.fields] == ["x", "y", "z", "eps0"] and cloud.point_stride == 16
        points = np.frombuffer(cloud.data, "<f4").reshape(-1, 4)
        assert len(points) == len(cloud_pixels(unpng(masks[stamp].data) > 0))
        assert np.all(points[:, 2] > 0.2) and np.all(points[:, 3] >= 0)
    transform = got[t.TRANSFORM][-1][1]
    assert (transform.parent_frame_id, transform.child_frame_id) == (t.WORLD_FRAME, t.CAMERA_FRAME)
    q = transform.rotation
    assert [q.x, q.y, q.z, q.w] == list(t.OPTICAL_IN_WORLD)
    # the feature maps: 8-bit crops of the foreground's box, placed and scaled by the box message of their frame
    boxes = {(m["timestamp"]["sec"], m["timestamp"]["nsec"]): m for _, m in got[t.FEATURE_BOX]}
    placed = 0
    for topic in t.FEATURES.values():
        for stamp, image in by_stamp(got[topic]).items():
            feature = unpng(image.data)
            assert image.format == "png" and feature.dtype == np.uint8
            if stamp in boxes and stamp in masks and boxes[stamp]["top"][topic] > 0:
                box, mask = boxes[stamp], unpng(masks[stamp].data) > 0
                rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
                assert (box["x"], box["y"], box["width"], box["height"]) == (
                    cols[0], rows[0], cols[-1] - cols[0] + 1, rows[-1] - rows[0] + 1)
                assert feature.shape == (box["height"], box["width"]) and feature.max() == 255
                inside = mask[box["y"]: box["y"] + box["height"], box["x"]: box["x"] + box["width"]]
                assert not feature[~inside].any()  # 0 outside the foreground
                placed += 1
    assert placed


def server_fds(proc: subprocess.Popen, url: str) -> int:
    """Open file descriptors of the child of the tofd process that listens on `url`'s port (the server)."""
    port = int(url.rsplit(":", 1)[1])
    (server,) = [c for c in psutil.Process(proc.pid).children()
                 if any(conn.laddr.port == port and conn.status == psutil.CONN_LISTEN
                        for conn in c.net_connections("tcp"))]
    return server.num_fds()


@pytest.mark.slow
def test_a_stalled_client_and_fifty_connections_cost_the_pipeline_nothing(tmp_path):
    summary_path = tmp_path / "summary.json"
    proc = tofd("run", "--emulate", "--config", write_config(tmp_path), "--foxglove", "127.0.0.1:0",
                "--health-port", "0", "--summary", summary_path)
    try:
        url, _ = wait_for_url(proc.stderr)
        stalled = Client(url)
        stalled.ws.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        stalled.subscribe()  # every channel (all advertised at connection), and never reads again
        first = Client(url)
        first.subscribe([t.RANGE])
        assert first.read(30, until=lambda got: len(got.get(t.RANGE, [])) >= 10)[t.RANGE]
        first.close()
        fds_before = server_fds(proc, url)
        for _ in range(50):
            c = Client(url)
            c.subscribe()
            c.read(0.05)
            c.close()
        time.sleep(1.0)  # the server notices the closes
        assert server_fds(proc, url) <= fds_before + 2  # the 50 connections left nothing behind
        reader = Client(url)
        reader.subscribe([t.RANGE, t.NOSE])
        got = reader.read(30, until=lambda got: len(got.get(t.NOSE, [])) >= 30)
        counters = [int(a.metadata[0].value) for _, a in got[t.NOSE]]
        assert len(counters) >= 30 and counters == sorted(counters)  # live frames keep coming, in order
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=60)
        reader.close()
        stalled.close()
    finally:
        proc.kill()
    assert proc.returncode == 0, err
    summary = json.loads(summary_path.read_text())
    assert summary["consistent"] and summary["error"] is None
    fox_drops = summary["viewer_dropped_by_reason"].get("foxglove_blocked", 0)
    assert fox_drops < summary["frames_out"] / 2  # the viewer process kept up; the stalled client lost its own
    if summary["foxglove"]["exit"] == "clean":
        assert summary["foxglove"]["frames"] + fox_drops == summary["frames_out"]
    else:  # the SDK's stop waits for the stalled client's closing handshake: the process is killed on time
        assert summary["foxglove"]["exit"] == "killed"
        assert any("foxglove" in part for part in summary["shutdown"]["abandoned"])


@pytest.mark.slow
def test_a_port_in_use_is_a_config_error_naming_the_key(tmp_path):
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        run = subprocess.run([sys.executable, "-m", "tofd", "run", "--emulate", "--frames", "5", "--health-port", "0",
                              "--config", write_config(tmp_path), "--foxglove", str(port)], cwd=ROOT,
                             capture_output=True, text=True, timeout=300)
    assert run.returncode == 2, run.stderr
    assert run.stderr.strip().splitlines()[-1] == (f"tofd run: config error: foxglove.port: port {port} on 127.0.0.1 "
                                                   "is already in use (--foxglove HOST:PORT)")


def test_the_foxglove_viewer_process_does_not_load_the_rerun_sdk():
    """The viewer host and the Foxglove publisher import no Rerun module: rerun-sdk stays out of that process."""
    from dataclasses import replace

    from tofd.service.viewer.process import ViewerProcess
    from tofd_testing.pipeline_sources import ModulesReportingFoxglove

    cfg = Config()
    cfg = replace(cfg, foxglove=replace(cfg.foxglove, enabled=True, port=0))
    viewer = ViewerProcess(cfg, "foxglove", open_backend=ModulesReportingFoxglove, name="foxglove")
    try:
        assert viewer.process.is_alive() and viewer.web_url is not None
        assert json.loads(viewer.web_url) == []
    finally:
        viewer.close(10.0)


@pytest.mark.slow
def test_a_replay_on_a_busy_port_fails_before_touching_the_previous_runs_outputs(tmp_path):
    clip = ROOT / "tests" / "data" / "v1_first3.mcap"
    out = tmp_path / "out"
    first = subprocess.run([sys.executable, "-m", "tofd", "replay", str(clip), "--out", str(out), "--config",
                            write_config(tmp_path, pipeline=PATIENT_VIEWER)], cwd=ROOT, capture_output=True,
                           text=True, timeout=300)
    assert first.returncode == 0, first.stderr
    before = {p.name: (p.read_bytes(), p.stat().st_mtime_ns) for p in out.iterdir()}
    assert {"v1_first3.rrd", "v1_first3.results.jsonl", "v1_first3.summary.json"} <= set(before)
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        again = subprocess.run([sys.executable, "-m", "tofd", "replay", str(clip), "--out", str(out), "--config",
                                write_config(tmp_path, pipeline=PATIENT_VIEWER), "--foxglove", f"127.0.0.1:{port}"],
                               cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert again.returncode == 2 and "Traceback" not in again.stderr, again.stderr
    assert again.stderr.strip().splitlines()[-1].endswith(f"port {port} on 127.0.0.1 is already in use "
                                                          "(--foxglove HOST:PORT)"), again.stderr
    assert {p.name: (p.read_bytes(), p.stat().st_mtime_ns) for p in out.iterdir()} == before


def test_a_clients_bad_request_makes_a_few_prefixed_log_lines_not_one_per_item():
    """A client subscribing 1000 times to a channel that does not exist: the SDK warns per subscription; tofd's log
    (the root logger's handlers) gets at most LimitedLines' burst of them, each saying it is the foxglove SDK's."""
    import logging

    from tofd.service.foxglove.publisher import FoxglovePublisher

    class Lines(logging.Handler):
        def __init__(self) -> None:
            super().__init__()
            self.lines: list[str] = []

        def emit(self, record: logging.LogRecord) -> None:
            self.lines.append(record.getMessage())

    tofd_log = Lines()
    logging.getLogger().addHandler(tofd_log)
    publisher = FoxglovePublisher(parse_foxglove_spec("127.0.0.1:0", Config()))
    try:
        publisher(result(0, None, None))  # the server listens from the first frame on
        client = Client(publisher.web_url)
        client.ws.send(json.dumps({"op": "subscribe",
                                   "subscriptions": [{"id": i, "channelId": 9999} for i in range(1000)]}))
        client.read(1.0)  # the server has handled the request
        client.close()
    finally:
        publisher.close(1.0)
        logging.getLogger().removeHandler(tofd_log)
    lines = [line for line in tofd_log.lines if "9999" in line]
    assert 1 <= len(lines) <= 5, lines
    assert all(line.startswith("foxglove SDK: ") for line in lines)


def test_limited_lines_lets_a_burst_through_per_interval_and_counts_the_rest():
    import logging

    from tofd.logs import LimitedLines

    limited = LimitedLines("lib: ", burst=2, interval_s=0.2)
    records = [logging.LogRecord("lib", logging.WARNING, __file__, 1, "item %d", (i,), None) for i in range(6)]
    passed = [r.getMessage() for r in records[:5] if limited.filter(r)]
    assert passed == ["lib: item 0", "lib: item 1"]
    time.sleep(0.25)  # a new interval: its first line says how many were left out
    assert limited.filter(records[5])
    assert records[5].getMessage() == "lib: item 5 (3 more lines left out before this one)"


def test_a_port_in_use_or_an_address_not_here_is_refused_at_start_not_at_the_first_frame():
    from tofd.service.foxglove.publisher import FoxglovePublisher

    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        with pytest.raises(RuntimeError, match=rf"cannot listen on 127.0.0.1:{port} \(foxglove.bind / foxglove.port\)"):
            FoxglovePublisher(parse_foxglove_spec(f"127.0.0.1:{port}", Config()))
    with pytest.raises(RuntimeError, match=r"cannot listen on 192.0.2.1:0"):  # TEST-NET-1: no host's own address
        FoxglovePublisher(parse_foxglove_spec("192.0.2.1:0", Config()))


def test_the_servers_connections_send_without_delay():
    """foxglove-sdk's server leaves Nagle's algorithm on; tofd turns it off on the listening socket, which the
    connections it accepts inherit: a frame's last small messages do not wait for the client's delayed ACK."""
    from tofd.service.foxglove.publisher import FoxglovePublisher, tcp_sockets

    publisher = FoxglovePublisher(parse_foxglove_spec("127.0.0.1:0", Config()))
    port = int(publisher.web_url.rsplit(":", 1)[1])
    try:
        publisher(result(0, None, None))  # the server listens from the first frame on
        client = Client(publisher.web_url)
        # this process's TCP sockets on the server's port: (listening, TCP_NODELAY) of the listener and of the
        # connection it accepted (the client's own socket has the port as its peer, not as its name)
        nodelay = [(bool(sock.getsockopt(socket.SOL_SOCKET, socket.SO_ACCEPTCONN)),
                    sock.getsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY))
                   for sock in tcp_sockets() if sock.getsockname()[1] == port]
        client.close()
    finally:
        publisher.close(1.0)
    assert sorted(nodelay) == [(False, 1), (True, 1)], nodelay  # the client's connection and the listener
