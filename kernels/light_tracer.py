"""Light tracing for caustics: light -> one or more mirrors -> any bounces -> a diffuse point -> the camera.

A path tracer finds these paths only when a diffuse bounce happens to reflect off the mirrors into the light (the
bright speckles on the walls of the mirror scenes); a light path finds them whenever it leaves the light towards a
mirror. The two estimators split path space instead of weighting each other: with light tracing on, the integrator
leaves out emission reached through mirrors on every path whose first hit is diffuse (``lt_owned`` in
kernels/integrator.py), and this kernel estimates exactly those paths: the light paths that start light -> mirror,
connected to the camera at each of their diffuse points. Every other path stays the integrator's (a caustic seen in
a mirror, camera -> mirror -> diffuse -> mirror -> light, cannot be connected to a pinhole from the light's side).

One light path per thread (``n_paths`` per pass):
- a light chosen uniformly, a point uniform on it, a direction cosine-distributed about its normal: the path
  carries beta = Le |A| pi n_lights (emitted radiance over the density of what was sampled);
- a light path whose first hit is diffuse is dropped (next-event estimation covers it);
- mirrors reflect it as the integrator does (same sidedness rules), with weight rgb |ng . wn| / |ng . wl| (wl towards
  the light, wn the reflection): reflection about the shading normal keeps solid angle but not the projected solid
  angle that carries the flux, so the adjoint of the integrator's rule (radiance times rgb) needs that factor;
- at every diffuse point x after the first mirror the path is connected to the pinhole and adds to the pixel it
  projects to

      beta (rho / pi) (ns . wl) / |ng . wl| |ng . wc| / (d^2 cos^3(theta_c) A_pixel) / n_paths

  with wc towards the camera at distance d, theta_c the angle to the optical axis and A_pixel a pixel's area on the
  film plane at distance 1 (the image is the average radiance over each pixel, box filter). (ns . wl) / |ng . wl|
  turns the particle's flux measure (geometric cosine) into the integrator's shading cosine; the sidedness tests are
  the adjoint of the integrator's;
- then it bounces on, cosine-distributed about ns, with weight rho (ns . wl) |ng . wn| / (|ng . wl| (ns . wn)) (the
  adjoint BSDF with shading normals, Veach's thesis 5.3.2);
- a path has at most max_depth segments counting the camera's, or with unlimited depth roulette after rr_depth
  bounces on the product of the weights.
Splats go to one buffer per pass (atomic adds), folded into sums and sums of squares so that the pass-to-pass spread
of the light-traced part enters the error estimate like the path-traced part's.
"""

import functools

import warp as wp

from kernels.integrator import Features, light_sample_scale, make_tracers
from kernels.offset import offset_origin
from kernels.rng import rand4
from kernels.sampling import reflect, sample_cosine_around, sample_parallelogram
from kernels.types import CameraData, PassParams, SceneData

LIGHT_DIM0 = wp.constant(wp.uint32(0x40000000))  # random dimensions of light paths: apart from the camera paths'


@wp.struct
class FilmPoint:
    pixel: int  # -1: outside the view or the clip range
    weight: float  # |ng . wc| / (d^2 cos^3 theta_c A_pixel)
    near: float  # distance from the pinhole to the near plane along the ray to the point


@wp.func
def camera_importance(cam: CameraData, p: wp.vec3, ng: wp.vec3) -> FilmPoint:
    """Where point ``p`` (geometric normal ``ng``) lands on the film, and the film-area Jacobian that turns a
    particle's flux there into the pixel's average radiance."""
    r = FilmPoint()
    r.pixel = -1
    to_p = p - cam.origin
    d2 = wp.dot(to_p, to_p)
    if d2 <= 0.0:
        return r
    dist = wp.sqrt(d2)
    w = to_p / dist
    local = cam.to_local * w
    lz = wp.length(local)
    if lz <= 0.0:
        return r
    local = local / lz
    if local[2] <= 0.0:
        return r
    depth = dist * local[2]
    if depth < cam.near_clip or depth > cam.far_clip:
        return r
    fx = 0.5 * (1.0 - local[0] / (local[2] * cam.tan_x))
    fy = 0.5 * (1.0 - local[1] / (local[2] * cam.tan_y))
    if not (fx >= 0.0 and fx < 1.0 and fy >= 0.0 and fy < 1.0):
        return r
    col = wp.min(int(fx * float(cam.width)), cam.width - 1)
    row = wp.min(int(fy * float(cam.height)), cam.height - 1)
    a_pixel = 4.0 * cam.tan_x * cam.tan_y / float(cam.width * cam.height)
    cos_c = local[2]
    r.pixel = row * cam.width + col
    r.weight = wp.abs(wp.dot(ng, w)) / (d2 * cos_c * cos_c * cos_c * a_pixel)
    r.near = cam.near_clip / cos_c
    return r


@wp.kernel(enable_backward=False)
def fold_pass(splat: wp.array(dtype=wp.vec3d), lt_sum: wp.array(dtype=wp.vec3d), lt_sum_sq: wp.array(dtype=wp.vec3d)):
    """Add one pass's splats to the sums (and squares) and clear the buffer for the next pass."""
    i = wp.tid()
    v = splat[i]
    lt_sum[i] = lt_sum[i] + v
    lt_sum_sq[i] = lt_sum_sq[i] + wp.cw_mul(v, v)
    splat[i] = wp.vec3d(0.0)


