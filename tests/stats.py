"""Statistics for testing estimators without flaky tests (TESTING.md), in plain numpy and ``math``.

- ``run_batches(estimator, seeds)``: B >= 16 independent batch estimates (one per seed).
- ``assert_mean(values, expected, z=4)``: the batch mean against a known value, with the batches' own standard error.
- ``assert_pixels_mean(values, expected)``: the same per pixel, with a Sidak correction over the pixels (exact
  Student t p-values of each pixel's B batches), or the ">= 99.7% of pixels pass at the |z| <= 4 level" rule.
- ``welch`` / ``assert_agree`` / ``assert_pixels_agree``: two estimators of one quantity (Welch's unequal-variance
  t test, Welch-Satterthwaite degrees of freedom).
- ``chi2_sf``, ``t_sf``, ``f_sf`` and their inverses: survival functions from the regularized incomplete gamma and
  beta functions (Numerical Recipes' series and Lentz continued fractions), so the tests need no scipy.

Every ``assert_*`` prints its figure (``pytest -s`` shows them) and returns it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Iterable

import numpy as np

from helpers import add_furnace_cube, add_rect, batch_z, make_scene, material

B = 16  # default number of batches (seeds)
Z_MAX = 4.0

# ------------------------------------------------------------------------------------------------
# special functions


def _gamma_p_series(a: float, x: float) -> float:
    term = total = 1.0 / a
    ap = a
    for _ in range(10_000):
        ap += 1.0
        term *= x / ap
        total += term
        if abs(term) < abs(total) * 1e-15:
            break
    return total * math.exp(-x + a * math.log(x) - math.lgamma(a))


def _gamma_q_cf(a: float, x: float) -> float:
    tiny = 1e-300
    b = x + 1.0 - a
    c = 1.0 / tiny
    d = 1.0 / b
    h = d
    for i in range(1, 10_000):
        an = -i * (i - a)
        b += 2.0
        d = an * d + b
        d = tiny if abs(d) < tiny else d
        c = b + an / c
        c = tiny if abs(c) < tiny else c
        d = 1.0 / d
        delta = d * c
        h *= delta
        if abs(delta - 1.0) < 1e-15:
            break
    return math.exp(-x + a * math.log(x) - math.lgamma(a)) * h


def gamma_q(a: float, x: float) -> float:
    """Regularized upper incomplete gamma Q(a, x) = Gamma(a, x) / Gamma(a)."""
    if x <= 0.0:
        return 1.0
    if x < a + 1.0:
        return 1.0 - _gamma_p_series(a, x)
    return _gamma_q_cf(a, x)


def _beta_cf(a: float, b: float, x: float) -> float:
    tiny = 1e-300
    qab, qap, qam = a + b, a + 1.0, a - 1.0
    c = 1.0
    d = 1.0 - qab * x / qap
    d = tiny if abs(d) < tiny else d
    d = 1.0 / d
    h = d
    for m in range(1, 10_000):
        m2 = 2 * m
        aa = m * (b - m) * x / ((qam + m2) * (a + m2))
        d = 1.0 + aa * d
        d = tiny if abs(d) < tiny else d
        c = 1.0 + aa / c
        c = tiny if abs(c) < tiny else c
        d = 1.0 / d
        h *= d * c
        aa = -(a + m) * (qab + m) * x / ((a + m2) * (qap + m2))
        d = 1.0 + aa * d
        d = tiny if abs(d) < tiny else d
        c = 1.0 + aa / c
        c = tiny if abs(c) < tiny else c
        d = 1.0 / d
        delta = d * c
        h *= delta
        if abs(delta - 1.0) < 1e-15:
            break
    return h


def beta_inc(a: float, b: float, x: float) -> float:
    """Regularized incomplete beta I_x(a, b)."""
    if x <= 0.0:
        return 0.0
    if x >= 1.0:
        return 1.0
    lbt = math.lgamma(a + b) - math.lgamma(a) - math.lgamma(b) + a * math.log(x) + b * math.log1p(-x)
    if x < (a + 1.0) / (a + b + 2.0):
        return math.exp(lbt) * _beta_cf(a, b, x) / a
    return 1.0 - math.exp(lbt) * _beta_cf(b, a, 1.0 - x) / b


def chi2_sf(x: float, dof: float) -> float:
    """P(X > x) for X ~ chi-square(dof)."""
    return gamma_q(0.5 * dof, 0.5 * x)


def t_sf2(t: float, dof: float) -> float:
    """Two-sided P(|T| > |t|) for T ~ Student t(dof)."""
    if not math.isfinite(t):
        return 0.0
    return beta_inc(0.5 * dof, 0.5, dof / (dof + t * t))


def f_sf(x: float, d1: float, d2: float) -> float:
    """P(F > x) for F ~ F(d1, d2)."""
    if x <= 0.0:
        return 1.0
    return beta_inc(0.5 * d2, 0.5 * d1, d2 / (d2 + d1 * x))


def normal_sf2(z: float) -> float:
    """Two-sided P(|Z| > |z|) for a standard normal."""
    return math.erfc(abs(z) / math.sqrt(2.0))


def _isf(sf: Callable[[float], float], p: float, lo: float, hi: float) -> float:
    """x with sf(x) = p for a decreasing sf, by bisection (hi is doubled until it brackets)."""
    while sf(hi) > p:
        hi *= 2.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if sf(mid) > p:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def chi2_isf(p: float, dof: float) -> float:
    return _isf(lambda x: chi2_sf(x, dof), p, 0.0, dof + 10.0)


def t_isf2(p: float, dof: float) -> float:
    """|t| with two-sided tail probability p."""
    return _isf(lambda x: t_sf2(x, dof), p, 0.0, 10.0)


def f_isf(p: float, d1: float, d2: float) -> float:
    return _isf(lambda x: f_sf(x, d1, d2), p, 0.0, 10.0)


def sidak(family_alpha: float, m: int) -> float:
    """Per-test level that keeps the family-wise error at ``family_alpha`` over m independent tests."""
    return -math.expm1(math.log1p(-family_alpha) / m)


# ------------------------------------------------------------------------------------------------
# batches, means, agreement


def run_batches(estimator: Callable[[int], object], seeds: Iterable[int] = range(B)) -> np.ndarray:
    """``estimator(seed)`` for each seed (a scalar or an array each): float64 (B, ...). Requires B >= 16."""
    values = np.array([np.asarray(estimator(int(s)), dtype=np.float64) for s in seeds])
    assert len(values) >= 16, "use at least 16 independent batches"
    return values


def mean_se(values) -> tuple[float, float]:
    """Mean of independent batch estimates and its standard error from their spread."""
    v = np.asarray(values, dtype=np.float64).reshape(-1)
    return float(v.mean()), float(v.std(ddof=1) / math.sqrt(v.size))


def assert_mean(values, expected: float, z: float = Z_MAX, name: str = "") -> tuple[float, float, float]:
    """|mean - expected| <= z * SE over the batches ``values`` (B,). Returns (mean, se, z)."""
    mean, se, zz = batch_z(values, expected)
    print(f"\n[stats] {name}: expected {expected:.6g}, got {mean:.6g} +- {se:.2g} (z = {zz:+.2f}, B = {len(values)})")
    assert abs(zz) <= z, f"{name}: mean {mean:.6g} vs expected {expected:.6g}: z = {zz:+.2f} (SE {se:.3g})"
    return mean, se, zz


@dataclass
class Welch:
    diff: float  # mean(a) - mean(b)
    se: float
    t: float
    dof: float
    p: float  # two-sided


def welch(a, b) -> Welch:
    """Welch's unequal-variance t test of mean(a) = mean(b) for two sets of independent batch estimates."""
    a = np.asarray(a, dtype=np.float64).reshape(-1)
    b = np.asarray(b, dtype=np.float64).reshape(-1)
    va, vb = a.var(ddof=1) / a.size, b.var(ddof=1) / b.size
    se = math.sqrt(va + vb)
    diff = float(a.mean() - b.mean())
    if se == 0.0:
        return Welch(diff, 0.0, 0.0 if diff == 0.0 else math.inf, math.inf, 1.0 if diff == 0.0 else 0.0)
    dof = (va + vb) ** 2 / (va**2 / (a.size - 1) + vb**2 / (b.size - 1))
    t = diff / se
    return Welch(diff, se, t, dof, t_sf2(t, dof))


