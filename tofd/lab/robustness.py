"""The robustness matrix: a trained model on held-out identities under sensor conditions training never saw.

Cell = (condition, subject, nose distance). Per cell and variant: the per-image EER and what the pipeline
reports with the model's operating scale and the detector's margin test (found / wrong, tofd.lab.roc.answers_at).
The summary gives, per variant, the worst cell of each measure beside the mean over cells: one bad cell is the
failure a user meets.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass

import numpy as np

from tofd.algorithm.detector import NOSE_RADIUS_M, PAPER_RULE, Candidates, Margin, NoseModel
from tofd.algorithm.params import FeatureConfig, SegmentationConfig
from tofd.lab.conditions import CONDITIONS
from tofd.lab.evaluation import evaluate_model, extract_samples
from tofd.lab.faces import HOLDOUT_SUBJECTS, TEST_DISTANCES_M, render_frames

MATRIX_VARIANTS = ("nfft_range", "fft_range")
GOAL_EER, GOAL_FOUND, GOAL_WRONG = 0.02, 0.97, 0.01  # the goal for a cell: EER, found and wrong rates
MEANS = ("eer", "found", "wrong", "rejected", "outranked", "no_candidate")  # per-cell measures averaged


@dataclass(frozen=True, slots=True)
class Cell:
    """One variant's results in one (condition, subject, distance) cell; rates are shares of the cell's frames."""

    variant: str
    condition: str
    subject: str
    distance_m: float
    frames: int
    eer: float
    found: float  # the accepted pixel is within the true-nose radius
    wrong: float  # a pixel is accepted and it is not
    rejected: float  # misses (tofd.lab.roc.Answers): the nose scored best but was not reported,
    outranked: float  # another pixel scored better,
    no_candidate: float  # or no nose pixel was a candidate


@dataclass(frozen=True, slots=True)
class MatrixSpec:
    """What to render: conditions x subjects x distances, `frames` frames per cell, poses from `seed`."""

    conditions: tuple[str, ...] = tuple(CONDITIONS)
    subjects: tuple[str, ...] = HOLDOUT_SUBJECTS
    distances_m: tuple[float, ...] = TEST_DISTANCES_M
    frames: int = 60
    seed: int = 1000


def run_matrix(model: NoseModel, spec: MatrixSpec, features: FeatureConfig, segmentation: SegmentationConfig,
               candidates: Candidates, margin: Margin = PAPER_RULE, radius_m: float = NOSE_RADIUS_M, workers: int = 2,
               variants: tuple[str, ...] = MATRIX_VARIANTS,
               progress: Callable[[str], None] | None = None) -> list[Cell]:
    """Every cell of the matrix for every variant (rendered per condition and subject, then split by distance)."""
    cells = []
    for ci, name in enumerate(spec.conditions):
        for si, subject in enumerate(spec.subjects):
            ds = render_frames((subject,), spec.distances_m, spec.frames * len(spec.distances_m),
                               spec.seed + 100 * ci + si, model=CONDITIONS[name])
            samples = extract_samples(ds, features, segmentation, workers)
            results = evaluate_model(model, samples, ds.distance_m, radius_m, candidates, margin)
            for variant in variants:
                r = results[variant]
                for d, roc in sorted(r.per_distance.items()):
                    a = r.answers_per_distance[d]
                    cells.append(Cell(variant, name, subject, d, roc.n_images, roc.eer, a.found, a.wrong,
                                      a.rejected, a.outranked, a.no_candidate))
            if progress is not None:
                progress(f"{name} {subject}")
    return cells


def summarize(cells: list[Cell]) -> dict[str, dict]:
    """Per variant: mean EER / found / wrong / the three kinds of miss over cells, and the worst cell of each of
    EER, found and wrong (highest EER, lowest found, highest wrong) as a dict."""
    out: dict[str, dict] = {}
    for variant in dict.fromkeys(c.variant for c in cells):
        mine = [c for c in cells if c.variant == variant]
        means = {k: np.array([getattr(c, k) for c in mine]) for k in MEANS}
        eer, found, wrong = means["eer"], means["found"], means["wrong"]
        out[variant] = {
            "cells": len(mine),
            "mean": {k: float(v.mean()) for k, v in means.items()},
            "worst_eer": asdict(mine[int(np.argmax(eer))]),
            "worst_found": asdict(mine[int(np.argmin(found))]),
            "worst_wrong": asdict(mine[int(np.argmax(wrong))]),
            "cells_meeting_goal": int(np.sum((eer <= GOAL_EER) & (found >= GOAL_FOUND) & (wrong <= GOAL_WRONG))),
        }
    return out


def condition_table(cells: list[Cell], variant: str) -> str:
    """Rows: conditions; columns: distances; cell: worst EER % over subjects / worst found % / worst wrong %."""
    mine = [c for c in cells if c.variant == variant]
    distances = sorted({c.distance_m for c in mine})
    head = f"{'condition':<18}" + "".join(f"{d:>15.2f}m" for d in distances)
    lines = [f"{variant}: worst over subjects, EER % / found % / wrong %", head, "-" * len(head)]
    for name in dict.fromkeys(c.condition for c in mine):
        row = []
        for d in distances:
            here = [c for c in mine if c.condition == name and c.distance_m == d]
            row.append(f"{100 * max(c.eer for c in here):.0f}/{100 * min(c.found for c in here):.0f}/"
                       f"{100 * max(c.wrong for c in here):.0f}")
        lines.append(f"{name:<18}" + "".join(f"{x:>16}" for x in row))
    return "\n".join(lines)
