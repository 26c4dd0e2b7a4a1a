"""Statistical tests of the estimators (TESTING.md, issue 3): every one can fail, none is flaky.

Fixed seeds throughout; means are compared with the batches' own standard error (B = 16 seeds, |z| <= 4), two
estimators with Welch's test, per-pixel results with a Sidak correction, densities with chi-square p-values
(``tests/stats.py`` has the statistics, ``tests/helpers.py`` the scenes). Every figure is printed (``pytest -s``).

1. the statistics themselves against textbook table values, and their power (they reject what they must);
2. 2D chi-square tests of the cosine-hemisphere and parallelogram samplers, fed by the integrator's own random
   numbers (``rand4``);
3. the variance-growth detector (``pathtracer.diagnostics.variance_growth``) on Pareto and finite-variance samples;
4. irradiance under a square light (on axis, off axis, tilted receiver) against Lambert's polygon formula, with
   K = 1, 4, 16 light samples: the same mean, and per-sample variances in the ratio 1 / K;
5. light reaching a point only through a planar mirror (TESTING.md truth 4), by max_depth;
6. Russian roulette: both rules agree with no roulette; the seed rule's infinite-variance regime is reported by the
   static check and found by the detector in a render.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import warp as wp

import probes
import stats
from helpers import add_rect, material, polygon_irradiance
from kernels.integrator import SEED_RR_LAMBDA as KERNEL_SEED_RR_LAMBDA
from pathtracer import diagnostics
from pathtracer.diagnostics import roulette_variance_warning, variance_growth
from pathtracer.render import Renderer
from stats import closed_box, irradiance_scene, mirror_caustic_scene, tangent_frame

P_MIN = 1e-4  # chi-square tests: a correct sampler fails one in 10^4 seed choices; the seeds are fixed


# ================================================================================================
# 1. the statistics


def test_distribution_functions_match_tables():
    """Survival functions and quantiles against printed tables (Abramowitz & Stegun; NIST handbook)."""
    assert stats.chi2_sf(3.841459, 1) == pytest.approx(0.05, abs=1e-6)
    assert stats.chi2_sf(124.3421, 100) == pytest.approx(0.05, abs=1e-6)
    assert stats.chi2_sf(2.0, 2) == pytest.approx(math.exp(-1.0), rel=1e-12)  # chi2(2) is exponential
    assert stats.chi2_isf(0.01, 10) == pytest.approx(23.20925, abs=1e-4)
    assert stats.t_sf2(2.131450, 15) == pytest.approx(0.05, abs=1e-6)
    assert stats.t_sf2(1.0, 1) == pytest.approx(0.5, abs=1e-12)  # Cauchy: P(|T| > 1) = 1/2
    assert stats.t_isf2(0.01, 30) == pytest.approx(2.749996, abs=1e-5)
    assert stats.f_isf(0.05, 15, 15) == pytest.approx(2.403447, abs=1e-5)
    assert stats.f_sf(1.0, 7, 7) == pytest.approx(0.5, abs=1e-12)
    assert stats.normal_sf2(1.959964) == pytest.approx(0.05, abs=1e-6)
    assert stats.sidak(0.05, 1) == pytest.approx(0.05)
    assert stats.sidak(0.05, 2) == pytest.approx(0.0253205655191, rel=1e-10)  # 1 - sqrt(0.95)
    assert stats.sidak(1e-3, 256) == pytest.approx(3.90819679108e-06, rel=1e-9)  # 1 - 0.999^(1/256)
    assert stats.sidak(1e-3, 256) > 1e-3 / 256  # a little less strict than Bonferroni


def test_assertions_accept_the_truth_and_reject_a_bias():
    """The helpers pass unbiased batches and fail batches biased by 6 standard errors (they have power)."""
    rng = np.random.default_rng(11)
    v = rng.normal(1.0, 0.1, size=16)
    stats.assert_mean(v, 1.0, name="unbiased normal batches")
    with pytest.raises(AssertionError):
        stats.assert_mean(v, 1.0 - 6 * 0.1 / 4, name="expected value off by 6 SE")
    w = rng.normal(1.0, 0.3, size=16)
    stats.assert_agree(v, w, name="two unbiased estimators")
    with pytest.raises(AssertionError):
        stats.assert_agree(v, w + 0.5, name="one estimator biased")
    px = rng.normal(2.0, 1.0, size=(16, 32, 32))
    stats.assert_pixels_mean(px, 2.0, name="1024 unbiased pixels (Sidak)")
    stats.assert_pixels_mean(px, 2.0, rule="fraction", name="1024 unbiased pixels (99.7% rule)")
    biased = px.copy()
    biased[:, 5, 7] += 3.0  # one pixel of 1024 off by 12 SE
    with pytest.raises(AssertionError):
        stats.assert_pixels_mean(biased, 2.0, name="one biased pixel (Sidak)")
    stats.assert_pixels_agree(px, rng.normal(2.0, 0.5, size=(16, 32, 32)), name="two unbiased images")
    with pytest.raises(AssertionError):
        stats.assert_pixels_agree(biased, rng.normal(2.0, 0.5, size=(16, 32, 32)), name="one biased pixel")


# ================================================================================================
# 2. samplers: 2D chi-square, with the integrator's random numbers


def _integrator_uniforms(n: int, seed: int) -> np.ndarray:
    """(n, 2) uniforms as the integrator draws a bounce direction: lanes 0 and 1 of rand4((pixel, pass, seed), dim)
    for n pixels of pass 0, dimension 3."""
    keys = np.stack([np.arange(n), np.zeros(n), np.full(n, seed)], axis=1)
    u = probes.launch(probes.probe_rand, n, "cpu", [probes.arr(keys, wp.vec3ui, "cpu"),
                                                    probes.arr(np.full(n, 3), wp.uint32, "cpu")], [wp.vec4])
    return u[:, :2].astype(np.float64)


def _sample(device, normals, u2):
    """probe_sampling with (u0, u1) driving both the cosine samplers and the parallelogram sampler."""
    n = len(normals)
    us = np.concatenate([u2, u2], axis=1)
    out = probes.launch(
        probes.probe_sampling, n, device,
        [probes.arr(normals, wp.vec3, device), probes.arr(normals, wp.vec3, device), probes.arr(us, wp.vec4, device),
         wp.vec3(*PAR_CENTER), wp.vec3(*PAR_HU), wp.vec3(*PAR_HV), 0.5],
        [wp.mat33, wp.vec3, wp.vec3, wp.vec3, wp.vec3, float])
    return out[1].astype(np.float64), out[2].astype(np.float64), out[3].astype(np.float64)


PAR_CENTER = (0.3, -1.0, 2.0)
PAR_HU = (0.8, 0.2, 0.0)
PAR_HV = (-0.1, 0.3, 0.6)
N_SAMPLES = 1 << 18
BINS = 16  # 16 x 16 cells: 1024 expected per cell


def _chi2_2d(x, y, x_edges, y_edges, expected, name):
    counts = np.histogram2d(x, y, bins=[x_edges, y_edges])[0]
    assert counts.sum() == len(x), "samples outside the binned domain"
    stat = float(((counts - expected) ** 2 / expected).sum())
    dof = counts.size - 1
    p = stats.chi2_sf(stat, dof)
    print(f"\n[stats] {name}: chi2 = {stat:.1f} on {dof} dof, p = {p:.3g} (n = {len(x)})")
    assert p >= P_MIN, f"{name}: chi-square {stat:.1f} on {dof} dof, p = {p:.3g}"
    return p


def _cosine_bins(d, n):
    """(cos^2 theta, phi) of directions ``d`` in the frame of ``n``, and the expected counts of pdf cos(theta)/pi
    over the 16 x 16 cells: integral of cos/pi dw = (delta cos^2 theta / 2) (delta phi / pi)."""
    t, b, n = tangent_frame(n)
    c = d @ n
    assert c.min() >= -1e-6
    c2 = np.clip(c, 0.0, 1.0) ** 2
    phi = np.arctan2(d @ b, d @ t)
    ce = np.linspace(0.0, 1.0, BINS + 1)
    pe = np.linspace(-np.pi, np.pi, BINS + 1)
    cell = np.outer(np.diff(ce) / 2.0, np.diff(pe) / np.pi)
    assert cell.sum() == pytest.approx(1.0)
    return c2, phi, ce, pe, len(d) * cell


@pytest.mark.parametrize("normal", [(0.0, 0.0, 1.0), (0.3, -0.8, -0.5), (0.0, 0.0, -1.0)],
                         ids=["z", "tilted", "minus-z"])
def test_cosine_hemisphere_2d_chi_square(device, normal):
    """Cosine-weighted directions (cosine_hemisphere, then sample_cosine_around a tilted normal and the -z pole):
    joint (cos^2 theta, phi) histogram against pdf cos(theta)/pi, 16 x 16 cells."""
    u = _integrator_uniforms(N_SAMPLES, seed=17)
    n = np.asarray(normal) / np.linalg.norm(normal)
    local, around, _ = _sample(device, np.tile(n.astype(np.float32), (N_SAMPLES, 1)), u)
    if normal == (0.0, 0.0, 1.0):
        _chi2_2d(*_cosine_bins(local, n), "cosine_hemisphere (cos^2 theta, phi)")
    _chi2_2d(*_cosine_bins(around, n), f"sample_cosine_around n = {normal} (cos^2 theta, phi)")


def test_parallelogram_2d_chi_square(device):
    """Uniform points on a parallelogram: joint (s, t) histogram against the density 1 / area, 16 x 16 cells."""
    u = _integrator_uniforms(N_SAMPLES, seed=23)
    _, _, pts = _sample(device, np.tile(np.float32([0, 0, 1]), (N_SAMPLES, 1)), u)
    hu, hv = np.asarray(PAR_HU), np.asarray(PAR_HV)
    st = np.linalg.lstsq(np.stack([hu, hv], axis=1), (pts - np.asarray(PAR_CENTER)).T, rcond=None)[0]
    resid = pts - (np.asarray(PAR_CENTER) + np.outer(st[0], hu) + np.outer(st[1], hv))
    assert np.abs(resid).max() < 1e-5, "points off the parallelogram's plane"
    s, t = np.clip(st, -1.0, 1.0)
    assert np.abs(st).max() <= 1.0 + 1e-5
    edges = np.linspace(-1.0, 1.0, BINS + 1)
    # the claimed density 1 / area over a cell of (s, t) area (2 / 16)^2 is (1/4) (2/16)^2 = 1/256
    expected = np.full((BINS, BINS), N_SAMPLES / BINS**2)
    _chi2_2d(s, t, edges, edges, expected, "sample_parallelogram (s, t)")


# ================================================================================================
# 3. the variance-growth detector


@pytest.mark.parametrize("n", [1024, 4096])
@pytest.mark.parametrize("alpha", [1.5, 1.2])
def test_variance_growth_flags_pareto_infinite_variance(n, alpha):
    """Pareto samples of tail index alpha < 2 (infinite variance), fixed seeds: flagged."""
    x = np.random.default_rng(101).pareto(alpha, n) + 1.0
    rep = variance_growth(x)
    print(f"\n[stats] Pareto alpha = {alpha}, n = {n}: {rep}")
    assert rep.conclusive and rep.infinite_variance
    assert abs(rep.tail_index - alpha) < 4 * rep.tail_index_se + 0.3


FINITE = {
    "normal": lambda r, n: r.normal(3.0, 1.0, n),
    "exponential": lambda r, n: r.exponential(1.0, n),
    "lognormal sigma 0.5": lambda r, n: r.lognormal(0.0, 0.5, n),
    "Pareto alpha 4": lambda r, n: r.pareto(4.0, n) + 1.0,
    "Bernoulli 0.02": lambda r, n: (r.random(n) < 0.02).astype(float),
    "mean of 64 exponentials": lambda r, n: r.exponential(1.0, (n, 64)),  # per-pass means of a 64-pixel image
}


@pytest.mark.parametrize("n", [1024, 4096])
@pytest.mark.parametrize("name", list(FINITE))
def test_variance_growth_passes_finite_variance(name, n):
    rep = variance_growth(FINITE[name](np.random.default_rng(202), n))
    print(f"\n[stats] {name}, n = {n}: {rep}")
    assert rep.conclusive and not rep.infinite_variance


def test_variance_growth_edge_cases():
    assert not variance_growth(np.zeros(4096)).infinite_variance
    assert not variance_growth(np.full(4096, 2.5)).infinite_variance
    rep = variance_growth(np.random.default_rng(3).pareto(1.5, 100))
    assert not rep.conclusive and not rep.infinite_variance  # too few values to say
    x = np.random.default_rng(4).pareto(1.5, 4096) + 1.0
    x[::97] = np.nan
    rep = variance_growth(x)
    assert rep.nonfinite == len(x[::97]) and rep.n == 4096 - rep.nonfinite and rep.infinite_variance


# ================================================================================================
# 4. irradiance under a square light, K = 1, 4, 16 light samples

LE, RHO, H, S = 10.0, 0.5, 1.0, 0.5  # radiance, receiver albedo, light height, light half-side
IRR_CASES = {  # receiver point, receiver normal
    "on axis": ((0.0, 0.0, 0.0), (0.0, 0.0, 1.0)),
    "off axis": ((0.8, 0.3, 0.0), (0.0, 0.0, 1.0)),
    "tilted": ((0.3, -0.2, 0.1), (0.3, -0.5, 1.0)),
}
KS = (1, 4, 16)
IRR_SPP = 16


@pytest.mark.parametrize("case", list(IRR_CASES))
def test_irradiance_under_square_light_with_k_light_samples(case):
    """rho E / pi against Lambert's polygon formula for K = 1, 4, 16 (|z| <= 4 each), and per-sample variances
    about 1 / K: per seed, K times the pooled per-sample variance estimates the K = 1 variance, and the 16 seeds'
    values of it must agree with those of K = 1 under Welch (the variance's own standard error).

    max_depth 2 ends each path after next-event estimation at the receiver: the sample is rho/pi times the mean of
    K independent estimates of E (the camera jitter moves the point by < 5e-4, adding a variance below 1e-6 of
    the total), so K Var_K = Var_1. (An F test of the two pooled variances would assume normal samples; these are
    far from normal, and the F bound would be too tight by the samples' kurtosis: hence batches.)
    """
    p, n = IRR_CASES[case]
    scene, corners = irradiance_scene(p, n, (0.0, 0.0, H), S, LE, RHO)
    n_unit = np.asarray(n) / np.linalg.norm(n)
    expected = RHO / np.pi * polygon_irradiance(LE, p, n_unit, corners)
    var1 = None
    for k, seeds in zip(KS, (range(0, 16), range(100, 116), range(200, 216))):
        # 16 Sobol' replicates of one point each: the per-pixel variance gets 15 degrees of freedom (the default
        # two replicates give one, and the variance comparison below then has no power)
        r = Renderer(scene, device="cpu", max_depth=2, light_samples=k, rr="throughput", replicates=IRR_SPP)
        means, variances = stats.render_batches(r, IRR_SPP, seeds)
        batch_means = means[..., 0].mean(axis=(1, 2))
        _, se, _ = stats.assert_mean(batch_means, expected, name=f"{case}: rho E / pi, K = {k}")
        assert se < 0.01 * expected  # the test has power
        kvar = k * variances[..., 0].mean(axis=(1, 2))  # per seed: K Var_K, an estimate of Var_1
        if var1 is None:
            var1 = kvar
            continue
        ratio = kvar.mean() / var1.mean()
        w = stats.assert_agree(kvar, var1, name=f"{case}: K Var_K vs Var_1, K = {k} (ratio {ratio:.4f})")
        assert w.se < 0.05 * var1.mean()  # a ratio off by 20% would fail


# ================================================================================================
# 5. light through a planar mirror only


def _mirror_expected():
    scene, p, n, image = mirror_caustic_scene()
    rho, r, Le = 0.5, 0.8, 10.0
    return scene, rho / np.pi * r * polygon_irradiance(Le, p, n, image)


@pytest.mark.parametrize("max_depth", [2, 3, 4, -1])
def test_light_only_through_planar_mirror(max_depth):
    """TESTING.md truth 4: rho/pi r E(mirrored light polygon).

    The receiver cannot see the light (it faces away); the light's only way in is the caustic path
    receiver -(diffuse bounce)-> mirror -> light, which next-event estimation cannot sample: emission counts only
    after a mirror bounce, found by BSDF sampling. With the camera ray that is 3 segments (camera -> receiver ->
    mirror -> light), so max_depth 3 gives the full value and max_depth 2 exactly 0; more depth adds nothing
    (the light is black, and the receiver's own mirror image lies in its tangent plane).
    """
    scene, expected = _mirror_expected()
    r = Renderer(scene, device="cpu", max_depth=max_depth)
    images = stats.run_batches(lambda seed: r.render_passes(seed=seed, count=64).mean, range(300, 316))
    if max_depth == 2:
        assert np.array_equal(images, np.zeros_like(images))
        return
    v = images[..., 0].mean(axis=(1, 2))
    _, se, _ = stats.assert_mean(v, expected, name=f"mirror-only light, max_depth {max_depth}")
    assert se < 0.025 * expected


# ================================================================================================
# 6. Russian roulette

RR_ALBEDO, RR_DEPTH, RR_SPP = 0.8, 8, 8  # a^2 = 0.64 < 1 - 0.2: the seed rule has finite variance here


@pytest.fixture(scope="module")
def no_roulette_box():
    """The closed box rendered without roulette: per-seed images (16, H, W) of channel 0."""
    r = Renderer(closed_box(RR_ALBEDO, 16, 16, rr_depth=2), device="cpu", max_depth=RR_DEPTH, rr="none",
                 light_samples=1)
    return stats.render_batches(r, RR_SPP, range(0, 16))[0][..., 0]


@pytest.mark.parametrize("rr,seeds", [("seed", range(100, 116)), ("throughput", range(200, 216))])
def test_roulette_agrees_with_no_roulette(no_roulette_box, rr, seeds):
    """The closed box (albedo 0.8, max_depth 8, throughput roulette from depth 2): the image mean agrees with no
    roulette under Welch, and so does every pixel (Sidak over the 256 pixels). Disjoint seed sets: independent."""
    r = Renderer(closed_box(RR_ALBEDO, 16, 16, rr_depth=2), device="cpu", max_depth=RR_DEPTH, rr=rr,
                 light_samples=1)
    imgs = stats.render_batches(r, RR_SPP, seeds)[0][..., 0]
    a, b = imgs.mean(axis=(1, 2)), no_roulette_box.mean(axis=(1, 2))
    w = stats.assert_agree(a, b, name=f"closed box, rr = {rr} vs none (image mean)")
    assert w.se < 0.01 * b.mean()  # power: a 4% bias would fail
    stats.assert_pixels_agree(imgs, no_roulette_box, name=f"closed box, rr = {rr} vs none (per pixel)")


def test_roulette_variance_warning_static_check():
    assert diagnostics.SEED_RR_LAMBDA == pytest.approx(float(KERNEL_SEED_RR_LAMBDA))  # the kernel's lambda
    hot, mild = closed_box(0.95), closed_box(0.8)
    msg = roulette_variance_warning(hot, "seed")  # unlimited depth (the scene's max_depth is -1)
    print(f"\n[stats] warning: {msg}")
    assert msg is not None and "infinite" in msg and "0.95" in msg
    assert roulette_variance_warning(hot, "throughput") is None
    assert roulette_variance_warning(hot, "none") is None
    assert roulette_variance_warning(hot, None) is None
    assert roulette_variance_warning(mild, "seed") is None  # 0.64 < 0.8
    # the boundary a^2 = 1 - lambda: a = 0.8945 is in, 0.894 is not
    assert roulette_variance_warning(closed_box(0.8945), "seed") is not None
    assert roulette_variance_warning(closed_box(0.894), "seed") is None
    # finite depth: at most D - 2 roulette steps, each multiplying the second moment by g = 0.95^2 / 0.8 = 1.128
    assert roulette_variance_warning(hot, "seed", max_depth=8) is None  # g^6 = 2.1
    assert "max_depth 40" in roulette_variance_warning(hot, "seed", max_depth=40)  # g^38 = 98
    # the largest albedo over channels and over mirrors counts
    box = closed_box(0.5)
    add_rect(box, (0, 0, 0.5), (0.1, 0, 0), (0, 0.1, 0), (0, 0, -1), material(box, "mirror", (0.2, 0.97, 0.3)))
    assert "0.97" in roulette_variance_warning(box, "seed")


DETECT_PASSES = 2048


@pytest.mark.parametrize("albedo,rr,flag", [(0.95, "seed", True), (0.95, "throughput", False),
                                            (0.8, "seed", False)])
def test_variance_growth_detector_on_roulette_renders(albedo, rr, flag):
    """Per-pass image means of the closed box (8 x 8 pixels, unlimited depth, 2048 passes): the seed rule at
    albedo 0.95 has infinite variance (per-sample tail index log 0.8 / log(0.8 / 0.95) = 1.30) and is flagged;
    the throughput rule at 0.95 and the seed rule at 0.8 (a^2 < 0.8) are not. The static check agrees.

    Both rules start at the second bounce (rr_depth 2), so that they meet the same paths. (With rr_depth 5 a
    throughput rule broken into the seed rule is still infinite, but its per-pass means of 64 pixels need 8192
    passes to be flagged: feeding per-pixel samples instead of image means gives the detector more power.)"""
    scene = closed_box(albedo, rr_depth=2)
    r = Renderer(scene, device="cpu", max_depth=-1, rr=rr, light_samples=1, threads=1)
    values = stats.per_pass_values(r, seed=7, passes=DETECT_PASSES)[..., 0].mean(axis=(1, 2))
    rep = variance_growth(values)
    print(f"\n[stats] closed box a = {albedo}, rr = {rr}: {rep}")
    assert rep.conclusive and rep.infinite_variance == flag
    assert (roulette_variance_warning(scene, rr) is not None) == flag


def test_render_reports_the_infinite_variance_roulette_regime():
    """render() warns before rendering and fills stats['roulette_warning']; the throughput rule is silent."""
    import warnings

    import pathtracer
    from stats import closed_box

    scene = closed_box(0.95, width=4, height=4)
    st: dict = {}
    with pytest.warns(RuntimeWarning, match="variance"):
        pathtracer.render(scene, spp=1, max_depth=-1, rr="seed", stats=st, progress=False)
    assert st["roulette_warning"]
    st = {}
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        pathtracer.render(scene, spp=1, max_depth=-1, rr="throughput", stats=st, progress=False)
    assert st["roulette_warning"] is None
