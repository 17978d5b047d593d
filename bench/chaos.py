"""Chaos suite: inject each fault into a real tofd (or the replay reader) and check that it survives.

    python bench/chaos.py                  # every fault once
    python bench/chaos.py --trials 3 --only worker_sigstop,worker_sigkill
    python bench/chaos.py --only fuzz --fuzz-trials 100

Faults of a live `tofd run --emulate` (SIGTERM at the end, shutdown_timeout_s = SHUTDOWN_S): viewer_stall (a
Rerun peer that accepts and never reads), worker_sigstop (the worker stays stopped through the SIGTERM),
worker_sigkill, main_kill9_restart (kill -9: no orphan, no /dev/shm segment, the next start works).
Faults of a recording, through a real `tofd replay` of an excerpt of the bundled clip: damaged_frames (a
flipped byte), zero_crc_frames (chunk CRC 0), duplicated_frames (a record twice), malformed_frames (planes of
10x10), each done to FAULTY frames; bad_pixel_frames (NaN/zero/negative pixels, a 10x10 frame, a counter
beyond int64) through the pipeline in-process. fuzz: seeded random mutations of a recording's bytes (bit
flips, truncations, inserted/deleted/duplicated/overwritten runs) through the replay reader, each trial with a
hang guard. Per row: fault | trials | frames in / out / dropped by reason | exit code | seconds to exit (from
SIGTERM; kill -9: to the last child gone; replay: the whole run; fuzz: the longest trial) | peak RSS (tofd
and its children). A row passes when nothing hung, no exception escaped, in = out + dropped, the exit came
within its timeout, RSS stayed under its bound and the fault's own checks hold. Prints a table, writes
bench/results/chaos.json.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import signal
import sys
import tempfile
import threading
import time
from collections import Counter
from collections.abc import Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))  # the checkout's tofd_testing package (test support, not installed)

import numpy as np  # noqa: E402
from proc_stats import rss_mb  # noqa: E402
from report import write_json  # noqa: E402

from tofd_testing.chaos_helpers import (  # noqa: E402
    BlackHole,
    alive,
    free_port,
    metric,
    metrics,
    shm_segments,
    tofd,
    tree,
    wait_for,
    workers_of,
)
from tofd_testing.pipeline_sources import write_config  # noqa: E402
from tofd_testing.recording_helpers import RECORDING_FAULTS, excerpt, faulty_copy, mutate  # noqa: E402

BUNDLED = ROOT / "replay_data" / "emulated_face_035_070.mcap"
SHUTDOWN_S = 4.0  # shutdown_timeout_s of the live faults: SIGTERM must end tofd within it
HANG_S = 120.0  # a process still alive this long after SIGTERM (or a replay this long after its start) hung
REPLAY_TIMEOUT_S = 120.0  # a replay of the excerpt must end within this
FUZZ_TRIAL_TIMEOUT_S = 30.0  # one fuzzed recording must be read within this
EXCERPT_FRAMES = 12  # frames of the bundled clip replayed by the recording faults
FAULTY = {3, 6, 9}  # counters of the frames a recording fault is done to
FUZZ_FRAMES = 12  # frames of the bundled clip in the fuzzed recording
RSS_BOUND_MB = 1024.0  # peak RSS of tofd and its children
VIEWER_RSS_BOUND_MB = 1536.0  # with a stalled viewer: the Rerun SDK queues ~300 MB before its calls block


def tree_rss_mb(pid: int) -> float:
    return sum(rss_mb(p) for p in tree(pid))


class PeakRss:
    """Samples the RSS of a process tree every `interval_s` in a thread; `peak_mb` is the largest sum seen."""

    def __init__(self, pid: int, interval_s: float = 0.5):
        self.pid, self.peak_mb, self._stop = pid, tree_rss_mb(pid), threading.Event()
        self.interval_s = interval_s
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.wait(self.interval_s):
            self.peak_mb = max(self.peak_mb, tree_rss_mb(self.pid))

    def stop(self) -> float:
        self._stop.set()
        self._thread.join()
        return round(self.peak_mb, 1)


def by_reason(drops: list[dict]) -> dict[str, int]:
    return dict(Counter(f"{d['stage']}/{d['reason'].split(':')[0]}" for d in drops))


def from_summary(path: Path) -> dict:
    """The row fields a run summary gives (nothing if it was not written)."""
    if not path.exists():
        return {"failed": ["no summary written"]}
    s = json.loads(path.read_text())
    return {"frames_in": s["frames_in"], "frames_out": s["frames_out"], "frames_dropped": s["frames_dropped"],
            "dropped_by_reason": by_reason(s["drops"]), "viewer_dropped": s.get("viewer_dropped", 0),
            "shutdown": s.get("shutdown")}


def finish(proc, t0: float, timeout_s: float) -> dict:
    """Wait for `proc` (a hang guard of `timeout_s`): exit code, seconds since `t0`, whether a traceback
    escaped to stderr."""
    try:
        _, err = proc.communicate(timeout=timeout_s)
    except Exception:  # noqa: BLE001 (TimeoutExpired: it hung)
        return {"exit_code": None, "exit_s": None}
    return {"exit_code": proc.returncode, "exit_s": round(time.monotonic() - t0, 2),
            "traceback": "Traceback" in err}


# ---------------------------------------------------------------- live faults
def run_live(work: Path, fault: Callable, sink: str = "none", settle_frames: int = 30, **cfg_sections) -> dict:
    """Start `tofd run --emulate`, wait for `settle_frames`, apply `fault(proc, health_port)`, SIGTERM, and
    report the summary, exit code and time to exit."""
    health, summary = free_port(), work / "summary.json"
    cfg = write_config(work, pipeline={"shutdown_timeout_s": SHUTDOWN_S}, **cfg_sections)
    proc = tofd("run", "--emulate", "--config", cfg, "--rerun", sink, "--health-port", health, "--summary", summary)
    rss = PeakRss(proc.pid)
    row: dict = {"timeout_s": SHUTDOWN_S}
    try:
        if not wait_for(lambda: metric(metrics(health), "tofd_frames_out_total") >= settle_frames
                        or proc.poll() is not None, 180):
            row["failed"] = ["no frames before the fault"]
        row.update(fault(proc, health) or {})
        t0 = time.monotonic()
        proc.send_signal(signal.SIGTERM)
        row.update(finish(proc, t0, HANG_S))
    finally:
        proc.kill()
        row["peak_rss_mb"] = rss.stop()
    extra = row.pop("failed", [])
    row.update(from_summary(summary))
    row["failed"] = extra + row.get("failed", [])
    return row


def went_on(health: int) -> bool:
    """Whether 30 more frames are delivered (a guard of 60 s)."""
    out = metric(metrics(health), "tofd_frames_out_total")
    return wait_for(lambda: metric(metrics(health), "tofd_frames_out_total") > out + 30, 60)


def viewer_stall(work: Path) -> dict:
    hole = BlackHole()

    def fault(proc, health):
        stalled = wait_for(lambda: metric(metrics(health), "tofd_viewer_frames_dropped_total",
                                          '{reason="blocked"}') > 30, 180)
        on = went_on(health)
        return {"note": f"viewer stalled: {stalled}; results went on: {on}",
                "failed": [] if stalled and on else ["results stopped with the viewer"]}

    try:
        row = run_live(work, fault, f"connect:rerun+http://127.0.0.1:{hole.port}/proxy")
    finally:
        hole.close()
    row["rss_bound_mb"] = VIEWER_RSS_BOUND_MB
    return row


def _signal_worker(sig: int):
    def fault(proc, health):
        victims = workers_of(proc.pid)
        if not victims:
            return {"failed": ["no worker found"]}
        os.kill(victims[0], sig)
        on = went_on(health)
        return {"note": f"output went on: {on}; workers alive {metric(metrics(health), 'tofd_workers_alive'):g}",
                "failed": [] if on else ["output stopped"]}

    return fault


def worker_sigstop(work: Path) -> dict:
    return run_live(work, _signal_worker(signal.SIGSTOP))  # still stopped at the SIGTERM: it must be killed


def worker_sigkill(work: Path) -> dict:
    return run_live(work, _signal_worker(signal.SIGKILL))


def main_kill9_restart(work: Path) -> dict:
    rerun = {"grpc_port": free_port(), "web_port": free_port()}
    health = free_port()
    first = tofd("run", "--emulate", "--config", write_config(work, rerun=rerun), "--rerun", "web",
                 "--health-port", health)
    rss = PeakRss(first.pid)
    wait_for(lambda: metric(metrics(health), "tofd_frames_out_total") >= 30 or first.poll() is not None, 180)
    kids = tree(first.pid)[1:]
    segments = {s for s in shm_segments() if s.startswith(f"tofd_{first.pid}_")}
    t0 = time.monotonic()
    first.kill()
    first.communicate(timeout=30)
    gone = wait_for(lambda: not any(alive(k) for k in kids), HANG_S, poll_s=0.05)
    exit_s = round(time.monotonic() - t0, 2) if gone else None
    peak = rss.stop()
    orphans, left = sum(alive(k) for k in kids), len(segments & shm_segments())
    row = run_live(work, lambda proc, health: {}, "web", rerun=rerun)  # the next start
    row["failed"] += (["orphans"] if orphans else []) + (["shm left"] if left else [])
    row.update(note=f"orphans after kill -9: {orphans} of {len(kids)}; shm left: {left}; restart exit "
                    f"{row.get('exit_code')} in {row.get('exit_s')} s",
               exit_s=exit_s, peak_rss_mb=max(peak, row["peak_rss_mb"]))
    return row


# ---------------------------------------------------------------- recording faults
def replay_fault(fault: str) -> Callable[[Path], dict]:
    """A row: `tofd replay` of the excerpt with `fault` done to the FAULTY frames; each must be ledgered at
    capture with the fault's reason, every other frame delivered."""

    def run(work: Path) -> dict:
        clip = faulty_copy(excerpt(BUNDLED, work / "clip.mcap", EXCERPT_FRAMES), work / f"{fault}.mcap", fault, FAULTY)
        out = work / "out"
        t0 = time.monotonic()
        proc = tofd("replay", clip, "--out", out, "--rerun", "none", "--config", write_config(work))
        rss = PeakRss(proc.pid)
        try:
            row = {"timeout_s": REPLAY_TIMEOUT_S, **finish(proc, t0, HANG_S)}
        finally:
            proc.kill()
            row["peak_rss_mb"] = rss.stop()
        row.update(from_summary(out / f"{fault}.summary.json"))
        expected = {f"capture/{RECORDING_FAULTS[fault]}": len(FAULTY)}
        row["note"] = f"expected drops {expected}"
        row["failed"] = row.get("failed", []) + ([] if row.get("dropped_by_reason") == expected else
                                                  ["not exactly the faulty frames dropped"])
        return row

    return run


