"""Mitsuba's BSDFs (kernels/bsdfs.py, kernels/materials.py): Fresnel terms against Mitsuba 3.9.1's own values,
the microfacet sampler against its density, and furnaces where the image is known in closed form."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

import pathtracer
from pathtracer import transform as tf
from probes import probe_fresnel, probe_microfacet, probe_rough_plastic
from stats import assert_agree, assert_mean

BK7 = 1.5046 / 1.000277  # Mitsuba's default dielectric: bk7 in air
AU = ((0.143036, 0.3753071, 1.442045), (3.982997, 2.385556, 1.603359))  # Mitsuba 3.9.1's RGB gold


def fresnel(device, cos_i, eta, ceta=(0.0, 0.0, 0.0), ck=(1.0, 1.0, 1.0)):
    cos_i = np.asarray(cos_i, np.float32)
    outs = [wp.zeros(len(cos_i), dtype=wp.vec3, device=device) for _ in range(3)]
    wp.launch(probe_fresnel, len(cos_i), inputs=[wp.array(cos_i, dtype=float, device=device), float(eta),
                                                 wp.vec3(*ceta), wp.vec3(*ck)], outputs=outs, device=device)
    return [o.numpy() for o in outs]


def test_fresnel_terms_match_mitsuba(device):
    c = np.cos(0.5)
    f_d, f_c, _ = fresnel(device, [c], BK7, *AU)
    # values printed by Mitsuba 3.9.1 (docs/mitsuba_semantics/study_bsdfs.md)
    assert f_d[0, 0] == pytest.approx(0.041785, abs=2e-6)
    assert f_d[0, 2] == pytest.approx(1.0 / BK7, rel=1e-6)
    assert np.allclose(f_c[0], (0.966462, 0.801686, 0.325818), atol=2e-6)
    r = f_d[0, 0]
    assert 2 * r / (1 + r) == pytest.approx(0.0802186, abs=2e-6)  # thindielectric's reflectance there
    f_in, _, _ = fresnel(device, [c], 1.0 / BK7)  # the same angle from inside the glass
    assert f_in[0, 0] == pytest.approx(0.052228, abs=2e-6)
    # beyond the critical angle from inside: total internal reflection
    tir, _, _ = fresnel(device, [np.cos(np.arcsin(1.0 / BK7) + 0.01)], 1.0 / BK7)
    assert tir[0, 0] == 1.0 and tir[0, 1] == 0.0
    # eta 1 and k 1: Mitsuba's conductor "none" reflects everything at every angle
    _, none, _ = fresnel(device, np.linspace(0.01, 1.0, 50), BK7)
    assert np.allclose(none, 1.0, atol=1e-6)


def test_plastic_diffuse_lobe_matches_its_formula(device):
    cos = np.array([1.0, 0.6, 0.2], np.float32)
    f_d, _, plastic = fresnel(device, cos, 1.49 / 1.000277)
    eta = 1.49 / 1.000277
    expect = 0.5 / (1.0 - 0.5904789) * (1 - f_d[:, 0]) ** 2 / (eta * eta * np.pi)
    assert np.allclose(plastic[:, 0], expect, rtol=1e-5)
    f0 = ((eta - 1) / (eta + 1)) ** 2  # normal incidence: Fresnel's closed form
    assert f_d[0, 0] == pytest.approx(f0, rel=1e-5)


def microfacet(device, theta, alpha, dist, n=200_000, seed=3):
    rng = np.random.default_rng(seed)
    us = rng.random((n, 2)).astype(np.float32)
    z = rng.random(n)
    phi = 2 * np.pi * rng.random(n)
    r = np.sqrt(1 - z * z)
    dirs = np.stack([r * np.cos(phi), r * np.sin(phi), z], 1).astype(np.float32)  # uniform on the hemisphere
    wi = wp.vec3(np.sin(theta), 0.0, np.cos(theta))
    outs = [wp.zeros(n, dtype=t, device=device) for t in (wp.vec3, wp.vec3, wp.vec3, float, float)]
    wp.launch(probe_microfacet, n, inputs=[wi, alpha, dist, wp.vec3(0.0), wp.vec3(1.0),
                                           wp.array(us, dtype=wp.vec2, device=device),
                                           wp.array(dirs, dtype=wp.vec3, device=device)], outputs=outs, device=device)
    m, weight, f_cos, pdf, d_cos = (o.numpy() for o in outs)
    return m, weight, f_cos, pdf, d_cos


CASES = [(dist, alpha, theta) for dist in (0, 1) for alpha in (0.2, 0.5) for theta in (0.0, 1.0, 1.35)]


@pytest.mark.parametrize("dist,alpha,theta", CASES)
def test_microfacet_sampler_has_the_density_it_reports(device, dist, alpha, theta):
    m, weight, f_cos, pdf, d_cos = microfacet(device, theta, alpha, dist)
    two_pi = 2 * np.pi
    # D is a distribution of normals: the integral of D(m) cos(m) over the hemisphere is 1
    assert_mean(two_pi * d_cos, 1.0, name=f"D cos, dist {dist} alpha {alpha}")
    # the reported pdf integrates, over the upper hemisphere, to the share of samples that land there
    wi = np.array([np.sin(theta), 0.0, np.cos(theta)])
    wo = 2 * (m @ wi)[:, None] * m - wi
    above = (wo[:, 2] > 0).astype(np.float64)
    assert_agree(two_pi * pdf, above, name="pdf mass vs samples above the horizon")
    # sampled weights f cos / pdf average to the albedo that uniform directions integrate from f alone
    assert_agree(weight[:, 0], two_pi * f_cos[:, 0], name="albedo: BSDF samples vs uniform directions")


def ggx_albedo_normal_incidence(alpha: float, n: int = 400_000) -> tuple[float, float]:
    """The directional albedo at normal incidence of a GGX conductor with F = 1, integrated in numpy from the
    textbook D and Smith G (independent of the kernels), with its standard error."""
    rng = np.random.default_rng(11)
    # stratified in cos^2 of the half vector, where D concentrates: cos_o = 2 cos_h^2 - 1 at normal incidence
    z = rng.random(n)
    wo_z = z
    h_z = np.sqrt((1 + wo_z) / 2)
    t2h = (1 - h_z**2) / h_z**2
    d = 1 / (np.pi * alpha**2 * h_z**4 * (1 + t2h / alpha**2) ** 2)
    t2o = (1 - wo_z**2) / wo_z**2
    g1o = 2 / (1 + np.sqrt(1 + alpha**2 * t2o))
    f_cos = d * g1o / 4.0  # D G / (4 cos_i cos_o) cos_o with cos_i = 1, G1(wi) = 1
    vals = 2 * np.pi * f_cos  # uniform in cos_o over the hemisphere (the integrand is azimuthally symmetric)
    return float(vals.mean()), float(vals.std() / np.sqrt(n))


def furnace(bsdf: dict, size: int = 33, spp: int = 64, seed: int = 0, max_depth: int = -1, device="cpu"):
    """A unit sphere of ``bsdf`` inside a constant unit environment, seen head-on."""
    scene = pathtracer.load_dict({
        "type": "scene", "integrator": {"type": "path", "max_depth": max_depth},
        "sensor": {"type": "perspective", "fov": 30, "to_world": tf.look_at([0, 0, 5], [0, 0, 0], [0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": size, "height": size, "rfilter": {"type": "box"}}},
        "ball": {"type": "sphere", "bsdf": bsdf},
        "sky": {"type": "constant", "radiance": 1.0}})
    return pathtracer.render(scene, spp=spp, seed=seed, device=device, progress=False).astype(np.float64)


@pytest.mark.parametrize("bsdf", [{"type": "dielectric"}, {"type": "dielectric", "int_ior": "diamond"},
                                  {"type": "thindielectric", "int_ior": 1.8}], ids=["bk7", "diamond", "thin"])
def test_glass_in_a_furnace_is_invisible(device, bsdf):
    """Lossless glass in a uniform environment: every path carries exactly the environment's radiance (the
    eta^2 radiance scaling in and out cancels), roulette aside."""
    means = np.array([furnace(bsdf, size=17, spp=16, seed=s, device=device).mean() for s in range(16)])
    assert_mean(means, 1.0, name=f"furnace {bsdf}")


def test_gold_sphere_in_a_furnace_shows_fresnel_at_normal_incidence(device):
    img = furnace({"type": "conductor", "material": "Au"}, spp=4, device=device)
    _, f_c, _ = fresnel(device, [1.0], BK7, *AU)
    # the centre pixel sees the sphere within 0.05 degrees of normal incidence; one bounce, then the sky
    assert np.allclose(img[16, 16], f_c[0], atol=2e-4)


def test_rough_conductor_in_a_furnace_is_its_albedo_with_mis(device):
    """Environment light samples and BSDF samples, weighed by MIS, must add up to the BSDF's albedo."""
    expect, se_ref = ggx_albedo_normal_incidence(0.3)
    vals = np.array([furnace({"type": "roughconductor", "distribution": "ggx", "alpha": 0.3}, spp=64, seed=s,
                             device=device)[15:18, 15:18, 0].mean() for s in range(16)])
    mean, se = vals.mean(), vals.std(ddof=1) / np.sqrt(len(vals))
    z = (mean - expect) / np.hypot(se, se_ref)
    print(f"rough conductor albedo: ours {mean:.5f} +- {se:.5f}, numpy {expect:.5f} +- {se_ref:.5f}, z {z:+.2f}")
    # the 3x3 centre pixels see normals within 0.15 degrees of the view: the albedo there differs by < 1e-5
    assert abs(z) < 4


