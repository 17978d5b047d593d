"""A FrameResult as one bytes message for the viewer process: what the Rerun logger reads, no pickle.

Layout: 4-byte little-endian header length, a JSON header (scalars, detection, track, timings), then the
planes as raw float32/bool in the order of PLANES, each (H, W) C-contiguous.
"""

from __future__ import annotations

import json
import struct

import numpy as np

from drivers.frame import Frame
from drivers.intrinsics import Intrinsics
from tofd.algorithm.names import VIEWED_MAPS
from tofd.service.pipeline.results import FrameResult, track_dict, track_from
from tofd.service.pipeline.slots import SLOT_FIELDS
from tofd.service.pipeline.stages import detection_dict, detection_from

PLANES = tuple((name, dtype) for name, dtype in SLOT_FIELDS if name in ("range_m", "amplitude", "mask", *VIEWED_MAPS))
"""The planes the viewer logs: the frame's, the mask and the viewed feature maps, in the slot's order."""

OWN_TIMINGS = ("logging", "latency")  # the viewer process measures these itself (RerunLogger)


def encode(r: FrameResult) -> bytes:
    f, det = r.frame, r.detection
    header = {"seq": r.seq, "frame_counter": f.frame_counter, "timestamp_us": f.timestamp_us,
              "host_monotonic_s": f.host_monotonic_s, "arrival_s": r.arrival_s, "gap_before": r.gap_before,
              "nfft_iterations": r.nfft_iterations, "nfft_residual": r.nfft_residual,
              "timings_ms": {k: v for k, v in r.timings_ms.items() if k not in OWN_TIMINGS},
              "shape": list(f.range_m.shape),
              "detection": None if det is None else detection_dict(det), "track": track_dict(r.track)}
    planes = {"range_m": f.range_m, "amplitude": f.amplitude, "mask": r.mask, **r.features}
    head = json.dumps(header).encode()
    return b"".join([struct.pack("<I", len(head)), head,
                     *(np.ascontiguousarray(planes[name], dtype).tobytes() for name, dtype in PLANES)])


def decode(blob: bytes, intrinsics: Intrinsics) -> FrameResult:
    (n,) = struct.unpack_from("<I", blob)
    h = json.loads(blob[4:4 + n])
    shape, offset, planes = tuple(h["shape"]), 4 + n, {}
    count = shape[0] * shape[1]
    for name, dtype in PLANES:
        planes[name] = np.frombuffer(blob, dtype, count, offset).reshape(shape)
        offset += count * np.dtype(dtype).itemsize
    frame = Frame(planes["range_m"], planes["amplitude"], h["frame_counter"], h["timestamp_us"],
                  host_monotonic_s=h["host_monotonic_s"], host_wall_s=0.0, intrinsics=intrinsics)
    return FrameResult(seq=h["seq"], frame=frame, mask=planes["mask"],
                       features={name: planes[name] for name in VIEWED_MAPS}, nfft_iterations=h["nfft_iterations"],
                       nfft_residual=h["nfft_residual"], arrival_s=h["arrival_s"], timings_ms=h["timings_ms"],
                       detection=detection_from(h), track=track_from(h["track"]), gap_before=h["gap_before"])
