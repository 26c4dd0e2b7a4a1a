"""Diagnostics for estimators whose variance may be infinite (TESTING.md: detect it, do not average it away).

``variance_growth(values)`` looks at independent per-pass (or per-batch) values of one estimator and says whether
their variance keeps growing with the number of samples. ``roulette_variance_warning(scene, rr)`` is the static
check: the seed's Russian roulette rule (stop with probability lambda = 0.2 after the first bounce, survivors
divided by 0.8) has infinite variance when a surface's albedo a satisfies a^2 >= 1 - lambda (a >= 0.894).

Why the seed rule diverges: a path that survives n roulette steps on surfaces of albedo a carries the throughput
(a / 0.8)^n, with probability 0.8^n; the second moment sums (a^2 / 0.8)^n over n, which diverges for a^2 >= 0.8.
Its per-sample values then have a power-law tail P(X > x) ~ x^-alpha with alpha = log(0.8) / log(0.8 / a)
(alpha = 1.30 at a = 0.95): the mean is finite, the variance is not. Mitsuba's throughput rule (continue with
probability min(max(beta), 0.95) and divide by it) keeps the throughput near 1 and has no such regime.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

SEED_RR_LAMBDA = 0.2  # kernels/integrator.py SEED_RR_LAMBDA (kept equal by tests/test_statistics.py)
AMPLIFICATION_LIMIT = 10.0  # finite max_depth: warn when the second moment may grow by more than this

# variance_growth defaults (chosen on simulated Pareto, exponential, normal, lognormal and gamma samples and on
# the renders of tests/test_statistics.py; see that file for the figures)
MIN_VALUES = 256
MIN_BLOCK = 8
MIN_BLOCKS = 8
TAIL_EXPONENT = 0.6  # the Hill estimator uses the k = n^0.6 largest deviations
TAIL_Z = 2.0  # flag only when the tail index is below 2 by this many of its standard errors
GROWTH_THRESHOLD = 0.1  # and the variance grows at least as N^0.1 (7% per doubling)


@dataclass
class VarianceGrowthReport:
    """What ``variance_growth`` found. ``infinite_variance`` is the verdict; the rest says why."""

    infinite_variance: bool
    conclusive: bool  # False when there were too few values to judge (infinite_variance is then False)
    n: int  # finite values used
    nonfinite: int  # NaN / Inf values left out
    growth_exponent: float  # slope of log(median block variance) against log(block size); ~0 for finite variance
    block_sizes: list[int] = field(default_factory=list)
    block_variances: list[float] = field(default_factory=list)  # median sample variance of blocks of that size
    tail_index: float = math.inf  # Hill estimate of alpha in P(|X - median| > x) ~ x^-alpha; alpha < 2: infinite
    tail_index_se: float = math.inf  # its standard error, alpha / sqrt(k)
    tail_count: int = 0  # k, the number of largest deviations the Hill estimate used
    reason: str = ""

    def __str__(self) -> str:
        verdict = "INFINITE variance" if self.infinite_variance else "finite variance"
        if not self.conclusive:
            verdict = "inconclusive"
        return (f"{verdict}: n = {self.n}, variance growth exponent {self.growth_exponent:.2f} "
                f"(block sizes {self.block_sizes[:1] + self.block_sizes[-1:]}), tail index "
                f"{self.tail_index:.2f} +- {self.tail_index_se:.2f} (k = {self.tail_count}); {self.reason}")


def _block_variances(x: np.ndarray, min_block: int, min_blocks: int) -> tuple[list[int], list[float]]:
    """Median over disjoint blocks of size m of the blocks' sample variances, for m = min_block, 2 min_block, ..."""
    sizes, meds = [], []
    m = min_block
    while len(x) // m >= min_blocks:
        nb = len(x) // m
        v = x[: nb * m].reshape(nb, m).var(axis=1, ddof=1)
        sizes.append(m)
        meds.append(float(np.median(v)))
        m *= 2
    return sizes, meds


def _hill(x: np.ndarray, exponent: float) -> tuple[float, float, int]:
    """Hill's estimator of the tail index of |x - median(x)| from its k = n^exponent largest values."""
    y = np.abs(x - np.median(x))
    y = np.sort(y[y > 0])[::-1]
    k = min(max(16, int(round(len(x) ** exponent))), len(y) - 1)
    if k < 16:
        return math.inf, math.inf, 0  # (almost) constant: no tail at all
    logs = np.log(y[:k] / y[k])
    s = float(logs.sum())
    if s <= 0.0:
        return math.inf, math.inf, k
    alpha = k / s
    return alpha, alpha / math.sqrt(k), k


