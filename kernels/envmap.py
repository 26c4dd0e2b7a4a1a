"""Mitsuba's ``envmap`` emitter: a latitude-longitude image of the radiance arriving from every direction.

Mapping (src/emitters/envmap.cpp, Mitsuba 3.9.1), for a direction ``v`` in the emitter's frame (to_world^-1 d):
u = atan2(v.x, -v.z) / (2 pi) wrapped to [0, 1), v = acos(v.y) / pi. The radiance is bilinear in the texels
with texel column j centred at u = (j + 0.5) / W (wrapping around in u) and row i at v = i / (H - 1) (the first
row is the +y pole, the last the -y pole, clamped), times ``scale``.

Sampling: a cell of a W x (H - 1) grid over (u, v) is picked from tabulated CDFs (rows, then the column within
the row) in proportion to a bound of its luminance times sin(theta), then (u, v) is uniform in the cell. The
density in solid angle is p_cell W (H - 1) / (2 pi^2 sin(theta)). Any density that is positive wherever the
radiance is gives the same image; this one only decides the noise.
"""

import warp as wp

from kernels.sampling import pick_in_cdf
from kernels.textures import bilinear
from kernels.types import SceneData


@wp.struct
class EnvSample:
    d: wp.vec3  # world direction towards the environment
    pdf: float  # solid-angle density; 0: no sample


@wp.func
def env_texel(scene: SceneData, x: int, y: int) -> wp.vec3:
    w = scene.env_width
    xi = x % w
    if xi < 0:
        xi += w
    yi = wp.clamp(y, 0, scene.env_height - 1)
    return scene.env_image[yi * w + xi]


@wp.func
def env_uv(scene: SceneData, d: wp.vec3) -> wp.vec2:
    v = scene.env_to_local * d
    u = wp.atan2(v[0], -v[2]) * (0.5 / wp.pi)
    u = u - wp.floor(u)
    return wp.vec2(u, wp.acos(wp.clamp(v[1] / wp.length(v), -1.0, 1.0)) / wp.pi)


@wp.func
def env_eval(scene: SceneData, d: wp.vec3) -> wp.vec3:
    """Radiance arriving along -d (seen looking along world direction ``d``)."""
    uv = env_uv(scene, d)
    x = uv[0] * float(scene.env_width) - 0.5
    y = uv[1] * float(scene.env_height - 1)
    x0 = wp.floor(x)
    y0 = wp.floor(y)
    fx = x - x0
    fy = y - y0
    ix = int(x0)
    iy = int(y0)
    return bilinear(env_texel(scene, ix, iy), env_texel(scene, ix + 1, iy), env_texel(scene, ix, iy + 1),
                    env_texel(scene, ix + 1, iy + 1), fx, fy) * scene.env_scale


@wp.func
def env_cell_prob(scene: SceneData, row: int, col: int) -> float:
    """Probability of picking cell (row, col)."""
    rows = scene.env_height - 1
    p_row = scene.env_row_cdf[row]
    if row > 0:
        p_row -= scene.env_row_cdf[row - 1]
    base = row * scene.env_width
    p_col = scene.env_col_cdf[base + col]
    if col > 0:
        p_col -= scene.env_col_cdf[base + col - 1]
    return p_row * p_col


@wp.func
def env_pdf(scene: SceneData, d: wp.vec3) -> float:
    """Solid-angle density of ``env_sample`` at world direction ``d``."""
    uv = env_uv(scene, d)
    rows = scene.env_height - 1
    row = wp.min(int(uv[1] * float(rows)), rows - 1)
    col = wp.min(int(uv[0] * float(scene.env_width)), scene.env_width - 1)
    sin_t = wp.sin(uv[1] * wp.pi)
    if sin_t <= 0.0:
        return 0.0
    return env_cell_prob(scene, row, col) * float(scene.env_width * rows) / (2.0 * wp.pi * wp.pi * sin_t)


@wp.func
def env_sample(scene: SceneData, u1: float, u2: float) -> EnvSample:
    out = EnvSample()
    rows = scene.env_height - 1
    row = pick_in_cdf(scene.env_row_cdf, 0, rows, u1)
    lo = float(0.0)
    if row > 0:
        lo = scene.env_row_cdf[row - 1]
    fu1 = wp.clamp((u1 - lo) / wp.max(scene.env_row_cdf[row] - lo, 1.0e-30), 0.0, 0.99999994)
    base = row * scene.env_width
    col = pick_in_cdf(scene.env_col_cdf, base, scene.env_width, u2) - base
    lo2 = float(0.0)
    if col > 0:
        lo2 = scene.env_col_cdf[base + col - 1]
    fu2 = wp.clamp((u2 - lo2) / wp.max(scene.env_col_cdf[base + col] - lo2, 1.0e-30), 0.0, 0.99999994)
    u = (float(col) + fu2) / float(scene.env_width)
    v = (float(row) + fu1) / float(rows)
    theta = v * wp.pi
    phi = u * 2.0 * wp.pi
    sin_t = wp.sin(theta)
    if sin_t <= 0.0:
        return out
    local = wp.vec3(sin_t * wp.sin(phi), wp.cos(theta), -sin_t * wp.cos(phi))
    out.d = wp.normalize(scene.env_to_world * local)
    out.pdf = env_cell_prob(scene, row, col) * float(scene.env_width * rows) / (2.0 * wp.pi * wp.pi * sin_t)
    return out
