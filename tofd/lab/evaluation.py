"""The paper's evaluation: train the box detector on one dataset, trace per-image ROC curves on another.

Features are computed once per frame (all four families: range and amplitude, FFT and NFFT), reduced to
the foreground pixels' log10 features and their 3-D distance to the ground-truth nose tip, and reused by all
four variants and every box scale. True nose pixels: foreground pixels within `radius_m` (15 mm) of the tip,
each pixel's 3-D point taken from the 3x3-median-filtered range (`label_points`);
the box is learned from the tighter `positive_radius_m` neighbourhood of the tip (the tip's own features,
not those of the nose's flanks, which also sit 15 mm away from it), and its half-widths are then shaped with
all training pixels, nose and not (`shape_box`). Only the
candidate pixels (detector.Candidates: border margin, front test) are ever classified nose, in training as in
testing, as in the pipeline.
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import multiprocessing
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

import numpy as np

from tofd.algorithm.detector import (
    ALL_FOREGROUND,
    NOSE_RADIUS_M,
    PAPER_RULE,
    VARIANTS,
    Box,
    Candidates,
    Margin,
    NoseModel,
    VariantModel,
    border_distance_m,
    depth_noise_m,
    front_gap_m,
    learn_box,
    rival_distance,
    to_log_features,
)
from tofd.algorithm.extract import FeatureExtractor
from tofd.algorithm.names import MAP_NAMES
from tofd.algorithm.params import FeatureConfig, SegmentationConfig
from tofd.algorithm.segmentation import filtered, valid_pixels
from tofd.drivers.intrinsics import Intrinsics
from tofd.lab.dataset import Dataset
from tofd.lab.roc import Answers, RocCurve, answers_at, margin_scale, roc_from_min_distances
from tofd.process_setup import THREAD_ENV, child_environment, prepare_compute_process

DISTANCE_BIN_M = 0.05  # per-distance results group frames by nose distance rounded to this
LABEL_MEDIAN_PX = 3  # median filter (pixels) of the range the true-nose labels are measured on (label_points)


def label_points(range_m: np.ndarray, intrinsics: Intrinsics) -> np.ndarray:
    """(H, W, 3) camera-frame points (metres) of the LABEL_MEDIAN_PX median-filtered range, for the labels.

    A label is ground truth, so range noise must not move a pixel across the true-nose radius; invalid pixels
    count as far (segmentation.filtered).
    """
    return intrinsics.backproject(filtered(range_m, valid_pixels(range_m), LABEL_MEDIAN_PX))


@dataclass(slots=True)
class FrameSamples:
    """The foreground pixels of one frame, reduced to what the evaluation needs."""

    log_features: np.ndarray  # (P, len(MAP_NAMES)) float32 log10 eccentricities, columns MAP_NAMES
    tip_distance_m: np.ndarray  # (P,) float32 3-D distance to the ground-truth nose tip (NaN if unknown)
    border_m: np.ndarray  # (P,) float32 distance to the mask border, metres (tofd.algorithm.detector.border_distance_m)
    front_gap: np.ndarray  # (P,) float32 metres behind the front-most pixel nearby (detector.front_gap_m)
    noise_m: np.ndarray  # (P,) float32 local range noise sigma, metres (detector.depth_noise_m)
    xyz_m: np.ndarray  # (P, 3) float32 camera-frame point of the range, metres (the detector's rival distance)
    nfft_iterations: int = 0


def frame_samples(extractor: FeatureExtractor, range_m: np.ndarray, amplitude: np.ndarray,
                  nose_xyz_m: np.ndarray) -> FrameSamples:
    """Features of one frame's foreground pixels and their distance to the nose tip (label_points)."""
    ff = extractor(range_m, amplitude)
    points = label_points(range_m, extractor.intrinsics)[ff.mask]
    tip = np.linalg.norm(points - np.asarray(nose_xyz_m, dtype=np.float64), axis=1).astype(np.float32)
    feats = np.stack([ff.maps[n][ff.mask] for n in MAP_NAMES], axis=1)
    border = border_distance_m(ff.mask, range_m, extractor.intrinsics)[ff.mask]
    front = front_gap_m(ff.mask, range_m, extractor.intrinsics, ff.rotation[2])[ff.mask]
    noise = depth_noise_m(ff.mask, range_m, extractor.intrinsics, ff.rotation[2])[ff.mask]
    xyz = extractor.intrinsics.backproject(range_m)[ff.mask].astype(np.float32)
    return FrameSamples(to_log_features(feats).astype(np.float32), tip, border, front, noise, xyz, ff.nfft_iterations)


Settings = tuple[Intrinsics, FeatureConfig, SegmentationConfig]


@functools.cache
def _extractor(settings: Settings) -> FeatureExtractor:
    """A FeatureExtractor of `settings`, made once per process (its plans take a while to build)."""
    return FeatureExtractor(*settings)


