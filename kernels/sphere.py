"""Analytic ray-sphere intersection, numerically stable far away, up close and for huge radii."""

import warp as wp

SELF_NONE = wp.constant(0)  # the ray did not start on this sphere
SELF_SKIP = wp.constant(1)  # it starts on this sphere and leaves it: a convex sphere cannot be hit again
SELF_FAR = wp.constant(2)  # it starts on this sphere and enters it: only the far root is a real hit


@wp.func
def ray_sphere(o: wp.vec3, d: wp.vec3, center: wp.vec3, radius: float, tmax: float, self_mode: int) -> float:
    """Distance to the nearest hit in [0, tmax) of the ray o + t d (unit d), or -1 on a miss.

    Solved in float64 with the discriminant of Haines et al. (Ray Tracing Gems ch. 7): r^2 - |f|^2 with
    f = (o - c) - b d, and the two roots as q and c/q, so neither cancels for distant, tiny or huge spheres.
    """
    if self_mode == SELF_SKIP:
        return -1.0
    ocx = wp.float64(o[0]) - wp.float64(center[0])
    ocy = wp.float64(o[1]) - wp.float64(center[1])
    ocz = wp.float64(o[2]) - wp.float64(center[2])
    dx = wp.float64(d[0])
    dy = wp.float64(d[1])
    dz = wp.float64(d[2])
    r = wp.float64(radius)
    b = ocx * dx + ocy * dy + ocz * dz
    fx = ocx - b * dx
    fy = ocy - b * dy
    fz = ocz - b * dz
    disc = r * r - (fx * fx + fy * fy + fz * fz)
    if disc < wp.float64(0.0):
        return -1.0
    c = ocx * ocx + ocy * ocy + ocz * ocz - r * r
    sq = wp.sqrt(disc)
    q = -b - sq
    if b < wp.float64(0.0):
        q = -b + sq
    t0 = wp.float64(0.0)
    t1 = wp.float64(0.0)
    if q != wp.float64(0.0):
        t0 = c / q
        t1 = q
    if t0 > t1:
        tmp = t0
        t0 = t1
        t1 = tmp
    limit = wp.float64(tmax)
    if self_mode != SELF_FAR and t0 > wp.float64(0.0) and t0 < limit:
        return float(t0)
    if t1 > wp.float64(0.0) and t1 < limit:
        return float(t1)
    return -1.0
