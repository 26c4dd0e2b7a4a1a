"""The pass-based driver (pathtracer/render.py): determinism, merging of PassSums, callbacks, stats, option checks,
and the compile-time specialisation of the integrator kernel."""

from __future__ import annotations

import glob
import os
import re

import numpy as np
import pytest
import warp as wp

import pathtracer
from helpers import add_sphere, make_scene, material, square
from kernels.integrator import RR_THROUGHPUT, SAMPLER_SOBOL, VIEW_RADIANCE, Features
from pathtracer.device_scene import DeviceScene
from pathtracer.errors import RenderError
from pathtracer.render import PassSum, Renderer

U32 = 2.0**-24  # unit roundoff of float32


def box_scene(width=24, height=16, spheres=False):
    """A small Cornell-like box: five walls, a ceiling light (lowered 1e-3 below the ceiling), no spheres unless
    asked: it shares its compiled variant (meshes + lights) with the analytic tests."""
    scene = make_scene((0, 0, 7), (0, 0, 4), 45, width, height, fov_axis="y", max_depth=4)
    white = material(scene, "diffuse", (0.725, 0.71, 0.68))
    red = material(scene, "diffuse", (0.63, 0.065, 0.05))
    green = material(scene, "diffuse", (0.14, 0.45, 0.091))
    black = material(scene, "diffuse", 0.0)
    for c, n, m in [((0, -2, 0), (0, 1, 0), white), ((0, 2, 0), (0, -1, 0), white), ((-2, 0, 0), (1, 0, 0), red),
                    ((2, 0, 0), (-1, 0, 0), green), ((0, 0, -2), (0, 0, 1), white)]:
        square(scene, c, 4.0, n, m)
    square(scene, (0, 1.999, 0), 1.0, (0, -1, 0), black, radiance=30.0)
    if spheres:
        # a mirror sphere: the same variant (meshes + spheres + mirrors + lights) as the analytic tests use
        add_sphere(scene, (0.75, -1.4, 0.55), 0.6, material(scene, "mirror", 0.89))
    return scene


def render(scene, **kw):
    kw.setdefault("progress", False)
    return pathtracer.render(scene, **kw)


# ------------------------------------------------------------------------------------------------
# determinism


def test_same_inputs_bit_identical_and_finite(device):
    scene = box_scene()
    st = {}
    a = render(scene, spp=4, seed=7, device=device, stats=st)
    b = render(scene, spp=4, seed=7, device=device)
    assert a.dtype == np.float32 and a.shape == (16, 24, 3)
    assert np.array_equal(a, b)
    assert np.isfinite(a).all() and st["discarded"] == 0
    assert a.mean() > 0.05  # not a black image


def test_thread_count_does_not_change_the_image():
    scene = box_scene()
    imgs = [render(scene, spp=3, seed=2, device="cpu", threads=t) for t in (1, 2, 3, 16)]
    for img in imgs[1:]:
        assert np.array_equal(imgs[0], img)


def test_sums_do_not_depend_on_threads_tiles_or_passes_per_launch():
    """37 passes: several launches of up to 16 passes with a short last one, 1 to 8 tiles, and one pass per launch
    with a callback: every pixel must add the same float64 samples in the same order (bit-identical sums)."""
    scene = box_scene()
    runs = []
    for threads in (1, 2, 5):
        r = pathtracer.Renderer(scene, device="cpu", threads=threads)
        runs.append(r.render_passes(seed=4, first_pass=3, count=37))
        runs.append(r.render_passes(seed=4, first_pass=3, count=37, callback=lambda i, s: True))
        r.close()
    for other in runs[1:]:
        assert other.passes == 37
        assert np.array_equal(runs[0].sum, other.sum) and np.array_equal(runs[0].sum_sq, other.sum_sq)
        assert np.array_equal(runs[0].rep_sum, other.rep_sum) and np.array_equal(runs[0].rep_passes, other.rep_passes)
    # passes 3..39 into the default 2 replicates by pass mod 2: 18 even, 19 odd
    assert runs[0].rep_passes.tolist() == [18, 19]