def variance_growth(
    values,
    *,
    min_block: int = MIN_BLOCK,
    min_blocks: int = MIN_BLOCKS,
    tail_exponent: float = TAIL_EXPONENT,
    tail_z: float = TAIL_Z,
    growth_threshold: float = GROWTH_THRESHOLD,
) -> VarianceGrowthReport:
    """Does the variance of these independent, identically distributed values keep growing as N doubles?

    ``values``: per-pass (or per-batch) values of one estimator, in the order they were drawn, shape (N,); an
    (N, ...) array is reduced to its per-pass mean over the other axes. Two signs must agree to flag:

    1. growth: the median, over disjoint blocks of m values, of the blocks' sample variance, for m = 8, 16, 32, ...
       (at least 8 blocks). With a finite variance it settles at sigma^2; with a tail index alpha < 2 it grows as
       m^(2 / alpha - 1). The fitted exponent must exceed ``growth_threshold``. (The plain variance of the first
       N, 2N, 4N, ... values grows too, but one huge value makes it jump and never fall back: far too noisy.)
    2. tail: Hill's estimate of the tail index of |x - median| from the k = N^0.6 largest deviations must be below
       2 by ``tail_z`` standard errors (alpha / sqrt(k)).

    Needs at least 256 finite values to be conclusive (about 1000 for a tail index near 1.5 to be found reliably).
    A finite variance with a very slowly converging sample variance (a tail index between 2 and 3) can be flagged
    at small N: that, too, is a variance that keeps growing over the N at hand.
    """
    x = np.asarray(values, dtype=np.float64)
    if x.ndim > 1:
        x = x.reshape(len(x), -1).mean(axis=1)
    finite = np.isfinite(x)
    nonfinite = int((~finite).sum())
    x = x[finite]
    n = len(x)
    if n < MIN_VALUES:
        return VarianceGrowthReport(False, False, n, nonfinite, math.nan,
                                    reason=f"too few values to judge ({n} < {MIN_VALUES})")
    sizes, meds = _block_variances(x, min_block, min_blocks)
    ok = [i for i, v in enumerate(meds) if v > 0.0]
    if len(ok) >= 3:
        growth = float(np.polyfit(np.log([sizes[i] for i in ok]), np.log([meds[i] for i in ok]), 1)[0])
    else:
        growth = 0.0  # (almost) every block is constant
    alpha, alpha_se, k = _hill(x, tail_exponent)
    grows = growth > growth_threshold
    heavy = alpha + tail_z * alpha_se < 2.0
    flagged = bool(grows and heavy)
    if flagged:
        reason = (f"the variance grows as N^{growth:.2f} and the tail index {alpha:.2f} is below 2 "
                  f"(the mean may be finite, its error estimate is not)")
    elif grows:
        reason = f"the variance grows as N^{growth:.2f}, but the tail index {alpha:.2f} is not clearly below 2"
    elif heavy:
        reason = f"the tail index {alpha:.2f} is below 2, but the variance does not grow (N^{growth:.2f})"
    else:
        reason = "the variance settles and the tail is light"
    return VarianceGrowthReport(flagged, True, n, nonfinite, growth, sizes, meds, alpha, alpha_se, k, reason)


# ------------------------------------------------------------------------------------------------
# Russian roulette: a static check


def _used_materials(scene) -> set[int]:
    """Indices of the materials any shape of ``scene`` refers to (every list of objects with a ``material``)."""
    used: set[int] = set()
    for items in vars(scene).values():
        if isinstance(items, list):
            for obj in items:
                m = getattr(obj, "material", None)
                if isinstance(m, (int, np.integer)) and not isinstance(m, bool):
                    used.add(int(m))
    return used


def largest_albedo(scene) -> float:
    """The largest diffuse albedo or mirror reflectance, over channels, of the materials the scene's shapes use."""
    used = _used_materials(scene)
    values = [max(scene.materials[i].rgb) for i in used if 0 <= i < len(scene.materials)]
    return float(max(values, default=0.0))


def roulette_variance_warning(scene, rr: str | None, max_depth: int | None = None) -> str | None:
    """A warning (one line) when the roulette rule ``rr`` gives ``scene`` an infinite (or hugely amplified)
    variance, else None.

    Only the seed rule has such a regime: with the scene's largest albedo or mirror reflectance a, a path that keeps
    bouncing has a second moment that grows by g = a^2 / (1 - lambda) per roulette step, lambda = 0.2; g >= 1
    (a >= 0.894) is infinite with unlimited depth (TESTING.md truth 5). With a finite ``max_depth`` D (None: the
    scene's) there are at most D - 2 roulette steps, and the warning is given when g^(D - 2) exceeds 10.
    ``rr`` None means the renderer's default (the throughput rule): no warning.
    """
    if rr != "seed":
        return None
    a = largest_albedo(scene)
    g = a * a / (1.0 - SEED_RR_LAMBDA)
    if g < 1.0:
        return None
    depth = scene.integrator.max_depth if max_depth is None else int(max_depth)
    head = (f"Russian roulette 'seed' (lambda = {SEED_RR_LAMBDA:g}) with albedo {a:.3g}: "
            f"a^2 = {a * a:.3g} >= 1 - lambda = {1.0 - SEED_RR_LAMBDA:.3g}")
    if depth < 0:
        grow = math.log(a / (1.0 - SEED_RR_LAMBDA))  # > 0: a >= 0.894 > 0.8 here
        alpha = -math.log(1.0 - SEED_RR_LAMBDA) / grow if grow > 0.0 else math.inf
        return (f"{head}: the variance is infinite (per-sample tail index about {alpha:.2f} <= 2); the noise will "
                f"not average away and the error estimate is meaningless. Use rr='throughput' or a finite max_depth.")
    amp = g ** max(depth - 2, 0)
    if amp <= AMPLIFICATION_LIMIT:
        return None
    return (f"{head}: the variance is infinite without a depth limit; at max_depth {depth} long paths' second "
            f"moment still grows {amp:.3g}-fold (g^(D - 2), g = a^2 / (1 - lambda) = {g:.3g}). "
            f"Use rr='throughput'.")
