"""The raw messages of a ROS 1 or ROS 2 bag, with the readable prefix of a damaged or truncated one.

rosbags reads intact bags through their index (ROS 1) or database (ROS 2 sqlite3) and MCAP summary. A bag cut
short loses exactly those (a ROS 1 index sits at the end, a cut sqlite3 file is "malformed"), so when rosbags
cannot open it, the records are read in file order instead: ROS 1 records one by one (chunks uncompressed,
bz2 or LZ4), the sqlite3 `messages` table row by row, MCAP messages in stream order. Reading stops at the first
record that cannot be read and `damage` says where and why. A ROS 1 or ROS 2 MCAP chunk may decompress to at
most MAX_CHUNK_BYTES (checked streaming, before rosbags decompresses it whole: a compression bomb is damage where it
starts), and a cut sqlite3 file is read as the pages it has, whatever page count its header claims. Message
definitions come from the bag where it has them (ROS 1 always; ROS 2 where recorded), else the latest ROS 2
definitions, registered leniently: a vendor's definition that contradicts its bytes (Orbbec's Image) is read by
tofd.drivers.bags.ros1_wire instead.
"""

from __future__ import annotations

import bz2
import sqlite3
import struct
from collections.abc import Collection, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mcap.writer import MCAP0_MAGIC

from tofd.drivers.source import DriverError

ROS1_MAGIC = b"#ROSBAG V2.0\n"
SQLITE_MAGIC = b"SQLite format 3\x00"
OP_MESSAGE, OP_CHUNK, OP_CONNECTION = 0x02, 0x05, 0x07
MAX_CHUNK_BYTES = 128 << 20
"""Most bytes one ROS 1 chunk may decompress to (rosbag writes chunks of about 768 KiB: a few images)."""
MAX_HEADER_BYTES = 1 << 20
"""Largest ROS 1 record header read to check a chunk (a chunk's has two short fields)."""
_PIECE = 1 << 20


class BagError(DriverError):
    """A bag that cannot be imported: unreadable, a topic missing or of the wrong type, an image tofd cannot use."""


class DamagedMessage(BagError):
    """A message whose bytes do not decode (garbled in the file): its frame is ledgered and the bag read on.
    frame_number: the device's number of the frame it belongs to, when known."""

    def __init__(self, message: str, frame_number: int | None = None) -> None:
        super().__init__(message)
        self.frame_number = frame_number


@dataclass(frozen=True, slots=True)
class Topic:
    """A topic of a bag: its message type (ROS 2 spelling, pkg/msg/Name) and message count (-1: unknown)."""

    msgtype: str
    count: int


@dataclass(frozen=True, slots=True)
class RawMessage:
    topic: str
    log_ns: int  # the bag's receive time
    raw: bytes | memoryview


def _ros2_msgtype(name: str) -> str:
    """pkg/Name (ROS 1) -> pkg/msg/Name."""
    return name if name.count("/") != 1 else name.replace("/", "/msg/")


