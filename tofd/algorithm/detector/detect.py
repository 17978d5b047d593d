"""Nose detection in one frame: the candidate pixel of smallest box distance, reported if the acceptance rule
(acceptance.py: within the box scale, and with the margin test well ahead of any rival) holds, refined to the
sub-pixel tip (tip.py). Beside it, the best pixel of each of up to MAX_ALTERNATIVES regions (RIVAL_RADIUS_M apart)
whose box distance alone would pass the rule: a nose track near one of them may take it when the frame's own
answer is rejected (tofd.algorithm.tracking), since the track settles what the margin test cannot in one frame."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tofd.algorithm.detector.acceptance import PAPER_RULE, Margin, region_bests
from tofd.algorithm.detector.box import Box, require_maps, stack_features
from tofd.algorithm.detector.candidates import ALL_FOREGROUND, Candidates
from tofd.algorithm.detector.model_file import NoseModel
from tofd.algorithm.detector.tip import refine_tip
from tofd.algorithm.extract import FeatureExtractor
from tofd.algorithm.names import families_for
from tofd.algorithm.params import DetectorConfig, FeatureConfig, SegmentationConfig
from tofd.algorithm.segmentation import rotation_to_z
from tofd.drivers.intrinsics import Intrinsics

MAX_ALTERNATIVES = 3  # regions whose best pixel a frame reports as alternatives
NOSE_RADIUS_M = 0.015
"""Metres: a detection is right (the nose "found") when its point lies within this 3-D distance of the true tip;
evaluation counts the foreground pixels within it as the nose (tofd.lab.evaluation)."""


@dataclass(frozen=True, slots=True)
class Alternative:
    """A region's best candidate pixel inside the box at the acceptance scale (the margin test left out)."""

    px: tuple[int, int]  # (u, v) = (column, row)
    xyz_m: tuple[float, float, float]  # the pixel's point, camera frame, metres
    score: float  # box distance
    tip_xyz_m: tuple[float, float, float] | None = None  # its refined tip (None: not refined)

    @property
    def answer_xyz_m(self) -> tuple[float, float, float]:
        return self.tip_xyz_m if self.tip_xyz_m is not None else self.xyz_m


@dataclass(frozen=True, slots=True)
class Detection:
    """The detector's answer for one frame: the best pixel, its 3-D point, and whether it is in the box."""

    nose_px: tuple[int, int] | None  # (u, v) = (column, row) of the accepted pixel, None if none accepted
    nose_xyz_m: tuple[float, float, float] | None  # camera frame, metres
    score: float  # box distance of the best foreground pixel (lower is better; inf if no foreground)
    accepted: bool  # the acceptance rule holds (acceptance.Margin.accepts)
    tip_px: tuple[float, float] | None = None  # (u, v) sub-pixel nose tip near the accepted pixel (tip.py), or None
    tip_xyz_m: tuple[float, float, float] | None = None  # camera frame, metres; None: not refined or none accepted
    alternatives: tuple[Alternative, ...] = ()  # best first (module docstring); empty when none is inside the box

    @property
    def answer_xyz_m(self) -> tuple[float, float, float] | None:
        """The reported nose point: the refined tip, else the accepted pixel's point (None if none accepted)."""
        return self.tip_xyz_m if self.tip_xyz_m is not None else self.nose_xyz_m

    @property
    def answer_px(self) -> tuple[float, float] | None:
        """The reported nose pixel (u, v): the refined tip's, else the accepted pixel (None if none accepted)."""
        return self.tip_px if self.tip_px is not None else self.nose_px


