"""Hit records: triangles (found by ``kernels.triangle``) and spheres."""

import warp as wp

from kernels.offset import FLT_EPS, max_abs
from kernels.triangle import TriHit
from kernels.types import Hit, SceneData


INSIDE_ULPS = wp.constant(8.0)  # how far inside its triangle a hit point is kept, in ulps of the coordinates


@wp.func
def inside_point(a: wp.vec3, b: wp.vec3, c: wp.vec3, u: float, v: float, scale: float) -> wp.vec3:
    """The point with barycentrics (u, v, 1 - u - v), kept at least INSIDE_ULPS ulps of ``scale`` inside the
    triangle's edges (the centroid for a triangle too small for that).

    A hit at an edge computed in float32 can land an ulp beyond it, that is beyond the plane of the adjacent face:
    the ray spawned there (offset along this face's normal only) then starts outside that face and, heading back
    in, hits it from outside at t ~ 1e-12: a path leaked out of a closed cube this way (camera inside a cube of
    half-size 1e-3, 1 pixel in 6144). Kept inside its own triangle, the point is on the inner side of every
    adjacent face (for a convex or a concave edge alike), by more than the rounding of the sum below.
    """
    area2 = wp.length(wp.cross(b - a, c - a))
    e = INSIDE_ULPS * FLT_EPS * scale
    w = 1.0 - u - v
    if area2 > 0.0:
        # barycentric margins: the distance to the opposite edge is (weight) x (twice the area) / (edge length)
        mu = e * wp.length(c - b) / area2
        mv = e * wp.length(a - c) / area2
        mw = e * wp.length(b - a) / area2
        if mu + mv + mw < 0.5:
            u = wp.max(u, mu)
            v = wp.max(v, mv)
            w = wp.max(w, mw)
        else:
            u = 1.0
            v = 1.0
            w = 1.0
        total = u + v + w
        u = u / total
        v = v / total
        w = w / total
    return u * a + v * b + w * c


@wp.func
def mesh_hit(scene: SceneData, o: wp.vec3, d: wp.vec3, q: TriHit) -> Hit:
    """Hit record of a ``mesh_closest`` result, flat-shaded (``ns = ng``, the winding normal).

    The point is rebuilt from the barycentrics (u weights vertex 0, v vertex 1), so its error is a few
    ulps of the triangle's own coordinates whatever the ray origin was.
    """
    i0 = scene.indices[3 * q.face + 0]
    i1 = scene.indices[3 * q.face + 1]
    i2 = scene.indices[3 * q.face + 2]
    a = scene.points[i0]
    b = scene.points[i1]
    c = scene.points[i2]
    h = Hit()
    h.t = q.t
    h.scale = wp.max(max_abs(a), wp.max(max_abs(b), max_abs(c)))
    h.p = inside_point(a, b, c, q.u, q.v, h.scale)
    h.ng = wp.normalize(wp.cross(b - a, c - a))
    h.ns = h.ng
    h.material = scene.face_material[q.face]
    h.light = scene.face_light[q.face]
    h.sphere = -1
    h.quad = -1
    h.face = q.face
    h.bary = wp.vec2(q.u, q.v)
    return h


@wp.func
def smooth_normal(scene: SceneData, face: int, u: float, v: float, ng: wp.vec3) -> wp.vec3:
    """Shading normal interpolated from the face's corner normals; ``ng`` if they cancel out."""
    n = u * scene.corner_normals[3 * face + 0] + v * scene.corner_normals[3 * face + 1]
    n = n + (1.0 - u - v) * scene.corner_normals[3 * face + 2]
    len_n = wp.length(n)
    if len_n > 1.0e-12:
        return n / len_n
    return ng


@wp.func
def sphere_hit(scene: SceneData, o: wp.vec3, d: wp.vec3, t: float, i: int) -> Hit:
    """Hit record on sphere ``i`` at distance ``t``; the point is projected back onto the sphere."""
    c = scene.sphere_center[i]
    r = scene.sphere_radius[i]
    n = wp.normalize(o + t * d - c)
    h = Hit()
    h.t = t
    h.p = c + r * n
    h.ng = n
    h.ns = n
    h.scale = max_abs(h.p)
    h.material = scene.sphere_material[i]
    h.light = scene.sphere_light[i]
    h.sphere = i
    h.quad = -1
    return h