class BagReader:
    """Topics and raw messages of a bag file or ROS 2 bag directory; `deserialize` decodes one message.

    Opening raises BagError when nothing of the file can be read; a damaged part later in the file ends
    `messages` early with `damage` set (e.g. "truncated at byte 30000 of 45869: ...").
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        if not self.path.exists():
            raise BagError(f"{self.path}: no such file or directory")
        self.ros1 = self.path.is_file() and _starts_with(self.path, ROS1_MAGIC)
        self.damage: str | None = None
        self._fallback: _Ros1Scan | _SqliteScan | _McapScan | None = None
        self._reader: Any = None
        try:
            self._reader = _open_rosbags(self.path, self.ros1)
            if self.ros1:
                _check_chunks(self.path, [info.pos for info in self._reader.chunk_infos])
            else:
                for storage in [self.path] if self.path.is_file() else sorted(self.path.glob("*.mcap")):
                    if _starts_with(storage, MCAP0_MAGIC):
                        _check_mcap_chunks(storage)
            connections = self._reader.connections
            self._connections = {c.id: c for c in connections}
            self.topics = _topics((c.topic, c.msgtype, c.msgcount) for c in connections)
            definitions = [(c.msgtype, c.msgdef.data) for c in connections if c.msgdef.data]
        except ImportError:  # rosbags itself is missing: the 'rosbag' extra (tofd.extras) names what to install
            raise
        except Exception as exc:  # noqa: BLE001 (whatever rosbags cannot open is read record by record)
            self._fallback = _fallback(self.path, self.ros1, exc)
            self.topics = self._fallback.topics
            definitions = self._fallback.definitions
        self.typestore = _typestore(definitions, self.ros1)

    @property
    def recovering(self) -> bool:
        """Whether the bag is read record by record because rosbags could not open it (it is damaged)."""
        return self._fallback is not None

    def messages(self, topics: Collection[str]) -> Iterator[RawMessage]:
        """The messages of `topics` (all when empty) in bag order, up to the first damaged record."""
        if self._fallback is not None:
            yield from self._fallback.messages(topics)
            self.damage = self._fallback.damage
            return
        connections = [c for c in self._connections.values() if not topics or c.topic in topics]
        try:
            for connection, log_ns, raw in self._reader.messages(connections=connections):
                yield RawMessage(connection.topic, log_ns, raw)
        except Exception as exc:  # noqa: BLE001 (a record rosbags cannot read ends the readable part)
            self.damage = f"unreadable record ({type(exc).__name__}: {exc})"

    def deserialize(self, raw: bytes | memoryview, msgtype: str) -> Any:
        """The decoded message; BagError names the type when its bytes do not fit its definition."""
        try:
            if self.ros1:
                return self.typestore.deserialize_ros1(bytes(raw), msgtype)
            return self.typestore.deserialize_cdr(bytes(raw), msgtype)
        except Exception as exc:  # noqa: BLE001 (any decoding failure is a message tofd cannot read)
            raise DamagedMessage(f"{msgtype}: unreadable message ({type(exc).__name__}: {exc})") from None

    def close(self) -> None:
        if self._reader is not None:
            self._reader.close()
            self._reader = None
        if self._fallback is not None:
            self._fallback.close()


def _starts_with(path: Path, magic: bytes) -> bool:
    with open(path, "rb") as f:
        return f.read(len(magic)) == magic


def _open_rosbags(path: Path, ros1: bool) -> Any:
    from rosbags.rosbag1 import Reader as Reader1
    from rosbags.rosbag2 import Reader as Reader2

    if not ros1 and path.is_file() and path.suffix not in (".db3", ".mcap"):
        raise BagError(f"a ROS 2 storage file named {path.suffix or 'without a suffix'} (rosbags goes by .db3/.mcap)")
    reader = Reader1(path) if ros1 else Reader2(path)
    reader.open()
    return reader


def _topics(rows: Iterator[tuple[str, str, int]]) -> dict[str, Topic]:
    topics: dict[str, Topic] = {}
    for topic, msgtype, count in rows:
        known = topics.get(topic)
        topics[topic] = Topic(_ros2_msgtype(msgtype), count + (known.count if known else 0))
    return topics


def _typestore(definitions: list[tuple[str, str]], ros1: bool) -> Any:
    """A typestore with the bag's own definitions (each registered alone; one that does not parse or
    contradicts another is left out), over the latest ROS 2 ones for a ROS 2 bag without definitions."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    if not ros1 and not definitions:
        return get_typestore(Stores.LATEST)
    store = get_typestore(Stores.EMPTY if ros1 else Stores.LATEST)
    for msgtype, text in definitions:
        try:
            store.register(get_types_from_msg(text, _ros2_msgtype(msgtype)))
        except Exception:  # noqa: BLE001,S112 (a vendor definition rosbags cannot take: read by hand if needed)
            continue
    return store


def _check_chunks(path: Path, offsets: list[int]) -> None:
    """ValueError when a ROS 1 chunk at one of `offsets` decompresses to more than MAX_CHUNK_BYTES (decompressed
    piece by piece and counted, never held whole)."""
    with open(path, "rb") as f:
        for pos in offsets:
            f.seek(pos)
            (header_len,) = struct.unpack("<I", f.read(4).ljust(4, b"\xff"))
            if header_len > MAX_HEADER_BYTES:
                raise ValueError(f"a chunk header of {header_len} bytes at byte {pos}")
            fields, _, _ = _fields(memoryview(f.read(header_len)), 0, header_len)
            (data_len,) = struct.unpack("<I", f.read(4).ljust(4, b"\0"))
            compression = fields.get("compression", b"none").decode()
            if compression != "none":
                decompress(compression, f.read(data_len), f"the chunk at byte {pos}", keep=False)


