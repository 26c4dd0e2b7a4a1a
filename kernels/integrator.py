"""The path integrator: one kernel body, compiled per scene with only the code that scene needs.

``make_render_kernel(features)`` returns a kernel specialised at compile time (``wp.static``) on which primitives,
materials, view and roulette rule the scene uses; each variant has a small module of its own
(``Features.module_name``) so a new variant never rebuilds another. ``Li`` traces one camera path; the kernel adds one sample per pixel and pass, for a
run of consecutive passes over a tile (a set of rows), into the accumulators.

Estimator (equal in expectation to Mitsuba's ``path`` integrator, which adds MIS):
emission is counted on camera rays and after mirror bounces; at diffuse hits next-event estimation takes K uniform
samples on every rectangle light, and emission found by the following diffuse bounce is not counted again.
Light samples are uniform in area (weight Le cos_x cos_y / d^2 * area / K), or, with ``light_sampling``
"solid_angle", uniform in the solid angle a rectangular light subtends (kernels/sphrect.py; weight
Le cos_x Omega / K), which removes the cos_y / d^2 variance near a light; non-rectangular parallelograms and points
where the solid angle is tiny fall back to area sampling.
With ``light_tracing``, paths camera -> diffuse first hit -> any bounces -> one or more mirrors -> light are left to
the light tracer (kernels/light_tracer.py): their emission is not counted here (``lt_owned``).
"""

# (no ``from __future__ import annotations``: Warp would evaluate every parameter annotation of the functions made
# per variant from its string again; with ``compiled_if`` below, making the Cornell box's kernel took 53 ms instead
# of 64)
import functools
import hashlib
from dataclasses import dataclass

import warp as wp

from kernels.adjoint import ADJ_CAP, adjoint_slot, inverse_reflectance, mat_entries, vec_keys
from kernels.camera import camera_ray, thin_lens_ray
from kernels.envmap import env_eval, env_pdf, env_sample
from kernels.film import filter_offset, srgb_to_xyz
from kernels.lights import sample_sphere_cone, sample_triangle_light, sphere_cone_pdf, spot_falloff
from kernels.materials import MAT_CONDUCTOR, MAT_DIELECTRIC, MAT_DIFFUSE, MAT_THIN_DIELECTRIC, make_materials
from kernels.mesh import mesh_hit, smooth_normal, sphere_hit
from kernels.triangle import mesh_closest, mesh_occluded
from kernels.triangle_warp import warp_mesh_closest, warp_mesh_occluded
from kernels.offset import FLT_EPS, max_abs, offset_origin
from kernels.quad import nearest_quad, occluded_quads, quad_hit
from kernels.textures import surface_uv, texture_eval
from kernels.sobol import independent4, padded_sobol4, replicate_seed
from kernels.sampling import pick_in_cdf, reflect, sample_cosine_around, sample_parallelogram
from kernels.sphrect import sample_spherical_rectangle
from kernels.sphere import SELF_FAR, SELF_NONE, SELF_SKIP, ray_sphere
from kernels.types import Adjoint, CameraData, Hit, PassParams, SceneData

VIEW_RADIANCE = 0
VIEW_DIRECTION = 1
VIEW_NORMAL = 2
VIEWS = {"radiance": VIEW_RADIANCE, "direction": VIEW_DIRECTION, "normal": VIEW_NORMAL}

RR_NONE = 0
RR_SEED = 1  # the seed's rule: after the first bounce stop with probability 0.2, survivors / 0.8
RR_THROUGHPUT = 2  # Mitsuba's: from rr_depth on, continue with probability min(max(beta), 0.95)
RR_RULES = {"none": RR_NONE, "seed": RR_SEED, "throughput": RR_THROUGHPUT}

SAMPLER_INDEPENDENT = 0  # pcg4d hash of (pixel, pass, seed, dim): independent uniforms
SAMPLER_SOBOL = 1  # Owen-scrambled, shuffled Sobol' points indexed by pass (stratified across passes) at the first
# two path vertices, independent deeper (kernels/sobol.py: padded_sobol4)
SAMPLERS = {"independent": SAMPLER_INDEPENDENT, "sobol": SAMPLER_SOBOL}

LIGHT_AREA = 0  # next-event samples uniform in the light's area
LIGHT_SOLID_ANGLE = 1  # uniform in the solid angle of rectangular lights (Urena et al. 2013), area otherwise
LIGHT_SAMPLINGS = {"area": LIGHT_AREA, "solid_angle": LIGHT_SOLID_ANGLE}

TRIANGLES_WIDE = 0  # our 4-wide box tree over padded boxes, watertight (kernels/triangle.py)
TRIANGLES_WARP = 1  # Warp's wp.Mesh and mesh_query_ray (kernels/triangle_warp.py)
TRIANGLES = {"wide": TRIANGLES_WIDE, "warp": TRIANGLES_WARP}

SEED_RR_LAMBDA = wp.constant(0.2)
INF = wp.constant(3.0e38)


@dataclass(frozen=True)
class Features:
    """What one compiled variant contains. Two scenes with equal features share a kernel."""

    meshes: bool  # triangles in the BVH
    spheres: bool
    mirrors: bool
    smooth_normals: bool
    lights: bool
    quads: bool = False  # analytic parallelograms (rectangles, cube faces)
    view: int = VIEW_RADIANCE
    rr: int = RR_THROUGHPUT
    sampler: int = SAMPLER_INDEPENDENT
    light_sampling: int = LIGHT_AREA
    count_rays: bool = False  # instrumented variant for benchmarks: counts closest-hit and shadow rays
    light_tracing: bool = False  # caustics seen directly are left to the light tracer (kernels/light_tracer.py)
    triangles: int = TRIANGLES_WIDE  # the triangle backend
    pixel_filter: bool = False  # film offsets drawn from a tabulated filter (kernels/film.py); False: box
    thin_lens: bool = False  # Mitsuba's thinlens camera (depth of field) instead of the pinhole
    # emitters other than parallelograms (``lights``), each compiled in only where the scene has one (kernels/lights.py)
    sphere_lights: bool = False
    mesh_lights: bool = False
    point_lights: bool = False
    spot_lights: bool = False
    directional_lights: bool = False
    environment: bool = False  # Mitsuba's constant emitter
    envmap: bool = False  # Mitsuba's envmap (kernels/envmap.py)
    textures: bool = False  # reflectances given by textures (kernels/textures.py)
    # BSDFs other than diffuse and mirror (kernels/materials.py), each compiled in only where the scene has one
    dielectrics: bool = False
    thin_dielectrics: bool = False
    conductors: bool = False
    plastics: bool = False
    rough_conductors: bool = False
    rough_plastics: bool = False
    moments: bool = False  # Mitsuba's moment integrator: also sum each sample's squared XYZ (kernels/film.py)
    adaptive: bool = False  # per-pixel pass limits (adaptive sampling, pathtracer/adaptive.py)
    gradient: bool = False  # forward-mode derivatives of each path's radiance (pathtracer/gradients.py)
    backward: bool = False  # path replay: every reflectance's and radiance's adjoint at once (pathtracer/gradients.py)

    def module_name(self, kind: str) -> str:
        """A Warp module name of its own for this variant's ``kind`` of kernel. Named, not ``module="unique"``:
        Warp names a unique module by hashing the kernel and every function it calls when the kernel is defined,
        then hashes it all again when it loads (0.04 s each for the render kernel); a name from the features
        leaves only the load's hash, which keys the disk cache on the code itself."""
        return f"pathtracer_{kind}_{hashlib.sha256(repr(self).encode()).hexdigest()[:16]}"

    @property
    def other_materials(self) -> bool:
        """Any BSDF but diffuse and mirror?"""
        return (self.dielectrics or self.thin_dielectrics or self.conductors or self.plastics or self.rough_conductors
                or self.rough_plastics)


