"""The best estimator per scene ("auto"): light tracing or not, decided by a short pilot that counts toward the image.

Light tracing (kernels/light_tracer.py) is 3-4x more efficient on the seed's mirror scenes and 6x less on the open
sky, where light paths land next to the camera; nothing in the scene description tells the two apart reliably, so a
pilot measures both. Every other choice is fixed because it measured best (or within noise of best) on every seed
scene: one light sample per light, area sampling of the lights, Sobol' (docs/performance.md).

The pilot renders ``P`` = spp / 32 passes with each candidate: A (path tracing alone) from ``seed``, B (path tracing
plus light tracing) from a seed of its own (``pilot_seed``), so that the two are independent. The candidate with the
lower relMSE x cost per pass then renders its remaining passes up to spp, continuing its own pass sequence (its
Sobol' points stay a prefix of the sequence, spp of them: a power of two stays one; with spp - P, 240 of 256, the
open sky's error was 25% higher). The image is the winner's: its pilot passes count, the loser's pilot is the price
of deciding (about 3% of the time). Averaging it in by inverse estimated error made the open sky 16% noisier: the
loser's error estimate is least reliable exactly where it loses (rare huge samples). The cost per pass is a
constant measured ratio, not the pilot's wall time: the decision, hence the image, depends only on the seed, spp
and device, never on the machine's load or the thread count.

Where the pilot has at least 2 x MIN_PILOT passes, B is looked at half way: losing by more than ``EARLY_MARGIN``
there, it renders no more (on the open sky, where it loses, its second half was 2-3% of the render). The check
depends on the candidates' sums alone, so a resumed pilot makes it again from the same sums, or finds it made.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pathtracer.render import PassSum, Renderer, box3

PILOT_FRACTION = 32  # the pilot renders 1/32 of the passes with each candidate
MIN_PILOT = 8  # ... and at least this many (two per replicate)
# light tracing's cost per pass relative to path tracing alone, measured on the two mirror scenes and the open sky
# (docs/performance.md: 1.4-1.6x); the decision margins there are 3-6x
LIGHT_TRACING_COST = 1.5
# light tracing's relMSE x cost per pass this many times path tracing's after half its pilot: it has lost. Its
# estimate there errs low, not high (the rare huge samples that make it lose are the ones a short run misses: on the
# open sky 1.8-2.3x path tracing's at half, 3.1-3.7x at the end, 6 seeds; the mirror scenes 0.05-0.13x at both)
EARLY_MARGIN = 1.5
_PILOT_SALT = 0x6C8E9CF5


def pilot_seed(seed: int) -> int:
    """The seed of candidate B's passes: a fixed bijection of ``seed``, so B's random numbers are independent of A's."""
    return (seed ^ _PILOT_SALT) * 0x9E3779B1 % 2**32


@dataclass
class Combined:
    """Means of independent estimators of one image, with fixed weights summing to 1 (as the pilot weighs its
    candidates: the winner's 1, the loser's 0, which still counts in ``seconds``)."""

    parts: list[PassSum]
    weights: list[float]
    config: dict = field(default_factory=dict)

    @property
    def mean(self) -> np.ndarray:
        return sum(w * p.mean.astype(np.float64) for w, p in zip(self.weights, self.parts)).astype(np.float32)

    @property
    def variance_of_mean(self) -> np.ndarray:
        return sum(w * w * p.variance_of_mean for w, p in zip(self.weights, self.parts))

    @property
    def relmse_estimate(self) -> float:
        """As ``PassSum.relmse_estimate``: Var[mean] / (box3(mean)^2 + 0.01), averaged over pixels and channels."""
        return float(np.mean(self.variance_of_mean / (box3(self.mean.astype(np.float64)) ** 2 + 0.01)))

    @property
    def passes(self) -> int:
        """Passes in the image (parts with a weight)."""
        return sum(p.passes for w, p in zip(self.weights, self.parts) if w > 0)

    @property
    def seconds(self) -> float:
        """Rendering time of every part, weighted or not (the pilot's time is spent either way)."""
        return sum(p.seconds for p in self.parts)

    @property
    def discarded(self) -> int:
        return sum(p.discarded for w, p in zip(self.weights, self.parts) if w > 0)


