"""The public detector and its training / evaluation entry points on rendered, labelled frames."""

import dataclasses

import numpy as np
import pytest

import tofd
from tofd.algorithm.detector import ModelError, ModelMismatch
from tofd.config import load_config


@pytest.fixture(scope="module")
def frames():
    return tofd.render_dataset("test", 4, seed=3)


def test_detect_nose_with_the_shipped_model_finds_rendered_noses(frames):
    for i in range(len(frames)):
        found = tofd.detect_nose(frames.range_m[i].astype(np.float64), frames.amplitude[i], frames.intrinsics)
        assert found.accepted and found.nose_px is not None
        assert np.hypot(*(np.asarray(found.nose_px) - frames.nose_px[i])) <= 5.0
        assert 0.3 < found.nose_xyz_m[2] < 0.8


def test_detect_nose_checks_its_arguments(frames, tmp_path):
    r, a, intr = frames.range_m[0].astype(np.float64), frames.amplitude[0], frames.intrinsics
    with pytest.raises(ValueError, match="amplitude has shape"):
        tofd.detect_nose(r, a[:-1], intr)
    with pytest.raises(ValueError, match="range_m looks like millimetres"):
        tofd.detect_nose(1000 * r, a, intr)
    with pytest.raises(ValueError, match="model must be a NoseModel"):
        tofd.detect_nose(r, a, intr, model=3)
    bad = tmp_path / "model.json"
    bad.write_text("{}")
    with pytest.raises(ModelError, match="model.json"):
        tofd.detect_nose(r, a, intr, model=bad)


@pytest.mark.slow
def test_train_save_load_evaluate_round_trip(frames, tmp_path):
    model = tofd.train_model(tofd.render_dataset("train", 12, seed=1))
    path = tofd.save_model(model, tmp_path / "m.json")
    loaded = tofd.load_model(path)
    assert set(loaded.variants) == set(model.variants)
    results = tofd.evaluate_model(path, frames)
    assert results["nfft_range"].answers.found >= 0.75
    found = tofd.detect_nose(frames.range_m[0].astype(np.float64), frames.amplitude[0], frames.intrinsics,
                             model=loaded)
    assert found.nose_px is not None
    config = load_config()
    other = dataclasses.replace(config, features=dataclasses.replace(config.features, damping=0.02))
    with pytest.raises(ModelMismatch, match="features.damping"):
        tofd.evaluate_model(loaded, frames, config=other)
