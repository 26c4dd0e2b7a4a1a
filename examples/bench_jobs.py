"""How well render jobs keep their budgets (pathtracer/jobs.py), measured on the seed scenes:

- ``--time T``: the render time and the whole process's wall time against T (CLI, one process per run);
- ``--target-error REL``: the relMSE actually reached, against the committed Mitsuba references (tests/data/refs,
  65536 spp at 64x48: their own noise is subtracted), divided by REL, over several seeds;
- a resume after SIGINT: bit-identical to the render that never stopped;
- adaptive sampling against uniform sampling at equal time (the relMSE each reaches in T seconds, measured against
  the Mitsuba references), with the adaptive threshold at the uniform render's estimated relMSE and at 1/4 of it;
- the Ray farm (``--ray``): throughput of one worker and of two against one process with one and two threads, and
  the cost per unit (from a render cut into one-pass units against the default units).

    python examples/bench_jobs.py --json docs/bench_jobs.json
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
SCENES = ["cornell_box", "cornell_box_mirror", "teapot_in_box", "open_sky"]


def cli(*args, env=None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "pathtracer", *map(str, args)], cwd=ROOT, env=env,
                          capture_output=True, text=True, check=True)


def time_budget(scene: str, seconds: float, tmp: Path) -> dict:
    stats = tmp / "t.json"
    t0 = time.perf_counter()
    cli(ROOT / "scenes" / f"{scene}.xml", "-o", tmp / "t.exr", "--time", seconds, "--stats", stats, "--no-progress",
        "-D", "width=160", "-D", "height=120")
    wall = time.perf_counter() - t0
    st = json.loads(stats.read_text())
    return {"time_limit": seconds, "render_seconds": st["render_seconds"], "process_seconds": wall,
            "spp": st["spp"], "stop_reason": st["stop_reason"],
            "render_over_limit": st["render_seconds"] / seconds}


def measured_relmse(img: np.ndarray, ref: np.ndarray, ref_var: np.ndarray) -> float:
    """mean((img - ref)^2 / (ref^2 + 0.01)) less the reference's own noise (its variance of the mean)."""
    denom = ref.astype(np.float64) ** 2 + 0.01
    return float(np.mean((img - ref) ** 2 / denom) - np.mean(ref_var / denom))


def with_reference(scene: str):
    """(the scene at its committed Mitsuba reference's size, the reference, its variance): tests/data/refs."""
    import pathtracer
    from pathtracer.imageio import read_image

    refs = ROOT / "tests" / "data" / "refs"
    ref, var = read_image(refs / f"{scene}.exr"), read_image(refs / f"{scene}_var.exr")
    s = pathtracer.load_file(str(ROOT / "scenes" / f"{scene}.xml"), width=ref.shape[1], height=ref.shape[0])
    return s, ref, var


def target_error(scene: str, target: float, seeds: range) -> dict:
    import pathtracer

    s, ref, var = with_reference(scene)
    rows = []
    for seed in seeds:
        st: dict = {}
        img = pathtracer.render(s, target_error=target, seed=seed, progress=False, stats=st)
        rows.append({"seed": seed, "spp": st["spp"], "estimate": st["relmse_estimate"],
                     "measured": measured_relmse(img, ref, var)})
    ratios = [r["measured"] / target for r in rows]
    return {"target": target, "runs": rows, "measured_over_target": ratios,
            "geomean_measured_over_target": float(np.exp(np.mean(np.log(np.maximum(ratios, 1e-12)))))}


