"""tofd.process_setup.keep_arrays_on_the_heap: a frame-sized array freed and allocated again stays on the heap (no
fresh mmap)."""

from __future__ import annotations

import json
import platform
import subprocess
import sys

import pytest

PROBE = """
import ctypes, json, sys
import numpy as np

class MallInfo2(ctypes.Structure):
    _fields_ = [(name, ctypes.c_size_t) for name in
                ("arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks", "fsmblks", "uordblks", "fordblks",
                 "keepcost")]

libc = ctypes.CDLL("libc.so.6")
libc.mallinfo2.restype = MallInfo2
if sys.argv[1] == "keep":
    from tofd.process_setup import keep_arrays_on_the_heap
    assert keep_arrays_on_the_heap()
before = libc.mallinfo2().hblkhd
frame = np.ones((8, 144, 176), np.float32)  # a frame's maps, 811 kB
print(json.dumps({"mmapped_bytes": libc.mallinfo2().hblkhd - before, "size": frame.nbytes}))
"""


def _mmapped(mode: str) -> dict:
    out = subprocess.run([sys.executable, "-c", PROBE, mode], capture_output=True, text=True, check=True)
    return json.loads(out.stdout)


@pytest.mark.skipif(platform.system() != "Linux" or platform.libc_ver()[0] != "glibc", reason="glibc only")
def test_frame_arrays_come_from_the_heap_not_fresh_mappings():
    default, kept = _mmapped("default"), _mmapped("keep")
    assert default["mmapped_bytes"] >= default["size"]  # glibc's default: its own mapping, faulted in anew
    assert kept["mmapped_bytes"] == 0
