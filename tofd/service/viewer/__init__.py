"""Rerun streaming of pipeline results: entity tree and blueprint, per-frame logger, sinks (file/viewers),
and the viewer process that runs them apart from the pipeline."""

from tofd.service.viewer.blueprint import build_blueprint
from tofd.service.viewer.logger import RerunLogger
from tofd.service.viewer.targets import RerunTarget, ViewerError

__all__ = ["RerunLogger", "RerunTarget", "ViewerError", "build_blueprint"]
