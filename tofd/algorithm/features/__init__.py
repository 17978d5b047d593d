"""Scale-invariant range features: generalized eccentricities eps0, eps2 (and any user operator) by FFT (image grid)
and NFFT (back-projected foreground, scale-invariant). See transfer.py and operators.py for the filters, fft.py and
nfft.py for the paths, sampling.py for what a camera must carry."""

from tofd.algorithm.features.eccentricity import Eccentricities
from tofd.algorithm.features.fft import FFTFeatures
from tofd.algorithm.features.nfft import NFFTFeatures
from tofd.algorithm.features.operators import Transfer
from tofd.algorithm.features.sampling import BandWarning, PatchWarning, SamplingError

__all__ = ["BandWarning", "Eccentricities", "FFTFeatures", "NFFTFeatures", "PatchWarning", "SamplingError", "Transfer"]
