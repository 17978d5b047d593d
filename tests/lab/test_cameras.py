"""One model for every camera: the lab's camera option, the segmentation's pixel sizes in metres on a camera of
finer pixels, and the shipped model (trained on SR3000 renders) finding the tip on a 640x576 camera."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tofd.algorithm.segmentation import coarse_stride, decimated, segment_face
from tofd.config import load_config
from tofd.drivers.emulator.render import Pose, render_face
from tofd.drivers.intrinsics import Intrinsics
from tofd.lab.cameras import CAMERAS, parse_intrinsics
from tofd.lab.faces import SUBJECTS, make_subject
from tofd.service.model import load_detector

ROOT = Path(__file__).resolve().parents[2]
K4A = CAMERAS["k4a-nfov"]


def test_intrinsics_option_takes_a_name_six_numbers_or_a_recording():
    assert parse_intrinsics("sr3000") == Intrinsics()
    assert parse_intrinsics("96,80,100,101,47.5,39.5") == Intrinsics(96, 80, 100.0, 101.0, 47.5, 39.5)
    assert parse_intrinsics(str(ROOT / "replay_data" / "emulated_face_035_070.mcap")) == Intrinsics()
    for bad, words in (("96,80,0,100,47,39", "fx and fy"), ("a,b,c,d,e,f", "six numbers"), ("k4a", "not a camera")):
        with pytest.raises(ValueError, match=words):
            parse_intrinsics(bad)


def test_dataset_generate_renders_the_given_camera(tmp_path):
    env = {**os.environ, "RERUN": "off"}
    out = tmp_path / "d.npz"
    run = subprocess.run([sys.executable, "-m", "tofd", "dataset", "generate", str(out), "--frames", "2",
                          "--intrinsics", "96,80,100,100,47.5,39.5"], capture_output=True, text=True, env=env,
                         timeout=120)
    assert run.returncode == 0, run.stderr
    with np.load(out) as d:
        assert d["range"].shape == (2, 80, 96)
    assert json.loads(out.with_suffix(".json").read_text())["intrinsics"]["fx"] == 100.0
    bad = subprocess.run([sys.executable, "-m", "tofd", "dataset", "generate", str(tmp_path / "e.npz"),
                          "--intrinsics", "640x576"], capture_output=True, text=True, env=env, timeout=120)
    assert bad.returncode == 2 and "--intrinsics" in bad.stderr and "Traceback" not in bad.stderr


def test_decimation_keeps_each_pixels_ray():
    assert coarse_stride(Intrinsics()) == 1 and coarse_stride(K4A) == 3
    coarse = decimated(K4A, 3)
    np.testing.assert_allclose(coarse.unit_rays(), K4A.unit_rays()[::3, ::3], atol=1e-12)


def foreground_m2(mask: np.ndarray, range_m: np.ndarray, intrinsics: Intrinsics) -> float:
    """Area the foreground covers, square metres (each pixel's footprint at its depth)."""
    z = range_m * intrinsics.unit_rays()[..., 2]
    return float(np.sum((z[mask] / intrinsics.fx) * (z[mask] / intrinsics.fy)))


@pytest.mark.parametrize("distance", [0.35, 0.7])
def test_segmentation_covers_the_same_face_on_both_cameras(distance):
    cfg = load_config(None)
    mesh, pose = make_subject(SUBJECTS["mp_bignose"]), Pose(distance, 15.0, 5.0)
    found = {}
    for name, intrinsics in (("sr3000", Intrinsics()), ("k4a", K4A)):
        r = render_face(mesh, pose, intrinsics, np.random.default_rng(2))
        fg = segment_face(r.range_m, r.amplitude, cfg.segmentation, intrinsics)
        assert fg.mask[round(r.nose_px[1]), round(r.nose_px[0])]
        found[name] = (foreground_m2(fg.mask, r.range_m, intrinsics), fg.rotation[2])
    assert found["k4a"][0] == pytest.approx(found["sr3000"][0], rel=0.15)
    assert np.degrees(np.arccos(found["k4a"][1] @ found["sr3000"][1])) < 3.0


@pytest.mark.parametrize("distance", [0.4, 0.65])
def test_shipped_model_finds_the_tip_on_a_640x576_camera(distance):
    cfg = load_config(None)
    detector = load_detector(cfg)
    detector = type(detector)(detector.model, cfg.detector, cfg.features, cfg.segmentation, K4A)
    r = render_face(make_subject(SUBJECTS["lps_smallnose"]), Pose(distance, -12.0, 4.0), K4A,
                    np.random.default_rng(7))
    det = detector.detect_frame(r.range_m, r.amplitude)
    assert det.accepted and np.linalg.norm(np.subtract(det.answer_xyz_m, r.nose_xyz_m)) < 0.010


def test_front_gap_of_a_noisy_plane_is_alike_on_both_cameras():
    """The front test compares a pixel with the front-most depth within 12 mm: on a noisy plane that gap is noise
    only, and it must not grow with the number of pixels the disc holds on a camera of finer pixels."""
    from tofd.algorithm.detector import front_gap_m

    gaps = {}
    for name, intrinsics in (("sr3000", Intrinsics()), ("k4a", K4A)):
        rng = np.random.default_rng(4)
        range_m = 0.6 / intrinsics.unit_rays()[..., 2] + rng.normal(0.0, 0.003, intrinsics.shape)
        mask = np.ones(intrinsics.shape, bool)
        gaps[name] = float(np.median(front_gap_m(mask, range_m, intrinsics)[mask]))
    assert gaps["k4a"] == pytest.approx(gaps["sr3000"], rel=0.25)
