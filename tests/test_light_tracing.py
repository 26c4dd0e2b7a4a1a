"""Light tracing for caustics (kernels/light_tracer.py, the ``light_tracing`` option).

- ``camera_importance`` (a probe): inverts the camera's ray mapping to the pixel, with the film-area Jacobian.
- Unbiased: with light tracing the path tracer leaves camera -> diffuse -> any bounces -> mirrors -> light to the
  light paths; the image must not change in expectation. In a room lit through a mirror the two renderings agree
  over the image and over 16 regions (B = 16 batches each, Welch tests), with flat and with leaning shading normals,
  to a fixed depth and with roulette; a copy of the code that still counts those paths in the path tracer too
  (double counting), drops them from both, or leaves out the flux factors of leaning normals fails this.
- Deterministic whatever the thread count; pass sums merge; the option compiles only where it applies.
(Agreement with Mitsuba with light tracing on: tests/test_mitsuba_refs.py.)
"""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

import probes
import stats
from helpers import add_rect, make_scene, material
from pathtracer.device_scene import camera_data
from pathtracer.render import Renderer
from pathtracer.scene import TriangleMesh


def leaning_rect(scene, center, half_u, half_v, mat: int, tilt: float, n: int = 6) -> None:
    """The parallelogram ``center + s half_u + t half_v`` (facing half_u x half_v) as an n x n-vertex grid of
    triangles whose vertex normals lean from the plane's normal by about ``tilt`` radians in a smooth pattern, as a
    curved surface's do on coarse triangles, and towards half_u on average (so that the shading cosines' errors do
    not average out)."""
    c, u, v = (np.asarray(x, dtype=np.float64) for x in (center, half_u, half_v))
    normal = np.cross(u, v) / np.linalg.norm(np.cross(u, v))
    s, t = (a.ravel() for a in np.meshgrid(np.linspace(-1, 1, n), np.linspace(-1, 1, n), indexing="ij"))
    verts = c + s[:, None] * u + t[:, None] * v
    lean = tilt * ((0.6 + np.sin(3.1 * s))[:, None] * u / np.linalg.norm(u)
                   + np.cos(3.4 * t + 0.4)[:, None] * v / np.linalg.norm(v))
    normals = normal + lean
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    quads = [(i * n + j, (i + 1) * n + j, (i + 1) * n + j + 1, i * n + j + 1)
             for i in range(n - 1) for j in range(n - 1)]
    faces = np.array([f for a, b, c_, d in quads for f in ((a, b, c_), (a, c_, d))])  # counter-clockwise about normal
    scene.meshes.append(TriangleMesh(verts, faces, normals, mat))


def rect(scene, center, half_u, half_v, mat: int, tilt: float) -> None:
    """The parallelogram facing half_u x half_v: ``add_rect``'s two triangles, or with ``tilt`` ``leaning_rect``."""
    if tilt == 0.0:
        n = np.cross(np.asarray(half_u, dtype=np.float64), np.asarray(half_v, dtype=np.float64))
        add_rect(scene, center, half_u, half_v, n, mat)
    else:
        leaning_rect(scene, center, half_u, half_v, mat, tilt)


def mirror_room(width: int = 32, height: int = 32, max_depth: int = 3, light_half: float = 0.8, wall: bool = False,
                tilt: float = 0.0):
    """A 4x4 floor seen from above, a vertical planar mirror at x = -2 facing +x, and a vertical light at x = 0
    facing the mirror: the floor gets direct light, and light reflected once by the mirror (a caustic).

    ``wall``: a diffuse back wall at z = -2, so that light reaches the floor through the mirror and then a diffuse
    bounce (camera -> floor -> wall -> mirror -> light). ``tilt``: the mirror and the wall become grids of triangles
    with leaning vertex normals (``leaning_rect``): reflection about the shading normal then does not keep the
    projected solid angle, and a diffuse bounce's shading cosine is not the geometric one, so the light tracer must
    weigh its flux for both."""
    s = make_scene((0.3, 6.0, 0.2), (0.0, 0.0, 0.0), 50, width, height, up=(0, 0, -1), max_depth=max_depth)
    add_rect(s, (0, 0, 0), (2, 0, 0), (0, 0, 2), (0, 1, 0), material(s, "diffuse", 0.5))
    rect(s, (-2, 1.5, 0), (0, 1.5, 0), (0, 0, 2), material(s, "mirror", 0.8), tilt)
    if wall:
        rect(s, (0, 1.5, -2), (2, 0, 0), (0, 1.5, 0), material(s, "diffuse", 0.7), tilt)
    add_rect(s, (0, 1.5, 0), (0, 0, light_half), (0, 0.5, 0), (-1, 0, 0), material(s, "diffuse", 0.0), radiance=5.0)
    return s


