"""Solid-angle sampling of rectangular lights (kernels/sphrect.py, ``light_sampling="solid_angle"``).

1. ``sample_spherical_rectangle``: points on the rectangle, the solid angle against Van Oosterom-Strackee (two
   spherical triangles, float64), uniform in solid angle (chi-square over a grid of sub-rectangles, each expected
   to hold its own solid angle's share), finite at the edge cases (grazing, near, far, in the plane).
2. The renderer: irradiance under a square light against Lambert's polygon formula (|z| <= 4), with far less
   variance than area sampling; a Cornell box agrees with area sampling; non-rectangles fall back to area sampling.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import warp as wp

import stats
from helpers import add_quad, chi2_stat, chi2_upper, make_scene, material, polygon_irradiance
from kernels.sphrect import sample_spherical_rectangle
from pathtracer import load_file
from pathtracer.cli import UsageError, _render_kwargs, build_parser
from pathtracer.device_scene import DeviceScene, is_rectangle
from pathtracer.errors import RenderError
from pathtracer.render import Renderer
from stats import irradiance_scene

ROOT = Path(__file__).resolve().parents[1]


@wp.kernel
def _sample_kernel(o: wp.array(dtype=wp.vec3), s: wp.vec3, ex: wp.vec3, ey: wp.vec3, u: wp.array(dtype=wp.vec2),
                   p: wp.array(dtype=wp.vec3), omega: wp.array(dtype=float)):
    i = wp.tid()
    r = sample_spherical_rectangle(o[i], s, ex, ey, u[i][0], u[i][1])
    p[i] = r.p
    omega[i] = r.solid_angle


def sample(device, o, s, ex, ey, u):
    """(points (N, 3), solid angles (N,)) for shading points ``o`` (3,) or (N, 3) and uniforms ``u`` (N, 2)."""
    u = np.asarray(u, dtype=np.float32)
    n = len(u)
    o = np.broadcast_to(np.asarray(o, dtype=np.float32), (n, 3)).copy()
    with wp.ScopedDevice(device):
        p = wp.zeros(n, dtype=wp.vec3)
        om = wp.zeros(n, dtype=float)
        wp.launch(_sample_kernel, n, inputs=[wp.array(o, dtype=wp.vec3), wp.vec3(*s), wp.vec3(*ex), wp.vec3(*ey),
                                             wp.array(u, dtype=wp.vec2), p, om])
        return p.numpy().astype(np.float64), om.numpy().astype(np.float64)


def triangle_solid_angle(o, a, b, c) -> float:
    """Van Oosterom-Strackee: the solid angle of triangle abc seen from o (float64)."""
    a, b, c = (np.asarray(x, np.float64) - np.asarray(o, np.float64) for x in (a, b, c))
    la, lb, lc = (float(np.linalg.norm(x)) for x in (a, b, c))
    num = abs(float(np.dot(a, np.cross(b, c))))
    den = la * lb * lc + float(np.dot(a, b)) * lc + float(np.dot(a, c)) * lb + float(np.dot(b, c)) * la
    return 2.0 * math.atan2(num, den)


def rect_solid_angle(o, s, ex, ey) -> float:
    s, ex, ey = (np.asarray(x, np.float64) for x in (s, ex, ey))
    return triangle_solid_angle(o, s, s + ex, s + ex + ey) + triangle_solid_angle(o, s, s + ex + ey, s + ey)


def _rotation(axis, deg) -> np.ndarray:
    a = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    t = math.radians(deg)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + math.sin(t) * k + (1 - math.cos(t)) * k @ k


# a 1.2 x 0.6 rectangle in the plane z = 1, and the same one rotated and moved
RECTS = {
    "axis": (np.array([-0.5, -0.3, 1.0]), np.array([1.2, 0.0, 0.0]), np.array([0.0, 0.6, 0.0])),
}
_R = _rotation((0.3, 1.0, -0.4), 37.0)
RECTS["tilted"] = (_R @ RECTS["axis"][0] + np.array([0.2, -1.0, 0.5]), _R @ RECTS["axis"][1], _R @ RECTS["axis"][2])

# shading points in the frame of the axis rectangle (the tilted cases map them along with it)
POINTS = {
    "below": (0.0, 0.0, 0.0),
    "off axis": (1.5, -0.8, 0.2),
    "above": (0.3, 0.1, 1.7),  # the other side: the sampler does not care, the integrator does
    "near": (0.1, 0.05, 0.99),  # 0.01 below the light: solid angle close to 2 pi
    "grazing": (3.0, 0.2, 0.98),  # 0.02 below its plane, far to the side
    "far": (40.0, 25.0, -30.0),  # solid angle about 2e-4
}


def _case(rect: str, point: str):
    s, ex, ey = RECTS[rect]
    o = np.asarray(POINTS[point], np.float64)
    if rect == "tilted":
        o = _R @ o + np.array([0.2, -1.0, 0.5])
    return o, s.astype(np.float32).astype(np.float64), ex.astype(np.float32).astype(np.float64), \
        ey.astype(np.float32).astype(np.float64)


def _params(p, s, ex, ey):
    """(a, b) of points p = s + a ex + b ey, and the distances off the rectangle's plane."""
    d = p - s
    a = d @ ex / float(ex @ ex)
    b = d @ ey / float(ey @ ey)
    n = np.cross(ex, ey)
    off = np.abs(d @ (n / np.linalg.norm(n)))
    return a, b, off


