"""Sampling routines and frames. Directions are unit vectors; local frames have the normal as +z."""

import warp as wp


@wp.func
def orthonormal_basis(n: wp.vec3) -> wp.mat33:
    """Columns (t, b, n): a right-handed frame around unit ``n`` (Duff et al. 2017, branchless, no singularity)."""
    sign = wp.where(n[2] >= 0.0, 1.0, -1.0)
    a = -1.0 / (sign + n[2])
    b = n[0] * n[1] * a
    t = wp.vec3(1.0 + sign * n[0] * n[0] * a, sign * b, -sign * n[0])
    bt = wp.vec3(b, sign + n[1] * n[1] * a, -n[1])
    return wp.mat33(t[0], bt[0], n[0], t[1], bt[1], n[1], t[2], bt[2], n[2])


@wp.func
def cosine_hemisphere(u1: float, u2: float) -> wp.vec3:
    """Cosine-weighted direction about +z (pdf cos(theta)/pi), as the seed: phi = 2 pi u1, cos(theta) = sqrt(u2)."""
    phi = 2.0 * wp.pi * u1
    r = wp.sqrt(1.0 - u2)
    return wp.vec3(r * wp.cos(phi), r * wp.sin(phi), wp.sqrt(u2))


@wp.func
def sample_cosine_around(n: wp.vec3, u1: float, u2: float) -> wp.vec3:
    """Cosine-weighted unit direction in the hemisphere of unit normal ``n``."""
    return wp.normalize(orthonormal_basis(n) * cosine_hemisphere(u1, u2))


@wp.func
def sample_parallelogram(center: wp.vec3, half_u: wp.vec3, half_v: wp.vec3, u1: float, u2: float) -> wp.vec3:
    """Uniform point on ``center + s half_u + t half_v``, s, t in [-1, 1] (pdf 1 / area)."""
    return center + (2.0 * u1 - 1.0) * half_u + (2.0 * u2 - 1.0) * half_v


@wp.func
def reflect(d: wp.vec3, n: wp.vec3) -> wp.vec3:
    """Mirror direction of incoming ``d`` about unit ``n``: d - 2 (d.n) n."""
    return d - 2.0 * wp.dot(d, n) * n


@wp.func
def square_to_disk_concentric(u1: float, u2: float) -> wp.vec2:
    """Shirley-Chiu concentric map of [0, 1)^2 onto the unit disk (uniform; Mitsuba's square_to_uniform_disk_concentric)."""
    x = 2.0 * u1 - 1.0
    y = 2.0 * u2 - 1.0
    if x == 0.0 and y == 0.0:
        return wp.vec2(0.0, 0.0)
    r = float(0.0)
    phi = float(0.0)
    if wp.abs(x) < wp.abs(y):
        r = y
        phi = 0.5 * wp.pi - 0.25 * wp.pi * (x / y)
    else:
        r = x
        phi = 0.25 * wp.pi * (y / x)
    return wp.vec2(r * wp.cos(phi), r * wp.sin(phi))


@wp.func
def pick_in_cdf(cdf: wp.array(dtype=float), start: int, count: int, u: float) -> int:
    """The index i in [start, start + count) with cdf[i - 1] <= u < cdf[i] (cdf[start - 1] taken as 0; the last
    index when u >= every entry), by binary search: the entry drawn in proportion to its mass (a mesh light's
    triangle, a filter table's bin)."""
    lo = start
    hi = start + count - 1
    while lo < hi:
        mid = (lo + hi) // 2
        if u < cdf[mid]:
            hi = mid
        else:
            lo = mid + 1
    return lo
