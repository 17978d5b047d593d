"""A minimal MCAP writer for recordings whose every chunk is one unit (a frame): records, CRCs, summary, footer.

Chunks are compressed with zstd (CHUNK_ZSTD_LEVEL). Schemas and channels are written once, as top-level records
before the first chunk, and repeated in the summary; every chunk carries the CRC-32 of its records.
"""

from __future__ import annotations

import struct
import zlib
from collections import defaultdict
from typing import IO, Any

import zstandard
from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (
    Attachment,
    AttachmentIndex,
    Channel,
    Chunk,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    Message,
    MessageIndex,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)
from mcap.writer import MCAP0_MAGIC

CHUNK_ZSTD_LEVEL = 3
"""zstd level of every chunk: zstd's optimal parser would write the noisy 16-bit images a tenth smaller, at many times
the CPU to record and to decode, which a camera computer has less of than disk."""


class McapChunkWriter:
    """Writes an MCAP file to a binary stream: start(), schemas, channels, metadata, attachments, chunks of
    messages (write_chunk), finish(). Each call writes whole records to the stream (no buffering here)."""

    def __init__(self, stream: IO[bytes], *, profile: str, library: str) -> None:
        self._stream = stream
        self._compressor = zstandard.ZstdCompressor(level=CHUNK_ZSTD_LEVEL)
        self._schemas: list[Schema] = []
        self._channels: list[Channel] = []
        self._chunk_indexes: list[ChunkIndex] = []
        self._attachment_indexes: list[AttachmentIndex] = []
        self._metadata_indexes: list[MetadataIndex] = []
        self._stats = Statistics(message_count=0, schema_count=0, channel_count=0, attachment_count=0,
                                 metadata_count=0, chunk_count=0, message_start_time=0, message_end_time=0,
                                 channel_message_counts=defaultdict(int))
        stream.write(MCAP0_MAGIC)
        self._write(Header(profile=profile, library=library))

    def _write(self, *records: object) -> int:
        """Write records; returns the offset of the first."""
        builder = RecordBuilder()
        for record in records:
            record.write(builder)  # type: ignore[attr-defined]
        offset = self._stream.tell()
        self._stream.write(builder.end())
        return offset

    def add_schema(self, schema_id: int, name: str, encoding: str, data: bytes) -> None:
        schema = Schema(id=schema_id, name=name, encoding=encoding, data=data)
        self._schemas.append(schema)
        self._stats.schema_count += 1
        self._write(schema)

    def add_channel(self, channel_id: int, topic: str, message_encoding: str, schema_id: int) -> None:
        channel = Channel(id=channel_id, topic=topic, message_encoding=message_encoding, schema_id=schema_id,
                          metadata={})
        self._channels.append(channel)
        self._stats.channel_count += 1
        self._write(channel)

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        start = self._stream.tell()
        self._write(Metadata(name=name, metadata=data))
        self._metadata_indexes.append(MetadataIndex(offset=start, length=self._stream.tell() - start, name=name))
        self._stats.metadata_count += 1

    def add_attachment(self, log_time: int, name: str, media_type: str, data: bytes) -> None:
        start = self._stream.tell()
        self._write(Attachment(create_time=log_time, log_time=log_time, name=name, media_type=media_type,
                               data=data))
        self._attachment_indexes.append(AttachmentIndex(
            offset=start, length=self._stream.tell() - start, create_time=log_time, log_time=log_time,
            data_size=len(data), name=name, media_type=media_type))
        self._stats.attachment_count += 1

    def write_chunk(self, messages: list[Message]) -> None:
        """One zstd-compressed, CRC-checked chunk holding `messages` (in this order), and its message indexes."""
        builder = RecordBuilder()
        indexes: dict[int, MessageIndex] = {}
        for message in messages:
            indexes.setdefault(message.channel_id, MessageIndex(channel_id=message.channel_id, records=[]))
            indexes[message.channel_id].records.append((message.log_time, builder.count))
            message.write(builder)
            self._stats.channel_message_counts[message.channel_id] += 1
        records = builder.end()
        start, end = min(m.log_time for m in messages), max(m.log_time for m in messages)
        compressed = self._compressor.compress(records)
        chunk_start = self._write(Chunk(message_start_time=start, message_end_time=end,
                                        uncompressed_size=len(records), uncompressed_crc=zlib.crc32(records),
                                        compression="zstd", data=compressed))
        index_start = self._stream.tell()
        offsets = {}
        for channel_id, index in indexes.items():
            offsets[channel_id] = self._write(index)
        self._chunk_indexes.append(ChunkIndex(
            message_start_time=start, message_end_time=end, chunk_start_offset=chunk_start,
            chunk_length=index_start - chunk_start, message_index_offsets=offsets,
            message_index_length=self._stream.tell() - index_start, compression="zstd",
            compressed_size=len(compressed), uncompressed_size=len(records)))
        stats = self._stats
        stats.message_start_time = start if stats.message_count == 0 else min(stats.message_start_time, start)
        stats.message_end_time = max(stats.message_end_time, end)
        stats.message_count += len(messages)
        stats.chunk_count += 1

    def finish(self) -> None:
        """The end-of-data record, the summary (schemas, channels, statistics, indexes, offsets), the footer."""
        self._write(DataEnd(data_section_crc=0))
        summary_start = self._stream.tell()
        builder = RecordBuilder()
        groups: list[tuple[int, list[Any]]] = [
            (Opcode.SCHEMA, self._schemas), (Opcode.CHANNEL, self._channels), (Opcode.STATISTICS, [self._stats]),
            (Opcode.CHUNK_INDEX, self._chunk_indexes), (Opcode.ATTACHMENT_INDEX, self._attachment_indexes),
            (Opcode.METADATA_INDEX, self._metadata_indexes)]
        offsets = []
        for opcode, records in groups:
            group_start = builder.count
            for record in records:
                record.write(builder)
            offsets.append(SummaryOffset(group_opcode=opcode, group_start=summary_start + group_start,
                                         group_length=builder.count - group_start))
        offset_start = summary_start + builder.count
        for offset in offsets:
            offset.write(builder)
        summary = builder.end()
        footer_head = struct.pack("<BQQQ", Opcode.FOOTER, 8 + 8 + 4, summary_start, offset_start)
        self._stream.write(summary)
        self._write(Footer(summary_start=summary_start, summary_offset_start=offset_start,
                           summary_crc=zlib.crc32(footer_head, zlib.crc32(summary))))
        self._stream.write(MCAP0_MAGIC)
