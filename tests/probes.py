"""Probe kernels: each ``@wp.func`` of ``kernels/`` called from a tiny kernel, results written to arrays.

All probes live in this one module so that Warp compiles them as one module (a cold CPU compile costs seconds
per module). ``launch(kernel, n, device, inputs, outputs)`` is a small convenience wrapper.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from kernels.bsdfs import (fresnel_conductor, fresnel_dielectric, microfacet_d, plastic_diffuse_f, rough_conductor_f,
                           rough_plastic_f, rough_plastic_pdf,
                           rough_conductor_pdf, sample_microfacet)
from kernels.camera import camera_ray
from kernels.film import filter_offset
from kernels.lights import sample_sphere_cone, sample_triangle_light, spot_falloff
from kernels.light_tracer import camera_importance
from kernels.integrator import light_sample_scale, self_mode
from kernels.mesh import mesh_hit, smooth_normal, sphere_hit
from kernels.triangle import ray_shear, ray_triangle
from kernels.triangle_warp import any_mesh_closest as mesh_closest, any_mesh_occluded as mesh_occluded
from kernels.offset import offset_origin
from kernels.quad import nearest_quad, quad_hit, ray_box, ray_quad
from kernels.rng import rand4
from kernels.sampling import (cosine_hemisphere, orthonormal_basis, pick_in_cdf, reflect, sample_cosine_around,
                              sample_parallelogram)
from kernels.sphere import SELF_NONE, ray_sphere
from kernels.textures import surface_uv, texture_eval
from kernels.types import CameraData, Hit, SceneData

INF = wp.constant(3.0e38)


@wp.kernel(enable_backward=False)
def probe_filter_offset(cdf: wp.array(dtype=float), radius: float, pixels: wp.array(dtype=int), size: int,
                        border: int, us: wp.array(dtype=float), out: wp.array(dtype=float)):
    i = wp.tid()
    out[i] = filter_offset(cdf, radius, pixels[i], size, border, us[i])


@wp.kernel(enable_backward=False)
def probe_rand(keys: wp.array(dtype=wp.vec3ui), dims: wp.array(dtype=wp.uint32), out: wp.array(dtype=wp.vec4)):
    i = wp.tid()
    out[i] = rand4(keys[i], dims[i])


@wp.kernel(enable_backward=False)
def probe_sampling(
    ns: wp.array(dtype=wp.vec3),
    ds: wp.array(dtype=wp.vec3),
    us: wp.array(dtype=wp.vec4),
    center: wp.vec3,
    half_u: wp.vec3,
    half_v: wp.vec3,
    albedo: float,
    basis: wp.array(dtype=wp.mat33),
    cos_dir: wp.array(dtype=wp.vec3),
    around: wp.array(dtype=wp.vec3),
    par: wp.array(dtype=wp.vec3),
    refl: wp.array(dtype=wp.vec3),
    weight: wp.array(dtype=float),
):
    i = wp.tid()
    n = ns[i]
    u = us[i]
    basis[i] = orthonormal_basis(n)
    cos_dir[i] = cosine_hemisphere(u[0], u[1])
    wi = sample_cosine_around(n, u[0], u[1])
    around[i] = wi
    par[i] = sample_parallelogram(center, half_u, half_v, u[2], u[3])
    refl[i] = reflect(ds[i], n)
    # Lambertian estimator weight f cos / pdf with pdf = cos / pi: should be exactly the albedo
    c = wp.dot(n, wi)
    weight[i] = (albedo / wp.pi) * c / (c / wp.pi)


@wp.kernel(enable_backward=False)
def probe_camera_importance(
    cam: CameraData,
    p: wp.array(dtype=wp.vec3),
    ng: wp.array(dtype=wp.vec3),
    out: wp.array(dtype=wp.vec4),
):
    i = wp.tid()
    f = camera_importance(cam, p[i], ng[i])
    out[i] = wp.vec4(float(f.pixel), f.weight, f.near, 0.0)  # (the test's pixels stay far below 2^24)


@wp.kernel(enable_backward=False)
def probe_camera(
    cam: CameraData,
    cols: wp.array(dtype=wp.int32),
    rows: wp.array(dtype=wp.int32),
    jit: wp.array(dtype=wp.vec2),
    out_o: wp.array(dtype=wp.vec3),
    out_d: wp.array(dtype=wp.vec3),
    out_tmax: wp.array(dtype=float),
):
    i = wp.tid()
    r = camera_ray(cam, cols[i], rows[i], jit[i][0], jit[i][1])
    out_o[i] = r.o
    out_d[i] = r.d
    out_tmax[i] = r.tmax


@wp.kernel(enable_backward=False)
def probe_sphere(
    o: wp.array(dtype=wp.vec3),
    d: wp.array(dtype=wp.vec3),
    center: wp.array(dtype=wp.vec3),
    radius: wp.array(dtype=float),
    tmax: wp.array(dtype=float),
    mode: wp.array(dtype=wp.int32),
    out_t: wp.array(dtype=float),
):
    i = wp.tid()
    out_t[i] = ray_sphere(o[i], d[i], center[i], radius[i], tmax[i], mode[i])


@wp.kernel(enable_backward=False)
def probe_mesh(
    scene: SceneData,
    o: wp.array(dtype=wp.vec3),
    d: wp.array(dtype=wp.vec3),
    out_face: wp.array(dtype=wp.int32),
    out_t: wp.array(dtype=float),
    out_uv: wp.array(dtype=wp.vec2),
    out_p: wp.array(dtype=wp.vec3),
    out_ng: wp.array(dtype=wp.vec3),
    out_ns: wp.array(dtype=wp.vec3),
):
    i = wp.tid()
    q = mesh_closest(scene, o[i], d[i], INF)
    if q.face >= 0:
        h = mesh_hit(scene, o[i], d[i], q)
        out_face[i] = q.face
        out_t[i] = h.t
        out_uv[i] = wp.vec2(q.u, q.v)
        out_p[i] = h.p
        out_ng[i] = h.ng
        out_ns[i] = smooth_normal(scene, q.face, q.u, q.v, h.ng)
    else:
        out_face[i] = -1
        out_t[i] = -1.0


@wp.kernel(enable_backward=False)
def probe_ray_triangle(
    o: wp.array(dtype=wp.vec3),
    d: wp.array(dtype=wp.vec3),
    a: wp.array(dtype=wp.vec3),
    b: wp.array(dtype=wp.vec3),
    c: wp.array(dtype=wp.vec3),
    tmax: wp.array(dtype=float),
    out_tuv: wp.array(dtype=wp.vec3),
    out_box_dir: wp.array(dtype=wp.vec3),
):
    i = wp.tid()
    r = ray_shear(d[i])
    out_tuv[i] = ray_triangle(o[i], r, a[i], b[i], c[i], tmax[i])
    out_box_dir[i] = r.box_dir


@wp.kernel(enable_backward=False)
def probe_respawn_mesh(
    scene: SceneData,
    o: wp.array(dtype=wp.vec3),
    d: wp.array(dtype=wp.vec3),
    w: wp.array(dtype=wp.vec3),
    use_offset: int,
    out_face: wp.array(dtype=wp.int32),
    out_face2: wp.array(dtype=wp.int32),
    out_t2: wp.array(dtype=float),
):
    """Hit a triangle, spawn a ray toward ``w`` from the offset hit point (the bare point if ``use_offset`` is 0),
    report what it hits first."""
    i = wp.tid()
    out_face[i] = -1
    out_face2[i] = -1
    out_t2[i] = -1.0
    q = mesh_closest(scene, o[i], d[i], INF)
    if q.face >= 0:
        h = mesh_hit(scene, o[i], d[i], q)
        out_face[i] = q.face
        o2 = h.p
        if use_offset != 0:
            o2 = offset_origin(h.p, h.ng, h.scale, w[i])
        q2 = mesh_closest(scene, o2, w[i], INF)
        if q2.face >= 0:
            out_face2[i] = q2.face
            out_t2[i] = q2.t


@wp.kernel(enable_backward=False)
def probe_respawn_sphere(
    scene: SceneData,
    o: wp.array(dtype=wp.vec3),
    d: wp.array(dtype=wp.vec3),
    idx: wp.array(dtype=wp.int32),
    w: wp.array(dtype=wp.vec3),
    out_t: wp.array(dtype=float),
    out_p: wp.array(dtype=wp.vec3),
    out_ng: wp.array(dtype=wp.vec3),
    out_t2: wp.array(dtype=float),
    out_t2_none: wp.array(dtype=float),
):
    """Hit sphere ``idx``, spawn toward ``w`` as the integrator does (offset + self mode) and re-intersect it:
    ``out_t2`` with the integrator's self mode, ``out_t2_none`` with the offset alone."""
    i = wp.tid()
    k = idx[i]
    c = scene.sphere_center[k]
    r = scene.sphere_radius[k]
    t = ray_sphere(o[i], d[i], c, r, INF, SELF_NONE)
    out_t[i] = t
    out_t2[i] = -2.0
    out_t2_none[i] = -2.0
    if t >= 0.0:
        h = sphere_hit(scene, o[i], d[i], t, k)
        out_p[i] = h.p
        out_ng[i] = h.ng
        o2 = offset_origin(h.p, h.ng, h.scale, w[i])
        out_t2[i] = ray_sphere(o2, w[i], c, r, INF, self_mode(k, k, h.ng, w[i]))
        out_t2_none[i] = ray_sphere(o2, w[i], c, r, INF, SELF_NONE)


