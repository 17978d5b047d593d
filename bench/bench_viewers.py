"""Viewer data rates: bytes per frame and MB/s per view of the Rerun .rrd and of the Foxglove stream, per camera, and
the replay rate with and without each viewer, from one run.

    python bench/bench_viewers.py                      # sr3000 (the bundled clip) and 640x576
    python bench/bench_viewers.py --replay-frames 300 --runs 3 --live-seconds 10 --live-runs 3

Per camera (bench/cameras.py): the SR3000's bundled clip (replay_data/emulated_face_035_070.mcap) and a clip of the
emulator's face rendered in the Azure Kinect NFOV geometry (640x576) as a millimetre camera delivers it (z-depth in
whole mm, amplitude in whole units), once per --conditions sensor model (bench/cameras.SENSOR_MODELS: the training
sensor's noise, which grows as the amplitude falls, SR3000-like; a constant 4 mm; and the training sensor's noise at
most the Azure Kinect's specified random error, 17 mm, as a millimetre camera within its operating range gives it):
lossless PNG shrinks a plane to about its noise's entropy, so the sizes follow the noise (each row's range_noise_mm).
Lossless replay of --replay-frames frames (the clip looped) through the real
pipeline, --runs times each of: no viewer, the daemon's Rerun viewer process saving an .rrd (batched, as a replay
does), and the Foxglove viewer process with one client subscribed to every channel (reading as fast as it can); runs
interleaved, fps is the median run's, ratios against no viewer in the same run. The .rrd of the last Rerun run gives
bytes per frame on disk (Rerun's LZ4 chunks), per view the bytes on disk of its chunks written alone by Rerun's writer,
and the bytes its rows hold (an encoded image's PNG, a raw image's pixels, the points) before that compression.
Then --live-seconds of the clip replayed in real time (30 fps, looped, latest-wins, bench/cameras.MemoryCamera) with
the Foxglove viewer and a client subscribed to every channel: bytes per message and MB/s received per topic; then
--live-runs times as long with both viewers on (Rerun sent each frame at once, as to a live viewer): frames delivered
per second, capture to the Rerun viewer process's send and to the Foxglove client's receipt of a frame's last
message, median and p99, each run (live_both_viewers; a 2-core machine's p99 varies by tens of ms between runs).
Rerun's live rate is its bytes per frame times 30 fps; with the default rotation budget
([rerun] rotate_mb x (keep_files + 1): 2000 MB x 25 segments, the most a live .rrd takes on disk), the hours of
recording that budget keeps; and per camera the least bytes a lossless coder predicting from the left neighbour gets
the first frame's depth and amplitude to (the entropy of their row differences). Prints tables,
writes bench/results/bench_viewers.json.
"""

from __future__ import annotations

import argparse
import concurrent.futures
import json
import os
import platform
import struct
import tempfile
import threading
import time
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import websocket
from bench_pipeline import CLIP, Latencies, one_rrd, with_detector
from cameras import CAMERAS, FRAME_PERIOD_US, SENSOR_MODELS, MemoryCamera, range_noise_mm, write_face_clip
from report import run_to_end, write_json

from tofd.config import RerunConfig, load_config
from tofd.drivers.recording.replay import ReplaySource
from tofd.lab.conditions import TRAIN_CONDITION
from tofd.process_setup import prepare_service_process
from tofd.service.foxglove.publisher import FoxglovePublisher
from tofd.service.model import load_service_model
from tofd.service.pipeline import Pipeline, maps_read
from tofd.service.viewer import blueprint as bp
from tofd.service.viewer.encoding import (
    amplitude_u8,
    amplitude_u16,
    in_units,
    jpeg,
    source_unit_m,
    z_depth_m,
)
from tofd.service.viewer.encoding import png as tofd_png
from tofd.service.viewer.logger import LATENCY, LOGGING, frames_per_send
from tofd.service.viewer.process import ViewerProcess, hand_off_frames
from tofd.service.viewer.targets import file_footer
from tofd_testing.foxglove_client import MESSAGE_DATA, connect, refused_channel