def _samples(settings: Settings, job: tuple[np.ndarray, np.ndarray, np.ndarray]) -> FrameSamples:
    return frame_samples(_extractor(settings), *job)


def extract_samples(dataset: Dataset, features: FeatureConfig, segmentation: SegmentationConfig,
                    workers: int = 2, progress: Callable[[int, int], None] | None = None) -> list[FrameSamples]:
    """FrameSamples of every frame, in order; `workers` > 1 spreads frames over spawned processes."""
    tips = dataset.nose_points()
    tips[~dataset.nose_visible] = np.nan
    jobs = ((dataset.range_m[i], dataset.amplitude[i], tips[i]) for i in range(len(dataset)))
    out: list[FrameSamples] = []

    def collect(results: Iterator[FrameSamples]) -> list[FrameSamples]:
        for s in results:
            out.append(s)
            if progress is not None:
                progress(len(out), len(dataset))
        return out

    settings = (dataset.intrinsics, features, segmentation)
    if workers <= 1 or len(dataset) < 2 * workers:
        extractor = FeatureExtractor(*settings)  # in this process, whose settings stay the caller's
        return collect(frame_samples(extractor, *job) for job in jobs)
    with child_environment(THREAD_ENV):  # the spawned workers' BLAS/OpenMP load single-threaded
        pool = multiprocessing.get_context("spawn").Pool(workers, prepare_compute_process)
    with pool:
        return collect(pool.imap(functools.partial(_samples, settings), jobs, chunksize=2))


def _columns(variant: str) -> list[int]:
    return [MAP_NAMES.index(n) for n in VARIANTS[variant]]


