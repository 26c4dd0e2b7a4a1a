"""Spectra given as ``<spectrum>`` -> linear sRGB, exactly as Mitsuba 3's RGB variants convert them.

Mitsuba's RGB variants never render spectrally: a ``<spectrum>`` property is integrated once, when
the plugin reads it (``Properties::get_texture_impl`` and ``spectrum_list_to_srgb`` in
``src/core/properties.cpp`` and ``src/core/spectrum.cpp``, Mitsuba 3.9). The rules reproduced here:

* a uniform spectrum ``{"type": "spectrum", "value": v}`` is the grey ``(v, v, v)`` as a reflectance,
  but ``v * xyz_to_srgb(1, 1, 1)`` (about ``v * (1.2048, 0.9483, 0.9089)``, "purple-ish") as an
  emitter's radiance, so that RGB renders match spectral ones;
* a piecewise-linear spectrum ``{"type": "spectrum", "wavelengths": [...], "values": [...]}`` is
  sampled at 1000 wavelengths evenly spread over [360, 830] nm (zero outside the given range),
  weighted by the CIE 1931 2-degree matching functions, and, for reflectances only, by the D65
  illuminant (so a flat 1 reflects as white); emitters use the matching functions alone. The XYZ
  sum becomes linear sRGB (Rec. 709 primaries, no gamma). Out-of-gamut results are clamped as
  Mitsuba does (with a warning there): a bounded value (a reflectance) to [0, 1], an unbounded one
  (an emitter, or e.g. a conductor's ``eta``) to >= 0.

The tables are Mitsuba's own (``cie1931_tbl`` in src/core/spectrum.cpp and ``d65_table`` in
include/mitsuba/core/spectrum.h: 95 samples, 360..830 nm every 5 nm). Mitsuba stores them as 32-bit
floats and does the rest in double precision, so they are rounded to float32 here too. They are
turned into arrays on first use, so importing this module costs nothing measurable.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from functools import lru_cache

import numpy as np

CIE_MIN, CIE_MAX, CIE_SAMPLES = 360.0, 830.0, 95
STEPS = 1000  # Mitsuba's sample count in spectrum_list_to_srgb
CIE_Y_NORMALIZATION = 1.0 / 106.7502593994140625  # a flat unit spectrum integrates to Y = 1
CIE_D65_NORMALIZATION = 1.0 / 98.99741751876255  # D65 integrates to Y = 1
# XYZ -> linear sRGB, as Mitsuba writes it (float literals)
XYZ_TO_SRGB = (
    (3.240479, -1.537150, -0.498535),
    (-0.969256, 1.875991, 0.041556),
    (0.055648, -0.204043, 1.057311),
)

# CIE 1931 2-degree colour matching functions x-bar, y-bar, z-bar at 360, 365, ..., 830 nm
# (Mitsuba 3.9, src/core/spectrum.cpp, cie1931_tbl).
_CIE_X = (
    0.0001299, 0.0002321, 0.0004149, 0.0007416, 0.001368, 0.002236, 0.004243, 0.00765, 0.01431, 0.02319,
    0.04351, 0.07763, 0.13438, 0.21477, 0.2839, 0.3285, 0.34828, 0.34806, 0.3362, 0.3187, 0.2908, 0.2511,
    0.19536, 0.1421, 0.09564, 0.05795001, 0.03201, 0.0147, 0.0049, 0.0024, 0.0093, 0.0291, 0.06327, 0.1096,
    0.1655, 0.2257499, 0.2904, 0.3597, 0.4334499, 0.5120501, 0.5945, 0.6784, 0.7621, 0.8425, 0.9163, 0.9786,
    1.0263, 1.0567, 1.0622, 1.0456, 1.0026, 0.9384, 0.8544499, 0.7514, 0.6424, 0.5419, 0.4479, 0.3608,
    0.2835, 0.2187, 0.1649, 0.1212, 0.0874, 0.0636, 0.04677, 0.0329, 0.0227, 0.01584, 0.01135916,
    0.008110916, 0.005790346, 0.004109457, 0.002899327, 0.00204919, 0.001439971, 0.0009999493, 0.0006900786,
    0.0004760213, 0.0003323011, 0.0002348261, 0.0001661505, 0.000117413, 8.307527e-05, 5.870652e-05,
    4.150994e-05, 2.935326e-05, 2.067383e-05, 1.455977e-05, 1.025398e-05, 7.221456e-06, 5.085868e-06,
    3.581652e-06, 2.522525e-06, 1.776509e-06, 1.251141e-06,
)

_CIE_Y = (
    3.917e-06, 6.965e-06, 1.239e-05, 2.202e-05, 3.9e-05, 6.4e-05, 0.00012, 0.000217, 0.000396, 0.00064,
    0.00121, 0.00218, 0.004, 0.0073, 0.0116, 0.01684, 0.023, 0.0298, 0.038, 0.048, 0.06, 0.0739, 0.09098,
    0.1126, 0.13902, 0.1693, 0.20802, 0.2586, 0.323, 0.4073, 0.503, 0.6082, 0.71, 0.7932, 0.862, 0.9148501,
    0.954, 0.9803, 0.9949501, 1.0, 0.995, 0.9786, 0.952, 0.9154, 0.87, 0.8163, 0.757, 0.6949, 0.631, 0.5668,
    0.503, 0.4412, 0.381, 0.321, 0.265, 0.217, 0.175, 0.1382, 0.107, 0.0816, 0.061, 0.04458, 0.032, 0.0232,
    0.017, 0.01192, 0.00821, 0.005723, 0.004102, 0.002929, 0.002091, 0.001484, 0.001047, 0.00074, 0.00052,
    0.0003611, 0.0002492, 0.0001719, 0.00012, 8.48e-05, 6e-05, 4.24e-05, 3e-05, 2.12e-05, 1.499e-05,
    1.06e-05, 7.4657e-06, 5.2578e-06, 3.7029e-06, 2.6078e-06, 1.8366e-06, 1.2934e-06, 9.1093e-07, 6.4153e-07,
    4.5181e-07,
)

_CIE_Z = (
    0.0006061, 0.001086, 0.001946, 0.003486, 0.006450001, 0.01054999, 0.02005001, 0.03621, 0.06785001,
    0.1102, 0.2074, 0.3713, 0.6456, 1.0390501, 1.3856, 1.62296, 1.74706, 1.7826, 1.77211, 1.7441, 1.6692,
    1.5281, 1.28764, 1.0419, 0.8129501, 0.6162, 0.46518, 0.3533, 0.272, 0.2123, 0.1582, 0.1117, 0.07824999,
    0.05725001, 0.04216, 0.02984, 0.0203, 0.0134, 0.008749999, 0.005749999, 0.0039, 0.002749999, 0.0021,
    0.0018, 0.001650001, 0.0014, 0.0011, 0.001, 0.0008, 0.0006, 0.00034, 0.00024, 0.00019, 0.0001,
    4.999999e-05, 3e-05, 2e-05, 1e-05, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
    0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
    0.0, 0.0,
)

# CIE D65 relative spectral power at the same wavelengths, 100 at 560 nm
# (Mitsuba 3.9, include/mitsuba/core/spectrum.h, d65_table).
_D65 = (
    46.6383, 49.3637, 52.0891, 51.0323, 49.9755, 52.3118, 54.6482, 68.7015, 82.7549, 87.1204, 91.486,
    92.4589, 93.4318, 90.057, 86.6823, 95.7736, 104.865, 110.936, 117.008, 117.41, 117.812, 116.336, 114.861,
    115.392, 115.923, 112.367, 108.811, 109.082, 109.354, 108.578, 107.802, 106.296, 104.79, 106.239,
    107.689, 106.047, 104.405, 104.225, 104.046, 102.023, 100.0, 98.1671, 96.3342, 96.0611, 95.788, 92.2368,
    88.6856, 89.3459, 90.0062, 89.8026, 89.5991, 88.6489, 87.6987, 85.4936, 83.2886, 83.4939, 83.6992,
    81.863, 80.0268, 80.1207, 80.2146, 81.2462, 82.2778, 80.281, 78.2842, 74.0027, 69.7213, 70.6652, 71.6091,
    72.979, 74.349, 67.9765, 61.604, 65.7448, 69.8856, 72.4863, 75.087, 69.3398, 63.5927, 55.0054, 46.4182,
    56.6118, 66.8054, 65.0941, 63.3828, 63.8434, 64.304, 61.8779, 59.4519, 55.7054, 51.959, 54.6998, 57.4406,
    58.8765, 60.3125,
)


@lru_cache(maxsize=1)
def _tables() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(xyz table (95, 3), D65 table (95,), XYZ->sRGB matrix), float32-rounded like Mitsuba's."""
    xyz = np.array([_CIE_X, _CIE_Y, _CIE_Z], dtype=np.float32).T.astype(np.float64)
    d65 = np.array(_D65, dtype=np.float32).astype(np.float64)
    m = np.array(XYZ_TO_SRGB, dtype=np.float32).astype(np.float64)
    return xyz, d65, m


