"""Rerun streaming of pipeline results: entity tree and blueprint, per-frame logger, sinks (file/viewers)."""

from tofd.service.viewer.blueprint import build_blueprint
from tofd.service.viewer.logger import RerunLogger
from tofd.service.viewer.targets import RerunTarget, ViewerError

__all__ = ["RerunLogger", "RerunTarget", "ViewerError", "build_blueprint"]
