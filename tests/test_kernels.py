"""Every ``@wp.func`` of ``kernels/`` through a tiny probe kernel (tests/probes.py), against numpy references.

Runs on the CPU, and on CUDA too when there is a device (the ``device`` fixture of conftest.py).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import trimesh
import warp as wp

import probes
from helpers import chi2_stat, chi2_upper, make_scene, material
from kernels.mesh import inside_point
from kernels.offset import max_abs
from kernels.sphere import SELF_FAR, SELF_NONE, SELF_SKIP
from pathtracer.device_scene import DeviceScene, camera_data
from pathtracer.scene import Sphere, TriangleMesh

ROOT = Path(__file__).resolve().parents[1]
FLT_EPS = float(np.finfo(np.float32).eps)


def unit(v):
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def f32unit(v):
    """Unit vectors rounded to float32 (what a kernel receives)."""
    return unit(v).astype(np.float32)


def random_dirs(rng, n):
    return f32unit(rng.normal(size=(n, 3)))


# ================================================================================================
# rng


def _rand(device, keys, dims):
    return probes.launch(probes.probe_rand, len(keys), device,
                         [probes.arr(keys, wp.vec3ui, device), probes.arr(dims, wp.uint32, device)], [wp.vec4])


def test_rand4_range_determinism_and_keys(device):
    rng = np.random.default_rng(1)
    n = 4096
    keys = rng.integers(0, 2**32, size=(n, 3), dtype=np.uint64).astype(np.uint32)
    keys[:4] = [[0, 0, 0], [2**32 - 1] * 3, [0, 0, 1], [1, 0, 0]]
    dims = rng.integers(0, 64, size=n).astype(np.uint32)
    a = _rand(device, keys, dims)
    b = _rand(device, keys, dims)
    assert a.dtype == np.float32
    assert np.array_equal(a, b), "same key and dim must give the same numbers"
    assert (a >= 0.0).all() and (a < 1.0).all()
    # 24-bit values: exact multiples of 2^-24
    assert np.array_equal(a * 2.0**24, np.floor(a * 2.0**24))
    # every component of the key, and the dimension, changes the numbers
    for col in range(3):
        k2 = keys.copy()
        k2[:, col] += np.uint32(1)
        c = _rand(device, k2, dims)
        assert np.mean(c == a) < 0.01, f"key component {col} does not change the draws"
    c = _rand(device, keys, dims + np.uint32(1))
    assert np.mean(c == a) < 0.01
    # the four lanes of one draw differ
    assert np.mean(a[:, 0] == a[:, 1]) < 0.01


def test_rand4_uniformity(device):
    """1e5 keys x 4 lanes: mean, variance and a 64-bin chi-square per lane, bounds at about 4 sigma."""
    n = 100_000
    pixel = np.arange(n, dtype=np.uint32)
    keys = np.stack([pixel, np.full(n, 3, np.uint32), np.full(n, 12345, np.uint32)], axis=1)
    a = _rand(device, keys, np.full(n, 5, np.uint32)).astype(np.float64)
    se_mean = math.sqrt(1.0 / 12.0 / n)
    se_var = math.sqrt((1.0 / 80.0 - 1.0 / 144.0) / n)
    bound = chi2_upper(63)
    for lane in range(4):
        x = a[:, lane]
        assert abs(x.mean() - 0.5) < 4 * se_mean, (lane, x.mean())
        assert abs(x.var() - 1.0 / 12.0) < 4 * se_var, (lane, x.var())
        counts = np.bincount((x * 64).astype(int), minlength=64)
        assert chi2_stat(counts, np.full(64, n / 64)) < bound, lane
    # no linear correlation between lanes, nor between consecutive pixels
    for i, j in ((0, 1), (1, 2), (2, 3), (0, 3)):
        assert abs(np.corrcoef(a[:, i], a[:, j])[0, 1]) < 4 / math.sqrt(n)
    assert abs(np.corrcoef(a[:-1, 0], a[1:, 0])[0, 1]) < 4 / math.sqrt(n)
    # the same pixels at consecutive dimensions are independent too
    b = _rand(device, keys, np.full(n, 6, np.uint32)).astype(np.float64)
    assert abs(np.corrcoef(a[:, 0], b[:, 0])[0, 1]) < 4 / math.sqrt(n)
    # 2-D uniformity of (lane 0, lane 1) on an 8x8 grid: 63 degrees of freedom
    cells = (a[:, 0] * 8).astype(int) * 8 + (a[:, 1] * 8).astype(int)
    assert chi2_stat(np.bincount(cells, minlength=64), np.full(64, n / 64)) < bound


# ================================================================================================
# sampling


def _sampling(device, ns, us, ds=None, center=(0.0, 0.0, 0.0), hu=(1.0, 0.0, 0.0), hv=(0.0, 1.0, 0.0), albedo=0.5):
    n = len(ns)
    if ds is None:
        ds = ns
    return probes.launch(
        probes.probe_sampling, n, device,
        [probes.arr(ns, wp.vec3, device), probes.arr(ds, wp.vec3, device), probes.arr(us, wp.vec4, device),
         wp.vec3(*center), wp.vec3(*hu), wp.vec3(*hv), float(albedo)],
        [wp.mat33, wp.vec3, wp.vec3, wp.vec3, wp.vec3, float])


def _special_normals():
    tiny = [1e-3, 1e-5, 1e-7, 1e-9, 0.0]
    out = [[0, 0, -1], [0, 0, 1], [1, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0], [1, 1, 0], [1, 0, -1e-8]]
    for e in tiny:
        out += [[e, 0, -1], [0, e, -1], [e, e, -1], [-e, e, -1], [e, 0, 1], [e, -e, 1]]
    return f32unit(np.array(out, dtype=np.float64))


def test_orthonormal_basis(device):
    rng = np.random.default_rng(2)
    k = 4000
    tilt = rng.normal(size=(k, 2)) * 10 ** rng.uniform(-8, -1, (k, 1))
    near_pole = f32unit(np.c_[tilt, np.where(np.arange(k) % 4 == 0, 1.0, -1.0)])  # mostly near -z
    ns = np.concatenate([_special_normals(), random_dirs(rng, 20000), near_pole])
    assert (near_pole[:, 2] < -0.99).sum() > 2000
    us = rng.random((len(ns), 4))
    basis = _sampling(device, ns, us)[0].astype(np.float64)
    eye = np.broadcast_to(np.eye(3), basis.shape)
    err = np.abs(np.einsum("nji,njk->nik", basis, basis) - eye).max(axis=(1, 2))
    assert err.max() < 2e-6, f"not orthonormal: {err.max()} at n = {ns[err.argmax()]}"
    det = np.linalg.det(basis)
    assert np.abs(det - 1.0).max() < 2e-6, "not right-handed"
    assert np.abs(basis[:, :, 2] - ns).max() < 1e-7, "third column must be n"
    assert np.isfinite(basis).all()


def test_cosine_hemisphere_density(device):
    rng = np.random.default_rng(3)
    n = 100_000
    us = rng.random((n, 4)).astype(np.float32)
    us[:4, :2] = [[0, 0], [0.999999, 0.999999], [0.5, 0], [0.25, 0.999999]]  # ends of the unit square
    ns = np.tile([0, 0, 1.0], (n, 1))
    d = _sampling(device, ns, us)[1].astype(np.float64)
    assert np.isfinite(d).all()
    assert np.abs(np.linalg.norm(d, axis=1) - 1.0).max() < 1e-6
    assert (d[:, 2] >= 0.0).all()
    # P(cos theta <= c) = c^2 for pdf cos/pi; 32 bins in cos theta
    edges = np.linspace(0.0, 1.0, 33)
    counts = np.histogram(np.clip(d[:, 2], 0, 1), bins=edges)[0]
    expected = n * np.diff(edges**2)
    assert chi2_stat(counts, expected) < chi2_upper(31)
    # azimuth uniform
    phi = np.arctan2(d[:, 1], d[:, 0])
    counts = np.histogram(phi, bins=np.linspace(-np.pi, np.pi, 33))[0]
    assert chi2_stat(counts, np.full(32, n / 32)) < chi2_upper(31)


def test_sample_cosine_around_and_lambert_weight(device):
    rng = np.random.default_rng(4)
    base = np.concatenate([_special_normals(), random_dirs(rng, 64)])
    reps = 1000
    ns = np.repeat(base, reps, axis=0)
    us = rng.random((len(ns), 4)).astype(np.float32)
    out = _sampling(device, ns, us, albedo=0.7)
    wi, weight = out[2].astype(np.float64), out[5]
    assert np.isfinite(wi).all()
    assert np.abs(np.linalg.norm(wi, axis=1) - 1.0).max() < 1e-6
    cos = np.einsum("ij,ij->i", wi, ns)
    assert cos.min() >= -1e-6, "direction below the hemisphere of n"
    # density about each n: chi-square of cos theta over 10 bins, per normal
    edges = np.linspace(0.0, 1.0, 11)
    bound = chi2_upper(9, 4.5)  # ~100 tests: a bit more margin
    for k in range(len(base)):
        c = np.clip(cos[k * reps:(k + 1) * reps], 0, 1)
        counts = np.histogram(c, bins=edges)[0]
        assert chi2_stat(counts, reps * np.diff(edges**2)) < bound, base[k]
    # TESTING.md truth 6: cosine sampling of a Lambertian BSDF has weight f cos / pdf = albedo: zero variance
    ok = cos > 1e-6
    assert np.abs(weight[ok] - np.float32(0.7)).max() <= 2 * FLT_EPS
    assert np.std(weight[ok]) < 1e-6


def test_sample_parallelogram(device):
    rng = np.random.default_rng(5)
    n = 100_000
    center, hu, hv = np.array([1.0, -2.0, 3.0]), np.array([0.5, 0.25, 0.0]), np.array([-0.1, 0.2, 0.7])
    us = rng.random((n, 4)).astype(np.float32)
    p = _sampling(device, np.tile([0, 0, 1.0], (n, 1)), us, center=center, hu=hu, hv=hv)[3].astype(np.float64)
    cov = (np.outer(hu, hu) + np.outer(hv, hv)) / 3.0
    se = np.sqrt(np.diag(cov) / n)
    assert (np.abs(p.mean(axis=0) - center) < 4 * se).all()
    emp = np.cov(p.T)
    assert np.abs(emp - cov).max() < 0.02 * np.abs(cov).max()
    # every point inside: solve for (s, t)
    st = np.linalg.lstsq(np.stack([hu, hv], axis=1), (p - center).T, rcond=None)[0]
    assert np.abs(st).max() <= 1.0 + 1e-5
    # the coordinates are uniform: s and t each flat on 20 bins
    for row in st:
        counts = np.histogram(row, bins=np.linspace(-1, 1, 21))[0]
        assert chi2_stat(counts, np.full(20, n / 20)) < chi2_upper(19)


def test_reflect(device):
    rng = np.random.default_rng(6)
    n = 10_000
    ns = random_dirs(rng, n)
    ds = random_dirs(rng, n)
    r = _sampling(device, ns, rng.random((n, 4)), ds=ds)[4].astype(np.float64)
    n64, d64 = ns.astype(np.float64), ds.astype(np.float64)
    ref = d64 - 2 * np.einsum("ij,ij->i", d64, n64)[:, None] * n64
    assert np.abs(r - ref).max() < 1e-6
    assert np.abs(np.linalg.norm(r, axis=1) - 1.0).max() < 1e-6
    assert np.abs(np.einsum("ij,ij->i", r, n64) + np.einsum("ij,ij->i", d64, n64)).max() < 1e-6
    # tangential part kept
    tan = lambda v: v - np.einsum("ij,ij->i", v, n64)[:, None] * n64  # noqa: E731
    assert np.abs(tan(r) - tan(d64)).max() < 1e-6


# ================================================================================================
# camera


def _camera_rays(device, scene, cols, rows, jit):
    cam = camera_data(scene)
    return probes.launch(probes.probe_camera, len(cols), device,
                         [cam, probes.arr(cols, wp.int32, device), probes.arr(rows, wp.int32, device),
                          probes.arr(jit, wp.vec2, device)], [wp.vec3, wp.vec3, float])


def seed_camera_dirs(eye, target, up, fovy_deg, w_px, h_px, cols, rows, jit):
    """The seed's camera (SCENES.md): w = -forward, u = right, v = up;
    alpha = tan(fovy/2) aspect (2 (i + x) / W - 1), beta = tan(fovy/2) (1 - 2 (j + y) / H)."""
    eye, target, up = (np.asarray(x, dtype=np.float64) for x in (eye, target, up))
    w = unit(eye - target)
    u = unit(np.cross(up, w))
    v = np.cross(w, u)
    t = math.tan(math.radians(fovy_deg) / 2)
    alpha = t * (w_px / h_px) * (2 * (cols + jit[:, 0]) / w_px - 1)
    beta = t * (1 - 2 * (rows + jit[:, 1]) / h_px)
    return unit(alpha[:, None] * u + beta[:, None] * v - w)


def test_camera_matches_seed_formula(device):
    W, H = 800, 600
    scene = make_scene((0, 0, 7), (0, 0, 4), 45, W, H, fov_axis="y", near_clip=0.0)
    rng = np.random.default_rng(7)
    rows, cols = np.divmod(np.arange(W * H), W)
    jit = rng.random((W * H, 2)).astype(np.float32)
    jit[:4] = [[0, 0], [0.999999, 0.999999], [0.5, 0.5], [0, 0.999999]]
    o, d, _ = _camera_rays(device, scene, cols, rows, jit)
    ref = seed_camera_dirs((0, 0, 7), (0, 0, 4), (0, 1, 0), 45, W, H, cols, rows, jit.astype(np.float64))
    assert np.abs(d - ref).max() < 1e-6
    assert np.abs(o - [0, 0, 7]).max() == 0.0
    # row 0 is the top, column 0 the left (u = right = +x here)
    img = d.reshape(H, W, 3)
    assert (img[0, :, 1] > 0).all() and (img[-1, :, 1] < 0).all()
    assert (img[:, 0, 0] < 0).all() and (img[:, -1, 0] > 0).all()
    # the image centre (a pixel corner for an even size) looks straight along -z
    c = _camera_rays(device, scene, np.array([W // 2]), np.array([H // 2]), np.zeros((1, 2)))[1][0]
    assert np.abs(c - [0, 0, -1]).max() < 1e-7
    # the edges of the vertical field of view are at +-22.5 degrees
    top = _camera_rays(device, scene, np.array([W // 2]), np.array([0]), np.zeros((1, 2)))[1][0]
    assert math.degrees(math.atan2(top[1], -top[2])) == pytest.approx(22.5, abs=1e-4)


def test_camera_general_lookat_and_middle_pixel(device):
    """A tilted camera against the seed formula, and the pixel-centre ray of the middle pixel of an odd image."""
    eye, target, up = (1.0, 2.0, -3.0), (-0.5, 0.3, 2.0), (0.1, 1.0, 0.2)
    W, H = 17, 13
    scene = make_scene(eye, target, 37.0, W, H, up=up, fov_axis="y", near_clip=0.0)
    rows, cols = np.divmod(np.arange(W * H), W)
    jit = np.full((W * H, 2), 0.5)
    _, d, _ = _camera_rays(device, scene, cols, rows, jit)
    ref = seed_camera_dirs(eye, target, up, 37.0, W, H, cols, rows, jit)
    assert np.abs(d - ref).max() < 1e-6
    mid = d.reshape(H, W, 3)[H // 2, W // 2]
    assert np.abs(mid - unit(np.subtract(target, eye))).max() < 1e-6


def test_camera_near_far_clip(device):
    W, H = 32, 24
    rng = np.random.default_rng(8)
    rows, cols = rng.integers(0, H, 500), rng.integers(0, W, 500)
    jit = rng.random((500, 2))
    eye = np.array([0.0, 0.0, 7.0])
    fwd = np.array([0.0, 0.0, -1.0])
    s0 = make_scene(eye, (0, 0, 4), 45, W, H, fov_axis="y", near_clip=0.0, far_clip=100.0)
    s1 = make_scene(eye, (0, 0, 4), 45, W, H, fov_axis="y", near_clip=0.5, far_clip=100.0)
    o0, d0, t0 = _camera_rays(device, s0, cols, rows, jit)
    o1, d1, t1 = _camera_rays(device, s1, cols, rows, jit)
    assert np.array_equal(d0, d1)
    assert np.abs(o0 - eye).max() == 0.0
    # the origin moves onto the near plane along the ray, and the ray ends on the far plane
    assert np.abs((o1 - eye) @ fwd - 0.5).max() < 1e-6
    cosz = d1 @ fwd
    assert np.abs(np.cross(o1 - eye, d1)).max() < 1e-6
    assert np.abs(t0 * cosz - 100.0).max() < 1e-3
    assert np.abs(((o1 + t1[:, None] * d1) - eye) @ fwd - 100.0).max() < 1e-3


@pytest.mark.parametrize("axis", ["x", "y"])
def test_camera_fov_axis(device, axis):
    W, H = 40, 20  # aspect 2
    fov = 60.0
    scene = make_scene((0, 0, 0), (0, 0, -1), fov, W, H, fov_axis=axis, near_clip=0.0)
    t = math.tan(math.radians(fov / 2))
    # left edge, vertical middle; top edge, horizontal middle (film points exactly on the edges)
    _, d, _ = _camera_rays(device, scene, np.array([0, W // 2]), np.array([H // 2, 0]), np.zeros((2, 2)))
    left, top = d.astype(np.float64)
    tx, ty = (t, t / 2) if axis == "x" else (2 * t, t)
    assert left[0] / -left[2] == pytest.approx(-tx, rel=1e-6)
    assert top[1] / -top[2] == pytest.approx(ty, rel=1e-6)


# ================================================================================================
# ray-sphere


def sphere_ref(o, d, c, r, tmax, far_only=False):
    """Nearest root in (0, tmax) in long double, for the rays exactly as given (d need not be unit).

    Also returns the discriminant over r^2 (how far from tangency). far_only: only the far root counts.
    """
    ld = np.longdouble
    o, d, c, r, tmax = (np.asarray(x).astype(ld) for x in (o, d, c, r, tmax))
    oc = o - c
    a = (d * d).sum(axis=1)
    b = (oc * d).sum(axis=1)
    f = oc - (b / a)[:, None] * d
    disc = r * r - (f * f).sum(axis=1)  # r^2 - (distance of the centre from the line)^2
    hit = disc >= 0
    sq = np.sqrt(np.maximum(disc, 0) * a)
    q = -b - np.where(b >= 0, sq, -sq)
    cc = (oc * oc).sum(axis=1) - r * r
    with np.errstate(divide="ignore", invalid="ignore"):
        t0, t1 = q / a, cc / q
    t0, t1 = np.minimum(t0, t1), np.maximum(t0, t1)
    t = np.where((t1 > 0) & (t1 < tmax), t1, -1)
    if not far_only:
        t = np.where((t0 > 0) & (t0 < tmax), t0, t)
    t = np.where(hit, t, -1)
    return t.astype(np.float64), (disc / (r * r)).astype(np.float64)


def _sphere(device, o, d, c, r, tmax, mode):
    n = len(o)
    return probes.launch(probes.probe_sphere, n, device,
                         [probes.arr(o, wp.vec3, device), probes.arr(d, wp.vec3, device),
                          probes.arr(c, wp.vec3, device), probes.arr(np.broadcast_to(r, (n,)), float, device),
                          probes.arr(np.broadcast_to(tmax, (n,)), float, device),
                          probes.arr(np.broadcast_to(mode, (n,)), wp.int32, device)], [float])


def _sphere_cases(rng):
    """(name, o, d, c, r) float32 ray and sphere sets."""
    cases = []
    n = 20000
    # generic: spheres in a 20-unit box, rays toward random points near them
    c = rng.uniform(-10, 10, (n, 3))
    r = rng.uniform(0.05, 5, n)
    o = rng.uniform(-10, 10, (n, 3))
    aim = c + rng.normal(size=(n, 3)) * r[:, None]
    cases.append(("generic", o, aim - o, c, r))
    # far and tiny: distance / radius = 1e4, 1e5 (radius 1 far away, radius 1e-4 at distance 1..10)
    for ratio in (1e4, 1e5):
        for radius in (1.0, 1e-4):
            dist = ratio * radius
            dirs = unit(rng.normal(size=(n, 3)))
            o = rng.uniform(-1, 1, (n, 3)) * radius
            c = o + dirs * dist
            aim = c + rng.uniform(-1.3, 1.3, (n, 3)) * radius
            cases.append((f"far{ratio:.0e}_r{radius:g}", o, aim - o, c, np.full(n, radius)))
    # huge ground spheres, camera 1 unit above the surface, rays down and toward the horizon
    for radius in (1e3, 1e4, 1e5):
        c = np.tile([0.0, -radius - 1.0, 0.0], (n, 1))
        o = np.zeros((n, 3)) + rng.uniform(-1, 1, (n, 3)) * [1, 0, 1]
        elev = -np.concatenate([rng.uniform(0, np.pi / 2, n // 2), 10 ** rng.uniform(-5, -1, n - n // 2)])
        az = rng.uniform(0, 2 * np.pi, n)
        d = np.stack([np.cos(elev) * np.cos(az), np.sin(elev), np.cos(elev) * np.sin(az)], axis=1)
        cases.append((f"ground{radius:.0e}", o, d, c, np.full(n, radius)))
    # grazing: rays passing at distance r (1 +- eps) from the centre
    c = rng.uniform(-5, 5, (n, 3))
    r = rng.uniform(0.1, 3, n)
    d = unit(rng.normal(size=(n, 3)))
    perp = unit(np.cross(d, rng.normal(size=(n, 3))))
    eps = np.concatenate([10 ** rng.uniform(-7, -1, n // 2), -(10 ** rng.uniform(-7, -1, n - n // 2))])
    closest = c + perp * (r * (1 + eps))[:, None]
    o = closest - d * rng.uniform(0.5, 20, n)[:, None]
    cases.append(("grazing", o, d, c, r))
    # from inside
    c = rng.uniform(-5, 5, (n, 3))
    r = rng.uniform(0.1, 3, n)
    o = c + unit(rng.normal(size=(n, 3))) * (r * rng.uniform(0, 0.999, n))[:, None]
    cases.append(("inside", o, rng.normal(size=(n, 3)), c, r))
    return [(name, o.astype(np.float32), f32unit(d), c.astype(np.float32), r.astype(np.float32))
            for name, o, d, c, r in cases]


def test_ray_sphere_against_float64_reference(device):
    rng = np.random.default_rng(9)
    for name, o, d, c, r in _sphere_cases(rng):
        t = _sphere(device, o, d, c, r, np.float32(3e38), SELF_NONE).astype(np.float64)
        ref, margin = sphere_ref(o, d, c, r, 3e38)
        assert np.isfinite(t).all(), name
        agree = (t >= 0) == (ref >= 0)
        # disagreements may only be rays within float rounding of tangency
        assert agree.mean() >= 0.9999, f"{name}: hit/miss agree on {agree.mean():.6f}"
        assert (np.abs(margin[~agree]) < 1e-5).all(), f"{name}: a clear hit or miss was wrong"
        both = (t >= 0) & (ref >= 0)
        rel = np.abs(t[both] - ref[both]) / ref[both]
        assert rel.max() < 1e-5, f"{name}: t off by {rel.max():.2e}"
        if name == "inside":
            assert (t >= 0).all() and both.all()
        if name.startswith("far") or name.startswith("ground"):
            assert both.mean() > 0.3, f"{name}: too few hits to test"


def test_ray_sphere_tmax(device):
    rng = np.random.default_rng(10)
    n = 5000
    c = np.zeros((n, 3), np.float32)
    o = np.tile(np.float32([0, 0, -5]), (n, 1))
    d = np.tile(np.float32([0, 0, 1]), (n, 1))
    tmax = rng.uniform(0, 10, n).astype(np.float32)
    t = _sphere(device, o, d, c, np.float32(1.0), tmax, SELF_NONE)
    expect = np.where(tmax > 4, 4.0, -1.0)  # the near root, or nothing (the far root 6 is beyond tmax then)
    assert np.array_equal(t, expect.astype(np.float32))
    # from inside the sphere, only the far root, and only below tmax
    o[:] = [0, 0, 0.25]
    t = _sphere(device, o, d, c, np.float32(1.0), tmax, SELF_NONE)
    assert np.array_equal(t, np.where(tmax > 0.75, 0.75, -1.0).astype(np.float32))


def test_ray_sphere_self_modes(device):
    """Rays that start on the sphere: SELF_SKIP never hits it; SELF_FAR returns the exit point, never ~0."""
    rng = np.random.default_rng(11)
    n = 20000
    c = rng.uniform(-100, 100, (n, 3)).astype(np.float32)
    r = (10 ** rng.uniform(-2, 2, n)).astype(np.float32)
    nrm = unit(rng.normal(size=(n, 3)))
    p = (c + nrm * r[:, None]).astype(np.float32)  # on the surface up to float rounding
    d = random_dirs(rng, n)
    inward = np.einsum("ij,ij->i", d, nrm) < 0
    d[~inward] *= -1  # all inward
    t_skip = _sphere(device, p, d, c, r, np.float32(3e38), SELF_SKIP)
    assert (t_skip == -1.0).all()
    t_far = _sphere(device, p, d, c, r, np.float32(3e38), SELF_FAR).astype(np.float64)
    # reference: the far root from the start point as rounded to float32; that point may lie just outside the
    # sphere, so a grazing inward ray can truly miss it (those within rounding of tangency are not judged)
    ref_far, margin = sphere_ref(p, d, c, r, 3e38, far_only=True)
    clear = margin > 1e-5
    assert clear.mean() > 0.99
    assert (t_far[clear] > 0).all(), "SELF_FAR lost the exit point"
    assert (np.abs(t_far[clear] - ref_far[clear]) <= 1e-5 * ref_far[clear]).all()
    chord = -2.0 * r * np.einsum("ij,ij->i", d, nrm)
    assert (t_far[clear] > 0.5 * chord[clear]).all()  # the exit, not the entry point
    assert (t_far[~clear & (margin < -1e-5)] < 0).all()
    # outward rays with SELF_SKIP see nothing
    assert (_sphere(device, p, -d, c, r, np.float32(3e38), SELF_SKIP) == -1.0).all()


# ================================================================================================
# mesh


def moller_trumbore(o, d, tris, chunk=256):
    """Brute-force nearest hit (float64): t, face, MT barycentrics (u weights v1, v weights v2) and, per ray,
    an ambiguity flag: some triangle at or before the nearest hit has an edge within 1e-5 (barycentric) of the ray."""
    o, d, tris = (np.asarray(x, dtype=np.float64) for x in (o, d, tris))
    v0, e1, e2 = tris[:, 0], tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]
    n = len(o)
    best_t = np.full(n, np.inf)
    best_f = np.full(n, -1)
    best_u = np.zeros(n)
    best_v = np.zeros(n)
    amb = np.zeros(n, bool)
    for s in range(0, n, chunk):
        oo, dd = o[s:s + chunk, None, :], d[s:s + chunk, None, :]
        pvec = np.cross(dd, e2[None])
        det = (e1[None] * pvec).sum(-1)
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / det
            tvec = oo - v0[None]
            u = (tvec * pvec).sum(-1) * inv
            qvec = np.cross(tvec, e1[None])
            v = (dd * qvec).sum(-1) * inv
            t = (e2[None] * qvec).sum(-1) * inv
        margin = np.minimum(np.minimum(u, v), 1 - u - v)
        valid = np.isfinite(t) & (t > 0)
        hit = valid & (margin >= 0)
        th = np.where(hit, t, np.inf)
        f = th.argmin(axis=1)
        rows = np.arange(len(f))
        bt = th[rows, f]
        best_t[s:s + chunk] = bt
        best_f[s:s + chunk] = np.where(np.isfinite(bt), f, -1)
        best_u[s:s + chunk] = u[rows, f]
        best_v[s:s + chunk] = v[rows, f]
        near_edge = valid & (np.abs(margin) < 1e-5) & (t <= bt[:, None] * (1 + 1e-5))
        # also: a second triangle at (nearly) the same distance (shared edges, coplanar overlaps)
        with np.errstate(invalid="ignore"):
            tie = hit & (np.abs(th - bt[:, None]) <= 1e-5 * bt[:, None])
        amb[s:s + chunk] = near_edge.any(axis=1) | (tie.sum(axis=1) > 1) | (np.abs(det[rows, f]) < 1e-12)
    return best_t, best_f, best_u, best_v, amb


def _ray_triangle(device, o, d, a, b, c, tmax=None):
    n = len(o)
    tmax = np.full(n, 3.0e38) if tmax is None else tmax
    tuv, box_dir = probes.launch(probes.probe_ray_triangle, n, device,
                                 [probes.arr(x, wp.vec3, device) for x in (o, d, a, b, c)]
                                 + [probes.arr(tmax, float, device)], [wp.vec3, wp.vec3])
    return tuv, box_dir


def _moller_trumbore_pairs(o, d, tri):
    """float64 Moller-Trumbore of ray k against triangle k: t (inf on a miss), MT u (weights v1), v (weights v2),
    and the distance of the hit to the triangle's edges in barycentric units (negative outside)."""
    o, d, tri = (np.asarray(x, dtype=np.float64) for x in (o, d, tri))
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    p = np.cross(d, e2)
    det = (e1 * p).sum(1)
    tv = o - tri[:, 0]
    u = (tv * p).sum(1) / det
    q = np.cross(tv, e1)
    v = (d * q).sum(1) / det
    t = (e2 * q).sum(1) / det
    margin = np.minimum(np.minimum(u, v), 1 - u - v)
    return np.where((margin >= 0) & (t > 0), t, np.inf), u, v, margin