def lamp_under_mirror(max_depth: int, tilt: float, width: int = 32, height: int = 32):
    """A light facing up just under a mirror facing down (0.2 apart, beside a 4x4 floor's centre), and a diffuse
    back wall: the camera sees only the wall, which the light reaches mostly by mirror -> floor -> wall, so most of the
    light tracer's share is paths that go on after their first diffuse point. ``tilt``: the floor, the wall and the
    mirror lean their vertex normals (``leaning_rect``), the floor's towards the wall."""
    s = make_scene((0.0, 1.5, 1.8), (0.0, 1.5, -2.0), 40, width, height, max_depth=max_depth)
    floor, back, mirror = (material(s, "diffuse", 0.8), material(s, "diffuse", 0.7), material(s, "mirror", 0.8))
    rect(s, (0, 0, 0), (0, 0, -2), (-2, 0, 0), floor, tilt)
    rect(s, (0, 1.5, -2), (0, 1.5, 0), (-2, 0, 0), back, tilt)
    rect(s, (0, 0.8, 1), (0.4, 0, 0), (0, 0, 0.4), mirror, tilt)
    add_rect(s, (0, 0.6, 1), (0.3, 0, 0), (0, 0, 0.3), (0, 1, 0), material(s, "diffuse", 0.0), radiance=20.0)
    return s


def test_camera_importance_inverts_camera_rays(device):
    """Points along camera rays through random film points map back to their pixel, with the importance factor
    |ng . w| / (d^2 cos^3 theta A_pixel) and the near-plane distance; points behind, outside the view or closer than
    the near clip give pixel -1."""
    rng = np.random.default_rng(51)
    scene = make_scene((0.5, 1.0, 4.0), (0.0, 0.2, 0.0), 40, 24, 16, near_clip=0.5)
    cam = camera_data(scene)
    n = 2000
    cols, rows = rng.integers(0, 24, n), rng.integers(0, 16, n)
    jit = rng.uniform(0.05, 0.95, (n, 2))
    o, d, _ = probes.launch(probes.probe_camera, n, device,
                            [cam, probes.arr(cols, wp.int32, device), probes.arr(rows, wp.int32, device),
                             probes.arr(jit, wp.vec2, device)], [wp.vec3, wp.vec3, float])
    m = np.asarray(scene.camera.to_world)[:3, :3]
    origin = np.asarray(scene.camera.to_world)[:3, 3]
    dist = rng.uniform(1.0, 20.0, n)
    p = origin + d.astype(np.float64) * dist[:, None]
    ng = rng.normal(size=(n, 3))
    ng /= np.linalg.norm(ng, axis=1, keepdims=True)
    out = probes.launch(probes.probe_camera_importance, n, device,
                        [cam, probes.arr(p, wp.vec3, device), probes.arr(ng, wp.vec3, device)], [wp.vec4])
    assert (out[:, 0] == rows * 24 + cols).all()
    cos_c = (d.astype(np.float64) @ m[:, 2]) / np.linalg.norm(m[:, 2])
    a_pixel = 4 * cam.tan_x * cam.tan_y / (24 * 16)
    expect = np.abs(np.einsum("ij,ij->i", ng, d)) / (dist**2 * cos_c**3 * a_pixel)
    np.testing.assert_allclose(out[:, 1], expect, rtol=2e-4)
    np.testing.assert_allclose(out[:, 2], 0.5 / cos_c, rtol=1e-5)
    behind = origin - d.astype(np.float64) * 3.0
    too_near = origin + d.astype(np.float64) * 0.2
    outside = origin + (m @ np.array([5.0, 0.0, 1.0])) * 3.0
    pts = np.concatenate([behind[:10], too_near[:10], outside[None]])
    out2 = probes.launch(probes.probe_camera_importance, len(pts), device,
                         [cam, probes.arr(pts, wp.vec3, device), probes.arr(np.tile([0, 0, 1.0], (len(pts), 1)),
                                                                              wp.vec3, device)], [wp.vec4])
    assert (out2[:, 0] == -1).all()


def _batches(scene, light_tracing: bool, spp: int, seeds):
    r = Renderer(scene, device="cpu", light_tracing=light_tracing)
    assert r.light_tracing == light_tracing
    return stats.run_batches(lambda seed: r.render_passes(seed=seed, count=spp).mean, seeds)


@pytest.mark.parametrize("max_depth,wall,tilt", [(3, False, 0.0), (3, False, 0.35), (5, True, 0.0),
                                                 (-1, True, 0.35)])
