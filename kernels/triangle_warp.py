"""Triangle hits through Warp's own ``wp.Mesh`` BVH (``wp.mesh_query_ray``): the "warp" triangle backend.

The user's design names it, so it is kept as an option (``triangles="warp"``), with the same ``TriHit`` contract as
``kernels.triangle``'s 4-wide tree. It is not the default on the CPU: Warp 1.19's slab test has no rounding slack,
so rays aimed exactly at a vertex can slip between the faces around it (``examples/bench_rays.py`` counts them),
and it traces fewer rays per second there.
"""

import warp as wp

from kernels.triangle import TriHit, mesh_closest, mesh_occluded
from kernels.types import SceneData


@wp.func
def warp_mesh_closest(scene: SceneData, o: wp.vec3, d: wp.vec3, tmax: float) -> TriHit:
    """The nearest hit of ``scene.mesh_id`` in 0 <= t < tmax (unit d); ``face`` -1 if none. u weights the face's
    vertex 0 and v its vertex 1, as in ``kernels.triangle``."""
    q = wp.mesh_query_ray(scene.mesh_id, o, d, tmax)
    best = TriHit()
    best.face = -1
    best.t = tmax
    if q.result and q.t < tmax:
        best.face = q.face
        best.t = q.t
        best.u = q.u
        best.v = q.v
    return best


@wp.func
def warp_mesh_occluded(scene: SceneData, o: wp.vec3, d: wp.vec3, tmax: float) -> bool:
    """Any hit of ``scene.mesh_id`` in 0 <= t < tmax (unit d)?"""
    return wp.mesh_query_ray_anyhit(scene.mesh_id, o, d, tmax)


@wp.func
def any_mesh_closest(scene: SceneData, o: wp.vec3, d: wp.vec3, tmax: float) -> TriHit:
    """Whichever backend the scene was uploaded with (``mesh_id`` set: warp), chosen at run time: for probes and
    tests, which run one kernel over both. The integrator picks one at compile time instead."""
    if scene.mesh_id != wp.uint64(0):
        return warp_mesh_closest(scene, o, d, tmax)
    return mesh_closest(scene, o, d, tmax)


@wp.func
def any_mesh_occluded(scene: SceneData, o: wp.vec3, d: wp.vec3, tmax: float) -> bool:
    if scene.mesh_id != wp.uint64(0):
        return warp_mesh_occluded(scene, o, d, tmax)
    return mesh_occluded(scene, o, d, tmax)
