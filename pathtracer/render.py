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
from kernels.types import Adjoint, PassParams
from pathtracer.device_scene import DeviceScene
from pathtracer.diagnostics import roulette_variance_warning
from pathtracer.errors import RenderError
from pathtracer.film import SRGB_TO_XYZ, Film, PassSum, box3  # noqa: F401 (re-exported)
from pathtracer import jobs
from pathtracer.jobs import check_film_size
from pathtracer.scene import Scene
from pathtracer.warp_setup import init_warp

DEFAULT_LIGHT_SAMPLES = 1
DEFAULT_RR = "throughput"
DEFAULT_SAMPLER = "sobol"  # 1.1-3.2x more efficient than independent on every seed scene (docs/performance.md)
# independent Sobol' scrambles a render is split into, for its error estimate: two keep twice the points per
# scramble of four (Sobol' stratifies better the more points a scramble has): 12-13% lower relMSE at 512 spp on
# the Cornell box, the mirror box and the open sky (the teapot within noise), and the image's estimate stays
# unbiased (docs/performance.md)
DEFAULT_REPLICATES = 2
# a render that stops on its own estimate (an error budget, adaptive sampling) keeps four: it decides from its
# first few passes, an adaptive one pixel by pixel, and an estimate from two scrambles is too noisy for that (at
# 1e-2 on the teapot an error budget then stopped at a third of its target)
DECIDING_REPLICATES = 4


def default_sampler(spp: int, replicates: int | None = None) -> str:
    """The sampler a render of ``spp`` passes gets when none is asked for: Sobol', unless some replicate would get
    a single point (fewer than two per replicate): a scramble's first point is a uniform random one, so Sobol'
    then only costs its extra time (about 20% a sample) and stratifies nothing."""
    reps = DEFAULT_REPLICATES if replicates is None else replicates
    return DEFAULT_SAMPLER if spp >= 2 * reps else "independent"
