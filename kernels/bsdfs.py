"""Fresnel terms and microfacet distributions of Mitsuba 3's BSDFs (docs/mitsuba_semantics/study_bsdfs.md).

Directions are unit vectors in the local shading frame (+z the shading normal), ``wi`` towards the viewer and
``wo`` towards the light, as Mitsuba names them. Only isotropic roughness is modelled (one ``alpha``).
"""

import warp as wp

DIST_BECKMANN = 0
DIST_GGX = 1
DISTRIBUTIONS = {"beckmann": DIST_BECKMANN, "ggx": DIST_GGX}
MIN_ALPHA = 1.0e-4  # Mitsuba clamps alpha from below (MicrofacetDistribution::configure)


@wp.struct
class DielectricFresnel:
    F: float  # unpolarized reflectance
    cos_t: float  # |cos| of the refracted direction (0 under total internal reflection)
    eta_ti: float  # ratio of the indices, incident side over transmitted side


@wp.func
def fresnel_dielectric(cos_i: float, eta: float) -> DielectricFresnel:
    """Reflectance of a smooth dielectric boundary for a ray arriving from the side where ``cos_i`` > 0 is
    measured; ``eta`` is the relative index of the other side over this one (Mitsuba's fresnel() with cos_i >= 0;
    callers flip eta for rays from inside)."""
    out = DielectricFresnel()
    eta_ti = 1.0 / eta
    ci = wp.abs(cos_i)
    cos_t2 = 1.0 - eta_ti * eta_ti * (1.0 - ci * ci)
    ct = wp.sqrt(wp.max(0.0, cos_t2))
    a_s = (ci - eta * ct) / (ci + eta * ct)
    a_p = (ct - eta * ci) / (ct + eta * ci)
    F = 0.5 * (a_s * a_s + a_p * a_p)
    if eta == 1.0:
        F = 0.0
    elif ci == 0.0 or cos_t2 <= 0.0:
        F = 1.0
    out.F = F
    out.cos_t = ct
    out.eta_ti = eta_ti
    return out


@wp.func
def fresnel_conductor1(cos_i: float, eta: float, k: float) -> float:
    """Unpolarized reflectance of a conductor with complex index ``eta + i k`` (Mitsuba's fresnel_conductor)."""
    c2 = cos_i * cos_i
    s2 = 1.0 - c2
    s4 = s2 * s2
    temp_1 = eta * eta - k * k - s2
    a2pb2 = wp.sqrt(wp.max(0.0, temp_1 * temp_1 + 4.0 * k * k * eta * eta))
    a = wp.sqrt(wp.max(0.0, 0.5 * (a2pb2 + temp_1)))
    term_1 = a2pb2 + c2
    term_2 = 2.0 * cos_i * a
    r_s = (term_1 - term_2) / (term_1 + term_2)
    term_3 = a2pb2 * c2 + s4
    term_4 = term_2 * s2
    r_p = r_s * (term_3 - term_4) / (term_3 + term_4)
    return 0.5 * (r_s + r_p)


@wp.func
def fresnel_conductor(cos_i: float, eta: wp.vec3, k: wp.vec3) -> wp.vec3:
    """``fresnel_conductor1`` per RGB channel."""
    return wp.vec3(fresnel_conductor1(cos_i, eta[0], k[0]), fresnel_conductor1(cos_i, eta[1], k[1]),
                   fresnel_conductor1(cos_i, eta[2], k[2]))


@wp.func
def microfacet_d(m: wp.vec3, alpha: float, dist: int) -> float:
    """Normal distribution D(m) of an isotropic Beckmann or GGX surface (per unit projected area)."""
    cos2 = m[2] * m[2]
    if m[2] <= 0.0:
        return 0.0
    a2 = alpha * alpha
    xy2 = (m[0] * m[0] + m[1] * m[1]) / a2
    d = float(0.0)
    if dist == DIST_GGX:
        t = xy2 + cos2
        d = 1.0 / (wp.pi * a2 * t * t)
    else:
        d = wp.exp(-xy2 / cos2) / (wp.pi * a2 * cos2 * cos2)
    if d * m[2] <= 1.0e-20:
        return 0.0
    return d


