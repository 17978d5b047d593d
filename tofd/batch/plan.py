"""What a batch run does: its inputs (recordings found from paths, directories, globs or fsspec URLs), each cut
into partitions (frame ranges read through the recording's index), each named by its digests.

A partition's output name is part-<first>-<stop>-<key>.parquet under <out>/recording=<name>/, where key =
sha256(input digest, first, stop, config digest, model digest, tofd version): the same work always gets the same
name, so --resume can skip it and a changed config or model never reuses a stale file.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass, field
from pathlib import PurePosixPath

import fsspec
from mcap.writer import MCAP0_MAGIC

import tofd
from drivers.recording.index import frame_index

RECORDING_SUFFIX = ".mcap"


@dataclass(frozen=True, slots=True)
class Partition:
    """Chunks first <= k < stop of one recording (one frame per chunk), read at the given byte offsets; offsets is
    empty for a recording without an index (read sequentially, whole, as one partition)."""

    url: str
    recording: str  # output directory name: recording=<recording>
    first: int
    stop: int
    offsets: tuple[int, ...]
    frame_channels: tuple[tuple[int, str], ...]  # (channel id, role): drivers.recording.index.FrameIndex
    output: str  # URL of the partition's Parquet file

    def to_json(self) -> str:
        return json.dumps(asdict(self))

    @classmethod
    def from_json(cls, text: str) -> Partition:
        d = json.loads(text)
        return cls(**{**d, "offsets": tuple(d["offsets"]), "frame_channels": tuple(map(tuple, d["frame_channels"]))})

    @property
    def frames(self) -> int:
        return self.stop - self.first


@dataclass(slots=True)
class InputPlan:
    """One input: its partitions, or the one-line reason it cannot be processed."""

    url: str
    recording: str = ""
    frames: int = 0
    indexed: bool = True
    partitions: list[Partition] = field(default_factory=list)
    error: str = ""


def digest(obj: object) -> str:
    """sha256 of a JSON-ready object (keys sorted)."""
    return hashlib.sha256(json.dumps(obj, sort_keys=True).encode()).hexdigest()


def expand_inputs(items: list[str]) -> list[InputPlan]:
    """Recordings named by paths, directories (searched recursively for *.mcap), glob patterns or fsspec URLs, in
    a stable order; an item that names nothing usable becomes an InputPlan with its error."""
    found: list[InputPlan] = []
    for item in items:
        try:
            fs, path = fsspec.core.url_to_fs(item)
            if any(c in item for c in "*?["):
                paths = sorted(p for p in fs.glob(path) if not fs.isdir(p))
            elif fs.isdir(path):
                paths = sorted(p for p in fs.find(path) if p.endswith(RECORDING_SUFFIX))
            elif fs.exists(path):
                paths = [path]
            else:
                found.append(InputPlan(item, error="no such file or directory"))
                continue
        except Exception as exc:  # noqa: BLE001 (bad URL, unknown protocol, missing credentials: report it)
            found.append(InputPlan(item, error=f"{type(exc).__name__}: {exc}"))
            continue
        if not paths:
            found.append(InputPlan(item, error="matches no recording"))
        found.extend(InputPlan(fs.unstrip_protocol(p) if fs.protocol not in ("file", ("file", "local")) else p)
                     for p in paths)
    seen: set[str] = set()
    return [p for p in found if p.error or not (p.url in seen or seen.add(p.url))]


def _name(url: str, taken: set[str]) -> str:
    stem = PurePosixPath(url).name.split(".")[0] or "recording"
    name, k = stem, 2
    while name in taken:
        name, k = f"{stem}_{k}", k + 1
    taken.add(name)
    return name


def plan_inputs(inputs: list[InputPlan], out: str, run_digest: str, partition_frames: int) -> None:
    """Fill in each input's partitions (in place); run_digest = digest of config, model and tofd version."""
    taken: set[str] = set()
    for inp in inputs:
        if inp.error:
            continue
        if not inp.url.endswith(RECORDING_SUFFIX):
            inp.error = f"not a recording (expected {RECORDING_SUFFIX}; dataset .npz inputs are not supported yet)"
            continue
        try:
            with fsspec.open(inp.url, "rb") as f:
                if f.read(len(MCAP0_MAGIC)) != MCAP0_MAGIC:
                    inp.error = "not a tofd recording (no MCAP magic at its start)"
                    continue
                index = frame_index(f)
                if index is None:
                    f.seek(0)
                    input_digest = hashlib.file_digest(f, "sha256").hexdigest()  # type: ignore[arg-type]
        except Exception as exc:  # noqa: BLE001 (unreadable input: report it, go on with the others)
            inp.error = f"cannot read: {type(exc).__name__}: {exc}"
            continue
        inp.recording = _name(inp.url, taken)
        if index is None:
            if "://" in inp.url:
                inp.error = "recording has no index (its writer did not finish); copy it locally to read it whole"
                continue
            inp.indexed, bounds, offsets, channels = False, [(0, 0)], (), ()
        else:
            input_digest = index.digest
            n = index.chunk_count
            inp.frames = n
            parts = -(-n // partition_frames)  # equal sizes (within one frame), none above partition_frames
            bounds = [(k * n // parts, (k + 1) * n // parts) for k in range(parts)]
            offsets, channels = index.chunk_offsets, tuple(sorted(index.frame_channels))
        for first, stop in bounds:
            key = digest([input_digest, first, stop, run_digest])[:16]
            output = f"{out.rstrip('/')}/recording={inp.recording}/part-{first:07d}-{stop:07d}-{key}.parquet"
            inp.partitions.append(Partition(inp.url, inp.recording, first, stop, tuple(offsets[first:stop]),
                                            channels, output))


RESULT_SECTIONS = ("segmentation", "features", "detector")
"""Config sections the per-frame results depend on (the others set how the service runs, not what it computes)."""


def run_digests(config_table: dict, model_dict: dict | None) -> dict[str, str]:
    """Digests naming a run's results: config (its RESULT_SECTIONS), model, tofd version, all three ("run")."""
    d = {"config": digest({k: config_table[k] for k in RESULT_SECTIONS}),
         "model": digest(model_dict) if model_dict else "none", "version": tofd.__version__}
    d["run"] = digest(d)
    return d
