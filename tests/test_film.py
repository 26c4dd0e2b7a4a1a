"""Reconstruction filters: the tabulated CDF and the film offsets the camera draws from it (kernels/film.py).

The offsets are checked as quadrature: with u on a fine midpoint grid, the mean of g(offset) is the integral of g
against the drawn density, which must equal the filter's own f-weighted mean (truncated to the film, as Mitsuba's
film drops splats outside it) up to the table's and the grid's discretisation, far below any render noise.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import warp as wp

from pathtracer.rfilter import filter_cdf
from pathtracer.scene import PixelFilter
from probes import probe_filter_offset

FILTERS = [PixelFilter("tent", 1.0), PixelFilter("tent", 2.5), PixelFilter.gaussian(0.5), PixelFilter.gaussian(0.3)]
IDS = ["tent1", "tent2.5", "gauss0.5", "gauss0.3"]


def trapezoid(y: np.ndarray, x: np.ndarray) -> float:
    return float(np.sum((y[1:] + y[:-1]) * np.diff(x)) / 2.0)  # np.trapezoid needs numpy 2


def truncated_moments(f: PixelFilter, lo: float, hi: float, n: int = 200001):
    """E[x], E[x^2] and P(x < 0) under f restricted to [lo, hi], by the trapezoid rule on a fine grid."""
    x = np.linspace(max(lo, -f.radius), min(hi, f.radius), n)
    w = f.eval(x)
    z = trapezoid(w, x)
    return trapezoid(w * x, x) / z, trapezoid(w * x * x, x) / z, trapezoid(np.where(x < 0, w, 0), x) / z


def draw(f: PixelFilter, pixel: int, size: int, n: int = 65536, device: str = "cpu", border: int = 0) -> np.ndarray:
    cdf = wp.array(filter_cdf(f).astype(np.float32), dtype=float, device=device)
    us = wp.array(((np.arange(n) + 0.5) / n).astype(np.float32), dtype=float, device=device)
    px = wp.array(np.full(n, pixel, dtype=np.int32), dtype=int, device=device)
    out = wp.zeros(n, dtype=float, device=device)
    wp.launch(probe_filter_offset, n, inputs=[cdf, f.radius, px, size, border, us], outputs=[out], device=device)
    return out.numpy().astype(np.float64)


@pytest.mark.parametrize("f", FILTERS, ids=IDS)
def test_cdf_table_matches_the_closed_form(f):
    cdf = filter_cdf(f)
    x = np.linspace(-f.radius, f.radius, len(cdf))
    if f.kind == "tent":
        r = f.radius
        exact = np.where(x < 0, (x + r) ** 2 / (2 * r * r), 1 - (r - x) ** 2 / (2 * r * r))
    else:
        s, r = f.stddev, f.radius
        erf = np.vectorize(math.erf)
        g = np.sqrt(np.pi / 2) * s * (erf(x / (np.sqrt(2) * s)) - erf(-r / (np.sqrt(2) * s)))
        g -= np.exp(-r * r / (2 * s * s)) * (x + r)
        exact = g / g[-1]
    assert cdf[0] == 0.0 and cdf[-1] == 1.0 and np.all(np.diff(cdf) >= 0)
    np.testing.assert_allclose(cdf, exact, atol=1e-12)


def test_cdf_table_needs_an_even_bin_count():
    with pytest.raises(ValueError):
        filter_cdf(PixelFilter("tent", 1.0), bins=7)


@pytest.mark.parametrize("f", FILTERS, ids=IDS)
@pytest.mark.parametrize("pixel", [0, 1, 5, 9], ids=["edge", "near_edge", "inside", "last"])
def test_offsets_follow_the_filter_truncated_to_the_film(device, f, pixel):
    size = 10
    lo, hi = -(pixel + 0.5), size - (pixel + 0.5)
    x = draw(f, pixel, size, device=device)
    # always on the film, and never beyond the filter's support
    assert x.min() >= max(lo, -f.radius) - 1e-6 and x.max() <= min(hi, f.radius) + 1e-6
    m1, m2, below = truncated_moments(f, lo, hi)
    scale = f.radius
    assert abs(x.mean() - m1) <= 2e-4 * scale, (x.mean(), m1)
    assert abs(np.mean(x * x) - m2) <= 2e-4 * scale * scale, (np.mean(x * x), m2)
    assert abs(np.mean(x < 0) - below) <= 1e-4


def test_sample_border_widens_the_truncation(device):
    """Mitsuba's sample_border: the film is sampled ceil(radius - 0.5) pixels beyond its edges."""
    f = PixelFilter.gaussian()
    x = draw(f, 0, 10, device=device, border=2)
    m1, m2, _ = truncated_moments(f, -2.5, 9.5)
    assert x.min() < -0.5 and abs(x.mean() - m1) <= 4e-4 and abs(np.mean(x * x) - m2) <= 8e-4


def test_offsets_are_monotone_in_u_so_strata_map_to_strata(device):
    x = draw(PixelFilter.gaussian(), 3, 8, n=4096, device=device)
    assert np.all(np.diff(x) >= 0)


def test_box_filter_is_not_tabulated():
    assert PixelFilter().is_box and not PixelFilter.gaussian().is_box
    np.testing.assert_array_equal(PixelFilter().eval([-0.5, 0.0, 0.4999, 0.5]), [1, 1, 1, 0])
    assert PixelFilter.gaussian().eval(2.0) == 0.0 and PixelFilter.gaussian().radius == 2.0
