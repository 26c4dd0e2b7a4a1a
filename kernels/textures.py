"""Mitsuba's ``checkerboard`` and ``bitmap`` textures, and the uv coordinates of the surfaces they go on
(docs/mitsuba_semantics/study_bsdfs.md section 6).

uv: a rectangle's is ((x + 1) / 2, (y + 1) / 2) in its local [-1, 1]^2, a cube maps each face onto [0, 1]^2 (both
kept per quad as an affine map of the quad's own coordinates), a sphere's is (phi / 2 pi, theta / pi) in its object
frame, phi = atan2(y, x) in [0, 2 pi), theta = acos(z); a triangle's is interpolated from its three corners' (the
mesh file's texture coordinates, or Mitsuba's barycentric (b1, b2) where it has none).

checkerboard: uv' = to_uv uv; color0 where frac(u') > 0.5 and frac(v') > 0.5 agree, else color1.
bitmap: uv' = to_uv uv; v' = 0 is the image's first (top) row, no flip; bilinear between texel centres
((i + 0.5) / W, (j + 0.5) / H) or nearest (floor(uv' res)), texel indices wrapped by repeat, mirror or clamp.
"""

import warp as wp

from kernels.types import Hit, SceneData


@wp.func
def bilinear(c00: wp.vec3, c10: wp.vec3, c01: wp.vec3, c11: wp.vec3, fx: float, fy: float) -> wp.vec3:
    """Blend of four texels (cxy: x, y offsets 0 or 1) at fractions fx, fy: along x first, as Mitsuba's bitmap
    and envmap lookups (each caller fetches its own texels with its own wrap rule)."""
    top = (1.0 - fx) * c00 + fx * c10
    bottom = (1.0 - fx) * c01 + fx * c11
    return (1.0 - fy) * top + fy * bottom


@wp.func
def surface_uv(scene: SceneData, hit: Hit) -> wp.vec2:
    """Texture coordinates at a hit: on a quad or a sphere from its own map, on a triangle interpolated from its
    corners' (Mitsuba: uv0 b0 + uv1 b1 + uv2 b2)."""
    if hit.quad >= 0:
        q = hit.quad
        rel = wp.vec3d(hit.p) - scene.quad_center[q]
        s = float(wp.dot(rel, scene.quad_ustar[q]))
        r = float(wp.dot(rel, scene.quad_vstar[q]))
        return scene.quad_uv[3 * q] + s * scene.quad_uv[3 * q + 1] + r * scene.quad_uv[3 * q + 2]
    if hit.sphere >= 0:
        i = hit.sphere
        local = scene.sphere_to_local[i] * (hit.p - scene.sphere_center[i])
        local = wp.normalize(local)
        phi = wp.atan2(local[1], local[0])
        if phi < 0.0:
            phi += 2.0 * wp.pi
        return wp.vec2(phi / (2.0 * wp.pi), wp.acos(wp.clamp(local[2], -1.0, 1.0)) / wp.pi)
    f = hit.face
    if 3 * f + 2 >= scene.corner_uv.shape[0]:
        return wp.vec2(0.0, 0.0)  # no triangle texture coordinates (no textured mesh)
    b0 = hit.bary[0]
    b1 = hit.bary[1]
    return b0 * scene.corner_uv[3 * f] + b1 * scene.corner_uv[3 * f + 1] + (1.0 - b0 - b1) * scene.corner_uv[3 * f + 2]


@wp.func
def wrap_index(i: int, n: int, mode: int) -> int:
    if mode == 2:  # clamp
        return wp.clamp(i, 0, n - 1)
    if mode == 1:  # mirror: ... 1 0 | 0 1 ... n-1 | n-1 n-2 ...
        period = 2 * n
        m = i % period
        if m < 0:
            m += period
        if m >= n:
            m = period - 1 - m
        return m
    m = i % n
    if m < 0:
        m += n
    return m


@wp.func
def texel(scene: SceneData, t: int, x: int, y: int) -> wp.vec3:
    size = scene.tex_size[t]
    mode = scene.tex_mode[t][1]
    xi = wrap_index(x, size[0], mode)
    yi = wrap_index(y, size[1], mode)
    return scene.tex_texels[scene.tex_start[t] + yi * size[0] + xi]


@wp.func
def texture_eval(scene: SceneData, t: int, uv: wp.vec2) -> wp.vec3:
    """The value of texture ``t`` at surface coordinates ``uv``."""
    p = wp.vec3(uv[0], uv[1], 1.0)
    u = wp.dot(scene.tex_uv_u[t], p)
    v = wp.dot(scene.tex_uv_v[t], p)
    if scene.tex_kind[t] == 0:
        mu = (u - wp.floor(u)) > 0.5
        mv = (v - wp.floor(v)) > 0.5
        if mu == mv:
            return scene.tex_color0[t]
        return scene.tex_color1[t]
    size = scene.tex_size[t]
    if scene.tex_mode[t][0] == 1:  # nearest
        return texel(scene, t, int(wp.floor(u * float(size[0]))), int(wp.floor(v * float(size[1]))))
    x = u * float(size[0]) - 0.5
    y = v * float(size[1]) - 0.5
    x0 = wp.floor(x)
    y0 = wp.floor(y)
    fx = x - x0
    fy = y - y0
    ix = int(x0)
    iy = int(y0)
    return bilinear(texel(scene, t, ix, iy), texel(scene, t, ix + 1, iy), texel(scene, t, ix, iy + 1),
                    texel(scene, t, ix + 1, iy + 1), fx, fy)