def test_light_tracing_leaves_the_image_unchanged(max_depth, wall, tilt):
    """Path tracing alone and path + light tracing, 16 batches each, in the mirror room (the caustic is a large
    part of the floor's light): the image means and the means of 16 regions (8x8-pixel blocks) agree, Welch
    tests with a Sidak correction over the 17 comparisons. Also with a diffuse bounce between the mirror and the
    floor (the light tracer's paths go on after their first diffuse point, the path tracer leaves every path whose
    first hit is diffuse and whose light comes through mirrors to them), to a fixed depth and with roulette, and
    with a mirror whose shading normals lean (before the flux correction for them, 5.9 standard errors off)."""
    scene = mirror_room(light_half=0.8, max_depth=max_depth, wall=wall, tilt=tilt)
    pt = _batches(scene, False, 64, range(700, 716))
    lt = _batches(scene, True, 64, range(800, 816))
    stats.assert_agree(pt.mean(axis=(1, 2, 3)), lt.mean(axis=(1, 2, 3)), name="mirror room: path vs light tracing")
    blocks = lambda x: x.reshape(16, 4, 8, 4, 8, 3).mean(axis=(2, 4, 5)).reshape(16, -1)  # noqa: E731
    res = stats.assert_pixels_agree(blocks(pt), blocks(lt), name="mirror room, 16 regions")
    assert res.pass_fraction == 1.0
    # and the caustic is there: light tracing has it where the floor sees only the mirror image of the light
    assert lt.mean() > 0


@pytest.mark.parametrize("max_depth", [4, -1])
def test_light_tracing_after_a_diffuse_bounce(max_depth):
    """Light through a mirror, then the floor, then the wall the camera sees (lamp_under_mirror, normals leaning):
    the light tracer's paths carry on after the floor, weighed by the adjoint of the path tracer's diffuse bounce
    with its shading-normal factor. Image means agree (Welch); without that factor they were 5.9 and 6.2 standard
    errors apart, and the light tracer's share is about a quarter of the image."""
    scene = lamp_under_mirror(max_depth, tilt=0.35)
    pt = _batches(scene, False, 64, range(700, 716))
    lt = _batches(scene, True, 64, range(800, 816))
    stats.assert_agree(pt.mean(axis=(1, 2, 3)), lt.mean(axis=(1, 2, 3)), name="lamp under a mirror: path vs light")


def test_light_tracing_has_less_noise_on_the_caustic():
    """The point of it: per-pixel variance of the mean over the floor, light tracing against path tracing at the same
    spp (measured 44x lower here, asserted > 3x)."""
    scene = mirror_room(light_half=0.3)
    ratios = []
    for lt in (False, True):
        s = Renderer(scene, device="cpu", light_tracing=lt).render_passes(seed=3, count=256)
        ratios.append(np.mean(s.variance_of_mean))
    print(f"\n[light tracing] mean per-pixel variance: path tracing {ratios[0]:.3e}, with light tracing "
          f"{ratios[1]:.3e} ({ratios[0] / ratios[1]:.1f}x lower)")
    assert ratios[0] > 3 * ratios[1]


def test_light_tracing_deterministic_across_threads_and_merges():
    scene = mirror_room(16, 16)
    one = Renderer(scene, device="cpu", light_tracing=True, threads=1).render_passes(seed=9, count=8)
    two = Renderer(scene, device="cpu", light_tracing=True, threads=2).render_passes(seed=9, count=8)
    assert np.array_equal(one.mean, two.mean) and np.array_equal(one.lt_sum, two.lt_sum)
    r = Renderer(scene, device="cpu", light_tracing=True)
    a, b = r.render_passes(seed=9, first_pass=0, count=5), r.render_passes(seed=9, first_pass=5, count=3)
    merged = a + b
    np.testing.assert_allclose(merged.lt_sum, one.lt_sum, rtol=1e-12, atol=1e-300)
    np.testing.assert_allclose(merged.mean, one.mean, rtol=1e-6)
    assert np.all(np.isfinite(merged.variance_of_mean)) and (merged.variance_of_mean >= 0).all()


def test_light_tracing_only_where_it_applies():
    """No mirrors, max_depth < 3, or a debug view: the option is off and no light kernel is compiled."""
    plain = make_scene((0, 3, 3), (0, 0, 0), 40, 8, 8)
    add_rect(plain, (0, 0, 0), (1, 0, 0), (0, 0, 1), (0, 1, 0), material(plain, "diffuse", 0.5))
    add_rect(plain, (0, 2, 0), (0.2, 0, 0), (0, 0, 0.2), (0, -1, 0), material(plain, "diffuse", 0.0), radiance=1.0)
    for scene, kw in ((plain, {}), (mirror_room(8, 8, max_depth=2), {}), (mirror_room(8, 8), {"view": "normal"})):
        r = Renderer(scene, device="cpu", light_tracing=True, **kw)
        assert not r.light_tracing and r.light_kernel is None and not r.features.light_tracing
    assert Renderer(mirror_room(8, 8), device="cpu").light_tracing is False  # off by default
