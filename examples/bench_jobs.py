"""How well render jobs keep their budgets (pathtracer/jobs.py), measured on the seed scenes:

- ``--time T``: the render time and the whole process's wall time against T (CLI, one process per run);
- ``--target-error REL``: the relMSE actually reached, against the committed Mitsuba references (tests/data/refs,
  65536 spp at 64x48: their own noise is subtracted), divided by REL, over several seeds;
- a resume after SIGINT: bit-identical to the render that never stopped.

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


def target_error(scene: str, target: float, seeds: range) -> dict:
    import pathtracer
    from pathtracer.imageio import read_image

    refs = ROOT / "tests" / "data" / "refs"
    ref, var = read_image(refs / f"{scene}.exr"), read_image(refs / f"{scene}_var.exr")
    s = pathtracer.load_file(str(ROOT / "scenes" / f"{scene}.xml"), width=ref.shape[1], height=ref.shape[0])
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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", nargs="*", default=SCENES)
    ap.add_argument("--time", type=float, nargs="*", default=[3.0])
    ap.add_argument("--targets", type=float, nargs="*", default=[1e-2, 1e-3])
    ap.add_argument("--seeds", type=int, default=5)
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
        report["sigint_resume"] = sigint_resume(tmp)
        print("SIGINT then --resume:", report["sigint_resume"], flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