CASES = [(r, p) for r in RECTS for p in POINTS]


@pytest.mark.parametrize("rect,point", CASES, ids=[f"{r}-{p}" for r, p in CASES])
def test_points_on_rectangle_and_solid_angle(device, rect, point):
    """Every sample lies on the rectangle (float32 rounding), and the solid angle is Van Oosterom-Strackee's to
    1e-5 relative; the corners of the unit square of uniforms also give finite points on it."""
    o, s, ex, ey = _case(rect, point)
    rng = np.random.default_rng(5)
    grid = np.array([[0, 0], [1, 0], [0, 1], [1, 1], [0.5, 0.5], [1 - 2**-24, 2**-24]])
    u = np.concatenate([grid, rng.random((4096, 2))]).astype(np.float32)
    p, om = sample(device, o, s, ex, ey, u)
    assert np.isfinite(p).all() and np.isfinite(om).all()
    expected = rect_solid_angle(o.astype(np.float32), s, ex, ey)
    assert np.all(om == om[0]) and om[0] > 0.0
    assert om[0] == pytest.approx(expected, rel=1e-5, abs=0.0), (om[0], expected)
    a, b, off = _params(p, s, ex, ey)
    scale = float(np.abs(s).max() + np.linalg.norm(ex) + np.linalg.norm(ey))
    assert off.max() < 4e-7 * (scale + np.abs(o).max())
    assert a.min() > -1e-5 and a.max() < 1 + 1e-5 and b.min() > -1e-5 and b.max() < 1 + 1e-5


CHI_CASES = [("axis", "below"), ("axis", "off axis"), ("axis", "near"), ("axis", "grazing"), ("tilted", "off axis"),
             ("tilted", "above")]


