"""The paper's nose detector: a pixel is the nose tip iff its feature vector lies in an axis-aligned box.

Features are the generalised eccentricities eps0, eps2 of the range image (FFT or NFFT path) and, for the
"+amplitude" variants, eps0, eps2 of the amplitude image on the same path (the NFFT amplitude features are
scale-invariant too: measured without the front test on the rendered default split with 960 test frames,
NFFT range+amplitude EER 6.9 -> 5.4 % and 5.2 -> 4.8 % on two draws, leave-one-subject-out mean 3.2 -> 2.8 %,
against FFT amplitude features in the NFFT variant). The box lives in log10 feature space
(eccentricities span decades; a box there is still an axis-aligned box in the raw features).

Learning (`learn_box`): per feature, the `quantile` and 1 - `quantile` quantiles of the training pixels near the
true nose tip give the box at scale 1; the box at scale s has the same centre and s times the half-widths.
Training (tofd.evaluate.train_model) then rescales each feature's half-width with the labelled negatives
(tofd.evaluate.shape_box), so a feature that separates nothing is widened instead of costing detections.
A pixel's *box distance* is max_k |x_k - centre_k| / half_width_k: the pixel is inside the box at scale s iff
its box distance <= s. The detector reports the foreground pixel of smallest box distance (its score) and
accepts it iff score <= the operating scale, so sweeping the scale traces the ROC (tofd.roc).

Border exclusion (`border_margin_m`, config detector.border_margin_m): the filters' response within about one
filter width of the mask border is dominated by the clamped background (e.g. a chin that pokes just past the
segmentation's iso-depth cut leaves a small flat-topped cap that looks like a nose tip), so pixels nearer than
this physical distance to the border of the foreground (or the image edge) are never candidates. The distance
is measured in pixels (cv2.distanceTransform, to the border line half a pixel beyond the last foreground pixel)
and converted to metres with each pixel's depth / f, so the excluded strip is the same on the face at any distance.

Front test (`front_depth_m`, config detector.front_depth_m): the nose tip is the front-most point of its
surroundings, so a pixel more than this behind the front-most foreground pixel within FRONT_RADIUS_M (along the
face's viewing direction, depth median-filtered) is never a candidate. It removes the false positives that the
per-pixel features cannot: pixels 15-27 mm from the tip on the nose, e.g. with the head pitched down the upper
lip just below the tip in the image, 2 cm behind it, to which the filters (6 mm wide) give the tip's response.
Measured (bench/tune_detector.py --grid front, leave-one-training-subject-out, mean of three draws), EER % FFT
range / NFFT range / NFFT range+amplitude: off 7.3 / 1.4 / 1.6; 0.5 mm 1.0 / 0.8 / 0.9; 1 mm 1.1 / 0.7 / 0.6;
1.5 mm 1.2 / 0.4 / 0.4; 2 mm 1.3 / 0.4 / 0.3; 3 mm 3.0 / 0.8 / 0.7; 8 mm 7.3 / 1.1 / 1.6 (labels on the
filtered range, tofd.evaluate.label_points). Default 1 mm: 0.5-2 mm differ by about one frame per fold; 1.5 mm
was not better when each rendered identity was held out in turn (lps_flat / lps_long, 160 frames each: NFFT
range 0.6 / 4.4 % at 1 mm, 1.2 / 5.0 % at 1.5 mm), and 1 mm leaves twice the room for depth noise of 0.5 mm.

`Candidates` bundles both tests; training and evaluation apply the same ones as the pipeline.

Model file (`save_model` / `load_model`): small JSON, one box per variant plus the feature and segmentation
settings it was trained with, so features computed with other settings are refused (ModelMismatch).
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from drivers.camera import Intrinsics
from tofd.config import default_file
from tofd.segmentation import filtered

MODEL_FORMAT = "tofd-nose-model"
MODEL_VERSION = 1

VARIANTS: dict[str, tuple[str, ...]] = {
    "fft_range": ("range_fft_eps0", "range_fft_eps2"),
    "fft_range_amp": ("range_fft_eps0", "range_fft_eps2", "amp_fft_eps0", "amp_fft_eps2"),
    "nfft_range": ("range_nfft_eps0", "range_nfft_eps2"),
    "nfft_range_amp": ("range_nfft_eps0", "range_nfft_eps2", "amp_nfft_eps0", "amp_nfft_eps2"),
}
"""Variant name -> the feature maps (names as produced by tofd.feature_maps) its box is learned on."""

LOG_FLOOR = 1e-30  # eccentricities below this are clipped before log10


class ModelError(ValueError):
    """A model file that cannot be used; the message names the file and the key."""


class ModelMismatch(ModelError):
    """Features computed with settings other than the model's (the message names the differing keys)."""


