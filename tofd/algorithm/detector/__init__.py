"""The paper's nose detector: a pixel is the nose tip iff its log10 feature vector lies in an axis-aligned box.

box.py: the box and its distance; model_file.py: the JSON model; candidates.py: which pixels may be the tip;
acceptance.py: whether the best of them is reported; detect.py: one frame's detection.
"""

from tofd.algorithm.detector.acceptance import PAPER_RULE, Margin, rival_distance
from tofd.algorithm.detector.box import Box, learn_box, stack_features, to_log_features
from tofd.algorithm.detector.candidates import (
    ALL_FOREGROUND,
    Candidates,
    border_distance_m,
    depth_noise_m,
    front_gap_m,
)
from tofd.algorithm.detector.detect import NOSE_RADIUS_M, Alternative, Detection, NoseDetector, detect
from tofd.algorithm.detector.model_file import (
    ModelError,
    ModelMismatch,
    NoseModel,
    VariantModel,
    load_model,
    parse_model,
    save_model,
)
from tofd.algorithm.names import VARIANTS

__all__ = ["ALL_FOREGROUND", "NOSE_RADIUS_M", "PAPER_RULE", "VARIANTS", "Alternative", "Box", "Candidates",
           "Detection", "Margin", "ModelError", "ModelMismatch", "NoseDetector", "NoseModel", "VariantModel",
           "border_distance_m", "depth_noise_m", "detect", "front_gap_m", "learn_box", "load_model", "parse_model",
           "rival_distance", "save_model", "stack_features", "to_log_features"]
