"""The --rerun option: which Rerun sink a run streams to."""

from __future__ import annotations

from dataclasses import replace

from tofd.config import RERUN_SINKS, Config, ConfigError, override

RERUN_SPEC_HELP = "save:PATH | web | connect:URL | spawn | none (default: the config's [rerun] sink)"


def parse_rerun_spec(spec: str | None, cfg: Config) -> Config:
    """Apply a --rerun value (see RERUN_SPEC_HELP) to the [rerun] section; ConfigError names a bad one."""
    if spec is None:
        return cfg
    kind, colon, arg = spec.partition(":")
    if kind == "save" and colon:
        return override(cfg, "rerun", "--rerun", sink="save", path=arg)
    if kind == "connect":
        return override(cfg, "rerun", "--rerun", sink="connect", url=arg or cfg.rerun.url)
    if kind in RERUN_SINKS and not arg:
        return replace(cfg, rerun=replace(cfg.rerun, sink=kind))
    raise ConfigError(f"--rerun: {spec!r} is not one of {RERUN_SPEC_HELP}")
