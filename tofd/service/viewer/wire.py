"""A FrameResult handed to the viewer process: its planes in a shared-memory slot, the rest as a MessagePack header.

The planes (PLANES: the frame's, the mask and the viewed feature maps, (H, W) each) are copied once into a
SlotRing slot with these fields; the header (scalars, detection, track, timings, the slot index) goes over the
pipe. No pickle, and no large message: a pipe carries each byte through two kernel copies and many wake-ups.
MessagePack rather than JSON: its floats go as their 8 bytes (exact, NaN and infinities included) instead of being
formatted as text and parsed back, several times faster on both sides, every frame.
A feature map is copied over the box the views show only (pixels.shown_box of FrameResult.box): the viewers read
nothing of it elsewhere (it is NaN there), and at a modern camera's resolution the box is a fraction of the
frame. Outside the box the slot keeps an earlier frame's values.
"""

from __future__ import annotations

from typing import TypedDict

import msgpack
import numpy as np

from tofd.algorithm.names import VIEWED_MAPS
from tofd.drivers.frame import Frame, Registers, SensorInfo
from tofd.drivers.intrinsics import Intrinsics
from tofd.service.pipeline.messages import DetectionMessage
from tofd.service.pipeline.results import FrameResult, box_from, box_list, flat_dict, track_dict, track_from
from tofd.service.pipeline.slots import SLOT_FIELDS, SlotRing
from tofd.service.pipeline.stages import detection_dict, detection_from
from tofd.service.viewer.pixels import shown_box

PLANES = tuple((name, dtype) for name, dtype in SLOT_FIELDS if name in ("range_m", "amplitude", "mask", *VIEWED_MAPS))
"""The planes the viewer logs (the fields of its slots): the frame's, the mask and the viewed feature maps."""

OWN_TIMINGS = ("logging", "latency")  # the viewer process measures these itself (RerunLogger)


class FrameHeader(TypedDict):
    """The header of one frame handed to the viewer process: FrameResult's fields beside its planes (times in
    seconds of time.monotonic(), timings in ms) and the slot holding the planes."""

    slot: int
    seq: int
    frame_counter: int
    timestamp_us: int
    host_monotonic_s: float
    arrival_s: float
    box: list[int]  # results.box_list
    gap_before: str
    nfft_iterations: int
    nfft_residual: float
    timings_ms: dict[str, float]
    detection: DetectionMessage | None
    track: dict | None  # results.track_dict
    registers: dict | None  # the frame's Registers as a dict (an SR3000's: the unit of its range codes)
    sensor: dict | None  # the frame's SensorInfo.to_dict() (its depth unit decides how the viewers show depth)


def write(r: FrameResult, slot: int, planes: dict[str, np.ndarray]) -> bytes:
    """Copy r's planes into `planes` (one slot's views, PLANES; the feature maps over the foreground's box) and
    return the header naming `slot`."""
    f, det, box = r.frame, r.detection, shown_box(r.box)
    for name, plane in (("range_m", f.range_m), ("amplitude", f.amplitude), ("mask", r.mask)):
        np.copyto(planes[name], plane, casting="unsafe")
    for name in VIEWED_MAPS:
        np.copyto(planes[name][box], r.features[name][box], casting="unsafe")
    header = FrameHeader(slot=slot, seq=r.seq, frame_counter=f.frame_counter, timestamp_us=f.timestamp_us,
                         host_monotonic_s=f.host_monotonic_s, arrival_s=r.arrival_s, box=box_list(r.box),
                         gap_before=r.gap_before,
                         nfft_iterations=r.nfft_iterations, nfft_residual=r.nfft_residual,
                         timings_ms={k: v for k, v in r.timings_ms.items() if k not in OWN_TIMINGS},
                         detection=None if det is None else detection_dict(det), track=track_dict(r.track),
                         registers=None if f.registers is None else flat_dict(f.registers),
                         sensor=None if f.sensor is None else f.sensor.to_dict())
    packed: bytes = msgpack.packb(header)
    return packed


def read(header: bytes, ring: SlotRing, intrinsics: Intrinsics) -> FrameResult:
    """The FrameResult of a header, whose arrays are views of the slot it names (use them before the slot is
    written again; its feature maps only over pixels.shown_box of its box)."""
    h: FrameHeader = msgpack.unpackb(header)
    planes = ring.views(h["slot"])
    frame = Frame(planes["range_m"], planes["amplitude"], h["frame_counter"], h["timestamp_us"],
                  host_monotonic_s=h["host_monotonic_s"], host_wall_s=0.0, intrinsics=intrinsics,
                  registers=None if h["registers"] is None else Registers(**h["registers"]),
                  sensor=None if h["sensor"] is None else SensorInfo.from_dict(h["sensor"]))
    return FrameResult(seq=h["seq"], frame=frame, mask=planes["mask"],
                       features={name: planes[name] for name in VIEWED_MAPS}, nfft_iterations=h["nfft_iterations"],
                       nfft_residual=h["nfft_residual"], arrival_s=h["arrival_s"], box=box_from(h["box"]),
                       timings_ms=h["timings_ms"],
                       detection=detection_from(h["detection"]), track=track_from(h["track"]),
                       gap_before=h["gap_before"])
