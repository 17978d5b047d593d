"""The method of Haker et al. (2008) as functions on arrays: segmentation, FFT/NFFT eccentricities, nose detector."""
