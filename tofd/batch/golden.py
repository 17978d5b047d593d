"""Golden replay checks: a stored file of a recording's per-frame rows (tofd.batch.rows, without timings), and
the comparison of a run with it, field by field within TOLERANCES.

Floating-point results are compared within tolerances, never bit for bit: FFT, finufft and the compiled CG
kernels round differently on another CPU or library build. Equal results digests show bit identity (then, and
only then, the check says so); a different digest with every field within tolerance passes.
"""

from __future__ import annotations

import fnmatch
import json
import math
from dataclasses import dataclass
from pathlib import Path

from tofd.algorithm.detector import NoseModel
from tofd.batch.plan import run_digests
from tofd.batch.rows import frame_row, pipeline_fields, rows_digest
from tofd.config import Config, config_table
from tofd.errors import UsageError
from tofd.service.pipeline.results import FrameResult

FORMAT = "tofd.golden.v1"
EXACT = ("timestamp_us", "foreground_px", "nose_px", "accepted", "ground_truth_px", "ground_truth_xyz_m",
         "ground_truth_visible")
"""Fields that must be equal: integers, the recording's own values, and the detection (a pixel of the candidate
grid and its decision: moving it is what the check exists to catch)."""


@dataclass(frozen=True)
class Tolerance:
    """Two numbers a, b agree when |a - b| <= max(rel * max(|a|, |b|), abs) (math.isclose)."""

    rel: float
    abs: float

    def accepts(self, a: float, b: float) -> bool:
        return math.isclose(a, b, rel_tol=self.rel, abs_tol=self.abs)

    def __str__(self) -> str:
        return f"rel {self.rel:g}, abs {self.abs:g}"


TOLERANCES: dict[str, Tolerance] = {
    "score": Tolerance(rel=2e-2, abs=1e-9),
    "nose_xyz_m": Tolerance(rel=0.0, abs=1e-4),
    "tip_px": Tolerance(rel=0.0, abs=0.02),
    "tip_xyz_m": Tolerance(rel=0.0, abs=1e-4),
    "nfft_iterations": Tolerance(rel=0.0, abs=6),
    "nfft_residual": Tolerance(rel=0.5, abs=0.0),
    "mean_*_nfft_*": Tolerance(rel=2e-2, abs=1e-12),
    "mean_*_fft_*": Tolerance(rel=1e-6, abs=1e-12),
}
"""Tolerance per field (a pattern for the map means; units: score unitless, nose_xyz_m and tip_xyz_m metres,
tip_px pixels, nfft_iterations CG iterations, nfft_residual and means as the rows give them). The NFFT path runs
CG in single precision until a residual threshold that keeps eps0 within 1 % of the converged value, so another
rounding may stop it some iterations earlier or later: the NFFT maps may then differ by up to 1 % each way, hence
scores and NFFT map means within 2 %, the residual within half and the count within a few iterations
(tests/batch/test_golden.py replays the clip with the threshold moved so that CG stops elsewhere and holds the check to
these). The FFT maps are direct double-precision transforms: rounding moves them by far under 1e-6."""
MAX_LINES = 25


def tolerance(field: str) -> Tolerance | None:
    """The field's tolerance; None for a field the check leaves out (host_wall_s and the map digests)."""
    return next((tol for pattern, tol in TOLERANCES.items() if fnmatch.fnmatchcase(field, pattern)), None)


@dataclass(frozen=True)
class CheckReport:
    """What a golden check compared and found: `problems` are regressions (one readable line each), `notes` say
    what was compared, the largest differences within tolerance and whether the run is bit-identical."""

    frames_compared: int
    problems: tuple[str, ...]
    notes: tuple[str, ...]
    bit_identical: bool


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
            "tolerances": {field: {"rel": t.rel, "abs": t.abs} for field, t in TOLERANCES.items()},
            "results_digest": rows_digest(rows), "frames": rows}


def write_golden(path: str | Path, document: dict) -> None:
    Path(path).write_text(json.dumps(document, indent=1) + "\n")


