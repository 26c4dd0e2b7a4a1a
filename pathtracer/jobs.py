"""Render jobs: a render stopped by a sample count, a time or an error budget, saved as it goes to a checkpoint
that is written atomically, and resumed bit for bit.

A render is the passes 0, 1, 2, ... of one seed, each added to the film's float64 sums in pass order by the render
kernel (pathtracer/film.py). The job renders them in units (runs of consecutive passes) and, between units, checks
its budgets, writes the checkpoint and the preview, and looks at the stop flag that SIGINT and SIGTERM set. A
checkpoint holds the sums after a unit and the next pass; loaded back, the kernel continues the same additions in
the same order, so a resumed render is bit-identical to one that never stopped. Unit sizes change nothing in the
image: they only set how often the job looks up.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import signal
import threading
import time
import zipfile
from dataclasses import dataclass, field

import numpy as np

from pathtracer.errors import RenderError
from pathtracer.film import PassSum

CHECKPOINT_FORMAT = "pathtracer-checkpoint"
CHECKPOINT_VERSION = 1
UNIT_SECONDS = 1.0  # a unit's target length when the job must look up between units (budgets, checkpoints, signals)
FIRST_UNIT_SAMPLES = 1 << 14  # the first unit, before the time per pass is known
MIN_TARGET_PASSES = 16  # a target error may stop the render only after this many passes (and 4 per replicate)
MAX_PASSES = 2**32 - 1
TARGET_STEP_FRACTION = 16  # near a target error, a unit adds at least 1/16 of the passes so far


class CheckpointError(RenderError):
    """A checkpoint that cannot be used: missing, corrupt, truncated, or from another scene or configuration."""


@dataclass
class Budget:
    """When to stop: the first bound reached. ``spp`` is always a bound (the most passes); ``seconds`` the render
    time (pilot included, compilation and set-up not); ``target_error`` the image's estimated relMSE
    (``PassSum.relmse_estimate``), checked once ``min_passes`` are done."""

    spp: int
    seconds: float | None = None
    target_error: float | None = None
    min_passes: int = MIN_TARGET_PASSES


class Interrupted(KeyboardInterrupt):
    """SIGINT or SIGTERM before rendering started (nothing to save yet): ``signum`` says which."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum


@dataclass
class StopFlag:
    """Set by a signal handler (``handle_signals``) or by the caller; the job stops after the passes it has started
    (a local renderer: at its next pass; the Ray farm: after its current unit).
    ``armed`` while a job renders: before that a signal interrupts at once (``Interrupted``), as there is nothing
    to save yet."""

    signum: int | None = None
    event: threading.Event = field(default_factory=threading.Event)
    armed: bool = False

    def set(self, signum: int | None = None) -> None:
        self.signum = signum
        self.event.set()

    def is_set(self) -> bool:
        return self.event.is_set()


class handle_signals:
    """While active: SIGINT and SIGTERM set ``flag`` instead of killing the process (the job then stops after its
    unit, writes its checkpoint and returns what it has). Main thread only; elsewhere it does nothing."""

    def __init__(self, flag: StopFlag):
        self.flag = flag
        self.previous: dict = {}

    def __enter__(self):
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                self.previous[sig] = signal.signal(sig, self._handle)
        return self.flag

    def _handle(self, signum, frame):
        if not self.flag.armed:
            raise Interrupted(signum)
        self.flag.set(signum)

    def __exit__(self, *exc):
        for sig, handler in self.previous.items():
            signal.signal(sig, handler)
        return False


# ---------------------------------------------------------------- the scene's identity