def detect(maps: dict[str, np.ndarray], range_m: np.ndarray, intrinsics: Intrinsics, box: Box,
           scale: float, candidates: Candidates = ALL_FOREGROUND, direction: np.ndarray | None = None,
           margin: Margin = PAPER_RULE, tip_radius_m: float = 0.0,
           bounds: tuple[slice, slice] | None = None) -> Detection:
    """Detect the nose in one frame from its feature maps ((H, W), NaN outside the foreground).

    range_m: (H, W) radial range in metres, for the 3-D point of the detected pixel and the candidate tests.
    candidates: which foreground pixels (where all the box's features are finite) may be the nose (module
    docstring); direction: the face's viewing direction for the front test (segmentation.Foreground.rotation
    row 2). Only candidate pixels are scored (a few thousand of 25k). margin: the acceptance rule beyond the scale.
    tip_radius_m: > 0: the accepted pixel is refined to the sub-pixel tip (tip.refine_tip, window of this radius).
    bounds: (rows, cols) outside which every map is NaN (the segmentation mask's bounding box), so only these
    pixels of the maps are read; None: the whole image.
    """
    require_maps(maps, box.features)
    region = bounds or (slice(None), slice(None))
    foreground = np.zeros(np.shape(maps[box.features[0]]), bool)
    inside = np.isfinite(maps[box.features[0]][region])
    for name in box.features[1:]:
        inside &= np.isfinite(maps[name][region])
    foreground[region] = inside
    rows, cols = candidates.pixels(foreground, range_m, intrinsics, direction)
    if rows.size == 0:
        return Detection(None, None, float("inf"), False)
    dist = box.distance(stack_features({n: maps[n][rows, cols] for n in box.features}, box.features))
    points = intrinsics.unit_rays()[rows, cols] * np.asarray(range_m, dtype=np.float64)[rows, cols, None]
    regions = region_bests(dist, points, MAX_ALTERNATIVES) or [int(np.argmin(dist))]
    best = regions[0]
    score = float(dist[best])
    rival = float(dist[regions[1]]) if len(regions) > 1 else np.inf
    rotation = np.eye(3) if direction is None else rotation_to_z(np.asarray(direction, dtype=np.float64))
    within = margin.scale_factor * scale if margin.ratio > 0 else scale

    def alternative(i: int) -> Alternative:
        pixel, (x, y, z) = (int(cols[i]), int(rows[i])), (float(c) for c in points[i])
        tip = (refine_tip(np.asarray(range_m), foreground, intrinsics, pixel, rotation, tip_radius_m)
               if tip_radius_m > 0 else None)
        return Alternative(pixel, (x, y, z), float(dist[i]), None if tip is None else tip.xyz_m)

    alternatives = tuple(alternative(i) for i in regions if dist[i] <= within)
    if not margin.accepts(score, rival, scale):
        return Detection(None, None, score, False, alternatives=alternatives)
    top = alternatives[0]
    if top.tip_xyz_m is None:
        return Detection(top.px, top.xyz_m, score, True, alternatives=alternatives)
    u, v = intrinsics.project(np.asarray(top.tip_xyz_m))
    return Detection(top.px, top.xyz_m, score, True, (float(u), float(v)), top.tip_xyz_m, alternatives)


class NoseDetector:
    """One variant of a nose model at one box scale, with the candidate tests of `detector`.

    `detect_maps` works on feature maps computed elsewhere (the pipeline's workers); `detect_frame` segments and
    computes the variant's features itself (tofd.algorithm.extract).
    """

    def __init__(self, model: NoseModel, detector: DetectorConfig, features: FeatureConfig,
                 segmentation: SegmentationConfig, intrinsics: Intrinsics) -> None:
        model.check_compatible(features, segmentation)
        vm = model.variant(detector.variant)
        self.model, self.box, self.intrinsics = model, vm.box, intrinsics
        self.scale = detector.box_scale if detector.box_scale > 0 else vm.operating_scale
        self.candidates = Candidates.from_config(detector, segmentation)
        self.margin = Margin.from_config(detector)
        self.tip_radius_m = detector.tip_radius_m
        self.families = families_for(self.box.features)
        self._features, self._segmentation = features, segmentation
        self._extractor: FeatureExtractor | None = None

    def detect_maps(self, maps: dict[str, np.ndarray], range_m: np.ndarray,
                    direction: np.ndarray | None = None, bounds: tuple[slice, slice] | None = None) -> Detection:
        """Detection from named feature maps (tofd.algorithm.names), the frame's (H, W) range in metres and the
        face's viewing direction (FrameFeatures.rotation[2]; None: the camera's z axis); `bounds`: see detect."""
        return detect(maps, range_m, self.intrinsics, self.box, self.scale, self.candidates, direction, self.margin,
                      self.tip_radius_m, bounds)

    def detect_frame(self, range_m: np.ndarray, amplitude: np.ndarray) -> Detection:
        """Segment, compute this variant's features, detect."""
        if self._extractor is None:
            self._extractor = FeatureExtractor(self.intrinsics, self._features, self._segmentation, self.families)
        ff = self._extractor(range_m, amplitude)
        return self.detect_maps(ff.maps, range_m, ff.rotation[2])