def sigint_resume(tmp: Path) -> dict:
    env = dict(os.environ)
    common = ["--spp", 512, "--no-progress", "-D", "width=160", "-D", "height=120"]
    scene = ROOT / "scenes" / "cornell_box_mirror.xml"
    args = [scene, "-o", tmp / "i.exr", *common, "--checkpoint", tmp / "i.npz", "--checkpoint-every", 0.5]
    cli(scene, "-o", tmp / "u.exr", *common, env=env)
    p = subprocess.Popen([sys.executable, "-m", "pathtracer", *map(str, args)], cwd=ROOT, env=env,
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    while not (tmp / "i.npz").exists():
        time.sleep(0.05)
    time.sleep(1.0)
    p.send_signal(signal.SIGINT)
    p.communicate()
    code = p.returncode
    cli(*args, "--resume", env=env)
    from pathtracer.imageio import read_image

    return {"exit_status": code, "bit_identical": bool(np.array_equal(read_image(tmp / "i.exr"),
                                                                        read_image(tmp / "u.exr")))}


def adaptive_vs_uniform(scene: str, seconds: float, seeds: range) -> dict:
    import pathtracer

    s, ref, var = with_reference(scene)
    rows = []
    for seed in seeds:
        st: dict = {}
        img = pathtracer.render(s, time_limit=seconds, seed=seed, progress=False, stats=st)
        row = {"seed": seed, "uniform": {"relmse": measured_relmse(img, ref, var), "spp": st["spp"],
                                         "estimate": st["relmse_estimate"]}}
        sp: dict = {}  # the same estimator as adaptive sampling's (which cannot light-trace)
        img = pathtracer.render(s, time_limit=seconds, seed=seed, progress=False, stats=sp, light_tracing=False)
        row["uniform_path_only"] = {"relmse": measured_relmse(img, ref, var), "spp": sp["spp"],
                                    "estimate": sp["relmse_estimate"]}
        row["uniform"]["light_tracing"] = st["config"]["light_tracing"]
        for name, threshold in (("adaptive_at_estimate", st["relmse_estimate"]),
                                ("adaptive_at_quarter", st["relmse_estimate"] / 4)):
            sa: dict = {}
            img = pathtracer.render(s, time_limit=seconds, seed=seed, progress=False, stats=sa, adaptive=threshold)
            row[name] = {"relmse": measured_relmse(img, ref, var), "threshold": threshold, "spp": sa["spp"],
                         "mean_spp": sa["adaptive"]["mean_spp"], "stop_reason": sa["stop_reason"],
                         "render_seconds": sa["render_seconds"], "estimate": sa["relmse_estimate"]}
        rows.append(row)
    out = {"seconds": seconds, "runs": rows}
    for name in ("adaptive_at_estimate", "adaptive_at_quarter"):
        # > 1: adaptive reaches a lower error in the same time (efficiency ratio at equal time)
        for base in ("uniform", "uniform_path_only"):
            out[f"{base}_over_{name}"] = float(np.exp(np.mean([np.log(r[base]["relmse"] / r[name]["relmse"])
                                                               for r in rows])))
    return out


def ray_farm(reps: int) -> dict:
    """Median seconds of one render (cornell_box, 160x120, 1024 spp) in-process and on a local Ray farm."""
    import logging

    import pathtracer
    import ray
    from pathtracer.ray_executor import RayExecutor

    s = pathtracer.load_file(str(ROOT / "scenes" / "cornell_box.xml"), width=160, height=120)
    spp, pixels = 1024, 160 * 120
    os.environ.setdefault("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", "0")
    ray.init(address="local", include_dashboard=False, _node_ip_address="127.0.0.1", logging_level=logging.ERROR,
             log_to_driver=False)
    runs: dict = {}

    def timed(name, **kw):
        times = []
        for _ in range(reps):
            st: dict = {}
            pathtracer.render(s, spp=spp, seed=0, progress=False, stats=st, **kw)
            times.append(st["render_seconds"])
        runs[name] = {"median_seconds": float(np.median(times)), "seconds": times,
                      "msamples_per_second": spp * pixels / float(np.median(times)) / 1e6}
        print(f"  {name:28s} {runs[name]['median_seconds']:.2f} s ({runs[name]['msamples_per_second']:.2f} "
              f"M samples/s)", flush=True)
        return runs[name]["median_seconds"]

    try:
        timed("in-process, 1 thread", threads=1)
        timed("in-process, 2 threads", threads=2)
        units = {}
        for workers in (1, 2):
            with RayExecutor(None, workers=workers) as ex:
                pathtracer.render(s, spp=16, progress=False, executor=ex)  # the workers compile (cached)
                timed(f"ray, {workers} worker(s)", executor=ex)
                units[workers] = -(-spp // max(8, (1 << 20) // pixels))
        with RayExecutor(None, workers=1, unit_samples=pixels, unit_min_passes=1) as ex:
            pathtracer.render(s, spp=16, progress=False, executor=ex)
            t_small = timed("ray, 1 worker, 1-pass units", executor=ex)
        per_unit = (t_small - runs["ray, 1 worker(s)"]["median_seconds"]) / (spp - units[1])
    finally:
        ray.shutdown()
    return {"scene": "cornell_box 160x120", "spp": spp, "reps": reps, "runs": runs,
            "two_workers_over_one": runs["ray, 1 worker(s)"]["median_seconds"] / runs["ray, 2 worker(s)"]["median_seconds"],
            "ray_2_over_inprocess_2_threads": runs["ray, 2 worker(s)"]["median_seconds"]
            / runs["in-process, 2 threads"]["median_seconds"],
            "seconds_per_unit_overhead": per_unit,
            "unit_film_bytes": pixels * 3 * 8 * 6}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", nargs="*", default=SCENES)
    ap.add_argument("--time", type=float, nargs="*", default=[3.0])
    ap.add_argument("--targets", type=float, nargs="*", default=[1e-2, 1e-3])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--adaptive-seconds", type=float, default=1.0, help="time per render of the adaptive "
                    "comparison (0: skip)")
    ap.add_argument("--ray-reps", type=int, default=3, help="repetitions of each Ray farm run (0: skip)")
    ap.add_argument("--json")
    args = ap.parse_args()
    report = {"time": [], "target_error": [], "machine": os.uname().nodename, "cpus": os.cpu_count()}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for scene in args.scenes:
            cli(ROOT / "scenes" / f"{scene}.xml", "-o", tmp / "w.exr", "--spp", 4, "--no-progress")  # warm cache
            for t in args.time:
                row = dict(scene=scene, **time_budget(scene, t, tmp))
                report["time"].append(row)
                print(f"{scene:20s} --time {t}: render {row['render_seconds']:.2f} s, process "
                      f"{row['process_seconds']:.2f} s, {row['spp']} spp ({row['stop_reason']})", flush=True)
            for target in args.targets:
                row = dict(scene=scene, **target_error(scene, target, range(args.seeds)))
                report["target_error"].append(row)
                print(f"{scene:20s} --target-error {target:g}: measured/target "
                      f"{['%.2f' % r for r in row['measured_over_target']]}, geomean "
                      f"{row['geomean_measured_over_target']:.2f}, spp {[r['spp'] for r in row['runs']]}",
                      flush=True)
        if args.adaptive_seconds:
            report["adaptive"] = []
            for scene in args.scenes:
                row = dict(scene=scene, **adaptive_vs_uniform(scene, args.adaptive_seconds, range(args.seeds)))
                report["adaptive"].append(row)
                print(f"{scene:20s} adaptive vs uniform in {args.adaptive_seconds:g} s: uniform relMSE / adaptive "
                      f"relMSE {row['uniform_over_adaptive_at_estimate']:.2f} (threshold = uniform's estimate), "
                      f"{row['uniform_over_adaptive_at_quarter']:.2f} (a quarter of it); uniform path tracing "
                      f"alone / adaptive {row['uniform_path_only_over_adaptive_at_estimate']:.2f}, "
                      f"{row['uniform_path_only_over_adaptive_at_quarter']:.2f}", flush=True)
        report["sigint_resume"] = sigint_resume(tmp)
        print("SIGINT then --resume:", report["sigint_resume"], flush=True)
    if args.ray_reps:
        print("Ray farm:", flush=True)
        report["ray"] = ray_farm(args.ray_reps)
        r = report["ray"]
        print(f"  two workers / one: {r['two_workers_over_one']:.2f}x, two workers / two threads in-process: "
              f"{r['ray_2_over_inprocess_2_threads']:.2f}, overhead per unit {r['seconds_per_unit_overhead'] * 1e3:.1f} ms",
              flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
