"""What a batch run does: its inputs (recordings and dataset .npz files found from paths, directories, globs or
fsspec URLs), each cut into partitions (frame ranges: read through a recording's index, or a dataset's arrays),
each named by its digests.

A partition's output name is part-<first>-<stop>-<key>.parquet under <out>/recording=<name>/, where key =
sha256(input digest, first, stop, config digest, model digest, tofd version, row schema): the same work always
gets the same name, so --resume can skip it and a changed config, model or row layout never reuses a stale file.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass, field
from pathlib import Path, PurePosixPath

import fsspec
from mcap.writer import MCAP0_MAGIC

import tofd
from tofd.batch import rows
from tofd.drivers.recording.index import frame_index
from tofd.lab.dataset import DATASET_SUFFIX, DatasetError, DatasetFile

RECORDING_SUFFIX = ".mcap"
SOURCE_SUFFIXES = (".mkv", ".bag", ".db3")
"""Other files a directory is searched for (recognised by content when planned: tofd.drivers.opener)."""
INPUT_SUFFIXES = (RECORDING_SUFFIX, DATASET_SUFFIX, *SOURCE_SUFFIXES)


@dataclass(frozen=True, slots=True)
class Partition:
    """Chunks first <= k < stop of one recording (one frame per chunk), read at the given byte offsets; offsets is
    empty for a recording without an index (read sequentially, whole, as one partition). For a dataset .npz
    (dataset true): its frames first <= k < stop."""

    url: str
    recording: str  # output directory name: recording=<recording>
    first: int
    stop: int
    offsets: tuple[int, ...]
    frame_channels: tuple[tuple[int, str], ...]  # (channel id, role): tofd.drivers.recording.index.FrameIndex
    output: str  # URL of the partition's Parquet file
    dataset: bool = False
    reader: str = ""  # a tofd.drivers.opener format whose FrameSource reads the whole file sequentially (e.g. "k4a")

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
    """Recordings and datasets named by paths, directories (searched recursively for INPUT_SUFFIXES), glob patterns
    or fsspec URLs, in a stable order; an item that names nothing usable becomes an InputPlan with its error."""
    found: list[InputPlan] = []
    for item in items:
        try:
            fs, path = fsspec.core.url_to_fs(item)
            if any(c in item for c in "*?["):
                paths = sorted(p for p in fs.glob(path) if not fs.isdir(p))
            elif fs.isdir(path):
                paths = sorted(p for p in fs.find(path) if p.endswith(INPUT_SUFFIXES))
            elif fs.exists(path):
                paths = [path]
            else:
                found.append(InputPlan(item, error="no such file or directory"))
                continue
        except Exception as exc:  # noqa: BLE001 (bad URL, unknown protocol, missing credentials: report it)
            found.append(InputPlan(item, error=f"{type(exc).__name__}: {exc}"))
            continue
        if not paths:
            found.append(InputPlan(item, error="matches no recording or dataset"))
        found.extend(InputPlan(fs.unstrip_protocol(p) if fs.protocol not in ("file", ("file", "local")) else p)
                     for p in paths)
    seen: set[str] = set()
    kept = []
    for p in found:
        if p.error or p.url not in seen:
            kept.append(p)
            seen.add(p.url)
    return kept


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
        if inp.url.endswith(DATASET_SUFFIX):
            _plan_dataset(inp, out, run_digest, partition_frames, taken)
        elif inp.url.endswith(RECORDING_SUFFIX):
            _plan_recording(inp, out, run_digest, partition_frames, taken)
        elif "://" not in inp.url:
            _plan_by_content(inp, out, run_digest, partition_frames, taken)
        else:
            inp.error = f"not a recording or dataset (expected {' or '.join(INPUT_SUFFIXES)})"


def _ranges(n: int, partition_frames: int) -> list[tuple[int, int]]:
    """[first, stop) ranges covering n frames, of equal sizes within one frame, none above partition_frames."""
    parts = -(-n // partition_frames)
    return [(k * n // parts, (k + 1) * n // parts) for k in range(parts)]


def _output(out: str, recording: str, first: int, stop: int, input_digest: str, run_digest: str) -> str:
    key = digest([input_digest, first, stop, run_digest])[:16]
    return f"{out.rstrip('/')}/recording={recording}/part-{first:07d}-{stop:07d}-{key}.parquet"


def _plan_dataset(inp: InputPlan, out: str, run_digest: str, partition_frames: int, taken: set[str]) -> None:
    try:
        with DatasetFile(inp.url) as ds:
            ds.check()
            frames, input_digest = ds.frames, ds.digest
    except DatasetError as exc:
        inp.error = str(exc).removeprefix(f"{inp.url}: ")
        return
    except Exception as exc:  # noqa: BLE001 (unreadable input: report it, go on with the others)
        inp.error = f"cannot read: {type(exc).__name__}: {exc}"
        return
    inp.recording, inp.frames = _name(inp.url, taken), frames
    inp.partitions = [Partition(inp.url, inp.recording, first, stop, (), (),
                                _output(out, inp.recording, first, stop, input_digest, run_digest), dataset=True)
                      for first, stop in _ranges(frames, partition_frames)]


def _plan_recording(inp: InputPlan, out: str, run_digest: str, partition_frames: int, taken: set[str]) -> None:
    try:
        with fsspec.open(inp.url, "rb") as f:
            if f.read(len(MCAP0_MAGIC)) != MCAP0_MAGIC:
                inp.error = "not a tofd recording (no MCAP magic at its start)"
                return
            index = frame_index(f)
            if index is None:
                f.seek(0)
                input_digest = hashlib.file_digest(f, "sha256").hexdigest()  # type: ignore[arg-type]
    except Exception as exc:  # noqa: BLE001 (unreadable input: report it, go on with the others)
        inp.error = f"cannot read: {type(exc).__name__}: {exc}"
        return
    inp.recording = _name(inp.url, taken)
    if index is None:
        if "://" in inp.url:
            inp.error = "recording has no index (its writer did not finish); copy it locally to read it whole"
            return
        inp.indexed, bounds = False, [(0, 0)]
        offsets: tuple[int, ...] = ()
        channels: tuple[tuple[int, str], ...] = ()
    else:
        input_digest = index.digest
        inp.frames = index.chunk_count
        bounds = _ranges(index.chunk_count, partition_frames)
        offsets, channels = index.chunk_offsets, tuple(sorted(index.frame_channels))
    inp.partitions = [Partition(inp.url, inp.recording, first, stop, tuple(offsets[first:stop]), channels,
                                _output(out, inp.recording, first, stop, input_digest, run_digest))
                      for first, stop in bounds]


def _plan_by_content(inp: InputPlan, out: str, run_digest: str, partition_frames: int, taken: set[str]) -> None:
    """A local file named otherwise, recognised by its content (tofd.drivers.opener): a tofd recording, or a file a
    FrameSource reads (one sequential partition, like a recording without an index)."""
    from tofd.drivers.opener import identify

    try:
        fmt = identify(inp.url)
    except ValueError as exc:
        inp.error = str(exc).removeprefix(f"{inp.url}: ")
        return
    if fmt.read_as == "recording":
        _plan_recording(inp, out, run_digest, partition_frames, taken)
        return
    if Path(inp.url).is_dir():
        inp.error = f"a {fmt.description}: convert it with `tofd import` first"
        return
    with open(inp.url, "rb") as f:
        input_digest = hashlib.file_digest(f, "sha256").hexdigest()
    inp.recording, inp.indexed = _name(inp.url, taken), False
    inp.partitions = [Partition(inp.url, inp.recording, 0, 0, (), (),
                                _output(out, inp.recording, 0, 0, input_digest, run_digest), reader=fmt.name)]


RESULT_SECTIONS = ("segmentation", "features", "detector")
"""Config sections the per-frame results depend on (the others set how the service runs, not what it computes)."""


def run_digests(config_table: dict, model_dict: dict | None, evaluation: bool = True) -> dict[str, str]:
    """Digests naming a run's results: config (its RESULT_SECTIONS), model, tofd version, the Parquet row schema,
    all of them ("run"), which also tells a run without the eval_* columns (`evaluation` False) from one with them."""
    d = {"config": digest({k: config_table[k] for k in RESULT_SECTIONS}),
         "model": digest(model_dict) if model_dict else "none", "version": tofd.__version__,
         "schema": digest(rows.ROW_SCHEMA.to_string())}
    if not evaluation:
        d["evaluation"] = "off"
    d["run"] = digest(d)
    return d
