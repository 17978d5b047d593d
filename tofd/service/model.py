"""The nose model the service runs with: where its file is, and loading it once."""

from __future__ import annotations

import logging
from pathlib import Path

from tofd.algorithm.detector import ModelError, NoseDetector, NoseModel, load_model
from tofd.config import Config, ConfigError, default_file

log = logging.getLogger(__name__)


def resolve_model_path(model_path: str | Path) -> Path:
    """A model path as given if it exists (relative to the cwd), else relative to the bundled config/ directory."""
    path = Path(model_path)
    if path.is_absolute() or path.exists():
        return path
    return default_file(str(path))


def load_service_model(cfg: Config) -> NoseModel | None:
    """The model of cfg.detector, checked against the config's feature settings; None (with a warning) when its
    file does not exist. ConfigError names a model that cannot be used."""
    path = resolve_model_path(cfg.detector.model_path)
    if not path.exists():
        log.warning("no detector model at %s (detector.model_path): running without nose detection", path)
        return None
    try:
        model = load_model(path)
        NoseDetector(model, cfg.detector, cfg.features, cfg.segmentation, cfg.intrinsics)
    except ModelError as exc:
        raise ConfigError(f"detector.model_path: {exc}") from None
    return model


def load_detector(cfg: Config) -> NoseDetector:
    """The NoseDetector of cfg.detector with its model file; ModelError names a model that cannot be used."""
    model = load_model(resolve_model_path(cfg.detector.model_path))
    return NoseDetector(model, cfg.detector, cfg.features, cfg.segmentation, cfg.intrinsics)
