"""Chaos suite: inject each fault into a real `tofd run --emulate` (or the pipeline) and check it survives.

    python bench/chaos.py                  # every fault once
    python bench/chaos.py --trials 3 --only worker_sigstop,worker_sigkill

Faults: viewer_stall (Rerun peer that accepts and never reads), worker_sigstop, worker_sigkill,
main_kill9_restart (no orphan, no /dev/shm segment, next start works), malformed_frames (bad pixels, a
10x10 frame, a counter beyond int64, through the pipeline). Per fault: frames in / out / dropped by reason,
exit code, seconds from SIGTERM to exit, peak RSS (tofd and all its children). A row passes when nothing
hung, the exit code is 0, in = out + dropped. Prints a table, writes bench/results/chaos.json.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import tempfile
import threading
import time
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))

from bench_pipeline import rss_mb  # noqa: E402
from chaos_helpers import (  # noqa: E402
    BlackHole,
    alive,
    children_of,
    free_port,
    metric,
    metrics,
    shm_segments,
    tofd,
    wait_for,
)
from pipeline_sources import write_config  # noqa: E402
from report import write_json  # noqa: E402

EXIT_TIMEOUT_S = 60.0  # a fault whose process is still alive this long after SIGTERM "hung"


def tree(pid: int) -> list[int]:
    out, todo = [pid], [pid]
    while todo:
        kids = children_of(todo.pop())
        out.extend(kids)
        todo.extend(kids)
    return out


class PeakRss:
    """Samples the RSS of a process tree every 0.5 s in a thread; `peak_mb` is the largest sum seen."""

    def __init__(self, pid: int):
        self.pid, self.peak_mb, self._stop = pid, 0.0, threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.wait(0.5):
            self.peak_mb = max(self.peak_mb, rss_mb(tree(self.pid)))

    def stop(self) -> float:
        self._stop.set()
        self._thread.join()
        return round(self.peak_mb, 1)


def workers_of(pid: int) -> list[int]:
    """The feature worker processes of a tofd process (spawned children that are not the resource tracker
    nor the viewer)."""
    out = []
    for kid in children_of(pid):
        try:
            cmd = Path(f"/proc/{kid}/cmdline").read_bytes().decode(errors="replace")
        except OSError:
            continue
        if "spawn_main" in cmd and "resource_tracker" not in cmd:
            out.append(kid)
    return out


def run_live(work: Path, fault, sink: str = "none", settle_frames: int = 30, **cfg_sections) -> dict:
    """Start `tofd run --emulate`, wait for `settle_frames`, apply `fault(proc, health_port)`, SIGTERM, and
    report the summary, exit code and time to exit."""
    health, summary = free_port(), work / "summary.json"
    proc = tofd("run", "--emulate", "--config", write_config(work, **cfg_sections), "--rerun", sink,
                "--health-port", health, "--summary", summary)
    rss = PeakRss(proc.pid)
    row: dict = {}
    try:
        if not wait_for(lambda: metric(metrics(health), "tofd_frames_out_total") >= settle_frames
                        or proc.poll() is not None, 180):
            row["note"] = "no frames before the fault"
        row.update(fault(proc, health) or {})
        t0 = time.monotonic()
        proc.send_signal(signal.SIGTERM)
        try:
            proc.communicate(timeout=EXIT_TIMEOUT_S)
            row["exit_code"], row["exit_s"] = proc.returncode, round(time.monotonic() - t0, 2)
        except Exception:
            row["exit_code"], row["exit_s"] = None, None  # hung
    finally:
        proc.kill()
        row["peak_rss_mb"] = rss.stop()
    if summary.exists():
        s = json.loads(summary.read_text())
        row.update(frames_in=s["frames_in"], frames_out=s["frames_out"], frames_dropped=s["frames_dropped"],
                   dropped_by_reason=dict(Counter(f"{d['stage']}/{d['reason'].split(':')[0]}" for d in s["drops"])),
                   viewer_dropped=s.get("viewer_dropped", 0))
    return row


def viewer_stall(work: Path) -> dict:
    hole = BlackHole()

    def fault(proc, health):
        ok = wait_for(lambda: metric(metrics(health), "tofd_viewer_frames_dropped_total", '{reason="blocked"}') > 30,
                      180)
        out = metric(metrics(health), "tofd_frames_out_total")
        went_on = wait_for(lambda: metric(metrics(health), "tofd_frames_out_total") > out + 30, 60)
        return {"note": f"viewer stalled: {ok}; results went on: {went_on}"}

    try:
        return run_live(work, fault, f"connect:rerun+http://127.0.0.1:{hole.port}/proxy",
                        pipeline={"shutdown_timeout_s": 4.0})
    finally:
        hole.close()


def _signal_worker(sig: int, hold_s: float):
    def fault(proc, health):
        victims = workers_of(proc.pid)
        if not victims:
            return {"note": "no worker found"}
        os.kill(victims[0], sig)
        out = metric(metrics(health), "tofd_frames_out_total")
        went_on = wait_for(lambda: metric(metrics(health), "tofd_frames_out_total") > out + 30, 60)
        time.sleep(hold_s)
        if sig == signal.SIGSTOP:
            os.kill(victims[0], signal.SIGCONT)
        return {"note": f"output went on: {went_on}; workers alive {metric(metrics(health), 'tofd_workers_alive'):g}"}

    return fault


def worker_sigstop(work: Path) -> dict:
    return run_live(work, _signal_worker(signal.SIGSTOP, 2.0))


def worker_sigkill(work: Path) -> dict:
    return run_live(work, _signal_worker(signal.SIGKILL, 1.0))


def main_kill9_restart(work: Path) -> dict:
    rerun = {"grpc_port": free_port(), "web_port": free_port()}
    health = free_port()
    cfg = write_config(work, rerun=rerun)
    first = tofd("run", "--emulate", "--config", cfg, "--rerun", "web", "--health-port", health)
    rss = PeakRss(first.pid)
    wait_for(lambda: metric(metrics(health), "tofd_frames_out_total") >= 30 or first.poll() is not None, 180)
    kids = tree(first.pid)[1:]
    segments = {s for s in shm_segments() if s.startswith(f"tofd_{first.pid}_")}
    t0 = time.monotonic()
    first.kill()
    first.communicate(timeout=30)
    orphans_gone = wait_for(lambda: not any(alive(k) for k in kids), 30)
    exit_s = round(time.monotonic() - t0, 2)
    peak = rss.stop()

    def nothing(proc, health):
        return {}

    row = run_live(work, nothing, "web", rerun=rerun)
    row.update(note=f"orphans after kill -9: {sum(alive(k) for k in kids)} of {len(kids)} (gone: {orphans_gone}); "
                    f"shm left: {len(segments & shm_segments())}; restart exit {row.get('exit_code')}",
               exit_s=exit_s, peak_rss_mb=max(peak, row["peak_rss_mb"]))
    return row


def malformed_frames(work: Path) -> dict:
    from test_bad_frames import DamagedSource

    from tofd.config import load_config
    from tofd.service.model import load_detector
    from tofd.service.pipeline import Pipeline

    cfg = load_config(write_config(work))
    pipeline = Pipeline(cfg, "lossless", model=load_detector(cfg).model)
    t0 = time.monotonic()
    pipeline.start(DamagedSource(40, n_distinct=3))
    finished = pipeline.wait(EXIT_TIMEOUT_S)
    s = pipeline.close()
    return {"frames_in": s["frames_in"], "frames_out": s["frames_out"], "frames_dropped": s["frames_dropped"],
            "dropped_by_reason": dict(Counter(f"{d['stage']}/{d['reason'].split(':')[0]}" for d in s["drops"])),
            "viewer_dropped": 0, "exit_code": 0 if finished and pipeline.error is None else 1,
            "exit_s": round(time.monotonic() - t0, 2), "peak_rss_mb": round(rss_mb(tree(os.getpid())), 1),
            "note": "in-process pipeline, lossless"}


FAULTS = {"viewer_stall": viewer_stall, "worker_sigstop": worker_sigstop, "worker_sigkill": worker_sigkill,
          "main_kill9_restart": main_kill9_restart, "malformed_frames": malformed_frames}


def passed(row: dict) -> bool:
    return (row.get("exit_code") == 0 and row.get("frames_in") is not None
            and row["frames_in"] == row["frames_out"] + row["frames_dropped"])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=1)
    parser.add_argument("--only", default=",".join(FAULTS), help="comma-separated faults")
    args = parser.parse_args()
    os.environ.setdefault("RUST_LOG", "error")
    rows = []
    for name in args.only.split(","):
        for trial in range(args.trials):
            with tempfile.TemporaryDirectory() as tmp:
                row = {"fault": name, "trial": trial, **FAULTS[name](Path(tmp))}
            row["pass"] = passed(row)
            rows.append(row)
            print(f"{name} #{trial}: {'PASS' if row['pass'] else 'FAIL'}  {row.get('note', '')}", flush=True)
    header = f"{'fault':<20} {'trial':>5} {'in':>5} {'out':>5} {'drop':>5} {'viewer':>6} {'exit':>4} {'exit_s':>7} " \
             f"{'RSS MB':>7}  dropped by reason"
    print("\n" + header + "\n" + "-" * len(header))
    for r in rows:
        print(f"{r['fault']:<20} {r['trial']:>5} {r.get('frames_in', '-')!s:>5} {r.get('frames_out', '-')!s:>5} "
              f"{r.get('frames_dropped', '-')!s:>5} {r.get('viewer_dropped', '-')!s:>6} {r.get('exit_code')!s:>4} "
              f"{r.get('exit_s')!s:>7} {r.get('peak_rss_mb')!s:>7}  {r.get('dropped_by_reason', {})}")
    write_json(ROOT / "bench" / "results" / "chaos.json", {
        "title": "Chaos suite (bench/chaos.py)",
        "about": "Each fault injected into a real `tofd run --emulate` (malformed_frames: the pipeline in-process). "
                 "pass = exit code 0 and frames in = out + dropped; exit_s = SIGTERM to exit (kill -9: to the last "
                 "child gone); peak_rss_mb = tofd and all its children.",
        "cpu_count": os.cpu_count(), "rows": rows, "all_passed": all(r["pass"] for r in rows)})
    return 0 if all(r["pass"] for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