def test_work_scheduler_runs_each_tile_in_order_and_balances():
    """The free-running scheduler: every (chunk, tile) exactly once, a tile's chunks in order and never two at once,
    and a thread that is slowed down takes fewer items (the other takes up the slack)."""
    import threading
    import time

    scene = box_scene()
    r = pathtracer.Renderer(scene, device="cpu", threads=2)
    chunks = [(p, 2) for p in range(0, 20, 2)]
    tiles = 6
    lock = threading.Lock()
    log = []  # (tile, first, thread, start, end)
    running = set()
    slow = []

    def fake_launch(tile, first, n):
        me = threading.get_ident()
        with lock:
            assert tile not in running, "a tile rendered by two threads at once"
            running.add(tile)
            if not slow:
                slow.append(me)  # the first thread to start is the slow one
        t = time.perf_counter()
        time.sleep(0.004 if me == slow[0] else 0.001)
        with lock:
            running.discard(tile)
            log.append((tile, first, me, t, time.perf_counter()))

    class Bar:  # the progress bar gets the passes every tile has finished, in increasing steps
        def __init__(self):
            self.steps = []

        def update(self, n):
            assert n > 0
            self.steps.append(n)

    bar = Bar()
    done = r._run_free(r._worker_pool(), fake_launch, None, chunks, tiles, bar)
    r.close()
    assert done == 20 and sum(bar.steps) == 20 and all(step % 2 == 0 for step in bar.steps)
    assert sorted((t, f) for t, f, *_ in log) == sorted((t, f) for t in range(tiles) for f, _ in chunks)
    for t in range(tiles):
        starts = [(start, f) for tt, f, _, start, _ in log if tt == t]
        assert [f for _, f in sorted(starts)] == [f for f, _ in chunks]
    counts = {}
    for _, _, me, _, _ in log:
        counts[me] = counts.get(me, 0) + 1
    assert len(counts) == 2 and counts[slow[0]] < counts[next(k for k in counts if k != slow[0])] / 2


@pytest.mark.parametrize("with_lt", [False, True])
def test_run_free_stops_on_whole_chunks(with_lt):
    """A stop set while the tiles run: no chunk is started after it but every chunk some tile (or the light
    tracer) had started is finished on every tile, and the count returned is exactly those chunks' passes."""
    import threading
    import time

    class Flag:
        def __init__(self):
            self.event = threading.Event()

        def is_set(self):
            return self.event.is_set()

    for stop_after in (1, 7, 12, 40):  # launches before the stop is set (chunks of 6: in one, at an end)
        r = pathtracer.Renderer(box_scene(), device="cpu", threads=2)
        chunks = [(p, 1) for p in range(10)]
        tiles = 6
        lock = threading.Lock()
        log, lt_log = [], []
        flag = Flag()

        def fake_launch(tile, first, n):
            time.sleep(0.001)
            with lock:
                log.append((tile, first))
                if len(log) == stop_after:
                    flag.event.set()

        def fake_lt(first, n):  # slower than a chunk of tiles (3 ms): the path tiles run ahead of it
            time.sleep(0.004)
            with lock:
                lt_log.append(first)

        from concurrent.futures import ThreadPoolExecutor

        with ThreadPoolExecutor(3) as pool:  # two path workers and the light tracer's
            done = r._run_free(pool, fake_launch, fake_lt if with_lt else None, chunks, tiles, None, flag)
        r.close()
        assert 1 <= done < 10, (stop_after, done)
        assert sorted(log) == sorted((t, f) for t in range(tiles) for f in range(done)), (stop_after, done)
        if with_lt:
            assert lt_log == list(range(done))


@pytest.mark.parametrize("threads", [1, 2])
def test_stopped_render_holds_whole_passes(threads):
    """render_into with a stop that is set during the render: the film holds a whole number of passes, and they
    equal the same passes rendered without a stop (every tile stopped at the same pass); one thread (the launch
    loop) or two (the free-running scheduler)."""
    import threading

    scene = box_scene()
    r = Renderer(scene, device="cpu", threads=threads)

    class After:  # set once the first call to is_set after `n` calls
        def __init__(self, n):
            self.calls, self.n, self.lock = 0, n, threading.Lock()

        def is_set(self):
            with self.lock:
                self.calls += 1
                return self.calls > self.n

    film = r.new_film()
    done = r.render_into(film, 3, 0, 64, stop=After(2))  # (one thread looks once a launch of 16 passes)
    assert 1 <= done < 64 and film.passes == done and film.next_pass == done
    whole = r.render_passes(seed=3, first_pass=0, count=done)
    r.close()
    np.testing.assert_array_equal(film.sums().sum, whole.sum)