def to_log_features(values: np.ndarray) -> np.ndarray:
    """log10 of eccentricities (clipped at LOG_FLOOR); NaN stays NaN."""
    return np.log10(np.maximum(values, LOG_FLOOR))


def require_maps(maps: dict[str, np.ndarray], names: tuple[str, ...]) -> None:
    """Raise KeyError naming the feature maps that were not computed."""
    missing = [n for n in names if n not in maps]
    if missing:
        raise KeyError(f"feature map(s) {', '.join(missing)} not computed")


def stack_features(maps: dict[str, np.ndarray], names: tuple[str, ...]) -> np.ndarray:
    """(..., k) log10 feature vectors from named eccentricity maps (each (...)); NaN where any is missing."""
    require_maps(maps, names)
    return to_log_features(np.stack([np.asarray(maps[n], dtype=np.float64) for n in names], axis=-1))


@dataclass(frozen=True, slots=True)
class Box:
    """An axis-aligned box in log10 feature space at scale 1: centre +- half_width."""

    features: tuple[str, ...]
    centre: np.ndarray  # (k,) log10 units
    half_width: np.ndarray  # (k,) log10 units, > 0

    def distance(self, x: np.ndarray) -> np.ndarray:
        """(...) box distance of log10 feature vectors (..., k): the smallest scale whose box holds them.

        +inf where a feature is NaN (not foreground / not computed).
        """
        d = np.max(np.abs(x - self.centre) / self.half_width, axis=-1)
        return np.where(np.isnan(d), np.inf, d)

    def to_dict(self) -> dict:
        return {
            "features": list(self.features),
            "centre_log10": [round(float(c), 6) for c in self.centre],
            "half_width_log10": [round(float(h), 6) for h in self.half_width],
            "low": [float(f"{v:.6g}") for v in 10 ** (self.centre - self.half_width)],
            "high": [float(f"{v:.6g}") for v in 10 ** (self.centre + self.half_width)],
        }

    @classmethod
    def from_dict(cls, d: dict) -> Box:
        features = tuple(d["features"])
        centre = np.asarray(d["centre_log10"], dtype=np.float64)
        half = np.asarray(d["half_width_log10"], dtype=np.float64)
        if not (len(features) == len(centre) == len(half)):
            raise ValueError("features, centre_log10 and half_width_log10 must have the same length")
        if np.any(~np.isfinite(centre)) or np.any(~(half > 0)):
            raise ValueError("centre_log10 must be finite and half_width_log10 positive")
        return cls(features, centre, half)


MIN_HALF_WIDTH = 1e-3  # log10 units; keeps a box of identical samples usable


def learn_box(samples: np.ndarray, features: tuple[str, ...], quantile: float = 0.05) -> Box:
    """The box of the [quantile, 1 - quantile] range of each feature over positive samples (N, k), log10 units.

    Quantiles instead of min/max make the box robust to a few mislabelled or noisy pixels.
    """
    samples = np.asarray(samples, dtype=np.float64)
    if samples.ndim != 2 or samples.shape[1] != len(features):
        raise ValueError(f"samples must be (N, {len(features)}), got {samples.shape}")
    if not 0 <= quantile < 0.5:
        raise ValueError(f"quantile must be in [0, 0.5), got {quantile}")
    samples = samples[np.all(np.isfinite(samples), axis=1)]
    if len(samples) == 0:
        raise ValueError("no finite positive samples to learn a box from")
    lo, hi = np.quantile(samples, [quantile, 1 - quantile], axis=0)
    return Box(features, (lo + hi) / 2, np.maximum((hi - lo) / 2, MIN_HALF_WIDTH))


