"""Adaptive sampling (pathtracer/adaptive.py): per-pixel pass counts that merge like the sums, error estimates
with per-pixel counts, stops that keep dark and noisy regions going, determinism and bit-identical resumes."""

from __future__ import annotations

import dataclasses
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import pathtracer
from pathtracer import jobs
from pathtracer.adaptive import Adaptive, dilate_max, limits_from_counts
from pathtracer.errors import RenderError
from pathtracer.film import PassSum
from pathtracer.imageio import read_image, read_layers
from test_cli import _env

ROOT = Path(__file__).resolve().parents[1]
SCENES = ROOT / "scenes"
REFS = ROOT / "tests" / "data" / "refs"


def small(name: str, w: int = 32, h: int = 24):
    return pathtracer.load_file(str(SCENES / f"{name}.xml"), width=w, height=h)


def sums_of(scene, spp: int, sampler: str) -> PassSum:
    r = pathtracer.Renderer(scene, sampler=sampler)
    try:
        return r.render_passes(seed=1, count=spp)
    finally:
        r.close()


@pytest.mark.parametrize("sampler", ["independent", "sobol"])
def test_equal_per_pixel_counts_give_the_uniform_estimates(sampler):
    s = sums_of(small("cornell_box"), 24, sampler)
    c = dataclasses.replace(s, counts=np.full(s.sum.shape[:2], s.passes, dtype=np.int64))
    assert np.array_equal(c.mean, s.mean)
    np.testing.assert_allclose(c.variance_of_mean, s.variance_of_mean, rtol=1e-12)
    assert c.relmse_estimate == pytest.approx(s.relmse_estimate, rel=1e-12)


def test_counts_merge_by_addition_like_the_sums():
    s = sums_of(small("cornell_box"), 8, "independent")
    a = dataclasses.replace(s, counts=np.full(s.sum.shape[:2], 8, dtype=np.int64))
    total = a + s  # a uniform PassSum counts its passes in every pixel
    assert np.array_equal(total.counts, np.full(s.sum.shape[:2], 16))
    assert np.array_equal(total.mean, (s + s).mean)


def test_a_pixel_with_fewer_passes_is_averaged_over_its_own():
    s = sums_of(small("cornell_box"), 8, "independent")
    counts = np.full(s.sum.shape[:2], 8, dtype=np.int64)
    counts[3, 4] = 2  # (only the mean's division is checked here: its sums are the 8-pass ones)
    c = dataclasses.replace(s, counts=counts)
    np.testing.assert_allclose(c.mean[3, 4], (s.sum[3, 4] / 2).astype(np.float32))
    assert np.isfinite(c.variance_of_mean).all()


def test_decisions_start_at_the_floor_and_keep_a_lucky_pixel_among_noisy_ones_going():
    plan = Adaptive(1e-3, min_passes=64, every=32)
    assert [p for p in range(200) if plan.is_decision(p)] == [64, 96, 128, 160, 192]
    assert plan.next_decision(0) == 64 and plan.next_decision(64) == 96 and plan.next_decision(70) == 96
    err = np.full((5, 5), 1e-6)
    err[2, 2] = 1.0  # one noisy pixel: its eight neighbours' own errors are tiny, yet they keep going
    d = dilate_max(err)
    assert (d[1:4, 1:4] == 1.0).all() and d[0, 0] == 1e-6
    counts = np.array([[64, 100], [100, 100]])
    assert limits_from_counts(counts, 100).tolist() == [[64, 2**32 - 1], [2**32 - 1, 2**32 - 1]]
    with pytest.raises(RenderError, match="threshold must be > 0"):
        Adaptive(0.0)


