"""Child processes that die with their parent: Linux PR_SET_PDEATHSIG, so a `kill -9` of tofd leaves no
viewer holding its ports and no worker holding shared memory."""

from __future__ import annotations

import ctypes
import os
import signal
import sys

PR_SET_PDEATHSIG = 1  # <linux/prctl.h>


def die_with_parent(parent_pid: int | None = None) -> None:
    """Have the kernel SIGKILL this process when its parent exits; exit now if the parent is already gone
    (`parent_pid`: the pid the caller expects as its parent). No-op off Linux."""
    if not sys.platform.startswith("linux"):
        return
    libc = ctypes.CDLL(None, use_errno=True)
    libc.prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
    if parent_pid is not None and os.getppid() != parent_pid:
        os._exit(1)


def preexec_die_with_parent() -> None:
    """A subprocess.Popen preexec_fn: the child is killed when the process that started it exits."""
    die_with_parent()
