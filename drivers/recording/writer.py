"""RecordingWriter: writes Frames to a crash-safe, self-describing MCAP recording.

Crash safety: every frame is its own zstd-compressed, CRC-checked MCAP chunk (its header, range and amplitude
images and calibration), handed to the operating system (flushed) before write() returns, so a process killed
at any moment (kill -9) leaves a file whose every completed frame replays; only the frame being written is
lost. With `fsync_interval_s` the file is also forced to disk that often, which bounds the loss on power
failure. Layout: drivers/recording/format.py.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Mapping
from importlib import metadata as importlib_metadata
from pathlib import Path

from mcap.records import Message
from mcap.writer import LIBRARY_IDENTIFIER

from tofd.drivers.frame import Frame
from tofd.drivers.recording import format as fmt
from tofd.drivers.recording import schemas
from tofd.drivers.recording.mcap_writer import McapChunkWriter


def software_version() -> str:
    """Version of the installed tofd distribution (read from package metadata: drivers never imports tofd)."""
    try:
        return importlib_metadata.version("tofd")
    except importlib_metadata.PackageNotFoundError:
        return "unknown"


class RecordingWriter:
    """Append Frames to an MCAP recording at `path` (created or overwritten).

    `config` (a JSON-serialisable mapping, e.g. the service config as a dict) is stored as the attachment
    "config.json". The camera's intrinsics, device identity and registers (SR3000) or sensor info (other cameras)
    are stored as metadata from the first frame. close() (or leaving the `with` block) writes MCAP's summary and
    footer; a recording that was never closed still replays (the reader reports it as truncated after its last
    complete frame).
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
        self._writer = McapChunkWriter(self._file, profile=fmt.PROFILE,
                                       library=f"tofd/{software_version()} {LIBRARY_IDENTIFIER}")
        self._writer.add_metadata(fmt.META_RECORDING, fmt.seal_metadata({
            "format_version": str(fmt.FORMAT_VERSION),
            "software_version": software_version(),
            "created_wall_s": repr(time.time()),
            "layout": "see tofd's drivers/recording/format.py",
        }))
        if config is not None:
            self._writer.add_attachment(time.time_ns(), fmt.CONFIG_ATTACHMENT, "application/json",
                                        json.dumps(config, indent=1, default=str).encode())
        for schema_id, name in enumerate(fmt.SCHEMAS, start=1):
            self._writer.add_schema(schema_id, name, fmt.MESSAGE_ENCODING, schemas.schema_data(name))
        for channel in fmt.CHANNELS:
            self._writer.add_channel(channel.id, channel.topic, fmt.MESSAGE_ENCODING,
                                     fmt.SCHEMAS.index(channel.schema) + 1)
        self._file.flush()

    @property
    def bytes_written(self) -> int:
        """Size of the file so far, bytes."""
        return self._file.tell()

    def write(self, frame: Frame) -> None:
        """Append one frame; when this returns the frame survives the death of this process."""
        if self._file.closed:
            raise ValueError(f"recording {self.path} is closed")
        messages = fmt.encode_frame(frame)  # first: a frame that does not encode leaves the file as it was
        log_time, publish_time, sequence = fmt.message_times(frame)
        if self.frames_written == 0:
            self._writer.add_metadata(fmt.META_INTRINSICS, fmt.to_metadata(frame.intrinsics))
            self._writer.add_metadata(fmt.META_DEVICE, fmt.to_metadata(frame.device))
            if frame.registers is not None:
                self._writer.add_metadata(fmt.META_REGISTERS, fmt.to_metadata(frame.registers))
            if frame.sensor is not None:
                self._writer.add_metadata(fmt.META_SENSOR, fmt.sensor_metadata(frame.sensor))
        self._writer.write_chunk([
            Message(channel_id=channel.id, log_time=log_time, publish_time=publish_time, sequence=sequence, data=data)
            for channel, data in zip(fmt.CHANNELS, messages, strict=True)])
        self._file.flush()  # hands the chunk to the OS
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