def test_ray_triangle_against_float64(device):
    """The watertight test alone against float64 Moller-Trumbore at scales 1e-3 to 1e3: same hit/miss away from
    edges, same t and barycentrics (u weights a, v weights b), hit from either side; tmax is an open bound."""
    rng = np.random.default_rng(31)
    n = 20000
    tri = (rng.normal(size=(n, 3, 3)) * rng.choice([1e-3, 1.0, 1e3], (n, 1, 1))).astype(np.float32)
    bary = rng.uniform(-0.2, 1.2, (n, 3))
    target = np.einsum("nk,nkj->nj", bary / bary.sum(axis=1, keepdims=True), tri.astype(np.float64))
    scale = np.abs(tri).max(axis=(1, 2))
    o = (target + scale[:, None] * 3 * unit(rng.normal(size=(n, 3)))).astype(np.float32)
    d = f32unit(target - o)
    tuv, box_dir = _ray_triangle(device, o, d, tri[:, 0], tri[:, 1], tri[:, 2])
    bt, bu, bv, margin = _moller_trumbore_pairs(o, d, tri)
    hit, ref_hit, clear = tuv[:, 0] >= 0, np.isfinite(bt), np.abs(margin) > 1e-4
    assert clear.mean() > 0.98 and 0.3 < ref_hit.mean() < 0.9
    assert (hit == ref_hit)[clear].all()
    both = clear & ref_hit
    # float32 rounding of the vertices relative to the origin moves the plane by ~eps (t + scale), and t by that
    # over |cos| of the incidence angle (the grazing rays here reach |cos| ~ 1e-4); 8x the bound measured (1.3x)
    nrm = unit(np.cross(tri[:, 1].astype(np.float64) - tri[:, 0], tri[:, 2].astype(np.float64) - tri[:, 0]))
    cos = np.abs((nrm * d).sum(axis=1))
    bound = 8 * FLT_EPS * (bt + scale) / cos
    assert (np.abs(tuv[both, 0] - bt[both]) <= bound[both]).all()
    # the barycentrics give the same point as float64 (their own error is conditioned like t's)
    w = np.stack([tuv[:, 1], tuv[:, 2], 1 - tuv[:, 1] - tuv[:, 2]], axis=1).astype(np.float64)
    p = np.einsum("nk,nkj->nj", w, tri.astype(np.float64))
    p_ref = np.einsum("nk,nkj->nj", np.stack([1 - bu - bv, bu, bv], axis=1), tri.astype(np.float64))
    assert (np.linalg.norm(p - p_ref, axis=1)[both] <= bound[both]).all()
    good = both & (cos > 0.1)
    assert np.abs(tuv[good, 1] - (1 - bu - bv)[good]).max() < 1e-4
    assert np.abs(tuv[good, 2] - bu[good]).max() < 1e-4
    # tmax is an open bound: a limit at the hit distance (rounded down) rejects it
    hits = np.flatnonzero(hit)
    lim = np.nextafter(tuv[hits, 0], np.float32(0))
    tuv2, _ = _ray_triangle(device, o[hits], d[hits], tri[hits, 0], tri[hits, 1], tri[hits, 2], lim)
    assert (tuv2[:, 0] < 0).all()
    assert (np.abs(box_dir) >= 1e-30).all()


