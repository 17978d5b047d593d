"""Scale-invariant range features: generalized eccentricities eps0, eps2 by FFT (image grid) and NFFT
(back-projected foreground, scale-invariant). See transfer.py for the filters, fft.py and nfft.py."""

from tofd.algorithm.features.eccentricity import Eccentricities
from tofd.algorithm.features.fft import FFTFeatures
from tofd.algorithm.features.nfft import NFFTFeatures

__all__ = ["Eccentricities", "FFTFeatures", "NFFTFeatures"]
