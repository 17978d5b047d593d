"""A plain Foxglove WebSocket protocol client for the tests (websocket-client; no Foxglove code): connect with the
server's subprotocol, read its channel advertisements, subscribe, and decode message data with Foxglove's own
compiled protobuf schemas (foxglove-schemas-protobuf)."""

from __future__ import annotations

import importlib
import json
import re
import struct
import time
from dataclasses import dataclass, field

import websocket
from google.protobuf import descriptor_pb2

SUBPROTOCOL = "foxglove.sdk.v1"
MESSAGE_DATA = 0x01  # binary opcode: subscription id (uint32 LE), log time (uint64 LE ns), payload
UNKNOWN_CHANNEL = re.compile(r"Unknown channel ID: (\d+)")  # the server's status message refusing a subscription
CONNECT_RETRY_S = 0.01  # tofd's server listens from the first frame on: until then a connection is refused


def connect(url: str, timeout_s: float) -> websocket.WebSocket:
    """A WebSocket connection to a Foxglove server at `url` with its subprotocol, tried again while refused (the
    server not listening yet) for up to `timeout_s`."""
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            return websocket.create_connection(url, subprotocols=[SUBPROTOCOL], timeout=timeout_s)
        except ConnectionRefusedError:
            if time.monotonic() >= deadline:
                raise
            time.sleep(CONNECT_RETRY_S)


def refused_channel(msg: dict) -> int | None:
    """The channel id a server status message says a subscription was refused for (None: not such a message)."""
    refused = UNKNOWN_CHANNEL.search(msg.get("message", "")) if msg.get("op") == "status" else None
    return None if refused is None else int(refused.group(1))


def wait_for_url(stream, pattern: str = r"foxglove: (ws://\S+)") -> tuple[str, list[str]]:
    """The ws:// address a tofd process logs on `stream` (its stderr, text) and the lines read until then."""
    lines = []
    for line in stream:
        lines.append(line)
        found = re.search(pattern, line)
        if found:
            return found.group(1), lines
    raise AssertionError("no foxglove address logged:\n" + "".join(lines))


def decoder(schema_name: str):
    """The compiled protobuf class of a Foxglove schema name (foxglove.RawImage -> RawImage_pb2.RawImage)."""
    short = schema_name.removeprefix("foxglove.")
    return getattr(importlib.import_module(f"foxglove_schemas_protobuf.{short}_pb2"), short)


@dataclass
class Client:
    url: str
    timeout_s: float = 10.0
    channels: dict[int, dict] = field(default_factory=dict)  # channel id -> advertisement
    server_info: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.ws = connect(self.url, self.timeout_s)
        self.subprotocol = self.ws.getsubprotocol()
        deadline = time.monotonic() + self.timeout_s
        while not self.channels and time.monotonic() < deadline:
            msg = json.loads(self.ws.recv())
            if msg["op"] == "serverInfo":
                self.server_info = msg
            elif msg["op"] == "advertise":
                self.channels.update({c["id"]: c for c in msg["channels"]})

    def subscribe(self, topics: list[str] | None = None) -> None:
        """Subscribe to `topics` (all advertised when None); subscription id = channel id."""
        ids = [cid for cid, c in self.channels.items() if topics is None or c["topic"] in topics]
        self.ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": i, "channelId": i} for i in ids]}))

    def read(self, seconds: float, until: callable = lambda got: False) -> dict[str, list[tuple[int, object]]]:
        """Topic -> [(log time ns, decoded message)] received for `seconds` (or until `until(got)`); AssertionError
        if the server refused a subscription to a channel it advertised."""
        got: dict[str, list[tuple[int, object]]] = {}
        deadline = time.monotonic() + seconds
        self.ws.settimeout(0.5)
        while time.monotonic() < deadline and not until(got):
            try:
                data = self.ws.recv()
            except websocket.WebSocketTimeoutException:
                continue
            except (websocket.WebSocketConnectionClosedException, ConnectionError):
                break
            if isinstance(data, str):
                refused = refused_channel(json.loads(data) if data.startswith("{") else {})
                assert refused not in self.channels, f"subscription to advertised channel {refused} refused"
                continue
            if data[0] != MESSAGE_DATA:
                continue
            sub, log_ns = struct.unpack_from("<IQ", data, 1)
            channel = self.channels[sub]
            if channel["encoding"] == "json":
                msg = json.loads(data[13:])
            else:
                msg = decoder(channel["schemaName"])()
                msg.ParseFromString(data[13:])
            got.setdefault(channel["topic"], []).append((log_ns, msg))
        return got

    def schema_names(self, topic: str) -> set[str]:
        """The message names in the advertised schema of `topic` (a base64 protobuf FileDescriptorSet)."""
        import base64

        channel = next(c for c in self.channels.values() if c["topic"] == topic)
        fds = descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(channel["schema"]))
        return {f"{f.package}.{m.name}" for f in fds.file for m in f.message_type}

    def close(self) -> None:
        self.ws.close()