def assert_agree(a, b, z: float = Z_MAX, name: str = "") -> Welch:
    """Two estimators of one quantity agree: |Welch t| <= z."""
    w = welch(a, b)
    print(f"\n[stats] {name}: {np.mean(a):.6g} vs {np.mean(b):.6g}, diff {w.diff:+.3g} +- {w.se:.2g} "
          f"(Welch t = {w.t:+.2f}, dof {w.dof:.1f}, p = {w.p:.3g})")
    assert abs(w.t) <= z, f"{name}: Welch t = {w.t:+.2f} (diff {w.diff:+.4g} +- {w.se:.3g})"
    return w


@dataclass
class PixelTest:
    pixels: int
    worst_p: float  # smallest per-pixel two-sided p-value
    threshold: float  # per-pixel level (Sidak) the worst p must reach
    worst_t: float
    pass_fraction: float  # pixels whose p-value reaches that of |z| = 4 for a normal (6.3e-5)


def _pixel_verdict(t: np.ndarray, dof: np.ndarray, family_alpha: float) -> PixelTest:
    dof = np.broadcast_to(dof, t.shape).reshape(-1)
    t = t.reshape(-1)
    p = np.array([t_sf2(float(x), float(d)) for x, d in zip(t, dof)])
    k = int(np.argmin(p))
    return PixelTest(t.size, float(p[k]), sidak(family_alpha, t.size), float(t[k]),
                     float(np.mean(p >= normal_sf2(Z_MAX))))


