"""Frame sources for the pipeline tests: rendered faces, optionally paced, with injected gaps."""

from __future__ import annotations

import dataclasses
import json
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from tofd.config import Config, default_file, load_config
from tofd.drivers.emulator.render import Pose, load_face, render_face
from tofd.drivers.frame import DeviceInfo, Frame, GroundTruth, Registers
from tofd.drivers.intrinsics import Intrinsics
from tofd.drivers.source import FrameSource


def rendered_frames(n_distinct: int = 8, seed: int = 0) -> list[tuple[np.ndarray, np.ndarray, tuple[float, float]]]:
    """`n_distinct` noisy renderings of a face moving from 0.35 to 0.70 m: (range_m, amplitude, nose_px)."""
    rng, face = np.random.default_rng(seed), load_face("lee_perry_smith")
    out = []
    for d in np.linspace(0.35, 0.70, n_distinct):
        r = render_face(face, Pose(distance_m=float(d), yaw_deg=10.0 * np.sin(d * 20)), rng=rng)
        out.append((r.range_m, r.amplitude, r.nose_px))
    return out


class RenderedSource(FrameSource):
    """`n_frames` frames cycling through pre-rendered images; `fps` > 0 paces them like a camera.

    `skip_counters`: frame counters never emitted (a device-side counter gap).
    """

    def __init__(self, n_frames: int, fps: float = 0.0, skip_counters: tuple[int, ...] = (), n_distinct: int = 8):
        super().__init__()
        self.n_frames, self.fps, self.skip = n_frames, fps, set(skip_counters)
        self.images = rendered_frames(n_distinct)
        self.intrinsics = Intrinsics()
        self.emitted: list[int] = []

    def __iter__(self) -> Iterator[Frame]:
        t0 = time.monotonic()
        for counter in range(self.n_frames):
            if self.closed:
                return
            if self.fps > 0:
                time.sleep(max(0.0, t0 + counter / self.fps - time.monotonic()))
            if counter in self.skip:
                continue
            range_m, amplitude, nose = self.images[counter % len(self.images)]
            self.emitted.append(counter)
            yield Frame(range_m.copy(), amplitude.copy(), counter, timestamp_us=counter * 33_333,
                        host_monotonic_s=time.monotonic(), host_wall_s=time.time(), intrinsics=self.intrinsics,
                        device=DeviceInfo("0000BEEF", backend="emulated"), registers=Registers(),
                        ground_truth=GroundTruth(nose))


def write_test_model(path: Path, cfg: Config) -> Path:
    """A nose model for the current feature settings, learned on the 3x3 pixels around the true nose tip of a
    few rendered frames (so pipeline tests do not depend on the shipped model being in sync)."""
    from tofd.algorithm.detector import VARIANTS, NoseModel, VariantModel, learn_box, save_model, stack_features
    from tofd.algorithm.extract import FeatureExtractor

    extract = FeatureExtractor(cfg.intrinsics, cfg.features, cfg.segmentation)
    frames = [extract(r, a) for r, a, _ in rendered_frames(3)]
    variants = {}
    for name, features in VARIANTS.items():
        samples = []
        for feats, (_, _, (u, v)) in zip(frames, rendered_frames(3), strict=True):
            row, col = int(round(v)), int(round(u))
            patch = stack_features(feats.maps, features)[row - 1:row + 2, col - 1:col + 2]
            samples.append(patch.reshape(-1, len(features)))
        variants[name] = VariantModel(name, learn_box(np.concatenate(samples), features, quantile=0.0), 1.5)
    model = NoseModel(variants, dataclasses.asdict(cfg.features), dataclasses.asdict(cfg.segmentation))
    return save_model(model, path)


PATIENT_VIEWER = {"shutdown_timeout_s": 300.0}
"""[pipeline] settings for a run that saves an .rrd and does not test the shutdown's deadline: its niced viewer
child finishes the file however long a loaded machine takes, also when a signal stops the run (the default 10 s is
the service's SIGTERM budget; a run that reaches its end has finish_timeout_s)."""


def bundled_config(path: Path, **sections: dict[str, object]) -> Path:
    """Write the bundled config (with its model) to `path`, with `sections` overridden, e.g.
    pipeline=PATIENT_VIEWER."""
    cfg = load_config()
    table = json.loads(json.dumps(dataclasses.asdict(cfg)))
    table["detector"]["model_path"] = str(default_file(cfg.detector.model_path))
    for section, values in sections.items():
        table[section].update(values)
    path.write_text("".join(f"[{name}]\n" + "".join(f"{k} = {json.dumps(v)}\n" for k, v in values.items()) + "\n"
                            for name, values in table.items()))
    return path


def write_config(directory: Path, **sections: dict[str, object]) -> Path:
    """A config file: the bundled defaults with `sections` overridden, e.g. rerun={"sink": "web"}; the detector
    uses a model written by write_test_model."""
    model = write_test_model(directory / "nose_model.json", load_config())
    detector = {"model_path": str(model), **sections.pop("detector", {})}
    return bundled_config(directory / "tofd.toml", detector=detector, **sections)


class ModulesReportingFoxglove:
    """A viewer process backend: the Foxglove publisher, whose `web_url` is the JSON list of the Rerun SDK modules
    loaded in its process (so the parent sees what the viewer process imported)."""

    def __new__(cls, *args: object, **kwargs: object):  # noqa: ANN204 (returns the publisher itself)
        import json
        import sys

        from tofd.service.foxglove.publisher import FoxglovePublisher

        publisher = FoxglovePublisher(*args, **kwargs)  # type: ignore[arg-type]
        publisher.web_url = json.dumps(sorted(m for m in sys.modules if m.split(".")[0] == "rerun"))
        return publisher


def dropped_frames(summary: dict) -> list[dict]:
    """Each frame of a run summary's listed drop ranges as {frame_counter, seq, stage, reason} (a range's frames
    have consecutive counters and, unless a source rejected them at once, consecutive sequence numbers)."""
    return [{"frame_counter": d["frame_counter"] + i, "seq": d["seq"] + i, "stage": d["stage"], "reason": d["reason"]}
            for d in summary["drops"] for i in range(d["frames"])]


def rejected_counters(source: FrameSource) -> list[int]:
    """The frame counters of every frame `source` rejected and nobody took yet (takes them), in order."""
    return [r.frame_counter + i for r in source.take_rejected() for i in range(r.frames)]
