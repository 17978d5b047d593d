"""The nose model the service runs with: where its file is, its identity (path, SHA-256), and loading it once."""

from __future__ import annotations

import hashlib
import logging
from dataclasses import dataclass
from pathlib import Path

from tofd.algorithm.detector import ModelError, NoseDetector, NoseModel, load_model, parse_model
from tofd.config import MAX_MODEL_BYTES, NO_MODEL_PATH, Config, ConfigError, default_file, read_regular_file

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class ModelIdentity:
    """Which model file a run used: resolved path and SHA-256 of its bytes ("" for both without a model)."""

    path: str
    sha256: str


NO_MODEL = ModelIdentity("", "")


def resolve_model_path(model_path: str | Path) -> Path:
    """An absolute model path as is; a relative one from the bundled config/ directory (load_config has already
    made the paths of other config files absolute), never from the working directory."""
    path = Path(model_path)
    return path if path.is_absolute() else default_file(str(path))


@dataclass(frozen=True, slots=True)
class ModelFile:
    """cfg.detector's model file as read once, so that its identity and the model it holds are the same bytes."""

    path: Path | None  # resolved; None: the config chose no detector (model_path = "")
    data: bytes | None  # None: no detector

    @property
    def identity(self) -> ModelIdentity:
        """Resolved path and SHA-256 of the bytes; NO_MODEL without a file."""
        if self.data is None:
            return NO_MODEL
        return ModelIdentity(str(self.path), hashlib.sha256(self.data).hexdigest())


def read_model_file(cfg: Config) -> ModelFile:
    """The bytes of cfg.detector's model file, a regular file of at most MAX_MODEL_BYTES (no bytes when the config
    chooses no detector: model_path = ""); ConfigError when it is missing or cannot be read."""
    if cfg.detector.model_path == NO_MODEL_PATH:
        return ModelFile(None, None)
    path = resolve_model_path(cfg.detector.model_path).resolve()
    try:
        return ModelFile(path, read_regular_file(path, MAX_MODEL_BYTES, "model"))
    except ConfigError as exc:
        raise ConfigError(f"detector.model_path: {exc} (model_path = \"\" runs without nose detection)") from None


def service_model(cfg: Config, file: ModelFile) -> NoseModel | None:
    """The model in `file`, checked against the config's feature settings; None (logged) when the config chose no
    detector. ConfigError names a model that cannot be used."""
    if file.data is None:
        log.info("detector.model_path = \"\": running without nose detection")
        return None
    try:
        model = parse_model(file.data, str(file.path))
        NoseDetector(model, cfg.detector, cfg.features, cfg.segmentation, cfg.intrinsics)
    except ModelError as exc:
        raise ConfigError(f"detector.model_path: {exc}") from None
    return model


def load_service_model(cfg: Config) -> NoseModel | None:
    """service_model of cfg.detector's model file, read here (for callers that need no identity, e.g. batch)."""
    return service_model(cfg, read_model_file(cfg))


def load_detector(cfg: Config) -> NoseDetector:
    """The NoseDetector of cfg.detector with its model file; ModelError names a model that cannot be used."""
    model = load_model(resolve_model_path(cfg.detector.model_path))
    return NoseDetector(model, cfg.detector, cfg.features, cfg.segmentation, cfg.intrinsics)
