"""The driver: a render is a sum of independent, seeded sample passes.

Pass ``i`` of seed ``s`` adds one sample to every pixel, drawn from random numbers keyed by (pixel, i, s), so any
set of passes can be rendered anywhere (another thread, process or machine) and merged by adding ``PassSum``s.
On the CPU, worker threads (``wp.launch`` releases the GIL) take (tile, run of passes) items on demand, a tile being
a set of interleaved rows; a tile's runs are rendered in order, one at a time, so every pixel sums its passes in pass
order and the image is bit-identical whatever the thread count.
"""

from __future__ import annotations

import dataclasses
import itertools
import os
import threading
import time
import warnings
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import warp as wp

from kernels.integrator import LIGHT_SAMPLINGS, RR_RULES, SAMPLERS, TRIANGLES, VIEWS, render_kernel
from kernels.light_tracer import fold_pass, light_kernel
from kernels.types import PassParams
from pathtracer.device_scene import DeviceScene
from pathtracer.diagnostics import roulette_variance_warning
from pathtracer.errors import RenderError
from pathtracer.scene import Scene
from pathtracer.warp_setup import init_warp

DEFAULT_LIGHT_SAMPLES = 1
DEFAULT_RR = "throughput"
DEFAULT_SAMPLER = "sobol"  # 1.1-3.2x more efficient than independent on every seed scene (docs/performance.md)
DEFAULT_REPLICATES = 4  # independent Sobol' scrambles a render is split into, for its error estimate
DEFAULT_LIGHT_SAMPLING = "area"
DEFAULT_LIGHT_TRACING = False
DEFAULT_TRIANGLES = "wide"  # watertight, and faster than "warp" on the CPU (examples/bench_rays.py)
UINT32_LIMIT = 2**32
TILES_PER_THREAD = 4  # row sets per CPU thread, taken on demand (load balancing)
LAUNCH_SAMPLES = 1 << 15  # samples one launch aims at (~10-20 ms on a CPU core), by grouping passes
MAX_PASSES_PER_LAUNCH = 16


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

    def __add__(self, other: "PassSum") -> "PassSum":
        def add(a, b):
            return b if a is None else a if b is None else a + b

        if self.estimator != other.estimator:
            raise ValueError(f"cannot merge sums of different samplers ({self.estimator} and {other.estimator})")
        if self.rep_sum is not None and other.rep_sum is not None and len(self.rep_sum) != len(other.rep_sum):
            raise ValueError(f"cannot merge sums of {len(self.rep_sum)} and {len(other.rep_sum)} replicates")
        return PassSum(self.sum + other.sum, self.sum_sq + other.sum_sq, self.passes + other.passes,
                       self.discarded + other.discarded, self.seconds + other.seconds, self.rays + other.rays,
                       add(self.lt_sum, other.lt_sum), add(self.lt_sum_sq, other.lt_sum_sq),
                       add(self.rep_sum, other.rep_sum), add(self.rep_passes, other.rep_passes), self.estimator,
                       add(self.m2_sum, other.m2_sum))

    @property
    def mean(self) -> np.ndarray:
        """Linear radiance, float32 (H, W, 3)."""
        total = self.sum if self.lt_sum is None else self.sum + self.lt_sum
        return (total / max(self.passes, 1)).astype(np.float32)

    def layers(self, names: tuple[str, ...]) -> dict[str, np.ndarray]:
        """Mitsuba's moment layers, float32 (H, W, 3) each: ``names[0]`` the mean XYZ of the samples, ``names[1]``
        the mean of their squares (``Integrator.layer_names``); empty when none were summed."""
        if self.m2_sum is None or not names:
            return {}
        n = max(self.passes, 1)
        xyz = (self.sum / n) @ SRGB_TO_XYZ.T
        return {names[0]: xyz.astype(np.float32), names[1]: (self.m2_sum / n).astype(np.float32)}

    @staticmethod
    def _var_of_mean(total: np.ndarray, total_sq: np.ndarray, n: int) -> np.ndarray:
        m = total / n
        return np.maximum(total_sq / n - m * m, 0.0) * n / (n - 1) / n

    def _replicate_var_of_mean(self) -> np.ndarray:
        """sum_r n_r (m_r - m)^2 / (R' - 1) / N over the R' non-empty replicates: the spread of the replicate
        means, each weighted by its pass count (exactly the variance of the mean of R equal replicates)."""
        n = np.asarray(self.rep_passes, dtype=np.float64)
        used = n > 0
        if used.sum() < 2:
            return np.full_like(self.sum, np.inf)
        reps = self.rep_sum[used]
        n = n[used]
        m = self.sum / self.passes
        dev = reps / n[:, None, None, None] - m
        return np.einsum("r,rhwc->hwc", n, dev * dev) / (len(n) - 1) / self.passes

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
            var = self._var_of_mean(self.sum, self.sum_sq, n)
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
        var = self.variance_of_mean
        return float(np.mean(var / (box3(self.mean.astype(np.float64)) ** 2 + 0.01)))


