"""The dataset file: round trip, invalid ranges, sidecar intrinsics, errors that name the key."""

import json

import numpy as np
import pytest

from tofd.drivers.frame import Frame, GroundTruth
from tofd.drivers.intrinsics import Intrinsics
from tofd.lab.dataset import Dataset, DatasetError, dataset_from_frames, load_dataset, save_dataset


def _arrays(f: int = 3, h: int = 144, w: int = 176) -> dict:
    rng = np.random.default_rng(0)
    r = (0.5 + 0.1 * rng.random((f, h, w))).astype(np.float32)
    r[:, 0, 0] = 0.0
    r[:, 0, 1] = np.nan
    return {
        "range": r,
        "amplitude": rng.random((f, h, w)).astype(np.float32),
        "nose_px": np.tile(np.array([[88.0, 70.0]], np.float32), (f, 1)),
        "nose_visible": np.array([True, True, False][:f]),
        "distance_m": np.full(f, 0.5),
        "yaw_deg": np.linspace(-30, 30, f),
        "pitch_deg": np.zeros(f),
        "subject": np.array(["a", "bb", "a"][:f]),
    }


def test_round_trip_and_zero_is_invalid(tmp_path):
    path = tmp_path / "d.npz"
    np.savez(path, **_arrays())
    ds = load_dataset(path)
    assert len(ds) == 3 and ds.intrinsics == Intrinsics()
    assert np.isnan(ds.range_m[:, 0, 0]).all() and np.isnan(ds.range_m[:, 0, 1]).all()
    assert list(ds.subject) == ["a", "bb", "a"]
    out = save_dataset(ds.subset(ds.subject == "a"), tmp_path / "e.npz")
    again = load_dataset(out)
    assert len(again) == 2 and list(again.subject) == ["a", "a"]
    np.testing.assert_array_equal(again.range_m, ds.range_m[[0, 2]])
    np.testing.assert_array_equal(again.yaw_deg, [-30, 30])


def test_nose_point_back_projected_from_range(tmp_path):
    arrays = _arrays()
    arrays["range"][:] = 0.6
    arrays["range"][:, 70, 88] = 0.5  # the tip is the nearest point of its neighbourhood
    np.savez(tmp_path / "d.npz", **arrays)
    pts = load_dataset(tmp_path / "d.npz").nose_points()
    np.testing.assert_allclose(np.linalg.norm(pts, axis=1), 0.5, rtol=1e-6)
    np.testing.assert_allclose(pts[0], Intrinsics().backproject(np.full((144, 176), 0.5))[70, 88], rtol=1e-6)


def test_nose_point_from_noisy_range_is_not_pulled_forward(tmp_path):
    """Noisy frames (sigma 4 mm, a face at 0.7 m): the tip's range is that of the surface, not the minimum of
    its noisy neighbours (~6 mm in front); a background pixel beside the tip is ignored."""
    f = 200
    arrays = _arrays(f)
    rng = np.random.default_rng(1)
    arrays["range"][:] = 0.7 + 0.004 * rng.standard_normal(arrays["range"].shape)
    arrays["range"][:, 69, 87] = 2.0  # a background pixel in the tip's window
    arrays["nose_visible"] = np.ones(f, bool)
    for key in ("distance_m", "yaw_deg", "pitch_deg"):
        arrays[key] = np.zeros(f)
    arrays["subject"] = np.array(["a"] * f)
    np.savez(tmp_path / "d.npz", **arrays)
    err_mm = (np.linalg.norm(load_dataset(tmp_path / "d.npz").nose_points(), axis=1) - 0.7) * 1e3
    assert abs(np.mean(err_mm)) < 0.6  # the minimum of 8 such ranges: -5.7 mm on average
    assert np.std(err_mm) < 2.5


def test_sidecar_intrinsics(tmp_path):
    small = Intrinsics(width=40, height=30, fx=50.0, fy=50.0, cx=19.5, cy=14.5)
    np.savez(tmp_path / "d.npz", **_arrays(h=30, w=40))
    (tmp_path / "d.json").write_text(json.dumps({"intrinsics": small.to_dict()}))
    assert load_dataset(tmp_path / "d.npz").intrinsics == small
    (tmp_path / "d.json").write_text(json.dumps({"intrinsics": {"fx": 1.0, "focal": 2}}))
    with pytest.raises(DatasetError, match="intrinsics"):
        load_dataset(tmp_path / "d.npz")


@pytest.mark.parametrize("key", ["range", "nose_px", "subject", "nose_visible"])
def test_missing_key_is_named(tmp_path, key):
    arrays = _arrays()
    del arrays[key]
    np.savez(tmp_path / "d.npz", **arrays)
    with pytest.raises(DatasetError, match=f"missing key.*'{key}'"):
        load_dataset(tmp_path / "d.npz")


@pytest.mark.parametrize("key,value", [("nose_px", np.zeros((3, 3), np.float32)),
                                       ("amplitude", np.zeros((3, 144, 170), np.float32)),
                                       ("yaw_deg", np.zeros(2)),
                                       ("range", np.zeros((3, 176, 144), np.float32))])
def test_misshaped_key_is_named(tmp_path, key, value):
    arrays = _arrays()
    arrays[key] = value
    np.savez(tmp_path / "d.npz", **arrays)
    with pytest.raises(DatasetError, match=f"key '{key}' has shape"):
        load_dataset(tmp_path / "d.npz")


def test_object_array_is_refused_without_pickle(tmp_path):
    arrays = _arrays()
    arrays["subject"] = np.array(["a", "b", "c"], dtype=object)
    np.savez(tmp_path / "d.npz", **arrays)
    with pytest.raises(DatasetError, match="'subject'.*pickle"):
        load_dataset(tmp_path / "d.npz")


def test_truncated_file_is_a_dataset_error(tmp_path):
    np.savez(tmp_path / "d.npz", **_arrays())
    data = (tmp_path / "d.npz").read_bytes()
    (tmp_path / "t.npz").write_bytes(data[: len(data) // 2])
    with pytest.raises(DatasetError, match="t.npz"):
        load_dataset(tmp_path / "t.npz")


def test_from_frames_keeps_labelled_frames():
    a = _arrays()
    frames = [Frame(a["range"][i], a["amplitude"][i], i, 0, 0.0, 0.0,
                    ground_truth=None if i == 1 else GroundTruth((88.0, 70.0), True, (0.0, 0.0, 0.55)))
              for i in range(3)]
    ds = dataset_from_frames(frames, subject="rec")
    assert isinstance(ds, Dataset) and len(ds) == 2
    np.testing.assert_allclose(ds.distance_m, 0.55)
    assert np.isnan(ds.range_m[:, 0, 0]).all() and list(ds.subject) == ["rec", "rec"]
    with pytest.raises(DatasetError, match="ground truth"):
        dataset_from_frames(frames[1:2])