def _feed(h, value) -> None:
    """A canonical encoding of a scene's data: dataclass fields in order, arrays by dtype, shape and bytes."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        h.update(type(value).__name__.encode())
        for f in dataclasses.fields(value):
            if f.name in ("source", "spp", "sampler_seed"):  # where it was read from, and budgets given elsewhere
                continue
            h.update(f.name.encode())
            _feed(h, getattr(value, f.name))
    elif isinstance(value, np.ndarray):
        a = np.ascontiguousarray(value)
        h.update(f"{a.dtype.str}{a.shape}".encode())
        h.update(a.tobytes())
    elif isinstance(value, (list, tuple)):
        h.update(f"[{len(value)}".encode())
        for v in value:
            _feed(h, v)
    elif isinstance(value, dict):
        h.update(f"{{{len(value)}".encode())
        for k in sorted(value, key=str):
            _feed(h, k)
            _feed(h, value[k])
    else:
        h.update(repr(value).encode())


def scene_hash(scene) -> str:
    """sha256 of everything in the loaded scene that changes the image (not its file name, spp or seed)."""
    h = hashlib.sha256()
    _feed(h, scene)
    return h.hexdigest()


# ---------------------------------------------------------------- checkpoints

_ARRAYS = ("sum", "sum_sq", "rep_sum", "rep_passes", "m2_sum", "lt_sum", "lt_sum_sq", "counts")


def _digest(arrays: dict) -> str:
    h = hashlib.sha256()
    for k in sorted(arrays):
        a = np.ascontiguousarray(arrays[k])
        h.update(f"{k}{a.dtype.str}{a.shape}".encode())
        h.update(a.tobytes())
    return h.hexdigest()


PILOT_B = "pilot_b_"  # a checkpoint taken during the auto pilot: the light-tracing candidate's arrays, so prefixed


def _sums_arrays(sums: PassSum, prefix: str = "") -> dict:
    return {prefix + k: getattr(sums, k) for k in _ARRAYS if getattr(sums, k) is not None}


def _sums_meta(sums: PassSum, next_pass: int) -> dict:
    return {"next_pass": next_pass, "passes": sums.passes, "discarded": sums.discarded, "seconds": sums.seconds,
            "rays": sums.rays, "estimator": sums.estimator}


def _sums_from(meta: dict, data: dict, prefix: str = "") -> tuple[PassSum, int]:
    get = lambda k: data.get(prefix + k)  # noqa: E731
    sums = PassSum(data[prefix + "sum"], data[prefix + "sum_sq"], int(meta["passes"]), int(meta["discarded"]),
                   float(meta["seconds"]), int(meta["rays"]), get("lt_sum"), get("lt_sum_sq"), get("rep_sum"),
                   get("rep_passes"), str(meta["estimator"]), get("m2_sum"), get("counts"))
    return sums, int(meta["next_pass"])


def write_checkpoint(path: str | os.PathLike, sums: PassSum, next_pass: int, config: dict,
                     pilot_b: tuple[PassSum, int] | None = None) -> None:
    """The sums, the next pass and the configuration, written to a temporary file in the same folder, flushed to
    disk and renamed over ``path``: the previous checkpoint stays whole until the new one is.

    ``pilot_b``: a checkpoint of an unfinished auto pilot (``sums`` are then the path-tracing candidate's): the
    light-tracing candidate's sums and next pass, so that a resume finishes the pilot and decides as a render
    without the interruption would have."""
    path = os.fspath(path)
    arrays = _sums_arrays(sums)
    meta = {"format": CHECKPOINT_FORMAT, "version": CHECKPOINT_VERSION, "config": config,
            **_sums_meta(sums, next_pass)}
    if pilot_b is not None:
        arrays.update(_sums_arrays(pilot_b[0], PILOT_B))
        meta["pilot_b"] = _sums_meta(*pilot_b)
    meta["digest"] = _digest(arrays)
    directory, name = os.path.split(os.path.abspath(path))
    tmp = os.path.join(directory, f".{name}.{os.getpid()}.tmp")
    try:
        with open(tmp, "wb") as f:
            np.savez(f, meta=np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8), **arrays)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
        try:  # the rename itself survives a crash only once the folder is flushed too
            fd = os.open(directory, os.O_RDONLY)
            try:
                os.fsync(fd)
            finally:
                os.close(fd)
        except OSError:
            pass
    except OSError as e:
        try:
            os.remove(tmp)
        except OSError:
            pass
        raise RenderError(f"{path}: cannot write checkpoint: {e.strerror or e}") from None


def checkpoint_config(path: str | os.PathLike) -> dict:
    """The configuration a checkpoint was made with, read without its sums (CheckpointError as ``read_checkpoint``)."""
    return _load(os.fspath(path), meta_only=True)[0]["config"]


def read_checkpoint(path: str | os.PathLike, with_pilot: bool = False):
    """(sums, next pass, configuration) of a checkpoint; CheckpointError (one line) if it cannot be used.

    ``with_pilot``: a fourth item, the light-tracing candidate's (sums, next pass) when the checkpoint was taken
    during the auto pilot (``write_checkpoint``'s ``pilot_b``), else None."""
    path = os.fspath(path)
    meta, data = _load(path)
    try:
        if _digest(data) != meta["digest"]:
            raise CheckpointError(f"{path}: checkpoint is corrupt (its sums do not match their checksum)")
        sums, next_pass = _sums_from(meta, data)
        pilot_b = _sums_from(meta["pilot_b"], data, PILOT_B) if "pilot_b" in meta else None
        if with_pilot:
            return sums, next_pass, dict(meta["config"]), pilot_b
        return sums, next_pass, dict(meta["config"])
    except CheckpointError:
        raise
    except (KeyError, TypeError, ValueError) as e:
        raise CheckpointError(f"{path}: checkpoint is corrupt ({type(e).__name__}: {e})") from None


def _load(path: str, meta_only: bool = False) -> tuple[dict, dict]:
    """A checkpoint's checked header and (unless ``meta_only``) its arrays."""
    try:
        with np.load(path, allow_pickle=False) as z:
            data = {k: z[k] for k in (["meta"] if meta_only else z.files)}
        meta = json.loads(bytes(data.pop("meta")).decode())
    except FileNotFoundError:
        raise CheckpointError(f"{path}: no checkpoint to resume from (no such file)") from None
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile, UnicodeDecodeError) as e:
        raise CheckpointError(f"{path}: checkpoint is corrupt or truncated ({type(e).__name__})") from None
    if not isinstance(meta, dict) or meta.get("format") != CHECKPOINT_FORMAT:
        raise CheckpointError(f"{path}: not a pathtracer checkpoint")
    if meta.get("version") != CHECKPOINT_VERSION:
        raise CheckpointError(f"{path}: checkpoint version {meta.get('version')} (this pathtracer reads "
                              f"{CHECKPOINT_VERSION})")
    if not isinstance(meta.get("config"), dict):
        raise CheckpointError(f"{path}: checkpoint is corrupt (no configuration)")
    return meta, data


def check_config(path: str, saved: dict, wanted: dict) -> None:
    """Refuse a checkpoint made for another scene or configuration, naming the first difference."""
    if saved.get("scene_hash") != wanted.get("scene_hash"):
        raise CheckpointError(f"{path}: checkpoint is of another scene (or the scene has changed since)")
    for k in sorted(set(saved) | set(wanted)):
        if k in ("scene_hash", "light_tracing", "pilot", "unit_passes"):  # (unit_passes: see ray_executor.py)
            continue
        if saved.get(k) != wanted.get(k):
            raise CheckpointError(f"{path}: checkpoint was made with {k} = {saved.get(k)!r}, this render has "
                                  f"{wanted.get(k)!r}")


# ---------------------------------------------------------------- the job


@dataclass
class Outcome:
    """What a job rendered and why it stopped: "spp", "time", "target_error" or "interrupted"."""

    sums: PassSum
    stop_reason: str
    config: dict
    extra_seconds: float = 0.0  # rendering that is not in the image (the pilot's loser)
    resumed_passes: int = 0  # passes that came from the checkpoint


def _pixels(scene) -> int:
    return scene.width * scene.height


def run_job(path_renderer, traced_renderer, seed: int, budget: Budget, *, pilot_spp: int,
            checkpoint: str | None = None, checkpoint_every: float = 30.0, resume: bool = False,
            preview=None, preview_every: float | None = None, stop: StopFlag | None = None,
            progress=False, base_config: dict | None = None, adaptive=None) -> Outcome:
    """Render until a bound of ``budget`` is reached or ``stop`` is set.

    ``traced_renderer``: the light-tracing candidate when the auto estimator may pick it (else None): the pilot
    (pathtracer/estimator.py, sized from ``pilot_spp``) decides, and its winner's passes continue. ``checkpoint``:
    written every ``checkpoint_every`` seconds and at the end; with ``resume`` the job continues from it (refused if
    it belongs to another scene or configuration). ``preview(sums)`` is called every ``preview_every`` seconds.
    ``adaptive``: a ``pathtracer.adaptive.Adaptive`` stops pixels at its decision passes (the renderer must have
    been made with ``adaptive=True``); when every pixel has stopped the render does too ("converged").
    """
    if stop is not None:
        stop.armed = True
    try:
        return _run_job(path_renderer, traced_renderer, seed, budget, pilot_spp, checkpoint, checkpoint_every,
                        resume, preview, preview_every, stop, progress, base_config, adaptive)
    finally:
        if stop is not None:
            stop.armed = False


def _run_job(path_renderer, traced_renderer, seed, budget, pilot_spp, checkpoint, checkpoint_every, resume,
             preview, preview_every, stop, progress, base_config, adaptive) -> Outcome:
    from pathtracer import estimator

    config = dict(base_config or {})
    # a job cut into units of about a second: for what needs a look between them (a local renderer looks at the
    # stop flag within a call: units would cost it a barrier each, 13% of a 2-thread teapot render at 16 spp)
    looks_up = (budget.seconds is not None or budget.target_error is not None or checkpoint is not None
                or preview is not None
                or (stop is not None and not getattr(path_renderer, "stops_mid_call", False)))
    t_start = time.perf_counter()
    extra_seconds = 0.0
    resumed = 0
    renderer, film, run_seed = path_renderer, None, seed

    pilot_films, pilot_size = None, None  # a resumed pilot's two films and passes per candidate
    if resume:
        if checkpoint is None:
            raise RenderError("resume needs a checkpoint path")
        sums, next_pass, saved, pilot_b = read_checkpoint(checkpoint, with_pilot=True)
        check_config(checkpoint, saved, config)
        if pilot_b is not None:  # taken during the auto pilot: the pilot goes on below
            if traced_renderer is None:
                raise CheckpointError(f"{checkpoint}: checkpoint was made during the light-tracing pilot, which "
                                      f"this render does not run")
            pilot_films = (path_renderer.new_film(), traced_renderer.new_film())
            pilot_resumed = {"path": sums.passes, "light_tracing": pilot_b[0].passes}
            # the pilot's size as it began (a resume with another spp must not change the decision's inputs)
            pilot_size = int(saved.get("pilot", {}).get("passes_each", 0)) or None
            for f, (s_, n_) in zip(pilot_films, ((sums, next_pass), pilot_b)):
                if s_.passes:
                    _load_film(f, s_, n_, checkpoint)
            resume = False
    if resume:
        if saved.get("light_tracing") and not path_renderer.light_tracing:  # auto chose light tracing
            if traced_renderer is None:
                raise CheckpointError(f"{checkpoint}: checkpoint was made with light tracing, which this render "
                                      f"does not use")
            renderer, run_seed = traced_renderer, estimator.pilot_seed(seed)
        if sums.passes > budget.spp:
            raise CheckpointError(f"{checkpoint}: checkpoint holds {sums.passes} passes, more than the {budget.spp} "
                                  f"asked for")
        film = renderer.new_film()
        _load_film(film, sums, next_pass, checkpoint)
        config["light_tracing"] = bool(saved.get("light_tracing"))
        if "pilot" in saved:
            config["pilot"] = saved["pilot"]
        resumed = sums.passes
    elif traced_renderer is not None:  # (the caller checked that pilot_spp leaves room for a pilot)
        pilot = estimator.run_pilot(path_renderer, traced_renderer, seed, pilot_spp, progress, stop=stop,
                                    films=pilot_films, passes=pilot_size)
        if pilot_films is not None:  # the image's passes that came from the checkpoint
            resumed = pilot_resumed[pilot.winner] if pilot.finished else pilot_resumed["path"]
        if not pilot.finished:  # stopped: both candidates' passes kept for a resume, candidate A's as the image
            return _unfinished_pilot(pilot, checkpoint, dict(config, **pilot.config), resumed)
        config.update(pilot.config)
        film = pilot.films[pilot.winner]
        extra_seconds = pilot.films[pilot.loser].seconds
        if hasattr(pilot.films[pilot.loser], "close"):
            pilot.films[pilot.loser].close()
        if pilot.use_light_tracing:
            renderer, run_seed = traced_renderer, pilot.seeds["light_tracing"]
    else:
        film = path_renderer.new_film()
        config["light_tracing"] = bool(path_renderer.light_tracing)

    if hasattr(film, "horizon"):  # the Ray farm renders ahead, up to the bound (pathtracer/ray_executor.py)
        film.horizon = budget.spp
    try:
        return _loop(renderer, film, run_seed, budget, checkpoint, checkpoint_every, preview, preview_every,
                     stop, progress, config, looks_up, t_start, extra_seconds, resumed, adaptive)
    finally:
        if hasattr(film, "close"):
            film.close()


def _load_film(film, sums: PassSum, next_pass: int, checkpoint: str) -> None:
    try:
        film.load(sums, next_pass)
    except ValueError as e:
        raise CheckpointError(f"{checkpoint}: {e}") from None


def _unfinished_pilot(pilot, checkpoint, config, resumed) -> Outcome:
    """A job stopped during its pilot: path tracing's passes so far are the image (the light-tracing candidate's,
    rendered after them, count as extra time), and the checkpoint keeps both for a resume to finish the pilot."""
    fa, fb = pilot.films["path"], pilot.films["light_tracing"]
    a, b = fa.sums(), fb.sums()
    if checkpoint is not None:
        write_checkpoint(checkpoint, a, fa.next_pass, config, pilot_b=(b, fb.next_pass))
    for f in (fa, fb):
        if hasattr(f, "close"):
            f.close()
    return Outcome(a, "interrupted", config, b.seconds, resumed)


def _loop(renderer, film, run_seed, budget, checkpoint, checkpoint_every, preview, preview_every, stop,
          progress, config, looks_up, t_start, extra_seconds, resumed, adaptive) -> Outcome:
    stop_reason = "spp"
    last_checkpoint = last_preview = t_loop = time.perf_counter()
    passes_at_loop = film.passes
    sec_per_pass = None
    estimate = None  # the last relmse_estimate, with a target error
    decided = None  # the pass of the last adaptive decision
    step = getattr(renderer, "step_passes", None)  # the least a call can render: a pass, or to a unit's end
    unit_sums = None  # one host copy of the film per unit, shared by whatever needs it until the next unit

    def sums() -> PassSum:
        nonlocal unit_sums
        if unit_sums is None:
            unit_sums = film.sums()
        return unit_sums

    while True:
        if film.passes >= budget.spp:
            stop_reason = "spp"
            break
        if stop is not None and stop.is_set():
            stop_reason = "interrupted"
            break
        if adaptive is not None:
            # decided before the pass is rendered, from the sums up to it: a resume at this pass decides again,
            # from the same sums, the same way
            if adaptive.is_decision(film.next_pass) and decided != film.next_pass:
                film.set_limits(adaptive.decide(sums(), film.limits, film.next_pass))  # (counts unchanged)
                decided = film.next_pass
            if int(film.limits.max()) <= film.next_pass:
                stop_reason = "converged"  # every pixel has stopped
                break
        elapsed = time.perf_counter() - t_start
        left = budget.spp - film.passes
        least = 1 if step is None else step(film.next_pass)
        if budget.seconds is not None and sec_per_pass is not None and \
                elapsed + least * sec_per_pass > budget.seconds:
            stop_reason = "time"
            break
        n = left
        if looks_up:
            if sec_per_pass is None:
                n = max(1, FIRST_UNIT_SAMPLES // _pixels(renderer.scene))
            else:
                slice_s = UNIT_SECONDS
                if checkpoint is not None:
                    slice_s = min(slice_s, checkpoint_every)
                if preview is not None and preview_every is not None:
                    slice_s = min(slice_s, preview_every)
                if budget.seconds is not None:
                    slice_s = min(slice_s, budget.seconds - elapsed)
                n = max(1, int(slice_s / sec_per_pass))
            if budget.target_error is not None:
                # relMSE falls as 1/passes: go about as far as the target needs, then look again (a unit of a
                # second overshoots a small image's target by hundreds of passes); before the first estimate, up
                # to the first passes it may be made at, or double the passes so far
                if estimate is None:
                    first_check = max(budget.min_passes, 4 * renderer.replicates)
                    n = min(n, max(first_check - film.passes, film.passes, 1))
                else:
                    needed = int(np.ceil(film.passes * estimate / budget.target_error)) - film.passes
                    n = min(n, max(needed, film.passes // TARGET_STEP_FRACTION, 1))
            n = min(n, left)
        if adaptive is not None:  # a call ends where the next decision is made
            n = min(n, adaptive.next_decision(film.next_pass) - film.next_pass)
        align = getattr(renderer, "align_passes", None)  # the Ray farm's units: fixed by pass index
        if align is not None:
            fit = None
            if budget.seconds is not None and sec_per_pass is not None:
                fit = int((budget.seconds - elapsed) / sec_per_pass)
            n = align(film.next_pass, n, left, fit)
        renderer.render_into(film, run_seed, film.next_pass, n, progress, stop=stop)
        unit_sums = None
        now = time.perf_counter()
        # over the whole loop, not the last call: the farm's calls return early when units rendered ahead are in
        sec_per_pass = (now - t_loop) / max(film.passes - passes_at_loop, 1)
        done_target = False
        if budget.target_error is not None and film.passes >= max(budget.min_passes, 4 * renderer.replicates):
            estimate = sums().relmse_estimate
            done_target = estimate <= budget.target_error
        if checkpoint is not None and now - last_checkpoint >= checkpoint_every:
            write_checkpoint(checkpoint, sums(), film.next_pass, config)
            last_checkpoint = time.perf_counter()
        if preview is not None and preview_every is not None and now - last_preview >= preview_every:
            preview(sums())
            last_preview = time.perf_counter()
        if done_target:
            stop_reason = "target_error"
            break
    final = sums()
    if checkpoint is not None:
        write_checkpoint(checkpoint, final, film.next_pass, config)
    return Outcome(final, stop_reason, config, extra_seconds, resumed)


def film_bytes(width: int, height: int, replicates: int, moments: bool, light_tracing: bool) -> int:
    """Memory a render's film takes: float64 RGB sums on the device (sums, squares, one per replicate, moments,
    the light tracer's three) and about twice that on the host while the image and its error are made."""
    planes = 2 + replicates + int(moments) + 3 * int(light_tracing)
    return 3 * planes * width * height * 24


def available_memory() -> int | None:
    """Bytes of memory available to this process (Linux: MemAvailable), or None where unknown."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError):
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def human_bytes(n: float) -> str:
    for unit in ("B", "KB", "MB", "GB", "TB", "PB"):
        if n < 1000 or unit == "PB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1000.0
    return f"{n:.1f} PB"


def check_film_size(width: int, height: int, replicates: int, moments: bool, light_tracing: bool,
                    device: str) -> None:
    """Refuse, before anything is compiled or allocated, a film the machine cannot hold or Warp cannot index."""
    need = film_bytes(width, height, replicates, moments, light_tracing)
    if device == "cpu":
        have = available_memory()
    else:
        try:
            import warp as wp

            have = wp.get_device(device).free_memory
        except Exception:
            have = None
    if have is not None and need > have:
        raise RenderError(f"a {width}x{height} film needs about {human_bytes(need)} of memory for its sums, "
                          f"{'this machine' if device == 'cpu' else device} has {human_bytes(have)} available")
    pixels = width * height
    if replicates * pixels >= 2**31:
        raise RenderError(f"a {width}x{height} film has {pixels} pixels; with {replicates} replicates its sums "
                          f"need more than 2^31 entries, the most a Warp array can index")