def test_different_seeds_differ(device):
    scene = box_scene()
    a = render(scene, spp=2, seed=0, device=device)
    b = render(scene, spp=2, seed=1, device=device)
    assert (a != b).any(axis=2).mean() > 0.5
    # and different pass ranges of one seed differ too
    r = Renderer(scene, device=device)
    assert (r.render_passes(seed=0, first_pass=0, count=1).sum != r.render_passes(seed=0, first_pass=1, count=1).sum).any()


def test_cpu_and_cuda_agree_statistically():
    """CPU and GPU draw the same random numbers: per-seed image means agree under a Welch test, and most pixels
    agree to float rounding (a few paths may diverge on rounding differences)."""
    if not wp.is_cuda_available():
        pytest.skip("needs a CUDA device")
    scene = box_scene()
    cpu = [render(scene, spp=4, seed=s, device="cpu") for s in range(16)]
    gpu = [render(scene, spp=4, seed=s, device="cuda:0") for s in range(16)]
    mc, mg = np.array([i.mean() for i in cpu]), np.array([i.mean() for i in gpu])
    z = (mc.mean() - mg.mean()) / np.sqrt(mc.var(ddof=1) / 16 + mg.var(ddof=1) / 16 + 1e-30)
    assert abs(z) <= 4
    rel = np.abs(cpu[0] - gpu[0]) / np.maximum(np.abs(cpu[0]), 1e-3)
    assert np.median(rel) < 1e-3


# ------------------------------------------------------------------------------------------------
# PassSum merging


def test_passsum_merging(device):
    """Passes 0..3 + passes 4..7 == passes 0..7.

    The device accumulates each call's passes in float32, one pixel at a time in pass order, so:
    - the first 4 passes of the 8-pass call are bit-identical to the 4-pass call (seen through the callback);
    - the merged sum equals the one-call sum only up to float32 rounding (the one call rounds the running sum of 8
      terms, the merge rounds two 4-term sums then adds them in float64): |difference| <= ~14 u sum.
    """
    scene = box_scene()
    r = Renderer(scene, device=device)
    first = r.render_passes(seed=11, first_pass=0, count=4)
    second = r.render_passes(seed=11, first_pass=4, count=4)
    snapshots = {}
    whole = r.render_passes(seed=11, first_pass=0, count=8,
                            callback=lambda i, s: snapshots.__setitem__(i, (s.sum.copy(), s.sum_sq.copy())))
    merged = first + second
    assert isinstance(merged, PassSum) and merged.passes == whole.passes == 8
    assert merged.discarded == whole.discarded == 0
    assert sorted(snapshots) == list(range(8))
    assert np.array_equal(snapshots[3][0], first.sum) and np.array_equal(snapshots[3][1], first.sum_sq)
    for m, w in ((merged.sum, whole.sum), (merged.sum_sq, whole.sum_sq)):
        assert (np.abs(m - w) <= 14 * U32 * np.abs(w) + 1e-30).all()
    assert np.abs(merged.mean - whole.mean).max() <= 14 * U32 * np.abs(whole.mean).max()
    assert (np.abs(merged.rep_sum - whole.rep_sum) <= 14 * U32 * np.abs(whole.rep_sum) + 1e-30).all()
    assert merged.rep_passes.tolist() == whole.rep_passes.tolist() == [4, 4]  # 8 passes, 2 replicates
    assert merged.estimator == whole.estimator == "replicates"  # the default sampler is Sobol'
    # the variance estimate of the merged sums is finite and equals the one-call one to rounding
    assert np.isfinite(whole.variance_of_mean).all()
    assert np.allclose(merged.variance_of_mean, whole.variance_of_mean, rtol=1e-3, atol=1e-9)
    # sums of different samplers or replicate counts do not merge
    with pytest.raises(ValueError, match="samplers"):
        first + Renderer(scene, device=device, sampler="independent").render_passes(seed=11, first_pass=4, count=4)
    with pytest.raises(ValueError, match="replicates"):
        first + Renderer(scene, device=device, replicates=4).render_passes(seed=11, first_pass=4, count=4)
    # a 1-pass sum has no variance estimate
    assert np.isinf(r.render_passes(seed=11, count=1).variance_of_mean).all()


