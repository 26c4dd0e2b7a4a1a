"""Watertight ray-triangle hits through a box tree (pathtracer/bvh.py) over padded triangle boxes.

Warp's ``mesh_query_ray`` has a watertight triangle test but a slab test with no rounding slack, so a ray through a
vertex that lies on a node box's face can skip the leaf that holds the hit (Warp 1.19: 99 of 34594 rays aimed at
the bunny's vertices). Here the BVH is built over every triangle's box grown by ``pad`` (see
``pathtracer.device_scene.triangle_box_pad``), which exceeds the slab test's rounding error for every ray that starts
within the scene's coordinate range, and the triangle test is Woop, Benthin and Wald's (JCGT 2013): the ray is
sheared so that it runs along +z through the origin, and the three 2D edge functions are computed the same way (up
to sign) for both triangles that share an edge, so that the ray is inside exactly one of them (or on the boundary of
both, which counts as a hit): no ray passes between triangles that share their vertices.
"""

import warp as wp

from kernels.types import SceneData


@wp.struct
class RayShear:
    """Per-ray set-up of the watertight test (computed once per ray, not per triangle)."""

    kx: int  # the permuted axes: kz is the direction's largest component
    ky: int
    kz: int
    s: wp.vec3  # shear (d[kx] / d[kz], d[ky] / d[kz]) and scale 1 / d[kz]
    box_dir: wp.vec3  # the direction given to the box traversal: no exact zeros (its slab test would form 0 * inf)
    inv_box_dir: wp.vec3  # its reciprocal, what the slab test multiplies by


@wp.struct
class TriHit:
    face: int  # -1: no hit
    t: float
    u: float  # barycentric weight of the face's vertex 0
    v: float  # ... of vertex 1


@wp.func
def ray_shear(d: wp.vec3) -> RayShear:
    kz = int(0)
    if wp.abs(d[1]) > wp.abs(d[kz]):
        kz = 1
    if wp.abs(d[2]) > wp.abs(d[kz]):
        kz = 2
    kx = (kz + 1) % 3
    ky = (kx + 1) % 3
    if d[kz] < 0.0:  # keep the winding: a mirror-image permutation would flip every edge function's sign
        tmp = kx
        kx = ky
        ky = tmp
    r = RayShear()
    r.kx = kx
    r.ky = ky
    r.kz = kz
    r.s = wp.vec3(d[kx] / d[kz], d[ky] / d[kz], 1.0 / d[kz])
    bd = d
    for j in range(3):
        if wp.abs(bd[j]) < 1.0e-30:
            bd[j] = 1.0e-30  # bends the ray by < 1e-30 rad, far inside the boxes' padding
    r.box_dir = bd
    r.inv_box_dir = wp.vec3(1.0 / bd[0], 1.0 / bd[1], 1.0 / bd[2])
    return r


@wp.func
def edge_function(ax: float, ay: float, bx: float, by: float) -> float:
    """ax by - ay bx. In float32 it is exactly antisymmetric (swapping the two points negates it bit for bit), so
    two triangles that share an edge always put a ray on opposite sides of it, or both on it; only an exact zero
    is worth a second look, in float64, where both products are exact."""
    e = ax * by - ay * bx
    if e == 0.0:
        e = float(wp.float64(ax) * wp.float64(by) - wp.float64(ay) * wp.float64(bx))
    return e


@wp.func
def ray_triangle(o: wp.vec3, r: RayShear, a: wp.vec3, b: wp.vec3, c: wp.vec3, tmax: float) -> wp.vec3:
    """(t, u, v) of the hit of ray o + t d (the ``RayShear`` of d) with triangle abc in 0 <= t < tmax; t = -1 on a
    miss. u, v weight a and b. Either side counts; a degenerate (zero-area) triangle is never hit."""
    miss = wp.vec3(-1.0, 0.0, 0.0)
    A = a - o
    B = b - o
    C = c - o
    ax = A[r.kx] - r.s[0] * A[r.kz]
    ay = A[r.ky] - r.s[1] * A[r.kz]
    bx = B[r.kx] - r.s[0] * B[r.kz]
    by = B[r.ky] - r.s[1] * B[r.kz]
    cx = C[r.kx] - r.s[0] * C[r.kz]
    cy = C[r.ky] - r.s[1] * C[r.kz]
    U = edge_function(cx, cy, bx, by)
    V = edge_function(ax, ay, cx, cy)
    W = edge_function(bx, by, ax, ay)
    if (U < 0.0 or V < 0.0 or W < 0.0) and (U > 0.0 or V > 0.0 or W > 0.0):
        return miss
    det = U + V + W
    if det == 0.0:
        return miss
    T = U * (r.s[2] * A[r.kz]) + V * (r.s[2] * B[r.kz]) + W * (r.s[2] * C[r.kz])
    if det < 0.0:
        T = -T
        det = -det
    # t = 0 counts, as in Warp's test: a ray spawned exactly on a cube's edge, offset along one face's normal, starts
    # in the adjacent face's plane, and must not leave through that face
    if not (T >= 0.0 and T < tmax * det):  # also rejects NaN
        return miss
    inv = 1.0 / det
    return wp.vec3(T * inv, wp.abs(U) * inv, wp.abs(V) * inv)


