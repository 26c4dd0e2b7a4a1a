"""Uniform sampling of the solid angle a rectangle subtends (Urena, Fajardo, King, "An Area-Preserving
Parametrization for Spherical Rectangles", EGSR 2013; the same steps as pbrt-v4's ``SampleSphericalRectangle``).

Computed in float64: the solid angle is a sum of four angles minus 2 pi, and float32 would lose it to cancellation
for small or distant lights. Where the solid angle is tiny (below ``MIN_SOLID_ANGLE``: a point almost in the
light's plane, or very far away) or a step is not finite, ``solid_angle`` is 0 and the caller falls back to
uniform area sampling, whose variance there is small anyway.
"""

import warp as wp

PI64 = wp.constant(wp.float64(3.141592653589793))
MIN_SOLID_ANGLE = wp.constant(wp.float64(1.0e-6))


@wp.struct
class SphRectSample:
    p: wp.vec3  # the sampled point on the rectangle
    solid_angle: float  # the rectangle's solid angle seen from o (1 / pdf); 0: not sampled, use area sampling


@wp.func
def angle_between(a: wp.vec3d, b: wp.vec3d) -> wp.float64:
    """Angle between unit vectors, accurate near 0 and pi (pbrt's AngleBetween)."""
    half = wp.float64(0.5)
    one = wp.float64(1.0)
    if wp.dot(a, b) < wp.float64(0.0):
        return PI64 - wp.float64(2.0) * wp.asin(wp.min(wp.length(a + b) * half, one))
    return wp.float64(2.0) * wp.asin(wp.min(wp.length(b - a) * half, one))


@wp.func
def sample_spherical_rectangle(o: wp.vec3, s: wp.vec3, ex: wp.vec3, ey: wp.vec3, u1: float, u2: float) -> SphRectSample:
    """Point on the rectangle ``s + a ex + b ey`` (a, b in [0, 1], ex orthogonal to ey) with a direction from ``o``
    uniform in the rectangle's solid angle, and that solid angle. Either side of the rectangle is sampled."""
    out = SphRectSample()
    out.p = s + u1 * ex + u2 * ey
    out.solid_angle = float(0.0)
    zero = wp.float64(0.0)
    one = wp.float64(1.0)
    exd = wp.vec3d(ex)
    eyd = wp.vec3d(ey)
    exl = wp.length(exd)
    eyl = wp.length(eyd)
    if exl <= zero or eyl <= zero:
        return out
    fx = exd / exl
    fy = eyd / eyl
    fz = wp.cross(fx, fy)
    dv = wp.vec3d(s) - wp.vec3d(o)
    x0 = wp.dot(dv, fx)
    y0 = wp.dot(dv, fy)
    z0 = wp.dot(dv, fz)
    if z0 > zero:  # z points away from the rectangle
        fz = -fz
        z0 = -z0
    if z0 >= zero:
        return out  # o in the rectangle's plane
    x1 = x0 + exl
    y1 = y0 + eyl
    v00 = wp.vec3d(x0, y0, z0)
    v01 = wp.vec3d(x0, y1, z0)
    v10 = wp.vec3d(x1, y0, z0)
    v11 = wp.vec3d(x1, y1, z0)
    n0 = wp.normalize(wp.cross(v00, v10))
    n1 = wp.normalize(wp.cross(v10, v11))
    n2 = wp.normalize(wp.cross(v11, v01))
    n3 = wp.normalize(wp.cross(v01, v00))
    g0 = angle_between(-n0, n1)
    g1 = angle_between(-n1, n2)
    g2 = angle_between(-n2, n3)
    g3 = angle_between(-n3, n0)
    omega = g0 + g1 + g2 + g3 - wp.float64(2.0) * PI64
    if not (omega >= MIN_SOLID_ANGLE):
        return out

    # u1 -> x: the area-preserving cut along x
    uu = wp.float64(u1)
    b0 = n0[2]
    b1 = n2[2]
    au = uu * (g0 + g1 - wp.float64(2.0) * PI64) + (uu - one) * (g2 + g3)
    fu = (wp.cos(au) * b0 - b1) / wp.sin(au)
    cu = one / wp.sqrt(fu * fu + b0 * b0)
    if fu < zero:
        cu = -cu
    lim = wp.float64(1.0 - 1.0e-15)
    cu = wp.clamp(cu, -lim, lim)
    xu = -(cu * z0) / wp.sqrt(one - cu * cu)
    xu = wp.clamp(xu, x0, x1)

    # u2 -> y: uniform in the sine of the elevation along the cut
    dd = wp.sqrt(xu * xu + z0 * z0)
    h0 = y0 / wp.sqrt(dd * dd + y0 * y0)
    h1 = y1 / wp.sqrt(dd * dd + y1 * y1)
    hv = h0 + wp.float64(u2) * (h1 - h0)
    hvsq = hv * hv
    yv = y1
    if hvsq < wp.float64(1.0 - 1.0e-12):
        yv = hv * dd / wp.sqrt(one - hvsq)
    yv = wp.clamp(yv, y0, y1)

    q = wp.vec3d(o) + xu * fx + yv * fy + z0 * fz
    p = wp.vec3(q)
    if not (wp.isfinite(p) and wp.isfinite(xu) and wp.isfinite(yv)):
        return out
    out.p = p
    out.solid_angle = float(omega)
    return out
