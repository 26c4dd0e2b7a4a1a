"""End-to-end checks of the renderer against analytic ground truths (TESTING.md), on small images.

Exact truths are compared exactly. Statistical ones use B = 16 independent batches (seeds): each batch is the mean
over the pixels of interest of one seed's render, the standard error comes from the spread of the batches, and a
test passes at |z| <= 4. Every figure is also printed (``pytest -s``) for the record.

Compiled integrator variants used here (one cold compile each): meshes + lights (most tests), the same with the
seed's roulette rule, and meshes + spheres + mirrors + lights (mirror and invisible-sphere tests).
"""

from __future__ import annotations

import numpy as np
import pytest

import pathtracer
from helpers import (
    add_furnace_cube,
    add_rect,
    add_sphere,
    batch_z,
    furnace_radiance,
    make_scene,
    material,
    polygon_irradiance,
    square_axis_irradiance,
)
from pathtracer.render import Renderer

B = 16  # batches (seeds)
Z_MAX = 4.0


def batch_images(scene, device, spp, seeds=range(B), **opts):
    """One image per seed (B, H, W, 3) float64: seed s renders passes 0 .. spp - 1 of seed s."""
    r = Renderer(scene, device=device, **opts)
    imgs = np.array([r.render_passes(seed=s, first_pass=0, count=spp).mean for s in seeds], dtype=np.float64)
    assert np.isfinite(imgs).all()
    return imgs


def batches(scene, device, spp, mask=None, seeds=range(B), **opts):
    """Per-seed means over the pixels in ``mask`` (all by default), channel 0: (B,)."""
    imgs = batch_images(scene, device, spp, seeds, **opts)
    return masked_means(imgs, mask)


def masked_means(imgs, mask=None):
    px = imgs.reshape(len(imgs), -1, 3) if mask is None else imgs[:, mask]
    return px.mean(axis=1)[:, 0]


def report(name, expected, values):
    mean, se, z = batch_z(values, expected)
    print(f"\n[analytic] {name}: expected {expected:.6g}, got {mean:.6g} +- {se:.2g} (z = {z:+.2f})")
    return mean, se, z


# ------------------------------------------------------------------------------------------------
# truth 3: lights seen directly, through a mirror, from behind: exact

LE = (3.0, 5.0, 7.0)  # dyadic values: sums and means of equal samples are exact in float32
R_MIRROR = 0.75


def _direct_light_scene(facing_camera: bool):
    scene = make_scene((0, 0, 0), (0, 0, -1), 20, 16, 16)
    black = material(scene, "diffuse", 0.0)  # the seed's lights are black one-sided diffuse surfaces
    n = (0, 0, 1) if facing_camera else (0, 0, -1)
    add_rect(scene, (0, 0, -2), (2, 0, 0), (0, 2, 0), n, black, radiance=LE)
    return scene


def _mirror_scene(facing: bool):
    """Camera looks along -z at a 45-degree mirror that sends every camera ray up (+y) into a big light.

    An out-of-view sphere behind the camera makes this scene share its compiled variant with the furnace spheres.
    """
    scene = make_scene((0, 0, 0), (0, 0, -1), 10, 16, 16)
    black = material(scene, "diffuse", 0.0)
    mirror = material(scene, "mirror", R_MIRROR)
    s = 2 ** -0.5
    add_rect(scene, (0, 0, -2), (1, 0, 0), (0, s, -s), (0, s, s), mirror)
    add_rect(scene, (0, 3, -2), (3, 0, 0), (0, 0, 3), (0, -1, 0) if facing else (0, 1, 0), black, radiance=LE)
    add_sphere(scene, (0, 0, 5), 0.1, material(scene, "diffuse", 0.5))
    return scene


@pytest.mark.parametrize("max_depth", [1, 2, 5, -1])
def test_light_seen_directly_is_exactly_its_radiance(device, max_depth):
    img = pathtracer.render(_direct_light_scene(True), spp=4, max_depth=max_depth, seed=3, device=device,
                            progress=False)
    assert np.array_equal(img, np.broadcast_to(np.float32(LE), img.shape))
    # one-sided: from behind it is black, exactly
    img = pathtracer.render(_direct_light_scene(False), spp=4, max_depth=max_depth, seed=3, device=device,
                            progress=False)
    assert np.array_equal(img, np.zeros_like(img))


@pytest.mark.parametrize("max_depth", [1, 2, 3, -1])
def test_light_through_planar_mirror_is_exactly_r_times_radiance(device, max_depth):
    img = pathtracer.render(_mirror_scene(True), spp=4, max_depth=max_depth, seed=5, device=device, progress=False)
    # max_depth 1 stops at the mirror: nothing; from 2 on, exactly r Le (float32 products of dyadic numbers)
    expect = np.zeros(3, np.float32) if max_depth == 1 else np.float32(R_MIRROR) * np.float32(LE)
    assert np.array_equal(img, np.broadcast_to(expect, img.shape)), (img.min(axis=(0, 1)), img.max(axis=(0, 1)))
    img = pathtracer.render(_mirror_scene(False), spp=4, max_depth=max_depth, seed=5, device=device, progress=False)
    assert np.array_equal(img, np.zeros_like(img))