def test_ray_triangle_shared_edges_are_watertight(device):
    """Two triangles sharing an edge (abc and bad, folded by a random angle), rays aimed at float32 points of the
    shared edge from directions that see both from the same side: every ray hits one of them, at the edge."""
    rng = np.random.default_rng(32)
    n = 200000
    a = rng.normal(size=(n, 3))
    b = a + unit(rng.normal(size=(n, 3))) * rng.uniform(0.1, 2, (n, 1))
    e = unit(b - a)
    side = unit(np.cross(e, rng.normal(size=(n, 3))))
    nrm = np.cross(e, side)
    fold = rng.uniform(-0.6, 0.6, (n, 1))
    c = 0.5 * (a + b) + side * rng.uniform(0.2, 1, (n, 1))
    dd = 0.5 * (a + b) - (np.cos(fold) * side + np.sin(fold) * nrm) * rng.uniform(0.2, 1, (n, 1))
    a, b, c, dd = (x.astype(np.float32) for x in (a, b, c, dd))
    s = rng.uniform(0.01, 0.99, (n, 1))
    target = (a + s * (b - a)).astype(np.float32).astype(np.float64)
    w = unit(nrm + 0.3 * rng.normal(size=(n, 3)))
    # keep the rays that see both faces from the same side (then the two cover the edge's neighbourhood)
    n1 = np.cross(b.astype(np.float64) - a, c.astype(np.float64) - a)
    n2 = np.cross(a.astype(np.float64) - b, dd.astype(np.float64) - b)
    ok = (np.sign((n1 * w).sum(1)) == np.sign((n2 * w).sum(1))) & (np.abs((unit(n1) * w).sum(1)) > 0.05) \
        & (np.abs((unit(n2) * w).sum(1)) > 0.05)
    o = (target + 3 * w).astype(np.float32)[ok]
    d = f32unit(target[ok] - o)
    h1, _ = _ray_triangle(device, o, d, a[ok], b[ok], c[ok])
    h2, _ = _ray_triangle(device, o, d, b[ok], a[ok], dd[ok])
    neither = (h1[:, 0] < 0) & (h2[:, 0] < 0)
    print(f"\n[kernels] shared edges: {int(ok.sum())} rays, {int(neither.sum())} hit neither triangle")
    assert ok.sum() > 0.3 * n and not neither.any()
    t = np.where(h1[:, 0] >= 0, h1[:, 0], h2[:, 0])
    assert np.abs(t - 3).max() < 1e-5