@pytest.mark.parametrize("rect,point", CHI_CASES, ids=[f"{r}-{p}" for r, p in CHI_CASES])
def test_uniform_in_solid_angle_chi_square(device, rect, point):
    """Split the rectangle into 8 x 8 sub-rectangles: the share of samples in each must be its solid angle over the
    whole one's (Van Oosterom-Strackee), chi-square at the 4-sigma level. Area sampling would give each cell the same
    share, which these cases tell apart (checked: its statistic is far above the bound)."""
    o, s, ex, ey = _case(rect, point)
    n, bins = 200_000, 8
    u = np.random.default_rng(11).random((n, 2)).astype(np.float32)
    p, om = sample(device, o, s, ex, ey, u)
    a, b, _ = _params(p, s, ex, ey)
    ia = np.clip((a * bins).astype(int), 0, bins - 1)
    ib = np.clip((b * bins).astype(int), 0, bins - 1)
    counts = np.bincount(ia * bins + ib, minlength=bins * bins)
    cell = np.array([[rect_solid_angle(o, s + i / bins * ex + j / bins * ey, ex / bins, ey / bins)
                      for j in range(bins)] for i in range(bins)]).reshape(-1)
    assert cell.sum() == pytest.approx(om[0], rel=1e-5)
    expected = n * cell / cell.sum()
    keep = expected >= 5.0
    c2 = chi2_stat(counts[keep], expected[keep])
    bound = chi2_upper(int(keep.sum()) - 1)
    uniform_area = chi2_stat(np.full(keep.sum(), n / bins**2), expected[keep])
    print(f"\n[stats] {rect}-{point}: chi2 {c2:.1f} (bound {bound:.1f}, dof {keep.sum() - 1}); "
          f"area sampling's expected counts would give {uniform_area:.1f}")
    assert keep.sum() >= 32
    assert c2 <= bound


def test_edge_cases_never_nan(device):
    """In the plane, a hair off it, very far, and at a corner: finite points, and a solid angle of 0 (the caller's
    signal to sample the area) exactly where the solid angle is tiny or 0."""
    s, ex, ey = RECTS["axis"]
    u = np.random.default_rng(3).random((256, 2)).astype(np.float32)
    for o, tiny in [((0.0, 0.0, 1.0), True), ((5.0, 0.0, 1.0), True), ((0.2, 0.1, 1.0 - 1e-7), False),
                    ((5.0, 0.0, 1.0 - 1e-6), True), ((1e4, 1e4, -1e4), True), ((-0.5, -0.3, 0.999), False),
                    ((0.7, 0.3, 1.0 + 1e-3), False)]:
        p, om = sample(device, o, s, ex, ey, u)
        assert np.isfinite(p).all() and np.isfinite(om).all(), o
        a, b, off = _params(p, s, ex, ey)
        assert off.max() < 1e-6 and a.min() > -1e-5 and a.max() < 1 + 1e-5 and b.min() > -1e-5 and b.max() < 1 + 1e-5
        if tiny:
            assert (om == 0.0).all(), (o, om[:3])
        else:
            assert om.min() > 0.0 and om[0] == pytest.approx(rect_solid_angle(np.float32(o), s, ex, ey), rel=1e-4)


# ------------------------------------------------------------------------------------------------
# the renderer

LE, RHO, H, S = 10.0, 0.5, 1.0, 0.5
IRR_CASES = {  # receiver point, receiver normal, camera distance, minimum variance ratio (area / solid angle)
    "on axis": ((0.0, 0.0, 0.0), (0.0, 0.0, 1.0), 0.5, 1.5),
    "off axis": ((0.8, 0.3, 0.0), (0.0, 0.0, 1.0), 0.5, 2.0),
    "tilted": ((0.3, -0.2, 0.1), (0.3, -0.5, 1.0), 0.5, 1.5),
    "near": ((0.1, 0.05, 0.9), (0.0, 0.0, 1.0), 0.15, 10.0),
}
IRR_SPP = 16