@wp.func
def smith_g1(v: wp.vec3, m: wp.vec3, alpha: float, dist: int) -> float:
    """Smith's masking term G1(v, m); Beckmann's is Walter et al.'s rational fit, as Mitsuba."""
    if wp.dot(v, m) * v[2] <= 0.0:
        return 0.0
    xy = alpha * alpha * (v[0] * v[0] + v[1] * v[1])
    if xy == 0.0:
        return 1.0
    tan2 = xy / (v[2] * v[2])
    if dist == DIST_GGX:
        return 2.0 / (1.0 + wp.sqrt(1.0 + tan2))
    a = 1.0 / wp.sqrt(tan2)
    if a >= 1.6:
        return 1.0
    return (3.535 * a + 2.181 * a * a) / (1.0 + 2.276 * a + 2.577 * a * a)


@wp.func
def sample_microfacet(wi: wp.vec3, alpha: float, dist: int, u1: float, u2: float) -> wp.vec3:
    """A microfacet normal m: GGX's visible normals seen from ``wi`` (Heitz 2018), pdf D G1(wi) (wi.m) / wi.z;
    Beckmann's D(m) cos(m)."""
    if dist == DIST_GGX:
        vh = wp.normalize(wp.vec3(alpha * wi[0], alpha * wi[1], wi[2]))
        lensq = vh[0] * vh[0] + vh[1] * vh[1]
        t1 = wp.vec3(1.0, 0.0, 0.0)
        if lensq > 0.0:
            t1 = wp.vec3(-vh[1], vh[0], 0.0) / wp.sqrt(lensq)
        t2 = wp.cross(vh, t1)
        r = wp.sqrt(u1)
        phi = 2.0 * wp.pi * u2
        p1 = r * wp.cos(phi)
        p2 = r * wp.sin(phi)
        s = 0.5 * (1.0 + vh[2])
        p2 = (1.0 - s) * wp.sqrt(wp.max(0.0, 1.0 - p1 * p1)) + s * p2
        nh = p1 * t1 + p2 * t2 + wp.sqrt(wp.max(0.0, 1.0 - p1 * p1 - p2 * p2)) * vh
        return wp.normalize(wp.vec3(alpha * nh[0], alpha * nh[1], wp.max(1.0e-6, nh[2])))
    tan2 = -alpha * alpha * wp.log(wp.max(1.0 - u1, 1.0e-30))
    cos_t = 1.0 / wp.sqrt(1.0 + tan2)
    sin_t = wp.sqrt(wp.max(0.0, 1.0 - cos_t * cos_t))
    phi = 2.0 * wp.pi * u2
    return wp.vec3(sin_t * wp.cos(phi), sin_t * wp.sin(phi), cos_t)


@wp.func
def microfacet_pdf(wi: wp.vec3, m: wp.vec3, alpha: float, dist: int) -> float:
    """Density of ``sample_microfacet`` at m (per solid angle of m)."""
    d = microfacet_d(m, alpha, dist)
    if dist == DIST_GGX:
        if wi[2] <= 0.0:
            return 0.0
        return d * smith_g1(wi, m, alpha, dist) * wp.max(0.0, wp.dot(wi, m)) / wi[2]
    return d * m[2]


@wp.func
def rough_conductor_f(wi: wp.vec3, wo: wp.vec3, alpha: float, dist: int, eta: wp.vec3, k: wp.vec3) -> wp.vec3:
    """BSDF value (without the cosine) of Mitsuba's roughconductor: D G F / (4 cos_i cos_o); 0 below the surface."""
    if wi[2] <= 0.0 or wo[2] <= 0.0:
        return wp.vec3(0.0)
    h = wp.normalize(wi + wo)
    d = microfacet_d(h, alpha, dist)
    if d == 0.0:
        return wp.vec3(0.0)
    g = smith_g1(wi, h, alpha, dist) * smith_g1(wo, h, alpha, dist)
    return fresnel_conductor(wp.dot(wi, h), eta, k) * (d * g / (4.0 * wi[2] * wo[2]))


