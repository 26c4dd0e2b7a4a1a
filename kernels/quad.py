"""Analytic parallelograms (rectangles and cube faces): a linear loop over a few of them beats the BVH.

A quad is ``center + s half_u + r half_v``, |s|, |r| <= 1, with unit normal ``normal`` (the winding normal of the
two triangles it replaces; the integrator decides sidedness with it, as for triangles). The device stores the dual
basis ``ustar = (half_v x n) / (n . (half_u x half_v))`` and ``vstar = (n x half_u) / (n . (half_u x half_v))``,
so that for a point p on the plane s = (p - center) . ustar and r = (p - center) . vstar.

Precision: the quads are stored in float64 (from the scene's float64 vertices, so adjacent quads share their
corners to float64 rounding) and intersected in float64, with t = ((center - o) . n) / (d . n) and the point relative
to the centre. In float32 the hit point's error along the plane is a few ulps of |o - center| / |d . n|: without a
tolerance about 4% of the rays aimed at a cube's edges from up to 1e3 sizes away slipped between its faces, and a
tolerance that closes that gap grows every quad seen at a grazing angle by as much. In float64 the same error bound
(``err`` below) is ~1e-15 relative, so accepting a ray within it of an edge closes shared edges (box corners, cube
edges) at a negligible growth. On the CPU the float64 loop measured as fast as a float32 one (scalar code either
way; the division is skipped for planes outside the ray's range).
The hit record clamps s, r (a few float32 ulps inside the edges) and rebuilds the point from them, so it lies on the
quad whatever the ray origin; a ray leaving a quad skips that quad (a plane cannot be hit again).

Speed: the quads of one shape (a cube's six faces) form a group with a float64 bounding box padded by 1e-9 of its
size; a ray that misses the box skips the group. Testing quads is most of a ray's cost in the seed's boxes (the
Cornell box renders 1.6x faster without its cube), and most rays miss the block.
"""

import warp as wp

from kernels.mesh import INSIDE_ULPS
from kernels.offset import FLT_EPS
from kernels.types import Hit, SceneData

QUAD_TOL = wp.constant(wp.float64(16.0 * 2.220446049250313e-16))  # bound on the hit point's relative error, x4

# A light wins a tie with a surface coplanar with it (the seed's light sits in its ceiling's plane): its distance
# may exceed the other's by this relative margin, far above the quads' float64 rounding and far below any real gap.
COPLANAR_TOL = wp.constant(wp.float64(1.0e-9))


@wp.struct
class QuadNearest:
    t: wp.float64
    index: int  # -1: no quad hit


@wp.func
def max_abs64(v: wp.vec3d) -> wp.float64:
    return wp.max(wp.abs(v[0]), wp.max(wp.abs(v[1]), wp.abs(v[2])))


@wp.func
def ray_quad(o: wp.vec3d, d: wp.vec3d, center: wp.vec3d, normal: wp.vec3d, ustar: wp.vec3d, vstar: wp.vec3d,
             dual_len: wp.vec2d, tmax: wp.float64) -> wp.float64:
    """Distance t in (0, tmax) to the two-sided parallelogram along the ray o + t d (unit d), or -1 on a miss.
    ``dual_len`` is (|ustar|, |vstar|), stored per quad: most rays that meet a quad's plane miss the quad, and
    their edge tolerance would cost two float64 square roots each."""
    one = wp.float64(1.0)
    dn = wp.dot(d, normal)
    oc = center - o
    num = wp.dot(oc, normal)
    # t = num / dn in (0, tmax), without the division for the many rays that miss the plane's range
    if not (num * dn > wp.float64(0.0) and wp.abs(num) < tmax * wp.abs(dn)):  # also rejects dn = 0 and NaN
        return wp.float64(-1.0)
    t = num / dn
    local = t * d - oc  # hit point relative to the centre
    s = wp.abs(wp.dot(local, ustar))
    r = wp.abs(wp.dot(local, vstar))
    if s <= one and r <= one:
        return t
    # near an edge (or a clear miss): accept within the rounding error of the hit point and of the quad's data
    err = QUAD_TOL * ((max_abs64(oc) + t) / wp.abs(dn) + max_abs64(center))
    if s <= one + QUAD_TOL + err * dual_len[0] and r <= one + QUAD_TOL + err * dual_len[1]:
        return t
    return wp.float64(-1.0)


