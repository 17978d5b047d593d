"""The public nose detector on the user's own arrays, and the training and evaluation entry points `tofd train` and
`tofd evaluate` use (the lab's code, imported when first called)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from tofd.algorithm.detector import Candidates, Detection, Margin, NoseDetector, NoseModel, load_model
from tofd.api_inputs import checked_image, checked_range
from tofd.config import Config, default_file, load_config
from tofd.drivers.intrinsics import Intrinsics

if TYPE_CHECKING:
    from tofd.lab.dataset import Dataset
    from tofd.lab.evaluation import VariantResult

DEFAULT_MODEL = "nose_model.json"
"""The shipped model, trained on SR3000 renders (config/nose_model.json, installed as tofd.defaults)."""


def detect_nose(range_m: np.ndarray, amplitude: np.ndarray, intrinsics: Intrinsics, *,
                model: NoseModel | str | Path | None = None, config: Config | None = None) -> Detection:
    """Find the nose tip in one frame: segment the face, compute the model variant's features, test each pixel.

    Parameters
    ----------
    range_m : (H, W) float ndarray
        Radial range in metres; NaN, inf and values <= 0 are invalid pixels.
    amplitude : (H, W) float or integer ndarray
        The camera's amplitude (infrared intensity) image, any gain; the segmentation thresholds it.
    intrinsics : Intrinsics
        The camera's intrinsics in pixels, lens model included.
    model : NoseModel or path, optional
        A model from `train_model` or `load_model`, or a model file; default the shipped model.
    config : tofd.config.Config, optional
        Detector, feature and segmentation settings (``tofd.config.load_config(path)``); default the bundled
        config, whose feature settings the shipped model was trained with.

    Returns
    -------
    Detection
        ``nose_px``: (u, v) pixel (column, row) or None; ``nose_xyz_m``: the camera-frame point in metres or None;
        ``score``: the best pixel's box distance; ``accepted``: whether the acceptance rule holds.

    Raises
    ------
    ValueError
        Naming the argument for bad arrays; tofd.algorithm.detector.ModelMismatch (a ValueError's sibling,
        UsageError) when the model was trained with other feature settings than `config`'s.
    """
    checked_range(range_m, intrinsics, None)
    checked_image("amplitude", amplitude, intrinsics, allow_integers=True)
    cfg = config if config is not None else load_config()
    detector = NoseDetector(_model(model), cfg.detector, cfg.features, cfg.segmentation, intrinsics)
    return detector.detect_frame(range_m, np.asarray(amplitude, dtype=np.float64))


def render_dataset(split: str = "train", frames: int = 120, seed: int = 0,
                   intrinsics: Intrinsics | None = None) -> Dataset:
    """Render labelled frames of the built-in face models (what `tofd train` uses without --train).

    Parameters
    ----------
    split : {"train", "test"}
        Which subjects and distances.
    frames : int
        Number of frames.
    seed : int
        Seed of poses and sensor noise.
    intrinsics : Intrinsics, optional
        The camera to render for; default the SR3000's.

    Returns
    -------
    tofd.lab.dataset.Dataset
        ``range_m``, ``amplitude`` (F, H, W) float32, ``nose_px`` (F, 2), ``distance_m`` (F,) and more.
    """
    from tofd.lab.faces import generate

    return generate(split, frames, seed, intrinsics)


def load_dataset(path: str | Path) -> Dataset:
    """A labelled dataset file (.npz from `tofd dataset generate` or `tofd import`), as `tofd train --train` reads
    it; tofd.lab.dataset.DatasetError names a bad file."""
    from tofd.lab.dataset import load_labelled

    return load_labelled(path)


def train_model(dataset: Dataset, *, config: Config | None = None, quantile: float = 0.05,
                positive_radius_m: float = 0.005, workers: int = 1) -> NoseModel:
    """Learn a nose model (one box per feature variant) from labelled frames, as `tofd train` does.

    Parameters
    ----------
    dataset : tofd.lab.dataset.Dataset
        Labelled frames (`render_dataset`, `load_dataset`).
    config : tofd.config.Config, optional
        Feature, segmentation and candidate settings; default the bundled config.
    quantile : float
        Box quantile q: each feature's box spans its [q, 1 - q] range over the nose pixels.
    positive_radius_m : float
        Nose pixels: within this 3-D distance of the labelled tip, metres.
    workers : int
        Processes for the features.

    Returns
    -------
    NoseModel
        Save it with `save_model`; pass it to `detect_nose` or `evaluate_model`.
    """
    from tofd.lab.evaluation import extract_samples
    from tofd.lab.evaluation import train_model as train

    cfg = config if config is not None else load_config()
    samples = extract_samples(dataset, cfg.features, cfg.segmentation, workers)
    return train(samples, cfg.features, cfg.segmentation, quantile, positive_radius_m,
                 training={"data": "tofd.train_model", "subjects": sorted(set(dataset.subject.tolist()))},
                 candidates=Candidates.from_config(cfg.detector, cfg.segmentation))


def evaluate_model(model: NoseModel | str | Path | None, dataset: Dataset, *, config: Config | None = None,
                   workers: int = 1) -> dict[str, VariantResult]:
    """ROC and answers of every variant of a model on labelled frames, as `tofd evaluate --model` computes them.

    Parameters
    ----------
    model : NoseModel or path or None
        The model (None: the shipped one).
    dataset : tofd.lab.dataset.Dataset
        Labelled test frames.
    config : tofd.config.Config, optional
        Settings; default the bundled config.
    workers : int
        Processes for the features.

    Returns
    -------
    dict of str to tofd.lab.evaluation.VariantResult
        Per variant: ``overall`` ROC (``eer``, ``eer_scale``), ``answers`` at the operating scale, and both per
        distance bin (metres).
    """
    from tofd.lab.evaluation import evaluate_model as evaluate
    from tofd.lab.evaluation import extract_samples

    cfg = config if config is not None else load_config()
    nose_model = _model(model)
    nose_model.check_compatible(cfg.features, cfg.segmentation)
    samples = extract_samples(dataset, cfg.features, cfg.segmentation, workers)
    return evaluate(nose_model, samples, dataset.distance_m, candidates=Candidates.from_config(
        cfg.detector, cfg.segmentation), margin=Margin.from_config(cfg.detector))


def _model(model: NoseModel | str | Path | None) -> NoseModel:
    if model is None:
        return load_model(default_file(DEFAULT_MODEL))
    if isinstance(model, NoseModel):
        return model
    if isinstance(model, (str, Path)):
        return load_model(model)
    raise ValueError(f"model must be a NoseModel, a model file path or None, got {type(model).__name__}")
