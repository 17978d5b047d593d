"""Hostile-input suite: each case fed to a real tofd, with its cost and how it ended.

    python bench/hostile.py                 # every case
    python bench/hostile.py --only zstd_bomb,npz_bomb,idle_connections

Cases: an intact recording (the baseline: what a replay of it costs), recordings whose chunks, records or
header claim what no camera sends (tofd_testing/hostile_inputs.py, through `tofd replay`), ROS bags written by
rosbags whose last chunk is a decompression bomb or whose sqlite3 header claims pages it does not have
(tofd_testing/hostile_bags.py, through `tofd info` and `tofd replay`), dataset .npz bombs (through
`tofd evaluate`), configs out of every bound (`tofd replay --config`),
and a live `tofd run --emulate` under 300 idle connections, 100 clients that leave before their answer, a save
sink on a full 2 MB tmpfs, and SIGUSR1 / SIGHUP / SIGQUIT. Per row: case | limit that must hold | peak RSS of
tofd and its children (MiB) | seconds | exit code | result (the one line tofd printed, or what was measured).
A row passes when tofd ended as the case expects (refused: exit 2 with one line; ledgered: exit 0; network:
/healthz answered and nothing spun), no traceback reached stderr, memory stayed under RSS_BOUND_MB and time under
TIME_BOUND_S. Prints a table, writes bench/results/hostile.json.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import socket
import struct
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.request
from collections.abc import Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))  # the checkout's tofd_testing package (test support, not installed)

from chaos import PeakRss  # noqa: E402
from proc_stats import cpu_s  # noqa: E402
from report import write_json  # noqa: E402

from tofd_testing.chaos_helpers import metric, metrics, tofd  # noqa: E402
from tofd_testing.hostile_bags import mcap_chunk_bomb, ros1_chunk_bomb, sqlite_page_claim  # noqa: E402
from tofd_testing.hostile_inputs import BASE_FRAMES, CONFIG_CASES, DATASET_CASES, RECORDING_CASES  # noqa: E402
from tofd_testing.pipeline_sources import write_config  # noqa: E402
from tofd_testing.recording_helpers import make_frame, write_recording  # noqa: E402
from tofd_testing.rosbag_helpers import frame_messages, typestore, write_bag, write_frames_bag  # noqa: E402

CLIP = ROOT / "replay_data" / "emulated_face_035_070.mcap"
SMALL_CLIP = ROOT / "tests" / "data" / "v1_first3.mcap"
RSS_BOUND_MB = 1024.0  # a hostile input costs at most this (tofd and its children)
TIME_BOUND_S = 60.0  # ... and ends within this
HANG_S = 300.0


def _run(args: list[object], expect: str, *, env: dict | None = None) -> dict:
    """Run `tofd *args` with its peak RSS sampled; the row fields."""
    t0 = time.monotonic()
    proc = tofd(*args, env=env or {})
    peak = PeakRss(proc.pid, interval_s=0.05)
    try:
        _, err = proc.communicate(timeout=HANG_S)
    except subprocess.TimeoutExpired:
        proc.kill()
        _, err = proc.communicate()
    seconds = round(time.monotonic() - t0, 2)
    lines = [line for line in err.strip().splitlines() if "INFO" not in line and "resource_tracker" not in line
             and "warnings.warn" not in line]
    row = {"peak_rss_mb": peak.stop(), "seconds": seconds, "exit_code": proc.returncode,
           "result": lines[-1][:160] if lines else "", "stderr_lines": len(lines), "traceback": "Traceback" in err}
    ok = {"refused": proc.returncode == 2 and len(lines) == 1,
          "ledgered": proc.returncode == 0}[expect]
    row["expected"] = expect
    row["passed"] = ok and not row["traceback"] and row["peak_rss_mb"] < RSS_BOUND_MB and seconds < TIME_BOUND_S
    return row


def recording_case(name: str) -> Callable[[Path], dict]:
    def run(work: Path) -> dict:
        path = RECORDING_CASES[name][0](work)
        expect = "refused" if name.startswith(("header_", "attachment_50", "deep_json")) else "ledgered"
        return _run(["replay", path, "--out", work / "out", "--rerun", "none"], expect)
    return run


def intact_baseline(work: Path) -> dict:
    """The recording the chunk cases are spliced into, intact: what the same replay costs without a hostile part."""
    path = work / "intact.mcap"
    write_recording(path, range(BASE_FRAMES))
    return _run(["replay", path, "--out", work / "out", "--rerun", "none"], "ledgered")


BAG_FRAMES = 6  # frames of the bag each bag case damages
BAG_BOMB_BYTES = 2 << 30  # what a bag's bomb chunk decompresses to


def _ros1_bomb(compression: str) -> Callable[[Path], Path]:
    def make(work: Path) -> Path:
        frames = [make_frame(c) for c in range(BAG_FRAMES)]
        ts = typestore("ros1")
        bag = write_bag(work / "clip.bag", "ros1", (m for f in frames for m in frame_messages(ts, f)),
                        chunk_bytes=1 << 10, compression=compression)
        return ros1_chunk_bomb(bag, work / "bomb.bag", BAG_BOMB_BYTES)
    return make


def _mcap_bomb(work: Path) -> Path:
    bag = write_frames_bag(work, "mcap", [make_frame(c) for c in range(BAG_FRAMES)])
    return mcap_chunk_bomb(next(bag.glob("*.mcap")), work / "bomb.mcap", BOMB_BYTES_MCAP)


def _sqlite_claim(work: Path) -> Path:
    bag = write_frames_bag(work, "sqlite3", [make_frame(c) for c in range(BAG_FRAMES)])
    return sqlite_page_claim(next(bag.glob("*.db3")), work / "cut.db3", 0.6, 2 << 30)


BOMB_BYTES_MCAP = 1 << 30  # the MCAP bomb's message is built in memory here, so half the others'
BAG_CASES: dict[str, tuple[Callable[[Path], Path], str]] = {
    "ros1_lz4_bomb": (_ros1_bomb("lz4"), "a 2 GiB LZ4 chunk: never decompressed whole"),
    "ros1_bz2_bomb": (_ros1_bomb("bz2"), "a 2 GiB bz2 chunk: never decompressed whole"),
    "ros2_mcap_bomb": (_mcap_bomb, "a 1 GiB zstd chunk: never decompressed whole"),
    "sqlite_page_claim": (_sqlite_claim, "a cut .db3 claiming 2 GiB: read as the pages it has"),
}
"""Bag case -> (maker of the file in a work dir, the limit that must hold)."""


def bag_case(name: str, command: str) -> Callable[[Path], dict]:
    def run(work: Path) -> dict:
        path = BAG_CASES[name][0](work)
        args = ["info", path] if command == "info" else ["replay", path, "--out", work / "out", "--rerun", "none"]
        return _run(args, "ledgered")
    return run


def dataset_case(name: str) -> Callable[[Path], dict]:
    def run(work: Path) -> dict:
        path = DATASET_CASES[name][0](work)
        return _run(["evaluate", "--test", path, "--out", work / "ev"], "refused")
    return run


def config_case(name: str) -> Callable[[Path], dict]:
    def run(work: Path) -> dict:
        config = work / "tofd.toml"
        config.write_text(CONFIG_CASES[name][0])
        return _run(["replay", SMALL_CLIP, "--config", config, "--out", work / "out", "--rerun", "none"], "refused")
    return run


# ---------------------------------------------------------------- a live daemon
class Daemon:
    """`tofd run --emulate` with /healthz on a free port, until stop()."""

    def __init__(self, work: Path, *extra: object):
        self.summary = work / "summary.json"
        config = write_config(work, rerun={"rotate_mb": 0.0})  # a "save" sink writes one file, not segments
        self.proc = tofd("run", "--emulate", "--config", config, "--health-port", "0", "--rerun",
                         "none", "--summary", self.summary, *extra, start_new_session=True)
        self.peak = PeakRss(self.proc.pid, interval_s=0.1)
        self.lines: list[str] = []
        while not any("INFO health:" in line for line in self.lines):
            self.lines.append(self.proc.stderr.readline())
            if not self.lines[-1]:
                raise RuntimeError("tofd run ended before serving: " + "".join(self.lines))
        self.port = int(next(x for x in self.lines if "INFO health:" in x).split(":")[-1].split("/")[0])
        deadline = time.monotonic() + 120
        while self.healthz() != 200 and time.monotonic() < deadline:  # workers up, frames delivered
            time.sleep(0.5)

    def healthz(self, timeout_s: float = 30) -> int | None:
        """The /healthz status code; None if it did not answer."""
        try:
            with urllib.request.urlopen(f"http://127.0.0.1:{self.port}/healthz", timeout=timeout_s) as resp:
                return resp.status
        except urllib.error.HTTPError as exc:
            return exc.code
        except OSError:
            return None

    def stop(self, sig: int = signal.SIGTERM) -> dict:
        os.killpg(self.proc.pid, sig)
        try:
            _, err = self.proc.communicate(timeout=HANG_S)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            _, err = self.proc.communicate()
        err = "".join(self.lines) + err
        lines = [x for x in err.strip().splitlines() if " INFO " not in x and "resource_tracker" not in x
                 and "warnings.warn" not in x]
        summary = json.loads(self.summary.read_text()) if self.summary.exists() else {}
        return {"peak_rss_mb": self.peak.stop(), "exit_code": self.proc.returncode, "traceback": "Traceback" in err,
                "stderr_lines": len(lines), "summary": bool(summary),
                "shutdown_reason": summary.get("shutdown", {}).get("reason")}


def idle_connections(work: Path) -> dict:
    """300 connections that send nothing (and one half request line) held for 12 s: the server closes them,
    /healthz answers, the main process does not spin."""
    daemon = Daemon(work)
    t0 = time.monotonic()
    cpu0 = cpu_s(daemon.proc.pid)
    held = []
    for _ in range(300):
        try:
            held.append(socket.create_connection(("127.0.0.1", daemon.port), timeout=5))
        except OSError:
            break
    held[-1].sendall(b"GET /healthz\r\n")
    time.sleep(12)
    closed = 0
    for sock in held:
        sock.settimeout(0.01)
        try:
            closed += sock.recv(1) == b""
        except (TimeoutError, BlockingIOError):
            pass
        except OSError:
            closed += 1
    main_cpu = cpu_s(daemon.proc.pid) - cpu0  # the whole process: workers' frames are in their own processes
    for sock in held:
        sock.close()
    code = daemon.healthz()
    row = daemon.stop()
    seconds = round(time.monotonic() - t0, 1)
    row.update(seconds=seconds, result=f"{closed}/{len(held)} closed by the server in 12 s; /healthz {code}; main "
                                       f"process CPU {main_cpu / 12:.0%} meanwhile")
    row["passed"] = code == 200 and closed >= len(held) - 32 and row["exit_code"] == 0 and not row["traceback"]
    return row


def early_leavers(work: Path) -> dict:
    """100 clients that reset their connection right after the request: no line on stderr."""
    daemon = Daemon(work)
    t0 = time.monotonic()
    for _ in range(100):
        sock = socket.create_connection(("127.0.0.1", daemon.port))
        sock.sendall(b"GET /metrics HTTP/1.1\r\nHost: x\r\n\r\n")
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
        sock.close()
    code = daemon.healthz()
    row = daemon.stop()
    row.update(seconds=round(time.monotonic() - t0, 1),
               result=f"/healthz {code}; {row['stderr_lines'] - 1} stderr lines besides the exit line")
    row["passed"] = code == 200 and row["stderr_lines"] <= 1 and not row["traceback"]
    return row


def full_disk(work: Path) -> dict:
    """A live save sink on a 2 MB tmpfs: /healthz degraded and tofd_output_failed while it runs."""
    disk = work / "disk"
    disk.mkdir()
    mount = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=2m", "tmpfs", str(disk)], capture_output=True,
                           text=True)
    if mount.returncode != 0:
        return {"passed": True, "result": f"skipped: cannot mount a tmpfs ({mount.stderr.strip()})"}
    try:
        rrd = disk / "live.rrd"
        daemon = Daemon(work, "--rerun", f"save:{rrd}")
        t0, status = time.monotonic(), {}
        while status.get("status") != "degraded" and time.monotonic() - t0 < 120:
            time.sleep(0.5)
            with urllib.request.urlopen(f"http://127.0.0.1:{daemon.port}/healthz", timeout=5) as resp:
                status = json.loads(resp.read())
        failed = metric(metrics(daemon.port), "tofd_output_failed", f'{{output="{rrd}"}}')
        row = daemon.stop()
        leftovers = [p.name for p in disk.iterdir() if p.name.endswith(".tmp")]
        row.update(seconds=round(time.monotonic() - t0, 1),
                   result=f"/healthz {status.get('status')}; tofd_output_failed {failed:g}; "
                          f"left {sorted(os.listdir(disk))}")
        row["passed"] = (status.get("status") == "degraded" and failed == 1 and not rrd.exists() and not leftovers
                         and row["exit_code"] == 1 and row["summary"] and not row["traceback"])
        return row
    finally:
        subprocess.run(["umount", "-l", str(disk)], check=False)


def signal_case(sig: int) -> Callable[[Path], dict]:
    def run(work: Path) -> dict:
        daemon = Daemon(work)
        time.sleep(2)
        os.killpg(daemon.proc.pid, signal.SIGUSR1)
        time.sleep(1)
        alive = daemon.proc.poll() is None
        t0 = time.monotonic()
        row = daemon.stop(sig)
        row.update(seconds=round(time.monotonic() - t0, 1),
                   result=f"alive after SIGUSR1: {alive}; exit {row['exit_code']}, summary reason "
                          f"{row['shutdown_reason']}")
        row["passed"] = alive and row["exit_code"] == 0 and row["shutdown_reason"] == signal.Signals(sig).name \
            and not row["traceback"]
        return row
    return run


CASES: dict[str, tuple[str, Callable[[Path], dict]]] = {
    "intact_baseline": ("(the same replay, nothing hostile)", intact_baseline),
    **{name: (limit, recording_case(name)) for name, (_, limit) in RECORDING_CASES.items()},
    **{f"{name}_{command}": (limit, bag_case(name, command)) for name, (_, limit) in BAG_CASES.items()
       for command in ("info", "replay")},
    **{name: (limit, dataset_case(name)) for name, (_, limit) in DATASET_CASES.items()},
    **{f"config_{name}": (f"config error naming {key}", config_case(name))
       for name, (_, key) in CONFIG_CASES.items()},
    "idle_connections": ("silent connections closed after 5 s; <= 32 open", idle_connections),
    "early_leavers": ("no log line per client", early_leavers),
    "full_disk_live": ("degraded, named, no temp file", full_disk),
    "sighup": ("drain, summary, exit 0", signal_case(signal.SIGHUP)),
    "sigquit": ("drain, summary, exit 0", signal_case(signal.SIGQUIT)),
}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", default=None, help="comma-separated case names")
    parser.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "hostile.json")
    args = parser.parse_args()
    names = args.only.split(",") if args.only else list(CASES)
    unknown = set(names) - set(CASES)
    if unknown:
        parser.error(f"unknown case(s): {', '.join(sorted(unknown))} (known: {', '.join(CASES)})")
    rows = {}
    print(f"{'case':<30} {'limit':<44} {'RSS MiB':>8} {'s':>6} {'exit':>4}  result")
    for name in names:
        limit, run = CASES[name]
        with tempfile.TemporaryDirectory(prefix="tofd-hostile-") as tmp:
            row = {"limit": limit, **run(Path(tmp))}
        rows[name] = row
        print(f"{name:<30} {limit:<44} {row.get('peak_rss_mb', 0):>8.0f} {row.get('seconds', 0):>6} "
              f"{row.get('exit_code', '')!s:>4}  {'ok ' if row['passed'] else 'FAIL'} {row.get('result', '')}",
              flush=True)
    write_json(args.out, {"rss_bound_mb": RSS_BOUND_MB, "time_bound_s": TIME_BOUND_S, "cases": rows})
    failed = [name for name, row in rows.items() if not row["passed"]]
    print(f"{len(rows) - len(failed)}/{len(rows)} held" + (f"; failed: {', '.join(failed)}" if failed else ""))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