def _check_pixels(res: PixelTest, rule: str, name: str) -> PixelTest:
    print(f"\n[stats] {name}: {res.pixels} pixels, worst t = {res.worst_t:+.2f} (p = {res.worst_p:.3g}, "
          f"Sidak level {res.threshold:.3g}), {100 * res.pass_fraction:.2f}% pass at the |z| <= {Z_MAX:g} level")
    if rule == "sidak":
        assert res.worst_p >= res.threshold, f"{name}: a pixel fails the Sidak-corrected test: {res}"
    elif rule == "fraction":
        assert res.pass_fraction >= 0.997, f"{name}: fewer than 99.7% of pixels pass: {res}"
    else:
        raise ValueError(rule)
    return res


def assert_pixels_mean(values, expected, family_alpha: float = 1e-3, rule: str = "sidak", name: str = "") -> PixelTest:
    """Per-pixel batch means ``values`` (B, ...) against ``expected`` (broadcastable to values[0]).

    Each pixel's t = (mean - expected) / SE has B - 1 degrees of freedom. ``rule="sidak"``: every pixel's two-sided
    p-value must reach the Sidak level for ``family_alpha`` over all pixels; ``rule="fraction"``: >= 99.7% of the
    pixels pass at the level of |z| <= 4 (p >= 6.3e-5; with B = 16 that is |t| <= 5.6: the t(15) tails are too
    heavy for a plain |t| <= 4, which a correct estimator fails on 0.12% of pixels).
    """
    v = np.asarray(values, dtype=np.float64)
    n = v.shape[0]
    assert n >= 16
    se = v.std(axis=0, ddof=1) / math.sqrt(n)
    diff = v.mean(axis=0) - np.broadcast_to(expected, v.shape[1:])
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(se > 0, diff / se, np.where(diff == 0, 0.0, np.inf))
    return _check_pixels(_pixel_verdict(t, np.array(n - 1.0), family_alpha), rule, name)


