"""The --foxglove option: where the Foxglove WebSocket server listens."""

from __future__ import annotations

import errno
import socket
from dataclasses import replace

from tofd.config import Config, ConfigError, FoxgloveConfig

FOXGLOVE_SPEC_HELP = ("serve the live stream to Foxglove on [HOST:]PORT (HOST 127.0.0.1 by default; PORT 0: any "
                      "free port), 'on' for the config's [foxglove] address, or 'none'")


def parse_foxglove_spec(spec: str | None, cfg: Config) -> Config:
    """Apply a --foxglove value (FOXGLOVE_SPEC_HELP) to the [foxglove] section; ConfigError names a bad one."""
    if spec is None:
        return cfg
    if spec in ("on", "none"):
        return replace(cfg, foxglove=replace(cfg.foxglove, enabled=spec == "on"))
    host, _, port = spec.rpartition(":")
    if not port.isdigit() or not 0 <= int(port) < 65536:
        raise ConfigError(f"--foxglove: {spec!r} is not [HOST:]PORT, 'on' or 'none' (PORT: 0-65535)")
    return replace(cfg, foxglove=replace(cfg.foxglove, enabled=True, bind=host.strip("[]") or "127.0.0.1",
                                         port=int(port)))


def listen_port(bind: str, port: int) -> int:
    """The port to listen on at `bind`: `port`, or for 0 one the system has free; OSError when it cannot be bound
    (an address not of this host, a port in use)."""
    with socket.socket(socket.AF_INET6 if ":" in bind else socket.AF_INET) as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as a server binds: TIME_WAIT does not count
        probe.bind((bind, port))
        return int(probe.getsockname()[1])


def check_port_free(fc: FoxgloveConfig) -> None:
    """ConfigError naming foxglove.port when the port is in use at foxglove.bind (listen_port; port 0: any free one,
    never); any other reason it cannot be bound is the Foxglove viewer process's to report."""
    if fc.port == 0:
        return
    try:
        listen_port(fc.bind, fc.port)
    except OSError as exc:
        if exc.errno == errno.EADDRINUSE:
            raise ConfigError(f"foxglove.port: port {fc.port} on {fc.bind} is already in use "
                              "(--foxglove HOST:PORT)") from None
