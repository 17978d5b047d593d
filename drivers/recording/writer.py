"""RecordingWriter: writes Frames to a crash-safe, self-describing MCAP recording.

Crash safety: every frame is its own zstd-compressed, CRC-checked MCAP chunk, handed to the operating
system (flushed) before write() returns, so a process killed at any moment (kill -9) leaves a file whose
every completed frame replays; only the frame being written is lost. With `fsync_interval_s` the file is
also forced to disk that often, which bounds the loss on power failure. Layout: drivers/recording/format.py.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Mapping
from importlib import metadata as importlib_metadata
from pathlib import Path

from mcap.writer import CompressionType, Writer

from drivers.frame import Frame
from drivers.recording import format as fmt


def software_version() -> str:
    """Version of the installed tofd distribution (read from package metadata: drivers never imports tofd)."""
    try:
        return importlib_metadata.version("tofd")
    except importlib_metadata.PackageNotFoundError:
        return "unknown"


class RecordingWriter:
    """Append Frames to an MCAP recording at `path` (created or overwritten).

    `config` (a JSON-serialisable mapping, e.g. the service config as a dict) is stored as the attachment
    "config.json". The camera's intrinsics, device identity and registers are stored as metadata from the
    first frame. close() (or leaving the `with` block) writes MCAP's summary and footer; a recording that
    was never closed still replays (the reader reports it as truncated after its last complete frame).
    """

    def __init__(self, path: str | Path, *, config: Mapping | None = None,
                 fsync_interval_s: float | None = 1.0) -> None:
        if fsync_interval_s is not None and not fsync_interval_s > 0:
            raise ValueError(f"fsync_interval_s: expected > 0 s or None, got {fsync_interval_s!r}")
        self.path = Path(path)
        self.frames_written = 0
        self._fsync_interval_s = fsync_interval_s
        self._last_sync = time.monotonic()
        self._file = open(self.path, "wb")  # noqa: SIM115 (closed in close())
        self._writer = Writer(self._file, chunk_size=1 << 30, compression=CompressionType.ZSTD)
        self._writer.start(profile=fmt.PROFILE)
        self._writer.add_metadata(fmt.META_RECORDING, fmt.seal_metadata({
            "format_version": str(fmt.FORMAT_VERSION),
            "software_version": software_version(),
            "created_wall_s": repr(time.time()),
            "layout": "see schema tofd.Frame and tofd's drivers/recording/format.py",
        }))
        if config is not None:
            now_ns = time.time_ns()
            self._writer.add_attachment(now_ns, now_ns, fmt.CONFIG_ATTACHMENT, "application/json",
                                        json.dumps(config, indent=1, default=str).encode())
        schema_id = self._writer.register_schema(fmt.FRAME_SCHEMA_NAME, "jsonschema",
                                                 json.dumps(fmt.FRAME_SCHEMA).encode())
        self._channel = self._writer.register_channel(fmt.FRAME_TOPIC, fmt.FRAME_ENCODING, schema_id)
        self._writer.flush()

    @property
    def bytes_written(self) -> int:
        """Size of the file so far, bytes."""
        return self._file.tell()

    def write(self, frame: Frame) -> None:
        """Append one frame; when this returns the frame survives the death of this process."""
        if self._file.closed:
            raise ValueError(f"recording {self.path} is closed")
        data = fmt.encode_frame(frame)  # first: a frame that does not encode leaves the file as it was
        if self.frames_written == 0:
            self._writer.add_metadata(fmt.META_INTRINSICS, fmt.to_metadata(frame.intrinsics))
            self._writer.add_metadata(fmt.META_DEVICE, fmt.to_metadata(frame.device))
            self._writer.add_metadata(fmt.META_REGISTERS, fmt.to_metadata(frame.registers))
        self._writer.add_message(
            self._channel,
            log_time=int(round(frame.host_wall_s * 1e9)),
            publish_time=int(frame.timestamp_us) * 1000,
            sequence=int(frame.frame_counter) & 0xFFFFFFFF,
            data=data,
        )
        self._writer.flush()  # closes the chunk (CRC, zstd) and hands it to the OS
        self.frames_written += 1
        now = time.monotonic()
        if self._fsync_interval_s is not None and now - self._last_sync >= self._fsync_interval_s:
            os.fsync(self._file.fileno())
            self._last_sync = now

    def close(self) -> None:
        """Write the summary and footer and close the file. Idempotent."""
        if self._file.closed:
            return
        try:
            self._writer.finish()
            self._file.flush()
            os.fsync(self._file.fileno())
        finally:
            self._file.close()

    def __enter__(self) -> RecordingWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