@wp.struct
class PathSample:
    L: wp.vec3  # radiance along one camera path
    rays: wp.int64  # rays it traced (counted only in the instrumented variant)
    dL: wp.vec3  # gradient variants: dL/dtheta, the tangent 1 in each of theta's three channels
    replay: bool  # backward variants: the path met too many parameters for one pass (kernels/adjoint.py)


@wp.func
def self_mode(origin_sphere: int, i: int, origin_normal: wp.vec3, d: wp.vec3) -> int:
    """How sphere ``i`` treats a ray that started on sphere ``origin_sphere`` with outward normal there."""
    if i != origin_sphere:
        return SELF_NONE
    if wp.dot(d, origin_normal) > 0.0:
        return SELF_SKIP
    return SELF_FAR


@wp.func
def occluded_spheres(
    scene: SceneData, o: wp.vec3, d: wp.vec3, tmax: float, origin_sphere: int, origin_normal: wp.vec3
) -> bool:
    """Any sphere hit in [0, tmax) of the shadow ray?"""
    for i in range(scene.num_spheres):
        if ray_sphere(o, d, scene.sphere_center[i], scene.sphere_radius[i], tmax, self_mode(origin_sphere, i, origin_normal, d)) >= 0.0:
            return True
    return False


@wp.func
def light_sample_scale(scene: SceneData, light: int) -> float:
    """Coordinate magnitude of points on light ``light`` (for offsetting shadow-ray ends)."""
    return max_abs(scene.light_center[light]) + wp.length(scene.light_half_u[light]) + wp.length(scene.light_half_v[light])


def make_tracers(features: Features):
    """(trace, occluded): nearest hit and shadow test over exactly the primitive kinds in ``features``."""
    HAS_MESH = features.meshes
    HAS_QUADS = features.quads
    HAS_SPHERES = features.spheres
    HAS_SMOOTH = features.smooth_normals
    closest, any_hit = (warp_mesh_closest, warp_mesh_occluded) if features.triangles == TRIANGLES_WARP else (
        mesh_closest, mesh_occluded)

    @wp.func
    def trace(scene: SceneData, o: wp.vec3, d: wp.vec3, tmax: float, origin_quad: int, origin_sphere: int,
              origin_normal: wp.vec3) -> Hit:
        """Nearest hit in (0, tmax) over the primitive kinds the scene has; ``material`` -1 when the ray escapes."""
        hit = Hit()
        hit.t = tmax
        hit.material = -1
        if wp.static(HAS_QUADS):
            # first, so that the BVH query below gets the nearest quad's distance as its limit
            o64 = wp.vec3d(o)
            d64 = wp.vec3d(d)
            nq = nearest_quad(scene, o64, d64, wp.float64(tmax), origin_quad)
            if nq.index >= 0:
                hit = quad_hit(scene, o64, d64, nq.t, nq.index)
        if wp.static(HAS_MESH):
            mesh_limit = hit.t
            if hit.material >= 0 and hit.light >= 0:
                mesh_limit = hit.t * (1.0 - 1.0e-5)  # the light also wins a float32 tie with a triangle
            q = wp.static(closest)(scene, o, d, mesh_limit)
            if q.face >= 0:
                hit = mesh_hit(scene, o, d, q)
                if wp.static(HAS_SMOOTH):
                    hit.ns = smooth_normal(scene, q.face, q.u, q.v, hit.ng)
        if wp.static(HAS_SPHERES):
            for i in range(scene.num_spheres):
                t = ray_sphere(o, d, scene.sphere_center[i], scene.sphere_radius[i], hit.t,
                               self_mode(origin_sphere, i, origin_normal, d))
                if t >= 0.0:
                    hit = sphere_hit(scene, o, d, t, i)
        return hit

    @wp.func
    def occluded(scene: SceneData, o: wp.vec3, d: wp.vec3, tmax: float, skip_quad_a: int, skip_quad_b: int,
                 origin_sphere: int, origin_normal: wp.vec3) -> bool:
        """Is anything hit in (0, tmax)? (The quads skipped are those the segment's two ends lie on.)"""
        if wp.static(HAS_QUADS):
            if occluded_quads(scene, o, d, tmax, skip_quad_a, skip_quad_b):
                return True
        if wp.static(HAS_MESH):
            if wp.static(any_hit)(scene, o, d, tmax):
                return True
        if wp.static(HAS_SPHERES):
            if occluded_spheres(scene, o, d, tmax, origin_sphere, origin_normal):
                return True
        return False

    @wp.func
    def occluded_but_face(scene: SceneData, o: wp.vec3, d: wp.vec3, tmax: float, skip_quad: int, origin_sphere: int,
                          origin_normal: wp.vec3, face: int) -> bool:
        """``occluded`` for a segment that ends on triangle ``face`` (a mesh light's sample): the triangles' nearest
        hit, not any hit, so that ``face`` itself never occludes. Its hit at the segment's end has a rounding error
        of about eps (edge length)^2 / area relative: on slivers (a 1024-sided tube's facets, 4000:1) far more than
        the end point's offset, which lost 2.7% of a thin tube light's light on the floor below it. A hit near the
        end on another face counts only beyond its own rounding error (of the same kind) from the end."""
        if wp.static(HAS_QUADS):
            if occluded_quads(scene, o, d, tmax, skip_quad, -1):
                return True
        q = wp.static(closest)(scene, o, d, tmax)
        if q.face >= 0 and q.face != face:
            # a hit within its own rounding error of the end cannot be told from the end (a neighbour of the
            # light's face, met beside their shared edge): the test's relative error in t is about
            # eps (edge)^2 / (projected doubled area), bounded here with a factor 8
            a = scene.points[scene.indices[3 * q.face + 0]]
            b = scene.points[scene.indices[3 * q.face + 1]]
            c = scene.points[scene.indices[3 * q.face + 2]]
            e2 = wp.max(wp.length_sq(b - a), wp.max(wp.length_sq(c - b), wp.length_sq(a - c)))
            proj = wp.abs(wp.dot(wp.cross(b - a, c - a), d))
            if proj * q.t < proj * tmax - 8.0 * FLT_EPS * e2 * tmax:
                return True
        if wp.static(HAS_SPHERES):
            if occluded_spheres(scene, o, d, tmax, origin_sphere, origin_normal):
                return True
        return False

    return trace, occluded, occluded_but_face


