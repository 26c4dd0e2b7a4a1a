"""pathtracer/estimator.py: the "auto" choice of light tracing, by a pilot that counts toward the image."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import pathtracer
from pathtracer import estimator
from pathtracer.render import PassSum

SCENES = Path(__file__).resolve().parents[1] / "scenes"


def test_pilot_size():
    assert estimator.pilot_passes(1024, 4) == 32  # 1/32 of the passes, a multiple of the replicates
    assert estimator.early_passes(32, 4) == 16 and estimator.early_passes(16, 2) == 8
    assert estimator.early_passes(8, 2) == 0 and estimator.early_passes(12, 4) == 0  # fewer than MIN_PILOT at half
    assert estimator.pilot_passes(64, 4) == 8  # at least MIN_PILOT
    assert estimator.pilot_passes(28, 4) == 0  # too few passes for a pilot of both and a main run
    assert estimator.pilot_passes(1000, 3) % 3 == 0


def test_pilot_seed_is_a_different_sequence():
    seeds = [estimator.pilot_seed(s) for s in range(1000)]
    assert len(set(seeds)) == 1000 and all(0 <= s < 2**32 for s in seeds)
    assert all(estimator.pilot_seed(s) != s for s in range(1000))


def _sums(value, var, passes):
    shape = (2, 2, 3)
    total = np.full(shape, value * passes)
    return PassSum(total, total * value + var * passes * passes, passes)  # per-pass variance `var * passes`


def test_combination_of_two_estimates():
    a, b = _sums(1.0, 0.04, 10), _sums(1.0, 0.01, 10)  # b's error is four times smaller
    inv = [1.0 / a.relmse_estimate, 1.0 / b.relmse_estimate]
    w = [x / sum(inv) for x in inv]  # inverse-error weights
    assert sum(w) == pytest.approx(1.0) and w[1] == pytest.approx(4 * w[0], rel=1e-6)
    c = estimator.Combined([a, b], w)
    # the combination's variance is the weighted sum, below either part's
    assert np.all(c.variance_of_mean < np.minimum(a.variance_of_mean, b.variance_of_mean))
    assert np.allclose(c.mean, 1.0)
    # a part with weight 0 (the loser's pilot) adds its time, not its passes
    drop = estimator.Combined([a, b], [0.0, 1.0])
    assert drop.passes == 10 and np.array_equal(drop.variance_of_mean, b.variance_of_mean)


@pytest.mark.parametrize("name,expect", [("cornell_box_mirror.xml", True), ("open_sky.xml", False)])
def test_auto_picks_light_tracing_where_it_wins(name, expect):
    """The seed's mirror box: light tracing (3-4x more efficient in docs/performance.md); the open sky: not (6x
    less). The winner's pilot counts: the image is its spp passes; the loser's pilot is left out."""
    scene = pathtracer.load_file(SCENES / name, width=48, height=36)
    st = {}
    img = pathtracer.render(scene, spp=128, seed=1, progress=False, stats=st)
    cfg = st["config"]
    assert cfg["light_tracing"] is expect and cfg["light_tracing_choice"] == "auto"
    assert st["spp"] == 128 and cfg["pilot"]["passes_each"] == 8
    assert cfg["pilot"]["relmse_x_cost_per_pass_at_half"] is None  # too short a pilot for a half-way check
    w = cfg["pilot"]["weights"]
    assert w["light_tracing" if expect else "path"] == 1.0 and sum(w.values()) == 1.0
    assert np.isfinite(img).all() and img.mean() > 0


def test_a_light_tracer_losing_half_way_renders_no_more(monkeypatch):
    """On the open sky light tracing loses (its pilot's error x cost 1.8-2.8x path tracing's half way, 3-4x at the
    end): from 512 spp on (16 pilot passes each) it stops after 8, and the decision and the image are those of the
    whole pilot (the image is path tracing's, from the same seed, as with light tracing off)."""
    scene = pathtracer.load_file(SCENES / "open_sky.xml", width=128, height=64)  # (smaller, B may not lose by 1.5x)
    st = {}
    img = pathtracer.render(scene, spp=512, seed=3, progress=False, stats=st)
    pilot = st["config"]["pilot"]
    assert pilot["passes_each"] == 16 and pilot["lost_at_half"] and pilot["light_tracing_passes"] == 8
    half = pilot["relmse_x_cost_per_pass_at_half"]
    assert half["light_tracing"] > estimator.EARLY_MARGIN * half["path"]
    assert st["config"]["light_tracing"] is False and st["spp"] == 512
    assert np.array_equal(img, pathtracer.render(scene, spp=512, seed=3, progress=False, light_tracing=False))
    monkeypatch.setattr(estimator, "EARLY_MARGIN", float("inf"))  # the whole pilot, as before the check
    st2 = {}
    whole = pathtracer.render(scene, spp=512, seed=3, progress=False, stats=st2)
    assert st2["config"]["pilot"]["light_tracing_passes"] == 16 and not st2["config"]["pilot"]["lost_at_half"]
    assert st2["config"]["light_tracing"] is False and np.array_equal(whole, img)


def test_a_light_tracer_winning_half_way_finishes_its_pilot():
    """The mirror box: light tracing wins (0.1x path tracing's error x cost), so the check lets it go on."""
    scene = pathtracer.load_file(SCENES / "cornell_box_mirror.xml", width=48, height=36)
    st = {}
    pathtracer.render(scene, spp=512, seed=1, progress=False, stats=st)
    pilot = st["config"]["pilot"]
    assert st["config"]["light_tracing"] is True and not pilot["lost_at_half"]
    assert pilot["light_tracing_passes"] == 16 and pilot["relmse_x_cost_per_pass_at_half"] is not None


def test_auto_does_not_depend_on_threads():
    scene = pathtracer.load_file(SCENES / "cornell_box_mirror.xml", width=32, height=24)
    a = pathtracer.render(scene, spp=64, seed=2, threads=1, progress=False)
    b = pathtracer.render(scene, spp=64, seed=2, threads=2, progress=False)
    assert np.array_equal(a, b)


def test_fixed_choices_run_no_pilot():
    scene = pathtracer.load_file(SCENES / "cornell_box_mirror.xml", width=16, height=12)
    for lt in (True, False):
        st = {}
        pathtracer.render(scene, spp=64, seed=0, light_tracing=lt, progress=False, stats=st)
        assert st["config"]["light_tracing"] is lt and "pilot" not in st["config"]
    st = {}  # no mirrors: nothing to decide, no pilot
    pathtracer.render(pathtracer.load_file(SCENES / "cornell_box.xml", width=16, height=12), spp=64,
                      progress=False, stats=st)
    assert st["config"]["light_tracing"] is False and "pilot" not in st["config"]