def test_ray_triangle_special_rays(device):
    """Axis-aligned rays (zero direction components) hit; a ray in the triangle's plane, a zero-area triangle and a
    triangle behind the origin are missed; an origin on the triangle hits at t = 0."""
    tri = np.float32([[-1, -1, 0], [1, -1, 0], [0, 1, 0]])
    o = np.float32([[0, 0, 2], [0, 0, -2], [0.1, 0.1, 2], [-3, 0, 0], [0, 0, 2], [0, 0, -2], [0, 0, 0]])
    d = np.float32([[0, 0, -1], [0, 0, 1], [0, 0, -1], [1, 0, 0], [0, 0, -1], [0, 0, -1], [0, 0, 1]])
    a, b, c = (np.repeat(tri[None, k], len(o), axis=0) for k in range(3))
    b[4] = a[4]  # zero area
    tuv, box_dir = _ray_triangle(device, o, d, a, b, c)
    assert np.allclose(tuv[:3, 0], 2.0) and (tuv[3:6, 0] < 0).all() and tuv[6, 0] == 0.0
    assert (np.abs(box_dir) > 0).all()


def _mesh_scene(vertices, faces, normals=None):
    scene = make_scene((0, 0, 5), (0, 0, 0), 45, 4, 4)
    m = material(scene, "diffuse", 0.5)
    scene.meshes.append(TriangleMesh(np.asarray(vertices, np.float64), np.asarray(faces, np.int64), normals, m))
    return scene