def test_adaptive_render_is_deterministic_and_resumes_bit_identically(tmp_path):
    scene = small("cornell_box_mirror")
    st: dict = {}
    a = pathtracer.render(scene, spp=320, seed=4, progress=False, adaptive=1e-3, threads=1, stats=st)
    assert 0 < st["adaptive"]["stopped_fraction"] < 1 and st["adaptive"]["min_spp"] == 64
    assert st["samples"] < 320 * scene.width * scene.height
    b = pathtracer.render(scene, spp=320, seed=4, progress=False, adaptive=1e-3, threads=2)
    assert np.array_equal(a, b)
    ck = tmp_path / "ck.npz"
    flag = jobs.StopFlag()
    calls = []

    def preview(img):
        calls.append(1)
        if len(calls) == 4:
            flag.set()

    part: dict = {}
    pathtracer.render(scene, spp=320, seed=4, progress=False, adaptive=1e-3, checkpoint=ck, preview=preview,
                      preview_every=1e-9, stop=flag, stats=part)
    assert part["stop_reason"] == "interrupted" and part["spp"] < 320
    resumed = pathtracer.render(scene, spp=320, seed=4, progress=False, adaptive=1e-3, checkpoint=ck, resume=True)
    assert np.array_equal(resumed, a)
    with pytest.raises(jobs.CheckpointError, match="adaptive"):  # a uniform render cannot continue it
        pathtracer.render(scene, spp=320, seed=4, progress=False, checkpoint=ck, resume=True)


@pytest.mark.parametrize("name", ["cornell_box_mirror", "open_sky"])
def test_stopped_pixels_really_are_below_the_threshold_against_mitsuba(name):
    """The known failure: dark pixels (the caustic under the mirror sphere, the ground far from the light) whose few
    samples all missed stop at once. Measured against the converged references: with the floor of 64 passes and
    the 3x3 neighbourhood the stopped pixels' true relMSE is 0.2-0.5 of the threshold; without them (8 passes,
    each pixel alone) it was 4.9x and 17.8x the threshold, and the image's estimate 8x and 51x too low."""
    ref, var = read_image(REFS / f"{name}.exr"), read_image(REFS / f"{name}_var.exr")
    scene = pathtracer.load_file(str(SCENES / f"{name}.xml"), width=ref.shape[1], height=ref.shape[0])
    st: dict = {}
    layers: dict = {}
    threshold = 1e-3
    img = pathtracer.render(scene, spp=2048, seed=0, progress=False, adaptive=threshold, stats=st, layers=layers)
    err = np.mean(((img - ref) ** 2 - var) / (ref.astype(np.float64) ** 2 + 0.01), axis=-1)
    stopped = layers["spp"] < st["spp"]
    assert stopped.mean() > 0.3
    assert err[stopped].mean() < threshold, err[stopped].mean() / threshold
    assert err.mean() / st["relmse_estimate"] < 1.5  # the estimate with per-pixel counts stays honest


def test_adaptive_refuses_what_it_cannot_do():
    scene = small("cornell_box_mirror")
    with pytest.raises(RenderError, match="light tracing"):
        pathtracer.render(scene, spp=8, progress=False, adaptive=True, light_tracing=True)
    with pytest.raises(RenderError, match="callback"):
        pathtracer.render(scene, spp=8, progress=False, adaptive=True, callback=lambda i, s: None)
    st: dict = {}
    pathtracer.render(scene, spp=8, progress=False, adaptive=True, stats=st)  # auto: light tracing stays off
    assert st["config"]["light_tracing"] is False and st["adaptive"]["threshold"] == 1e-4


def test_cli_adaptive_writes_the_per_pixel_counts(tmp_path):
    out = tmp_path / "a.exr"
    r = subprocess.run([sys.executable, "-m", "pathtracer", str(SCENES / "cornell_box.xml"), "-o", str(out),
                        "--spp", "256", "--adaptive", "1e-3", "-D", "width=32", "-D", "height=24", "--no-progress"],
                       cwd=ROOT, env=_env(), capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    layers = read_layers(out)
    spp = layers["spp"]
    assert spp.min() == 64 and spp.max() == 256
    assert "stderr" in layers or "stderr.R" in layers
    bad = subprocess.run([sys.executable, "-m", "pathtracer", str(SCENES / "cornell_box.xml"), "-o", str(out),
                          "--adaptive", "-1"], cwd=ROOT, env=_env(), capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and bad.stderr.strip() == "pathtracer: error: --adaptive must be > 0, got -1.0"


def test_pass_limits_are_compiled_only_into_adaptive_renders():
    from test_render_driver import generated_source

    scene = small("cornell_box", 8, 8)
    plain, adaptive = pathtracer.Renderer(scene), pathtracer.Renderer(scene, adaptive=True)
    load = "wp::address(var_pass_limit,"
    assert load not in generated_source(plain.kernel)  # (the argument is there, never read)
    assert load in generated_source(adaptive.kernel)
    assert plain.kernel is not adaptive.kernel