def box3(img: np.ndarray) -> np.ndarray:
    """(H, W, C) image averaged over each pixel's 3x3 neighbourhood (edges repeated)."""
    h, w = img.shape[:2]
    p = np.pad(img, ((1, 1), (1, 1), (0, 0)), mode="edge")
    return sum(p[dy:dy + h, dx:dx + w] for dy in range(3) for dx in range(3)) / 9.0


def resolve_device(device: str | None) -> str:
    """``None`` -> CUDA when present, else CPU; anything unknown is a RenderError."""
    init_warp()
    if device is None:
        return "cuda:0" if wp.is_cuda_available() else "cpu"
    name = str(device)
    if name == "cpu":
        return "cpu"
    if name == "cuda" or name.startswith("cuda:"):
        if not wp.is_cuda_available():
            raise RenderError(f"device {name!r}: no CUDA device is available on this machine (use --device cpu)")
        dev = "cuda:0" if name == "cuda" else name
        try:
            wp.get_device(dev)
        except Exception as exc:  # Warp raises a plain RuntimeError for unknown ordinals
            raise RenderError(f"device {name!r}: {exc}") from None
        return dev
    raise RenderError(f"unknown device {name!r} (supported: cpu, cuda, cuda:N)")


def _check_int(name: str, value, low: int, high: int | None = None) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise RenderError(f"{name} must be an integer, got {value!r}")
    if value < low or (high is not None and value >= high):
        bound = f">= {low}" if high is None else f"in [{low}, {high})"
        raise RenderError(f"{name} must be {bound}, got {value}")
    return int(value)