KINDS = ("none", "rerun", "foxglove")
LIVE_FPS = 1e6 / FRAME_PERIOD_US
CONNECT_TIMEOUT_S = 60.0  # the Foxglove server listens from the pipeline's first frame on
ROTATE_MB, KEEP_FILES = RerunConfig().rotate_mb, RerunConfig().keep_files  # the default [rerun] rotation


class CountingClient:
    """A Foxglove WebSocket client on a thread: it connects (once the server listens), subscribes to every channel
    (advertised now or later) and counts the messages and payload bytes it receives per topic; `refused` counts
    subscriptions the server refused to channels it advertised."""

    def __init__(self, url: str):
        self.url = url
        self.ws: websocket.WebSocket | None = None
        self.connected = threading.Event()
        self.refused = 0
        self.topics: dict[int, str] = {}  # channel id -> topic
        self._subscriptions: dict[int, str] = {}  # subscription id -> topic
        self.messages: dict[str, int] = {}
        self.bytes: dict[str, int] = {}
        self.received_ns: dict[int, int] = {}  # a frame's log time (its capture, host wall clock) -> last receipt
        self.started_s = time.monotonic()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._read, name="counting-client", daemon=True)
        self._thread.start()

    def _read(self) -> None:
        self.ws = ws = connect(self.url, CONNECT_TIMEOUT_S)
        ws.settimeout(0.5)
        self.connected.set()
        while not self._stop.is_set():
            try:
                data = ws.recv()
            except websocket.WebSocketTimeoutException:
                continue
            except (websocket.WebSocketConnectionClosedException, ConnectionError, OSError):
                return
            if isinstance(data, str):
                msg = json.loads(data)
                if msg.get("op") == "advertise":
                    fresh = {c["id"]: c["topic"] for c in msg["channels"]}
                    self.topics.update(fresh)
                    self._subscribe(list(fresh))
                self.refused += refused_channel(msg) in self.topics
            elif data and data[0] == MESSAGE_DATA:
                topic = self._subscriptions[struct.unpack_from("<I", data, 1)[0]]
                self.received_ns[struct.unpack_from("<Q", data, 5)[0]] = time.time_ns()
                self.messages[topic] = self.messages.get(topic, 0) + 1
                self.bytes[topic] = self.bytes.get(topic, 0) + len(data) - 13

    def _subscribe(self, channels: list[int]) -> None:
        """Subscribe to `channels`, each under a new subscription id."""
        subscriptions = []
        for channel in channels:
            self._subscriptions[len(self._subscriptions)] = self.topics[channel]
            subscriptions.append({"id": len(self._subscriptions) - 1, "channelId": channel})
        assert self.ws is not None
        self.ws.send(json.dumps({"op": "subscribe", "subscriptions": subscriptions}))

    def reset(self) -> None:
        """Count from now on (once connected: the server listens from the first frame on)."""
        if not self.connected.wait(CONNECT_TIMEOUT_S):
            raise RuntimeError(f"the Foxglove server at {self.url} did not listen in {CONNECT_TIMEOUT_S:g} s")
        self.messages, self.bytes, self.received_ns, self.started_s = {}, {}, {}, time.monotonic()

    def latencies_ms(self) -> np.ndarray:
        """Per frame received: milliseconds from its capture (the log time tofd gives every message of a frame: the
        host's wall clock when the frame arrived) to the receipt of its last message."""
        return np.array([(last - logged) / 1e6 for logged, last in self.received_ns.items()])

    def close(self) -> float:
        """Stop reading; the seconds counted."""
        seconds = time.monotonic() - self.started_s
        self._stop.set()
        self._thread.join(5)
        if self.ws is not None:
            self.ws.close()
        return seconds