class PixelTable:
    """All frames' foreground pixels of one variant in one array, for fast per-image minima over many boxes.

    Rows are frames' candidate pixels (detector.Candidates) in frame order; the others are never classified
    nose. true: pixels within radius_m of the ground-truth tip.
    """

    def __init__(self, samples: list[FrameSamples], variant: str, radius_m: float,
                 candidates: Candidates = ALL_FOREGROUND):
        cols = _columns(variant)
        keep = [candidates.keep(s.border_m, s.front_gap, s.noise_m) for s in samples]
        self.n_frames = len(samples)
        self.features = np.concatenate([s.log_features[k][:, cols] for s, k in zip(samples, keep, strict=True)]
                                        or [np.empty((0, len(cols)), np.float32)]).astype(np.float64)
        self.frame = np.repeat(np.arange(len(samples)), [int(k.sum()) for k in keep])
        self.true = np.concatenate([s.tip_distance_m[k] <= radius_m for s, k in zip(samples, keep, strict=True)]
                                   or [np.empty(0, bool)])
        self.xyz = np.concatenate([s.xyz_m[k] for s, k in zip(samples, keep, strict=True)]
                                  or [np.empty((0, 3), np.float32)])

    def min_distances(self, distance: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per frame: smallest of `distance` (one per row) over its true nose pixels and over its others (inf:
        none)."""
        return (self._frame_min(distance[self.true], self.frame[self.true]),
                self._frame_min(distance[~self.true], self.frame[~self.true]))

    def rivals(self, distance: np.ndarray) -> np.ndarray:
        """Per frame: the smallest of `distance` over the pixels farther than the detector's rival radius from the
        frame's best pixel (tofd.algorithm.detector.rival_distance; inf: none)."""
        out = np.full(self.n_frames, np.inf)
        bounds: list[int] = (np.flatnonzero(np.r_[True, self.frame[1:] != self.frame[:-1], True]).tolist()
                             if len(self.frame) else [])
        for start, stop in itertools.pairwise(bounds):
            d = distance[start:stop]
            out[self.frame[start]] = rival_distance(d, self.xyz[start:stop])
        return out

    def _frame_min(self, values: np.ndarray, frame: np.ndarray) -> np.ndarray:
        out = np.full(self.n_frames, np.inf)
        if len(values):
            starts = np.flatnonzero(np.r_[True, frame[1:] != frame[:-1]])
            out[frame[starts]] = np.minimum.reduceat(values, starts)
        return out


def min_distances(samples: list[FrameSamples], variant: str, box: Box, radius_m: float,
                  candidates: Candidates = ALL_FOREGROUND) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per frame: smallest box distance of its true nose pixels and of its other foreground pixels, and that of
    the best pixel's rival (inf: none); pixels that are not candidates count as inf (never classified nose)."""
    table = PixelTable(samples, variant, radius_m, candidates)
    distance = box.distance(table.features)
    return (*table.min_distances(distance), table.rivals(distance))


WIDTH_MULTIPLIERS = (0.5, 0.7, 1.0, 1.4, 2.0, 3.0, 10.0)
"""Candidate factors on each feature's quantile half-width but the first (the ROC sweep sets the overall size);
10 all but removes a feature from the box."""
MARGIN_CLIP = 0.5  # log10 units: a frame's margin log10(false_min / true_min) counts up to this


def shape_box(box: Box, table: PixelTable, has_nose: np.ndarray) -> tuple[Box, RocCurve]:
    """The box with per-feature half-widths rescaled by WIDTH_MULTIPLIERS to minimise the training EER.

    The quantile box only knows the nose pixels; the negatives decide how much each feature may vary: a feature
    that separates nothing on the training frames (e.g. amplitude on some data) is widened until it stops
    costing detections, one that separates well is tightened. Ties go to the box nearest the quantile box
    (smallest sum of |log multiplier|), then to the larger mean per-frame margin log10(false_min / true_min)
    (clipped at MARGIN_CLIP): the paper's box changes only where the training EER asks for it, and the many ties
    at training EER 0 are not broken by the margin's chance variations. Vectorised over pixels: 7^(k-1) ROC
    sweeps on per-feature box distances computed once.
    """
    deviation = np.abs(table.features - box.centre) / box.half_width  # (P, k): box distance per feature
    deviation[np.isnan(deviation)] = np.inf
    best: tuple[tuple[float, float, float], np.ndarray, RocCurve] | None = None
    for tail in itertools.product(WIDTH_MULTIPLIERS, repeat=len(box.features) - 1):
        mult = np.array((1.0, *tail))
        true_min, false_min = table.min_distances(np.max(deviation / mult, axis=1))
        roc = roc_from_min_distances(true_min, false_min, has_nose)
        with np.errstate(divide="ignore", invalid="ignore"):
            margin = np.clip(np.log10(false_min[has_nose] / true_min[has_nose]), -MARGIN_CLIP, MARGIN_CLIP)
        key = (round(roc.eer, 9), float(np.abs(np.log(mult)).sum()), -float(np.nan_to_num(margin, nan=0.0).mean()))
        if best is None or key < best[0]:
            best = (key, mult, roc)
    if best is None:
        raise ValueError("box: has no features")
    _, mult, roc = best
    return Box(box.features, box.centre, box.half_width * mult), roc


def has_nose(samples: list[FrameSamples], radius_m: float) -> np.ndarray:
    """(F,) bool: frames with a foreground pixel within radius_m of the nose tip (they count for detection)."""
    return np.array([bool(np.any(s.tip_distance_m <= radius_m)) for s in samples])


def train_model(samples: list[FrameSamples], features: FeatureConfig, segmentation: SegmentationConfig,
                quantile: float = 0.05, positive_radius_m: float = 0.005, radius_m: float = NOSE_RADIUS_M,
                variants: tuple[str, ...] = tuple(VARIANTS), training: dict | None = None,
                candidates: Candidates = ALL_FOREGROUND) -> NoseModel:
    """Learn each variant's box: the quantile box of the candidate pixels within positive_radius_m of the nose
    tips, its half-widths then shaped on the training frames (shape_box, true nose radius radius_m). The
    operating scale is the middle of the training frames' zero-error interval (tofd.lab.roc.margin_scale), else their
    equal-error scale: the interval's lower end, the training EER scale, fits the training noses with no room,
    and the pipeline then rejected noses of new faces (3-subject default model, NFFT range, share of 960 frames
    found: lps_long 95.7 -> 99.4 %, mp_bignose 89.8 -> 97.8 %, lps_smallnose 4.4 -> 33.5 %; wrong answers
    0.0 % at both scales; `tofd evaluate [--test-subjects S]`). The candidate rule is recorded in the model's
    training info."""
    positive = [s.log_features[(s.tip_distance_m <= positive_radius_m)
                               & candidates.keep(s.border_m, s.front_gap, s.noise_m)] for s in samples]
    pos = np.concatenate(positive) if positive else np.empty((0, len(MAP_NAMES)), np.float32)
    with_nose = has_nose(samples, radius_m)
    out = {}
    for variant in variants:
        table = PixelTable(samples, variant, radius_m, candidates)
        box, roc = shape_box(learn_box(pos[:, _columns(variant)], VARIANTS[variant], quantile), table, with_nose)
        scale = margin_scale(*table.min_distances(box.distance(table.features)), with_nose, roc.eer_scale)
        out[variant] = VariantModel(variant, box, round(scale, 6), round(roc.eer, 6))
    info = {"frames": len(samples), "positive_pixels": int(len(pos)), **dataclasses.asdict(candidates),
            **(training or {})}
    return NoseModel(out, dataclasses.asdict(features), dataclasses.asdict(segmentation), quantile,
                     positive_radius_m * 1e3, info)


@dataclass(slots=True)
class VariantResult:
    """One variant's ROC on the whole test set, per distance bin (metres) and per identity (subject name), and
    its answers at the model's operating scale (what the pipeline reports) likewise."""

    variant: str
    overall: RocCurve
    answers: Answers
    per_distance: dict[float, RocCurve] = field(default_factory=dict)
    answers_per_distance: dict[float, Answers] = field(default_factory=dict)
    per_subject: dict[str, RocCurve] = field(default_factory=dict)
    answers_per_subject: dict[str, Answers] = field(default_factory=dict)


def distance_bins(distance_m: np.ndarray) -> np.ndarray:
    """Nose distances rounded to DISTANCE_BIN_M (the keys of the per-distance results)."""
    return np.round(np.round(np.asarray(distance_m) / DISTANCE_BIN_M) * DISTANCE_BIN_M, 3)


def distance_groups(distance_m: np.ndarray) -> dict[float, np.ndarray]:
    """Bin (distance_bins) -> indices of the frames in it; frames of unknown (non-finite) distance are in none."""
    distance_m = np.asarray(distance_m, dtype=np.float64)
    known = np.flatnonzero(np.isfinite(distance_m))
    bins = distance_bins(distance_m[known])
    return {float(b): known[bins == b] for b in np.unique(bins)}


def subject_groups(subject: np.ndarray) -> dict[str, np.ndarray]:
    """Identity (subject name) -> indices of its frames, names sorted."""
    subject = np.asarray(subject).astype(str)
    return {str(s): np.flatnonzero(subject == s) for s in np.unique(subject)}


@dataclass(slots=True)
class ImageMinima:
    """Per image, what each variant's per-image ROC needs (tofd.lab.roc.roc_from_min_distances): whether it has
    a true nose pixel, and the smallest box distance of its true nose pixels and of its other candidate pixels."""

    has_nose: np.ndarray  # (F,) bool
    true_min: dict[str, np.ndarray]  # variant -> (F,) float64, inf: no such pixel
    false_min: dict[str, np.ndarray]  # variant -> (F,) float64, inf: no such pixel
    rival: dict[str, np.ndarray]  # variant -> (F,) float64: the best pixel's rival (acceptance.rival_distance)


def image_minima(model: NoseModel, samples: list[FrameSamples], radius_m: float = NOSE_RADIUS_M,
                 candidates: Candidates = ALL_FOREGROUND) -> ImageMinima:
    """ImageMinima of the frames' samples for every variant of the model (true nose: within radius_m of the tip)."""
    mins = {name: min_distances(samples, name, vm.box, radius_m, candidates) for name, vm in model.variants.items()}
    return ImageMinima(has_nose(samples, radius_m), {n: m[0] for n, m in mins.items()},
                       {n: m[1] for n, m in mins.items()}, {n: m[2] for n, m in mins.items()})


def variant_results(model: NoseModel, minima: ImageMinima, distance_m: np.ndarray,
                    margin: Margin = PAPER_RULE, subject: np.ndarray | None = None) -> dict[str, VariantResult]:
    """ROC curves and answers (with the acceptance rule's `margin`) of every variant of the model from the images'
    minima, overall, per distance bin (distance_m: (F,) nose distance of each image, metres) and, given the
    images' subject names (F,), per identity."""
    by_distance = distance_groups(distance_m)
    by_subject = subject_groups(subject) if subject is not None else {}
    results = {}
    for name, vm in model.variants.items():
        part = functools.partial(_roc_and_answers, minima, name, vm.operating_scale, margin)
        res = VariantResult(name, *part(np.arange(len(minima.has_nose))))
        for b, sel in by_distance.items():
            res.per_distance[b], res.answers_per_distance[b] = part(sel)
        for s, sel in by_subject.items():
            res.per_subject[s], res.answers_per_subject[s] = part(sel)
        results[name] = res
    return results


def _roc_and_answers(minima: ImageMinima, variant: str, scale: float, margin: Margin,
                     sel: np.ndarray) -> tuple[RocCurve, Answers]:
    """The ROC and the answers of one variant over the images `sel`."""
    tmin, fmin, rival = minima.true_min[variant][sel], minima.false_min[variant][sel], minima.rival[variant][sel]
    return roc_from_min_distances(tmin, fmin, minima.has_nose[sel]), answers_at(tmin, fmin, scale, rival, margin)


def evaluate_model(model: NoseModel, samples: list[FrameSamples], distance_m: np.ndarray,
                   radius_m: float = NOSE_RADIUS_M, candidates: Candidates = ALL_FOREGROUND,
                   margin: Margin = PAPER_RULE, subject: np.ndarray | None = None) -> dict[str, VariantResult]:
    """ROC curves and answers (acceptance rule: the scale and `margin`) of every variant of the model on test
    samples, overall, per distance bin and (given the frames' subject names) per identity."""
    return variant_results(model, image_minima(model, samples, radius_m, candidates), distance_m, margin, subject)