def assert_pixels_agree(a, b, family_alpha: float = 1e-3, rule: str = "sidak", name: str = "") -> PixelTest:
    """Per-pixel Welch tests of two estimators, (B, ...) each, with the Sidak correction (or the fraction rule)."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    assert a.shape[0] >= 16 and b.shape[0] >= 16
    va, vb = a.var(axis=0, ddof=1) / a.shape[0], b.var(axis=0, ddof=1) / b.shape[0]
    s2 = va + vb
    diff = a.mean(axis=0) - b.mean(axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(s2 > 0, diff / np.sqrt(s2), np.where(diff == 0, 0.0, np.inf))
        dof = np.where(s2 > 0, s2**2 / (va**2 / (a.shape[0] - 1) + vb**2 / (b.shape[0] - 1)), 1.0)
    return _check_pixels(_pixel_verdict(t, np.nan_to_num(dof, nan=1.0), family_alpha), rule, name)


# ------------------------------------------------------------------------------------------------
# renders


def render_batches(renderer, spp: int, seeds: Iterable[int] = range(B)):
    """Per seed, passes 0 .. spp - 1: (means (B, H, W, 3), per-pixel sample variances (B, H, W, 3)), float64."""
    means, variances = [], []
    for s in seeds:
        ps = renderer.render_passes(seed=int(s), first_pass=0, count=spp)
        total = ps.sum if ps.lt_sum is None else ps.sum + ps.lt_sum  # with light tracing, both parts
        means.append(total / ps.passes)
        variances.append(ps.variance_of_mean * ps.passes)  # per-sample variance, summed over the two estimators
    means, variances = np.array(means), np.array(variances)
    assert np.isfinite(means).all() and len(means) >= 16
    return means, variances


def per_pass_values(renderer, seed: int, passes: int) -> np.ndarray:
    """Every pass's sample of every pixel, (passes, H, W, 3) float64: pass i rendered alone (exact samples)."""
    return np.array([renderer.render_passes(seed=seed, first_pass=i, count=1).sum for i in range(passes)])


# ------------------------------------------------------------------------------------------------
# scenes of tests/test_statistics.py (built with tests/helpers.py)