@dataclass(frozen=True, slots=True)
class VariantModel:
    """The learned box of one variant and its operating scale (tofd.evaluate.train_model: the middle of the
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

    def check_compatible(self, feature_config: object, segmentation_config: object) -> None:
        """Raise ModelMismatch naming every setting that differs from the model's."""
        diffs = _diff("features", self.feature_config, dataclasses.asdict(feature_config)) + _diff(
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
    """Write the model as indented JSON."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(model.to_dict(), indent=2) + "\n")
    return path


def load_model(path: str | Path) -> NoseModel:
    """Read a model JSON; ModelError names the file and the bad key."""
    path = Path(path)
    try:
        d = json.loads(path.read_text())
    except OSError as exc:
        raise ModelError(f"cannot read model {path}: {exc.strerror}") from None
    except json.JSONDecodeError as exc:
        raise ModelError(f"{path}: invalid JSON: {exc}") from None
    if not isinstance(d, dict):
        raise ModelError(f"{path}: expected a JSON object")
    return NoseModel.from_dict(d, str(path))


@dataclass(frozen=True, slots=True)
class Detection:
    """The detector's answer for one frame: the best pixel, its 3-D point, and whether it is in the box."""

    nose_px: tuple[int, int] | None  # (u, v) = (column, row) of the accepted pixel, None if none accepted
    nose_xyz_m: tuple[float, float, float] | None  # camera frame, metres
    score: float  # box distance of the best foreground pixel (lower is better; inf if no foreground)
    accepted: bool  # score <= scale


def border_distance_m(mask: np.ndarray, range_m: np.ndarray, intrinsics: Intrinsics) -> np.ndarray:
    """(H, W) float32 distance in metres from each mask pixel to the mask border or image edge (0 off the mask).

    Pixels: Euclidean distance to the nearest non-mask pixel (outside the image counts as non-mask) minus half a
    pixel; metres: times the pixel's depth (range * z of its unit ray) / fx.
    """
    padded = np.pad(np.asarray(mask, dtype=np.uint8), 1)
    px = cv2.distanceTransform(padded, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)[1:-1, 1:-1]
    with np.errstate(invalid="ignore"):
        metres = np.maximum(px - 0.5, 0) * (np.asarray(range_m) * intrinsics.unit_rays()[..., 2]) / intrinsics.fx
    return np.where(mask, np.nan_to_num(metres, nan=0.0), 0.0).astype(np.float32)


FRONT_RADIUS_M = 0.012  # the front test's neighbourhood: about the nose tip's own radius of curvature
FRONT_MEDIAN_PX = 5  # depth median filter of the front test (the segmentation's): a minimum of noisy depths
# would sit ~2 sigma in front of the surface (8 mm at 0.7 m)


def front_gap_m(mask: np.ndarray, range_m: np.ndarray, intrinsics: Intrinsics, direction: np.ndarray | None = None,
                radius_m: float = FRONT_RADIUS_M) -> np.ndarray:
    """(H, W) float32 metres each mask pixel lies behind the front-most mask pixel within radius_m (0 off the mask).

    Depth along `direction` (unit, camera frame; default the camera's z axis), median-filtered FRONT_MEDIAN_PX;
    the disc's radius in pixels is radius_m at the mask's median depth.
    """
    rays = intrinsics.unit_rays()
    with np.errstate(invalid="ignore"):
        depth = np.asarray(range_m) * (rays[..., 2] if direction is None else rays @ direction)
    valid = np.asarray(mask, dtype=bool) & np.isfinite(depth)
    if not valid.any():
        return np.zeros(valid.shape, np.float32)
    smooth = filtered(depth, valid, FRONT_MEDIAN_PX)
    r_px = max(1, round(radius_m * intrinsics.fx / float(np.median(depth[valid]))))
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r_px + 1, 2 * r_px + 1))
    return np.where(valid, smooth - cv2.erode(smooth, disc), 0.0).astype(np.float32)


@dataclass(frozen=True, slots=True)
class Candidates:
    """Which foreground pixels may be the nose at all (module docstring); metres, 0 switches a test off."""

    border_margin_m: float = 0.0  # at least this far from the mask border
    front_depth_m: float = 0.0  # at most this far behind the front-most pixel within FRONT_RADIUS_M

    @classmethod
    def from_config(cls, detector: object) -> Candidates:
        return cls(detector.border_margin_m, detector.front_depth_m)

    def keep(self, border_m: np.ndarray, front_gap: np.ndarray) -> np.ndarray:
        """Bool per pixel from its border distance and front gap (metres)."""
        ok = np.asarray(border_m) >= self.border_margin_m
        return ok & (np.asarray(front_gap) <= self.front_depth_m) if self.front_depth_m > 0 else ok

    def mask(self, foreground: np.ndarray, range_m: np.ndarray, intrinsics: Intrinsics,
             direction: np.ndarray | None = None) -> np.ndarray:
        """(H, W) bool: the candidate pixels of a frame's foreground (direction: the face's, see front_gap_m).

        Only the tests that are on are computed; `keep` applies them.
        """
        border = border_distance_m(foreground, range_m, intrinsics) if self.border_margin_m > 0 else np.inf
        gap = front_gap_m(foreground, range_m, intrinsics, direction) if self.front_depth_m > 0 else 0.0
        return np.asarray(foreground, dtype=bool) & self.keep(border, gap)


