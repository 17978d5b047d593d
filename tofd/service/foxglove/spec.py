"""The --foxglove option: where the Foxglove WebSocket server listens."""

from __future__ import annotations

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


def check_port_free(fc: FoxgloveConfig) -> None:
    """ConfigError naming foxglove.port when something already listens on it (port 0: any free one, never)."""
    if fc.port == 0:
        return
    with socket.socket() as s:
        s.settimeout(0.2)
        if s.connect_ex(("127.0.0.1" if fc.bind in ("0.0.0.0", "") else fc.bind, fc.port)) == 0:
            raise ConfigError(f"foxglove.port: port {fc.port} on {fc.bind} is already in use (--foxglove HOST:PORT)")
