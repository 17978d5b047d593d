"""A ring of frame slots in one shared-memory block: the parent writes range/amplitude, a worker writes the
mask and feature maps back (SLOT_FIELDS; the viewer hand-off uses its own fields). Only slot indices cross the
process boundary, never arrays."""

from __future__ import annotations

import os
import secrets
from multiprocessing import shared_memory
from pathlib import Path

import numpy as np

from tofd.algorithm.names import MAP_NAMES

SLOT_FIELDS: tuple[tuple[str, type], ...] = (
    ("range_m", np.float32),  # input: radial range, metres, NaN invalid
    ("amplitude", np.float32),  # input: sensor units
    ("mask", np.bool_),  # output: foreground
    *((name, np.float32) for name in MAP_NAMES),  # outputs: feature maps, NaN outside the foreground
)

SHM_PREFIX = "tofd_"  # /dev/shm/tofd_<pid of the owner>_<use>_<random>
SHM_DIR = Path("/dev/shm")


def remove_stale_segments() -> list[str]:
    """Unlink the slot rings of tofd processes that are gone (a kill -9 skips the owner's unlink); their names."""
    removed = []
    for path in SHM_DIR.glob(SHM_PREFIX + "*"):
        try:
            pid = int(path.name[len(SHM_PREFIX):].split("_")[0])
            os.kill(pid, 0)
        except ValueError:
            continue  # not one of ours
        except ProcessLookupError:
            path.unlink(missing_ok=True)
            removed.append(path.name)
        except PermissionError:
            continue  # alive, another user's
    return removed


Fields = tuple[tuple[str, type], ...]


def _layout(shape: tuple[int, int], fields: Fields) -> tuple[dict[str, tuple[int, type]], int]:
    """Byte offset of each field within a slot (64-byte aligned) and the slot size in bytes."""
    offsets, offset = {}, 0
    for name, dtype in fields:
        offsets[name] = (offset, dtype)
        offset += -(-shape[0] * shape[1] * np.dtype(dtype).itemsize // 64) * 64
    return offsets, offset


def local_slot(shape: tuple[int, int]) -> dict[str, np.ndarray]:
    """One slot's arrays in this process's memory (for running a FeatureStage without workers)."""
    return {name: np.empty(shape, dtype) for name, dtype in SLOT_FIELDS}


class SlotRing:
    """`n_slots` frame slots of `shape` (rows, columns) in shared memory, each holding `fields` (name, dtype).

    The creating process owns the block (`create`, then `close(unlink=True)`); workers `attach` by name.
    Free-slot bookkeeping (`acquire`/`release`) lives in the creating process only, and its caller serialises
    it (tofd.service.pipeline.pool.WorkerPool holds its lock around every call).
    """

    def __init__(self, shm: shared_memory.SharedMemory, n_slots: int, shape: tuple[int, int], owner: bool,
                 fields: Fields = SLOT_FIELDS):
        self.shm, self.n_slots, self._owner = shm, n_slots, owner
        self.shape: tuple[int, int] = (int(shape[0]), int(shape[1]))
        offsets, slot_bytes = _layout(self.shape, fields)
        self._views = [
            {name: np.ndarray(self.shape, dtype, shm.buf, k * slot_bytes + off)
             for name, (off, dtype) in offsets.items()}
            for k in range(n_slots)
        ]
        self._free = list(range(n_slots))

    @classmethod
    def create(cls, n_slots: int, shape: tuple[int, int], fields: Fields = SLOT_FIELDS,
               use: str = "workers") -> SlotRing:
        """A new block named for its owner's pid and its `use`."""
        if n_slots < 1:
            raise ValueError(f"n_slots: must be >= 1, got {n_slots}")
        remove_stale_segments()
        size = n_slots * _layout((int(shape[0]), int(shape[1])), fields)[1]
        name = f"{SHM_PREFIX}{os.getpid()}_{use}_{secrets.token_hex(4)}"
        return cls(shared_memory.SharedMemory(name=name, create=True, size=size), n_slots, shape, True, fields)

    @classmethod
    def attach(cls, name: str, n_slots: int, shape: tuple[int, int], fields: Fields = SLOT_FIELDS) -> SlotRing:
        return cls(shared_memory.SharedMemory(name=name), n_slots, shape, False, fields)

    @property
    def name(self) -> str:
        return self.shm.name

    def views(self, slot: int) -> dict[str, np.ndarray]:
        """The arrays of one slot, by field name (writable views into shared memory)."""
        return self._views[slot]

    @property
    def free(self) -> int:
        """How many slots are free."""
        return len(self._free)

    def acquire(self) -> int | None:
        """A free slot index, or None if every slot is in use."""
        return self._free.pop() if self._free else None

    def release(self, slot: int) -> None:
        if slot in self._free:
            raise RuntimeError(f"slot {slot} released twice")
        self._free.append(slot)

    def close(self) -> None:
        """Drop the views and detach; the owner also unlinks the block."""
        self._views = []
        self.shm.close()
        if self._owner:
            self.shm.unlink()