# ------------------------------------------------------------------------------------------------
# truth 1: on-axis irradiance under a square light


def _axis_scene(s: float, h: float, Le: float, rho: float):
    """Receiver z = 0 (albedo rho, facing +z), a square light of half-side s at height h facing it. The camera
    looks at the axis point (the origin) from at most 45 degrees and from outside the light's footprint, through a
    0.05 degree field of view: every pixel sees a point within 0.0013 h of the axis, where E differs from its axis
    value by a relative 2 (delta / h)^2 < 4e-6 (with 0.5 degrees the s/h = 0.05 case was biased by -1.6e-4, 25 SE)."""
    elev = np.arctan(min(1.0, 0.5 * h / s))  # the camera ray crosses the light's plane outside it
    eye = 2.0 * h * np.array([0.0, -np.cos(elev), np.sin(elev)])
    scene = make_scene(eye, (0, 0, 0), 0.05, 8, 8, up=(0, 0, 1))
    recv = material(scene, "diffuse", rho)
    black = material(scene, "diffuse", 0.0)
    add_rect(scene, (0, 0, 0), (20 * h, 0, 0), (0, 20 * h, 0), (0, 0, 1), recv)
    add_rect(scene, (0, 0, h), (s, 0, 0), (0, s, 0), (0, 0, -1), black, radiance=Le)
    return scene


def test_axis_irradiance_formula():
    """The closed form of TESTING.md against Lambert's polygon formula, and its quoted values."""
    for s, h in ((0.5, 1.0), (0.05, 1.0), (1.0, 3.0)):
        corners = [(-s, -s, h), (s, -s, h), (s, s, h), (-s, s, h)]
        assert square_axis_irradiance(1.0, s, h) == pytest.approx(polygon_irradiance(1.0, (0, 0, 0), (0, 0, 1),
                                                                                     corners), rel=1e-12)
    assert square_axis_irradiance(1.0, 0.5, 1.0) == pytest.approx(0.752275, abs=1e-6)
    assert square_axis_irradiance(1.0, 0.05, 1.0) == pytest.approx(0.009967, abs=1e-6)


@pytest.mark.parametrize("s_over_h", [0.5, 0.05, 2.0])
def test_on_axis_irradiance_under_square_light(device, s_over_h):
    h, Le, rho = 1.0, 10.0, 0.5
    s = s_over_h * h
    scene = _axis_scene(s, h, Le, rho)
    expected = rho / np.pi * square_axis_irradiance(Le, s, h)
    v = batches(scene, device, spp=16, max_depth=2, light_samples=8)  # K = 8: enough samples for the power check
    _, se, z = report(f"on-axis radiance rho E / pi, s/h = {s_over_h}", expected, v)
    assert abs(z) <= Z_MAX
    assert se < 0.01 * expected  # the test has power


# ------------------------------------------------------------------------------------------------
# truth 2: the furnace


def _furnace(a: float, Le: float = 1.0, spheres: bool = False):
    """Camera at the centre of the cube [-1, 1]^3 looking at the +z face through 60 degrees: every pixel sees the
    inside of one face, none straddles an edge. The six faces are one-sided lights that are also diffuse."""
    scene = make_scene((0, 0, 0), (0, 0, 1), 60, 16, 16)
    wall = material(scene, "diffuse", a)
    add_furnace_cube(scene, 1.0, wall, Le)
    if spheres:
        add_sphere(scene, (-0.3, 0.0, 0.6), 0.2, material(scene, "diffuse", 1.0))
        add_sphere(scene, (0.3, 0.0, 0.6), 0.2, material(scene, "mirror", 1.0))
    return scene


def test_furnace_max_depth_1_is_exactly_Le(device):
    img = pathtracer.render(_furnace(0.5, Le=3.0), spp=4, max_depth=1, device=device, progress=False)
    assert np.array_equal(img, np.full_like(img, 3.0))


FURNACE_CASES = [  # albedo, max_depth, roulette, spp per batch
    (0.5, 2, "throughput", 16),
    (0.5, 3, "throughput", 16),
    (0.8, 4, "throughput", 16),
    (0.3, 6, "throughput", 16),
    (0.5, -1, "throughput", 16),
    (0.8, -1, "throughput", 16),
    (0.5, -1, "seed", 16),
    (0.8, -1, "seed", 16),  # a^2 = 0.64 < 1 - 0.2: finite variance (TESTING.md truth 5)
    (0.5, 4, "seed", 16),
]