@wp.func
def face_triangle_hit(scene: SceneData, f: int, o: wp.vec3, r: RayShear, tmax: float) -> wp.vec3:
    return ray_triangle(o, r, scene.points[scene.indices[3 * f + 0]], scene.points[scene.indices[3 * f + 1]],
                        scene.points[scene.indices[3 * f + 2]], tmax)


STACK_SIZE = 64  # a traversal pushes at most one node per level; pathtracer/bvh.py keeps trees shallower
StackInt = wp.types.vector(length=STACK_SIZE, dtype=wp.int32)
StackFloat = wp.types.vector(length=STACK_SIZE, dtype=wp.float32)


@wp.func
def box_entry(scene: SceneData, node: int, o: wp.vec3, inv_d: wp.vec3, tmax: float) -> float:
    """Where the ray enters node ``node``'s box (0 if it starts inside), or -1 if it misses it within [0, tmax).
    The same float32 slab test as Warp's BVH query (the box padding is sized for its rounding)."""
    lo = scene.bvh_lower[node]
    hi = scene.bvh_upper[node]
    l1 = (lo[0] - o[0]) * inv_d[0]
    l2 = (hi[0] - o[0]) * inv_d[0]
    lmin = wp.min(l1, l2)
    lmax = wp.max(l1, l2)
    l1 = (lo[1] - o[1]) * inv_d[1]
    l2 = (hi[1] - o[1]) * inv_d[1]
    lmin = wp.max(wp.min(l1, l2), lmin)
    lmax = wp.min(wp.max(l1, l2), lmax)
    l1 = (lo[2] - o[2]) * inv_d[2]
    l2 = (hi[2] - o[2]) * inv_d[2]
    lmin = wp.max(wp.min(l1, l2), lmin)
    lmax = wp.min(wp.max(l1, l2), lmax)
    if lmax >= 0.0 and lmax >= lmin and lmin < tmax:
        return wp.max(lmin, 0.0)
    return -1.0


@wp.func
def mesh_closest(scene: SceneData, o: wp.vec3, d: wp.vec3, tmax: float) -> TriHit:
    """The nearest triangle hit in 0 <= t < tmax (unit d); ``face`` -1 if none.

    Nearest-first traversal of the box tree (pathtracer/bvh.py): of a node's two children the nearer is entered
    first and the farther pushed with its entry distance, which is skipped when popped beyond the nearest hit so far.
    """
    r = ray_shear(d)
    inv_d = r.inv_box_dir
    best = TriHit()
    best.face = -1
    best.t = tmax
    if box_entry(scene, 0, o, inv_d, tmax) < 0.0:
        return best
    stack_node = StackInt()
    stack_t = StackFloat()
    sp = int(0)
    node = int(0)
    while True:
        count = scene.bvh_count[node]
        descend = bool(False)
        if count > 0:
            first = scene.bvh_start[node]
            for k in range(count):
                f = scene.bvh_prims[first + k]
                h = face_triangle_hit(scene, f, o, r, best.t)
                if h[0] >= 0.0:
                    best.face = f
                    best.t = h[0]
                    best.u = h[1]
                    best.v = h[2]
        else:
            a = scene.bvh_start[node]  # an inner node's children: bvh_start, bvh_start + 1
            b = a + 1
            ta = box_entry(scene, a, o, inv_d, best.t)
            tb = box_entry(scene, b, o, inv_d, best.t)
            if ta >= 0.0 and tb >= 0.0:
                if tb < ta:
                    tmp = a
                    a = b
                    b = tmp
                    tt = ta
                    ta = tb
                    tb = tt
                stack_node[sp] = b
                stack_t[sp] = tb
                sp += 1
                node = a
                descend = True
            elif ta >= 0.0:
                node = a
                descend = True
            elif tb >= 0.0:
                node = b
                descend = True
        if not descend:
            # pop the next subtree that still starts before the nearest hit
            while sp > 0 and not descend:
                sp -= 1
                if stack_t[sp] < best.t:
                    node = stack_node[sp]
                    descend = True
            if not descend:
                break
    return best


@wp.func
def mesh_occluded(scene: SceneData, o: wp.vec3, d: wp.vec3, tmax: float) -> bool:
    """Any triangle hit in 0 <= t < tmax (unit d)? (Any hit ends the search, so no ordering.)"""
    r = ray_shear(d)
    inv_d = r.inv_box_dir
    if box_entry(scene, 0, o, inv_d, tmax) < 0.0:
        return False
    stack_node = StackInt()
    sp = int(0)
    node = int(0)
    while True:
        count = scene.bvh_count[node]
        if count > 0:
            first = scene.bvh_start[node]
            for k in range(count):
                if face_triangle_hit(scene, scene.bvh_prims[first + k], o, r, tmax)[0] >= 0.0:
                    return True
        else:
            a = scene.bvh_start[node]  # an inner node's children: bvh_start, bvh_start + 1
            b = a + 1
            hit_a = box_entry(scene, a, o, inv_d, tmax) >= 0.0
            hit_b = box_entry(scene, b, o, inv_d, tmax) >= 0.0
            if hit_a and hit_b:
                stack_node[sp] = b
                sp += 1
                node = a
                continue
            if hit_a:
                node = a
                continue
            if hit_b:
                node = b
                continue
        if sp == 0:
            break
        sp -= 1
        node = stack_node[sp]
    return False
