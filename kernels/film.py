"""Film sample positions drawn from the reconstruction filter (filter importance sampling), and the film's colour
conversion for the moment integrator's XYZ layers.

The filter's CDF on [-radius, radius] is a table (pathtracer/rfilter.py: ``filter_cdf``), linear between its points
(a piecewise-constant pdf). Each axis is drawn separately, from the filter truncated to the film, as Mitsuba's film
drops splats outside it: u is mapped into [C(a), C(b)] for the part [a, b] of the filter's support that lies on the
film, then through the inverse CDF. The same u gives the same stratum of the filter, so Sobol' points stay stratified.
"""

import warp as wp

from kernels.sampling import pick_in_cdf


@wp.func
def filter_cdf_at(cdf: wp.array(dtype=float), radius: float, x: float) -> float:
    """The tabulated CDF at offset ``x`` (pixels): 0 below -radius, 1 above radius, linear in between."""
    n = cdf.shape[0] - 1
    s = (x + radius) / (2.0 * radius) * float(n)
    if s <= 0.0:
        return 0.0
    if s >= float(n):
        return 1.0
    i = wp.min(int(s), n - 1)
    t = s - float(i)
    return cdf[i] + t * (cdf[i + 1] - cdf[i])


@wp.func
def filter_cdf_inverse(cdf: wp.array(dtype=float), radius: float, u: float) -> float:
    """The offset x with C(x) = u, for u in [0, 1]: binary search for the bin, linear inside it."""
    n = cdf.shape[0] - 1
    lo = pick_in_cdf(cdf, 1, n, u) - 1  # the bin: the last table point at or below u
    mass = cdf[lo + 1] - cdf[lo]
    t = float(0.5)
    if mass > 0.0:
        t = wp.clamp((u - cdf[lo]) / mass, 0.0, 1.0)
    return -radius + (float(lo) + t) * (2.0 * radius / float(n))


@wp.func
def filter_offset(cdf: wp.array(dtype=float), radius: float, pixel: int, size: int, border: int, u: float) -> float:
    """Offset from the centre of ``pixel`` (of ``size`` along this axis), in pixels, drawn with uniform ``u`` from
    the filter truncated to the sampled part of the film, [-border, size + border]."""
    c = float(pixel) + 0.5
    a = filter_cdf_at(cdf, radius, -c - float(border))
    b = filter_cdf_at(cdf, radius, float(size + border) - c)
    return filter_cdf_inverse(cdf, radius, a + u * (b - a))


@wp.func
def srgb_to_xyz(c: wp.vec3d) -> wp.vec3d:
    """Linear Rec. 709 RGB to CIE XYZ, Mitsuba's matrix (its moment integrator records XYZ)."""
    return wp.vec3d(
        wp.float64(0.412453) * c[0] + wp.float64(0.357580) * c[1] + wp.float64(0.180423) * c[2],
        wp.float64(0.212671) * c[0] + wp.float64(0.715160) * c[1] + wp.float64(0.072169) * c[2],
        wp.float64(0.019334) * c[0] + wp.float64(0.119193) * c[1] + wp.float64(0.950227) * c[2],
    )