def _seed_spread(scene, sampler, seeds=32, spp=32, replicates=4):
    """Per pixel and channel: the mean over seeds of the estimated variance of the mean, the variance of the mean
    across seeds (the truth it estimates), and the per-pass estimate."""
    r = Renderer(scene, device="cpu", sampler=sampler, replicates=replicates)
    runs = [r.render_passes(seed=s, count=spp) for s in range(seeds)]
    means = np.stack([x.mean.astype(np.float64) for x in runs])
    est = np.stack([x.variance_of_mean for x in runs])
    per_pass = np.stack([PassSum._var_of_mean(x.sum, x.sum_sq, x.passes) for x in runs])
    return est.mean(axis=0), means.var(axis=0, ddof=1), per_pass.mean(axis=0)


def _z_ratio(est, truth):
    """z of mean(est - truth) over pixel channels, with its standard error from their spread."""
    d = (est - truth).ravel()
    return d.mean() / (d.std(ddof=1) / np.sqrt(d.size)), est.mean() / truth.mean()


@pytest.mark.parametrize("replicates", [2, 4])
def test_replicate_variance_estimate_is_unbiased_with_sobol(replicates):
    """With the default Sobol' sampler the variance of a pixel's mean, estimated from its replicates (2, the
    default, or 4 as an adaptive render has), agrees on
    average with the actual spread of the mean over 32 seeds (z of the mean difference over the pixel channels, with
    its standard error from their own spread, within 4). Control: the spread of the stratified passes themselves
    over-estimates it (the estimate the replicates replace)."""
    scene = box_scene(32, 24)
    est, truth, per_pass = _seed_spread(scene, "sobol", replicates=replicates)
    z, ratio = _z_ratio(est, truth)
    z_pass, ratio_pass = _z_ratio(per_pass, truth)
    print(f"\n[replicates] estimate / truth {ratio:.3f} (z {z:+.2f}); per-pass estimate / truth {ratio_pass:.3f} "
          f"(z {z_pass:+.2f})")
    assert abs(z) <= 4.0
    assert z_pass > 4.0


def test_replicate_variance_estimate_is_unbiased_with_independent_sampling():
    """The same with independent sampling, where the per-pass estimate (the one used there) is exact too."""
    scene = box_scene(24, 16)
    est, truth, per_pass = _seed_spread(scene, "independent")
    assert abs(_z_ratio(est, truth)[0]) <= 4.0
    assert abs(_z_ratio(per_pass, truth)[0]) <= 4.0


def test_callback_and_early_stop(device):
    scene = box_scene()
    calls = []
    render(scene, spp=5, seed=1, device=device, callback=lambda i, s: calls.append((i, s.passes)))
    assert calls == [(i, i + 1) for i in range(5)]
    # returning False stops after that pass; nothing done is lost
    r = Renderer(scene, device=device)
    stopped = r.render_passes(seed=1, count=10, callback=lambda i, s: i < 2)
    assert stopped.passes == 3
    assert np.array_equal(stopped.sum, r.render_passes(seed=1, count=3).sum)


def test_stats_are_filled(device):
    scene = box_scene()
    st = {}
    render(scene, spp=3, seed=0, device=device, stats=st, threads=2)
    assert st["spp"] == 3 and st["samples"] == 3 * 24 * 16
    assert st["discarded"] == 0
    assert st["device"] == device
    assert st["threads"] == (2 if device == "cpu" else 1)
    assert st["seconds"] > 0 and st["compile_seconds"] >= 0


# ------------------------------------------------------------------------------------------------
# option checks


