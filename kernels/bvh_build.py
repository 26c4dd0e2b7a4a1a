"""Per-primitive steps of building the triangle tree for millions of triangles (pathtracer/bvh.py and
pathtracer/device_scene.py), one thread per primitive: what numpy did with several full-size temporaries."""

import warp as wp

MORTON_SCALE = wp.constant(2097151.0)  # 2^21 - 1: 21 bits per axis


@wp.func
def spread_bits(x: wp.uint64) -> wp.uint64:
    """The 21 low bits of x moved to every third bit position."""
    x = x & wp.uint64(0x1FFFFF)
    x = (x | (x << wp.uint64(32))) & wp.uint64(0x1F00000000FFFF)
    x = (x | (x << wp.uint64(16))) & wp.uint64(0x1F0000FF0000FF)
    x = (x | (x << wp.uint64(8))) & wp.uint64(0x100F00F00F00F00F)
    x = (x | (x << wp.uint64(4))) & wp.uint64(0x10C30C30C30C30C3)
    x = (x | (x << wp.uint64(2))) & wp.uint64(0x1249249249249249)
    return x


@wp.func
def quantise(c: wp.float64, lo: wp.float64, inv_extent: wp.float64) -> wp.uint64:
    q = (c - lo) * inv_extent * wp.float64(MORTON_SCALE)
    q = wp.max(wp.float64(0.0), wp.min(q, wp.float64(MORTON_SCALE)))
    return wp.uint64(q)


@wp.kernel(enable_backward=False)
def morton_codes(
    lower: wp.array(dtype=wp.vec3),
    upper: wp.array(dtype=wp.vec3),
    lo: wp.vec3d,  # the box centres' bounding box
    inv_extent: wp.vec3d,
    # output
    codes: wp.array(dtype=wp.uint64),
):
    i = wp.tid()
    c = wp.float64(0.5) * (wp.vec3d(lower[i]) + wp.vec3d(upper[i]))
    x = spread_bits(quantise(c[0], lo[0], inv_extent[0]))
    y = spread_bits(quantise(c[1], lo[1], inv_extent[1]))
    z = spread_bits(quantise(c[2], lo[2], inv_extent[2]))
    codes[i] = (x << wp.uint64(2)) | (y << wp.uint64(1)) | z


@wp.kernel(enable_backward=False)
def leaf_soa(
    points: wp.array(dtype=wp.vec3),
    faces: wp.array(dtype=wp.int32),  # 3 per face
    lanes: wp.array(dtype=wp.int32),  # 4 per leaf block: its faces, -1 for an unused lane
    # output
    soa: wp.array(dtype=wp.vec4),  # 9 per leaf block: corner k's axis a of its four triangles at 3 k + a
):
    leaf = wp.tid()
    nan = wp.float32(wp.nan)
    for corner in range(3):
        x = wp.vec4(nan)
        y = wp.vec4(nan)
        z = wp.vec4(nan)
        for lane in range(4):
            f = lanes[4 * leaf + lane]
            if f >= 0:
                p = points[faces[3 * f + corner]]
                x[lane] = p[0]
                y[lane] = p[1]
                z[lane] = p[2]
        soa[9 * leaf + 3 * corner + 0] = x
        soa[9 * leaf + 3 * corner + 1] = y
        soa[9 * leaf + 3 * corner + 2] = z


@wp.func
def box_area(lo: wp.vec3d, hi: wp.vec3d) -> wp.float64:
    e = hi - lo
    return e[0] * e[1] + e[1] * e[2] + e[2] * e[0]


@wp.kernel(enable_backward=False)
def sah_sweep(
    order: wp.array(dtype=wp.int32),  # box indices, each range sorted along one axis
    lower: wp.array(dtype=wp.vec3),
    upper: wp.array(dtype=wp.vec3),
    starts: wp.array(dtype=wp.int32),  # one range per thread (its first entry in order), at least 2 boxes
    sizes: wp.array(dtype=wp.int32),
    block: int,  # boxes per leaf block
    scratch: wp.array(dtype=wp.float64),  # as long as order: the left sides' areas
    # output
    cost: wp.array(dtype=wp.float64),
    cut: wp.array(dtype=wp.int32),
):
    """The cheapest cut of each range in its order: area(left) x blocks(left) + area(right) x blocks(right), where
    blocks counts the leaf blocks a side needs at least (so a cut that leaves blocks part-empty pays for it). Areas in
    float64: float32 boxes can hold areas float32 cannot. Among equal costs the most balanced cut wins."""
    r = wp.tid()
    s = starts[r]
    m = sizes[r]
    big = wp.float64(1.0e300)
    lo = wp.vec3d(big, big, big)
    hi = wp.vec3d(-big, -big, -big)
    for j in range(m - 1):
        p = order[s + j]
        lo = wp.min(lo, wp.vec3d(lower[p]))
        hi = wp.max(hi, wp.vec3d(upper[p]))
        scratch[s + j] = box_area(lo, hi)
    lo = wp.vec3d(big, big, big)
    hi = wp.vec3d(-big, -big, -big)
    best = wp.float64(big)
    best_k = m / 2
    fb = wp.float64(block)
    for j in range(m - 1, 0, -1):  # the right side holds positions j .. m - 1
        p = order[s + j]
        lo = wp.min(lo, wp.vec3d(lower[p]))
        hi = wp.max(hi, wp.vec3d(upper[p]))
        c = scratch[s + j - 1] * wp.ceil(wp.float64(j) / fb) + box_area(lo, hi) * wp.ceil(wp.float64(m - j) / fb)
        c = c * (wp.float64(1.0) + wp.float64(1.0e-12) * wp.float64(wp.abs(2 * j - m)))
        if c < best:  # j boxes on the left
            best = c
            best_k = j
    cost[r] = best
    cut[r] = best_k