def _check_mcap_chunks(path: Path) -> None:
    """ValueError when a chunk of the MCAP file `path` (by its summary's chunk index) declares or decompresses to
    more than MAX_CHUNK_BYTES (counted in pieces, never held whole); a file without a summary is left to rosbags."""
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        try:
            summary = make_reader(f).get_summary()
        except Exception:  # noqa: BLE001 (no readable summary: rosbags fails on it, the scan reads it bounded)
            return
        for index in [] if summary is None else summary.chunk_indexes:
            where = f"the chunk at byte {index.chunk_start_offset}"
            if index.uncompressed_size > MAX_CHUNK_BYTES:
                raise ValueError(f"{where} declares {index.uncompressed_size} bytes decompressed, more than "
                                 f"{MAX_CHUNK_BYTES}")
            if index.compression:
                f.seek(index.chunk_start_offset + 9 + 40 + len(index.compression))  # records after the header
                decompress(index.compression, f.read(index.compressed_size), where, keep=False)


def _pieces(compression: str, data: bytes) -> Iterator[bytes]:
    """The decompressed bytes of `data` (bz2, lz4 or zstd) in pieces of at most _PIECE bytes, as far as it goes."""
    if compression == "zstd":
        import zstandard

        with zstandard.ZstdDecompressor().stream_reader(data) as reader:
            while piece := reader.read(_PIECE):
                yield piece
        return
    if compression == "bz2":
        decompressor: Any = bz2.BZ2Decompressor()
    elif compression == "lz4":
        import lz4.frame

        decompressor = lz4.frame.LZ4FrameDecompressor()
    else:
        raise ValueError(f"chunk compression {compression!r} is not none, bz2, lz4 or zstd")
    while not decompressor.eof:
        piece = decompressor.decompress(data, max_length=_PIECE)
        data = b""
        if not piece and decompressor.needs_input:
            return
        yield piece


def decompress(compression: str, body: bytes | memoryview, where: str, keep: bool = True) -> memoryview:
    """`body` decompressed (bz2, lz4 or zstd) in pieces, as far as it goes (a body cut short gives its complete
    blocks); ValueError naming `where` past MAX_CHUNK_BYTES. keep=False only counts (returns an empty view)."""
    pieces, total = [], 0
    for piece in _pieces(compression, bytes(body)):
        total += len(piece)
        if total > MAX_CHUNK_BYTES:
            raise ValueError(f"{where} decompresses to more than {MAX_CHUNK_BYTES} bytes (a compression bomb?)")
        if keep:
            pieces.append(piece)
    return memoryview(b"".join(pieces))


def _fallback(path: Path, ros1: bool, exc: Exception) -> _Ros1Scan | _SqliteScan | _McapScan:
    """A record-by-record reader of a bag rosbags could not open (chosen by content: a renamed file too), or
    BagError when that cannot read it either."""
    why = f"{type(exc).__name__}: {exc}"
    files = sorted(path.glob("*.db3")) + sorted(path.glob("*.mcap")) if path.is_dir() else [path]
    try:
        if ros1:
            return _Ros1Scan(path)
        for candidate in files:
            if _starts_with(candidate, SQLITE_MAGIC):
                return _SqliteScan(candidate)
            if _starts_with(candidate, MCAP0_MAGIC):
                return _McapScan(candidate)
    except Exception as second:  # noqa: BLE001 (unreadable either way: say what rosbags said, and ours)
        why = f"{why}; read record by record: {type(second).__name__}: {second}"
    raise BagError(f"{path}: not a readable ROS bag ({why})")


