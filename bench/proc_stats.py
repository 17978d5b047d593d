"""Per-process resource readings from /proc (Linux): resident memory and CPU time, by pid."""

from __future__ import annotations

import os
from pathlib import Path

TICKS_PER_S = os.sysconf("SC_CLK_TCK")


def rss_mb(pid: int) -> float:
    """Resident set size (VmRSS) of one process in MiB; 0 if it is gone."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return 0.0


def cpu_s(pid: int) -> float:
    """User + system CPU seconds used so far by one process (its threads included); 0 if it is gone."""
    return _stat_cpu_s(Path(f"/proc/{pid}/stat"))


def own_thread_cpu_s(tid: int) -> float:
    """User + system CPU seconds used so far by one thread of this process (its native id); 0 if it is gone.
    (/proc/TID/stat would give the whole process's.)"""
    return _stat_cpu_s(Path(f"/proc/self/task/{tid}/stat"))


def _stat_cpu_s(path: Path) -> float:
    try:
        stat = path.read_text()
    except OSError:
        return 0.0
    fields = stat[stat.rindex(")") + 2:].split()  # after "pid (comm) ": state is field 3, utime 14, stime 15
    return (int(fields[11]) + int(fields[12])) / TICKS_PER_S