def viewers(cfg, kind: str, policy: str, rrd: Path) -> tuple[ViewerProcess | None, ViewerProcess | None]:
    """The (Rerun viewer process saving `rrd`, Foxglove viewer process on a free port) of a run of `kind`."""
    rerun = foxglove = None
    if kind in ("rerun", "both"):
        sink_cfg = one_rrd(cfg, rrd)
        # both (live): each frame sent at once and handed off as to a watched viewer, not as into a file
        sends = 1 if kind == "both" else frames_per_send(sink_cfg.rerun, policy)
        rerun = ViewerProcess(sink_cfg, "save", sends, hand_off_frames(policy, "web" if kind == "both" else "save"),
                              footer=file_footer(policy))
    if kind in ("foxglove", "both"):
        fox_cfg = replace(cfg, foxglove=replace(cfg.foxglove, enabled=True, bind="127.0.0.1", port=0))
        foxglove = ViewerProcess(fox_cfg, "foxglove", queue_frames=hand_off_frames(policy, "foxglove"),
                                 open_backend=FoxglovePublisher, name="foxglove")
    return rerun, foxglove


def run(cfg, source, kind: str, policy: str, *, frames: int | None, seconds: float | None, tmp: Path) -> dict:
    """One run of `source` through the pipeline with the viewer of `kind`: fps, and the client's or the .rrd's
    counts."""
    rrd = tmp / f"{kind}-{time.monotonic_ns()}.rrd"
    viewer, foxglove = viewers(cfg, kind, policy, rrd)
    client = CountingClient(foxglove.web_url) if foxglove is not None and foxglove.web_url else None
    lat = Latencies(max(1, (frames or 300) // 10), dict)  # steady fps: after the first tenth
    pipeline = Pipeline(cfg, policy, viewer=viewer, writers=(lat,), model=load_service_model(cfg),
                        live_source=policy == "latest", live_viewers=() if foxglove is None else (foxglove,),
                        result_maps=maps_read(kind != "none"))
    pipeline.start(source, frames)
    if client is not None:
        client.reset()
    elapsed = run_to_end(pipeline, seconds)
    summary = pipeline.close()
    out: dict = {"frames_out": summary["frames_out"], "seconds": round(elapsed, 2),
                 "fps": round(lat.steady_fps() or summary["frames_out"] / elapsed, 2),
                 "frames_in": summary["frames_in"], "dropped_by_reason": summary["dropped_by_reason"],
                 "viewer_dropped": summary["viewer_dropped"]}
    if client is not None:
        counted_s = client.close()
        out["client"] = {"seconds": round(counted_s, 2), "messages": client.messages, "bytes": client.bytes,
                         "latency_ms": client.latencies_ms(), "refused_subscriptions": client.refused}
    out["viewer_reports"] = [v.close(60.0) for v in (viewer, foxglove) if v is not None]
    if viewer is not None:
        out["rrd"] = str(rrd)
    return out


def rrd_views(path: Path, frames: int) -> dict:
    """The .rrd's bytes on disk per frame; per view (entity) its bytes on disk per frame (the entity's chunks, static
    ones too, written alone to an .rrd by Rerun's own writer, with its LZ4 chunk compression, less the bytes of an
    .rrd holding no chunk) and the bytes of its rows before that compression; and the viewer process's own
    milliseconds per frame (its `logging` timing: encoding and sending)."""
    from rerun.chunk import RrdReader

    per_entity: dict[str, int] = {}
    own_ms: list[float] = []
    latency: dict[int, float] = {}  # frame -> the viewer process's latency (capture to its send to Rerun), ms
    for chunk in RrdReader(str(path)).stream().to_chunks():
        batch = chunk.to_record_batch()
        per_entity[chunk.entity_path] = per_entity.get(chunk.entity_path, 0) + (0 if chunk.is_static else batch.nbytes)
        if not chunk.is_static and chunk.entity_path == bp.TIMINGS:
            timings = batch.column("Scalars:scalars").to_pylist()
            own_ms += [row[LOGGING] for row in timings]
            latency.update(zip(batch.column("frame").to_pylist(), (row[LATENCY] for row in timings), strict=True))
    alone = path.with_suffix(".view.rrd")

    def written_alone(content: str) -> int:
        RrdReader(str(path)).stream().filter(content=content).write_rrd(alone, application_id="bench_viewers",
                                                                        recording_id="view")
        return alone.stat().st_size

    empty = written_alone("/no/such/entity")
    on_disk = {entity: written_alone(entity) - empty for entity in per_entity}
    alone.unlink()
    size = path.stat().st_size

    def per_frame(bytes_of: dict[str, int]) -> dict[str, int]:
        return {e: round(b / frames) for e, b in sorted(bytes_of.items(), key=lambda x: -x[1]) if b / frames >= 100}

    return {"file_bytes_per_frame": round(size / frames),
            "viewer_ms_per_frame": {"median": round(float(np.median(own_ms)), 2),
                                    "p90": round(float(np.percentile(own_ms, 90)), 2)} if own_ms else None,
            "views_disk_bytes_per_frame": per_frame(on_disk),
            "rest_disk_bytes_per_frame": round((size - sum(on_disk.values())) / frames),  # headers, footer index
            "views_arrow_bytes_per_frame": per_frame(per_entity),
            "latency_ms": np.array([latency[f] for f in sorted(latency)])}


def percentiles(ms: np.ndarray, skip: int) -> dict:
    """Median, p99 and max of `ms` after its first `skip` values (start-up), and how many there were."""
    kept = ms[skip:]
    if not kept.size:
        return {"frames": 0}
    return {"frames": int(kept.size), "p50": round(float(np.median(kept)), 1),
            "p99": round(float(np.percentile(kept, 99)), 1), "max": round(float(kept.max()), 1)}


def live_both(cfg, clip: Path, seconds: float, tmp: Path) -> dict:
    """`seconds` of the clip as a live camera (MemoryCamera: 30 fps, latest-wins) with both viewers on: the Rerun
    viewer process sending each frame at once (as to a live viewer; into an .rrd, from which its latencies are
    read) and the Foxglove viewer process with a client subscribed to every channel. Frames delivered per second
    and dropped; capture to Rerun (the viewer process's send to the SDK) and capture to the Foxglove client (the
    receipt of a frame's last message) in ms, after the first second."""
    live = run(cfg, MemoryCamera(clip), "both", "latest", frames=None, seconds=seconds, tmp=tmp)
    skip = round(LIVE_FPS)
    return {"seconds": live["seconds"], "frames_in": live["frames_in"], "frames_out": live["frames_out"],
            "fps_delivered": live["fps"], "dropped_by_reason": live["dropped_by_reason"],
            "viewer_dropped": live["viewer_dropped"],
            "rerun_capture_to_send_ms": percentiles(rrd_views(Path(live["rrd"]), live["frames_out"])["latency_ms"],
                                                    skip),
            "foxglove_capture_to_client_ms": percentiles(live["client"]["latency_ms"], skip)}


def delta_entropy_bytes(plane: np.ndarray) -> int:
    """Bytes of a (H, W) integer plane at the entropy of its differences along rows (bits per pixel times pixels):
    about the least a lossless coder that predicts from the left neighbour (PNG's SUB filter) gets it to."""
    _, counts = np.unique(np.diff(plane.astype(np.int64), axis=1), return_counts=True)
    p = counts / counts.sum()
    return round(float(-(p * np.log2(p)).sum()) * plane.size / 8)


def lossless_bounds(clip: Path) -> dict:
    """delta_entropy_bytes of the clip's first frame's depth (in its source's unit, when whole) and amplitude."""
    with ReplaySource(clip) as source:
        frame = next(iter(source))
    unit = source_unit_m(frame)
    z = z_depth_m(frame.range_m, frame.intrinsics.unit_rays()[..., 2].astype(np.float32))
    units = in_units(z, unit) if unit is not None else None
    return {"depth": delta_entropy_bytes(units[0]) if units is not None and units[1] else None,
            "amplitude": delta_entropy_bytes(amplitude_u16(frame.amplitude))}


STRATEGIES = {"rle": cv2.IMWRITE_PNG_STRATEGY_RLE, "default": cv2.IMWRITE_PNG_STRATEGY_DEFAULT}


def timed(encode, repeats: int = 7) -> tuple[int, float]:
    """Bytes of encode()'s output and its median milliseconds over `repeats` calls."""
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = encode()
        times.append((time.perf_counter() - t0) * 1e3)
    return len(out), round(float(np.median(times)), 2)


def encodings(clip: Path) -> dict:
    """Bytes and ms of the clip's first frame's planes in the codecs the viewers could use: the depth (its source's
    integers, when whole) as 16-bit PNG by tofd (encoding.png: Sub filter, ISA-L's deflate) and, the baseline, by
    OpenCV's libpng at zlib levels 1, 3, 6 with the run-length and default strategies; the amplitude as lossless
    16-bit PNG, 8-bit PNG and 8-bit JPEG; tofd's depth and amplitude encodings one after the other and on two
    threads (both release the GIL)."""
    with ReplaySource(clip) as source:
        frame = next(iter(source))
    out: dict = {}
    unit = source_unit_m(frame)
    z = z_depth_m(frame.range_m, frame.intrinsics.unit_rays()[..., 2].astype(np.float32))
    depth = in_units(z, unit)[0] if unit is not None else None

    def png(plane, level=1, strategy=cv2.IMWRITE_PNG_STRATEGY_RLE):
        return lambda: cv2.imencode(".png", plane, [cv2.IMWRITE_PNG_COMPRESSION, level, cv2.IMWRITE_PNG_STRATEGY,
                                                    strategy, cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_SUB])[1]

    def jpg(plane, quality):
        return lambda: cv2.imencode(".jpg", plane, [cv2.IMWRITE_JPEG_QUALITY, quality])[1]

    if depth is not None:
        out["depth png16 tofd (isal)"] = timed(lambda: tofd_png(depth))
        for level in (1, 3, 6):
            for label, strategy in STRATEGIES.items():
                out[f"depth png16 level {level} {label}"] = timed(png(depth, level, strategy))
    amp8, _ = amplitude_u8(frame.amplitude)
    out["amplitude png16 level 1 rle"] = timed(png(amplitude_u16(frame.amplitude)))
    out["amplitude png8 level 1 rle"] = timed(png(amp8))
    for quality in (75, 90, 95):
        out[f"amplitude jpeg q{quality}"] = timed(jpg(amp8, quality))
    if depth is not None:
        serial = [lambda: tofd_png(depth), lambda: jpeg(amp8)]
        with concurrent.futures.ThreadPoolExecutor(2) as pool:
            out["depth + amplitude, two threads"] = timed(
                lambda: b"".join(f.result() for f in [pool.submit(e) for e in serial]))
        out["depth + amplitude, one after the other"] = timed(lambda: b"".join(e() for e in serial))
    return {codec: {"bytes": size, "ms": ms} for codec, (size, ms) in out.items()}


def compare(cfg, name: str, condition: str, clip: Path, replay_frames: int, runs: int, live_s: float, live_runs: int,
            tmp: Path) -> dict:
    """Replay rates with each viewer, the .rrd's and the live Foxglove stream's sizes, of one camera's clip."""
    cam_cfg = replace(cfg, intrinsics=CAMERAS[name])
    each: dict[str, list[dict]] = {kind: [] for kind in KINDS}
    for _ in range(runs):
        for kind in KINDS:
            with ReplaySource(clip, loop=True) as source:
                each[kind].append(run(cam_cfg, source, kind, "lossless", frames=replay_frames, seconds=None, tmp=tmp))
    fps = {kind: float(np.median([r["fps"] for r in rows])) for kind, rows in each.items()}
    last_rerun = each["rerun"][-1]
    rrd = rrd_views(Path(last_rerun["rrd"]), last_rerun["frames_out"])
    live = run(cam_cfg, MemoryCamera(clip), "foxglove", "latest", frames=None, seconds=live_s, tmp=tmp)
    both = [live_both(cam_cfg, clip, live_s, tmp) for _ in range(live_runs)]
    client = live["client"]
    seconds = client["seconds"]
    fox_topics = {topic: {"bytes_per_message": round(client["bytes"][topic] / n),
                          "MB_per_s": round(client["bytes"][topic] / seconds / 1e6, 3)}
                  for topic, n in sorted(client["messages"].items())}
    frame_bytes = sum(t["bytes_per_message"] for t in fox_topics.values())
    rerun_mb_s = rrd["file_bytes_per_frame"] * LIVE_FPS / 1e6
    budget_gb = ROTATE_MB * (KEEP_FILES + 1) / 1e3  # the kept segments and the one written
    return {
        "camera": name, "sensor_model": condition, "pixels": f"{CAMERAS[name].width}x{CAMERAS[name].height}",
        "replay_fps": {kind: round(v, 1) for kind, v in fps.items()},
        "replay_fps_each": {kind: [r["fps"] for r in rows] for kind, rows in each.items()},
        "rerun_over_none": round(fps["rerun"] / fps["none"], 3),
        "foxglove_over_none": round(fps["foxglove"] / fps["none"], 3),
        "rerun_MB_per_frame": round(rrd["file_bytes_per_frame"] / 1e6, 4),
        "rerun_live_MB_per_s_at_30fps": round(rerun_mb_s, 2),
        "rerun_live_GB_per_day": round(rerun_mb_s * 86400 / 1e3),
        "rerun_rotation_budget_GB": round(budget_gb, 1),
        "rerun_hours_kept_in_budget": round(budget_gb * 1e3 / rerun_mb_s / 3600, 1) if budget_gb else None,
        "rerun_views_disk_bytes_per_frame": rrd["views_disk_bytes_per_frame"],
        "rerun_rest_disk_bytes_per_frame": rrd["rest_disk_bytes_per_frame"],
        "rerun_views_arrow_bytes_per_frame": rrd["views_arrow_bytes_per_frame"],
        "lossless_bound_bytes": lossless_bounds(clip),
        "rerun_viewer_ms_per_frame": rrd["viewer_ms_per_frame"],
        "encodings_first_frame": encodings(clip),
        "foxglove_live_fps": live["fps"],
        "foxglove_MB_per_s": round(sum(client["bytes"].values()) / seconds / 1e6, 2),
        "foxglove_frame_bytes": frame_bytes,  # a published frame: every topic's mean message
        "foxglove_MB_per_s_at_30fps": round(frame_bytes * LIVE_FPS / 1e6, 2),
        "foxglove_topics": fox_topics,
        "foxglove_refused_subscriptions": client["refused_subscriptions"],  # to channels it advertised
        "live_both_viewers": both,
        "live_both_p99_ms": {viewer: [run[key].get("p99") for run in both] for viewer, key in
                             (("rerun", "rerun_capture_to_send_ms"), ("foxglove", "foxglove_capture_to_client_ms"))},
    }


def print_tables(rows: list[dict]) -> None:
    print(f"{'camera':>8} {'sensor model':>14} {'fps none':>9} {'rerun':>7} {'ratio':>6} {'foxglove':>9} {'ratio':>6} "
          f"{'rrd MB/frame':>13} {'rrd MB/s@30':>12} {'fox MB/s':>9} {'fox kB/frame':>13} {'fox MB/s@30':>12}")
    for r in rows:
        f = r["replay_fps"]
        print(f"{r['camera']:>8} {r['sensor_model']:>14} {f['none']:>9} {f['rerun']:>7} {r['rerun_over_none']:>6} "
              f"{f['foxglove']:>9} {r['foxglove_over_none']:>6} {r['rerun_MB_per_frame']:>13} "
              f"{r['rerun_live_MB_per_s_at_30fps']:>12} "
              f"{r['foxglove_MB_per_s']:>9} {r['foxglove_frame_bytes'] / 1e3:>13.1f} "
              f"{r['foxglove_MB_per_s_at_30fps']:>12}")
    for r in rows:
        print(f"\n{r['camera']} ({r['sensor_model']}): Rerun bytes per frame per view, on disk and before LZ4")
        arrow = r["rerun_views_arrow_bytes_per_frame"]
        for entity, b in r["rerun_views_disk_bytes_per_frame"].items():
            print(f"  {entity:40s} {b:>10} {arrow.get(entity, 0):>10}")
        print(f"  {'(headers, footer index)':40s} {r['rerun_rest_disk_bytes_per_frame']:>10}")
        print(f"  lossless bound (entropy of row differences): {r['lossless_bound_bytes']}")
        for both in r["live_both_viewers"]:
            print(f"{r['camera']} ({r['sensor_model']}): live with both viewers: {both['fps_delivered']} fps "
                  f"delivered, capture to Rerun's send {both['rerun_capture_to_send_ms']}, to the Foxglove client "
                  f"{both['foxglove_capture_to_client_ms']} ms, viewer drops {both['viewer_dropped']}")
        print(f"{r['camera']} ({r['sensor_model']}): Foxglove per topic (live, {r['foxglove_live_fps']} fps)")
        for topic, t in r["foxglove_topics"].items():
            print(f"  {topic:40s} {t['bytes_per_message']:>10} B  {t['MB_per_s']:>8} MB/s")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cameras", type=lambda text: text.split(","), default=["sr3000", "640x576"],
                    help=f"of: {', '.join(CAMERAS)} (sr3000: the bundled clip; others rendered as a mm camera)")
    ap.add_argument("--replay-frames", type=int, default=300, help="frames per lossless replay (the clip looped)")
    ap.add_argument("--runs", type=int, default=3, help="replay runs per viewer kind (interleaved; the median)")
    ap.add_argument("--camera-frames", type=int, default=60, help="frames of a rendered clip")
    ap.add_argument("--live-seconds", type=float, default=10.0, help="seconds of each real-time run")
    ap.add_argument("--live-runs", type=int, default=3, help="real-time runs with both viewers (each reported)")
    ap.add_argument("--conditions", type=lambda text: text.split(","),
                    default=[TRAIN_CONDITION, "noise_constant", "k4a_spec_noise"],
                    help=f"sensor models the rendered clips are made with (of: {', '.join(SENSOR_MODELS)})")
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "bench_viewers.json")
    args = ap.parse_args()
    prepare_service_process()  # as `tofd run` / `tofd replay` set up their process
    unknown = [c for c in args.cameras if c not in CAMERAS]
    if unknown:
        ap.error(f"--cameras: unknown {', '.join(unknown)} (known: {', '.join(CAMERAS)})")
    unknown = [c for c in args.conditions if c not in SENSOR_MODELS]
    if unknown:
        ap.error(f"--conditions: unknown {', '.join(unknown)} (known: {', '.join(SENSOR_MODELS)})")
    results: dict = {
        "title": "Viewer data rates (Rerun, Foxglove) and replay rate with each viewer",
        "about": (f"bench/bench_viewers.py: lossless replay of {args.replay_frames} frames, {args.runs} runs per "
                  f"viewer (median); Rerun: the .rrd a replay saves (MB per frame on disk; MB/s live = that at "
                  f"30 fps); Foxglove: {args.live_seconds:g} s real-time replay at 30 fps, one client subscribed to "
                  f"every channel; then {args.live_runs} runs as long with both viewers (live_both_viewers: each "
                  "run's capture to viewer p50 and p99; live_both_p99_ms: each run's p99). 640x576: the emulator's "
                  "face rendered as a millimetre camera (z-depth in whole "
                  "mm) delivers it, under each sensor model (range_noise_mm: the noise it puts on the scene; "
                  "k4a_spec_noise: at most the Azure Kinect's specified 17 mm)."),
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version(),
                    "load_avg_at_start": [round(x, 2) for x in os.getloadavg()]}}
    with tempfile.TemporaryDirectory() as tmp:
        tmp_path = Path(tmp)
        cfg = with_detector(load_config(), tmp_path)
        rows = []
        for name in args.cameras:
            for condition in ["bundled clip"] if name == "sr3000" else args.conditions:
                clip = CLIP if name == "sr3000" else write_face_clip(
                    tmp_path / f"{name}-{condition}.mcap", CAMERAS[name], args.camera_frames, millimetres=True,
                    model=SENSOR_MODELS[condition])
                row = compare(cfg, name, condition, clip, args.replay_frames, args.runs, args.live_seconds,
                              args.live_runs, tmp_path)
                if name != "sr3000":
                    row["range_noise_mm"] = range_noise_mm(CAMERAS[name], SENSOR_MODELS[condition])
                rows.append(row)
                print(json.dumps(rows[-1]))
    results["rows"] = rows
    print_tables(rows)
    write_json(args.out, results)


if __name__ == "__main__":
    main()