@wp.kernel(enable_backward=False)
def probe_shadow(
    scene: SceneData,
    o: wp.array(dtype=wp.vec3),
    d: wp.array(dtype=wp.vec3),
    uv: wp.array(dtype=wp.vec2),
    out_status: wp.array(dtype=wp.int32),
):
    """The integrator's shadow segment from a surface hit to a sample on light 0.

    status: -1 no usable pair (missed, hit the light, or the pair faces away), 0 visible, 1 occluded.
    """
    i = wp.tid()
    out_status[i] = -1
    q = mesh_closest(scene, o[i], d[i], INF)
    if q.face < 0:
        return
    h = mesh_hit(scene, o[i], d[i], q)
    if h.light >= 0:
        return
    ng = h.ng
    if wp.dot(d[i], ng) > 0.0:
        ng = -ng
    y = sample_parallelogram(scene.light_center[0], scene.light_half_u[0], scene.light_half_v[0], uv[i][0], uv[i][1])
    to_y = y - h.p
    w = wp.normalize(to_y)
    ln = scene.light_normal[0]
    if wp.dot(ng, w) <= 0.0 or wp.dot(ln, w) >= 0.0:
        return
    so = offset_origin(h.p, ng, h.scale, w)
    se = offset_origin(y, ln, light_sample_scale(scene, 0), -w)
    seg = se - so
    seg_len = wp.length(seg)
    out_status[i] = wp.where(mesh_occluded(scene, so, seg / seg_len, seg_len), 1, 0)