def pilot_passes(spp: int, replicates: int) -> int:
    """Passes per candidate in the pilot (a multiple of the replicates), or 0 when spp is too small for one."""
    p = max(MIN_PILOT, spp // PILOT_FRACTION)
    p -= p % replicates
    return p if 4 * p <= spp and p >= 2 * replicates else 0


def early_passes(p: int, replicates: int) -> int:
    """Candidate B's passes at the half-way check of a pilot of ``p`` each, or 0 when the pilot is too short for one."""
    h = p // 2
    h -= h % replicates
    return h if h >= MIN_PILOT and h < p else 0


def caustic_magnitude(scene) -> float:
    """The largest value one camera path can add for a caustic seen directly (diffuse bounce -> mirrors -> light):
    the bounce's weight (albedo, for cosine-weighted sampling of a Lambertian surface) times the mirrors'
    reflectance times the light's radiance, maximised over materials, mirrors and lights."""
    diffuse = [max(m.rgb) for m in scene.materials if m.kind == "diffuse"] or [1.0]
    mirrors = [max(m.rgb) for m in scene.materials if m.kind == "mirror"] or [1.0]
    lights = [max(light.radiance) for light in scene.lights] or [0.0]
    return float(max(diffuse) * max(1.0, max(mirrors)) * max(lights))


def predicted_path_error(traced_sums: PassSum, magnitude: float) -> float:
    """relMSE per pass that path tracing alone would have, predicted from a pilot with light tracing.

    The part of path space the light tracer takes over (caustics seen directly) is, for the path tracer, a rare
    event: a sample adds about ``magnitude`` when its diffuse bounce happens to reach the light through the
    mirrors, else nothing, so its variance per pass is about C x magnitude, C being that part's mean, which the
    light tracer measures (its image). A pilot of path tracing alone cannot see this: with a few passes it rarely
    draws such a sample at all, and so under-estimates its own error (on the mirror box, 8 passes chose wrongly one
    time in two). The rest of the path tracer's variance is the light-traced run's own path-tracing part."""
    pt_only = PassSum(traced_sums.sum, traced_sums.sum_sq, traced_sums.passes, rep_sum=traced_sums.rep_sum,
                      rep_passes=traced_sums.rep_passes, estimator=traced_sums.estimator)
    n = traced_sums.passes
    caustic = np.maximum(traced_sums.lt_sum / n, 0.0)
    image = box3(traced_sums.mean.astype(np.float64))
    denom = image * image + 0.01
    return float(np.mean(pt_only.variance_of_mean * n / denom) + np.mean(caustic * magnitude / denom))


@dataclass
class Pilot:
    """The pilot's outcome: which candidate won, the films of both (the winner's continues), the figures.

    ``finished`` False: a stop came first; the films hold the passes rendered until then (candidate A's, then B's)
    and nothing is decided (``use_light_tracing`` False, ``config`` only the pilot's progress)."""

    use_light_tracing: bool
    films: dict  # "path", "light_tracing" -> Film with the pilot's passes
    seeds: dict  # the same keys -> the seed of that candidate's passes
    passes: int  # per candidate
    config: dict
    finished: bool = True

    @property
    def winner(self) -> str:
        return "light_tracing" if self.use_light_tracing else "path"

    @property
    def loser(self) -> str:
        return "path" if self.use_light_tracing else "light_tracing"


def run_pilot(path: Renderer, traced: Renderer, seed: int, spp: int, progress=False, stop=None,
              films: tuple | None = None, passes: int | None = None) -> Pilot:
    """Render the pilot passes with both renderers (``path``: light tracing off, ``traced``: on) and decide.

    ``stop`` (a ``jobs.StopFlag``): once set, the pilot stops after the passes under way (unfinished: see ``Pilot``).
    ``films``: the two candidates' films to continue (a resumed pilot); they hold a prefix of each candidate's
    passes, so the pilot ends with the same sums, and the same decision, as one that was never interrupted.
    ``passes``: the pilot's passes per candidate (a resumed pilot keeps its own), else ``pilot_passes(spp)``."""
    p = passes if passes is not None else pilot_passes(spp, path.replicates)
    seed_b = pilot_seed(seed)
    fa, fb = films if films is not None else (path.new_film(), traced.new_film())
    seeds = {"path": seed, "light_tracing": seed_b}
    h = early_passes(p, path.replicates)
    # B's passes before its check (a resumed pilot past the check has made it already, and B went on)
    first_b = h if h and fb.passes <= h else p

    def stopped():
        return stop is not None and stop.is_set()

    if hasattr(path, "start"):  # the Ray farm: both candidates' units handed out before waiting for either
        if fa.passes < p:
            path.start(fa, seed, fa.next_pass, p - fa.passes)
        if fb.passes < first_b:
            traced.start(fb, seed_b, fb.next_pass, first_b - fb.passes)
    for renderer, film, s, n in ((path, fa, seed, p), (traced, fb, seed_b, first_b)):
        if film.passes < n and not stopped():
            renderer.render_into(film, s, film.next_pass, n - film.passes, progress, stop=stop)
    lost_early, at_half = False, None
    if fa.passes == p and fb.passes == first_b and first_b < p:  # the half-way check
        cost, measured, predicted = _costs(fa.sums(), fb.sums(), path.scene)
        lost_early = cost["light_tracing"] > EARLY_MARGIN * cost["path"]
        at_half = {k: float(v) for k, v in cost.items()}
        if not lost_early and not stopped():
            traced.render_into(fb, seed_b, fb.next_pass, p - fb.passes, progress, stop=stop)
    if fa.passes < p or (fb.passes < p and not lost_early):
        config = {"light_tracing": False, "pilot": {"passes_each": p, "unfinished": True,
                                                     "passes_done": {"path": fa.passes, "light_tracing": fb.passes}}}
        return Pilot(False, {"path": fa, "light_tracing": fb}, seeds, p, config, finished=False)
    if not lost_early:
        cost, measured, predicted = _costs(fa.sums(), fb.sums(), path.scene)
    a, b = fa.sums(), fb.sums()
    use_lt = cost["light_tracing"] < cost["path"]
    # the loser's pilot is not averaged in: it lost because its error is larger, and its own estimate of that error
    # is least reliable exactly then (light tracing's rare huge samples on the open sky): weighted by it, the image
    # came out 16% noisier there than path tracing alone
    weights = [0.0, 1.0] if use_lt else [1.0, 0.0]
    config = {"light_tracing": use_lt, "pilot": {
        "passes_each": p, "light_tracing_passes": fb.passes, "lost_at_half": lost_early,
        "relmse_x_cost_per_pass_at_half": at_half,
        "light_tracing_cost_ratio": LIGHT_TRACING_COST,
        "relmse_x_cost_per_pass": {k: float(v) for k, v in cost.items()},
        "path_measured": float(measured), "path_predicted": predicted,
        "pilot_seconds": {"path": a.seconds, "light_tracing": b.seconds},
        "weights": {"path": weights[0], "light_tracing": weights[1]}}}
    return Pilot(use_lt, {"path": fa, "light_tracing": fb}, seeds, p, config)


def _costs(a: PassSum, b: PassSum, scene) -> tuple[dict, float, float]:
    """relMSE x cost per pass of each candidate (A: path tracing, B: with light tracing), from their pilot sums:
    path tracing's measured or, where the pilot cannot have seen its rare caustic samples, predicted from the
    light tracer's view of them (whichever is larger). Also returns those two figures."""
    predicted = predicted_path_error(b, caustic_magnitude(scene))
    measured = a.relmse_estimate * a.passes
    cost = {"path": max(measured, predicted),
            "light_tracing": b.relmse_estimate * b.passes * LIGHT_TRACING_COST}
    return cost, measured, predicted