def _lerp_table(table: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Mitsuba's table lookup (cie1931_xyz, cie_d65): linear between 5 nm samples, zero outside."""
    t = (w - CIE_MIN) * ((CIE_SAMPLES - 1) / (CIE_MAX - CIE_MIN))
    i0 = np.clip(t.astype(np.int64), 0, CIE_SAMPLES - 2)
    f = t - i0
    if table.ndim == 2:
        f = f[:, None]
    v = (1.0 - f) * table[i0] + f * table[i0 + 1]
    inside = (w >= CIE_MIN) & (w <= CIE_MAX)
    return np.where(inside[:, None] if table.ndim == 2 else inside, v, 0.0)


def uniform_emitter_rgb() -> tuple[float, float, float]:
    """``xyz_to_srgb(1, 1, 1)``: the colour of a unit uniform spectrum used as a radiance."""
    _, _, m = _tables()
    return tuple(float(c) for c in m.sum(axis=1))


def spectrum_list_to_srgb(wavelengths, values, bounded: bool, d65: bool, clamp: bool = True) -> np.ndarray:
    """Mitsuba's ``spectrum_list_to_srgb``: integrate a piecewise-linear spectrum to linear sRGB.

    ``bounded`` clamps to [0, 1] (else only negatives are clamped); ``d65`` weights by the D65
    illuminant (reflectances) or not (emitters). ``clamp=False`` returns the raw colour, so a caller
    can tell that Mitsuba would clamp it (and warn).
    """
    wl = np.asarray(wavelengths, dtype=np.float64)
    val = np.asarray(values, dtype=np.float64)
    xyz_tab, d65_tab, m = _tables()
    w = CIE_MIN + (np.arange(STEPS) / (STEPS - 1)) * (CIE_MAX - CIE_MIN)
    w = w[(w >= wl[0]) & (w <= wl[-1])]  # zero outside the given range
    v = np.interp(w, wl, val)
    if d65:
        v = v * _lerp_table(d65_tab, w) * CIE_D65_NORMALIZATION
    xyz = (_lerp_table(xyz_tab, w) * v[:, None]).sum(axis=0)
    xyz *= (CIE_MAX - CIE_MIN) * CIE_Y_NORMALIZATION / STEPS  # Mitsuba divides by steps, not steps - 1
    rgb = m @ xyz
    if clamp:
        rgb = np.clip(rgb, 0.0, 1.0) if bounded else np.maximum(rgb, 0.0)
    return rgb


def spectrum_to_rgb(spec: Mapping, emitter: bool, *, unbounded: bool = False,
                    clamp: bool = True) -> tuple[float, float, float]:
    """The linear sRGB colour Mitsuba's RGB variants give a ``<spectrum>`` property.

    ``spec`` is a dict from :func:`pathtracer.loader_xml.parse_file`: ``{"type": "spectrum",
    "value": v}`` (uniform) or ``{"type": "spectrum", "wavelengths": [...], "values": [...]}``
    (at least 2 pairs, strictly increasing wavelengths in nm, finite numbers). ``emitter`` is true
    for an emitter's radiance/intensity/irradiance (Mitsuba's ``get_emissive_texture``): no D65
    weighting, never bounded. ``unbounded`` is for non-emitter properties Mitsuba reads unbounded
    (conductor ``eta``/``k``): D65-weighted, only negatives clamped. Raises ``ValueError`` for a
    malformed dict (the loader names the element).
    """
    if not isinstance(spec, Mapping) or spec.get("type") != "spectrum":
        raise ValueError(f'expected a {{"type": "spectrum", ...}} dict (got {spec!r:.60})')
    keys = set(spec) - {"type"}
    if keys == {"value"}:
        v = _finite(spec["value"], "value")
        if emitter:
            return tuple(v * c for c in uniform_emitter_rgb())
        return (v, v, v)
    if keys != {"wavelengths", "values"}:
        raise ValueError('a spectrum dict takes either "value" or both "wavelengths" and "values" '
                         f'(got {", ".join(sorted(map(str, keys))) or "neither"})')
    wl, val = spec["wavelengths"], spec["values"]
    if isinstance(wl, (str, bytes, Mapping)) or isinstance(val, (str, bytes, Mapping)):
        raise ValueError('"wavelengths" and "values" must be lists of numbers')
    wl = [_finite(x, "wavelength") for x in wl]
    val = [_finite(x, "value") for x in val]
    if len(wl) != len(val):
        raise ValueError(f"{len(wl)} wavelengths but {len(val)} values")
    if len(wl) < 2:
        raise ValueError(f"a spectrum needs at least 2 wavelength:value pairs (got {len(wl)})")
    for a, b in zip(wl, wl[1:]):
        if not b > a:
            raise ValueError(f"wavelengths must increase strictly ({b:g} follows {a:g})")
    rgb = spectrum_list_to_srgb(wl, val, bounded=not (emitter or unbounded), d65=not emitter, clamp=clamp)
    return tuple(float(c) for c in rgb)


def _finite(x, what: str) -> float:
    if isinstance(x, bool) or not isinstance(x, (int, float, np.integer, np.floating)):
        raise ValueError(f"{what} must be a number (got {x!r:.40})")
    try:
        f = float(x)
    except OverflowError:
        f = math.inf
    if not math.isfinite(f):
        raise ValueError(f"{what} must be finite (got {x!r})")
    return f