@pytest.mark.parametrize("case", list(IRR_CASES))
def test_irradiance_solid_angle_matches_polygon_formula(case):
    """rho E / pi with K = 1 solid-angle samples against Lambert's polygon formula (|z| <= 4 over 16 seeds), and the
    per-sample variance far below area sampling's on the same scene (max_depth 2: the sample is the NEE estimate)."""
    p, n, view_dist, min_ratio = IRR_CASES[case]
    scene, corners = irradiance_scene(p, n, (0.0, 0.0, H), S, LE, RHO, view_dist=view_dist)
    n_unit = np.asarray(n) / np.linalg.norm(n)
    expected = RHO / np.pi * polygon_irradiance(LE, p, n_unit, corners)
    var = {}
    for mode, seeds in (("solid_angle", range(0, 16)), ("area", range(100, 116))):
        r = Renderer(scene, device="cpu", max_depth=2, light_samples=1, light_sampling=mode)
        means, variances = stats.render_batches(r, IRR_SPP, seeds)
        batch_means = means[..., 0].mean(axis=(1, 2))
        _, se, _ = stats.assert_mean(batch_means, expected, name=f"{case}: rho E / pi, {mode}")
        var[mode] = variances[..., 0].mean()
    ratio = var["area"] / var["solid_angle"]
    print(f"\n[stats] {case}: variance area {var['area']:.4g}, solid angle {var['solid_angle']:.4g}, "
          f"ratio {ratio:.1f}")
    assert ratio > min_ratio


def test_cornell_box_agrees_with_area_sampling():
    """The Cornell box at 32 x 24: per seed the image mean with each light sampling, 16 seeds each, agree within
    4 SE (Welch), and so do the pixels (Sidak over the pixels)."""
    scene = load_file(ROOT / "scenes" / "cornell_box.xml", width=32, height=24)
    out = {}
    for mode, seeds in (("area", range(0, 16)), ("solid_angle", range(50, 66))):
        r = Renderer(scene, device="cpu", light_samples=1, light_sampling=mode)
        out[mode], _ = stats.render_batches(r, 16, seeds)
    stats.assert_agree(out["solid_angle"].mean(axis=(1, 2, 3)), out["area"].mean(axis=(1, 2, 3)),
                       name="cornell box image mean: solid angle vs area")
    stats.assert_pixels_agree(out["solid_angle"][..., 1], out["area"][..., 1], name="cornell box pixels (green)")


def test_rectangle_flag_and_option():
    """Only rectangles get the flag; a parallelogram light renders the same with either option (area sampling);
    unknown values are refused; the option is a compile-time feature, and the CLI passes it on."""
    assert is_rectangle((1, 0, 0), (0, 2, 0)) and is_rectangle((1, 0, 0), (1e-7, 2, 0))
    assert not is_rectangle((1, 0, 0), (1e-5, 2, 0)) and not is_rectangle((0, 0, 0), (0, 1, 0))
    scene = make_scene((0.0, 0.0, 0.5), (0.0, 0.0, 0.0), 0.05, 4, 4)
    add_quad(scene, [(-0.1, -0.1, 0), (0.1, -0.1, 0), (0.1, 0.1, 0), (-0.1, 0.1, 0)], (0, 0, 1),
             material(scene, "diffuse", 0.5))
    add_quad(scene, [(-0.3, -0.2, 1), (0.3, -0.2, 1), (0.5, 0.2, 1), (-0.1, 0.2, 1)], (0, 0, -1),
             material(scene, "diffuse", 0.0), radiance=5.0)
    assert DeviceScene(scene, "cpu").data.light_rect.numpy().tolist() == [0]
    imgs = [Renderer(scene, device="cpu", max_depth=2, light_sampling=m).render_passes(seed=3, count=4).sum
            for m in ("area", "solid_angle")]
    np.testing.assert_array_equal(imgs[0], imgs[1])
    assert Renderer(scene, device="cpu").light_sampling == "area"
    f = DeviceScene.features(scene, light_sampling="solid_angle")
    assert f != DeviceScene.features(scene) and f.light_sampling == 1
    with pytest.raises(RenderError, match="light sampling"):
        Renderer(scene, device="cpu", light_sampling="cosine")
    args = build_parser().parse_args(["x.xml", "-o", "y.exr", "--light-sampling", "solid_angle"])
    assert _render_kwargs(args)["light_sampling"] == "solid_angle"
    assert "light_sampling" not in _render_kwargs(build_parser().parse_args(["x.xml", "-o", "y.exr"]))
    with pytest.raises(UsageError, match="light-sampling"):
        build_parser().parse_args(["x.xml", "-o", "y.exr", "--light-sampling", "sphere"])
