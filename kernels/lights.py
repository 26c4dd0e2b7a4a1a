"""Next-event samples of the emitters other than parallelograms (those are in kernels/integrator.py and
kernels/sphrect.py): spheres (uniform in the cone they subtend), triangle meshes (uniform in area), point, spot and
directional lights (deltas: one deterministic connection each) and the constant environment.

Each sampler returns the point it connects to and the reciprocal of the sample's density in solid angle as seen
from the shading point, so the integrator adds Le cos_x / pdf for every unoccluded sample, whatever the emitter.
"""

import warp as wp

from kernels.sampling import orthonormal_basis


@wp.struct
class EmitterSample:
    p: wp.vec3  # the point on the emitter (a far point for directions)
    n: wp.vec3  # its outward normal (zero for points and directions)
    inv_pdf: float  # 1 / (density in solid angle at the shading point); 0: no valid sample


@wp.func
def sample_sphere_cone(x: wp.vec3, c: wp.vec3, r: float, u1: float, u2: float) -> EmitterSample:
    """A point on the part of the sphere (c, r) that ``x`` sees, by a direction uniform in the cone it subtends
    (pdf 1 / (2 pi (1 - cos theta_max))). ``x`` inside or on the sphere: no sample (it then sees only the inside,
    which a one-sided, outward emitter does not light)."""
    out = EmitterSample()
    to_c = c - x
    dist2 = wp.dot(to_c, to_c)
    if dist2 <= r * r:
        return out
    dist = wp.sqrt(dist2)
    sin2_max = r * r / dist2
    # 1 - cos(theta_max) without cancellation for small spheres
    one_minus_cos_max = sin2_max / (1.0 + wp.sqrt(wp.max(0.0, 1.0 - sin2_max)))
    one_minus_cos = u1 * one_minus_cos_max
    cos_t = 1.0 - one_minus_cos
    sin_t = wp.sqrt(wp.max(0.0, one_minus_cos * (2.0 - one_minus_cos)))
    phi = 2.0 * wp.pi * u2
    axis = to_c / dist
    w = orthonormal_basis(axis) * wp.vec3(sin_t * wp.cos(phi), sin_t * wp.sin(phi), cos_t)
    # the nearer intersection of x + t w with the sphere (w lies inside the cone, so it exists; clamp rounding)
    b = wp.dot(w, to_c)
    disc = wp.max(0.0, r * r - (dist2 - b * b))
    t = b - wp.sqrt(disc)
    n = wp.normalize(x + t * w - c)
    out.p = c + r * n
    out.n = n
    out.inv_pdf = 2.0 * wp.pi * one_minus_cos_max
    return out


@wp.func
def sphere_cone_pdf(x: wp.vec3, c: wp.vec3, r: float) -> float:
    """The solid-angle density of ``sample_sphere_cone`` from ``x``; 0 from inside the sphere (no samples there)."""
    to_c = c - x
    dist2 = wp.dot(to_c, to_c)
    if dist2 <= r * r:
        return 0.0
    sin2_max = r * r / dist2
    return 1.0 / (2.0 * wp.pi * (sin2_max / (1.0 + wp.sqrt(wp.max(0.0, 1.0 - sin2_max)))))


@wp.func
def sample_triangle_light(x: wp.vec3, a: wp.vec3, b: wp.vec3, c: wp.vec3, n: wp.vec3, total_area: float,
                          u1: float, u2: float) -> EmitterSample:
    """A point uniform in triangle (a, b, c) of a mesh light whose triangles are picked in proportion to their
    area (so the point is uniform on the whole mesh, pdf 1 / total_area); ``n`` its normal there. The inverse
    density in solid angle is total_area |cos_y| / d^2."""
    out = EmitterSample()
    su = wp.sqrt(u1)
    p = (1.0 - su) * a + (su * (1.0 - u2)) * b + (su * u2) * c
    d = p - x
    dist2 = wp.dot(d, d)
    if dist2 <= 0.0:
        return out
    out.p = p
    out.n = n
    out.inv_pdf = total_area * wp.abs(wp.dot(n, d)) / (dist2 * wp.sqrt(dist2))
    return out


@wp.func
def spot_falloff(cos_theta: float, cos_cutoff: float, cutoff: float, beam: float, cos_beam: float) -> float:
    """Mitsuba's spot profile: 1 inside the beam, linear in the angle down to 0 at the cutoff (exactly 0 there)."""
    if cos_theta <= cos_cutoff:
        return 0.0
    if cos_theta >= cos_beam:
        return 1.0
    return (cutoff - wp.acos(wp.clamp(cos_theta, -1.0, 1.0))) / (cutoff - beam)
