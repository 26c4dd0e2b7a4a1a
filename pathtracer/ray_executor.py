"""A render farm on Ray: the passes of a render handed out in units to long-lived workers, merged by unit.

``render(scene, executor=RayExecutor("local"))`` (CLI: ``--ray local`` or ``--ray ADDRESS``) renders on Ray
instead of in this process. The scene is shipped once (``ray.put``); each worker is one Ray actor that compiles
the render kernels once (a fresh process per task would pay Warp's start-up every time, and on a GPU a new CUDA
context) and renders units of consecutive passes into a film of its own; the driver adds the units' sums as they
arrive, with a bounded number in flight.

Units are fixed by the pass indices alone (``unit_passes``: boundaries at its multiples), and the driver adds
them in pass order whatever order they arrive in, keyed by their first pass, so a unit that a dead worker's
replacement renders again is never counted twice, and the image depends only on the seed and spp: not on the
number of workers, the order they finish in, a retried unit, or a checkpoint and resume in between. It equals the
one-process image to float32 rounding (the float64 sums are added in another grouping).

Ray is imported only here, and only when an executor is made (the optional extra ``pip install .[ray]``).
"""

from __future__ import annotations

import collections
import dataclasses
import os
import time

import numpy as np

from pathtracer.errors import RenderError
from pathtracer.film import PassSum

UNIT_SAMPLES = 1 << 20  # samples per unit (~0.5-1 s on one CPU core): the per-unit cost (~5 ms) stays small
UNIT_MIN_PASSES = 8  # ... and passes: a unit ships its float64 sums (~200 bytes a pixel), which must stay small next
#                      to the rendering (one pass of a 800x600 film is ~0.3 s of a core and ~100 MB of sums)
START_TIMEOUT = 60.0  # seconds to wait for a first worker before the cluster is judged unable to run one
IN_FLIGHT = 2  # units queued per worker, so that it never waits for the driver between units
RENDERERS_KEPT = 4  # compiled renderers a worker keeps (an LRU over the scenes and options it has seen)

_worker_class = None


def _import_ray():
    try:
        import ray
    except ImportError:
        raise RenderError("the Ray executor needs Ray: pip install 'pathtracer[ray]'") from None
    return ray


def _remote_worker(ray):
    """The actor class, made once per process (Ray is imported lazily, so it cannot be decorated at import)."""
    global _worker_class
    if _worker_class is None:
        _worker_class = ray.remote(max_restarts=0, max_task_retries=0)(_Worker)
    return _worker_class


class _Worker:
    """One Ray actor: renderers compiled on first use, kept while they are used, and units rendered on them."""

    def __init__(self):
        from pathtracer.warp_setup import init_warp

        init_warp()
        self.renderers: collections.OrderedDict = collections.OrderedDict()

    def pid(self) -> int:
        return os.getpid()

    def _renderer(self, key, scene_box, opts):
        from pathtracer.render import Renderer
        import ray

        r = self.renderers.pop(key, None)
        if r is None:
            scene = ray.get(scene_box[0])  # (in a list, so that Ray does not fetch it for every unit)
            r = Renderer(scene, **opts)
        self.renderers[key] = r
        while len(self.renderers) > RENDERERS_KEPT:
            self.renderers.popitem(last=False)[1].close()
        return r

    def describe(self, key, scene_box, opts) -> dict:
        """The options the renderer resolved (the driver reports and checkpoints them)."""
        r = self._renderer(key, scene_box, opts)
        return {k: getattr(r, k) for k in ("sampler", "replicates", "light_samples", "light_sampling", "rr",
                                           "max_depth", "triangles", "light_tracing", "light_tracing_possible",
                                           "device", "threads", "compile_seconds")} | {
            "moments": bool(r.features.moments)}

    def render(self, key, scene_box, opts, seed: int, first: int, count: int) -> PassSum:
        return self._renderer(key, scene_box, opts).render_passes(seed=seed, first_pass=first, count=count)


def _cause(e: BaseException) -> BaseException:
    """The worker's own exception inside a RayTaskError."""
    return getattr(e, "cause", None) or e


