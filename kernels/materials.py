"""The BSDFs other than diffuse and mirror, as Mitsuba 3's plugins: smooth ``dielectric`` and ``thindielectric``,
smooth ``conductor`` with a complex index, ``plastic``, ``roughconductor`` and ``roughplastic`` (docs/mitsuba_semantics/
study_bsdfs.md). ``make_materials(features)`` compiles in only the kinds a scene uses.

At a shading point the integrator knows the ray direction ``d``, the shading normal ``ns`` and geometric normal
``ng`` both flipped to the viewer's side, and ``front`` (the viewer is on the side the surface's normal points to,
which for glass says whether the ray is outside). ``sample`` draws the next direction from one uniform vec4 and
returns its weight f cos / pdf; ``eval_nee`` gives the BSDF value towards a light for next-event estimation, and
the density with which ``sample`` would have drawn that direction where multiple importance sampling applies.

Lobes: delta lobes (glass, smooth conductors, plastic's coat) are found only by ``sample`` and the emission they
reach counts in full; plastic's diffuse base is found only by next-event estimation (as the diffuse material);
the rough conductor's glossy lobe and the rough plastic (coat and base as one mixture) are found by both,
weighted by the power heuristic.
"""

import warp as wp

from kernels.bsdfs import (fresnel_conductor, fresnel_dielectric, plastic_diffuse_f, rough_conductor_f,
                           rough_conductor_pdf, rough_plastic_f, rough_plastic_pdf, sample_microfacet)
from kernels.sampling import cosine_hemisphere, orthonormal_basis, reflect
from kernels.types import SceneData

MAT_DIFFUSE = 0  # the codes of pathtracer.scene.MATERIAL_KINDS
MAT_MIRROR = 1
MAT_DIELECTRIC = 2
MAT_THIN_DIELECTRIC = 3
MAT_CONDUCTOR = 4
MAT_PLASTIC = 5
MAT_ROUGH_CONDUCTOR = 6
MAT_ROUGH_PLASTIC = 7
TRANSMITTANCE_RES = 64  # entries of roughplastic's coat transmittance table (pathtracer/microfacet_tables.py)


@wp.struct
class BsdfSample:
    wo: wp.vec3  # world direction of the next ray
    weight: wp.vec3  # f cos / pdf; zero ends the path
    pdf: float  # solid-angle density for multiple importance sampling, 0 where it does not apply
    count_emission: bool  # the next hit's emission counts (delta and MIS lobes)
    transmit: bool  # wo crosses the surface
    eta: float  # relative index crossed (for roulette), 1 for reflections


@wp.struct
class BsdfEval:
    f: wp.vec3  # BSDF value towards the light, without the cosine
    pdf: float  # density of sample() in that direction where MIS applies, else 0


@wp.func
def coat_transmittance(scene: SceneData, mat: int, mu: float) -> float:
    """roughplastic's tabulated coat transmittance at cos(theta) = mu, linearly interpolated (Mitsuba's lerp_gather)."""
    x = mu * float(TRANSMITTANCE_RES - 1)
    i = wp.clamp(int(x), 0, TRANSMITTANCE_RES - 2)
    start = scene.mat_table[mat]
    v0 = scene.rough_tables[start + i]
    v1 = scene.rough_tables[start + i + 1]
    return v0 + (v1 - v0) * (x - float(i))


@wp.func
def coat_pick(scene: SceneData, mat: int, t_i: float) -> float:
    """roughplastic's probability of sampling the coat: (1 - t_i) w / ((1 - t_i) w + t_i (1 - w))."""
    w = scene.mat_param[mat][2]
    p = (1.0 - t_i) * w
    return p / (p + t_i * (1.0 - w))