def load_golden(path: str | Path) -> dict:
    """A golden file; UsageError (a ValueError) names a file that is not one."""
    try:
        doc = json.loads(Path(path).read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise UsageError(f"{path}: cannot read golden file: {exc}") from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise UsageError(f"{path}: not a golden file (expected format {FORMAT!r})")
    return doc


def _numbers(value: object) -> list[float | None]:
    """A field's value as a flat list of numbers (None kept)."""
    if isinstance(value, list):
        return [None if v is None else float(v) for v in value]
    return [None if value is None else float(value)]  # type: ignore[arg-type]


def _difference(want: object, got: object, tol: Tolerance) -> float | None:
    """The largest absolute difference of two values of a field, or None when they disagree beyond `tol` (or in
    shape or missing values)."""
    a, b = _numbers(want), _numbers(got)
    if len(a) != len(b) or any((x is None) != (y is None) for x, y in zip(a, b, strict=True)):
        return None
    pairs = [(x, y) for x, y in zip(a, b, strict=True) if x is not None and y is not None]
    if not all(tol.accepts(x, y) for x, y in pairs):
        return None
    return max((abs(x - y) for x, y in pairs), default=0.0)


def compare(golden: dict, rows: list[dict]) -> CheckReport:
    """`rows` of a run against the golden document: EXACT fields equal, TOLERANCES fields within tolerance, the
    same frame counters; bit identity is reported (equal results digests), never required."""
    problems: list[str] = []
    want = {r["frame_counter"]: r for r in golden["frames"]}
    got = {r["frame_counter"]: r for r in rows}
    missing, extra = sorted(set(want) - set(got)), sorted(set(got) - set(want))
    if missing:
        problems.append(f"frames missing from the run: {len(missing)} (counters {missing[:10]})")
    if extra:
        problems.append(f"frames not in the golden file: {len(extra)} (counters {extra[:10]})")
    largest: dict[str, tuple[float, int]] = {}
    common = sorted(set(want) & set(got))
    for counter in common:
        w, g = want[counter], got[counter]
        for field in w:
            tol = tolerance(field)
            if field in EXACT:
                if w[field] != g.get(field):
                    problems.append(f"frame {counter}: {field} {w[field]!r} -> {g.get(field)!r} (exact)")
            elif tol is not None:
                diff = _difference(w[field], g.get(field), tol)
                if diff is None:
                    problems.append(f"frame {counter}: {field} {w[field]!r} -> {g.get(field)!r} (tolerance {tol})")
                elif diff > largest.get(field, (0.0, 0))[0]:
                    largest[field] = (diff, counter)
    identical = not missing and not extra and rows_digest(rows) == golden["results_digest"]
    notes = [f"compared {len(common)} frames: frame counters and {', '.join(EXACT)} exact; "
             + "; ".join(f"{pattern} within {tol}" for pattern, tol in TOLERANCES.items())]
    if largest:
        notes.append("largest differences within tolerance: "
                     + ", ".join(f"{f} {d:.2g} (frame {c})" for f, (d, c) in sorted(largest.items())))
    if identical:
        notes.append(f"bit-identical to the golden file (equal results digests {golden['results_digest'][:16]})")
    else:
        notes.append(f"not bit-identical: results digest {rows_digest(rows)[:16]}, the golden file's "
                     f"{str(golden['results_digest'])[:16]} (expected on another CPU or library build)")
    if len(problems) > MAX_LINES:
        problems = problems[:MAX_LINES] + [f"... and {len(problems) - MAX_LINES} more differences"]
    return CheckReport(len(common), tuple(problems), tuple(notes), identical)


def golden_check(rows: list[dict], recording: str, cfg: Config, model: NoseModel | None, write_to: Path | None,
                 check: Path | None) -> tuple[bool, list[str]]:
    """Write the golden file of a run's `rows` to `write_to` and/or compare them with the golden file `check`:
    whether the check found a regression, and the lines that report it (the differences indented). UsageError
    names a golden file that cannot be read."""
    doc = golden_document(rows, recording, cfg, model)
    lines = []
    if write_to:
        write_golden(write_to, doc)
        lines.append(f"wrote golden file {write_to} ({len(rows)} frames)")
    if not check:
        return False, lines
    golden = load_golden(check)
    report = compare(golden, rows)
    lines += [f"check: {line}" for line in report.notes]
    lines += [f"check: the golden file was made with {k} {v[:12]}, this run has {doc['digests'][k][:12]}"
              for k, v in golden.get("digests", {}).items() if k != "run" and v != doc["digests"].get(k)]
    if report.problems:
        return True, [*lines, f"check FAILED against {check}:", *(f"  {line}" for line in report.problems)]
    return False, [*lines, f"check passed against {check} ({report.frames_compared} frames within tolerance"
                           f"{', bit-identical' if report.bit_identical else ''})"]