@dataclass
class Renderer:
    """A scene uploaded to a device with one compiled integrator variant; renders passes on demand.

    max_depth, light_samples, rr, sampler: None means the scene file's value (max_depth) or the default
    (1 light sample per light, Mitsuba's throughput roulette from the scene's rr_depth, independent sampling:
    the most efficient choices measured in docs/performance.md, except Sobol, see below).
    sampler "sobol" draws Owen-scrambled Sobol' points indexed by pass at the first two path vertices (independent
    deeper): stratified across passes (best with a power-of-two pass count), so ``PassSum.variance_of_mean`` then
    overestimates the error.
    light_sampling "solid_angle" samples rectangular lights uniformly in the solid angle they subtend (Urena et al.
    2013) instead of uniformly in area ("area", default): far less variance near a light.
    count_rays compiles an instrumented variant that counts every ray traced (for benchmarks).
    light_tracing: caustics seen directly (light -> mirrors -> a diffuse surface -> camera) from light paths
    (kernels/light_tracer.py) instead of camera paths (default off; it applies only to scenes with mirrors and
    lights, and max_depth -1 or >= 3). Far less noise where the camera sees the surfaces the caustics fall on, far
    more where it sees only a sliver of them (a narrow view): light paths rarely land there.
    triangles: "wide" (default: our watertight 4-wide box tree, kernels/triangle.py) or "warp" (Warp's wp.Mesh and
    mesh_query_ray, kernels/triangle_warp.py: rays aimed exactly at a vertex can slip through it).
    """

    scene: Scene
    device: str | None = None
    max_depth: int | None = None
    light_samples: int | None = None
    rr: str | None = None
    view: str = "radiance"
    threads: int | None = None
    sampler: str | None = None
    count_rays: bool = False
    light_sampling: str | None = None
    light_tracing: bool | None = None
    triangles: str | None = None
    replicates: int | None = None
    compile_seconds: float = field(init=False, default=0.0)

    def __post_init__(self):
        self.device = resolve_device(self.device)
        if self.view not in VIEWS:
            raise RenderError(f"unknown view {self.view!r} (supported: {', '.join(VIEWS)})")
        rr = DEFAULT_RR if self.rr is None else self.rr
        if rr not in RR_RULES:
            raise RenderError(f"unknown roulette rule {rr!r} (supported: {', '.join(RR_RULES)})")
        self.rr = rr
        sampler = DEFAULT_SAMPLER if self.sampler is None else self.sampler
        if sampler not in SAMPLERS:
            raise RenderError(f"unknown sampler {sampler!r} (supported: {', '.join(SAMPLERS)})")
        self.sampler = sampler
        light_sampling = DEFAULT_LIGHT_SAMPLING if self.light_sampling is None else self.light_sampling
        if light_sampling not in LIGHT_SAMPLINGS:
            raise RenderError(f"unknown light sampling {light_sampling!r} (supported: {', '.join(LIGHT_SAMPLINGS)})")
        self.light_sampling = light_sampling
        triangles = DEFAULT_TRIANGLES if self.triangles is None else self.triangles
        if triangles not in TRIANGLES:
            raise RenderError(f"unknown triangle backend {triangles!r} (supported: {', '.join(TRIANGLES)})")
        self.triangles = triangles
        reps = DEFAULT_REPLICATES if self.replicates is None else self.replicates
        self.replicates = _check_int("replicates", reps, 1, 1025)
        depth = self.scene.integrator.max_depth if self.max_depth is None else self.max_depth
        self.max_depth = _check_int("max_depth", depth, -1)
        if self.max_depth == 0:
            raise RenderError("max_depth must be -1 (unlimited) or >= 1, got 0")
        k = self.light_samples
        if k is None:
            k = self.scene.integrator.light_samples or DEFAULT_LIGHT_SAMPLES
        self.light_samples = _check_int("light_samples", k, 1)
        cpu = self.device == "cpu"
        threads = (os.cpu_count() or 1) if self.threads is None else self.threads
        self.threads = _check_int("threads", threads, 1)
        if not cpu:
            self.threads = 1  # one launch already fills a GPU
        self.threads = min(self.threads, self.scene.height)

        self.features = DeviceScene.features(self.scene, self.view, self.rr, self.sampler, self.count_rays,
                                             self.light_sampling, self.triangles)
        # the light tracer starts on parallelogram lights only and splats each light path into the one pixel it
        # lands in (a box filter's film) through a pinhole; it knows diffuse surfaces and mirrors only
        possible = (not (self.features.pixel_filter or self.features.thin_lens or self.features.other_materials
                         or self.features.textures or self.features.moments)
                    and self.scene.only_rect_lights
                    and self.features.mirrors and self.features.lights and self.view == "radiance"
                    and (self.max_depth < 0 or self.max_depth >= 3))
        wanted = DEFAULT_LIGHT_TRACING if self.light_tracing is None else bool(self.light_tracing)
        self.light_tracing_possible = possible
        self.light_tracing = wanted and possible
        self.features = dataclasses.replace(self.features, light_tracing=self.light_tracing)
        self.kernel = render_kernel(self.features)
        self.light_kernel = light_kernel(self.features) if self.light_tracing else None
        t0 = time.perf_counter()
        wp.load_module(self.kernel.module, device=self.device)
        if self.light_kernel is not None:
            wp.load_module(self.light_kernel.module, device=self.device)
            wp.load_module(fold_pass.module, device=self.device)
        self.compile_seconds = time.perf_counter() - t0
        with wp.ScopedDevice(self.device):
            self.dscene = DeviceScene(self.scene, self.device, self.triangles)

    def render_passes(
        self,
        seed: int = 0,
        first_pass: int = 0,
        count: int = 1,
        progress: bool = False,
        callback: Callable[[int, "PassSum"], object] | None = None,
    ) -> PassSum:
        """Render passes ``first_pass .. first_pass + count - 1`` of ``seed``; returns their sums.

        ``callback(pass_index, sums_so_far)`` runs after each pass; returning False stops early (the sums
        then hold the passes done, nothing is lost).
        """
        seed = _check_int("seed", seed, 0, UINT32_LIMIT)
        count = _check_int("spp", count, 1)
        first_pass = _check_int("first_pass", first_pass, 0, UINT32_LIMIT)
        if first_pass + count > UINT32_LIMIT:
            raise RenderError("pass indices must stay below 2^32")
        s = self.scene
        npix = s.width * s.height
        tiles = self._tiles()
        # passes per launch: enough work per launch (about LAUNCH_SAMPLES samples) to hide its ~50 us overhead;
        # one with a callback, which runs after every pass
        per_launch = 1 if callback is not None else max(1, min(MAX_PASSES_PER_LAUNCH, LAUNCH_SAMPLES * tiles // npix))
        chunks = [(p, min(per_launch, first_pass + count - p)) for p in range(first_pass, first_pass + count, per_launch)]
        with wp.ScopedDevice(self.device):
            accum = wp.zeros(npix, dtype=wp.vec3d)
            accum_sq = wp.zeros(npix, dtype=wp.vec3d)
            accum_rep = wp.zeros(self.replicates * npix, dtype=wp.vec3d)
            accum_m2 = wp.zeros(npix if self.features.moments else 1, dtype=wp.vec3d)
            discarded = wp.zeros(tiles, dtype=wp.int32)  # one counter per tile
            rays = wp.zeros(tiles, dtype=wp.int64)
            lt = None
            if self.light_kernel is not None:
                lt = {k: wp.zeros(npix, dtype=wp.vec3d) for k in ("splat", "sum", "sum_sq")}
                lt["discarded"] = wp.zeros(1, dtype=wp.int32)
        rows_of = [len(range(t, s.height, tiles)) for t in range(tiles)]
        it = s.integrator

        def params(tile: int, pass_index: int, pass_count: int = 1) -> PassParams:
            p = PassParams()
            p.seed = wp.uint32(seed)
            p.pass_index = wp.uint32(pass_index)
            p.pass_count = pass_count
            p.row_offset = tile
            p.row_stride = tiles
            p.max_depth = self.max_depth
            p.rr_depth = it.rr_depth
            p.light_samples = self.light_samples
            p.hide_emitters = int(it.hide_emitters)
            p.replicates = self.replicates
            return p

        # one recorded launch per tile: later launches only swap the pass parameters (cheaper than wp.launch)
        cmds = [wp.launch(self.kernel, dim=rows_of[t] * s.width,
                          inputs=[self.dscene.data, self.dscene.camera, params(t, first_pass)],
                          outputs=[accum, accum_sq, accum_rep, accum_m2, discarded, rays], device=self.device,
                          record_cmd=True)
                for t in range(tiles)]

        def launch(tile: int, first: int, n: int):
            cmds[tile].set_param_by_name("params", params(tile, first, n))
            cmds[tile].launch()

        launch_lt = None
        if lt is not None:
            # the light paths of a pass splat into one buffer, folded into their own sums pass after pass, in pass
            # order, so the image does not depend on the thread count either
            lt_cmd = wp.launch(self.light_kernel, dim=npix,
                               inputs=[self.dscene.data, self.dscene.camera, params(0, first_pass), npix],
                               outputs=[lt["splat"], lt["discarded"]], device=self.device, record_cmd=True)
            fold = wp.launch(fold_pass, dim=npix, inputs=[lt["splat"], lt["sum"], lt["sum_sq"]],
                             device=self.device, record_cmd=True)

            def launch_lt(first: int, n: int):
                for pass_index in range(first, first + n):
                    lt_cmd.set_param_by_name("params", params(0, pass_index))
                    lt_cmd.launch()
                    fold.launch()

        bar = None
        if progress:
            from tqdm import tqdm

            bar = tqdm(total=count, unit="pass", desc="rendering", leave=False, dynamic_ncols=True)
        done = 0
        t0 = time.perf_counter()
        pool = self._worker_pool()
        try:
            if pool is not None and callback is None:
                done = self._run_free(pool, launch, launch_lt, chunks, tiles, bar)
            else:
                for first, n in chunks:
                    if pool is None:
                        for t in range(tiles):
                            launch(t, first, n)
                        if launch_lt is not None:
                            launch_lt(first, n)
                    else:
                        futures = [pool.submit(launch, t, first, n) for t in range(tiles)]
                        if launch_lt is not None:
                            futures.append(pool.submit(launch_lt, first, n))
                        for f in futures:
                            f.result()
                    done += n
                    if bar is not None:
                        bar.update(n)
                    if callback is not None:
                        wp.synchronize_device(self.device)
                        if callback(first + n - 1, self._sums(accum, accum_sq, accum_rep, accum_m2, discarded, rays, first_pass, done, t0, lt)) is False:
                            break
            wp.synchronize_device(self.device)
        finally:
            if bar is not None:
                bar.close()
        return self._sums(accum, accum_sq, accum_rep, accum_m2, discarded, rays, first_pass, done, t0, lt)

    def _tiles(self) -> int:
        """Row sets the image is split into: one per thread would leave a core idle whenever the other thread runs
        slower (measured 10-25% apart on this project's shared 2-core VM), so several per thread, taken on demand."""
        if self.threads == 1:
            return 1
        return min(self.scene.height, TILES_PER_THREAD * self.threads)

    def _worker_pool(self) -> ThreadPoolExecutor | None:
        """The renderer's worker threads, started once and reused by every call (None with one thread)."""
        if self.threads == 1:
            return None  # (with light tracing too: one core, one thread, the two kernels one after the other)
        if getattr(self, "_pool", None) is None:
            workers = self.threads + (self.light_kernel is not None)
            self._pool = ThreadPoolExecutor(workers, thread_name_prefix="pathtracer")
        return self._pool

    def close(self) -> None:
        """Stop the worker threads (also done when the renderer is garbage collected)."""
        pool, self._pool = getattr(self, "_pool", None), None
        if pool is not None:
            pool.shutdown(wait=True, cancel_futures=True)

    def __del__(self):
        try:
            self.close()
        except Exception:
            pass

    def _run_free(self, pool: ThreadPoolExecutor, launch, launch_lt, chunks: list[tuple[int, int]], tiles: int,
                  bar) -> int:
        """Render every (chunk of passes, tile) with the pool's threads, taken on demand in chunk-major order (a
        faster thread takes more of them), with no barrier between chunks; the light paths, if any, on a thread
        of their own. A tile's chunks run in order, one at a time, so every pixel sums its passes in pass order.
        Returns the number of passes done (all of them)."""
        items = len(chunks) * tiles
        taken = itertools.count()  # next(count) is atomic under the GIL
        cond = threading.Condition()
        next_chunk = [0] * tiles  # per tile: the chunk it may run next
        lt_done = [0]
        shown = [0]
        failed = threading.Event()
        passes_before = list(itertools.accumulate((n for _, n in chunks), initial=0))  # passes in chunks[:k]

        def report():  # under cond
            if bar is None:
                return
            low = min(next_chunk)
            if launch_lt is not None:
                low = min(low, lt_done[0])
            passes = passes_before[low]
            if passes > shown[0]:
                bar.update(passes - shown[0])
                shown[0] = passes

        def path_worker():
            try:
                while not failed.is_set():
                    i = next(taken)
                    if i >= items:
                        return
                    c, tile = divmod(i, tiles)
                    with cond:  # its previous chunk was taken `tiles` items ago: almost always done by now
                        cond.wait_for(lambda: next_chunk[tile] == c or failed.is_set())
                    if failed.is_set():
                        return
                    launch(tile, *chunks[c])
                    with cond:
                        next_chunk[tile] = c + 1
                        cond.notify_all()
                        report()
            except BaseException:
                with cond:
                    failed.set()
                    cond.notify_all()
                raise

        def lt_worker():
            for k, (first, n) in enumerate(chunks):
                if failed.is_set():
                    return
                launch_lt(first, n)
                with cond:
                    lt_done[0] = k + 1
                    report()

        futures = [pool.submit(path_worker) for _ in range(self.threads)]
        if launch_lt is not None:
            futures.append(pool.submit(lt_worker))
        try:
            for f in futures:
                f.result()
        except BaseException:
            with cond:
                failed.set()  # interrupted: workers stop after their current launch
                cond.notify_all()
            raise
        return passes_before[-1]

    def _sums(self, accum, accum_sq, accum_rep, accum_m2, discarded, rays, first: int, done: int, t0: float,
              lt=None) -> PassSum:
        s = self.scene
        shape = (s.height, s.width, 3)
        R = self.replicates
        passes = np.arange(first, first + done, dtype=np.int64)
        sums = PassSum(accum.numpy().reshape(shape).copy(), accum_sq.numpy().reshape(shape).copy(),
                       done, int(discarded.numpy().sum()), time.perf_counter() - t0, int(rays.numpy().sum()),
                       rep_sum=accum_rep.numpy().reshape((R,) + shape).copy(),
                       rep_passes=np.bincount(passes % R, minlength=R),
                       estimator="replicates" if self.sampler == "sobol" else "passes")
        if self.features.moments:
            sums.m2_sum = accum_m2.numpy().reshape(shape).copy()
        if lt is not None:
            sums.lt_sum = lt["sum"].numpy().reshape(shape).copy()
            sums.lt_sum_sq = lt["sum_sq"].numpy().reshape(shape).copy()
            sums.discarded += int(lt["discarded"].numpy()[0])
        return sums


_lock = threading.Lock()


def render(
    scene: Scene,
    spp: int | None = None,
    max_depth: int | None = None,
    seed: int | None = None,
    device: str | None = None,
    *,
    light_samples: int | None = None,
    rr: str | None = None,
    threads: int | None = None,
    view: str = "radiance",
    sampler: str | None = None,
    light_sampling: str | None = None,
    light_tracing: bool | str | None = None,
    triangles: str | None = None,
    replicates: int | None = None,
    progress: bool = True,
    callback: Callable[[int, PassSum], object] | None = None,
    stats: dict | None = None,
    layers: dict | None = None,
) -> np.ndarray:
    """Render ``scene``; returns linear radiance, float32 (H, W, 3).

    spp, max_depth, seed: None means the scene file's value (its sampler's sample_count, the integrator's
    max_depth, the sampler's seed). device: None picks CUDA when present, else "cpu".
    light_samples: next-event samples per light (default 1; the seed used 8).
    rr: "throughput" (Mitsuba's rule from the scene's rr_depth, default) or "seed" (stop with probability 0.2
    after the first bounce). threads: CPU worker threads (default: all cores); the image does not depend on it. view: "radiance", "direction" or "normal".
    sampler: "independent" (default) or "sobol" (Owen-scrambled Sobol' points, stratified across passes).
    light_sampling: "area" (default) or "solid_angle" (rectangular lights sampled uniformly in solid angle).
    light_tracing: caustics seen directly from light paths (see ``Renderer``): True, False, or None / "auto"
    (default): where the scene allows it, a pilot of 1/32 of the passes with and without decides, and counts
    toward the image (pathtracer/estimator.py: the winner renders spp passes, its pilot among them; the loser's
    pilot is left out).
    With a callback, auto means off.
    triangles: "wide" (default) or "warp" (see ``Renderer``).
    replicates: independent Sobol' scrambles the passes are dealt to (pass p to p mod R; default 4), whose spread
    is the error estimate.
    callback(pass_index, PassSum) runs after each pass. stats, if given, receives spp, render_seconds (kernels
    only; also as seconds), compile_seconds, wall_seconds (this call), samples, samples_per_second,
    relmse_estimate (the image's estimated relMSE, ``PassSum.relmse_estimate``), discarded, config (the estimator
    used, and the pilot's figures when "auto" ran one), threads, device, roulette_warning (None, or why the seed
    roulette rule has an infinite variance on this scene).
    layers, if given, receives the extra image layers of the scene's integrator (Mitsuba's moment integrator: the
    nested one's mean XYZ and per-sample second moment, ``Integrator.layer_names``), float32 (H, W, 3) each.
    """
    t_wall = time.perf_counter()
    spp = scene.spp if spp is None else spp
    spp = _check_int("spp", spp, 1)
    seed = scene.sampler_seed if seed is None else seed
    seed = _check_int("seed", seed, 0, UINT32_LIMIT)
    auto = light_tracing is None or light_tracing == "auto"
    opts = dict(device=device, max_depth=max_depth, light_samples=light_samples, rr=rr, view=view, threads=threads,
                sampler=sampler, light_sampling=light_sampling, triangles=triangles, replicates=replicates)
    r = Renderer(scene, light_tracing=False if auto else bool(light_tracing), **opts)
    roulette_warning = roulette_variance_warning(scene, r.rr, r.max_depth)
    if roulette_warning:  # detected and reported before any time is spent, never silently averaged
        warnings.warn(f"{scene.source}: {roulette_warning}", RuntimeWarning, stacklevel=2)
    from pathtracer import estimator  # (imports render.py itself)

    compile_seconds = r.compile_seconds
    if auto and callback is None and r.light_tracing_possible and estimator.pilot_passes(spp, r.replicates):
        traced = Renderer(scene, light_tracing=True, **opts)
        compile_seconds += traced.compile_seconds
        try:
            result = estimator.render_auto(r, traced, seed, spp, progress=progress)
        finally:
            traced.close()
        config_extra = result.config
    else:
        result = r.render_passes(seed=seed, first_pass=0, count=spp, progress=progress, callback=callback)
        config_extra = {"light_tracing": r.light_tracing}
    r.close()
    if layers is not None:
        layers.update(result.layers(scene.integrator.layer_names))
    if result.discarded:
        warnings.warn(f"{scene.source}: {result.discarded} non-finite samples were discarded", RuntimeWarning,
                      stacklevel=2)
    if stats is not None:
        config = {"sampler": r.sampler, "replicates": r.replicates, "light_samples": r.light_samples,
                  "light_sampling": r.light_sampling, "rr": r.rr, "max_depth": r.max_depth, "triangles": r.triangles,
                  "light_tracing_choice": "auto" if auto else "fixed"}
        config.update(config_extra)
        pixels = scene.width * scene.height
        seconds = result.seconds
        stats.update(spp=result.passes, render_seconds=seconds, seconds=seconds, compile_seconds=compile_seconds,
                     wall_seconds=time.perf_counter() - t_wall,
                     samples=result.passes * pixels, samples_per_second=result.passes * pixels / max(seconds, 1e-12),
                     relmse_estimate=result.relmse_estimate, discarded=result.discarded, config=config,
                     threads=r.threads, device=r.device, roulette_warning=roulette_warning)
    return result.mean
