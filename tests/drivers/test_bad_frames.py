"""Damaged frames: NaN/Inf/zero/negative amplitude or range, range 1e-30, planes of another shape, counters
beyond int64. No exception escapes: the algorithm gives an empty detection, the pipeline ledgers what it
cannot process (`capture`, `invalid_frame: ...`) and goes on."""

import dataclasses

import numpy as np
import pytest

from tofd.algorithm.extract import FeatureExtractor
from tofd.config import Config, load_config
from tofd.lab.evaluation import frame_samples
from tofd.service.model import load_detector
from tofd.service.pipeline import Pipeline
from tofd_testing.pipeline_sources import RenderedSource, dropped_frames, rendered_frames, write_config

R, A, NOSE = rendered_frames(1)[0]
RNG = np.random.default_rng(1)
SPECKLE = RNG.random(R.shape) < 0.1


def damaged(kind: str) -> tuple[np.ndarray, np.ndarray]:
    """(range_m, amplitude) of one kind of damage to a rendered face."""
    return {
        "amplitude_nan": (R, np.full_like(A, np.nan)),
        "amplitude_inf": (R, np.full_like(A, np.inf)),
        "amplitude_zero": (R, np.zeros_like(A)),
        "amplitude_negative": (R, -A),
        "range_nan": (np.full_like(R, np.nan), A),
        "range_inf": (np.full_like(R, np.inf), A),
        "range_zero": (np.zeros_like(R), A),
        "range_negative": (-R, A),
        "range_1e-30": (np.full_like(R, 1e-30), A),
        "range_1e30": (np.full_like(R, 1e30), A),
        "speckle_inf_negative": (np.where(SPECKLE, np.inf, R).astype(np.float32),
                                 np.where(SPECKLE, -5.0, A).astype(np.float32)),
    }[kind]


KINDS = ["amplitude_nan", "amplitude_inf", "amplitude_zero", "amplitude_negative", "range_nan", "range_inf",
         "range_zero", "range_negative", "range_1e-30", "range_1e30", "speckle_inf_negative"]


@pytest.fixture(scope="module")
def detector(tmp_path_factory):
    return load_detector(load_config(write_config(tmp_path_factory.mktemp("model"))))


@pytest.mark.parametrize("kind", KINDS)
def test_damaged_pixels_give_an_answer_not_an_exception(kind, detector):
    range_m, amplitude = damaged(kind)
    det = detector.detect_frame(range_m.astype(np.float32), amplitude.astype(np.float32))
    assert det.nose_px is None or (0 <= det.nose_px[0] < R.shape[1] and 0 <= det.nose_px[1] < R.shape[0])
    if kind != "speckle_inf_negative":  # nothing of a face is left: no nose may be accepted
        assert not det.accepted
    cfg = Config()  # `tofd evaluate`'s per-frame step
    extractor = FeatureExtractor(cfg.intrinsics, cfg.features, cfg.segmentation)
    samples = frame_samples(extractor, range_m, amplitude, np.array([0.0, 0.0, 0.4]))
    assert len(samples.log_features) == len(samples.tip_distance_m)


class DamagedSource(RenderedSource):
    """Rendered frames with damage at fixed counters: bad pixels, a 10x10 frame, a counter beyond int64."""

    BAD_PIXELS = {3: "amplitude_zero", 4: "range_1e-30", 5: "range_nan", 6: "amplitude_negative"}

    def __iter__(self):
        for frame in super().__iter__():
            c = frame.frame_counter
            if c in self.BAD_PIXELS:
                range_m, amplitude = damaged(self.BAD_PIXELS[c])
                frame = dataclasses.replace(frame, range_m=range_m.copy(), amplitude=amplitude.copy())
            elif c == 8:
                frame = dataclasses.replace(frame, range_m=np.ones((10, 10), np.float32),
                                            amplitude=np.ones((10, 10), np.float32))
            elif c == 9:
                frame = dataclasses.replace(frame, frame_counter=10**30, timestamp_us=10**30)
            yield frame


def test_damaged_frames_are_ledgered_and_the_run_goes_on(tmp_path):
    cfg = load_config(write_config(tmp_path))
    delivered = []
    pipeline = Pipeline(cfg, "lossless", writers=(delivered.append,), model=load_detector(cfg).model)
    pipeline.start(DamagedSource(14, n_distinct=3))
    assert pipeline.wait(120)
    summary = pipeline.close()
    assert pipeline.error is None
    assert summary["consistent"] and summary["frames_in"] == 14
    drops = {d["seq"]: (d["stage"], d["reason"]) for d in dropped_frames(summary)}
    assert set(drops) == {8, 9}, drops  # the bad-pixel frames were processed, not dropped
    assert drops[8][0] == "capture" and drops[8][1].startswith("invalid_frame: range_m is float32 (10, 10)")
    assert drops[9][0] == "capture" and "frame counter" in drops[9][1]
    by_counter = {r.frame.frame_counter: r for r in delivered}
    assert sorted(by_counter) == [c for c in range(14) if c not in (8, 9)]
    for c in DamagedSource.BAD_PIXELS:
        assert not by_counter[c].detection.accepted
    assert by_counter[12].detection.accepted  # and the frames after the damage are as good as before
