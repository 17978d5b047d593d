"""Presenting an evaluation: the EER table (text), everything as JSON, the ROC curves as a PNG."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

from tofd.lab.evaluation import VariantResult
from tofd.lab.roc import Answers, RocCurve
from tofd.outputs import save_figure, write_text

LABELS = {
    "fft_range": "FFT range",
    "fft_range_amp": "FFT range+amp",
    "nfft_range": "NFFT range",
    "nfft_range_amp": "NFFT range+amp",
}


Key = float | str | None  # a distance bin (metres), an identity (subject name), or None: all test frames


def _roc(r: VariantResult, key: Key) -> RocCurve:
    if key is None:
        return r.overall
    return r.per_subject[key] if isinstance(key, str) else r.per_distance[key]


def _answers(r: VariantResult, key: Key) -> Answers:
    if key is None:
        return r.answers
    return r.answers_per_subject[key] if isinstance(key, str) else r.answers_per_distance[key]


def _table(title: str, results: dict[str, VariantResult], cell: Callable[[VariantResult, Key], str],
           per_subject: bool = False) -> str:
    """Rows: variants; columns: all test frames (key None), then per distance bin (or per identity); cells
    right-aligned."""
    groups: list[dict] = [r.per_subject if per_subject else r.per_distance for r in results.values()]
    keys: list[Key] = sorted({k for g in groups for k in g})
    head = f"{'variant':<16}{'overall':>11}" + "".join(f"{k:>11}" if isinstance(k, str) else f"{k:>10.2f}m"
                                                      for k in keys)
    lines = [title, head, "-" * len(head)]
    for name, r in results.items():
        known = r.per_subject if per_subject else r.per_distance
        cells = "".join(f"{cell(r, k) if k in known else '-':>11}" for k in keys)
        lines.append(f"{LABELS.get(name, name):<16}{cell(r, None):>11}{cells}")
    return "\n".join(lines)


def _eer_cell(r: VariantResult, key: Key) -> str:
    return f"{100 * _roc(r, key).eer:.1f}"


def _answers_cell(r: VariantResult, key: Key) -> str:
    a = _answers(r, key)
    return f"{100 * a.found:.1f}/{100 * a.wrong:.1f}"


ANSWERS_TITLE = ("what the pipeline reports, % of frames: nose found / a wrong pixel accepted (the best candidate "
                 "pixel, by the operating scale and the margin test)")


def eer_table(results: dict[str, VariantResult], per_subject: bool = False) -> str:
    """Rows: variants; columns: EER in percent overall and per distance bin (or per identity)."""
    columns = "identity" if per_subject else "nose distance"
    return _table(f"EER % (per-image ROC; columns: all test frames, then per {columns})", results, _eer_cell,
                  per_subject)


def answers_table(results: dict[str, VariantResult], per_subject: bool = False) -> str:
    """Per variant, in percent of the frames (overall, per distance bin or per identity): nose found / wrong pixel
    reported by the detector's acceptance rule."""
    return _table(ANSWERS_TITLE, results, _answers_cell, per_subject)


def results_to_dict(results: dict[str, VariantResult], points: bool = True) -> dict:
    """Per variant, overall, per distance bin and (when evaluated so) per identity: the ROC (with its points unless
    `points` is False) and the answers."""
    out = {}
    for name, r in results.items():
        out[name] = {
            "overall": {**r.overall.to_dict(points), "answers": r.answers.to_dict()},
            "per_distance": {f"{d:.2f}": {**roc.to_dict(points), "answers": r.answers_per_distance[d].to_dict()}
                             for d, roc in sorted(r.per_distance.items())},
        }
        if r.per_subject:
            out[name]["per_subject"] = {s: {**roc.to_dict(points), "answers": r.answers_per_subject[s].to_dict()}
                                        for s, roc in sorted(r.per_subject.items())}
    return out


def write_json(path: Path, results: dict[str, VariantResult], **extra: object) -> Path:
    """Everything: settings, timing, model, and per variant the ROC points and EERs (overall, per distance)."""
    return write_text(path, json.dumps({**extra, "results": results_to_dict(results)}, indent=1) + "\n")


def plot_roc(path: Path, results: dict[str, VariantResult]) -> Path:
    """Left: ROC curves (detection rate vs false-positive rate) of all variants; right: EER per distance."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, bx) = plt.subplots(1, 2, figsize=(11, 4.6))
    for name, r in results.items():
        roc = r.overall
        style = "-" if name.startswith("nfft") else "--"
        ax.plot(roc.false_positive_rate, roc.detection_rate, style, drawstyle="steps-post",
                label=f"{LABELS.get(name, name)} (EER {100 * roc.eer:.1f} %)")
        ds = sorted(r.per_distance)
        bx.plot(ds, [100 * r.per_distance[d].eer for d in ds], style, marker="o", label=LABELS.get(name, name))
    ax.plot([0, 1], [1, 0], ":", color="grey", lw=0.8, label="EER line")
    ax.set(xlabel="false-positive rate (images)", ylabel="detection rate (images)", xlim=(0, 1), ylim=(0, 1.01),
           title="Nose detection, per-image ROC")
    ax.legend(loc="lower right", fontsize=8)
    bx.set(xlabel="nose distance (m)", ylabel="EER (%)", title="EER per distance", ylim=(-2, None))
    bx.grid(alpha=0.3)
    bx.legend(fontsize=8)
    fig.tight_layout()
    save_figure(fig, path, dpi=110)
    plt.close(fig)
    return path
