"""Golden replay checks: a stored file of a recording's per-frame rows (tofd.batch.rows, without timings), and
the comparison of a run with it, field by field within TOLERANCES.

Map digests are compared too: equal digests prove bit-identical maps; different digests with every number
within tolerance (another CPU or library build) are reported as a note, not a regression.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

from tofd.algorithm.detector import NoseModel
from tofd.batch.plan import run_digests
from tofd.batch.rows import frame_row, pipeline_fields, rows_digest
from tofd.config import Config, config_table
from tofd.service.pipeline.results import FrameResult

FORMAT = "tofd.golden.v1"
EXACT = ("timestamp_us", "foreground_px", "nose_px", "accepted", "ground_truth_px", "ground_truth_xyz_m",
         "ground_truth_visible")
TOLERANCES = {"score": 1e-6, "nose_xyz_m": 1e-4, "tip_px": 0.02, "tip_xyz_m": 1e-4, "nfft_iterations": 1,
              "nfft_residual": 1e-6, "mean_*": 1e-5}
"""Largest absolute difference accepted per field (score: unitless, nose_xyz_m and tip_xyz_m: metres, tip_px: pixels,
nfft_iterations: CG iterations, nfft_residual: relative residual, mean_*: a map's mean eccentricity); EXACT fields
must be equal."""
MAX_LINES = 25


class GoldenRecorder:
    """A results writer for the pipeline (called with each FrameResult) that keeps the rows for a golden file."""

    def __init__(self) -> None:
        self.rows: list[dict] = []

    def __call__(self, result: FrameResult) -> None:
        self.rows.append(pipeline_fields(frame_row(result)))


def golden_document(rows: list[dict], recording: str, cfg: Config, model: NoseModel | None) -> dict:
    """The golden file's content for `rows` of `recording` made with `cfg` and the detector `model` (None: none)."""
    return {"format": FORMAT, "recording": recording,
            "digests": run_digests(config_table(cfg), None if model is None else model.to_dict()),
            "tolerances": TOLERANCES, "results_digest": rows_digest(rows), "frames": rows}


def write_golden(path: str | Path, document: dict) -> None:
    Path(path).write_text(json.dumps(document, indent=1) + "\n")


def load_golden(path: str | Path) -> dict:
    """A golden file; ValueError names a file that is not one."""
    try:
        doc = json.loads(Path(path).read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise ValueError(f"{path}: cannot read golden file: {exc}") from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise ValueError(f"{path}: not a golden file (expected format {FORMAT!r})")
    return doc


def _tolerance(field: str) -> float | None:
    return TOLERANCES.get("mean_*" if field.startswith("mean_") else field)


def _differs(a: object, b: object, tol: float) -> bool:
    if isinstance(a, list) and isinstance(b, list):
        return len(a) != len(b) or any(_differs(x, y, tol) for x, y in zip(a, b, strict=True))
    if a is None or b is None:
        return a is not b
    return not math.isclose(float(a), float(b), rel_tol=0.0, abs_tol=tol)  # type: ignore[arg-type]


def compare(golden: dict, rows: list[dict]) -> tuple[list[str], list[str]]:
    """(regressions, notes) of `rows` against the golden document, one readable line each."""
    problems: list[str] = []
    notes: list[str] = []
    want = {r["frame_counter"]: r for r in golden["frames"]}
    got = {r["frame_counter"]: r for r in rows}
    missing, extra = sorted(set(want) - set(got)), sorted(set(got) - set(want))
    if missing:
        problems.append(f"frames missing from the run: {len(missing)} (counters {missing[:10]})")
    if extra:
        problems.append(f"frames not in the golden file: {len(extra)} (counters {extra[:10]})")
    bit_diff = 0
    for counter in sorted(set(want) & set(got)):
        w, g = want[counter], got[counter]
        if any(w.get(k) != g.get(k) for k in w if k.endswith("digest") or k.startswith("digest_")):
            bit_diff += 1
        for field in w:
            if field in EXACT:
                bad = w[field] != g.get(field)
            elif (tol := _tolerance(field)) is not None:
                bad = _differs(w[field], g.get(field), tol)
            else:
                continue
            if bad:
                tol_text = "exact" if field in EXACT else f"tolerance {_tolerance(field):g}"
                problems.append(f"frame {counter}: {field} {w[field]!r} -> {g.get(field)!r} ({tol_text})")
    if bit_diff:
        notes.append(f"{bit_diff} frames' mask or map digests differ from the golden file (bit-level)")
    if not problems and not bit_diff:
        notes.append(f"bit-identical to the golden file (results digest {rows_digest(rows)[:16]})")
    if len(problems) > MAX_LINES:
        problems = problems[:MAX_LINES] + [f"... and {len(problems) - MAX_LINES} more differences"]
    return problems, notes