DEFAULT_LIGHT_SAMPLING = "area"
DEFAULT_LIGHT_TRACING = False
DEFAULT_TRIANGLES = "wide"  # watertight, and faster than "warp" on the CPU (examples/bench_rays.py)
UINT32_LIMIT = 2**32
TILES_PER_THREAD = 4  # row sets per CPU thread, taken on demand (load balancing)
LAUNCH_SAMPLES = 1 << 15  # samples one launch aims at (~10-20 ms on a CPU core), by grouping passes
MAX_PASSES_PER_LAUNCH = 16


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
    light_tracing: caustics (light -> mirrors -> any bounces -> a diffuse surface -> camera) from light paths
    (kernels/light_tracer.py) instead of camera paths (default off; it applies only to scenes with mirrors and
    lights, and max_depth -1 or >= 3). Far less noise where the camera sees the surfaces the caustics fall on, far
    more where it sees only a sliver of them (a narrow view): light paths rarely land there.
    triangles: "wide" (default: our watertight 4-wide box tree, kernels/triangle.py) or "warp" (Warp's wp.Mesh and
    mesh_query_ray, kernels/triangle_warp.py: rays aimed exactly at a vertex can slip through it).
    adaptive: compile per-pixel pass limits in (``Film.set_limits``; pathtracer/adaptive.py decides them); not with
    light tracing or the moment integrator.
    gradient: compile forward-mode derivatives in: the film's ``grad_sum`` gets dL/dtheta of every path, theta being
    the reflectance of material ``grad_material`` or the radiance of parallelogram light ``grad_light`` (set them
    before rendering; pathtracer/gradients.py). Diffuse and mirror materials only; no light tracing.
    backward: compile path replay in: ``set_adjoint(weight)`` then render, and ``adjoint()`` gives every material's
    and parallelogram light's share of the loss gradient (pathtracer/gradients.py: render_backward).
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
    adaptive: bool = False
    gradient: bool = False
    backward: bool = False
    compile_seconds: float = field(init=False, default=0.0)
    grad_material: int = field(init=False, default=-1)  # gradient renderers: what render_into differentiates
    grad_light: int = field(init=False, default=-1)

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
        if self.replicates is None:
            reps = DECIDING_REPLICATES if bool(self.adaptive) else DEFAULT_REPLICATES
        else:
            reps = self.replicates
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
        self.adaptive = bool(self.adaptive)
        self.gradient = bool(self.gradient)
        self.backward = bool(self.backward)
        if self.gradient or self.backward:
            f = self.features
            if f.plastics or f.rough_conductors or f.rough_plastics or f.moments or f.textures:
                raise RenderError("gradients are available on scenes of diffuse, mirror, glass and smooth conductor "
                                  "materials without textures, and the path integrator (this scene has others)")
            if self.light_tracing:
                raise RenderError("gradients are not available with light tracing")
        if self.adaptive and self.features.moments:
            raise RenderError("adaptive sampling is not available with the moment integrator (its layers are "
                              "per-pass means)")
        possible = (not (self.features.pixel_filter or self.features.thin_lens or self.features.other_materials
                         or self.features.textures or self.features.moments or self.adaptive or self.gradient
                         or self.backward)
                    and self.scene.only_rect_lights
                    and self.features.mirrors and self.features.lights and self.view == "radiance"
                    and (self.max_depth < 0 or self.max_depth >= 3))
        if self.adaptive and self.light_tracing:
            raise RenderError("adaptive sampling is not available with light tracing (its paths land anywhere "
                              "on the film)")
        wanted = DEFAULT_LIGHT_TRACING if self.light_tracing is None else bool(self.light_tracing)
        self.light_tracing_possible = possible
        self.light_tracing = wanted and possible
        self.features = dataclasses.replace(self.features, light_tracing=self.light_tracing, adaptive=self.adaptive,
                                            gradient=self.gradient, backward=self.backward)
        # refused before anything is compiled or allocated: a film the machine cannot hold, or Warp cannot index
        check_film_size(self.scene.width, self.scene.height, self.replicates, self.features.moments,
                        self.light_tracing, self.device)
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
        self.adj = self._empty_adjoint()

    def _empty_adjoint(self) -> Adjoint:
        a = Adjoint()
        a.weight = wp.zeros(1, dtype=wp.vec3, device=self.device)
        a.rgb = wp.zeros(1, dtype=wp.vec3d, device=self.device)
        a.radiance = wp.zeros(1, dtype=wp.vec3d, device=self.device)
        a.num_materials = 0
        a.num_lights = 0
        return a

    def set_adjoint(self, weight: np.ndarray) -> None:
        """Backward renderers: each pixel's weight (H, W, 3: dLoss/dpixel divided by the spp to come), and
        zeroed adjoints."""
        s = self.scene
        tiles = self._tiles()
        a = Adjoint()
        a.weight = wp.array(np.ascontiguousarray(weight, dtype=np.float32).reshape(-1, 3), dtype=wp.vec3,
                            device=self.device)
        a.num_materials = len(s.materials)
        a.num_lights = len(s.lights)
        a.rgb = wp.zeros(max(1, tiles * a.num_materials), dtype=wp.vec3d, device=self.device)
        a.radiance = wp.zeros(max(1, tiles * a.num_lights), dtype=wp.vec3d, device=self.device)
        self.adj = a

    def adjoint(self) -> tuple[np.ndarray, np.ndarray]:
        """(materials (M, 3), lights (L, 3)) float64: the adjoints added since ``set_adjoint``, summed over
        tiles."""
        a = self.adj
        tiles = self._tiles()
        rgb = a.rgb.numpy()[: tiles * a.num_materials].reshape(tiles, a.num_materials, 3).sum(axis=0)
        rad = a.radiance.numpy()[: tiles * a.num_lights].reshape(tiles, a.num_lights, 3).sum(axis=0)
        return rgb, rad

    def new_film(self) -> Film:
        """Empty accumulators for this renderer's passes (``render_passes(film=...)`` adds to them)."""
        s = self.scene
        return Film(s.width, s.height, self.replicates, self.features.moments, self.light_kernel is not None,
                    self._tiles(), self.device, "replicates" if self.sampler == "sobol" else "passes", self.adaptive,
                    self.gradient)

    def render_passes(
        self,
        seed: int = 0,
        first_pass: int = 0,
        count: int = 1,
        progress=False,
        callback: Callable[[int, "PassSum"], object] | None = None,
        film: Film | None = None,
    ) -> PassSum:
        """Render passes ``first_pass .. first_pass + count - 1`` of ``seed``; returns their sums.

        ``film``: add them to this film (``new_film``; it must have been continued from pass ``first_pass``, or be
        empty) instead of a fresh one, and return all of its sums. ``progress``: a bar (True), none (False), or an
        object with ``update(n)`` to report passes to. ``callback(pass_index, sums_so_far)`` runs after each pass;
        returning False stops early (the sums then hold the passes done, nothing is lost).
        """
        film = self.new_film() if film is None else film
        self.render_into(film, seed, first_pass, count, progress, callback)
        return film.sums()

    stops_mid_call = True  # render_into takes a stop flag (the Ray executor's renderer does not)

    def render_into(self, film: Film, seed: int, first_pass: int, count: int, progress=False,
                    callback: Callable[[int, "PassSum"], object] | None = None, stop=None) -> int:
        """Add passes ``first_pass ..`` (``count`` of them) of ``seed`` to ``film``; returns the number added.

        ``stop`` (anything with ``is_set()``, such as a ``jobs.StopFlag``): once set, no new pass is started and
        the passes already started on some tile are finished on every tile, so the film still holds whole passes
        (fewer than ``count``). A job looks at it this way instead of cutting its render into short calls, whose
        ends would each leave a core idle while the other finishes its last tile."""
        seed = _check_int("seed", seed, 0, UINT32_LIMIT)
        count = _check_int("spp", count, 1)
        first_pass = _check_int("first_pass", first_pass, 0, UINT32_LIMIT)
        if first_pass + count > UINT32_LIMIT:
            raise RenderError("pass indices must stay below 2^32")
        if film.passes and first_pass != film.next_pass:
            raise RenderError(f"the film holds passes up to {film.next_pass - 1}: it continues with pass "
                              f"{film.next_pass}, not {first_pass}")
        s = self.scene
        npix = s.width * s.height
        tiles = self._tiles()
        # passes per launch: enough work per launch (about LAUNCH_SAMPLES samples) to hide its ~50 us overhead;
        # one with a callback, which runs after every pass
        per_launch = 1 if callback is not None else max(1, min(MAX_PASSES_PER_LAUNCH, LAUNCH_SAMPLES * tiles // npix))
        chunks = [(p, min(per_launch, first_pass + count - p)) for p in range(first_pass, first_pass + count, per_launch)]
        lt = film.lt
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
            p.grad_material = self.grad_material
            p.grad_light = self.grad_light
            return p

        # one recorded launch per tile: later launches only swap the pass parameters (cheaper than wp.launch)
        cmds = [wp.launch(self.kernel, dim=rows_of[t] * s.width,
                          inputs=[self.dscene.data, self.dscene.camera, params(t, first_pass), film.pass_limit,
                                  self.adj],
                          outputs=[film.accum, film.accum_sq, film.accum_rep, film.accum_m2, film.discarded,
                                   film.rays, film.accum_grad], device=self.device, record_cmd=True)
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
        if progress is True:
            from tqdm import tqdm

            bar = tqdm(total=count, unit="pass", desc="rendering", leave=False, dynamic_ncols=True)
        elif progress:
            bar = progress  # the caller's, over more than this call
        done = 0
        t0 = time.perf_counter()
        pool = self._worker_pool()
        try:
            if pool is not None and callback is None:
                done = self._run_free(pool, launch, launch_lt, chunks, tiles, bar, stop)
            else:
                for first, n in chunks:
                    if stop is not None and stop.is_set():
                        break
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
                        film.added(first, n, time.perf_counter() - t0)
                        t0 = time.perf_counter()
                        if callback(first + n - 1, film.sums()) is False:
                            return done
            wp.synchronize_device(self.device)
            if callback is None:
                film.added(first_pass, done, time.perf_counter() - t0)
        finally:
            if bar is not None and progress is True:
                bar.close()
        return done

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
                  bar, stop=None) -> int:
        """Render every (chunk of passes, tile) with the pool's threads, taken on demand in chunk-major order (a
        faster thread takes more of them), with no barrier between chunks; the light paths, if any, on a thread
        of their own. A tile's chunks run in order, one at a time, so every pixel sums its passes in pass order.
        Returns the number of passes done: all of them, or, once ``stop`` is set, those of the chunks that some
        tile (or the light tracer) had started by then, finished on every tile."""
        items = len(chunks) * tiles
        started = [-1]  # under cond: the last item started before the stop was seen
        cutoff = [items]  # under cond: the items that run (all, until the stop is seen: then whole chunks)

        def may_start(i: int) -> bool:  # under cond
            if cutoff[0] == items and stop is not None and stop.is_set():
                cutoff[0] = min(items, -(-(started[0] + 1) // tiles) * tiles)
            if i >= cutoff[0]:
                return False
            started[0] = max(started[0], i)
            return True
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
                        if not may_start(i):
                            return
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
                with cond:  # its chunk k is started like a tile's: the path tracer's must then finish too
                    if not may_start(k * tiles):
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
        return passes_before[cutoff[0] // tiles]

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
    time_limit: float | None = None,
    target_error: float | None = None,
    checkpoint: str | os.PathLike | None = None,
    checkpoint_every: float = 30.0,
    resume: bool = False,
    preview=None,
    preview_every: float | None = None,
    stop=None,
    executor=None,
    adaptive: bool | float = False,
) -> np.ndarray:
    """Render ``scene``; returns linear radiance, float32 (H, W, 3).

    spp, max_depth, seed: None means the scene file's value (its sampler's sample_count, the integrator's
    max_depth, the sampler's seed). device: None picks CUDA when present, else "cpu".
    light_samples: next-event samples per light (default 1; the seed used 8).
    rr: "throughput" (Mitsuba's rule from the scene's rr_depth, default) or "seed" (stop with probability 0.2
    after the first bounce). threads: CPU worker threads (default: all cores); the image does not depend on it. view: "radiance", "direction" or "normal".
    sampler: "sobol" (default: Owen-scrambled Sobol' points, stratified across passes, in ``replicates``
    independent scrambles) or "independent"; the default is independent when spp is below twice the replicates
    (``default_sampler``), and for a render with a budget or a checkpoint always Sobol'.
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
    nested one's mean XYZ and per-sample second moment, ``Integrator.layer_names``), float32 (H, W, 3) each, and,
    for a render with a time or error budget or a checkpoint, "stderr" (the standard error of each pixel's mean).

    Budgets (pathtracer/jobs.py): the render stops at the first of spp passes, ``time_limit`` seconds of rendering
    (it stops when the next pass would overrun) and ``target_error`` (``relmse_estimate`` at or below it, after a
    minimum of passes); with a time or error budget and no spp, spp is unbounded. ``checkpoint``: a file the sums
    are saved to every ``checkpoint_every`` seconds and at the end (atomically); ``resume`` continues from it, bit
    for bit (a checkpoint of another scene or configuration is refused). ``preview``: a path (or a callable taking
    the image) that gets the image so far every ``preview_every`` seconds. ``stop``: a ``jobs.StopFlag``; when set
    (for example by SIGINT, ``jobs.handle_signals``) the render stops after its current unit of passes and
    returns the image so far. stats then also has stop_reason ("spp", "time", "target_error" or "interrupted")
    and resumed_passes.

    ``executor``: a ``pathtracer.ray_executor.RayExecutor`` renders the passes on Ray workers instead of in this
    process (the same image to float32 rounding; every budget, checkpoint and resume works the same; no callback).

    ``adaptive``: True, or a threshold (a pixel's estimated relMSE; default ``target_error`` if given, else 1e-4):
    pixels stop once their error is at or below it (pathtracer/adaptive.py: after 64 passes, decided every 32);
    the render ends at the first bound or when every pixel has stopped (stop_reason "converged"). layers then
    get "spp" (passes per pixel) and "stderr"; stats get "adaptive". Not with light tracing (auto leaves it off),
    the moment integrator, a callback or an executor.
    """
    from pathtracer import estimator  # (it imports render.py itself)

    t_wall = time.perf_counter()
    budgeted = time_limit is not None or target_error is not None
    if time_limit is not None and not (isinstance(time_limit, (int, float)) and time_limit > 0):
        raise RenderError(f"time_limit must be > 0 seconds, got {time_limit!r}")
    if target_error is not None and not (isinstance(target_error, (int, float)) and target_error > 0):
        raise RenderError(f"target_error must be > 0, got {target_error!r}")
    if checkpoint_every <= 0:
        raise RenderError(f"checkpoint_every must be > 0 seconds, got {checkpoint_every!r}")
    if resume and checkpoint is None:
        raise RenderError("resume needs a checkpoint")
    if spp is None and budgeted:
        spp = jobs.MAX_PASSES  # bounded by time or error alone
    spp = scene.spp if spp is None else spp
    spp = _check_int("spp", spp, 1, UINT32_LIMIT)
    pilot_spp = min(spp, 256) if budgeted else spp  # a pilot sized for a time or error budget, not for its bound
    seed = scene.sampler_seed if seed is None else seed
    seed = _check_int("seed", seed, 0, UINT32_LIMIT)
    adaptive_on = adaptive is not False and adaptive is not None
    if replicates is None and (target_error is not None or adaptive_on):
        replicates = DECIDING_REPLICATES
    if sampler is None and not budgeted and checkpoint is None and isinstance(replicates, (int, type(None))):
        sampler = default_sampler(spp, replicates)
    auto = light_tracing is None or light_tracing == "auto"
    opts = dict(device=device, max_depth=max_depth, light_samples=light_samples, rr=rr, view=view, threads=threads,
                sampler=sampler, light_sampling=light_sampling, triangles=triangles, replicates=replicates)
    if executor is not None and callback is not None:
        raise RenderError("a per-pass callback is not available with an executor")
    plan = None
    if adaptive_on:
        from pathtracer.adaptive import DEFAULT_THRESHOLD, Adaptive

        if callback is not None or executor is not None:
            raise RenderError("adaptive sampling is not available with a per-pass callback or an executor")
        threshold = adaptive if not isinstance(adaptive, bool) else (target_error or DEFAULT_THRESHOLD)
        plan = Adaptive(threshold)
        opts["adaptive"] = True
    make = Renderer if executor is None else executor.renderer
    r = make(scene, light_tracing=False if auto else bool(light_tracing), **opts)
    roulette_warning = roulette_variance_warning(scene, r.rr, r.max_depth)
    if roulette_warning:  # detected and reported before any time is spent, never silently averaged
        warnings.warn(f"{scene.source}: {roulette_warning}", RuntimeWarning, stacklevel=2)

    compile_seconds = r.compile_seconds
    config = {"sampler": r.sampler, "replicates": r.replicates, "light_samples": r.light_samples,
              "light_sampling": r.light_sampling, "rr": r.rr, "max_depth": r.max_depth, "triangles": r.triangles,
              "light_tracing_choice": "auto" if auto else "fixed"}
    traced = None
    stop_reason, extra_seconds, resumed = "spp", 0.0, 0
    try:
        if callback is not None:
            result = r.render_passes(seed=seed, first_pass=0, count=spp, progress=progress, callback=callback)
            config["light_tracing"] = r.light_tracing
        else:
            may_trace = auto and r.light_tracing_possible and estimator.pilot_passes(pilot_spp, r.replicates) > 0
            if may_trace and resume:  # compile the light tracer only if the checkpoint's render used it
                saved = jobs.checkpoint_config(checkpoint)
                may_trace = bool(saved.get("light_tracing") or saved.get("pilot", {}).get("unfinished"))
            if may_trace:
                traced = make(scene, light_tracing=True, **opts)
                compile_seconds += traced.compile_seconds
            job_config = dict(config, view=view, seed=seed, width=scene.width, height=scene.height,
                              device="cpu" if r.device == "cpu" else "cuda")
            if checkpoint is not None:
                job_config["scene_hash"] = jobs.scene_hash(scene)
            if executor is not None:  # the farm's merge grouping (a resume elsewhere is right, not bit-identical)
                job_config["unit_passes"] = r.unit_passes
            if plan is not None:
                job_config["adaptive"] = plan.config()
            write_preview = None
            if preview is not None:
                def write_preview(sums: PassSum):
                    if callable(preview):
                        preview(sums.mean)
                    else:
                        from pathtracer.imageio import write_image

                        write_image(preview, sums.mean, display=view != "radiance")
            bar = None
            if progress:
                from tqdm import tqdm

                bar = tqdm(total=spp if spp < jobs.MAX_PASSES else None, unit="pass", desc="rendering",
                           leave=False, dynamic_ncols=True)
            try:
                outcome = jobs.run_job(r, traced, seed, jobs.Budget(spp, time_limit, target_error),
                                       pilot_spp=pilot_spp, checkpoint=None if checkpoint is None else
                                       os.fspath(checkpoint), checkpoint_every=checkpoint_every, resume=resume,
                                       preview=write_preview, preview_every=preview_every, stop=stop,
                                       progress=bar if bar is not None else False, base_config=job_config,
                                       adaptive=plan)
            finally:
                if bar is not None:
                    bar.close()
            result = outcome.sums
            stop_reason, extra_seconds, resumed = outcome.stop_reason, outcome.extra_seconds, outcome.resumed_passes
            config.update({k: v for k, v in outcome.config.items() if k in ("light_tracing", "pilot")})
    finally:
        if traced is not None:
            traced.close()
        r.close()
    if layers is not None:
        layers.update(result.layers(scene.integrator.layer_names))
        if budgeted or checkpoint is not None or plan is not None:
            layers["stderr"] = np.sqrt(result.variance_of_mean).astype(np.float32)
        if plan is not None:
            layers["spp"] = result.pixel_counts().astype(np.float32)
    if result.discarded:
        warnings.warn(f"{scene.source}: {result.discarded} non-finite samples were discarded", RuntimeWarning,
                      stacklevel=2)
    if stats is not None:
        pixels = scene.width * scene.height
        seconds = result.seconds + extra_seconds  # (with a resumed render: the earlier sessions' too)
        samples = result.passes * pixels if result.counts is None else int(result.counts.sum())
        stats.update(spp=result.passes, render_seconds=seconds, seconds=seconds, compile_seconds=compile_seconds,
                     wall_seconds=time.perf_counter() - t_wall,
                     samples=samples, samples_per_second=samples / max(seconds, 1e-12),
                     relmse_estimate=result.relmse_estimate, discarded=result.discarded, config=config,
                     threads=r.threads, device=r.device, roulette_warning=roulette_warning,
                     stop_reason=stop_reason, resumed_passes=resumed)
        if plan is not None:
            counts = result.pixel_counts()
            stats["adaptive"] = dict(plan.config(), mean_spp=float(counts.mean()), min_spp=int(counts.min()),
                                     max_spp=int(counts.max()),
                                     stopped_fraction=float(np.mean(counts < result.passes)))
        if executor is not None:
            stats["executor"] = {"kind": "ray", "workers": executor.workers, "unit_passes": r.unit_passes,
                                 "units_retried": executor.units_retried}
    return result.mean