# Mitsuba 3.9.1 scalar_rgb: roughplastic eval (f cos) and pdf for (theta_i, theta_o, phi_o), wi in the xz plane
RP_GGX = [  # distribution ggx, alpha 0.3, diffuse_reflectance (0.5, 0.3, 0.1), polypropylene in air
    ((0.0, 0.0, 0.0), (0.14473268389701843, 0.10051731765270233, 0.056301943957805634), 0.3958357572555542),
    ((0.5, 0.3, 2.0), (0.12045791745185852, 0.07861100882291794, 0.036764103919267654), 0.3202793300151825),
    ((1.2, 0.7, 0.5), (0.07480285316705704, 0.04546043276786804, 0.01611800491809845), 0.1650366336107254),
    ((0.3, 1.4, 3.0), (0.017158715054392815, 0.01121608354151249, 0.005273452028632164), 0.055567674338817596),
]


def test_rough_plastic_matches_mitsuba(device):
    from pathtracer.microfacet_tables import RES, external_transmittance, internal_reflectance

    eta = 1.49 / 1.000277
    table = external_transmittance(0.3, "ggx", eta)
    ri = internal_reflectance(0.3, "ggx", eta)

    def lerp(mu):  # Mitsuba's lerp_gather
        x = mu * (RES - 1)
        i = min(int(x), RES - 2)
        return table[i] + (table[i + 1] - table[i]) * (x - i)

    ang = np.array([a for a, _, _ in RP_GGX])
    wi = np.stack([np.sin(ang[:, 0]), 0 * ang[:, 0], np.cos(ang[:, 0])], 1)
    wo = np.stack([np.sin(ang[:, 1]) * np.cos(ang[:, 2]), np.sin(ang[:, 1]) * np.sin(ang[:, 2]), np.cos(ang[:, 1])], 1)
    t_i = np.array([lerp(m) for m in wi[:, 2]])
    t_o = np.array([lerp(m) for m in wo[:, 2]])
    w = 1.0 / (0.3 + 1.0)  # s_mean / (d_mean + s_mean)
    p_coat = (1 - t_i) * w / ((1 - t_i) * w + t_i * (1 - w))
    outs = [wp.zeros(len(wi), dtype=t, device=device) for t in (wp.vec3, float)]
    wp.launch(probe_rough_plastic, len(wi), inputs=[
        wp.array(wi.astype(np.float32), dtype=wp.vec3, device=device), wp.array(wo.astype(np.float32), dtype=wp.vec3,
                                                                              device=device),
        0.3, 1, eta, wp.vec3(0.5, 0.3, 0.1), ri, wp.array(t_i.astype(np.float32), dtype=float, device=device),
        wp.array(t_o.astype(np.float32), dtype=float, device=device),
        wp.array(p_coat.astype(np.float32), dtype=float, device=device)], outputs=outs, device=device)
    f_cos, pdf = (o.numpy() for o in outs)
    # the coat's tables are integrated by another quadrature than Mitsuba's: agreement to a few 1e-4 relative
    assert np.allclose(f_cos, [v for _, v, _ in RP_GGX], rtol=2e-3)
    assert np.allclose(pdf, [p for _, _, p in RP_GGX], rtol=2e-3)
