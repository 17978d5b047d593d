"""The feature vocabulary: map families, map names and detector variants; everything else imports these."""

from __future__ import annotations

FAMILIES = ("range_fft", "range_nfft", "amp_fft", "amp_nfft")
"""Groups of maps computed together: each family is one filter pass giving <family>_eps0 and <family>_eps2."""


def family_maps(families: tuple[str, ...]) -> tuple[str, ...]:
    """The map names of the given families, in their order."""
    return tuple(f"{fam}_{eps}" for fam in families for eps in ("eps0", "eps2"))


MAP_NAMES = family_maps(FAMILIES)
"""Every feature map a frame can have: (H, W) float32 eccentricities, NaN outside the foreground."""

VARIANTS: dict[str, tuple[str, ...]] = {
    "fft_range": ("range_fft_eps0", "range_fft_eps2"),
    "fft_range_amp": ("range_fft_eps0", "range_fft_eps2", "amp_fft_eps0", "amp_fft_eps2"),
    "nfft_range": ("range_nfft_eps0", "range_nfft_eps2"),
    "nfft_range_amp": ("range_nfft_eps0", "range_nfft_eps2", "amp_nfft_eps0", "amp_nfft_eps2"),
}
"""Detector variant -> the feature maps its box is learned on."""

VIEWED_FAMILIES = ("range_fft", "range_nfft")
"""Families the live pipeline always computes, for the viewer."""

VIEWED_MAPS = family_maps(VIEWED_FAMILIES)
"""The feature maps the viewer shows."""


def families_for(names: tuple[str, ...] | list[str]) -> tuple[str, ...]:
    """The families needed to compute the given map names."""
    unknown = [n for n in names if n not in MAP_NAMES]
    if unknown:
        raise ValueError(f"unknown feature map(s) {', '.join(unknown)} (known: {', '.join(MAP_NAMES)})")
    return tuple(f for f in FAMILIES if any(n.startswith(f + "_") for n in names))