def bad_pixel_frames(work: Path) -> dict:
    from tests.drivers.test_bad_frames import DamagedSource
    from tofd.config import load_config
    from tofd.service.model import load_detector
    from tofd.service.pipeline import Pipeline

    cfg = load_config(write_config(work))
    pipeline = Pipeline(cfg, "lossless", model=load_detector(cfg).model)
    rss = PeakRss(os.getpid())
    t0 = time.monotonic()
    pipeline.start(DamagedSource(40, n_distinct=3))
    finished = pipeline.wait(HANG_S)
    s = pipeline.close()
    return {"frames_in": s["frames_in"], "frames_out": s["frames_out"], "frames_dropped": s["frames_dropped"],
            "dropped_by_reason": by_reason(s["drops"]), "viewer_dropped": 0,
            "exit_code": 0 if finished and pipeline.error is None else (1 if finished else None),
            "exit_s": round(time.monotonic() - t0, 2), "timeout_s": REPLAY_TIMEOUT_S, "peak_rss_mb": rss.stop(),
            "note": "in-process pipeline, lossless", "failed": []}


# ---------------------------------------------------------------- fuzz
def fuzz_trial(path: Path, reference: dict) -> dict:
    """Read one fuzzed recording as `tofd replay` does (header, then every frame); what came out."""
    from tofd.drivers.recording.reader import read_recording_info
    from tofd.drivers.recording.replay import ReplaySource
    from tofd.drivers.source import DriverError

    try:
        read_recording_info(path)
        source = ReplaySource(path)
    except DriverError:
        return {"refused": True}
    with source:
        frames = list(source)
    rejected = source.take_rejected()
    bad = [f.frame_counter for f in frames
           if f.frame_counter not in reference or not np.array_equal(
               reference[f.frame_counter].view(np.uint32), f.range_m.view(np.uint32))]
    counters = [f.frame_counter for f in frames]
    return {"refused": False, "out": len(frames), "dropped": Counter(r.reason.split(":")[0] for r in rejected),
            "stopped": source.stopped_reason,
            "wrong": bad + ([-1] if len(set(counters)) != len(counters) else [])}


