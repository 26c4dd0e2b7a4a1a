"""Hit records: triangles (found by ``kernels.triangle``) and spheres."""

import warp as wp

from kernels.offset import max_abs
from kernels.triangle import TriHit
from kernels.types import Hit, SceneData


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
    h.p = q.u * a + q.v * b + (1.0 - q.u - q.v) * c
    h.ng = wp.normalize(wp.cross(b - a, c - a))
    h.ns = h.ng
    h.scale = wp.max(max_abs(a), wp.max(max_abs(b), max_abs(c)))
    h.material = scene.face_material[q.face]
    h.light = scene.face_light[q.face]
    h.sphere = -1
    h.quad = -1
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
    h.light = -1
    h.sphere = i
    h.quad = -1
    return h
