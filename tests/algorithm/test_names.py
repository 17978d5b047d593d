"""The one table of feature families (tofd.algorithm.names) gives the map names, the viewer's entities and their
parsing back, so a family added there reaches every reader."""

import pytest

from tofd.algorithm.names import EPS, FAMILIES, FAMILY_TABLE, MAP_NAMES, VARIANTS, Family, family_maps, map_parts
from tofd.service.viewer import blueprint as bp


def test_every_map_name_parses_back_to_its_family_and_eccentricity():
    assert len(MAP_NAMES) == len(FAMILIES) * len(EPS) == len(set(MAP_NAMES))
    for name in MAP_NAMES:
        family, eps = map_parts(name)
        assert family is FAMILY_TABLE[family.name] and family.map_name(eps) == name
    assert map_parts("amp_nfft_eps2") == (Family("amp", "nfft"), "eps2")
    assert family_maps(("range_fft",)) == ("range_fft_eps0", "range_fft_eps2")
    assert {m for maps in VARIANTS.values() for m in maps} <= set(MAP_NAMES)
    with pytest.raises(ValueError, match="range_fft_eps4"):
        map_parts("range_fft_eps4")


def test_viewer_entities_follow_the_family_table():
    assert bp.FEATURES == {"range_fft_eps0": "/features/fft/eps0", "range_fft_eps2": "/features/fft/eps2",
                           "range_nfft_eps0": "/features/nfft/eps0", "range_nfft_eps2": "/features/nfft/eps2"}