def fuzz(work: Path, trials: int, seed: int = 17) -> dict:
    """`trials` seeded mutations of an excerpt of the bundled clip through the replay reader."""
    from tofd.drivers.recording.replay import iter_frames

    logging.getLogger("tofd.drivers.recording.replay").setLevel(logging.ERROR)  # every trial warns of its damage
    clip = excerpt(BUNDLED, work / "clip.mcap", FUZZ_FRAMES)
    reference = {f.frame_counter: f.range_m for f in iter_frames(clip)}
    data, rng = clip.read_bytes(), np.random.default_rng(seed)
    rss = PeakRss(os.getpid())
    totals: Counter = Counter()
    dropped: Counter = Counter()
    kinds: Counter = Counter()
    escaped, wrong, hung, longest = [], 0, 0, 0.0
    for trial in range(trials):
        kind, mutated = mutate(data, rng)
        kinds[kind] += 1
        path = work / "fuzz.mcap"
        path.write_bytes(mutated)
        result: dict = {}

        def read(into=result, p=path):
            try:
                into.update(fuzz_trial(p, reference))
            except Exception as exc:  # noqa: BLE001 (what the row counts: an exception that escaped)
                into["escaped"] = f"{type(exc).__name__}: {exc}"

        t0 = time.monotonic()
        thread = threading.Thread(target=read, daemon=True)
        thread.start()
        thread.join(FUZZ_TRIAL_TIMEOUT_S)
        longest = max(longest, time.monotonic() - t0)
        if thread.is_alive():
            hung += 1
            break
        if "escaped" in result:
            escaped.append(f"trial {trial} ({kind}): {result['escaped']}")
            continue
        if result["refused"]:
            totals["refused"] += 1
            continue
        totals[f"stopped_{result['stopped']}"] += 1
        totals["out"] += result["out"]
        dropped.update(result["dropped"])
        wrong += bool(result["wrong"])
    n_dropped = sum(dropped.values())
    failed = ([f"{hung} trial(s) hung"] if hung else []) + ([f"{len(escaped)} exception(s) escaped"] if escaped
                                                             else [])
    failed += [f"{wrong} trial(s) replayed a damaged or repeated frame"] if wrong else []
    return {"trials": trials, "frames_in": totals["out"] + n_dropped, "frames_out": totals["out"],
            "frames_dropped": n_dropped, "dropped_by_reason": {f"capture/{k}": v for k, v in dropped.items()},
            "viewer_dropped": 0, "exit_code": None if hung else (1 if escaped else 0),
            "exit_s": round(longest, 2), "timeout_s": FUZZ_TRIAL_TIMEOUT_S, "peak_rss_mb": rss.stop(),
            "note": f"{totals['refused']} refused at open (header damaged), stopped: "
                    f"{ {k[8:]: v for k, v in totals.items() if k.startswith('stopped_')} }; mutations {dict(kinds)}",
            "escaped": escaped[:5], "failed": failed}