def make_render_kernel(features: Features):
    """Compile-time specialised integrator kernel for ``features`` (see module docstring)."""
    HAS_MESH = features.meshes
    HAS_QUADS = features.quads
    HAS_SPHERES = features.spheres
    HAS_MIRROR = features.mirrors
    HAS_SMOOTH = features.smooth_normals
    HAS_LIGHTS = features.lights
    VIEW = features.view
    RR = features.rr
    COUNT_RAYS = features.count_rays
    SOLID_ANGLE = features.light_sampling == LIGHT_SOLID_ANGLE
    SOBOL = features.sampler == SAMPLER_SOBOL
    draw4 = padded_sobol4 if SOBOL else independent4  # picked at compile time
    LIGHT_TRACING = features.light_tracing
    PIXEL_FILTER = features.pixel_filter
    THIN_LENS = features.thin_lens
    SPHERE_LIGHTS = features.sphere_lights
    MESH_LIGHTS = features.mesh_lights
    POINT_LIGHTS = features.point_lights
    SPOT_LIGHTS = features.spot_lights
    DIRECTIONAL = features.directional_lights
    ENVIRONMENT = features.environment
    ENVMAP = features.envmap
    EMITTING_SURFACES = HAS_LIGHTS or SPHERE_LIGHTS or MESH_LIGHTS  # hits can see emission
    OTHER_LIGHTS = (SPHERE_LIGHTS or MESH_LIGHTS or POINT_LIGHTS or SPOT_LIGHTS or DIRECTIONAL or ENVIRONMENT
                    or ENVMAP)
    NEE = HAS_LIGHTS or OTHER_LIGHTS
    OTHER_MATERIALS = features.other_materials
    DELTA_MATERIALS = features.dielectrics or features.thin_dielectrics or features.conductors  # no NEE at all
    # next-event estimation weighs each light sample by the BSDF towards it (diffuse alone: by albedo / pi, once)
    BSDF_NEE = features.plastics or features.rough_conductors or features.rough_plastics
    MIS = features.rough_conductors or features.rough_plastics  # glossy lobes: light and BSDF samples weighed by
    # the power heuristic
    GLASS = features.dielectrics
    TEXTURES = features.textures
    MOMENTS = features.moments
    ADAPTIVE = features.adaptive
    GRAD = features.gradient
    BACKWARD = features.backward

    trace, occluded, occluded_but_face = make_tracers(features)
    sample_bsdf, eval_nee = make_materials(features)

    def compiled_if(needed: bool):
        """``wp.func`` where this variant calls the function, else nothing: Warp parses a function's source when
        it is decorated (milliseconds each), and a call under a false ``wp.static`` is never compiled."""
        return wp.func if needed else (lambda f: None)

    @compiled_if(BSDF_NEE or OTHER_LIGHTS)
    def nee_weight(scene: SceneData, params: PassParams, mat: int, kind: int, rgb: wp.vec3, d: wp.vec3, ns: wp.vec3,
                   w: wp.vec3, cos_x: float, g: float, delta: bool) -> wp.vec3:
        """What a light sample along ``w`` with cos_x / pdf = ``g`` is multiplied by besides Le g / K: the BSDF
        value and MIS weight where the scene has materials that need them, else 1 (diffuse surfaces multiply by
        albedo / pi once, at the end). ``delta``: a point or direction, which BSDF sampling never finds."""
        if wp.static(not BSDF_NEE):
            return wp.vec3(1.0)
        ev = eval_nee(scene, mat, kind, rgb, d, ns, w)
        if wp.static(MIS):
            if ev.pdf > 0.0 and not delta and g > 0.0:
                p_light = float(params.light_samples) * cos_x / g
                return ev.f * (p_light * p_light / (p_light * p_light + ev.pdf * ev.pdf))
        return ev.f

    @compiled_if(MIS)
    def emitter_mis(scene: SceneData, params: PassParams, hit: Hit, x: wp.vec3, d: wp.vec3, pdf_bsdf: float) -> float:
        """Power-heuristic weight of emission at ``hit`` found by a glossy BSDF sample from ``x`` of density
        ``pdf_bsdf``, against the K next-event samples that could have found it (the same density as they use)."""
        l = hit.light
        to_y = hit.p - x
        dist2 = wp.dot(to_y, to_y)
        p = float(0.0)
        if l < scene.num_lights:
            if wp.static(HAS_LIGHTS):
                ln = scene.light_normal[l]
                if wp.static(SOLID_ANGLE):
                    if scene.light_rect[l] != 0 and wp.dot(x - scene.light_center[l], ln) > 0.0:
                        hu = scene.light_half_u[l]
                        hv = scene.light_half_v[l]
                        sr = sample_spherical_rectangle(x, scene.light_center[l] - hu - hv, 2.0 * hu, 2.0 * hv, 0.5, 0.5)
                        if sr.solid_angle > 0.0:
                            p = 1.0 / sr.solid_angle
                if p == 0.0:
                    p = dist2 / (wp.max(wp.abs(wp.dot(ln, d)), 1.0e-12) * scene.light_area[l])
        else:
            j = l - scene.num_lights
            if j < scene.num_sphere_lights:
                if wp.static(SPHERE_LIGHTS):
                    i = scene.sl_sphere[j]
                    p = sphere_cone_pdf(x, scene.sphere_center[i], scene.sphere_radius[i])
            else:
                if wp.static(MESH_LIGHTS):
                    m = j - scene.num_sphere_lights
                    p = dist2 / (wp.max(wp.abs(wp.dot(hit.ng, d)), 1.0e-12) * scene.ml_area[m])
        p = p * float(params.light_samples)
        return pdf_bsdf * pdf_bsdf / (pdf_bsdf * pdf_bsdf + p * p)

    @wp.func
    def visible(scene: SceneData, hit: Hit, ng: wp.vec3, y: wp.vec3, yn: wp.vec3, y_scale: float, w: wp.vec3,
                light_quad: int, far: bool, light_face: int) -> bool:
        """Does the shadow ray from the shading point towards unit ``w`` reach ``y`` (a point on an emitter with
        normal ``yn``, zero for a point light; on quad ``light_quad`` or mesh-light triangle ``light_face``, -1 if
        none) unoccluded? The segment runs between the two offset end points, stopping short of the emitter.
        ``far``: ``y`` is at infinity."""
        so = offset_origin(hit.p, ng, hit.scale, w)
        if far:
            return not occluded(scene, so, w, INF, hit.quad, -1, hit.sphere, hit.ng)
        se = y
        if wp.dot(yn, yn) > 0.0:
            se = offset_origin(y, yn, y_scale, -w)
        seg = se - so
        seg_len = wp.length(seg)
        if seg_len <= 0.0:
            return False
        if wp.static(MESH_LIGHTS):
            if light_face >= 0:
                return not occluded_but_face(scene, so, seg / seg_len, seg_len, hit.quad, hit.sphere, hit.ng,
                                             light_face)
        return not occluded(scene, so, seg / seg_len, seg_len, hit.quad, light_quad, hit.sphere, hit.ng)

    @compiled_if(OTHER_LIGHTS)
    def lit(scene: SceneData, hit: Hit, ng: wp.vec3, ns: wp.vec3, y: wp.vec3, yn: wp.vec3, y_scale: float,
            w: wp.vec3, far: bool, light_face: int) -> float:
        """cos_x for light reaching the shading point along unit ``w`` from ``y`` (as ``visible``): 0 when it
        arrives from behind the shading or the geometric normal, or is occluded."""
        cos_x = wp.dot(ns, w)
        if cos_x <= 0.0 or wp.dot(ng, w) <= 0.0:
            return 0.0
        if not visible(scene, hit, ng, y, yn, y_scale, w, -1, far, light_face):
            return 0.0
        return cos_x

    @compiled_if(OTHER_LIGHTS)
    def other_lights(scene: SceneData, params: PassParams, hit: Hit, ng: wp.vec3, ns: wp.vec3, mat: int, kind: int,
                     rgb: wp.vec3, d: wp.vec3, key: wp.vec3ui, dim: wp.uint32, depth: int) -> wp.vec3:
        """Next-event estimation of every emitter but the parallelograms: the sum of Le cos_x / pdf over the samples
        that see their emitter (K per sphere, mesh light and environment; one per point, spot and directional)."""
        Ld = wp.vec3(0.0)
        inv_k = 1.0 / float(params.light_samples)
        if wp.static(SPHERE_LIGHTS):
            for j in range(scene.num_sphere_lights):
                i = scene.sl_sphere[j]
                c = scene.sphere_center[i]
                r = scene.sphere_radius[i]
                for k in range(params.light_samples):
                    u = wp.static(draw4)(key, dim, depth)
                    dim += wp.uint32(1)
                    es = sample_sphere_cone(hit.p, c, r, u[0], u[1])
                    if es.inv_pdf <= 0.0:
                        continue
                    w = wp.normalize(es.p - hit.p)
                    if wp.dot(es.n, w) < 0.0:  # the emitting (outer) side faces the shading point
                        cos_x = lit(scene, hit, ng, ns, es.p, es.n, max_abs(es.p) + r, w, False, -1)
                        if cos_x > 0.0:
                            g = cos_x * es.inv_pdf
                            nw = nee_weight(scene, params, mat, kind, rgb, d, ns, w, cos_x, g, False)
                            Ld += wp.cw_mul(scene.light_radiance[scene.num_lights + j], nw) * (g * inv_k)
        if wp.static(MESH_LIGHTS):
            for m in range(scene.num_mesh_lights):
                start = scene.ml_start[m]
                count = scene.ml_count[m]
                for k in range(params.light_samples):
                    u = wp.static(draw4)(key, dim, depth)
                    dim += wp.uint32(1)
                    slot = pick_in_cdf(scene.ml_cdf, start, count, u[0])
                    lo = float(0.0)
                    if slot > start:
                        lo = scene.ml_cdf[slot - 1]
                    u0 = wp.clamp((u[0] - lo) / wp.max(scene.ml_cdf[slot] - lo, 1.0e-30), 0.0, 0.99999994)
                    f = scene.ml_face[slot]
                    a = scene.points[scene.indices[3 * f + 0]]
                    b = scene.points[scene.indices[3 * f + 1]]
                    c = scene.points[scene.indices[3 * f + 2]]
                    # barycentrics of the point sample_triangle_light draws, for the interpolated normal
                    su = wp.sqrt(u0)
                    n = (1.0 - su) * scene.corner_normals[3 * f + 0] + (su * (1.0 - u[1])) * scene.corner_normals[3 * f + 1]
                    n = wp.normalize(n + (su * u[1]) * scene.corner_normals[3 * f + 2])
                    # the area -> solid angle Jacobian is the face's own cosine; the emitting side is the shading
                    # normal's, as for hits (Mitsuba takes the shading normal for both, which is not the Jacobian:
                    # on smooth meshes its light samples disagree with its own emitter hits by about 1%)
                    ngy = wp.normalize(wp.cross(b - a, c - a))
                    es = sample_triangle_light(hit.p, a, b, c, ngy, scene.ml_area[m], u0, u[1])
                    if es.inv_pdf <= 0.0:
                        continue
                    w = wp.normalize(es.p - hit.p)
                    if wp.dot(n, w) < 0.0:  # the emitting side (the shading normal's) faces the shading point
                        if wp.dot(ngy, w) > 0.0:
                            ngy = -ngy  # offset the far end towards the shading point
                        y_scale = wp.max(max_abs(a), wp.max(max_abs(b), max_abs(c)))
                        cos_x = lit(scene, hit, ng, ns, es.p, -ngy, y_scale, w, False, f)
                        if cos_x > 0.0:
                            g = cos_x * es.inv_pdf
                            nw = nee_weight(scene, params, mat, kind, rgb, d, ns, w, cos_x, g, False)
                            Ld += wp.cw_mul(scene.light_radiance[scene.num_lights + scene.num_sphere_lights + m], nw) * (
                                g * inv_k)
        if wp.static(POINT_LIGHTS):
            for j in range(scene.num_point_lights):
                y = scene.pl_position[j]
                to_y = y - hit.p
                dist2 = wp.dot(to_y, to_y)
                if dist2 <= 0.0:
                    continue
                w = to_y / wp.sqrt(dist2)
                cos_x = lit(scene, hit, ng, ns, y, wp.vec3(0.0), 0.0, w, False, -1)
                if cos_x > 0.0:
                    nw = nee_weight(scene, params, mat, kind, rgb, d, ns, w, cos_x, 0.0, True)
                    Ld += wp.cw_mul(scene.pl_intensity[j], nw) * (cos_x / dist2)
        if wp.static(SPOT_LIGHTS):
            for j in range(scene.num_spot_lights):
                y = scene.spot_position[j]
                to_y = y - hit.p
                dist2 = wp.dot(to_y, to_y)
                if dist2 <= 0.0:
                    continue
                w = to_y / wp.sqrt(dist2)
                cone = scene.spot_cone[j]
                falloff = spot_falloff(wp.normalize(scene.spot_to_local[j] * (-w))[2], cone[0], cone[1], cone[2],
                                       cone[3])
                if falloff > 0.0:  # no shadow ray outside the cone
                    cos_x = lit(scene, hit, ng, ns, y, wp.vec3(0.0), 0.0, w, False, -1)
                    if cos_x > 0.0:
                        nw = nee_weight(scene, params, mat, kind, rgb, d, ns, w, cos_x, 0.0, True)
                        Ld += wp.cw_mul(scene.spot_intensity[j], nw) * (falloff * cos_x / dist2)
        if wp.static(DIRECTIONAL):
            for j in range(scene.num_directional_lights):
                w = -scene.dl_direction[j]
                cos_x = lit(scene, hit, ng, ns, hit.p, wp.vec3(0.0), 0.0, w, True, -1)
                if cos_x > 0.0:
                    nw = nee_weight(scene, params, mat, kind, rgb, d, ns, w, cos_x, 0.0, True)
                    Ld += wp.cw_mul(scene.dl_irradiance[j], nw) * cos_x
        if wp.static(ENVIRONMENT):
            # cosine-weighted directions: Le cos_x / pdf = pi Le (the bounce that follows never counts the sky)
            for k in range(params.light_samples):
                u = wp.static(draw4)(key, dim, depth)
                dim += wp.uint32(1)
                w = sample_cosine_around(ns, u[0], u[1])
                cos_x = lit(scene, hit, ng, ns, hit.p, wp.vec3(0.0), 0.0, w, True, -1)
                if cos_x > 0.0:
                    nw = nee_weight(scene, params, mat, kind, rgb, d, ns, w, cos_x, wp.pi, False)
                    Ld += wp.cw_mul(scene.env_radiance, nw) * (wp.pi * inv_k)
        if wp.static(ENVMAP):
            # directions drawn from the map's own distribution (luminance times sin theta)
            for k in range(params.light_samples):
                u = wp.static(draw4)(key, dim, depth)
                dim += wp.uint32(1)
                es = env_sample(scene, u[0], u[1])
                if es.pdf <= 0.0:
                    continue
                cos_x = lit(scene, hit, ng, ns, hit.p, wp.vec3(0.0), 0.0, es.d, True, -1)
                if cos_x > 0.0:
                    g = cos_x / es.pdf
                    nw = nee_weight(scene, params, mat, kind, rgb, d, ns, es.d, cos_x, g, False)
                    Ld += wp.cw_mul(env_eval(scene, es.d), nw) * (g * inv_k)
        return Ld

    @wp.func
    def Li(scene: SceneData, cam: CameraData, params: PassParams, col: int, row: int, sample_index: wp.uint32,
           seed: wp.uint32, replay: int, L_total: wp.vec3, adj: Adjoint) -> PathSample:
        """One camera path through pixel (col, row): sample ``sample_index`` of the sequence of ``seed``; the
        radiance it carries. Backward variants add each parameter's share of the loss gradient into ``adj``:
        ``replay`` 0 in the same pass (kernels/adjoint.py), unless the path meets more parameters than that holds
        (then ``out.replay``); ``replay`` 1: the same path again, knowing its radiance ``L_total`` (path replay: at
        a vertex of material m, the radiance still to come, L_total - L, carries one factor of m's reflectance)."""
        key = wp.vec3ui(wp.uint32(row * cam.width + col), sample_index, seed)

        # ---------------- camera ray ----------------
        jitter = wp.static(draw4)(key, wp.uint32(0), 0)
        jx = jitter[0]
        jy = jitter[1]
        if wp.static(PIXEL_FILTER):  # filter importance sampling: offsets from the pixel centre
            jx = 0.5 + filter_offset(cam.filter_cdf, cam.filter_radius, col, cam.width, cam.filter_border, jx)
            jy = 0.5 + filter_offset(cam.filter_cdf, cam.filter_radius, row, cam.height, cam.filter_border, jy)
        if wp.static(THIN_LENS):
            ray = thin_lens_ray(cam, col, row, jx, jy, jitter[2], jitter[3])
        else:
            ray = camera_ray(cam, col, row, jx, jy)
        o = ray.o
        d = ray.d
        tmax = ray.tmax
        dim = wp.uint32(1)

        L = wp.vec3(0.0)  # radiance gathered so far
        beta = wp.vec3(1.0)  # path throughput
        depth = int(0)  # index of the current path vertex (0: first hit)
        count_emission = bool(True)  # camera ray or mirror bounce: emission at the next hit counts
        origin_sphere = int(-1)  # sphere the current ray starts on, -1 if none
        origin_normal = wp.vec3(0.0)  # outward normal of that sphere at the origin
        origin_quad = int(-1)  # quad the current ray starts on (it cannot hit that plane again), -1 if none
        rays = wp.int64(0)  # rays traced (counted only in the instrumented variant)
        # camera -> diffuse first hit -> any bounces -> mirrors -> light: the light tracer's share of path space,
        # when it runs
        lt_owned = bool(False)
        mis_pdf = float(0.0)  # > 0: the current ray is a glossy BSDF sample of this density, from prev_p
        prev_p = wp.vec3(0.0)
        prev_ns = wp.vec3(0.0)  # the shading normal there (the environment's light samples are cosine-weighted)
        eta_scale = float(1.0)  # product of the relative indices crossed (for roulette, as Mitsuba)
        if wp.static(BACKWARD):
            adj_tile = params.row_offset  # this tile's row of the adjoints
            adj_w = adj.weight[row * cam.width + col]  # dLoss/dpixel / spp
            # one pass (replay 0): the path's entries (kernels/adjoint.py) and the radiance gathered at the last
            # change of their A
            ent_key = vec_keys()
            ent_a = mat_entries()
            ent_g = mat_entries()
            n_ent = int(0)
            overflow = bool(False)
            L_mark = wp.vec3(0.0)
        # forward-mode derivatives (gradient variants): dL/dtheta and d beta/dtheta. Sampling is detached (the
        # directions, light samples and roulette's probability do not move with theta), so each path's value is a
        # polynomial in the reflectances and linear in the radiances, and these are its exact derivatives
        dL = wp.vec3(0.0)
        dbeta = wp.vec3(0.0)

        if wp.static(VIEW == VIEW_DIRECTION):
            L = 0.5 * d + wp.vec3(0.5)
        else:
            while True:
                # ---------------- nearest hit ----------------
                if wp.static(COUNT_RAYS):
                    rays += wp.int64(1)
                hit = trace(scene, o, d, tmax, origin_quad, origin_sphere, origin_normal)
                if hit.material < 0:
                    if wp.static(ENVIRONMENT):  # seen directly or through mirrors; after diffuse bounces by NEE
                        if count_emission and (depth > 0 or params.hide_emitters == 0):
                            if wp.static(MIS):
                                if mis_pdf > 0.0:
                                    p_env = float(params.light_samples) * wp.max(0.0, wp.dot(prev_ns, d)) / wp.pi
                                    L += wp.cw_mul(beta, scene.env_radiance) * (
                                        mis_pdf * mis_pdf / (mis_pdf * mis_pdf + p_env * p_env))
                                else:
                                    L += wp.cw_mul(beta, scene.env_radiance)
                            else:
                                L += wp.cw_mul(beta, scene.env_radiance)
                            if wp.static(GRAD):  # (gradient variants are made without MIS)
                                dL += wp.cw_mul(dbeta, scene.env_radiance)
                    if wp.static(ENVMAP):
                        if count_emission and (depth > 0 or params.hide_emitters == 0):
                            Le = env_eval(scene, d)
                            if wp.static(MIS):
                                if mis_pdf > 0.0:
                                    p_env = float(params.light_samples) * env_pdf(scene, d)
                                    Le = Le * (mis_pdf * mis_pdf / (mis_pdf * mis_pdf + p_env * p_env))
                            L += wp.cw_mul(beta, Le)
                            if wp.static(GRAD):
                                dL += wp.cw_mul(dbeta, Le)
                    break  # without an environment the sky is black

                if wp.static(VIEW == VIEW_NORMAL):
                    L = 0.5 * hit.ns + wp.vec3(0.5)
                    break

                front = wp.dot(d, hit.ng) < 0.0

                # ---------------- emission seen directly or through mirrors ----------------
                if wp.static(EMITTING_SURFACES):
                    # one-sided emitters, seen from the side of the shading normal (Mitsuba: cos_theta(wi) > 0 in the
                    # shading frame; it is the face normal but on smooth meshes)
                    if count_emission and hit.light >= 0 and wp.dot(d, hit.ns) < 0.0 and not lt_owned:
                        if depth > 0 or params.hide_emitters == 0:
                            if wp.static(MIS):
                                if mis_pdf > 0.0:
                                    L += wp.cw_mul(beta, scene.light_radiance[hit.light]) * emitter_mis(
                                        scene, params, hit, prev_p, d, mis_pdf)
                                else:
                                    L += wp.cw_mul(beta, scene.light_radiance[hit.light])
                            else:
                                L += wp.cw_mul(beta, scene.light_radiance[hit.light])
                            if wp.static(GRAD):  # d(beta Le) = dbeta Le + beta dLe
                                dL += wp.cw_mul(dbeta, scene.light_radiance[hit.light])
                                if hit.light == params.grad_light:
                                    dL += beta
                            if wp.static(BACKWARD):  # (backward variants are made without MIS)
                                if hit.light < adj.num_lights:
                                    if replay != 0:
                                        wp.atomic_add(adj.radiance, adj_tile * adj.num_lights + hit.light,
                                                      wp.vec3d(wp.cw_mul(adj_w, beta)))
                                    else:
                                        e = adjoint_slot(ent_key, n_ent, -1 - hit.light)
                                        if e < ADJ_CAP:
                                            ent_key[e] = -1 - hit.light
                                            n_ent = wp.max(n_ent, e + 1)
                                            ent_g[e] = ent_g[e] + beta
                                        else:
                                            overflow = True

                if params.max_depth >= 0 and depth + 1 >= params.max_depth:
                    break

                # ---------------- surface frame ----------------
                mat = hit.material
                if not front and scene.mat_twosided[mat] == 0:
                    break  # one-sided materials are black from behind, as in Mitsuba
                ng = hit.ng
                ns = hit.ns
                if not front:
                    ng = -ng
                    ns = -ns
                if wp.dot(ns, d) >= 0.0:
                    break  # the shading normal faces away from the viewer: no reflection, as in Mitsuba
                albedo = scene.mat_rgb[mat]
                if wp.static(TEXTURES):
                    tex = scene.mat_texture[mat]
                    if tex >= 0:
                        albedo = texture_eval(scene, tex, surface_uv(scene, hit))

                kind = int(MAT_DIFFUSE)
                if wp.static(HAS_MIRROR or OTHER_MATERIALS):
                    kind = scene.mat_kind[mat]
                is_mirror = bool(False)
                if wp.static(HAS_MIRROR):
                    is_mirror = kind == 1
                is_delta = bool(False)  # glass or a smooth conductor: sampled only
                if wp.static(DELTA_MATERIALS):
                    is_delta = kind == MAT_DIELECTRIC or kind == MAT_THIN_DIELECTRIC or kind == MAT_CONDUCTOR
                if wp.static(BACKWARD):
                    # everything this path gathers from here on (next-event estimates here, and all after the
                    # bounce) carries this vertex's reflectance once: d/d rho of it is that radiance over rho
                    if kind == MAT_DIFFUSE or is_mirror:
                        if replay != 0:
                            share = wp.cw_mul(wp.cw_mul(adj_w, L_total - L), inverse_reflectance(albedo))
                            wp.atomic_add(adj.rgb, adj_tile * adj.num_materials + mat, wp.vec3d(share))
                        elif not overflow:
                            gathered = L - L_mark  # under the entries' A so far
                            for e in range(n_ent):
                                ent_g[e] = ent_g[e] + wp.cw_mul(gathered, ent_a[e])
                            L_mark = L
                            e = adjoint_slot(ent_key, n_ent, mat)
                            if e < ADJ_CAP:
                                ent_key[e] = mat
                                n_ent = wp.max(n_ent, e + 1)
                                ent_a[e] = ent_a[e] + inverse_reflectance(albedo)
                            else:
                                overflow = True

                wi = wp.vec3(0.0)
                weight = albedo  # f cos / pdf of the sampled direction
                transmit = bool(False)
                mis_pdf = 0.0
                if is_mirror:
                    # ---------------- mirror: perfect reflection ----------------
                    wi = reflect(d, ns)
                    count_emission = True
                elif is_delta:
                    # ---------------- glass, smooth conductors: one delta lobe, picked by its Fresnel weight ----
                    if wp.static(DELTA_MATERIALS):
                        u = wp.static(draw4)(key, dim, depth)
                        dim += wp.uint32(1)
                        bs = sample_bsdf(scene, mat, kind, albedo, d, ns, front, u)
                        wi = bs.wo
                        weight = bs.weight
                        transmit = bs.transmit
                        count_emission = True
                        if wp.static(GLASS):
                            eta_scale *= bs.eta
                else:
                    # ---------------- diffuse: next-event estimation ----------------
                    Ld = wp.vec3(0.0)
                    dLd = wp.vec3(0.0)  # dLd/dtheta (gradient variants: the differentiated light's share)
                    if wp.static(HAS_LIGHTS):
                        for l in range(scene.num_lights):
                            ln = scene.light_normal[l]
                            l_scale = light_sample_scale(scene, l)
                            Ll = wp.vec3(0.0)  # sum of f g / (albedo / pi) over the light's samples (with BSDFs)
                            Ll_cos = float(0.0)  # sum of g (diffuse only: f = albedo / pi, applied once below)
                            for k in range(params.light_samples):
                                u = wp.static(draw4)(key, dim, depth)
                                dim += wp.uint32(1)
                                y = wp.vec3(0.0)
                                omega = float(0.0)  # > 0: y is uniform in the light's solid angle
                                if wp.static(SOLID_ANGLE):
                                    if scene.light_rect[l] != 0:
                                        hu = scene.light_half_u[l]
                                        hv = scene.light_half_v[l]
                                        if wp.dot(hit.p - scene.light_center[l], ln) > 0.0:  # in front of the light
                                            sr = sample_spherical_rectangle(hit.p, scene.light_center[l] - hu - hv, 2.0 * hu, 2.0 * hv, u[0], u[1])
                                            y = sr.p
                                            omega = sr.solid_angle
                                if omega <= 0.0:
                                    y = sample_parallelogram(scene.light_center[l], scene.light_half_u[l], scene.light_half_v[l], u[0], u[1])
                                to_y = y - hit.p
                                dist2 = wp.dot(to_y, to_y)
                                if dist2 <= 0.0:
                                    continue
                                w = to_y / wp.sqrt(dist2)
                                cos_x = wp.dot(ns, w)
                                cos_y = -wp.dot(ln, w)
                                if cos_x <= 0.0 or cos_y <= 0.0 or wp.dot(ng, w) <= 0.0:
                                    continue
                                if wp.static(COUNT_RAYS):
                                    rays += wp.int64(1)
                                light_quad = int(-1)
                                if wp.static(HAS_QUADS):
                                    light_quad = scene.light_quad[l]
                                if visible(scene, hit, ng, y, ln, l_scale, w, light_quad, False, -1):
                                    g = float(0.0)  # cos_x / pdf
                                    if omega > 0.0:
                                        g = cos_x * omega
                                    else:
                                        g = cos_x * cos_y / dist2 * scene.light_area[l]
                                    if wp.static(BSDF_NEE):
                                        Ll += nee_weight(scene, params, mat, kind, albedo, d, ns, w, cos_x, g, False) * g
                                    else:
                                        Ll_cos += g
                            if wp.static(not BSDF_NEE):
                                Ll = wp.vec3(Ll_cos)
                            Ld += wp.cw_mul(scene.light_radiance[l], Ll / float(params.light_samples))
                            if wp.static(GRAD):
                                if l == params.grad_light:
                                    dLd = Ll / float(params.light_samples)
                            if wp.static(BACKWARD):  # d/dLe_l of beta albedo Le_l Ll / (pi K)
                                d_le = wp.cw_mul(wp.cw_mul(beta, albedo), Ll) * (
                                    1.0 / (wp.pi * float(params.light_samples)))
                                if replay != 0:
                                    wp.atomic_add(adj.radiance, adj_tile * adj.num_lights + l,
                                                  wp.vec3d(wp.cw_mul(adj_w, d_le)))
                                elif wp.max(Ll[0], wp.max(Ll[1], Ll[2])) > 0.0:
                                    e = adjoint_slot(ent_key, n_ent, -1 - l)
                                    if e < ADJ_CAP:
                                        ent_key[e] = -1 - l
                                        n_ent = wp.max(n_ent, e + 1)
                                        ent_g[e] = ent_g[e] + d_le
                                    else:
                                        overflow = True
                    if wp.static(OTHER_LIGHTS):
                        Ld += other_lights(scene, params, hit, ng, ns, mat, kind, albedo, d, key, dim, depth)
                        # the dims other_lights drew: K per sphere light, mesh light and environment
                        dim += wp.uint32(params.light_samples * (scene.num_sphere_lights + scene.num_mesh_lights
                                                                 + wp.static(int(ENVIRONMENT or ENVMAP))))
                    if wp.static(NEE):
                        if wp.static(BSDF_NEE):
                            L += wp.cw_mul(beta, Ld)
                        else:
                            L += wp.cw_mul(wp.cw_mul(beta, albedo), Ld) * (1.0 / wp.pi)
                        if wp.static(GRAD):  # (gradient variants are made without BSDF_NEE)
                            d_albedo = wp.cw_mul(dbeta, albedo)
                            if mat == params.grad_material:
                                d_albedo += beta
                            dL += (wp.cw_mul(d_albedo, Ld) + wp.cw_mul(wp.cw_mul(beta, albedo), dLd)) * (1.0 / wp.pi)

                    # ---------------- bounce: cosine-weighted (diffuse), or the BSDF's own sampling ----------
                    if kind == MAT_DIFFUSE and params.max_depth >= 0 and depth + 2 >= params.max_depth:
                        break  # the next vertex would be the last, and emission after a diffuse bounce never counts
                    u = wp.static(draw4)(key, dim, depth)
                    dim += wp.uint32(1)
                    count_emission = False
                    if kind == MAT_DIFFUSE:
                        wi = sample_cosine_around(ns, u[0], u[1])
                        if wp.static(LIGHT_TRACING):
                            if depth == 0:
                                lt_owned = True  # emission after mirrors, from here on: the light tracer's
                    else:
                        if wp.static(BSDF_NEE):
                            bs = sample_bsdf(scene, mat, kind, albedo, d, ns, front, u)
                            wi = bs.wo
                            weight = bs.weight
                            count_emission = bs.count_emission
                            if wp.static(MIS):
                                mis_pdf = bs.pdf
                                prev_p = hit.p
                                prev_ns = ns

                if transmit:
                    if wp.dot(wi, ng) >= 0.0:
                        break  # refracted or passed through, yet not to the other side of the surface
                elif wp.dot(wi, ng) <= 0.0:
                    break  # the new direction would go through the surface
                if wp.static(GRAD):  # d(beta w) = dbeta w + beta dw; w is the reflectance on diffuse and mirrors
                    dbeta = wp.cw_mul(dbeta, weight)
                    if mat == params.grad_material:
                        dbeta += beta
                beta = wp.cw_mul(beta, weight)
                depth += 1
                # The vertex this ray would reach is the last: it adds only emission, and that only where it
                # counts. After a bounce whose emission does not count (diffuse, and the BSDFs sampled with
                # next-event estimation but for their delta lobes) nothing would come of it, so the ray is not
                # traced: in a closed diffuse box one ray in four at max_depth 4, the image unchanged bit for bit.
                if not count_emission and params.max_depth >= 0 and depth + 1 >= params.max_depth:
                    break

                # ---------------- Russian roulette ----------------
                if wp.static(RR == RR_SEED):
                    if depth >= 2:
                        u = wp.static(draw4)(key, dim, depth)
                        dim += wp.uint32(1)
                        if u[0] < SEED_RR_LAMBDA:
                            break
                        beta = beta / (1.0 - SEED_RR_LAMBDA)
                        if wp.static(GRAD):
                            dbeta = dbeta / (1.0 - SEED_RR_LAMBDA)
                if wp.static(RR == RR_THROUGHPUT):
                    if depth >= params.rr_depth:
                        q_rr = wp.min(wp.max(beta[0], wp.max(beta[1], beta[2])) * eta_scale * eta_scale, 0.95)
                        u = wp.static(draw4)(key, dim, depth)
                        dim += wp.uint32(1)
                        if u[0] >= q_rr:
                            break
                        beta = beta / q_rr
                        if wp.static(GRAD):  # the survival probability is detached, as in Mitsuba's prb
                            dbeta = dbeta / q_rr
                if wp.max(beta[0], wp.max(beta[1], beta[2])) <= 0.0:
                    break

                # ---------------- spawn the next ray ----------------
                o = offset_origin(hit.p, ng, hit.scale, wi)
                d = wi
                tmax = INF
                origin_sphere = hit.sphere
                origin_quad = hit.quad
                origin_normal = hit.ng

        out = PathSample()
        out.L = L
        out.rays = rays
        if wp.static(GRAD):
            out.dL = dL
        if wp.static(BACKWARD):
            if replay == 0:
                out.replay = overflow
                if not overflow and wp.isfinite(L):  # (a dropped sample gives no gradient either)
                    gathered = L - L_mark
                    for e in range(n_ent):
                        adj_g = wp.vec3d(wp.cw_mul(adj_w, ent_g[e] + wp.cw_mul(gathered, ent_a[e])))
                        k_ent = ent_key[e]
                        if k_ent >= 0:
                            wp.atomic_add(adj.rgb, adj_tile * adj.num_materials + k_ent, adj_g)
                        else:
                            wp.atomic_add(adj.radiance, adj_tile * adj.num_lights - 1 - k_ent, adj_g)
        return out

    @wp.kernel(enable_backward=False, module=features.module_name("render"))
    def render_pass(
        scene: SceneData,
        cam: CameraData,
        params: PassParams,
        pass_limit: wp.array(dtype=wp.uint32),  # adaptive only (else one unused element): a pixel's passes end there
        adj: Adjoint,  # backward variants only (else empty)
        # outputs
        accum: wp.array(dtype=wp.vec3d),
        accum_sq: wp.array(dtype=wp.vec3d),
        accum_rep: wp.array(dtype=wp.vec3d),
        accum_m2: wp.array(dtype=wp.vec3d),  # with moments only (else one unused element)
        discarded: wp.array(dtype=wp.int32),
        ray_count: wp.array(dtype=wp.int64),
        accum_grad: wp.array(dtype=wp.vec3d),  # gradient variants only (else one unused element): sum of dL
    ):
        tid = wp.tid()
        col = tid % cam.width
        row = params.row_offset + (tid // cam.width) * params.row_stride
        if row >= cam.height:
            return
        pixel = row * cam.width + col
        # The launch's passes are added in pass order to sums held in registers: the same float64 additions, in
        # the same order, as one launch per pass, so the image does not depend on how passes are grouped.
        # float64 sums: finite float32 samples can never overflow them, nor lose small ones to rounding.
        total = accum[pixel]
        total_sq = accum_sq[pixel]
        total_m2 = wp.vec3d()
        if wp.static(MOMENTS):
            total_m2 = accum_m2[pixel]
        total_grad = wp.vec3d()
        if wp.static(GRAD):
            total_grad = accum_grad[pixel]
        bad = int(0)
        rays = wp.int64(0)
        npix = cam.width * cam.height
        count = params.pass_count
        if wp.static(ADAPTIVE):  # a stopped pixel renders no more passes (its passes stay a prefix 0 .. limit - 1)
            limit = pass_limit[pixel]
            if limit <= params.pass_index:
                return
            count = int(wp.min(wp.uint32(count), limit - params.pass_index))
        for k in range(count):
            # pass p belongs to replicate p mod R; with Sobol' it is point p div R of that replicate's own
            # scramble (seed hashed with the replicate), so the R replicates are independent randomised QMC
            # estimates whose spread is an unbiased error estimate (kernels/sobol.py: replicate_seed)
            p = params.pass_index + wp.uint32(k)
            rep = p % wp.uint32(params.replicates)
            sample_index = p
            seed = params.seed
            if wp.static(SOBOL):
                sample_index = p / wp.uint32(params.replicates)
                seed = replicate_seed(params.seed, rep)
            sample = Li(scene, cam, params, col, row, sample_index, seed, 0, wp.vec3(0.0), adj)
            finite = wp.isfinite(sample.L)
            if wp.static(BACKWARD):
                if finite and sample.replay:  # path replay: the same path, with its radiance known
                    Li(scene, cam, params, col, row, sample_index, seed, 1, sample.L, adj)
            if wp.static(GRAD):
                finite = finite and wp.isfinite(sample.dL)
            if finite:
                L64 = wp.vec3d(sample.L)
                total = total + L64
                total_sq = total_sq + wp.cw_mul(L64, L64)
                slot = int(rep) * npix + pixel
                accum_rep[slot] = accum_rep[slot] + L64
                if wp.static(MOMENTS):
                    xyz = srgb_to_xyz(L64)
                    total_m2 = total_m2 + wp.cw_mul(xyz, xyz)
                if wp.static(GRAD):
                    total_grad = total_grad + wp.vec3d(sample.dL)
            else:
                bad += 1  # dropped and counted, never averaged into the image
            rays += sample.rays
        accum[pixel] = total
        accum_sq[pixel] = total_sq
        if wp.static(MOMENTS):
            accum_m2[pixel] = total_m2
        if wp.static(GRAD):
            accum_grad[pixel] = total_grad
        # one counter per tile: Warp's CPU atomics are plain adds, and a tile is never rendered by two workers at once
        if bad > 0:
            wp.atomic_add(discarded, params.row_offset, bad)
        if wp.static(COUNT_RAYS):
            wp.atomic_add(ray_count, params.row_offset, rays)

    return render_pass


@functools.cache
def render_kernel(features: Features):
    """The kernel for ``features``, built once per process (Warp's disk cache makes later processes fast)."""
    return make_render_kernel(features)
