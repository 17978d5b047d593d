"""The JSON messages between the pipeline and its feature worker processes (tofd.service.pipeline.worker).

  worker -> parent  WorkerReady    once, after its plans are built
  parent -> worker  WorkerTask     process the frame in a slot (or {"stop": true}: exit)
  worker -> parent  WorkerReply    the slot's frame done (`reply`) or failed (`error`)
"""

from __future__ import annotations

import json
from typing import NotRequired, TypedDict, final


class DetectionMessage(TypedDict):
    """A Detection (tofd.algorithm.detector) as JSON: pixel (u, v), point (x, y, z) metres, score (inf: no
    foreground), accepted, the refined sub-pixel tip (u, v) and its point (metres), and each alternative as one list
    [u, v, x, y, z, score] (+ [tip x, y, z] when refined)."""

    nose_px: list[int] | None
    nose_xyz_m: list[float] | None
    score: float
    accepted: bool
    tip_px: list[float] | None
    tip_xyz_m: list[float] | None
    alternatives: list[list[float]]


class FeatureReply(TypedDict):
    """What FeatureStage.run found beside the maps it wrote into the slot: stage timings (ms), the NFFT path's CG
    iterations and relative residual, and the detection (absent without a detector)."""

    timings_ms: dict[str, float]
    box: list[int]  # the mask's foreground_box as [row start, row stop, col start, col stop] (results.box_list)
    nfft_iterations: int
    nfft_residual: float
    detection: NotRequired[DetectionMessage]


@final
class WorkerReady(TypedDict):
    ready: int  # the worker's pid


@final
class WorkerTask(TypedDict):
    seq: int  # pipeline sequence number
    slot: int  # the SlotRing slot holding the frame


@final
class WorkerReply(TypedDict):
    seq: int
    slot: int
    reply: NotRequired[FeatureReply]  # the frame was processed
    error: NotRequired[str]  # "<exception type>: <message>": the frame could not be processed


STOP = b'{"stop": true}'


def encode(message: WorkerReady | WorkerTask | WorkerReply) -> bytes:
    return json.dumps(message).encode()


def decode_from_worker(data: bytes) -> WorkerReady | WorkerReply:
    """A worker's message (json.loads; the protocol is this module's, between processes of one run)."""
    message: WorkerReady | WorkerReply = json.loads(data)
    return message


def decode_task(data: bytes) -> WorkerTask | None:
    """A task for the worker, or None for the stop message."""
    message = json.loads(data)
    return None if message.get("stop") else WorkerTask(seq=message["seq"], slot=message["slot"])
