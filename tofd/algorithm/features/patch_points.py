"""The NFFT path's compiled back-projection of foreground pixels into its patch (numba, compiled once and cached on
disk): one pass over the pixels instead of a dozen numpy passes over (3, M) arrays (tofd.algorithm.features.nfft)."""

import numba
import numpy as np


@numba.njit(cache=True, nogil=True, error_model="numpy")
def patch_points(flat: np.ndarray, ranges: np.ndarray, rays: np.ndarray, rotation: np.ndarray, width: float,
                 height: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float, float]:
    """Points of the pixels `flat` (flat indices) at radial `ranges` (metres) along unit `rays` (3, H W), turned by
    `rotation` (3, 3), in patch units: x / width, y / height centred on their mean, kept in [-1/2, 1/2)^2.

    Pixels whose range is not finite and > 0 are left out first. Returns (x, y, z, index, mean z^2, mean range^2)
    of the kept points: z in metres (not offset), index their flat pixel index; the means are NaN without one.
    """
    m = flat.size
    x, y, z, r = np.empty(m), np.empty(m), np.empty(m), np.empty(m)
    index = np.empty(m, np.int64)
    good = 0
    sx = sy = 0.0
    for j in range(m):
        rj = float(ranges[j])
        if not (np.isfinite(rj) and rj > 0):
            continue
        k = flat[j]
        u, v, w = rays[0, k] * rj, rays[1, k] * rj, rays[2, k] * rj
        px = rotation[0, 0] * u + rotation[0, 1] * v + rotation[0, 2] * w
        py = rotation[1, 0] * u + rotation[1, 1] * v + rotation[1, 2] * w
        z[good] = rotation[2, 0] * u + rotation[2, 1] * v + rotation[2, 2] * w
        x[good], y[good], r[good], index[good] = px / width, py / height, rj, k
        sx += x[good]
        sy += y[good]
        good += 1
    mx, my = (sx / good, sy / good) if good else (0.0, 0.0)
    kept = 0
    zz = rr = 0.0
    for j in range(good):
        xj, yj = x[j] - mx, y[j] - my
        if -0.5 <= xj < 0.5 and -0.5 <= yj < 0.5:
            x[kept], y[kept], z[kept], index[kept] = xj, yj, z[j], index[j]
            zz += z[j] * z[j]
            rr += r[j] * r[j]
            kept += 1
    mean_zz, mean_rr = (zz / kept, rr / kept) if kept else (np.nan, np.nan)
    return x[:kept], y[:kept], z[:kept], index[:kept], mean_zz, mean_rr