def tangent_frame(n) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unit (t, b, n): any right-handed orthonormal frame around ``n`` (numpy, float64)."""
    n = np.asarray(n, dtype=np.float64)
    n = n / np.linalg.norm(n)
    ref = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    t = np.cross(ref, n)
    t /= np.linalg.norm(t)
    return t, np.cross(n, t), n


def _segment_crosses_rect(a, b, center, half_u, half_v) -> bool:
    """Does the segment a -> b pass through the parallelogram center + s half_u + t half_v, |s|, |t| <= 1?"""
    a, b, c, u, v = (np.asarray(x, dtype=np.float64) for x in (a, b, center, half_u, half_v))
    n = np.cross(u, v)
    da, db = np.dot(a - c, n), np.dot(b - c, n)
    if da * db > 0 or da == db:
        return False
    p = a + (b - a) * (da / (da - db))
    st = np.linalg.lstsq(np.stack([u, v], axis=1), p - c, rcond=None)[0]
    return bool(np.abs(st).max() <= 1.0)


def irradiance_scene(p, n, light_center, light_half: float, Le: float, rho: float, view_tilt_deg: float = 60.0,
                     view_dist: float = 0.5, width: int = 8, height: int = 8):
    """A tiny receiver (half-side 0.05, albedo rho, facing unit ``n``) at ``p`` under a one-sided square light of
    half-side ``light_half`` centred at ``light_center``, facing -z; the camera looks at p through a 0.05 degree
    field of view from ``view_dist`` away, ``view_tilt_deg`` off the normal, so every pixel sees a point within
    5e-4 of p. Returns (scene, light corners). Asserts that the whole light is above the receiver's plane and that
    the camera's view of p does not pass through the light.
    """
    p = np.asarray(p, dtype=np.float64)
    t, b, n = tangent_frame(n)
    c = np.asarray(light_center, dtype=np.float64)
    hu, hv = np.array([light_half, 0.0, 0.0]), np.array([0.0, light_half, 0.0])
    corners = [c - hu - hv, c + hu - hv, c + hu + hv, c - hu + hv]
    assert all(np.dot(q - p, n) > 0.05 for q in corners), "the light must be wholly above the receiver's plane"
    beta = np.radians(view_tilt_deg)
    eye = p + view_dist * (np.cos(beta) * n + np.sin(beta) * b)
    assert not _segment_crosses_rect(eye, p, c, hu, hv)
    scene = make_scene(eye, p, 0.05, width, height, up=t)  # t is perpendicular to the view direction
    add_rect(scene, p, 0.05 * t, 0.05 * b, n, material(scene, "diffuse", rho))
    add_rect(scene, c, hu, hv, (0, 0, -1), material(scene, "diffuse", 0.0), radiance=Le)
    return scene, corners


def mirror_caustic_scene(Le: float = 10.0, rho: float = 0.5, r: float = 0.8, width: int = 16, height: int = 16):
    """TESTING.md truth 4: light reaching a diffuse point only through a planar mirror.

    A tiny floor patch (albedo rho, facing +z) at p = (1, 0, 0); a vertical square light (half-side 0.3, centre
    (0.5, 0, 1)) facing -x, away from the patch; a vertical mirror of reflectance r in the plane x = 0 facing +x.
    The patch sees the light only as its mirror image (x -> -x), and the real light does not block that view.
    The camera looks at p through a 0.05 degree field of view. Returns (scene, p, n, mirrored light corners).
    """
    p, n = np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0])
    c, hu, hv = np.array([0.5, 0.0, 1.0]), np.array([0.0, 0.3, 0.0]), np.array([0.0, 0.0, 0.3])
    corners = np.array([c - hu - hv, c + hu - hv, c + hu + hv, c - hu + hv])
    image = corners * np.array([-1.0, 1.0, 1.0])
    assert np.dot(p - c, (-1.0, 0.0, 0.0)) < 0.0  # p is behind the one-sided light: it never sees it directly
    for q in image:  # every ray from p to the image clears the real light, and meets the mirror inside it
        assert not _segment_crosses_rect(p, q, c, hu, hv)
        hit = p + (q - p) * (p[0] / (p[0] - q[0]))
        assert abs(hit[1]) < 1.0 and 0.0 < hit[2] < 2.0
    scene = make_scene((1.6, -0.6, 0.8), p, 0.05, width, height, up=(0, 0, 1))
    add_rect(scene, p, (0.05, 0, 0), (0, 0.05, 0), n, material(scene, "diffuse", rho))
    add_rect(scene, c, hu, hv, (-1, 0, 0), material(scene, "diffuse", 0.0), radiance=Le)
    add_rect(scene, (0, 0, 1), (0, 1, 0), (0, 0, 1), (1, 0, 0), material(scene, "mirror", r))
    return scene, p, n, image


def closed_box(albedo: float, width: int = 8, height: int = 8, rr_depth: int = 5, Le: float = 4.0):
    """A closed diffuse box [-1, 1]^3 (albedo ``albedo``, no emission) lit by a small one-sided square light
    floating under the ceiling (half-side 0.25 at y = 0.8, facing down): a furnace without emitting walls.

    Paths never escape, so every bounce meets Russian roulette; and unlike the emitting-wall furnace, next-event
    estimation has no singular geometry term (the light touches no wall), so every estimator here has finite
    variance unless the roulette rule itself makes it infinite.
    """
    scene = make_scene((0, -0.2, -0.9), (0, -0.5, 1), 70, width, height, rr_depth=rr_depth)
    add_furnace_cube(scene, 1.0, material(scene, "diffuse", albedo), None)
    add_rect(scene, (0, 0.8, 0), (0.25, 0, 0), (0, 0, 0.25), (0, -1, 0), material(scene, "diffuse", 0.0),
             radiance=Le)
    return scene