@pytest.mark.parametrize("a,max_depth,rr,spp", FURNACE_CASES)
def test_furnace(device, a, max_depth, rr, spp):
    """L = Le (1 - a^D) / (1 - a) for max_depth D (see helpers.furnace_radiance), Le / (1 - a) unlimited.

    Caveat measured while writing this: from max_depth 3 on, next-event estimation at secondary vertices near a
    cube edge has infinite variance (uniform area sampling of the adjacent face: the sample value ~ 1/eps^2 with
    probability ~ eps^2; tail P(F > t) ~ t^-1.5). The mean is right (a 1000-batch run gave z = +0.7), but batch
    means are right-skewed, so small-sample z values lean negative (about -2 here, occasionally beyond -4 for
    other seed sets). The seeds are fixed, so the test is deterministic.
    """
    Le = 1.0
    expected = furnace_radiance(Le, a, max_depth)
    v = batches(_furnace(a, Le), device, spp=spp, max_depth=max_depth, rr=rr, light_samples=1)
    _, se, z = report(f"furnace a = {a}, max_depth = {max_depth}, rr = {rr}", expected, v)
    assert abs(z) <= Z_MAX
    assert se < 0.02 * expected


def test_furnace_looking_into_a_corner(device):
    """Three faces, their edges and a corner in view (camera off-centre, looking at the corner (1, 1, 1)). Pixels
    that straddle an edge are excluded: those whose normal-view average (16 jittered rays) is not one face normal."""
    a, D, Le = 0.5, 3, 1.0
    scene = make_scene((-0.2, -0.1, -0.3), (1, 1, 1), 90, 24, 24)
    add_furnace_cube(scene, 1.0, material(scene, "diffuse", a), Le)
    normals = pathtracer.render(scene, spp=16, view="normal", device=device, progress=False)
    n = 2.0 * normals.astype(np.float64) - 1.0
    pure = np.isclose(np.abs(n).max(axis=2), 1.0, atol=1e-6) & (np.abs(n).sum(axis=2) < 1.0 + 1e-5)
    assert 0.5 * pure.size < pure.sum() < pure.size  # edges are in view, most pixels are not on them
    v = batches(scene, device, spp=16, mask=pure, max_depth=D, light_samples=1)
    _, _, z = report(f"furnace corner view a = {a}, max_depth = {D} ({pure.sum()} pixels)",
                     furnace_radiance(Le, a, D), v)
    assert abs(z) <= Z_MAX


@pytest.mark.parametrize("rr", ["throughput", "seed"])
def test_furnace_estimators_agree_across_light_samples(device, rr):
    """K = 1 and K = 4 light samples estimate the same radiance (Welch), whatever the roulette rule."""
    a, D = 0.5, 4
    v1 = batches(_furnace(a), device, spp=4, max_depth=D, rr=rr, light_samples=1)
    v4 = batches(_furnace(a), device, spp=4, max_depth=D, rr=rr, light_samples=4, seeds=range(100, 100 + B))
    z = (v1.mean() - v4.mean()) / np.sqrt(v1.var(ddof=1) / B + v4.var(ddof=1) / B)
    print(f"\n[analytic] furnace K=1 vs K=4 ({rr}): {v1.mean():.6g} vs {v4.mean():.6g} (Welch z = {z:+.2f})")
    assert abs(z) <= Z_MAX


def test_furnace_spheres_are_invisible(device):
    """A diffuse sphere of albedo 1 and a perfect mirror sphere inside the unlimited-depth furnace look exactly like
    the walls: Le / (1 - a) everywhere, on the sphere pixels as on the others."""
    a, Le = 0.5, 1.0
    expected = furnace_radiance(Le, a, -1)
    scene = _furnace(a, Le, spheres=True)
    # which pixels see which sphere: the normal view (sphere normals differ from the wall's (0, 0, -1) normal)
    normals = pathtracer.render(scene, spp=1, view="normal", device=device, progress=False, seed=0)
    wall_n = np.array([0.5, 0.5, 0.0])  # 0.5 n + 0.5 for n = (0, 0, -1)
    on_sphere = np.abs(normals - wall_n).max(axis=2) > 1e-3
    cols = np.arange(scene.width)[None, :].repeat(scene.height, axis=0)
    # the camera's image left is world +x (Mitsuba's lookat), so the diffuse sphere (x < 0) is on the right
    diffuse_px = on_sphere & (cols >= scene.width // 2)
    mirror_px = on_sphere & ~diffuse_px
    assert diffuse_px.sum() >= 4 and mirror_px.sum() >= 4
    imgs = batch_images(scene, device, spp=32, max_depth=-1, light_samples=1)
    for name, mask in (("diffuse sphere", diffuse_px), ("mirror sphere", mirror_px), ("walls", ~on_sphere)):
        _, _, z = report(f"furnace with spheres, {name} pixels ({mask.sum()})", expected, masked_means(imgs, mask))
        assert abs(z) <= Z_MAX