def make_light_kernel(features: Features):
    """The light-tracing kernel for a scene with ``features`` (mirrors and lights)."""
    trace, occluded, _ = make_tracers(features)

    @wp.kernel(enable_backward=False, module=features.module_name("light"))
    def light_pass(
        scene: SceneData,
        cam: CameraData,
        params: PassParams,
        n_paths: int,
        # outputs
        splat: wp.array(dtype=wp.vec3d),
        discarded: wp.array(dtype=wp.int32),
    ):
        tid = wp.tid()
        key = wp.vec3ui(wp.uint32(tid), params.pass_index, params.seed)
        dim = LIGHT_DIM0

        # ---------------- a point on a light, a direction out of it ----------------
        u = rand4(key, dim)
        dim += wp.uint32(1)
        l = wp.min(int(u[0] * float(scene.num_lights)), scene.num_lights - 1)
        ln = scene.light_normal[l]
        y = sample_parallelogram(scene.light_center[l], scene.light_half_u[l], scene.light_half_v[l], u[1], u[2])
        u = rand4(key, dim)
        dim += wp.uint32(1)
        d = sample_cosine_around(ln, u[0], u[1])
        beta = scene.light_radiance[l] * (scene.light_area[l] * wp.pi * float(scene.num_lights))
        o = offset_origin(y, ln, light_sample_scale(scene, l), d)
        origin_quad = int(-1)
        if wp.static(features.quads):
            origin_quad = scene.light_quad[l]
        origin_sphere = int(-1)
        origin_normal = wp.vec3(0.0)
        mirrors = int(0)
        segments = int(1)  # light -> the next hit; the camera segment makes a path of segments + 1
        refl = wp.vec3(1.0)  # the weights' product (over the roulette's survival): what roulette keys on

        while True:
            hit = trace(scene, o, d, 3.0e38, origin_quad, origin_sphere, origin_normal)
            if hit.material < 0:
                return
            mat = hit.material
            front = wp.dot(d, hit.ng) < 0.0
            if not front and scene.mat_twosided[mat] == 0:
                return  # one-sided: black from behind
            ng = hit.ng
            ns = hit.ns
            if not front:
                ng = -ng
                ns = -ns
            wl = -d  # towards the light side
            if wp.dot(ns, wl) <= 0.0 or wp.dot(ng, wl) <= 0.0:
                return  # the shading normal faces away from the light (the integrator's viewer test), or grazing
            # room for another segment beyond this hit and the camera's (the integrator's max_depth)
            go_on = params.max_depth < 0 or segments + 2 <= params.max_depth
            wn = wp.vec3(0.0)
            weight = wp.vec3(0.0)
            if scene.mat_kind[mat] == 1:
                # ---------------- mirror ----------------
                if not go_on:
                    return
                wn = reflect(d, ns)
                if wp.dot(wn, ng) <= 0.0:
                    return
                # the adjoint of the integrator's mirror (radiance times the reflectance about the shading
                # normal): reflection keeps solid angle, not the projected solid angle |ng . w| dw that carries
                # a particle's flux, so the flux gets |ng . wn| / |ng . wl| (1 where ns = ng)
                weight = scene.mat_rgb[mat] * (wp.dot(wn, ng) / wp.dot(wl, ng))
                mirrors += 1
            else:
                # ---------------- diffuse: seen by the camera, then onwards ----------------
                if mirrors == 0:
                    return  # light -> diffuse directly: next-event estimation's share
                albedo = scene.mat_rgb[mat]
                imp = camera_importance(cam, hit.p, hit.ng)
                wc = wp.normalize(cam.origin - hit.p)
                # the camera must be on the side the light arrived on (the integrator's one-sided and shading
                # tests)
                if imp.pixel >= 0 and wp.dot(ng, wc) > 0.0 and wp.dot(ns, wc) > 0.0:
                    so = offset_origin(hit.p, ng, hit.scale, wc)
                    end = cam.origin - wc * imp.near  # the near plane: what lies closer to the pinhole is clipped
                    seg = end - so
                    seg_len = wp.length(seg)
                    if seg_len > 0.0:
                        if not occluded(scene, so, seg / seg_len, seg_len, hit.quad, -1, hit.sphere, hit.ng):
                            value = wp.cw_mul(beta, albedo) * (wp.dot(ns, wl) / wp.dot(ng, wl)
                                                               * imp.weight / (wp.pi * float(n_paths)))
                            if wp.isfinite(value):
                                wp.atomic_add(splat, imp.pixel, wp.vec3d(value))
                            else:
                                wp.atomic_add(discarded, 0, 1)
                if not go_on:
                    return
                u = rand4(key, dim)
                dim += wp.uint32(1)
                wn = sample_cosine_around(ns, u[0], u[1])
                cos_n = wp.dot(wn, ng)
                if cos_n <= 0.0:
                    return
                # f / pdf of the cosine-sampled direction with the adjoint's shading-normal factor
                # |ns . wl| |ng . wn| / (|ng . wl| |ns . wn|) (Veach's thesis, 5.3.2)
                weight = albedo * (wp.dot(ns, wl) * cos_n / (wp.dot(ng, wl) * wp.dot(ns, wn)))
            beta = wp.cw_mul(beta, weight)
            refl = wp.cw_mul(refl, weight)
            segments += 1
            if params.max_depth < 0 and segments > params.rr_depth:
                q_rr = wp.min(wp.max(refl[0], wp.max(refl[1], refl[2])), 0.95)
                u = rand4(key, dim)
                dim += wp.uint32(1)
                if u[0] >= q_rr:
                    return
                beta = beta / q_rr
                refl = refl / q_rr
            o = offset_origin(hit.p, ng, hit.scale, wn)
            d = wn
            origin_quad = hit.quad
            origin_sphere = hit.sphere
            origin_normal = hit.ng

    return light_pass


@functools.cache
def light_kernel(features: Features):
    """The light-tracing kernel for ``features``, built once per process."""
    return make_light_kernel(features)
