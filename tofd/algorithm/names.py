"""The feature vocabulary: map families, map names and detector variants; everything else imports these."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

Signal = Literal["range", "amp"]
Method = Literal["fft", "nfft"]
EPS = ("eps0", "eps2")
"""The generalized eccentricities each family gives, in order."""


@dataclass(frozen=True, slots=True)
class Family:
    """A group of maps computed together: one filter pass of `method` (FFT on the image grid, NFFT on the 3-D
    points) over `signal` (the range or the amplitude image), giving <name>_eps0 and <name>_eps2."""

    signal: Signal
    method: Method

    @property
    def name(self) -> str:
        return f"{self.signal}_{self.method}"

    def map_name(self, eps: str) -> str:
        """The name of this family's map of eccentricity `eps` (one of EPS)."""
        return f"{self.name}_{eps}"


FAMILY_TABLE: dict[str, Family] = {f.name: f for f in (Family("range", "fft"), Family("range", "nfft"),
                                                       Family("amp", "fft"), Family("amp", "nfft"))}
"""Family name -> Family: the one table of feature families."""

FAMILIES = tuple(FAMILY_TABLE)
"""The family names, in the order maps are listed."""


def family_maps(families: tuple[str, ...]) -> tuple[str, ...]:
    """The map names of the given families, in their order."""
    return tuple(FAMILY_TABLE[fam].map_name(eps) for fam in families for eps in EPS)


def map_parts(name: str) -> tuple[Family, str]:
    """(family, eccentricity) of a map name (ValueError for a name not in MAP_NAMES)."""
    for family in FAMILY_TABLE.values():
        for eps in EPS:
            if family.map_name(eps) == name:
                return family, eps
    raise ValueError(f"unknown feature map {name!r} (known: {', '.join(family_maps(FAMILIES))})")


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