@wp.kernel(enable_backward=False)
def probe_occluded(
    scene: SceneData,
    o: wp.array(dtype=wp.vec3),
    d: wp.array(dtype=wp.vec3),
    tmax: wp.array(dtype=float),
    out_occluded: wp.array(dtype=wp.int32),
    out_t: wp.array(dtype=float),
):
    """The shadow-ray query within tmax, next to the nearest hit's distance (-1 if none) of the same ray."""
    i = wp.tid()
    out_occluded[i] = wp.where(mesh_occluded(scene, o[i], d[i], tmax[i]), 1, 0)
    q = mesh_closest(scene, o[i], d[i], INF)
    out_t[i] = wp.where(q.face >= 0, q.t, -1.0)


@wp.kernel(enable_backward=False)
def probe_ray_box(
    o: wp.array(dtype=wp.vec3d),
    d: wp.array(dtype=wp.vec3d),
    lo: wp.array(dtype=wp.vec3d),
    hi: wp.array(dtype=wp.vec3d),
    tmax: wp.array(dtype=wp.float64),
    out: wp.array(dtype=wp.int32),
):
    i = wp.tid()
    out[i] = wp.where(ray_box(o[i], d[i], lo[i], hi[i], tmax[i]), 1, 0)


@wp.kernel(enable_backward=False)
def probe_quads(
    scene: SceneData,
    o: wp.array(dtype=wp.vec3),
    d: wp.array(dtype=wp.vec3),
    w: wp.array(dtype=wp.vec3),
    direct: wp.array(dtype=wp.int32),
    tmax: wp.array(dtype=float),
    out_t_direct: wp.array(dtype=float),
    out_q: wp.array(dtype=wp.int32),
    out_t: wp.array(dtype=float),
    out_p: wp.array(dtype=wp.vec3),
    out_self_t: wp.array(dtype=float),
    out_q2: wp.array(dtype=wp.int32),
):
    """Quads (kernels/quad.py): ``ray_quad`` against quad ``direct[i]`` with ``tmax[i]`` (t_direct); the nearest quad
    over all (``nearest_quad``: q, t, p from ``quad_hit``); then, as the integrator spawns, a ray toward ``w`` from the offset hit point:
    ``self_t`` is ray_quad on the same quad with no skip (should miss), ``q2`` the nearest quad skipping it."""
    i = wp.tid()
    k = direct[i]
    o64 = wp.vec3d(o[i])
    d64 = wp.vec3d(d[i])
    out_t_direct[i] = float(ray_quad(o64, d64, scene.quad_center[k], scene.quad_normal[k], scene.quad_ustar[k],
                               scene.quad_vstar[k], scene.quad_dual_len[k], wp.float64(tmax[i])))
    nq = nearest_quad(scene, o64, d64, wp.float64(float(INF)), -1)
    best = nq.index
    t_best = nq.t
    out_q[i] = best
    out_t[i] = -1.0
    out_self_t[i] = -2.0
    out_q2[i] = -2
    if best >= 0:
        h = quad_hit(scene, o64, d64, t_best, best)
        out_t[i] = h.t
        out_p[i] = h.p
        o2 = offset_origin(h.p, h.ng, h.scale, w[i])
        o2_64 = wp.vec3d(o2)
        w64 = wp.vec3d(w[i])
        out_self_t[i] = float(ray_quad(o2_64, w64, scene.quad_center[best], scene.quad_normal[best],
                                       scene.quad_ustar[best], scene.quad_vstar[best], scene.quad_dual_len[best],
                                       wp.float64(INF)))
        out_q2[i] = nearest_quad(scene, o2_64, w64, wp.float64(float(INF)), best).index