def _mesh_query(device, scene, o, d, triangles="wide"):
    ds = DeviceScene(scene, device, triangles)
    res = probes.launch(probes.probe_mesh, len(o), device,
                        [ds.data, probes.arr(o, wp.vec3, device), probes.arr(d, wp.vec3, device)],
                        [wp.int32, float, wp.vec2, wp.vec3, wp.vec3, wp.vec3])
    return res


def _check_mesh_against_brute_force(device, verts, faces, o, d, normals=None, min_hits=0.2, triangles="wide"):
    verts = np.asarray(verts, np.float32)
    scene = _mesh_scene(verts, faces, normals)
    face, t, uv, p, ng, ns = _mesh_query(device, scene, o, d, triangles)
    tris = verts[faces]
    bt, bf, bu, bv, amb = moller_trumbore(o, d, tris)
    assert amb.mean() < 0.01
    clear = ~amb
    assert ((face >= 0) == (bf >= 0))[clear].all(), "hit/miss differs from brute force"
    assert (face == bf)[clear].all(), "nearest face differs from brute force"
    both = clear & (bf >= 0)
    assert both.mean() > min_hits
    assert (np.abs(t[both] - bt[both]) <= 1e-5 * bt[both]).all()
    # Warp's barycentrics: u weights vertex 0, v vertex 1 (MT's u weights vertex 1, v vertex 2)
    w0, w1 = 1 - bu - bv, bu
    assert np.abs(uv[both, 0] - w0[both]).max() < 1e-4
    assert np.abs(uv[both, 1] - w1[both]).max() < 1e-4
    # so mesh_hit's point u a + v b + (1 - u - v) c is on the ray
    on_ray = o.astype(np.float64) + t[:, None].astype(np.float64) * d
    scale = np.abs(tris).max(axis=(1, 2))[np.maximum(face, 0)]
    assert (np.abs(p[both] - on_ray[both]).max(axis=1) < 1e-5 * np.maximum(scale[both], t[both])).all()
    # geometric normal: unit, the winding's normal
    gn = unit(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]))
    assert np.abs(ng[both] - gn[face[both]]).max() < 1e-5
    return scene, face, uv, ns, both


