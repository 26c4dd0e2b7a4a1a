"""Reconstruction filters as sampling tables: the camera draws each sample's film offset from the filter itself
(filter importance sampling), so every sample has weight 1 and a pixel stays a plain mean of independent samples,
mergeable by addition like every other sum of the renderer.

For a positive separable filter f this has the same limit as Mitsuba's splatting film (sum of f-weighted samples over
the sum of the weights): the f-weighted mean of the radiance around the pixel centre. Mitsuba drops splats outside the
film, so at the edges its weights are those of f truncated to the film; the kernel draws from f truncated per axis to
the film the same way (kernels/film.py), which keeps the limit equal at the edges too.
"""

from __future__ import annotations

import numpy as np

from pathtracer.scene import PixelFilter

TABLE_BINS = 1024  # the pdf is f averaged over each bin: a relative error of about (2 r / bins)^2 / 24 * |f'' / f|
_GAUSS_NODES, _GAUSS_WEIGHTS = np.polynomial.legendre.leggauss(8)


def filter_cdf(f: PixelFilter, bins: int = TABLE_BINS) -> np.ndarray:
    """CDF of ``f`` on [-radius, radius] at ``bins + 1`` equally spaced points, from 0 to 1 (float64).

    Each bin's mass is f integrated by 8-point Gauss-Legendre, split at the filter's kinks (0 for the tent) by the
    bin grid: the grid is symmetric and has a point at 0 for even ``bins``.
    """
    if bins < 2 or bins % 2:
        raise ValueError("bins must be even and >= 2")
    edges = np.linspace(-f.radius, f.radius, bins + 1)
    lo, hi = edges[:-1], edges[1:]
    mid, half = (lo + hi) / 2.0, (hi - lo) / 2.0
    x = mid[:, None] + half[:, None] * _GAUSS_NODES[None, :]
    mass = (f.eval(x) * _GAUSS_WEIGHTS[None, :]).sum(axis=1) * half
    cdf = np.concatenate([[0.0], np.cumsum(mass)])
    return cdf / cdf[-1]
