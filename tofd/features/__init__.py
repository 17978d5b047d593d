"""Scale-invariant range features: generalized eccentricities eps0, eps2 by FFT (image grid) and NFFT
(back-projected foreground, scale-invariant). See transfer.py for the filters, fft.py and nfft.py."""

from tofd.features.fft import FFTFeatures
from tofd.features.maps import FeatureMaps
from tofd.features.nfft import NFFTFeatures

__all__ = ["FeatureMaps", "FFTFeatures", "NFFTFeatures"]
