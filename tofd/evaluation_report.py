"""Presenting an evaluation: the EER table (text), everything as JSON, the ROC curves as a PNG."""

from __future__ import annotations

import json
from pathlib import Path

from tofd.evaluate import VariantResult

LABELS = {
    "fft_range": "FFT range",
    "fft_range_amp": "FFT range+amp",
    "nfft_range": "NFFT range",
    "nfft_range_amp": "NFFT range+amp",
}


def eer_table(results: dict[str, VariantResult]) -> str:
    """Rows: variants; columns: EER in percent overall and per distance bin."""
    distances = sorted({d for r in results.values() for d in r.per_distance})
    head = f"{'variant':<16}{'overall':>9}" + "".join(f"{d:>8.2f}m" for d in distances)
    lines = ["EER % (per-image ROC; columns: all test frames, then per nose distance)", head, "-" * len(head)]
    for name, r in results.items():
        cells = "".join(f"{100 * r.per_distance[d].eer:>9.1f}" if d in r.per_distance else f"{'-':>9}"
                        for d in distances)
        lines.append(f"{LABELS.get(name, name):<16}{100 * r.overall.eer:>9.1f}{cells}")
    return "\n".join(lines)


def results_to_dict(results: dict[str, VariantResult]) -> dict:
    return {
        name: {
            "overall": r.overall.to_dict(),
            "per_distance": {f"{d:.2f}": roc.to_dict() for d, roc in sorted(r.per_distance.items())},
        }
        for name, r in results.items()
    }


def write_json(path: Path, results: dict[str, VariantResult], **extra: object) -> Path:
    """Everything: settings, timing, model, and per variant the ROC points and EERs (overall, per distance)."""
    path.write_text(json.dumps({**extra, "results": results_to_dict(results)}, indent=1) + "\n")
    return path


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
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