# both triangle backends: our 4-wide tree (the default) and Warp's wp.Mesh
TRIANGLES = ["wide", "warp"]


@pytest.mark.parametrize("triangles", TRIANGLES)
def test_mesh_hit_random_soup(device, triangles):
    rng = np.random.default_rng(12)
    nt = 300
    centers = rng.uniform(-1, 1, (nt, 3))
    verts = (centers[:, None, :] + rng.normal(size=(nt, 3, 3)) * 0.2).reshape(-1, 3)
    faces = np.arange(3 * nt).reshape(nt, 3)
    n = 20000
    o = (unit(rng.normal(size=(n, 3))) * 3).astype(np.float32)
    d = f32unit(rng.uniform(-1, 1, (n, 3)) - o)
    normals = random_dirs(rng, len(verts))
    _, face, uv, ns, both = _check_mesh_against_brute_force(device, verts, faces, o, d, normals=normals,
                                                            triangles=triangles)
    # smooth_normal interpolates the corner normals with the same weights
    corner = normals[faces[face[both]]].astype(np.float64)  # (k, 3 corners, 3)
    w = np.stack([uv[both, 0], uv[both, 1], 1 - uv[both, 0] - uv[both, 1]], axis=1)
    expect = unit((w[:, :, None] * corner).sum(axis=1))
    assert np.abs(ns[both] - expect).max() < 1e-4


@pytest.mark.parametrize("triangles", TRIANGLES)
def test_mesh_occluded_agrees_with_the_nearest_hit(device, triangles):
    """A shadow ray within tmax is blocked exactly when the nearest hit is closer than tmax (the wide tree's any-hit
    traversal and leaf test, ``leaf_any``, differ from the closest-hit ones); tmax drawn around the nearest hit,
    rays within 1e-5 of it left out (the two compare t at different roundings there)."""
    rng = np.random.default_rng(5)
    nt = 2000
    centers = rng.uniform(-1, 1, (nt, 3))
    verts = (centers[:, None, :] + rng.normal(size=(nt, 3, 3)) * 0.1).reshape(-1, 3).astype(np.float32)
    faces = np.arange(3 * nt).reshape(nt, 3)
    n = 20000
    o = (unit(rng.normal(size=(n, 3))) * 3).astype(np.float32)
    d = f32unit(rng.uniform(-1, 1, (n, 3)) - o)
    ds = DeviceScene(_mesh_scene(verts, faces), device, triangles)
    near = probes.launch(probes.probe_mesh, n, device, [ds.data, probes.arr(o, wp.vec3, device),
                                                        probes.arr(d, wp.vec3, device)],
                         [wp.int32, float, wp.vec2, wp.vec3, wp.vec3, wp.vec3])[1]
    hit = near > 0
    tmax = np.where(hit, near * rng.uniform(0.5, 1.5, n), rng.uniform(0.1, 10.0, n)).astype(np.float32)
    occluded, t = probes.launch(probes.probe_occluded, n, device,
                                [ds.data, probes.arr(o, wp.vec3, device), probes.arr(d, wp.vec3, device),
                                 probes.arr(tmax, float, device)], [wp.int32, float])
    assert np.array_equal(t, near)
    clear = ~hit | (np.abs(near - tmax) > 1e-5 * tmax)
    expect = hit & (near < tmax)
    assert 0.2 < expect.mean() < 0.8 and clear.mean() > 0.99
    assert np.array_equal(occluded[clear] == 1, expect[clear])


@pytest.mark.parametrize("triangles", TRIANGLES)
def test_mesh_hit_teapot(device, triangles):
    m = trimesh.load(ROOT / "scenes" / "meshes" / "teapot.obj", process=False, force="mesh")
    verts, faces = np.asarray(m.vertices, np.float32), np.asarray(m.faces)
    rng = np.random.default_rng(13)
    lo, hi = verts.min(axis=0), verts.max(axis=0)
    mid = (lo + hi) / 2
    n = 6000
    o = (mid + unit(rng.normal(size=(n, 3))) * 3).astype(np.float32)
    d = f32unit(rng.uniform(lo, hi, (n, 3)) - o)
    normals = np.asarray(m.vertex_normals, np.float64)
    _, face, uv, ns, both = _check_mesh_against_brute_force(device, verts, faces, o, d, normals=normals,
                                                            triangles=triangles)
    corner = normals[faces[face[both]]]
    w = np.stack([uv[both, 0], uv[both, 1], 1 - uv[both, 0] - uv[both, 1]], axis=1)
    assert np.abs(ns[both] - unit((w[:, :, None] * corner).sum(axis=1))).max() < 1e-4


@pytest.mark.parametrize("triangles", TRIANGLES)
def test_smooth_normal_falls_back_when_corner_normals_cancel(device, triangles):
    verts = np.array([[-1, -1, 0], [1, -1, 0], [0, 1, 0]], np.float64)
    normals = np.array([[0, 0, 1], [0, 0, -1], [0, 0, 0]], np.float64)
    scene = _mesh_scene(verts, [[0, 1, 2]], normals)
    # aim where u = v = 1/2 (the vertex-0/vertex-1 midpoint): the interpolated normal is 0
    o = np.float32([[0, -1, 1]])
    face, t, uv, p, ng, ns = _mesh_query(device, scene, o, np.float32([[0, 0, -1]]), triangles)
    assert face[0] == 0 and np.abs(uv[0] - 0.5).max() < 1e-6
    assert np.abs(ns[0] - ng[0]).max() < 1e-6 and np.isfinite(ns).all()