ALL_FOREGROUND = Candidates()
"""No candidate test: every foreground pixel may be the nose."""


def detect(maps: dict[str, np.ndarray], range_m: np.ndarray, intrinsics: Intrinsics, box: Box,
           scale: float, candidates: Candidates = ALL_FOREGROUND, direction: np.ndarray | None = None) -> Detection:
    """Detect the nose in one frame from its feature maps ((H, W), NaN outside the foreground).

    range_m: (H, W) radial range in metres, for the 3-D point of the detected pixel and the candidate tests.
    candidates: which foreground pixels (where all the box's features are finite) may be the nose (module
    docstring); direction: the face's viewing direction for the front test (tofd.segmentation.Foreground.rotation
    row 2). Only candidate pixels are scored (a few thousand of 25k).
    """
    require_maps(maps, box.features)
    foreground = np.logical_and.reduce([np.isfinite(maps[n]) for n in box.features])
    rows, cols = np.nonzero(candidates.mask(foreground, range_m, intrinsics, direction))
    if rows.size == 0:
        return Detection(None, None, float("inf"), False)
    dist = box.distance(stack_features({n: maps[n][rows, cols] for n in box.features}, box.features))
    best = int(np.argmin(dist))
    score = float(dist[best])
    if not score <= scale:
        return Detection(None, None, score, False)
    row, col = int(rows[best]), int(cols[best])
    ray = np.array([(col - intrinsics.cx) / intrinsics.fx, (row - intrinsics.cy) / intrinsics.fy, 1.0])
    xyz = ray / np.linalg.norm(ray) * float(range_m[row, col])
    return Detection((col, row), (float(xyz[0]), float(xyz[1]), float(xyz[2])), score, True)


def resolve_model_path(model_path: str | Path) -> Path:
    """A model path as given if it exists (relative to the cwd), else relative to the bundled config/ directory."""
    path = Path(model_path)
    if path.is_absolute() or path.exists():
        return path
    return default_file(str(path))


class NoseDetector:
    """The detector of the pipeline: one variant of a model file at one box scale, checked against the config.

    `detect_maps` works on feature maps computed elsewhere (e.g. by the pipeline's workers);
    `detect_frame` segments and computes the variant's features itself (tofd.feature_maps).
    """

    def __init__(self, config: object, model: NoseModel | None = None) -> None:
        from tofd.feature_maps import families_for

        det = config.detector
        self.model = model if model is not None else load_model(resolve_model_path(det.model_path))
        self.model.check_compatible(config.features, config.segmentation)
        vm = self.model.variant(det.variant)
        self.box = vm.box
        self.scale = det.box_scale if det.box_scale > 0 else vm.operating_scale
        self.candidates = Candidates.from_config(det)
        self.families = families_for(self.box.features)
        self.intrinsics = config.intrinsics
        self._config = config
        self._extractor = None

    def detect_maps(self, maps: dict[str, np.ndarray], range_m: np.ndarray,
                    direction: np.ndarray | None = None) -> Detection:
        """Detection from named feature maps (tofd.feature_maps names), the frame's range map (metres) and the
        face's viewing direction (FrameFeatures.rotation[2]; None: the camera's z axis)."""
        return detect(maps, range_m, self.intrinsics, self.box, self.scale, self.candidates, direction)

    def detect_frame(self, range_m: np.ndarray, amplitude: np.ndarray) -> Detection:
        """Segment, compute this variant's features, detect."""
        if self._extractor is None:
            from tofd.feature_maps import FeatureExtractor

            cfg = self._config
            self._extractor = FeatureExtractor(cfg.intrinsics, cfg.features, cfg.segmentation, self.families)
        ff = self._extractor(range_m, amplitude)
        return self.detect_maps(ff.maps, range_m, ff.rotation[2])