@wp.func
def rough_plastic_eval(scene: SceneData, mat: int, rgb: wp.vec3, wi: wp.vec3, wo: wp.vec3) -> BsdfEval:
    ev = BsdfEval()
    prm = scene.mat_param[mat]
    dist = int(prm[1])
    t_i = coat_transmittance(scene, mat, wi[2])
    t_o = coat_transmittance(scene, mat, wp.max(wo[2], 0.0))
    ev.f = rough_plastic_f(wi, wo, prm[0], dist, scene.mat_eta[mat][0], rgb, scene.mat_rgb2[mat], prm[3],
                           scene.mat_nonlinear[mat], t_i, t_o)
    ev.pdf = rough_plastic_pdf(wi, wo, prm[0], dist, coat_pick(scene, mat, t_i))
    return ev


@wp.func
def relative_eta(scene: SceneData, mat: int, front: bool) -> float:
    """Index of the far side over the viewer's side."""
    eta = scene.mat_eta[mat][0]
    if front:
        return eta
    return 1.0 / eta


def make_materials(features):
    """(sample, eval_nee) over exactly the BSDF kinds in ``features`` (kernels/integrator.Features)."""
    DIELECTRIC = features.dielectrics
    THIN = features.thin_dielectrics
    CONDUCTOR = features.conductors
    PLASTIC = features.plastics
    ROUGH_CONDUCTOR = features.rough_conductors
    ROUGH_PLASTIC = features.rough_plastics

    @wp.func
    def sample(scene: SceneData, mat: int, kind: int, rgb: wp.vec3, d: wp.vec3, ns: wp.vec3, front: bool,
               u: wp.vec4) -> BsdfSample:
        """The next direction at a surface of ``kind`` (not diffuse or mirror), seen along ``d``; ``rgb`` is the
        material's reflectance there (mat_rgb, or its texture's value)."""
        bs = BsdfSample()
        bs.eta = 1.0
        bs.count_emission = True
        cos_i = -wp.dot(d, ns)
        if wp.static(DIELECTRIC):
            if kind == MAT_DIELECTRIC:
                eta = relative_eta(scene, mat, front)
                fr = fresnel_dielectric(cos_i, eta)
                if u[0] <= fr.F:
                    bs.wo = reflect(d, ns)
                    bs.weight = rgb
                else:
                    bs.wo = wp.normalize(fr.eta_ti * d + (fr.eta_ti * cos_i - fr.cos_t) * ns)
                    # radiance is scaled by the squared index ratio when it crosses into another medium
                    bs.weight = scene.mat_rgb2[mat] * (fr.eta_ti * fr.eta_ti)
                    bs.transmit = True
                    bs.eta = eta
                return bs
        if wp.static(THIN):
            if kind == MAT_THIN_DIELECTRIC:
                r = fresnel_dielectric(cos_i, scene.mat_eta[mat][0]).F
                r = 2.0 * r / (1.0 + r)  # the sum over internal reflections of a thin slab
                if u[0] <= r:
                    bs.wo = reflect(d, ns)
                    bs.weight = rgb
                else:
                    bs.wo = d
                    bs.weight = scene.mat_rgb2[mat]
                    bs.transmit = True
                return bs
        if wp.static(CONDUCTOR):
            if kind == MAT_CONDUCTOR:
                bs.wo = reflect(d, ns)
                bs.weight = wp.cw_mul(rgb, fresnel_conductor(cos_i, scene.mat_eta[mat], scene.mat_k[mat]))
                return bs
        if wp.static(PLASTIC):
            if kind == MAT_PLASTIC:
                eta = scene.mat_eta[mat][0]
                f_i = fresnel_dielectric(cos_i, eta).F
                w = scene.mat_param[mat][2]
                p_spec = f_i * w
                p_spec = p_spec / (p_spec + (1.0 - f_i) * (1.0 - w))
                if u[0] < p_spec:
                    bs.wo = reflect(d, ns)
                    bs.weight = scene.mat_rgb2[mat] * (f_i / p_spec)
                else:
                    local = cosine_hemisphere(u[1], u[2])
                    bs.wo = wp.normalize(orthonormal_basis(ns) * local)
                    f = plastic_diffuse_f(cos_i, local[2], eta, rgb, scene.mat_param[mat][3],
                                          scene.mat_nonlinear[mat])
                    bs.weight = f * (wp.pi / (1.0 - p_spec))  # f cos / (cos / pi) over the lobe's probability
                    bs.count_emission = False  # next-event estimation covers the diffuse base
                return bs
        if wp.static(ROUGH_CONDUCTOR):
            if kind == MAT_ROUGH_CONDUCTOR:
                frame = orthonormal_basis(ns)
                wi = wp.transpose(frame) * (-d)
                alpha = scene.mat_param[mat][0]
                dist = int(scene.mat_param[mat][1])
                m = sample_microfacet(wi, alpha, dist, u[0], u[1])
                wo = 2.0 * wp.dot(wi, m) * m - wi
                pdf = rough_conductor_pdf(wi, wo, alpha, dist)
                bs.wo = wp.normalize(frame * wo)
                if pdf > 0.0:
                    f = rough_conductor_f(wi, wo, alpha, dist, scene.mat_eta[mat], scene.mat_k[mat])
                    bs.weight = wp.cw_mul(rgb, f) * (wo[2] / pdf)
                    bs.pdf = pdf
                return bs
        if wp.static(ROUGH_PLASTIC):
            if kind == MAT_ROUGH_PLASTIC:
                frame = orthonormal_basis(ns)
                wi = wp.transpose(frame) * (-d)
                alpha = scene.mat_param[mat][0]
                dist = int(scene.mat_param[mat][1])
                p_coat = coat_pick(scene, mat, coat_transmittance(scene, mat, wi[2]))
                wo = wp.vec3(0.0)
                if u[0] < p_coat:
                    m = sample_microfacet(wi, alpha, dist, u[1], u[2])
                    wo = 2.0 * wp.dot(wi, m) * m - wi
                else:
                    wo = cosine_hemisphere(u[1], u[2])
                bs.wo = wp.normalize(frame * wo)
                if wo[2] > 0.0:
                    ev = rough_plastic_eval(scene, mat, rgb, wi, wo)
                    if ev.pdf > 0.0:
                        bs.weight = ev.f * (wo[2] / ev.pdf)
                        bs.pdf = ev.pdf
                return bs
        return bs

    @wp.func
    def eval_nee(scene: SceneData, mat: int, kind: int, rgb: wp.vec3, d: wp.vec3, ns: wp.vec3,
                 w: wp.vec3) -> BsdfEval:
        """The BSDF towards light direction ``w`` of a surface with a lobe that next-event estimation sees."""
        ev = BsdfEval()
        if wp.static(PLASTIC):
            if kind == MAT_PLASTIC:
                ev.f = plastic_diffuse_f(-wp.dot(d, ns), wp.dot(w, ns), scene.mat_eta[mat][0], rgb,
                                         scene.mat_param[mat][3], scene.mat_nonlinear[mat])
                return ev
        if wp.static(ROUGH_CONDUCTOR):
            if kind == MAT_ROUGH_CONDUCTOR:
                frame_t = wp.transpose(orthonormal_basis(ns))
                wi = frame_t * (-d)
                wo = frame_t * w
                alpha = scene.mat_param[mat][0]
                dist = int(scene.mat_param[mat][1])
                ev.f = wp.cw_mul(rgb,
                                 rough_conductor_f(wi, wo, alpha, dist, scene.mat_eta[mat], scene.mat_k[mat]))
                ev.pdf = rough_conductor_pdf(wi, wo, alpha, dist)
                return ev
        if wp.static(ROUGH_PLASTIC):
            if kind == MAT_ROUGH_PLASTIC:
                frame_t = wp.transpose(orthonormal_basis(ns))
                return rough_plastic_eval(scene, mat, rgb, frame_t * (-d), frame_t * w)
        ev.f = rgb * (1.0 / wp.pi)
        return ev

    return sample, eval_nee