def _icosphere_targets(rng):
    m = trimesh.creation.icosphere(subdivisions=2, radius=1.0)
    verts, faces = np.asarray(m.vertices, np.float32), np.asarray(m.faces)
    edges = np.asarray(m.edges_unique)
    a, b = verts[edges[:, 0]].astype(np.float64), verts[edges[:, 1]].astype(np.float64)
    s = np.concatenate([np.full(len(edges), 0.5), rng.random(len(edges)), rng.random(len(edges))])
    on_edges = np.tile(a, (3, 1)) + s[:, None] * (np.tile(b, (3, 1)) - np.tile(a, (3, 1)))
    return verts, faces, verts.astype(np.float64), on_edges.astype(np.float32).astype(np.float64)


def _count_misses(device, scene, o, targets, triangles="wide"):
    o = o.astype(np.float32)
    d = f32unit(targets - o)
    face, t, *_ = _mesh_query(device, scene, o, d, triangles)
    hit = face >= 0
    dist = np.linalg.norm(targets - o, axis=1)
    assert np.abs(t - dist)[hit].max() < 1e-4 * dist.max()
    return int((~hit).sum())


def test_closed_mesh_edges_and_vertices_hit(device):
    """Rays aimed exactly at shared edges (from both sides) and vertices (from outside) of a closed mesh hit it,
    and random rays from inside always hit. (Vertices seen from inside: the test below.)"""
    rng = np.random.default_rng(14)
    verts, faces, at_vertices, at_edges = _icosphere_targets(rng)
    scene = _mesh_scene(verts, faces)

    def outside(t):  # within ~30 degrees of the inward normal at the target
        return t + 2.0 * unit(t + 0.15 * rng.normal(size=t.shape))

    cases = {
        "vertices from outside": (outside(at_vertices), at_vertices),
        "edges from outside": (outside(at_edges), at_edges),
        "edges from inside": (rng.normal(size=at_edges.shape) * 0.2, at_edges),
    }
    for name, (o, targets) in cases.items():
        misses = _count_misses(device, scene, o, targets)
        assert misses == 0, f"{name}: {misses} of {len(targets)} rays missed the closed mesh"
    o = (unit(rng.normal(size=(20000, 3))) * rng.uniform(0, 0.9, (20000, 1))).astype(np.float32)  # inside
    face = _mesh_query(device, scene, o, random_dirs(rng, 20000))[0]
    assert (face >= 0).all()


def test_rays_through_vertices_from_inside(device):
    """Rays from inside a cube to its corners (every corner is a BVH box corner) and from inside an icosphere to its
    vertices all hit: the padded boxes never drop the leaf that holds the hit (Warp 1.19's own mesh_query_ray did)."""
    rng = np.random.default_rng(18)
    box = trimesh.creation.box()  # axis-aligned unit cube: every corner is a BVH box corner
    v, f = np.asarray(box.vertices, np.float32), np.asarray(box.faces)
    corners = np.repeat(v.astype(np.float64), 500, axis=0)
    misses = _count_misses(device, _mesh_scene(v, f), rng.normal(size=corners.shape) * 0.1, corners)
    verts, faces, at_vertices, _ = _icosphere_targets(rng)
    targets = np.repeat(at_vertices, 20, axis=0)
    misses_ico = _count_misses(device, _mesh_scene(verts, faces), rng.normal(size=targets.shape) * 0.2, targets)
    assert (misses, misses_ico) == (0, 0), (
        f"{misses} of {len(corners)} rays from inside a cube to its corners and {misses_ico} of {len(targets)} "
        "rays from inside an icosphere to its vertices escaped")


# ================================================================================================
# offset_origin: spawned rays never re-hit their own surface

SCALES = [(1e-3, 0.0), (1.0, 0.0), (1e4, 0.0), (1e-3, 1.0), (1.0, 1e2), (1.0, 1e4), (1e2, 1e4), (1e4, 1e4)]


def _hemisphere_mix(rng, n, normals):
    """Random directions on both sides of each surface: uniform, plus grazing ones within ~1e-4 rad of it."""
    w = unit(rng.normal(size=(n, 3)))
    g = rng.random(n) < 0.25
    tang = unit(np.cross(normals[g], rng.normal(size=(g.sum(), 3))))
    side = np.where(rng.random(g.sum()) < 0.5, 1.0, -1.0)
    w[g] = unit(tang + (side * 10 ** rng.uniform(-7, -4, g.sum()))[:, None] * normals[g])
    return w.astype(np.float32)


@pytest.mark.parametrize("triangles", TRIANGLES)
@pytest.mark.parametrize("scale,shift", SCALES)
def test_offset_triangles_no_self_hits(device, scale, shift, triangles):
    rng = np.random.default_rng(15)
    nt = 200
    T = np.array([shift, -0.7 * shift, 0.3 * shift])
    centers = rng.uniform(-1, 1, (nt, 3))
    tri = centers[:, None, :] + rng.normal(size=(nt, 3, 3)) * 0.3
    verts = (T + scale * tri.reshape(-1, 3)).astype(np.float32)
    faces = np.arange(3 * nt).reshape(nt, 3)
    scene = _mesh_scene(verts, faces)
    n = 20000
    pick = rng.integers(0, nt, n)
    bary = rng.dirichlet([1, 1, 1], n)
    target = np.einsum("nk,nkj->nj", bary, verts[faces[pick]].astype(np.float64))
    o = (target + scale * unit(rng.normal(size=(n, 3))) * 2.5).astype(np.float32)
    d = f32unit(target - o)
    e1 = verts[faces[pick, 1]].astype(np.float64) - verts[faces[pick, 0]]
    e2 = verts[faces[pick, 2]].astype(np.float64) - verts[faces[pick, 0]]
    w = _hemisphere_mix(rng, n, unit(np.cross(e1, e2)))
    ds = DeviceScene(scene, device, triangles)

    def spawn(use_offset):
        return probes.launch(
            probes.probe_respawn_mesh, n, device,
            [ds.data, probes.arr(o, wp.vec3, device), probes.arr(d, wp.vec3, device),
             probes.arr(w, wp.vec3, device), use_offset],
            [wp.int32, wp.int32, float])

    face, face2, _ = spawn(1)
    hit = face >= 0
    assert hit.mean() > 0.9
    rehits = (face2 == face) & hit
    assert rehits.sum() == 0, f"{rehits.sum()} of {hit.sum()} spawned rays re-hit their own triangle"
    # control: from the bare hit point the same rays do re-hit (the test can fail)
    face, face2, _ = spawn(0)
    assert ((face2 == face) & (face >= 0)).mean() > 0.05


