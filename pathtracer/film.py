"""The film: a render's per-pixel float64 sums, on the device while passes are added to them (``Film``) and on the
host as a record that merges by addition and carries the error estimates (``PassSum``).

The render kernel adds each pass to the film in pass order (kernels/integrator.py: render_pass), so a film that
is continued over several calls, or saved and loaded back in between (pathtracer/jobs.py), holds the same sums bit
for bit as one call over all of its passes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp


SRGB_TO_XYZ = np.array([[0.412453, 0.357580, 0.180423],  # Mitsuba's (kernels/film.py: srgb_to_xyz)
                        [0.212671, 0.715160, 0.072169],
                        [0.019334, 0.119193, 0.950227]])


@dataclass
class PassSum:
    """Per-pixel sums over ``passes`` sample passes: mergeable by addition.

    Pass p also goes to replicate p mod R (``rep_sum``): with the Sobol' sampler each replicate is an independent
    scramble, so the spread of the replicate means is an unbiased estimate of the error of their average, while
    the spread of the passes (``sum_sq``) is not (stratified passes are negatively correlated). ``estimator`` says
    which one ``variance_of_mean`` uses: "passes" (independent sampling) or "replicates" (Sobol')."""

    sum: np.ndarray  # (H, W, 3) float64, sum of samples
    sum_sq: np.ndarray  # (H, W, 3) float64, sum of squared samples
    passes: int
    discarded: int = 0  # non-finite samples dropped (never reach the image)
    seconds: float = 0.0  # time spent rendering (excluding compilation)
    rays: int = 0  # rays traced, counted only by a Renderer made with count_rays=True
    # the light tracer's share (caustics seen directly), per pass, when it runs: independent of the path tracer's
    lt_sum: np.ndarray | None = None
    lt_sum_sq: np.ndarray | None = None
    rep_sum: np.ndarray | None = None  # (R, H, W, 3) float64: the path tracer's sum per replicate
    rep_passes: np.ndarray | None = None  # (R,) int: passes per replicate
    estimator: str = "passes"
    m2_sum: np.ndarray | None = None  # (H, W, 3) float64: sum of squared per-sample XYZ (moment integrator only)
    # (H, W) int64: passes each pixel has (adaptive sampling: a pixel's passes are 0 .. counts - 1); None: all have
    # ``passes``
    counts: np.ndarray | None = None
    grad_sum: np.ndarray | None = None  # (H, W, 3) float64: sum of each sample's dL/dtheta (gradient renders)

    def __add__(self, other: "PassSum") -> "PassSum":
        def add(a, b):
            return b if a is None else a if b is None else a + b

        if self.estimator != other.estimator:
            raise ValueError(f"cannot merge sums of different samplers ({self.estimator} and {other.estimator})")
        if self.rep_sum is not None and other.rep_sum is not None and len(self.rep_sum) != len(other.rep_sum):
            raise ValueError(f"cannot merge sums of {len(self.rep_sum)} and {len(other.rep_sum)} replicates")
        counts = None
        if self.counts is not None or other.counts is not None:
            counts = self.pixel_counts() + other.pixel_counts()
        return PassSum(self.sum + other.sum, self.sum_sq + other.sum_sq, self.passes + other.passes,
                       self.discarded + other.discarded, self.seconds + other.seconds, self.rays + other.rays,
                       add(self.lt_sum, other.lt_sum), add(self.lt_sum_sq, other.lt_sum_sq),
                       add(self.rep_sum, other.rep_sum), add(self.rep_passes, other.rep_passes), self.estimator,
                       add(self.m2_sum, other.m2_sum), counts, add(self.grad_sum, other.grad_sum))

    def pixel_counts(self) -> np.ndarray:
        """(H, W) int64: the passes of each pixel."""
        if self.counts is not None:
            return self.counts
        return np.full(self.sum.shape[:2], self.passes, dtype=np.int64)

    def _n(self):
        """Passes per pixel, broadcastable against (H, W, 3): a number, or (H, W, 1) with per-pixel counts."""
        return self.passes if self.counts is None else self.counts[..., None].astype(np.float64)

    @property
    def mean(self) -> np.ndarray:
        """Linear radiance, float32 (H, W, 3)."""
        total = self.sum if self.lt_sum is None else self.sum + self.lt_sum
        return (total / np.maximum(self._n(), 1)).astype(np.float32)

    def layers(self, names: tuple[str, ...]) -> dict[str, np.ndarray]:
        """Mitsuba's moment layers, float32 (H, W, 3) each: ``names[0]`` the mean XYZ of the samples, ``names[1]``
        the mean of their squares (``Integrator.layer_names``); empty when none were summed."""
        if self.m2_sum is None or not names:
            return {}
        n = max(self.passes, 1)
        xyz = (self.sum / n) @ SRGB_TO_XYZ.T
        return {names[0]: xyz.astype(np.float32), names[1]: (self.m2_sum / n).astype(np.float32)}

    @staticmethod
    def _var_of_mean(total: np.ndarray, total_sq: np.ndarray, n) -> np.ndarray:
        """The sample variance of the mean of n samples (n: a number or per-pixel counts; inf where n < 2)."""
        if np.isscalar(n):
            m = total / n
            return np.maximum(total_sq / n - m * m, 0.0) * n / (n - 1) / n
        k = np.maximum(n, 2.0)
        m = total / k
        return np.where(n >= 2, np.maximum(total_sq / k - m * m, 0.0) / (k - 1), np.inf)

    def _replicate_var_of_mean(self) -> np.ndarray:
        """sum_r n_r (m_r - m)^2 / (R' - 1) / N over the R' non-empty replicates: the spread of the replicate
        means, each weighted by its pass count (exactly the variance of the mean of R equal replicates)."""
        if self.counts is not None:
            return self._replicate_var_of_mean_per_pixel()
        n = np.asarray(self.rep_passes, dtype=np.float64)
        used = n > 0
        if used.sum() < 2:
            return np.full_like(self.sum, np.inf)
        reps = self.rep_sum[used]
        n = n[used]
        m = self.sum / self.passes
        dev = reps / n[:, None, None, None] - m
        return np.einsum("r,rhwc->hwc", n, dev * dev) / (len(n) - 1) / self.passes

    def _replicate_var_of_mean_per_pixel(self) -> np.ndarray:
        """As ``_replicate_var_of_mean`` with each pixel's own counts: its passes are 0 .. c - 1, so replicate r
        has ceil((c - r) / R) of them."""
        R = len(self.rep_sum)
        c = self.counts.astype(np.int64)
        n_r = np.maximum((c[None] - np.arange(R)[:, None, None] + R - 1) // R, 0).astype(np.float64)  # (R, H, W)
        used = n_r > 0
        r_used = used.sum(axis=0).astype(np.float64)  # (H, W)
        m = self.sum / np.maximum(c, 1)[..., None]
        dev = self.rep_sum / np.maximum(n_r, 1)[..., None] - m
        ss = np.einsum("rhw,rhwc->hwc", n_r, dev * dev)
        var = ss / np.maximum(r_used - 1, 1)[..., None] / np.maximum(c, 1)[..., None]
        return np.where((r_used >= 2)[..., None], var, np.inf)

    @property
    def variance_of_mean(self) -> np.ndarray:
        """Per-pixel, per-channel estimate of the variance of ``mean``: from the spread of the passes (independent
        sampling) or of the replicates (Sobol')."""
        n = self.passes
        if n < 2:
            return np.full_like(self.sum, np.inf)
        if self.estimator == "replicates":
            var = self._replicate_var_of_mean()
        else:
            var = self._var_of_mean(self.sum, self.sum_sq, self._n())
        if self.lt_sum is not None:  # the two estimators use independent random numbers: variances add
            var = var + self._var_of_mean(self.lt_sum, self.lt_sum_sq, n)
        return var

    @property
    def relmse_estimate(self) -> float:
        """The image's estimated relMSE against the true image R, mean((mean - R)^2 / (R^2 + 0.01)): the mean over
        pixels and channels of Var[mean] / (R'^2 + 0.01), R' the mean image box-filtered over 3x3 pixels.

        Why not mean^2 in the denominator: a pixel's rare huge sample (a caustic that a diffuse bounce happened to
        find) then inflates its own denominator and hides the very error it causes; on the mirror scenes that
        under-estimated the relMSE 2-5x at 64 spp. The filter dilutes a one-pixel spike nine-fold and leaves
        smooth regions as they are (measured estimate / true relMSE over 5 seeds: 0.75-0.96 at 64 spp,
        0.89-1.01 at 256 spp on the four seed scenes; the median or trimmed mean of the replicates instead
        over-estimated the teapot's 1.4-2x, where much of a pixel's value comes from rare paths)."""
        return float(np.mean(self.relative_variance))

    @property
    def relative_variance(self) -> np.ndarray:
        """(H, W, 3): each pixel's and channel's term of ``relmse_estimate``, Var[mean] / (R'^2 + 0.01)."""
        return self.variance_of_mean / (box3(self.mean.astype(np.float64)) ** 2 + 0.01)


def box3(img: np.ndarray) -> np.ndarray:
    """(H, W, C) image averaged over each pixel's 3x3 neighbourhood (edges repeated)."""
    h, w = img.shape[:2]
    p = np.pad(img, ((1, 1), (1, 1), (0, 0)), mode="edge")
    return sum(p[dy:dy + h, dx:dx + w] for dy in range(3) for dx in range(3)) / 9.0


class Film:
    """The device accumulators of one renderer's passes (the kernel's outputs), and the bookkeeping that turns
    them into a ``PassSum``: passes done, the next pass, passes per replicate, discarded samples, seconds."""

    def __init__(self, width: int, height: int, replicates: int, moments: bool, light_tracing: bool, tiles: int,
                 device: str, estimator: str, adaptive: bool = False, gradient: bool = False):
        self.width, self.height, self.replicates = width, height, replicates
        self.estimator = estimator
        npix = width * height
        with wp.ScopedDevice(device):
            self.accum = wp.zeros(npix, dtype=wp.vec3d)
            self.accum_sq = wp.zeros(npix, dtype=wp.vec3d)
            self.accum_rep = wp.zeros(replicates * npix, dtype=wp.vec3d)
            self.accum_m2 = wp.zeros(npix if moments else 1, dtype=wp.vec3d)
            self.accum_grad = wp.zeros(npix if gradient else 1, dtype=wp.vec3d)
            self.discarded = wp.zeros(tiles, dtype=wp.int32)  # one counter per tile
            # adaptive sampling: the pass each pixel stops at (pathtracer/adaptive.py); else one unused element
            self.limits = np.full((height, width), 2**32 - 1, dtype=np.uint32) if adaptive else None
            self.pass_limit = wp.array(self.limits.reshape(-1), dtype=wp.uint32) if adaptive else \
                wp.zeros(1, dtype=wp.uint32)
            self.rays = wp.zeros(tiles, dtype=wp.int64)
            self.lt = None
            if light_tracing:
                self.lt = {k: wp.zeros(npix, dtype=wp.vec3d) for k in ("splat", "sum", "sum_sq")}
                self.lt["discarded"] = wp.zeros(1, dtype=wp.int32)
        self.moments = moments
        self.gradient = gradient
        self.passes = 0
        self.next_pass = 0
        self.rep_passes = np.zeros(replicates, dtype=np.int64)
        self.seconds = 0.0
        self.base_discarded = 0  # counts and rays of passes loaded from a PassSum (not in the device counters)
        self.base_rays = 0

    def added(self, first: int, count: int, seconds: float) -> None:
        """Record that passes ``first .. first + count - 1`` were added (in order, after the ones before)."""
        passes = np.arange(first, first + count, dtype=np.int64)
        self.rep_passes += np.bincount(passes % self.replicates, minlength=self.replicates)
        self.passes += count
        self.next_pass = first + count
        self.seconds += seconds

    def sums(self) -> PassSum:
        """A host copy of the sums so far."""
        shape = (self.height, self.width, 3)
        R = self.replicates
        sums = PassSum(self.accum.numpy().reshape(shape).copy(), self.accum_sq.numpy().reshape(shape).copy(),
                       self.passes, self.base_discarded + int(self.discarded.numpy().sum()), self.seconds,
                       self.base_rays + int(self.rays.numpy().sum()),
                       rep_sum=self.accum_rep.numpy().reshape((R,) + shape).copy(),
                       rep_passes=self.rep_passes.copy(), estimator=self.estimator)
        if self.moments:
            sums.m2_sum = self.accum_m2.numpy().reshape(shape).copy()
        if self.gradient:
            sums.grad_sum = self.accum_grad.numpy().reshape(shape).copy()
        if self.limits is not None:
            sums.counts = np.minimum(self.limits.astype(np.int64), self.next_pass)
        if self.lt is not None:
            sums.lt_sum = self.lt["sum"].numpy().reshape(shape).copy()
            sums.lt_sum_sq = self.lt["sum_sq"].numpy().reshape(shape).copy()
            sums.discarded += int(self.lt["discarded"].numpy()[0])
        return sums

    def set_limits(self, limits: np.ndarray) -> None:
        """New per-pixel pass limits (adaptive sampling), used from the next launch on."""
        self.limits = np.ascontiguousarray(limits, dtype=np.uint32)
        wp.copy(self.pass_limit, wp.array(self.limits.reshape(-1), dtype=wp.uint32, device=self.accum.device))

    def load(self, sums: PassSum, next_pass: int) -> None:
        """Continue from ``sums`` (a checkpoint's): their arrays become the accumulators, ``next_pass`` the pass
        to add next."""
        R = self.replicates
        if sums.sum.shape != (self.height, self.width, 3) or sums.rep_sum is None or len(sums.rep_sum) != R:
            raise ValueError("the sums do not match this film")
        if (sums.m2_sum is not None) != self.moments or (sums.lt_sum is not None) != (self.lt is not None):
            raise ValueError("the sums do not match this film's layers")
        if (sums.counts is not None) != (self.limits is not None):
            raise ValueError("the sums are of an adaptive render and this one is not, or the other way round")
        device = self.accum.device

        def put(dst, a):
            wp.copy(dst, wp.array(np.ascontiguousarray(a, dtype=np.float64).reshape(-1, 3), dtype=wp.vec3d,
                                  device=device))

        put(self.accum, sums.sum)
        put(self.accum_sq, sums.sum_sq)
        put(self.accum_rep, sums.rep_sum)
        if self.moments:
            put(self.accum_m2, sums.m2_sum)
        if self.lt is not None:
            put(self.lt["sum"], sums.lt_sum)
            put(self.lt["sum_sq"], sums.lt_sum_sq)
            self.lt["discarded"].zero_()
        self.discarded.zero_()
        self.rays.zero_()
        self.passes = sums.passes
        self.next_pass = next_pass
        self.rep_passes = np.asarray(sums.rep_passes, dtype=np.int64).copy()
        self.seconds = sums.seconds
        self.base_discarded = sums.discarded
        self.base_rays = sums.rays
        if self.limits is not None:
            from pathtracer.adaptive import limits_from_counts

            self.set_limits(limits_from_counts(sums.counts, next_pass))
