"""The nose model the service runs with: where its file is, its identity (path, SHA-256), and loading it once."""

from __future__ import annotations

import hashlib
import logging
from dataclasses import dataclass
from pathlib import Path

from tofd.algorithm.detector import ModelError, NoseDetector, NoseModel, load_model
from tofd.config import Config, ConfigError, default_file

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class ModelIdentity:
    """Which model file a run used: resolved path and SHA-256 of its bytes ("" for both without a model)."""

    path: str
    sha256: str

    def to_dict(self) -> dict[str, str]:
        return {"path": self.path, "sha256": self.sha256}


NO_MODEL = ModelIdentity("", "")


def resolve_model_path(model_path: str | Path) -> Path:
    """An absolute model path as is; a relative one from the bundled config/ directory (load_config has already
    made the paths of other config files absolute), never from the working directory."""
    path = Path(model_path)
    return path if path.is_absolute() else default_file(str(path))


def model_identity(cfg: Config) -> ModelIdentity:
    """Resolved path and SHA-256 of cfg.detector's model file; NO_MODEL when there is none."""
    path = resolve_model_path(cfg.detector.model_path).resolve()
    try:
        return ModelIdentity(str(path), hashlib.sha256(path.read_bytes()).hexdigest())
    except FileNotFoundError:
        return NO_MODEL
    except OSError as exc:
        raise ConfigError(f"detector.model_path: cannot read {path}: {exc.strerror}") from None


def load_service_model(cfg: Config) -> NoseModel | None:
    """The model of cfg.detector, checked against the config's feature settings; None (with a warning) when its
    file does not exist. ConfigError names a model that cannot be used."""
    path = resolve_model_path(cfg.detector.model_path).resolve()
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