class RayExecutor:
    """Renders on a Ray cluster: ``address`` "local" starts Ray on this machine (loopback only), another value
    joins a running cluster ("auto", or the head's "HOST:PORT"), None uses the one this process is connected to.

    workers: actors to start (default: the cluster's CPUs, or GPUs, divided by what each takes);
    cpus_per_worker: CPU cores each worker takes and renders with (its threads); gpus_per_worker: GPUs each takes
    (> 0 renders on CUDA); start_timeout: seconds without any live worker after which the render fails (a worker
    that needs a resource no node has); unit_samples, unit_min_passes: a unit's size, in samples and at least in
    passes (it fixes how the float64 sums are grouped: the image changes with it, by float32 rounding).
    """

    def __init__(self, address: str | None = "local", workers: int | None = None, cpus_per_worker: float = 1,
                 gpus_per_worker: float = 0, start_timeout: float = START_TIMEOUT,
                 unit_samples: int = UNIT_SAMPLES, unit_min_passes: int = UNIT_MIN_PASSES,
                 in_flight: int = IN_FLIGHT):
        if workers is not None and workers < 1:
            raise RenderError(f"a Ray executor needs at least one worker, got {workers}")
        if cpus_per_worker <= 0 or gpus_per_worker < 0:
            raise RenderError("cpus_per_worker must be > 0 and gpus_per_worker >= 0")
        self.address = address
        self.requested_workers = workers
        self.cpus_per_worker = cpus_per_worker
        self.gpus_per_worker = gpus_per_worker
        self.start_timeout = float(start_timeout)
        self.unit_samples = int(unit_samples)
        self.unit_min_passes = max(1, int(unit_min_passes))
        self.in_flight = max(1, int(in_flight))
        self._ray = None
        self._started_ray = False
        self._actors: list = []  # live, ready workers
        self._starting: dict = {}  # pid ref -> actor, for workers not yet ready
        self._load: collections.Counter = collections.Counter()  # id(worker) -> its units in flight
        self._scenes: dict = {}  # id(scene) -> (scene, its object ref)
        self._started_total = 0
        self.units_done = 0  # units merged so far (all renders): tests and benches watch it
        self.units_retried = 0

    # ------------------------------------------------------------ the cluster

    def _connect(self):
        if self._ray is not None:
            return self._ray
        if self.address == "local":  # (read when Ray is imported, so set first)
            os.environ.setdefault("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", "0")
        ray = _import_ray()
        if not ray.is_initialized():
            import logging

            kw = dict(logging_level=logging.ERROR, log_to_driver=False)
            try:
                if self.address == "local":
                    # a local cluster is this machine's alone: bound to loopback, not the network address
                    ray.init(address="local", include_dashboard=False, _node_ip_address="127.0.0.1", **kw)
                else:
                    ray.init(address=self.address, **kw)
            except Exception as e:  # ConnectionError, RuntimeError, ValueError: Ray's own words, on one line
                where = "a local Ray cluster" if self.address == "local" else f"Ray at {self.address!r}"
                raise RenderError(f"cannot start {where}: {' '.join(str(e).split())[:300]}") from None
            self._started_ray = True
        self._ray = ray
        return ray

    def _worker_count(self) -> int:
        if self.requested_workers is not None:
            return self.requested_workers
        res = self._ray.cluster_resources()
        if self.gpus_per_worker > 0:
            return max(1, int(res.get("GPU", 0) // self.gpus_per_worker))
        return max(1, int(res.get("CPU", 1) // self.cpus_per_worker))

    def _start_worker(self) -> None:
        cls = _remote_worker(self._ray)
        actor = cls.options(num_cpus=self.cpus_per_worker, num_gpus=self.gpus_per_worker).remote()
        self._starting[actor.pid.remote()] = actor
        self._started_total += 1

    def _ensure_workers(self) -> None:
        self._connect()
        if not self._actors and not self._starting:
            for _ in range(self._worker_count()):
                self._start_worker()
        self._admit(timeout=0)
        if not self._actors:
            self._admit(timeout=self.start_timeout, need_one=True)

    def _admit(self, timeout: float, need_one: bool = False) -> None:
        """Move workers that have started to the live list; with ``need_one``, wait up to ``timeout`` for one."""
        ray = self._ray
        if not self._starting:
            if need_one:
                raise RenderError("no Ray worker is left to render on")
            return
        ready, _ = ray.wait(list(self._starting), num_returns=1 if need_one else len(self._starting),
                            timeout=timeout)
        for ref in ready:
            actor = self._starting.pop(ref)
            try:
                ray.get(ref)
                self._actors.append(actor)
            except Exception:
                pass  # died while starting: ignored, another is started when work is requeued
        if need_one and not self._actors:
            res = {k: v for k, v in ray.cluster_resources().items() if k in ("CPU", "GPU")}
            wanted = f"{self.cpus_per_worker:g} CPU" + (f" and {self.gpus_per_worker:g} GPU"
                                                        if self.gpus_per_worker else "")
            raise RenderError(f"no Ray worker could start within {self.start_timeout:g} s: each needs {wanted}, "
                              f"the cluster has {res or 'no resources'}")

    def worker_pids(self) -> list[int]:
        """Process ids of the live workers (tests kill them to check that a render survives)."""
        ray = self._connect()
        return ray.get([a.pid.remote() for a in self._actors])

    @property
    def workers(self) -> int:
        return len(self._actors)

    def scene_ref(self, scene):
        """The scene in Ray's object store, put there once per scene object."""
        self._connect()
        entry = self._scenes.get(id(scene))
        if entry is None or entry[0] is not scene:
            entry = (scene, self._ray.put(scene))
            self._scenes[id(scene)] = entry
        return entry[1]

    def close(self) -> None:
        """Stop the workers, and Ray itself if this executor started it."""
        ray, self._ray = self._ray, None
        if ray is None:
            return
        for actor in self._actors + list(self._starting.values()):
            try:
                ray.kill(actor)
            except Exception:
                pass
        self._actors, self._starting, self._scenes = [], {}, {}
        if self._started_ray:
            ray.shutdown()
            self._started_ray = False

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False

    # ------------------------------------------------------------ rendering

    def renderer(self, scene, **opts) -> "FarmRenderer":
        """The Ray counterpart of ``Renderer(scene, **opts)`` (what ``render(executor=...)`` renders with)."""
        if opts.get("threads") is None:
            opts["threads"] = max(1, int(self.cpus_per_worker))
        if opts.get("device") is None:
            opts["device"] = "cuda" if self.gpus_per_worker > 0 else "cpu"
        return FarmRenderer(self, scene, opts)

    def call(self, method: str, key, scene, opts, *args):
        """One call on a live worker, retried on another if that worker dies (the render's options are checked
        here: a RenderError in a worker is raised as it is)."""
        ray = self._connect()
        box = [self.scene_ref(scene)]
        while True:
            self._ensure_workers()
            actor = self._actors[0]
            try:
                return ray.get(getattr(actor, method).remote(key, box, opts, *args))
            except ray.exceptions.RayActorError:
                self._lost(actor)
            except ray.exceptions.ObjectLostError:
                continue  # the answer died with its node; asked again (a dead actor then says so)
            except ray.exceptions.RayTaskError as e:
                raise _as_render_error(_cause(e)) from None

    def _lost(self, actor) -> None:
        self._load.pop(id(actor), None)
        if actor in self._actors:
            self._actors.remove(actor)
            if self._started_total < 4 * max(1, self._worker_count()) + 4:
                self._start_worker()  # a replacement, used once it has started (it may never: a removed node)

    def issue(self, fr: "FarmRenderer", film: "FarmFilm", horizon: int) -> None:
        """Hand out units of ``film`` up to pass ``horizon`` to the least busy workers, ``in_flight`` at most each
        (over every film: the pilot's two candidates share the workers)."""
        box = None
        while True:
            idle = [a for a in self._actors if self._load[id(a)] < self.in_flight]
            if not idle:
                return
            unit = film.next_unit(horizon)
            if unit is None:
                return
            actor = min(idle, key=lambda a: self._load[id(a)])
            box = box or [self.scene_ref(fr.scene)]
            film.flying[actor.render.remote(fr.key, box, fr.opts, film.seed, *unit)] = (actor, unit)
            self._load[id(actor)] += 1

    def landed(self, actor) -> None:
        """A unit of ``actor``'s is back (or dropped)."""
        if self._load[id(actor)] > 0:
            self._load[id(actor)] -= 1

    def pump(self, fr: "FarmRenderer", film: "FarmFilm", target: int, horizon: int, joined) -> None:
        """Keep the workers busy with units of ``film`` up to pass ``horizon`` until the film holds the passes
        before ``target``; ``joined(n)`` is told of passes as they join the film. Units still flying when it
        returns stay in flight for the next call (``FarmFilm.close`` drops them)."""
        ray = self._connect()
        while film.next_pass < target:
            if film.flying:
                self._admit(timeout=0)  # replacements that have started since
            else:
                self._ensure_workers()
            self.issue(fr, film, horizon)
            if not film.flying:
                raise RenderError("no unit of passes is left to render (the film is past its bound)")
            ready, _ = ray.wait(list(film.flying), num_returns=1)
            for ref in ready:
                actor, unit = film.flying.pop(ref)
                self.landed(actor)
                try:
                    sums = ray.get(ref)
                except ray.exceptions.RayActorError:
                    self._lost(actor)
                    lost = [film.flying.pop(r)[1] for r, (a, _) in list(film.flying.items()) if a is actor]
                    self.units_retried += film.retry([unit, *lost])
                    continue
                except ray.exceptions.ObjectLostError:
                    # the unit was rendered, but its sums were on a node that left before we fetched them (an
                    # actor's task is not re-run to rebuild them: ObjectReconstructionFailedError): render it
                    # again; if its actor died with the node, its next task says so (RayActorError above)
                    self.units_retried += film.retry([unit])
                    continue
                except ray.exceptions.RayTaskError as e:
                    raise _as_render_error(_cause(e)) from None
                self.units_done += 1
                n = film.add_unit(unit[0], sums)
                if n:
                    joined(n)


def _as_render_error(e: BaseException) -> BaseException:
    from pathtracer.errors import PathtracerError

    if isinstance(e, PathtracerError):
        return e
    return RenderError(f"a Ray worker failed: {type(e).__name__}: {' '.join(str(e).split())[:300]}")


class FarmFilm:
    """A film whose passes are rendered on the farm: the units' sums added in pass order on the host, and the
    units of it in flight. ``horizon``: the last pass (exclusive) the render may reach (its spp), which lets the
    farm render ahead of what the job has asked for so far."""

    def __init__(self, renderer: "FarmRenderer"):
        self.renderer = renderer
        self.merged: PassSum | None = None
        self.pending: dict[int, PassSum] = {}  # units that arrived before the ones in front of them
        self.passes = 0
        self.next_pass = 0
        self.seconds = 0.0  # wall time of the driver's calls (the workers' own seconds overlap)
        self.seed: int | None = None
        self.horizon = 0
        self.issued = None  # the end of the last unit handed out
        self.flying: dict = {}  # ray ref -> (worker, unit)
        self.requeue: list[tuple[int, int]] = []  # units of a dead worker, handed out again first

    def next_unit(self, horizon: int) -> tuple[int, int] | None:
        """The next unit to hand out: a requeued one, else the one after the last, cut at the multiples of
        ``unit_passes`` (and at ``horizon``)."""
        if self.requeue:
            return self.requeue.pop(0)
        p = self.next_pass if self.issued is None else self.issued
        if p >= horizon:
            return None
        u = self.renderer.unit_passes
        q = min(horizon, (p // u + 1) * u)
        self.issued = q
        return p, q - p

    def retry(self, units: list[tuple[int, int]]) -> int:
        """Hand ``units`` out again before any new one, in pass order; returns how many."""
        self.requeue.extend(units)
        self.requeue.sort()
        return len(units)

    def add_unit(self, first: int, sums: PassSum) -> int:
        """Take a unit's sums; returns the passes that joined the film (0 until the units before it are in)."""
        if first < self.next_pass or first in self.pending:
            return 0  # a unit seen before (a retry): never counted twice
        self.pending[first] = sums
        joined = 0
        while self.next_pass in self.pending:
            unit = self.pending.pop(self.next_pass)
            self.merged = unit if self.merged is None else self.merged + unit
            self.next_pass += unit.passes
            self.passes += unit.passes
            joined += unit.passes
        return joined

    def sums(self) -> PassSum:
        if self.merged is None:
            return self.renderer.empty_sums()
        return dataclasses.replace(self.merged, seconds=self.seconds)

    def load(self, sums: PassSum, next_pass: int) -> None:
        s = self.renderer.scene
        if sums.sum.shape != (s.height, s.width, 3) or sums.rep_sum is None or \
                len(sums.rep_sum) != self.renderer.replicates:
            raise ValueError("the sums do not match this film")
        self.close()
        self.merged = dataclasses.replace(sums)
        self.pending, self.issued = {}, None
        self.passes, self.next_pass, self.seconds = sums.passes, next_pass, sums.seconds

    def close(self) -> None:
        """Drop the units still in flight (rendered ahead of a render that has stopped)."""
        flying, self.flying = self.flying, {}
        ex = self.renderer.executor
        if flying and ex._ray is not None:
            for ref, (actor, _) in flying.items():
                ex.landed(actor)
                try:
                    ex._ray.cancel(ref)
                except Exception:
                    pass
        self.requeue = []
        self.issued = None


class FarmRenderer:
    """What the render job needs of a ``Renderer`` (new_film, render_into, the resolved options), on the farm."""

    stops_mid_call = False  # a job looks at its stop flag between calls (units), not within one

    def __init__(self, executor: RayExecutor, scene, opts: dict):
        self.executor, self.scene, self.opts = executor, scene, dict(opts)
        self.key = (id(scene), tuple(sorted((k, repr(v)) for k, v in self.opts.items())))
        info = executor.call("describe", self.key, scene, self.opts)
        self.threads_per_worker = info.pop("threads")
        for k, v in info.items():
            setattr(self, k, v)
        self.unit_passes = max(executor.unit_min_passes, executor.unit_samples // (scene.width * scene.height))

    @property
    def workers(self) -> int:
        return self.executor.workers

    @property
    def threads(self) -> int:
        return self.executor.workers * self.threads_per_worker

    def new_film(self) -> FarmFilm:
        return FarmFilm(self)

    def empty_sums(self) -> PassSum:
        shape = (self.scene.height, self.scene.width, 3)
        z = np.zeros(shape)
        lt = self.light_tracing
        return PassSum(z, z.copy(), 0, rep_sum=np.zeros((self.replicates,) + shape),
                       rep_passes=np.zeros(self.replicates, dtype=np.int64),
                       estimator="replicates" if self.sampler == "sobol" else "passes",
                       lt_sum=z.copy() if lt else None, lt_sum_sq=z.copy() if lt else None,
                       m2_sum=z.copy() if self.moments else None)

    def step_passes(self, first: int) -> int:
        """The fewest passes a call from ``first`` waits for: those up to the end of their unit."""
        return self.unit_passes - first % self.unit_passes

    def align_passes(self, first: int, count: int, left: int, fit: int | None = None) -> int:
        """The passes the job's next call waits for: ``count`` rounded up to end on a unit boundary, at most
        ``left``; ``fit``, the passes a time budget has room for, rounds it down instead (but not below the next
        boundary)."""
        u = self.unit_passes
        end = -(-(first + max(count, 1)) // u) * u
        if fit is not None:
            end = min(end, max((first + fit) // u * u, (first // u + 1) * u))
        return min(end - first, left)

    def start(self, film: FarmFilm, seed: int, first_pass: int, count: int) -> None:
        """Hand out the units of passes ``first_pass ..`` (``count``) without waiting for them (``render_into``
        then collects them): the pilot starts both of its candidates this way, so that they run side by side."""
        self._begin(film, seed, first_pass)
        film.horizon = max(film.horizon, first_pass + count)
        self.executor._ensure_workers()
        self.executor.issue(self, film, film.horizon)

    def _begin(self, film: FarmFilm, seed: int, first_pass: int) -> None:
        if film.passes and first_pass != film.next_pass:
            raise RenderError(f"the film holds passes up to {film.next_pass - 1}: it continues with pass "
                              f"{film.next_pass}, not {first_pass}")
        if film.seed is not None and film.seed != seed:
            raise RenderError("a film continues with the seed it was started with")
        if not film.passes and film.issued is None:
            film.next_pass = first_pass
        film.seed = seed

    def render_into(self, film: FarmFilm, seed: int, first_pass: int, count: int, progress=False,
                    callback=None, stop=None) -> int:
        """Add passes ``first_pass .. first_pass + count - 1`` to ``film`` (and maybe more, rendered ahead up to
        ``film.horizon``); returns the passes added. ``stop`` is accepted and not looked at (``stops_mid_call``)."""
        if callback is not None:
            raise RenderError("a per-pass callback is not available on the Ray executor")
        self._begin(film, seed, first_pass)
        bar = progress if progress and progress is not True else None
        t0 = time.perf_counter()
        before = film.passes
        target = first_pass + count
        self.executor.pump(self, film, target, max(target, film.horizon),
                           (lambda n: bar.update(n)) if bar is not None else (lambda n: None))
        film.seconds += time.perf_counter() - t0
        return film.passes - before

    def close(self) -> None:
        pass  # the workers belong to the executor, which may render more scenes
