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
from tofd.extras import install_hint

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
        ``nose_px``: (u, v) = (column, row) of the accepted pixel, int, or None when no pixel is accepted;
        ``nose_xyz_m``: that pixel's camera-frame point (x right, y down, z forward) in metres, or None;
        ``score``: the best candidate pixel's box distance (lower is better; inf without a foreground);
        ``accepted``: whether the acceptance rule holds (the box scale and, if configured, the margin test);
        ``tip_px``: (u, v) float sub-pixel nose tip fitted about the accepted pixel within
        ``config.detector.tip_radius_m``, or None (not refined, or none accepted);
        ``tip_xyz_m``: the tip's camera-frame point in metres, or None;
        ``alternatives``: up to three `tofd.algorithm.detector.Alternative` (``px``, ``xyz_m``, ``score``,
        ``tip_xyz_m``), best first: the best pixel of each other region whose box distance alone would pass the rule
        (a tracker may take one when the frame's own answer is rejected);
        ``answer_px`` and ``answer_xyz_m``: the reported nose, the tip when refined, else the accepted pixel.
        A detection is right when its point lies within `tofd.NOSE_RADIUS_M` of the true tip.

    Raises
    ------
    ValueError
        Naming the argument for bad arrays or a bad `model`; `tofd.ModelMismatch` (a ValueError) when the model was
        trained with other feature or segmentation settings than `config`'s.
    """
    checked_range(range_m, intrinsics, None)
    checked_image("amplitude", amplitude, intrinsics, allow_integers=True)
    cfg = _config(config)
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
    it; tofd.lab.dataset.DatasetError names a bad file. Needs the lab extra (fsspec: local paths and URLs alike)."""
    from tofd.lab.dataset import load_labelled

    try:
        import fsspec  # noqa: F401  (checked here, to name the extra)
    except ModuleNotFoundError as exc:
        raise ModuleNotFoundError(f"tofd.load_dataset {install_hint('lab')}", name=exc.name) from exc

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

    cfg = _config(config)
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

    cfg = _config(config)
    nose_model = _model(model)
    nose_model.check_compatible(cfg.features, cfg.segmentation)
    samples = extract_samples(dataset, cfg.features, cfg.segmentation, workers)
    return evaluate(nose_model, samples, dataset.distance_m, candidates=Candidates.from_config(
        cfg.detector, cfg.segmentation), margin=Margin.from_config(cfg.detector))


def _config(config: Config | None) -> Config:
    """`config`, or the bundled config for None; ValueError unless it is a tofd.config.Config."""
    if config is None:
        return load_config()
    if not isinstance(config, Config):
        raise ValueError(f"config must be a tofd.config.Config (tofd.config.load_config(path)), got "
                         f"{type(config).__name__}")
    return config


def _model(model: NoseModel | str | Path | None) -> NoseModel:
    if model is None:
        return load_model(default_file(DEFAULT_MODEL))
    if isinstance(model, NoseModel):
        return model
    if isinstance(model, (str, Path)):
        return load_model(model)
    raise ValueError(f"model must be a NoseModel, a model file path or None, got {type(model).__name__}")