BAD_OPTIONS = [
    {"spp": 0},
    {"spp": -3},
    {"spp": 1.5},
    {"device": "tpu"},
    {"view": "x"},
    {"rr": "x"},
    {"max_depth": 0},
    {"max_depth": -2},
    {"seed": -1},
    {"seed": 2**32},
    {"threads": 0},
    {"light_samples": 0},
    {"replicates": 0},
    {"replicates": 2.0},
]


@pytest.mark.parametrize("opts", BAD_OPTIONS, ids=lambda o: "-".join(f"{k}={v}" for k, v in o.items()))
def test_bad_options_raise_render_error(opts):
    opts = {"spp": 1, "device": "cpu", **opts}
    with pytest.raises(RenderError):
        render(box_scene(8, 8), **opts)


def test_cuda_without_a_gpu_is_a_render_error():
    if wp.is_cuda_available():
        pytest.skip("a CUDA device is present")
    with pytest.raises(RenderError):
        render(box_scene(8, 8), spp=1, device="cuda")


def test_extreme_but_valid_options(device):
    scene = box_scene(8, 8)
    for opts in ({"seed": 2**32 - 1}, {"max_depth": 1}, {"max_depth": -1, "rr": "seed"}, {"rr": "none"},
                 {"light_samples": 3}):
        img = render(scene, spp=1, device=device, **opts)
        assert np.isfinite(img).all(), opts


# ------------------------------------------------------------------------------------------------
# specialisation: a sphere-free scene gets a kernel without sphere code


SPHERE_CODE = ("ray_sphere", "sphere_hit", "occluded_spheres", "self_mode", "(var_scene).sphere_",
               "(var_scene).num_spheres")


def generated_source(kernel) -> str:
    """Warp's generated C++ for the (loaded) module of ``kernel``: the .cpp Warp keeps in its kernel cache, or, if
    that is gone, the module's code generator run again."""
    module = kernel.module
    paths = glob.glob(os.path.join(wp.config.kernel_cache_dir, f"wp_{module.name}_*", "*.cpp"))
    if paths:
        with open(paths[0]) as f:
            return f.read()
    from warp._src.context import ModuleBuilder  # private API: only a fallback

    return ModuleBuilder(module, module.options | {"output_arch": None}, target="cpu").codegen("cpu")


def test_sphere_free_scene_gets_a_kernel_without_sphere_code():
    scene = box_scene(8, 8)
    f = DeviceScene.features(scene, sampler="sobol")
    assert f == Features(meshes=True, spheres=False, mirrors=False, smooth_normals=False, lights=True,
                         view=VIEW_RADIANCE, rr=RR_THROUGHPUT, sampler=SAMPLER_SOBOL)
    r = Renderer(scene, device="cpu")  # the default sampler: Sobol'
    assert r.features == f
    src = generated_source(r.kernel)
    assert "render_pass" in src
    found = [s for s in SPHERE_CODE if s in src]
    assert not found, f"sphere code in a sphere-free variant: {found}"
    # control: the variant with spheres does contain it
    rs = Renderer(box_scene(8, 8, spheres=True), device="cpu")
    assert rs.features.spheres and rs.kernel is not r.kernel
    src_s = generated_source(rs.kernel)
    assert all(s in src_s for s in SPHERE_CODE)
    # and the variant without spheres is smaller
    assert len(re.findall(r"\bvar_\d+\b", src)) < len(re.findall(r"\bvar_\d+\b", src_s))


QUAD_CODE = ("ray_quad", "quad_hit", "occluded_quads", "(var_scene).quad_", "(var_scene).num_quads",
             "(var_scene).light_quad")
MESH_CODE = ("mesh_closest", "mesh_occluded", "mesh_hit", "(var_scene).bvh", "(var_scene).indices")


