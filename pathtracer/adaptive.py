"""Adaptive sampling: each pixel stops once its own estimated error is low enough, and the passes that follow go to
the pixels that are still noisy.

A pixel's error is estimated as the image's is (``PassSum.relmse_estimate``), per pixel: the variance of its mean
over the squared 3x3-filtered image plus 0.01, averaged over the channels. Where this goes wrong is known: a dark
pixel whose few samples happened to all miss the light has a spread of zero and would stop at once, black. Three
things keep it from that: no pixel stops before ``min_passes``; a pixel's error is the largest over its 3x3
neighbourhood, so that one lucky pixel among noisy ones keeps going; and a stop is decided only at fixed passes
(``min_passes``, then every ``every`` passes), from the sums there.

A stopped pixel never starts again, so its passes are always the prefix 0 .. n - 1 of the sequence: its Sobol'
points stay a prefix, its replicate counts follow from n, and the per-pixel counts merge by addition like the
sums. The decisions depend only on the sums at fixed passes, which depend only on the seed: an adaptive render is
as deterministic as a uniform one, whatever the thread count, the unit sizes, or a checkpoint and resume between.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pathtracer.errors import RenderError
from pathtracer.film import PassSum

DEFAULT_THRESHOLD = 1e-4  # a pixel's relMSE: Cycles' default noise threshold (0.01 relative error), squared
MIN_PASSES = 64
EVERY = 32
NO_LIMIT = 2**32 - 1  # the limit of a pixel that has not stopped


@dataclass(frozen=True)
class Adaptive:
    """When pixels stop: at ``min_passes`` and every ``every`` passes after, those whose (neighbourhood) error is
    at or below ``threshold``."""

    threshold: float = DEFAULT_THRESHOLD
    min_passes: int = MIN_PASSES
    every: int = EVERY

    def __post_init__(self):
        if not (isinstance(self.threshold, (int, float)) and self.threshold > 0):
            raise RenderError(f"the adaptive threshold must be > 0, got {self.threshold!r}")
        if self.min_passes < 2 or self.every < 1:
            raise RenderError("adaptive sampling needs min_passes >= 2 and every >= 1")

    def config(self) -> dict:
        return {"threshold": float(self.threshold), "min_passes": int(self.min_passes), "every": int(self.every)}

    def is_decision(self, p: int) -> bool:
        """Is pass ``p`` (about to be rendered) where stops are decided?"""
        return p >= self.min_passes and (p - self.min_passes) % self.every == 0

    def next_decision(self, p: int) -> int:
        """The first decision pass after ``p``."""
        if p < self.min_passes:
            return self.min_passes
        return self.min_passes + ((p - self.min_passes) // self.every + 1) * self.every

    def decide(self, sums: PassSum, limits: np.ndarray, p: int) -> np.ndarray:
        """The pass limits (H, W) after the decision at pass ``p``: pixels still running whose error is at or
        below the threshold stop here (limit ``p``); the others keep theirs."""
        err = pixel_errors(sums)
        stop = (limits > p) & (dilate_max(err) <= self.threshold)
        out = limits.copy()
        out[stop] = p
        return out


def pixel_errors(sums: PassSum) -> np.ndarray:
    """(H, W) estimated relMSE of each pixel's mean, as ``PassSum.relmse_estimate`` averages it."""
    return np.mean(sums.relative_variance, axis=-1)


def dilate_max(a: np.ndarray) -> np.ndarray:
    """(H, W) the largest value over each pixel's 3x3 neighbourhood (edges repeated)."""
    h, w = a.shape
    p = np.pad(a, 1, mode="edge")
    return np.max([p[dy:dy + h, dx:dx + w] for dy in range(3) for dx in range(3)], axis=0)


def limits_from_counts(counts: np.ndarray, next_pass: int) -> np.ndarray:
    """The limits of a film loaded from sums with these per-pixel counts: a pixel with fewer passes than the film
    stopped there; one with all of them is still running (a decision at ``next_pass`` itself is made again, from
    the same sums, to the same result)."""
    c = np.asarray(counts, dtype=np.int64)
    return np.where(c < next_pass, c, NO_LIMIT).astype(np.uint32)
