"""The public detector and its training / evaluation entry points on rendered, labelled frames."""

import dataclasses
import subprocess
import sys

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


def test_detect_nose_reports_the_tip_and_its_answer_within_the_found_radius(frames):
    tips = frames.nose_points()
    for i in range(len(frames)):
        found = tofd.detect_nose(frames.range_m[i].astype(np.float64), frames.amplitude[i], frames.intrinsics)
        assert found.tip_px is not None and found.tip_xyz_m is not None
        assert np.hypot(*(np.asarray(found.tip_px) - found.nose_px)) < 3.0  # refined about the accepted pixel
        assert found.answer_xyz_m == found.tip_xyz_m and found.answer_px == found.tip_px
        assert np.linalg.norm(np.asarray(found.answer_xyz_m) - tips[i]) <= tofd.NOSE_RADIUS_M
        for alternative in found.alternatives:
            assert alternative.score >= found.score


def test_a_model_mismatch_and_a_bad_config_are_value_errors(frames):
    assert issubclass(tofd.ModelMismatch, ValueError)
    r, a, intr = frames.range_m[0].astype(np.float64), frames.amplitude[0], frames.intrinsics
    config = load_config()
    other = dataclasses.replace(config, features=dataclasses.replace(config.features, damping=0.02))
    with pytest.raises(ValueError, match="features.damping"):
        tofd.detect_nose(r, a, intr, config=other)
    with pytest.raises(ValueError, match="config must be a tofd.config.Config"):
        tofd.detect_nose(r, a, intr, config=config.features)


CORE_INSTALL = """
import importlib.abc, sys
from tofd.extras import MODULE_EXTRAS

class NoExtras(importlib.abc.MetaPathFinder):  # a core install: no extra's module can be imported
    def find_spec(self, name, path, target=None):
        if name.split(".")[0] in MODULE_EXTRAS:
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)

sys.meta_path.insert(0, NoExtras())
import numpy as np
import tofd
frames = tofd.render_dataset("test", frames=2, seed=3)
model = tofd.train_model(tofd.render_dataset("train", frames=4, seed=1))
results = tofd.evaluate_model(model, frames)
tofd.save_model(model, sys.argv[1])
found = tofd.detect_nose(frames.range_m[0].astype(np.float64), frames.amplitude[0], frames.intrinsics,
                         model=tofd.load_model(sys.argv[1]))
print(sorted(results), found.nose_px is not None)
try:
    tofd.load_dataset(sys.argv[1])
except ModuleNotFoundError as exc:
    print(exc)
"""


@pytest.mark.slow
def test_rendering_training_and_evaluating_run_in_a_core_install_and_load_dataset_names_its_extra(tmp_path):
    out = subprocess.run([sys.executable, "-c", CORE_INSTALL, str(tmp_path / "m.json")], capture_output=True,
                         text=True, timeout=600, stdin=subprocess.DEVNULL)
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    assert lines[0] == "['fft_range', 'fft_range_amp', 'nfft_range', 'nfft_range_amp'] True"
    assert lines[1] == "tofd.load_dataset needs the 'lab' extra: pip install 'tofd[lab]'"