@wp.func
def rough_conductor_pdf(wi: wp.vec3, wo: wp.vec3, alpha: float, dist: int) -> float:
    """Solid-angle density of reflecting ``wi`` into ``wo`` by ``sample_microfacet``."""
    if wi[2] <= 0.0 or wo[2] <= 0.0:
        return 0.0
    h = wp.normalize(wi + wo)
    return microfacet_pdf(wi, h, alpha, dist) / (4.0 * wp.dot(wo, h))


@wp.func
def plastic_diffuse_f(cos_i: float, cos_o: float, eta: float, diffuse: wp.vec3, fdr_int: float,
                      nonlinear: int) -> wp.vec3:
    """The diffuse lobe of Mitsuba's smooth plastic (without the cosine): light refracted in, scattered by the
    substrate with internal reflections, refracted out: R / (1 - fdr) (1 - F_i) (1 - F_o) / (eta^2 pi)."""
    if cos_i <= 0.0 or cos_o <= 0.0:
        return wp.vec3(0.0)
    f_i = fresnel_dielectric(cos_i, eta).F
    f_o = fresnel_dielectric(cos_o, eta).F
    scale = (1.0 - f_i) * (1.0 - f_o) / (eta * eta * wp.pi)
    if nonlinear != 0:
        return wp.vec3(diffuse[0] / (1.0 - diffuse[0] * fdr_int), diffuse[1] / (1.0 - diffuse[1] * fdr_int),
                       diffuse[2] / (1.0 - diffuse[2] * fdr_int)) * scale
    return diffuse * (scale / (1.0 - fdr_int))


@wp.func
def rough_plastic_f(wi: wp.vec3, wo: wp.vec3, alpha: float, dist: int, eta: float, diffuse: wp.vec3,
                    specular: wp.vec3, internal: float, nonlinear: int, t_i: float, t_o: float) -> wp.vec3:
    """BSDF value (without the cosine) of Mitsuba's roughplastic: the coat's microfacet reflection F D G / (4 cos_i
    cos_o) plus the base seen through it, R / (1 - R_int) t_i t_o / (eta^2 pi), with t the coat's tabulated
    transmittance at each direction and R_int its internal reflectance."""
    if wi[2] <= 0.0 or wo[2] <= 0.0:
        return wp.vec3(0.0)
    h = wp.normalize(wi + wo)
    d = microfacet_d(h, alpha, dist)
    f = fresnel_dielectric(wp.dot(wi, h), eta).F
    g = smith_g1(wi, h, alpha, dist) * smith_g1(wo, h, alpha, dist)
    coat = specular * (f * d * g / (4.0 * wi[2] * wo[2]))
    scale = t_i * t_o / (eta * eta * wp.pi)
    if nonlinear != 0:
        base = wp.vec3(diffuse[0] / (1.0 - diffuse[0] * internal), diffuse[1] / (1.0 - diffuse[1] * internal),
                       diffuse[2] / (1.0 - diffuse[2] * internal))
        return coat + base * scale
    return coat + diffuse * (scale / (1.0 - internal))


@wp.func
def rough_plastic_pdf(wi: wp.vec3, wo: wp.vec3, alpha: float, dist: int, p_coat: float) -> float:
    """Density of roughplastic's sampling: the coat's microfacet reflection with probability ``p_coat``, else
    cosine-weighted."""
    if wi[2] <= 0.0 or wo[2] <= 0.0:
        return 0.0
    h = wp.normalize(wi + wo)
    return p_coat * microfacet_pdf(wi, h, alpha, dist) / (4.0 * wp.dot(wo, h)) + (1.0 - p_coat) * wo[2] / wp.pi