# ------------------------------------------------------------------------------------------------


def arr(a, dtype, device):
    """numpy -> wp.array (float32/int32/uint32 as the dtype needs)."""
    if dtype in (wp.vec3, wp.vec4, wp.vec2, float, wp.mat33):
        a = np.ascontiguousarray(a, dtype=np.float32)
    elif dtype in (wp.int32,):
        a = np.ascontiguousarray(a, dtype=np.int32)
    elif dtype in (wp.uint32, wp.vec3ui):
        a = np.ascontiguousarray(a, dtype=np.uint32)
    return wp.array(a, dtype=dtype, device=device)


def launch(kernel, n: int, device: str, inputs: list, outputs: list):
    """Launch ``kernel`` over n threads; ``outputs`` lists the dtypes of its output arrays (length n each).

    Returns numpy copies of the outputs (one array, or a list of them).
    """
    outs = [wp.zeros(n, dtype=dtype, device=device) for dtype in outputs]
    wp.launch(kernel, dim=n, inputs=inputs, outputs=outs, device=device)
    wp.synchronize_device(device)
    res = [o.numpy().copy() for o in outs]
    return res[0] if len(res) == 1 else res


@wp.kernel(enable_backward=False)
def probe_lights(x: wp.vec3, c: wp.vec3, r: float, us: wp.array(dtype=wp.vec2), cos_t: wp.array(dtype=float),
                 cone_p: wp.array(dtype=wp.vec3), cone_n: wp.array(dtype=wp.vec3), cone_inv: wp.array(dtype=float),
                 falloff: wp.array(dtype=float), tri_p: wp.array(dtype=wp.vec3), cdf: wp.array(dtype=float),
                 picked: wp.array(dtype=int)):
    i = wp.tid()
    es = sample_sphere_cone(x, c, r, us[i][0], us[i][1])
    cone_p[i] = es.p
    cone_n[i] = es.n
    cone_inv[i] = es.inv_pdf
    falloff[i] = spot_falloff(cos_t[i], wp.cos(wp.radians(20.0)), wp.radians(20.0), wp.radians(15.0),
                              wp.cos(wp.radians(15.0)))
    t = sample_triangle_light(x, wp.vec3(0.0), wp.vec3(1.0, 0.0, 0.0), wp.vec3(0.0, 1.0, 0.0), wp.vec3(0.0, 0.0, 1.0),
                              0.5, us[i][0], us[i][1])
    tri_p[i] = t.p
    picked[i] = pick_in_cdf(cdf, 1, 3, us[i][0])