def test_quads_only_where_the_scene_has_them_and_no_bvh_code_without_triangles():
    # the helpers' rectangles are plain triangle meshes: no quad code
    r = Renderer(box_scene(8, 8), device="cpu")
    assert r.features.meshes and not r.features.quads
    src = generated_source(r.kernel)
    assert all(s in src for s in MESH_CODE)
    found = [s for s in QUAD_CODE if s in src]
    assert not found, f"quad code in a quad-free variant: {found}"
    # the Cornell box file: rectangles, a cube and a sphere, all analytic: quad code and no BVH code at all
    scene = pathtracer.load_file(os.path.join(os.path.dirname(__file__), "..", "scenes", "cornell_box.xml"),
                                 width=8, height=8)
    rq = Renderer(scene, device="cpu")
    assert rq.features.quads and not rq.features.meshes and rq.features.spheres
    src_q = generated_source(rq.kernel)
    assert all(s in src_q for s in QUAD_CODE)
    found = [s for s in MESH_CODE if s in src_q]
    assert not found, f"BVH code in a variant without triangles: {found}"


WIDE_CODE = ("wide_entry", "leaf_closest", "(var_scene).bvh_boxes", "(var_scene).tri_soa")
WARP_CODE = ("mesh_query_ray", "(var_scene).mesh_id")


def test_triangle_backend_compiles_only_its_own_traversal():
    """triangles="wide" (default) carries our 4-wide tree and no wp.Mesh query; "warp" the reverse."""
    scene = box_scene(8, 8)
    wide, warp = Renderer(scene, device="cpu"), Renderer(scene, device="cpu", triangles="warp")
    assert wide.triangles == "wide" and wide.features != warp.features
    src_wide, src_warp = generated_source(wide.kernel), generated_source(warp.kernel)
    assert all(s in src_wide for s in WIDE_CODE) and not any(s in src_wide for s in WARP_CODE)
    assert all(s in src_warp for s in WARP_CODE) and not any(s in src_warp for s in WIDE_CODE)
    # and the two render the same scene alike (same random numbers; only a vertex-aimed ray could differ)
    a = wide.render_passes(seed=3, count=4).mean
    b = warp.render_passes(seed=3, count=4).mean
    assert np.mean(np.abs(a - b) > 1e-4) < 1e-3
    with pytest.raises(pathtracer.RenderError, match="triangle backend"):
        Renderer(scene, device="cpu", triangles="embree")



def test_no_ray_is_traced_to_a_last_vertex_that_cannot_count():
    """After a diffuse bounce the next vertex's emission never counts (next-event estimation took it), so where
    that vertex would be the last, its ray is neither sampled nor traced. In the diffuse box (one light, one light
    sample) a path of max_depth m is then at most m - 1 nearest-hit rays and m - 1 shadow rays: at max_depth 2 a
    camera ray and a shadow ray (before, the bounce ray too: 2.23 rays per sample on the Cornell box)."""
    scene = box_scene()
    n = 4 * scene.width * scene.height
    for max_depth, bound in ((1, 1), (2, 2), (3, 4)):
        ps = Renderer(scene, device="cpu", count_rays=True, max_depth=max_depth).render_passes(seed=1, count=4)
        assert n <= ps.rays <= bound * n, (max_depth, ps.rays / n)

# ------------------------------------------------------------------------------------------------
# non-finite samples


def _infinite_light_scene(width, height):
    """Every camera ray sees a light of infinite radiance: every sample is non-finite and must be discarded."""
    from helpers import add_rect

    scene = make_scene((0, 0, 0), (0, 0, -1), 20, width, height)
    add_rect(scene, (0, 0, -2), (2, 0, 0), (0, 2, 0), (0, 0, 1), material(scene, "diffuse", 0.0),
             radiance=(np.inf, 1.0, 1.0))
    return scene


def test_non_finite_samples_are_discarded_and_counted(device):
    scene = _infinite_light_scene(16, 16)
    st = {}
    with pytest.warns(RuntimeWarning, match="non-finite"):
        img = render(scene, spp=3, max_depth=1, device=device, stats=st, threads=1)
    assert np.isfinite(img).all() and (img == 0).all()
    assert st["discarded"] == 3 * 16 * 16


def test_discarded_count_is_exact_with_worker_threads():
    """Regression: worker threads once shared one counter, and Warp's CPU atomic_add is a plain +=."""
    W = H = 512
    scene = _infinite_light_scene(W, H)
    st = {}
    with pytest.warns(RuntimeWarning, match="non-finite"):
        render(scene, spp=8, max_depth=1, device="cpu", stats=st, threads=2)
    assert st["discarded"] == 8 * W * H
