"""The SR3000-style camera as a device model: sensor size, modulation frequencies, and the conversion between its
16-bit distance codes and metres. Shared by the USB backend, the emulator, tofd's recordings and ROS driver bags."""

from __future__ import annotations

import numpy as np

WIDTH = 176
HEIGHT = 144
MOD_FREQS_MHZ = (40.0, 30.0, 21.0, 20.0, 19.0)
"""MOD_FREQ register index -> modulation frequency in MHz (SR3000)."""
RAW_INVALID = 0xFFFF  # end of the non-ambiguity range: saturated or no return
SPEED_OF_LIGHT_M_S = 299_792_458.0


def integration_time_us(int_time_code: int) -> int:
    """INT_TIME code -> integration time in microseconds: (code + 1) * 200."""
    return (int_time_code + 1) * 200


def mod_freq_khz(mod_freq_index: int) -> int:
    """MOD_FREQ index -> modulation frequency in kHz (3 -> 20000)."""
    return round(MOD_FREQS_MHZ[mod_freq_index] * 1000)


def mod_freq_index(freq_khz: int) -> int | None:
    """Modulation frequency in kHz -> MOD_FREQ index, None if it is not one of the table's frequencies."""
    for index in range(len(MOD_FREQS_MHZ)):
        if mod_freq_khz(index) == freq_khz:
            return index
    return None


def non_ambiguity_range_m(freq_khz: int) -> float:
    """c / (2 f_mod) in metres (7.49 m at 20 MHz)."""
    return SPEED_OF_LIGHT_M_S / (2.0 * freq_khz * 1e3)


def range_unit_m(freq_khz: int) -> float:
    """Metres per raw distance unit: the 16-bit distance spans the non-ambiguity range."""
    return non_ambiguity_range_m(freq_khz) / 65535.0


def raw_to_range_m(raw: np.ndarray, freq_khz: int, out: np.ndarray | None = None) -> np.ndarray:
    """uint16 distance -> float32 metres = raw / 65535 * c / (2 f_mod); raw 0xFFFF -> NaN."""
    scale = np.float32(range_unit_m(freq_khz))
    out = np.multiply(raw, scale, out=out, dtype=np.float32)
    out[raw == RAW_INVALID] = np.nan
    return out


def range_m_to_raw(range_m: np.ndarray, freq_khz: int) -> np.ndarray:
    """float metres -> uint16 distance (inverse of raw_to_range_m); NaN or beyond the range -> 0xFFFF."""
    raw = np.rint(np.asarray(range_m, dtype=np.float64) * (65535.0 / non_ambiguity_range_m(freq_khz)))
    invalid = ~np.isfinite(raw) | (raw >= RAW_INVALID)
    return np.where(invalid, RAW_INVALID, np.clip(np.nan_to_num(raw), 0, RAW_INVALID - 1)).astype("<u2")
