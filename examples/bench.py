"""Speed against error: render each seed scene over a ladder of sample counts and report error against seconds.

    python examples/bench.py                                  # all seed scenes, every configuration, markdown + plot
    python examples/bench.py --scenes cornell_box --quick     # one scene, a short ladder

For every configuration (light samples K, roulette rule, sampler, threads, and Mitsuba 3 on the same file when it
is installed) and every sample count of the ladder it measures seconds (compilation and JIT excluded), samples/s,
rays/s (ours: counted by a second, instrumented pass), relMSE against a reference, and efficiency =
1 / (relMSE x seconds). The reference is a long Mitsuba render when Mitsuba is installed (cached under
--ref-dir), else the committed tests/data/refs/*.exr at the same size, else a long render of our own.
"Time to 1e-3" extrapolates the last rung with relMSE proportional to 1/time (Monte Carlo's rate).

Writes <out>/performance.md (the table, the machine, the command) and <out>/performance.png (log-log plot).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import pathtracer  # noqa: E402

SCENES = ["cornell_box", "cornell_box_mirror", "teapot_in_box", "open_sky"]
TARGET = 1e-3


def rel_mse(img: np.ndarray, ref: np.ndarray) -> float:
    return float(np.mean((img - ref) ** 2 / (ref * ref + 0.01)))


def rel_mse_net(img: np.ndarray, ref: np.ndarray, ref_var: np.ndarray | None) -> float:
    """relMSE against the true image, from one against a reference whose own per-pixel variance of the mean is
    ``ref_var``: E[(img - ref)^2] = Var[img] + Var[ref] for independent unbiased estimates, so the reference's share
    is taken off (without it, a 16384-spp Mitsuba reference's noise was a third of what our 512-spp teapot with
    light tracing measured)."""
    if ref_var is None:
        return rel_mse(img, ref)
    return float(np.mean(((img - ref) ** 2 - ref_var) / (ref * ref + 0.01)))


def reference_variance(scene_name: str, w: int, h: int, ref_dir: Path, ref_spp: int) -> np.ndarray | None:
    """The per-pixel variance of the mean of a reference made by ``reference`` with Mitsuba (from the spread of its
    1024-spp chunks), or None for references made before it was kept."""
    path = Path(ref_dir) / f"{scene_name}_{w}x{h}_{ref_spp}_var.npy"
    return np.load(path) if path.exists() else None


@dataclass
class Config:
    label: str
    light_samples: int = 8
    rr: str = "throughput"
    sampler: str = "independent"
    threads: int | None = None
    mitsuba: bool = False
    light_tracing: bool = False
    defaults: bool = False  # pathtracer.render() with nothing set: Sobol', auto light tracing (pilot included)


@dataclass
class Row:
    scene: str
    config: str
    spp: int
    seconds: float
    relmse: float
    samples_per_s: float
    rays_per_s: float = float("nan")
    extra: dict = field(default_factory=dict)

    @property
    def efficiency(self) -> float:
        return 1.0 / (self.relmse * self.seconds)

    @property
    def time_to_target(self) -> float:
        return self.seconds * self.relmse / TARGET


def crossing_time(rows: list[Row], target: float = TARGET) -> tuple[float, str]:
    """Seconds at which one configuration's ladder reaches relMSE ``target``, and how it was found: interpolated
    on the log-log curve between the two rungs that bracket it (Sobol' converges faster than 1/t, so extrapolating
    from a far rung at Monte Carlo's rate would flatter it), else extrapolated from the nearest end at rate 1/t."""
    pts = sorted(rows, key=lambda r: r.spp)
    for a, b in zip(pts, pts[1:]):
        if a.relmse >= target >= b.relmse and a.relmse > b.relmse:
            f = np.log(a.relmse / target) / np.log(a.relmse / b.relmse)
            return float(np.exp(np.log(a.seconds) + f * np.log(b.seconds / a.seconds))), "interpolated"
    end = pts[-1] if pts[-1].relmse > target else pts[0]
    return end.seconds * end.relmse / target, "extrapolated"


DEFAULTS = "defaults (auto)"


def configs(quick: bool, have_mitsuba: bool, samplers: list[str]) -> list[Config]:
    out = [Config(DEFAULTS, defaults=True)]
    out += [Config(f"K={k}", light_samples=k) for k in ([1, 4, 8] if quick else [1, 2, 4, 8, 16])]
    out.append(Config("K=1 rr=seed", light_samples=1, rr="seed"))
    for s in samplers:
        if s != "independent":
            out += [Config(f"K={k} {s}", light_samples=k, sampler=s) for k in ([1, 8] if quick else [1, 2, 4, 8])]
    # light tracing: applies to the scenes with mirrors (elsewhere the same as the configuration without it)
    out.append(Config("K=1 lt", light_samples=1, light_tracing=True))
    for s in samplers:
        if s != "independent":
            out.append(Config(f"K=1 {s} lt", light_samples=1, sampler=s, light_tracing=True))
    if have_mitsuba:
        out.append(Config("mitsuba llvm_ad_rgb", mitsuba=True))
    return out


TIME_REPS = 3  # each rung is timed this many times (the same seed: the same image), the median is reported
THREAD_SPP = 128
THREAD_REPS = 15


def thread_scaling(scene_name: str, w: int, h: int, spp: int = THREAD_SPP, reps: int = THREAD_REPS
                   ) -> tuple[float, float, float]:
    """One thread against all cores, measured in pairs (one run each, back to back) in one process (same scene,
    seed and spp: the images are bit-identical). Returns the median seconds of each and the median of the pairs'
    ratios: this shared machine's neighbours slow some runs by up to 30%, and a pair mostly shares the disturbance."""
    scene = load(scene_name, w, h)
    rs = {t: pathtracer.Renderer(scene, threads=t) for t in (1, os.cpu_count() or 1)}
    for r in rs.values():
        r.render_passes(count=1)
    times = {t: [] for t in rs}
    for _ in range(reps):
        for t, r in rs.items():
            times[t].append(r.render_passes(seed=1, count=spp).seconds)
    one, alls = (float(np.median(v)) for v in times.values())
    ratio = float(np.median(np.divide(*times.values())))
    return one, alls, ratio


def load(scene: str, width: int, height: int):
    return pathtracer.load_file(ROOT / "scenes" / f"{scene}.xml", width=width, height=height)


def defaults_ladder(scene_name: str, ladder: list[int], ref: np.ndarray, w: int, h: int) -> list[Row]:
    """render() as a user calls it: its own choice of estimator, the pilot's passes and time included."""
    scene = load(scene_name, w, h)
    pathtracer.render(scene, spp=64, seed=3, progress=False)  # compile and load every variant it may pick
    rows = []
    for spp in ladder:
        runs = []
        for _ in range(TIME_REPS):
            st = {}
            img = pathtracer.render(scene, spp=spp, seed=1, progress=False, stats=st)
            runs.append((st["render_seconds"], img, st))
        seconds = float(np.median([x[0] for x in runs]))
        st = runs[0][2]
        rows.append(Row(scene_name, DEFAULTS, spp, seconds, rel_mse(runs[0][1], ref), spp * w * h / seconds,
                        extra={"relmse_estimate": st["relmse_estimate"], "config": st["config"]}))
    return rows


def ours_ladder(scene_name: str, cfg: Config, ladder: list[int], ref: np.ndarray, w: int, h: int) -> list[Row]:
    if cfg.defaults:
        return defaults_ladder(scene_name, ladder, ref, w, h)
    scene = load(scene_name, w, h)
    kwargs = dict(light_samples=cfg.light_samples, rr=cfg.rr, threads=cfg.threads, light_tracing=cfg.light_tracing,
                  sampler=cfg.sampler)
    r = pathtracer.Renderer(scene, **kwargs)
    rows = []
    for spp in ladder:
        runs = [r.render_passes(seed=1, first_pass=0, count=spp) for _ in range(TIME_REPS)]  # the same image each
        seconds = float(np.median([x.seconds for x in runs]))
        img = runs[0].mean
        paths = spp * w * h
        rows.append(Row(scene_name, cfg.label, spp, seconds, rel_mse(img, ref), paths / seconds,
                        extra={"compile_seconds": r.compile_seconds, "threads": r.threads}))
    # rays per path from an instrumented variant (same seed, so the same paths), then rays/s of the timed runs
    counted = pathtracer.Renderer(scene, count_rays=True, **kwargs).render_passes(seed=1, first_pass=0, count=4)
    rays_per_path = counted.rays / (4 * w * h)
    for row in rows:
        row.rays_per_s = row.samples_per_s * rays_per_path
        row.extra["rays_per_path"] = rays_per_path
    return rows


def mitsuba_ladder(scene_name: str, ladder: list[int], ref: np.ndarray, w: int, h: int) -> list[Row]:
    import mitsuba as mi

    scene = mi.load_file(str(ROOT / "scenes" / f"{scene_name}.xml"), width=str(w), height=str(h))
    rows = []
    for spp in ladder:
        np.array(mi.render(scene, spp=spp, seed=999))  # JIT warm-up for this size: not timed
        ts = []
        for _ in range(TIME_REPS):
            t0 = time.perf_counter()
            img = np.array(mi.render(scene, spp=spp, seed=1), dtype=np.float32)[..., :3]
            ts.append(time.perf_counter() - t0)
        t = float(np.median(ts))
        rows.append(Row(scene_name, "mitsuba llvm_ad_rgb", spp, t, rel_mse(img, ref), spp * w * h / t))
    return rows


def reference(scene_name: str, w: int, h: int, ref_dir: Path, ref_spp: int, have_mitsuba: bool) -> tuple[np.ndarray, str]:
    ref_dir.mkdir(parents=True, exist_ok=True)
    cached = ref_dir / f"{scene_name}_{w}x{h}_{ref_spp}.exr"
    if cached.exists():
        return pathtracer.read_image(cached), f"Mitsuba {ref_spp} spp (cached)"
    if have_mitsuba:
        import mitsuba as mi

        scene = mi.load_file(str(ROOT / "scenes" / f"{scene_name}.xml"), width=str(w), height=str(h))
        acc = np.zeros((h, w, 3))
        acc_sq = np.zeros((h, w, 3))
        chunk = 1024
        n = max(1, ref_spp // chunk)
        for i in range(n):
            part = np.array(mi.render(scene, spp=min(chunk, ref_spp), seed=10_000 + i), dtype=np.float64)[..., :3]
            acc += part
            acc_sq += part * part
        img = (acc / n).astype(np.float32)
        pathtracer.write_image(cached, img)
        if n >= 2:  # the chunks are independent: their spread gives the reference's own error
            np.save(ref_dir / f"{scene_name}_{w}x{h}_{ref_spp}_var.npy",
                    np.maximum(acc_sq / n - (acc / n) ** 2, 0.0) * n / (n - 1) / n)
        return img, f"Mitsuba {ref_spp} spp"
    committed = ROOT / "tests" / "data" / "refs" / f"{scene_name}.exr"
    if committed.exists():
        img = pathtracer.read_image(committed)
        if img.shape[:2] == (h, w):
            return img, "committed Mitsuba reference"
    scene = load(scene_name, w, h)
    img = pathtracer.render(scene, spp=ref_spp, seed=12345, progress=True)
    pathtracer.write_image(cached, img)
    return img, f"ours {ref_spp} spp"


COMPILE_PROBE = """
import sys, time
t0 = time.perf_counter()
import pathtracer
scene = pathtracer.load_file(sys.argv[1], width=8, height=6)
r = pathtracer.Renderer(scene)
print(r.compile_seconds, time.perf_counter() - t0)
"""


def compile_times(scenes: list[str]) -> list[tuple[str, float, float, float]]:
    """(scene, cold compile s, warm load s, warm process start-to-ready s), each in a fresh process with an
    empty kernel cache for the cold run."""
    import subprocess
    import tempfile

    out = []
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, WARP_CACHE_PATH=cache, PYTHONPATH=str(ROOT))
        for s in scenes:
            path = str(ROOT / "scenes" / f"{s}.xml")
            runs = []
            for _ in range(2):  # cold, then warm
                r = subprocess.run([sys.executable, "-c", COMPILE_PROBE, path], env=env, capture_output=True,
                                   text=True, check=True)
                runs.append([float(x) for x in r.stdout.split()[-2:]])
            out.append((s, runs[0][0], runs[1][0], runs[1][1]))
    return out


MITSUBA_PROCESS = """
import sys
import mitsuba as mi
mi.set_variant("llvm_ad_rgb")
scene = mi.load_file(sys.argv[1], width=int(sys.argv[3]), height=int(sys.argv[4]), spp=int(sys.argv[5]))
mi.util.write_bitmap(sys.argv[2], mi.render(scene))
"""


def whole_process(scene_name: str, ref: np.ndarray, w: int, h: int, spp: int, reps: int, have_mitsuba: bool,
                  tmp: Path) -> dict:
    """Python start to file written, for each renderer on the same file (the issue's measure): our CLI with its
    defaults and Mitsuba 3 in a script of its own, alternately, ``reps`` times; median seconds, relMSE of the
    image, efficiency = 1 / (relMSE x seconds)."""
    import subprocess

    path = str(ROOT / "scenes" / f"{scene_name}.xml")
    # Python's bytecode cache warm too, as an installed package's is (pip compiles it when it installs; a source
    # tree writes it on its first run) and as the kernel caches are: where PYTHONDONTWRITEBYTECODE is set (this
    # project's machines set it), every run of the tree compiled our ~12k lines of Python again, 70 ms on the
    # Cornell box. "ours_no_bytecode" is that run, kept for comparison.
    env = dict(os.environ, PYTHONPATH=str(ROOT), PYTHONPYCACHEPREFIX=str(tmp / "pycache"))
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    env_no_pyc = dict(os.environ, PYTHONPATH=str(ROOT), PYTHONDONTWRITEBYTECODE="1")
    ours = [sys.executable, "-m", "pathtracer", path, "-o", str(tmp / "ours.exr"), "--spp", str(spp),
            "-D", f"width={w}", "-D", f"height={h}", "--no-progress"]
    cmds = {"ours": (ours, env), "ours_no_bytecode": (ours, env_no_pyc)}
    if have_mitsuba:
        cmds["mitsuba"] = ([sys.executable, "-c", MITSUBA_PROCESS, path, str(tmp / "mitsuba.exr"), str(w), str(h),
                            str(spp)], env)
    for c, e in cmds.values():  # warm the caches (Warp kernels, Dr.Jit's LLVM kernels, bytecode): a second run
        subprocess.run(c, env=e, check=True, capture_output=True)
    secs = {k: [] for k in cmds}
    for _ in range(reps):
        for k, (c, e) in cmds.items():
            t0 = time.perf_counter()
            subprocess.run(c, env=e, check=True, capture_output=True)
            secs[k].append(time.perf_counter() - t0)
    out = {}
    for k in cmds:
        img = pathtracer.read_image(tmp / f"{'mitsuba' if k == 'mitsuba' else 'ours'}.exr")[..., :3]
        e = rel_mse(img, ref)
        t = float(np.median(secs[k]))
        out[k] = {"seconds": t, "relmse": e, "efficiency": 1.0 / (e * t)}
    return out


def estimate_honesty(scene_name: str, ref: np.ndarray, w: int, h: int, spp: int, seeds: int = 5,
                     ref_var: np.ndarray | None = None) -> dict:
    """relmse_estimate of the defaults against the measured relMSE (against the reference, its own share taken off
    where ``ref_var`` is known: ``rel_mse_net``), over seeds."""
    scene = load(scene_name, w, h)
    ratios, raw = [], []
    for s in range(seeds):
        st = {}
        img = pathtracer.render(scene, spp=spp, seed=100 + s, progress=False, stats=st)
        ratios.append(st["relmse_estimate"] / rel_mse_net(img, ref, ref_var))
        raw.append(st["relmse_estimate"] / rel_mse(img, ref))
    return {"ratios": ratios, "geometric_mean": float(np.exp(np.mean(np.log(ratios)))),
            "reference_noise_removed": ref_var is not None, "ratios_against_raw_relmse": raw,
            "geometric_mean_raw": float(np.exp(np.mean(np.log(raw))))}


FIXED = [("K=1 area", {}), ("K=2 area", {"light_samples": 2}), ("K=1 solid_angle", {"light_sampling": "solid_angle"})]


def auto_vs_fixed(scene_name: str, ref: np.ndarray, w: int, h: int, spp: int, seeds: int = 5,
                  ref_var: np.ndarray | None = None) -> dict:
    """The defaults ("auto": the pilot, its loser's time included) against each fixed configuration it could have
    been (light tracing on or off, where the scene allows it, times K = 1 or 2 and area or solid-angle light
    sampling), over the same seeds: efficiency = 1 / (mean relMSE x median render seconds)."""
    scene = load(scene_name, w, h)
    pathtracer.render(scene, spp=64, seed=3, progress=False)  # compile and load what auto may pick
    probe = pathtracer.Renderer(scene, light_tracing=True)
    lt_options = [False, True] if probe.light_tracing else [False]
    probe.close()
    runs = {"auto": {}} | {f"{label}{' lt' if lt else ''}": dict(opts, light_tracing=lt)
                           for lt in lt_options for label, opts in FIXED}
    got = {label: ([], [], []) for label in runs}
    for s in range(seeds):  # each seed's configurations side by side, so that the machine's drift falls on all alike
        for label, opts in runs.items():
            st = {}
            img = pathtracer.render(scene, spp=spp, seed=100 + s, progress=False, stats=st, **opts)
            errs, secs, choices = got[label]
            errs.append(rel_mse_net(img, ref, ref_var))
            secs.append(st["render_seconds"])
            choices.append(bool(st["config"].get("light_tracing")))
    out = {}
    for label, (errs, secs, choices) in got.items():
        e, t = float(np.mean(errs)), float(np.median(secs))
        out[label] = {"relmse": errs, "seconds": secs, "light_tracing": choices, "efficiency": 1.0 / (e * t)}
    best = max((k for k in out if k != "auto"), key=lambda k: out[k]["efficiency"])
    return {"runs": out, "best_fixed": best, "ratio": out["auto"]["efficiency"] / out[best]["efficiency"]}


def machine() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        for line in open("/proc/cpuinfo"):
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    import warp as wp

    simd = ""
    try:
        flags = next(line for line in open("/proc/cpuinfo") if line.startswith("flags")).split()
        simd = ", " + ("AVX-512" if "avx512f" in flags else "AVX2 (no AVX-512)" if "avx2" in flags else "no AVX2")
    except (OSError, StopIteration):
        pass
    return f"{cpu}{simd}, {os.cpu_count()} cores, Python {platform.python_version()}, warp {wp.__version__}"


def plot(rows: list[Row], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    scenes = sorted({r.scene for r in rows}, key=SCENES.index)
    fig, axes = plt.subplots(1, len(scenes), figsize=(5 * len(scenes), 4.2), squeeze=False)
    for ax, s in zip(axes[0], scenes):
        colours = plt.get_cmap("tab20").colors  # 13 configurations: the default 10-colour cycle repeats
        for k, label in enumerate(dict.fromkeys(r.config for r in rows if r.scene == s)):
            pts = [(r.seconds, r.relmse) for r in rows if r.scene == s and r.config == label]
            xs, ys = zip(*pts)
            if "mitsuba" in label:
                ax.loglog(xs, ys, "s--", color="black", lw=2, label=label, ms=4)
            else:
                ax.loglog(xs, ys, "o-", color=colours[(2 * k) % 20 + (k >= 10)], label=label, ms=3)
        ax.axhline(TARGET, color="gray", lw=0.8, ls=":")
        ax.set_title(s)
        ax.set_xlabel("seconds")
        ax.set_ylabel("relMSE")
        ax.grid(True, which="both", lw=0.3)
    axes[0][0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def markdown(rows: list[Row], refs: dict, args, wall: float, compiles=None, scaling=None, process=None,
             honesty=None, auto=None) -> str:
    scaling = scaling or {}
    notes = ROOT / "docs" / "performance_notes.md"
    lines = ["# Performance: speed against error", ""]
    if notes.exists():
        lines += [notes.read_text().strip(), "", "# The latest report", ""]
    lines += [
             f"Machine: {machine()}. Command: `python examples/bench.py {' '.join(sys.argv[1:])}` "
             f"({wall / 60:.1f} min). Image {args.width}x{args.height}, the scene files' max_depth and rr_depth.",
             f"Seconds: the median of {TIME_REPS} runs of each rung, excluding compilation and JIT warm-up. relMSE = mean((I - R)^2 / (R^2 + 0.01)); "
             "efficiency = 1 / (relMSE x seconds); the table's time to 1e-3 = seconds x relMSE / 1e-3 at that rung (the "
             "efficiency restated), the summary's is read off the ladder (interpolated between the rungs that bracket it). "
             "\"lt\": light tracing on (where the scene has mirrors; M rays/s then counts camera paths only).", ""]
    if process:
        lines += ["## The defaults, whole process", "",
                  f"`pathtracer SCENE.xml -o out.exr --spp {args.process_spp}` at {args.process_size[0]}x"
                  f"{args.process_size[1]} (the CLI's defaults) against Mitsuba 3 "
                  "`llvm_ad_rgb` rendering the same file in a script of its own, each a fresh Python process from "
                  "start to file written (warm kernel and bytecode caches), alternately, median of "
                  f"{args.process_reps}; efficiency = 1 / (relMSE x seconds). \"No bytecode\": ours again with "
                  "PYTHONDONTWRITEBYTECODE=1, compiling its Python on every run.", "",
                  "| scene | ours (s) | ours relMSE | Mitsuba (s) | Mitsuba relMSE | efficiency ours / Mitsuba | "
                  "no bytecode: ours (s), efficiency |",
                  "|---|---|---|---|---|---|---|"]
        for sname, p in process.items():
            o, m, nb = p["ours"], p.get("mitsuba"), p.get("ours_no_bytecode")
            extra = f" {nb['seconds']:.2f}, {nb['efficiency'] / m['efficiency']:.2f} |" if (m and nb) else " |"
            if m:
                lines.append(f"| {sname} | {o['seconds']:.2f} | {o['relmse']:.3e} | {m['seconds']:.2f} | "
                             f"{m['relmse']:.3e} | **{o['efficiency'] / m['efficiency']:.2f}** |" + extra)
            else:
                lines.append(f"| {sname} | {o['seconds']:.2f} | {o['relmse']:.3e} | | | |" + extra)
        lines.append("")
    if auto:
        lines += ["## Auto against the best fixed configuration", "",
                  f"Render seconds (the pilot and its loser included for auto) and relMSE against the reference, "
                  f"{args.process_spp} spp at {args.process_size[0]}x{args.process_size[1]}, the same 5 seeds for "
                  "each configuration (each seed's runs one after another); efficiency = 1 / (mean relMSE x "
                  "median seconds). The fixed configurations: "
                  "light tracing on (lt) or off where the scene allows it, K = 1 or 2, area or solid-angle light "
                  "sampling.", "",
                  "| scene | auto's choice (5 seeds) | auto: s, relMSE | best fixed | its s, relMSE | auto / best |",
                  "|---|---|---|---|---|---|"]
        for sname, av in auto.items():
            a, b = av["runs"]["auto"], av["runs"][av["best_fixed"]]
            picks = sum(a["light_tracing"])
            choice = ("light tracing" if picks == len(a["light_tracing"]) else "path tracing" if picks == 0
                      else f"light tracing {picks} of {len(a['light_tracing'])}")
            lines.append(f"| {sname} | {choice} | {np.median(a['seconds']):.2f}, {np.mean(a['relmse']):.3e} | "
                         f"{av['best_fixed']} | {np.median(b['seconds']):.2f}, {np.mean(b['relmse']):.3e} | "
                         f"**{av['ratio']:.2f}** |")
        lines.append("")
    elif rows:
        lines += ["## Auto against the best fixed configuration", "",
                  f"Efficiency at the ladder's top rung ({max(r.spp for r in rows)} spp), ours only.", "",
                  "| scene | defaults (auto) | its choice | best fixed configuration | its efficiency | auto / best |",
                  "|---|---|---|---|---|---|"]
        top = max(r.spp for r in rows)
        for sname in dict.fromkeys(r.scene for r in rows):
            at = {r.config: r for r in rows if r.scene == sname and r.spp == top and "mitsuba" not in r.config}
            if DEFAULTS not in at:
                continue
            d = at.pop(DEFAULTS)
            best = max(at.values(), key=lambda r: r.efficiency)
            choice = "light tracing" if d.extra.get("config", {}).get("light_tracing") else "path tracing"
            lines.append(f"| {sname} | {d.efficiency:.3g} | {choice} | {best.config} | {best.efficiency:.3g} | "
                         f"**{d.efficiency / best.efficiency:.2f}** |")
        lines.append("")
    if honesty:
        lines += ["## The error estimate", "",
                  f"`relmse_estimate` (stats) of the defaults divided by the measured relMSE against the reference, "
                  f"{args.process_spp} spp at {args.process_size[0]}x{args.process_size[1]}, 5 seeds.", "",
                  "| scene | geometric mean | each seed |", "|---|---|---|"]
        for sname, hv in honesty.items():
            lines.append(f"| {sname} | **{hv['geometric_mean']:.2f}** | "
                         f"{', '.join(f'{x:.2f}' for x in hv['ratios'])} |")
        lines.append("")
    if compiles:
        lines += ["## Compile and start-up", "",
                  "| scene | cold compile (s) | cached load (s) | warm process: import + load + upload (s) |",
                  "|---|---|---|---|"]
        lines += [f"| {s} | {c:.2f} | {w:.4f} | {p:.2f} |" for s, c, w, p in compiles]
        lines.append("")
    for s in dict.fromkeys(r.scene for r in rows):
        lines += [f"## {s}", "", f"Reference: {refs[s]}.", "",
                  "| configuration | spp | seconds | M samples/s | M rays/s | relMSE | efficiency | time to 1e-3 (s) |",
                  "|---|---|---|---|---|---|---|---|"]
        for r in rows:
            if r.scene == s:
                rays = "" if np.isnan(r.rays_per_s) else f"{r.rays_per_s / 1e6:.2f}"
                lines.append(f"| {r.config} | {r.spp} | {r.seconds:.3f} | {r.samples_per_s / 1e6:.2f} | {rays} | "
                             f"{r.relmse:.3e} | {r.efficiency:.3g} | {r.time_to_target:.2f} |")
        lines.append("")
        ladders = {}
        for r in rows:
            if r.scene == s:
                ladders.setdefault(r.config, []).append(r)
        if "mitsuba llvm_ad_rgb" in ladders:
            times = {c: crossing_time(v) for c, v in ladders.items()}
            best = min((c for c in times if "mitsuba" not in c), key=lambda c: times[c][0])
            default = DEFAULTS
            m = times["mitsuba llvm_ad_rgb"]
            lines += [f"Time to relMSE 1e-3 (on each ladder's error-against-seconds curve): Mitsuba {m[0]:.2f} s "
                      f"({m[1]}); best of ours ({best}) {times[best][0]:.2f} s ({times[best][1]}): ratio ours/Mitsuba = "
                      f"**{times[best][0] / m[0]:.2f}**; the default configuration ({default}) {times[default][0]:.2f} s "
                      f"({times[default][1]}): ratio {times[default][0] / m[0]:.2f}.", ""]
        if s in scaling:
            one, alls, ratio = scaling[s]
            lines += [f"Threads (default configuration, {THREAD_SPP} spp, {THREAD_REPS} back-to-back pairs): median "
                      f"1 thread {one:.3f} s, {os.cpu_count()} threads {alls:.3f} s; median ratio {ratio:.2f}x "
                      "faster.", ""]
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description="Speed against error for the seed scenes.")
    ap.add_argument("--scenes", nargs="*", default=SCENES, choices=SCENES)
    ap.add_argument("--width", type=int, default=128)
    ap.add_argument("--height", type=int, default=96)
    ap.add_argument("--ladder", type=int, nargs="*", default=[4, 16, 64, 256])
    ap.add_argument("--ref-spp", type=int, default=16384)
    ap.add_argument("--ref-dir", default=str(ROOT / "out" / "bench_refs"))
    ap.add_argument("--samplers", nargs="*", default=["independent", "sobol"])
    ap.add_argument("--quick", action="store_true", help="fewer configurations")
    ap.add_argument("--configs", nargs="*", help="only these configuration labels (e.g. 'K=1' 'K=1 sobol' mitsuba)")
    ap.add_argument("--no-threads", action="store_true", help="skip the thread-scaling pairs")
    ap.add_argument("--no-compile", action="store_true", help="skip the cold-compile measurements")
    ap.add_argument("--no-mitsuba", action="store_true")
    ap.add_argument("--out", default=str(ROOT / "docs"))
    ap.add_argument("--process-spp", type=int, default=512, help="spp of the whole-process runs")
    ap.add_argument("--process-size", type=int, nargs=2, default=[160, 120], metavar=("W", "H"),
                    help="image size of the whole-process runs (the issue's: 160 x 120)")
    ap.add_argument("--process-reps", type=int, default=3)
    ap.add_argument("--process-ref-spp", type=int, help="spp of the whole-process runs' references (default: "
                    "--ref-spp)")
    ap.add_argument("--no-auto", action="store_true", help="skip auto against the fixed configurations")
    ap.add_argument("--no-process", action="store_true", help="skip the whole-process and error-estimate runs")
    a = ap.parse_args(argv)
    a.process_ref_spp = a.process_ref_spp or a.ref_spp
    have_mitsuba = False
    if not a.no_mitsuba:
        try:
            import mitsuba as mi

            mi.set_variant("llvm_ad_rgb")
            have_mitsuba = True
        except Exception as exc:  # not installed, or no usable LLVM: bench ourselves only
            print(f"Mitsuba 3 llvm_ad_rgb unavailable ({exc}); benchmarking ours only", file=sys.stderr)
    t_start = time.perf_counter()
    rows: list[Row] = []
    refs = {}
    for s in a.scenes:
        ref, refs[s] = reference(s, a.width, a.height, Path(a.ref_dir), a.ref_spp, have_mitsuba)
        for cfg in configs(a.quick, have_mitsuba, a.samplers):
            if a.configs and not any(cfg.label == c or (c == "mitsuba" and cfg.mitsuba) for c in a.configs):
                continue
            got = (mitsuba_ladder(s, a.ladder, ref, a.width, a.height) if cfg.mitsuba
                   else ours_ladder(s, cfg, a.ladder, ref, a.width, a.height))
            rows += got
            last = got[-1]
            print(f"{s:20s} {cfg.label:22s} {last.spp:5d} spp {last.seconds:7.3f} s relMSE {last.relmse:.3e} "
                  f"to 1e-3: {last.time_to_target:7.2f} s", flush=True)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    scaling = ({s: thread_scaling(s, a.width, a.height) for s in a.scenes}
               if (os.cpu_count() or 1) > 1 and not a.no_threads else {})
    compiles = None if a.no_compile else compile_times(a.scenes)
    process, honesty, auto = {}, {}, {}
    if not a.no_process:
        import tempfile

        with tempfile.TemporaryDirectory() as tmp:
            pw, ph = a.process_size
            for s in a.scenes:
                ref, _ = reference(s, pw, ph, Path(a.ref_dir), a.process_ref_spp, have_mitsuba)
                ref_var = reference_variance(s, pw, ph, Path(a.ref_dir), a.process_ref_spp)
                process[s] = whole_process(s, ref, pw, ph, a.process_spp, a.process_reps, have_mitsuba, Path(tmp))
                honesty[s] = estimate_honesty(s, ref, pw, ph, a.process_spp, ref_var=ref_var)
                print(f"{s}: whole process {process[s]}; estimate/measured {honesty[s]['geometric_mean']:.2f}",
                      flush=True)
                if not a.no_auto:
                    auto[s] = auto_vs_fixed(s, ref, pw, ph, a.process_spp, ref_var=ref_var)
                    print(f"{s}: auto / best fixed ({auto[s]['best_fixed']}) {auto[s]['ratio']:.2f}", flush=True)
    (out / "performance.md").write_text(markdown(rows, refs, a, time.perf_counter() - t_start, compiles, scaling,
                                                 process, honesty, auto))
    with open(out / "process.json", "w") as f:
        json.dump({"whole_process": process, "estimate": honesty, "auto_vs_fixed": auto, "threads": scaling}, f,
                  indent=1)
    with open(out / "performance.json", "w") as f:
        json.dump([r.__dict__ | {"efficiency": r.efficiency} for r in rows], f, indent=0)
    try:
        plot(rows, out / "performance.png")
    except ImportError:
        print("matplotlib not installed: no plot", file=sys.stderr)
    print(f"wrote {out / 'performance.md'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