FAULTS: dict[str, Callable[[Path], dict]] = {
    "viewer_stall": viewer_stall, "worker_sigstop": worker_sigstop, "worker_sigkill": worker_sigkill,
    "main_kill9_restart": main_kill9_restart, **{f: replay_fault(f) for f in RECORDING_FAULTS},
    "bad_pixel_frames": bad_pixel_frames}


def failures(row: dict) -> list[str]:
    """The checks every row must pass, then the fault's own."""
    failed = []
    if row.get("exit_code") is None:
        failed.append("hung")
    elif row["exit_code"] != 0:
        failed.append(f"exit code {row['exit_code']}")
    if row.pop("traceback", False):
        failed.append("a traceback escaped")
    if row.get("frames_in") is None or row["frames_in"] != row["frames_out"] + row["frames_dropped"]:
        failed.append("in != out + dropped")
    if row.get("exit_s") is not None and row["exit_s"] > row["timeout_s"]:
        failed.append(f"exit after {row['exit_s']} s > {row['timeout_s']} s")
    row.setdefault("rss_bound_mb", RSS_BOUND_MB)
    if row["peak_rss_mb"] > row["rss_bound_mb"]:
        failed.append(f"peak RSS {row['peak_rss_mb']} MB > {row['rss_bound_mb']} MB")
    return failed + row.pop("failed", [])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=1, help="trials of each fault but the fuzz")
    parser.add_argument("--fuzz-trials", type=int, default=500)
    parser.add_argument("--only", default=",".join([*FAULTS, "fuzz"]), help="comma-separated faults")
    args = parser.parse_args()
    os.environ.setdefault("RUST_LOG", "error")
    rows = []
    for name in args.only.split(","):
        for trial in range(1 if name == "fuzz" else args.trials):
            with tempfile.TemporaryDirectory() as tmp:
                found = fuzz(Path(tmp), args.fuzz_trials) if name == "fuzz" else FAULTS[name](Path(tmp))
            row = {"fault": name, "trial": trial, "trials": 1, **found}
            row["failed"] = failures(row)
            row["pass"] = not row["failed"]
            rows.append(row)
            print(f"{name} #{trial}: {'PASS' if row['pass'] else 'FAIL ' + '; '.join(row['failed'])}  "
                  f"{row.get('note', '')}", flush=True)
    header = f"{'fault':<19} {'trials':>6} {'in':>6} {'out':>6} {'drop':>5} {'viewer':>6} {'exit':>4} " \
             f"{'exit_s':>6} {'limit':>5} {'RSS MB':>7}  dropped by reason"
    print("\n" + header + "\n" + "-" * len(header))
    for r in rows:
        print(f"{r['fault']:<19} {r['trials']:>6} {r.get('frames_in', '-')!s:>6} {r.get('frames_out', '-')!s:>6} "
              f"{r.get('frames_dropped', '-')!s:>5} {r.get('viewer_dropped', '-')!s:>6} {r.get('exit_code')!s:>4} "
              f"{r.get('exit_s')!s:>6} {r['timeout_s']:>5g} {r['peak_rss_mb']:>7}  {r.get('dropped_by_reason', {})}")
    write_json(ROOT / "bench" / "results" / "chaos.json", {
        "title": "Chaos suite (bench/chaos.py)",
        "about": "Each fault injected into a real `tofd run --emulate` or `tofd replay` (bad_pixel_frames: the "
                 "pipeline in-process; fuzz: the replay reader in-process). pass = nothing hung, no exception "
                 "escaped, exit code 0, frames in = out + dropped, exit within timeout_s (live: SIGTERM to exit "
                 "with shutdown_timeout_s = timeout_s; kill -9: to the last child gone; replay: the whole run; "
                 "fuzz: the longest trial), peak_rss_mb (tofd and all its children) within rss_bound_mb, and the "
                 "fault's own checks (see `note`).",
        "cpu_count": os.cpu_count(), "rows": rows, "all_passed": all(r["pass"] for r in rows)})
    return 0 if all(r["pass"] for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
