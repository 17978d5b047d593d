"""The nose model file: JSON with one box per variant, its operating scale, and the feature and segmentation
settings it was trained with, so features computed with other settings are refused (ModelMismatch)."""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path

from tofd.algorithm.detector.box import Box
from tofd.algorithm.names import VARIANTS
from tofd.algorithm.params import FeatureConfig, SegmentationConfig, recorded_feature_settings
from tofd.errors import UsageError
from tofd.outputs import write_text

MODEL_FORMAT = "tofd-nose-model"
MODEL_VERSION = 1


class ModelError(UsageError):
    """A model file that cannot be used; the message names the file and the key."""


class ModelMismatch(ModelError):
    """Features computed with settings other than the model's (the message names the differing keys)."""


@dataclass(frozen=True, slots=True)
class VariantModel:
    """The learned box of one variant and its operating scale (tofd.lab.evaluation.train_model: the middle of the
    training frames' zero-error scales, else their equal-error scale)."""

    variant: str
    box: Box
    operating_scale: float = 1.0
    train_eer: float | None = None


@dataclass(frozen=True, slots=True)
class NoseModel:
    """Boxes for one or more variants and the settings their features were computed with."""

    variants: dict[str, VariantModel]
    feature_config: dict  # dataclasses.asdict(FeatureConfig) at training time
    segmentation_config: dict  # dataclasses.asdict(SegmentationConfig) at training time
    quantile: float = 0.05
    positive_radius_mm: float = 5.0
    training: dict = dataclasses.field(default_factory=dict)  # provenance: data, frames, pixels

    def variant(self, name: str) -> VariantModel:
        if name not in self.variants:
            raise ModelError(f"model has no variant {name!r} (has: {', '.join(self.variants)})")
        return self.variants[name]

    def check_compatible(self, feature_config: FeatureConfig, segmentation_config: SegmentationConfig) -> None:
        """Raise ModelMismatch naming every setting that differs from the model's."""
        diffs = _diff("features", recorded_feature_settings(self.feature_config),
                      dataclasses.asdict(feature_config)) + _diff(
            "segmentation", self.segmentation_config, dataclasses.asdict(segmentation_config))
        if diffs:
            raise ModelMismatch("model was trained with other feature settings: " + "; ".join(diffs))

    def to_dict(self) -> dict:
        return {
            "format": MODEL_FORMAT,
            "version": MODEL_VERSION,
            "about": "tofd nose detector (Haker et al. 2008): a pixel is the nose tip iff its log10 feature "
            "vector x satisfies max_k |x_k - centre_log10_k| / half_width_log10_k <= scale. low/high: the "
            "box in raw eccentricity units at scale 1. operating_scale: scale used by the pipeline.",
            "quantile": self.quantile,
            "positive_radius_mm": self.positive_radius_mm,
            "feature_config": self.feature_config,
            "segmentation_config": self.segmentation_config,
            "training": self.training,
            "variants": {
                name: {"box": vm.box.to_dict(), "operating_scale": vm.operating_scale, "train_eer": vm.train_eer}
                for name, vm in self.variants.items()
            },
        }

    @classmethod
    def from_dict(cls, d: dict, where: str = "model") -> NoseModel:
        if d.get("format") != MODEL_FORMAT:
            raise ModelError(f"{where}: key 'format' is {d.get('format')!r}, expected {MODEL_FORMAT!r}")
        if d.get("version") != MODEL_VERSION:
            raise ModelError(f"{where}: key 'version' is {d.get('version')!r}, expected {MODEL_VERSION}")
        for key in ("variants", "feature_config", "segmentation_config"):
            if not isinstance(d.get(key), dict):
                raise ModelError(f"{where}: key {key!r} missing or not a table")
        variants = {}
        for name, v in d["variants"].items():
            if name not in VARIANTS:
                raise ModelError(f"{where}: key 'variants.{name}': unknown variant (known: {', '.join(VARIANTS)})")
            try:
                box = Box.from_dict(v["box"])
                scale = float(v.get("operating_scale", 1.0))
            except (KeyError, TypeError, ValueError) as exc:
                raise ModelError(f"{where}: key 'variants.{name}.box': {exc}") from None
            if box.features != VARIANTS[name]:
                raise ModelError(f"{where}: key 'variants.{name}.box.features' is {list(box.features)}, "
                                 f"expected {list(VARIANTS[name])}")
            variants[name] = VariantModel(name, box, scale, v.get("train_eer"))
        return cls(variants, d["feature_config"], d["segmentation_config"], float(d.get("quantile", 0.05)),
                   float(d.get("positive_radius_mm", 5.0)), dict(d.get("training", {})))


def _diff(section: str, saved: dict, current: dict) -> list[str]:
    keys = sorted(set(saved) | set(current))
    return [f"{section}.{k}: model {saved.get(k)!r} != current {current.get(k)!r}"
            for k in keys if saved.get(k) != current.get(k)]


def save_model(model: NoseModel, path: str | Path) -> Path:
    """Write the model as indented JSON, atomically (tofd.outputs)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    return write_text(path, json.dumps(model.to_dict(), indent=2) + "\n")


def load_model(path: str | Path) -> NoseModel:
    """Read a model JSON; ModelError names the file and the bad key."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise ModelError(f"cannot read model {path}: {exc.strerror}") from None
    return parse_model(text, str(path))


def parse_model(text: str | bytes, where: str) -> NoseModel:
    """The model in JSON `text` (read by the caller, e.g. once for both its hash and its content); ModelError
    names `where` (the file) and the bad key."""
    try:
        d = json.loads(text)
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ModelError(f"{where}: invalid JSON: {exc}") from None
    if not isinstance(d, dict):
        raise ModelError(f"{where}: expected a JSON object")
    return NoseModel.from_dict(d, where)