class _Ros1Scan:
    """ROS 1 bag records in file order (format 2.0: op-coded records, chunks of connections and messages)."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.damage: str | None = None
        self._data = path.read_bytes()
        self.connections: dict[int, tuple[str, str, str]] = {}  # conn id -> topic, type, definition
        self._counts: dict[int, int] = {}
        for _ in self._records(None):  # a first pass for the topics and counts
            pass
        self.damage = None
        if not self.connections:
            raise BagError("no connection record before the damage")
        self.topics = _topics((topic, msgtype, self._counts.get(cid, 0))
                              for cid, (topic, msgtype, _) in self.connections.items())
        self.definitions = [(msgtype, text) for _, msgtype, text in self.connections.values()]

    def messages(self, topics: Collection[str]) -> Iterator[RawMessage]:
        yield from self._records(topics)

    def _records(self, topics: Collection[str] | None) -> Iterator[RawMessage]:
        """Messages of the wanted topics (None: count them all), following chunks, until the data ends."""
        try:
            yield from self._walk(memoryview(self._data), len(ROS1_MAGIC), topics)
        except (ValueError, KeyError, struct.error, OSError, EOFError, RuntimeError) as exc:  # lz4: RuntimeError
            self.damage = f"{exc}"

    def _walk(self, data: memoryview, pos: int, topics: Collection[str] | None) -> Iterator[RawMessage]:
        while pos < len(data):
            fields, body, end = _record(data, pos)
            op = fields.get("op", b"\xff")[0]
            if op == OP_CHUNK:
                yield from self._walk(_chunk(fields, body, pos), 0, topics)
            elif end > len(data):
                raise ValueError(f"truncated at byte {pos} of {len(data)}: a record of {end - pos} bytes")
            elif op == OP_CONNECTION:
                conn = struct.unpack("<I", fields["conn"])[0]
                header, _, _ = _fields(body, 0, len(body))
                self.connections[conn] = (fields["topic"].decode(), header["type"].decode(),
                                          header.get("message_definition", b"").decode())
            elif op == OP_MESSAGE:
                conn = struct.unpack("<I", fields["conn"])[0]
                topic = self.connections[conn][0] if conn in self.connections else None
                if topics is None:
                    self._counts[conn] = self._counts.get(conn, 0) + 1
                elif topic is not None and (not topics or topic in topics):
                    sec, nsec = struct.unpack("<II", fields["time"])
                    yield RawMessage(topic, sec * 1_000_000_000 + nsec, body)
            if end > len(data):  # an uncompressed chunk cut short: its whole records were read above
                raise ValueError(f"truncated at byte {pos} of {len(data)}: a chunk of {end - pos} bytes")
            pos = end

    def close(self) -> None:
        self._data = b""


def _record(data: memoryview, pos: int) -> tuple[dict[str, bytes], memoryview, int]:
    """(header fields, data, end) of the ROS 1 record at `pos`; a record cut short by the end of `data` has the
    bytes that are there and an end beyond it."""
    if pos + 4 > len(data):
        raise ValueError(f"truncated at byte {pos} of {len(data)}: a record header length")
    (header_len,) = struct.unpack_from("<I", data, pos)
    fields, pos, _ = _fields(data, pos + 4, header_len)
    if pos + 4 > len(data):
        raise ValueError(f"truncated at byte {pos} of {len(data)}: a record's data length")
    (data_len,) = struct.unpack_from("<I", data, pos)
    return fields, data[pos + 4:pos + 4 + data_len], pos + 4 + data_len


def _fields(data: memoryview, pos: int, length: int) -> tuple[dict[str, bytes], int, int]:
    """The name=value fields of a ROS 1 record header of `length` bytes at `pos`; (fields, end, length)."""
    end = pos + length
    if end > len(data):
        raise ValueError(f"truncated at byte {pos} of {len(data)}: a record header of {length} bytes")
    fields: dict[str, bytes] = {}
    while pos < end:
        (size,) = struct.unpack_from("<I", data, pos)
        item = bytes(data[pos + 4:pos + 4 + size])
        name, sep, value = item.partition(b"=")
        if not sep or pos + 4 + size > end:
            raise ValueError(f"a malformed record header field at byte {pos}")
        fields[name.decode("ascii", "replace")] = value
        pos += 4 + size
    return fields, end, length


def _chunk(fields: dict[str, bytes], body: memoryview, pos: int) -> memoryview:
    """A chunk's records, decompressed (none, bz2 or lz4) with streaming decompressors, so that a chunk cut short
    gives the records of its complete blocks."""
    compression = fields.get("compression", b"none").decode()
    if compression == "none":  # possibly cut short: the walk stops at its first incomplete record
        return body
    return decompress(compression, body, f"the chunk at byte {pos}")


class _SqliteScan:
    """Rows of a rosbag2 sqlite3 file in id order, read with sqlite3 itself (no metadata.yaml needed).

    A file cut short is taken as the pages it has (in memory: its last page completed with zeros, the header's page
    count set to match, never trusted): sqlite then reads every row on the pages that are there and reports the
    first missing one as malformed.
    """

    def __init__(self, path: Path) -> None:
        self.path = path
        self.damage: str | None = None
        data = path.read_bytes()
        if len(data) < 100 or not data.startswith(SQLITE_MAGIC):
            raise BagError(f"{path}: not an sqlite3 file")
        page_size = struct.unpack(">H", data[16:18])[0]
        page_size = 65536 if page_size == 1 else page_size
        if page_size < 512 or page_size & (page_size - 1):
            raise BagError(f"{path}: sqlite3 header: page size {page_size} is not a power of two >= 512")
        pages = -(-len(data) // page_size)
        self._db = sqlite3.connect(":memory:")
        self._db.deserialize(data[:28] + struct.pack(">I", pages) + data[32:] + bytes(pages * page_size - len(data)))
        rows = self._db.execute("SELECT id, name, type FROM topics").fetchall()
        self._names = {tid: name for tid, name, _ in rows}
        self.topics = _topics((name, msgtype, -1) for _, name, msgtype in rows)
        try:
            self.definitions = [(t, d) for t, e, d in self._db.execute(
                "SELECT topic_type, encoding, encoded_message_definition FROM message_definitions") if e == "ros2msg"]
        except sqlite3.DatabaseError:
            self.definitions = []

    def messages(self, topics: Collection[str]) -> Iterator[RawMessage]:
        try:
            for tid, log_ns, data in self._db.execute("SELECT topic_id, timestamp, data FROM messages ORDER BY id"):
                topic = self._names.get(tid)
                if topic is not None and (not topics or topic in topics):
                    yield RawMessage(topic, int(log_ns), data)
        except sqlite3.DatabaseError as exc:
            self.damage = f"sqlite3: {exc}"

    def close(self) -> None:
        self._db.close()


class _McapScan:
    """ROS 2 messages of an MCAP file in stream order (no summary or index needed; chunks decompressed within
    MAX_CHUNK_BYTES)."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.damage: str | None = None
        self._file = open(path, "rb")  # noqa: SIM115 (closed by close())
        self.topics: dict[str, Topic] = {}
        self.definitions: list[tuple[str, str]] = []
        counts: dict[str, int] = {}
        types: dict[str, str] = {}
        try:
            for schema, channel, _ in self._messages():
                counts[channel.topic] = counts.get(channel.topic, 0) + 1
                if schema is not None and channel.topic not in types:
                    types[channel.topic] = schema.name
                    if schema.encoding == "ros2msg":
                        self.definitions.append((schema.name, schema.data.decode()))
        except Exception:  # noqa: BLE001,S110 (the count stops where the stream does; messages() says why)
            pass
        self.topics = _topics((t, types[t], n) for t, n in counts.items() if t in types)

    def _messages(self) -> Iterator[tuple[Any, Any, Any]]:
        """(schema or None, channel, message) in stream order, each chunk decompressed with `decompress` (its records
        then read by mcap's breakup_chunk, its CRC checked)."""
        import dataclasses

        from mcap.records import Channel, Chunk, Message, Schema
        from mcap.stream_reader import StreamReader, breakup_chunk

        schemas: dict[int, Any] = {}
        channels: dict[int, Any] = {}
        self._file.seek(0)

        def expanded() -> Iterator[Any]:
            for record in StreamReader(self._file, emit_chunks=True, record_size_limit=MAX_CHUNK_BYTES).records:
                if isinstance(record, Chunk):
                    data = bytes(record.data if not record.compression else decompress(
                        record.compression, record.data, "a chunk"))
                    yield from breakup_chunk(dataclasses.replace(record, compression="", data=data,
                                                                 uncompressed_size=len(data)), validate_crc=True)
                else:
                    yield record

        for record in expanded():
            if isinstance(record, Schema):
                schemas[record.id] = record
            elif isinstance(record, Channel):
                channels[record.id] = record
            elif isinstance(record, Message) and record.channel_id in channels:
                channel = channels[record.channel_id]
                yield schemas.get(channel.schema_id), channel, record

    def messages(self, topics: Collection[str]) -> Iterator[RawMessage]:
        try:
            for _, channel, message in self._messages():
                if not topics or channel.topic in topics:
                    yield RawMessage(channel.topic, message.log_time, message.data)
        except Exception as exc:  # noqa: BLE001 (the first record the stream reader cannot take ends the bag)
            self.damage = f"mcap: a record cut short or damaged ({type(exc).__name__}{f': {exc}' if str(exc) else ''})"

    def close(self) -> None:
        self._file.close()