@wp.kernel(enable_backward=False)
def probe_microfacet(wi: wp.vec3, alpha: float, dist: int, eta: wp.vec3, k: wp.vec3, us: wp.array(dtype=wp.vec2),
                     dirs: wp.array(dtype=wp.vec3), m_out: wp.array(dtype=wp.vec3), sample_w: wp.array(dtype=wp.vec3),
                     f_cos: wp.array(dtype=wp.vec3), pdf: wp.array(dtype=float), d_cos: wp.array(dtype=float)):
    """Per thread: a sampled normal and its reflection's weight f cos / pdf; and, at a given direction, f cos, the
    sampler's density and D(m) cos(m) (m = the direction itself, for normalisation checks)."""
    i = wp.tid()
    m = sample_microfacet(wi, alpha, dist, us[i][0], us[i][1])
    m_out[i] = m
    wo = 2.0 * wp.dot(wi, m) * m - wi
    p = rough_conductor_pdf(wi, wo, alpha, dist)
    if p > 0.0:
        sample_w[i] = rough_conductor_f(wi, wo, alpha, dist, eta, k) * (wo[2] / p)
    w = dirs[i]
    f_cos[i] = rough_conductor_f(wi, w, alpha, dist, eta, k) * wp.max(w[2], 0.0)
    pdf[i] = rough_conductor_pdf(wi, w, alpha, dist)
    d_cos[i] = microfacet_d(w, alpha, dist) * wp.max(w[2], 0.0)


@wp.kernel(enable_backward=False)
def probe_fresnel(cos_i: wp.array(dtype=float), eta: float, ceta: wp.vec3, ck: wp.vec3, f_d: wp.array(dtype=wp.vec3),
                  f_c: wp.array(dtype=wp.vec3), plastic: wp.array(dtype=wp.vec3)):
    """Dielectric (F, cos_t, eta_ti), conductor reflectance and plastic's diffuse lobe (cos_o = cos_i)."""
    i = wp.tid()
    fr = fresnel_dielectric(cos_i[i], eta)
    f_d[i] = wp.vec3(fr.F, fr.cos_t, fr.eta_ti)
    f_c[i] = fresnel_conductor(cos_i[i], ceta, ck)
    plastic[i] = plastic_diffuse_f(cos_i[i], cos_i[i], eta, wp.vec3(0.5), 0.5904789, 0)


@wp.kernel(enable_backward=False)
def probe_textures(scene: SceneData, quad: wp.array(dtype=wp.int32), sphere: wp.array(dtype=wp.int32),
                   p: wp.array(dtype=wp.vec3), face: wp.array(dtype=wp.int32), bary: wp.array(dtype=wp.vec2),
                   tex: wp.array(dtype=wp.int32), uv_in: wp.array(dtype=wp.vec2),
                   uv_out: wp.array(dtype=wp.vec2), value: wp.array(dtype=wp.vec3)):
    """surface_uv at point p[i] of quad[i] or sphere[i] (else at barycentrics bary[i] of triangle face[i]);
    texture tex[i] at uv_in[i]."""
    i = wp.tid()
    hit = Hit()
    hit.p = p[i]
    hit.quad = quad[i]
    hit.sphere = sphere[i]
    hit.face = face[i]
    hit.bary = bary[i]
    uv_out[i] = surface_uv(scene, hit)
    value[i] = texture_eval(scene, tex[i], uv_in[i])


@wp.kernel(enable_backward=False)
def probe_rough_plastic(wi: wp.array(dtype=wp.vec3), wo: wp.array(dtype=wp.vec3), alpha: float, dist: int,
                        eta: float, diffuse: wp.vec3, internal: float, t_i: wp.array(dtype=float),
                        t_o: wp.array(dtype=float), p_coat: wp.array(dtype=float), f_cos: wp.array(dtype=wp.vec3),
                        pdf: wp.array(dtype=float)):
    i = wp.tid()
    f_cos[i] = rough_plastic_f(wi[i], wo[i], alpha, dist, eta, diffuse, wp.vec3(1.0), internal, 0, t_i[i],
                               t_o[i]) * wp.max(wo[i][2], 0.0)
    pdf[i] = rough_plastic_pdf(wi[i], wo[i], alpha, dist, p_coat[i])