@wp.func
def quad_hit(scene: SceneData, o: wp.vec3d, d: wp.vec3d, t: wp.float64, i: int) -> Hit:
    """Hit record on quad ``i`` at distance ``t`` (from ``ray_quad``): the point rebuilt from the clamped s, r."""
    c = scene.quad_center[i]
    hu = scene.quad_half_u[i]
    hv = scene.quad_half_v[i]
    local = t * d - (c - o)
    # Kept INSIDE_ULPS float32 ulps inside the edges (as triangle hits are, kernels/mesh.py: inside_point): the
    # float32 point must not round beyond the plane of the adjacent face, or a ray spawned there starts outside it.
    # (A cube of half-size 1e-4 around the camera leaked 32 pixels in 18432 without this.) The limits are the
    # quad's own (``quad_inside``, pathtracer/device_scene.py: quad_inside).
    lim = scene.quad_inside[i]
    s = wp.clamp(wp.dot(local, scene.quad_ustar[i]), -lim[0], lim[0])
    r = wp.clamp(wp.dot(local, scene.quad_vstar[i]), -lim[1], lim[1])
    if lim[0] <= wp.float64(0.5):
        s = wp.float64(0.0)
    if lim[1] <= wp.float64(0.5):
        r = wp.float64(0.0)
    h = Hit()
    h.t = float(t)
    h.p = wp.vec3(c + s * hu + r * hv)
    h.ng = wp.vec3(scene.quad_normal[i])
    h.ns = h.ng
    h.scale = scene.quad_scale[i]
    h.material = scene.quad_material[i]
    h.light = scene.quad_light[i]
    h.sphere = -1
    h.quad = i
    return h


@wp.func
def ray_box(o: wp.vec3d, d: wp.vec3d, lo: wp.vec3d, hi: wp.vec3d, tmax: wp.float64) -> bool:
    """Does the ray o + t d meet the box [lo, hi] for some t in [0, tmax]? (Slab test; a zero direction component
    tests the origin against that slab instead of forming 0 * inf.)"""
    t0 = wp.float64(0.0)
    t1 = tmax
    for k in range(3):
        if d[k] == wp.float64(0.0):
            if o[k] < lo[k] or o[k] > hi[k]:
                return False
        else:
            inv = wp.float64(1.0) / d[k]
            ta = (lo[k] - o[k]) * inv
            tb = (hi[k] - o[k]) * inv
            t0 = wp.max(t0, wp.min(ta, tb))
            t1 = wp.min(t1, wp.max(ta, tb))
    return t0 <= t1


@wp.func
def nearest_quad(scene: SceneData, o: wp.vec3d, d: wp.vec3d, tmax: wp.float64, skip: int) -> QuadNearest:
    """The nearest quad other than ``skip`` hit in (0, tmax); a light wins a tie (within ``COPLANAR_TOL``) with a
    surface in its plane."""
    best = QuadNearest()
    best.t = tmax
    best.index = -1
    best_is_light = bool(False)
    i = int(0)
    while i < scene.num_quads:  # one flat loop (a loop over groups measured 25% slower), skipping missed groups
        end = scene.quad_group_end[i]
        if end > i:
            if not ray_box(o, d, scene.quad_box_lo[i], scene.quad_box_hi[i], best.t * (wp.float64(1.0) + COPLANAR_TOL)):
                i = end
                continue
        if i != skip:
            is_light = scene.quad_light[i] >= 0
            limit = best.t
            if is_light:
                limit = best.t * (wp.float64(1.0) + COPLANAR_TOL)
            elif best_is_light:
                limit = best.t * (wp.float64(1.0) - COPLANAR_TOL)
            tq = ray_quad(o, d, scene.quad_center[i], scene.quad_normal[i], scene.quad_ustar[i], scene.quad_vstar[i],
                          scene.quad_dual_len[i], limit)
            if tq > wp.float64(0.0):
                best.t = tq
                best.index = i
                best_is_light = is_light
        i += 1
    return best


@wp.func
def occluded_quads(scene: SceneData, o: wp.vec3, d: wp.vec3, tmax: float, skip_a: int, skip_b: int) -> bool:
    """Any quad other than ``skip_a``, ``skip_b`` hit in (0, tmax)? (The quad the ray leaves, the light it aims at:
    a segment meets each of those planes only at its end point.)"""
    o64 = wp.vec3d(o)
    d64 = wp.vec3d(d)
    tmax64 = wp.float64(tmax)
    i = int(0)
    while i < scene.num_quads:
        end = scene.quad_group_end[i]
        if end > i:
            if not ray_box(o64, d64, scene.quad_box_lo[i], scene.quad_box_hi[i], tmax64):
                i = end
                continue
        if i != skip_a and i != skip_b:
            if ray_quad(o64, d64, scene.quad_center[i], scene.quad_normal[i], scene.quad_ustar[i],
                        scene.quad_vstar[i], scene.quad_dual_len[i], tmax64) > wp.float64(0.0):
                return True
        i += 1
    return False