@pytest.mark.parametrize("scale,shift", [(s, t) for s, t in SCALES if not (s == 1e-3 and t >= 1e2)])
def test_offset_spheres_no_self_hits(device, scale, shift):
    rng = np.random.default_rng(16)
    ns = 50
    T = np.array([shift, 0.5 * shift, -0.8 * shift])
    scene = make_scene((0, 0, 5), (0, 0, 0), 45, 4, 4)
    m = material(scene, "diffuse", 0.5)
    centers = T + scale * rng.uniform(-5, 5, (ns, 3))
    radii = scale * rng.uniform(0.3, 1.0, ns)
    for c, r in zip(centers, radii):
        scene.spheres.append(Sphere(c, float(r), m))
    c32, r32 = centers.astype(np.float32), radii.astype(np.float32)
    n = 20000
    idx = rng.integers(0, ns, n)
    o = (c32[idx] + unit(rng.normal(size=(n, 3))) * (r32[idx] * 3)[:, None]).astype(np.float32)
    aim = c32[idx] + rng.uniform(-0.9, 0.9, (n, 3)) * r32[idx, None] / math.sqrt(3)
    d = f32unit(aim - o)
    # spawn directions: random hemispheres, with grazing ones; normals approximated from the aim point
    approx_n = unit(o - c32[idx])
    w = _hemisphere_mix(rng, n, approx_n)
    ds = DeviceScene(scene, device)
    t, p, ng, t2, t2_none = probes.launch(
        probes.probe_respawn_sphere, n, device,
        [ds.data, probes.arr(o, wp.vec3, device), probes.arr(d, wp.vec3, device),
         probes.arr(idx, wp.int32, device), probes.arr(w, wp.vec3, device)],
        [float, wp.vec3, wp.vec3, float, float])
    assert (t >= 0).all()
    cos = np.einsum("ij,ij->i", w.astype(np.float64), ng)  # the side is decided by the hit's own normal
    out = cos > 1e-6
    # leaving the sphere: no hit, with the integrator's self mode and with the offset alone
    assert (t2[out] < 0).all()
    assert (t2_none[out] < 0).all(), f"{(t2_none[out] >= 0).sum()} outward rays re-hit through the offset alone"
    # entering: the hit is the exit point (the chord), never the start point
    inn = cos < -1e-3
    assert (t2[cos < -1e-6] > 0).all()
    chord = -2.0 * r32[idx] * cos
    tol = 1e-4 * r32[idx] + 2 * 64 * FLT_EPS * np.abs(p).max(axis=1) / np.maximum(-cos, 1e-3)
    assert (np.abs(t2 - chord)[inn] < tol[inn]).all()


@pytest.mark.parametrize("scale,shift", SCALES)
def test_shadow_rays_between_facing_quads_never_occluded(device, scale, shift):
    from helpers import add_rect

    rng = np.random.default_rng(17)
    T = np.array([0.6 * shift, -shift, 0.2 * shift])
    scene = make_scene((0, 0, 5), (0, 0, 0), 45, 4, 4)
    m = material(scene, "diffuse", 0.5)
    blk = material(scene, "diffuse", 0.0)
    h = scale
    add_rect(scene, T, (h, 0, 0), (0, h, 0), (0, 0, 1), m)  # receiver A at z = 0, facing +z
    add_rect(scene, T + [0, 0, h], (0, 0.7 * h, 0), (0.7 * h, 0, 0), (0, 0, -1), blk, radiance=1.0)  # light B
    n = 20000
    target = T + np.c_[rng.uniform(-h, h, (n, 2)), np.zeros(n)]
    o = (T + np.c_[rng.uniform(-h, h, (n, 2)) * 0.5, np.full(n, 0.5 * h)]).astype(np.float32)
    d = f32unit(target - o)
    uv = rng.random((n, 2)).astype(np.float32)
    ds = DeviceScene(scene, device)
    status = probes.launch(probes.probe_shadow, n, device,
                           [ds.data, probes.arr(o, wp.vec3, device), probes.arr(d, wp.vec3, device),
                            probes.arr(uv, wp.vec2, device)], [wp.int32])
    assert (status == 0).mean() > 0.95
    assert (status == 1).sum() == 0, f"{(status == 1).sum()} shadow rays between visible points were blocked"


@wp.kernel(enable_backward=False)
def probe_inside_point(tri: wp.array(dtype=wp.vec3), uv: wp.array(dtype=wp.vec2), out: wp.array(dtype=wp.vec3)):
    i = wp.tid()
    a = tri[3 * i]
    b = tri[3 * i + 1]
    c = tri[3 * i + 2]
    scale = wp.max(max_abs(a), wp.max(max_abs(b), max_abs(c)))
    out[i] = inside_point(a, b, c, uv[i][0], uv[i][1], scale)


def test_inside_point_keeps_edge_hits_inside_their_triangle(device):
    """Hits on an edge or at a vertex move a few ulps into the triangle (never beyond an adjacent face's plane),
    interior hits stay put, and a triangle too small for the margin gives its centroid."""
    from kernels.mesh import INSIDE_ULPS

    rng = np.random.default_rng(5)
    tris, uvs = [], []
    for _ in range(300):
        centre = rng.uniform(-1e3, 1e3, 3) * rng.choice([1e-3, 1.0])
        t = centre + rng.normal(size=(3, 3)) * rng.choice([1e-2, 1.0, 10.0])
        tris.append(t)
        uvs.append(rng.choice([(0.0, 0.5), (0.5, 0.0), (0.5, 0.5), (1.0, 0.0), (0.0, 0.0), (0.2, 0.3)]))
    for _ in range(10):  # a few ulps across: no room for the margin
        tris.append(100.0 + rng.normal(size=(3, 3)) * 1e-4)
        uvs.append((0.0, 0.5))
    tris = np.array(tris, dtype=np.float32)
    uvs = np.array(uvs, dtype=np.float32)
    out = wp.zeros(len(tris), dtype=wp.vec3, device=device)
    wp.launch(probe_inside_point, dim=len(tris), device=device,
              inputs=[wp.array(tris.reshape(-1, 3), dtype=wp.vec3, device=device),
                      wp.array(uvs, dtype=wp.vec2, device=device)], outputs=[out])
    p = out.numpy().astype(np.float64)
    kinds = {"centroid": 0, "moved": 0, "kept": 0}
    for t, (u, v), q in zip(tris.astype(np.float64), uvs, p):
        a, b, c = t
        ulp = float(np.finfo(np.float32).eps) * np.abs(t).max()
        e = INSIDE_ULPS * ulp
        n = np.cross(b - a, c - a)
        area2 = np.linalg.norm(n)
        margins = e * np.array([np.linalg.norm(c - b), np.linalg.norm(a - c), np.linalg.norm(b - a)]) / area2
        want = u * a + v * b + (1 - u - v) * c
        if margins.sum() >= 0.5:  # too small for the margin: the centroid
            kinds["centroid"] += 1
            assert np.abs(q - t.mean(axis=0)).max() <= 4 * ulp
            continue
        # in-plane distance of q to each edge line, positive inside
        dist = [np.dot(np.cross(e1 - e0, q - e0), n) / area2 / np.linalg.norm(e1 - e0)
                for e0, e1 in ((b, c), (c, a), (a, b))]
        assert min(dist) >= 0.5 * e, (t, u, v, dist)
        if (np.array([u, v, 1 - u - v]) > margins).all():
            kinds["kept"] += 1
            assert np.abs(q - want).max() <= 4 * ulp  # interior hits stay put
        else:  # moved by the margins: each weight by at most its margin, times the longest edge
            kinds["moved"] += 1
            longest = max(np.linalg.norm(b - c), np.linalg.norm(c - a), np.linalg.norm(a - b))
            assert np.linalg.norm(q - want) <= 2 * margins.sum() * longest + 4 * ulp, (t, u, v)
    assert min(kinds.values()) >= 5, kinds  # every branch exercised
