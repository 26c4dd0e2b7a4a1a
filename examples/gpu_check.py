"""What to run on a machine with CUDA (under 5 minutes): the CUDA tests, every seed scene on cpu and cuda compared
statistically, the two triangle backends on the GPU, and speed against error next to Mitsuba 3 ``cuda_ad_rgb`` when
it is installed. Prints a JSON report (also written with --out) for docs/performance.md.

    python examples/gpu_check.py [--out gpu_check.json] [--skip-tests]

On a machine without CUDA it says so and exits with status 0 (nothing to check).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import warp as wp  # noqa: E402

from pathtracer.warp_setup import init_warp  # noqa: E402

init_warp()

import pathtracer  # noqa: E402

SEED_SCENES = ["cornell_box", "cornell_box_mirror", "teapot_in_box", "open_sky"]
Z_MAX = 4.0


def run_cuda_tests() -> dict:
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, "-m", "pytest", "-q", "-m", "cuda", "tests"], cwd=ROOT, capture_output=True,
                       text=True, timeout=240)
    tail = r.stdout.strip().splitlines()[-1] if r.stdout.strip() else r.stderr[-500:]
    return {"returncode": r.returncode, "summary": tail, "seconds": time.perf_counter() - t0}


def batches(scene, device, seeds, spp, **opts):
    imgs = np.stack([pathtracer.render(scene, spp=spp, seed=s, device=device, progress=False, **opts)
                     .astype(np.float64) for s in seeds])
    return imgs.mean(axis=0), imgs.var(axis=0, ddof=1) / len(imgs)


def cpu_vs_cuda(name: str, width=64, height=48, spp=64, n=8) -> dict:
    """Both devices, independent seeds: per-pixel z of the difference and the image means."""
    scene = pathtracer.load_file(ROOT / "scenes" / f"{name}.xml", width=width, height=height)
    a, va = batches(scene, "cpu", range(n), spp)
    b, vb = batches(scene, "cuda:0", range(100, 100 + n), spp)
    var = va + vb
    noisy = var > 0
    z = (a - b)[noisy] / np.sqrt(var[noisy])
    zm = (a.mean() - b.mean()) / np.sqrt(var.sum() / var.size**2)
    return {"pixel_pass": float(np.mean(np.abs(z) <= Z_MAX)), "image_mean_z": float(zm),
            "ok": bool(np.mean(np.abs(z) <= Z_MAX) >= 0.99 and abs(zm) <= Z_MAX)}


def speed_vs_error(name: str, width=256, height=192, spp=256) -> dict:
    """Our render on cuda (defaults, then each triangle backend) and Mitsuba cuda_ad_rgb when installed: seconds
    and relMSE against a long render of ours."""
    scene = pathtracer.load_file(ROOT / "scenes" / f"{name}.xml", width=width, height=height)
    ref = pathtracer.render(scene, spp=8 * spp, seed=99, device="cuda:0", progress=False).astype(np.float64)
    denom = ref * ref + 0.01
    out = {}
    configs = {"defaults": {}}
    if scene.meshes and any(len(m.faces) > 12 for m in scene.meshes):
        configs.update({"triangles=wide": {"triangles": "wide"}, "triangles=warp": {"triangles": "warp"}})
    for label, opts in configs.items():
        pathtracer.render(scene, spp=4, seed=1, device="cuda:0", progress=False, **opts)  # compile, warm up
        st = {}
        img = pathtracer.render(scene, spp=spp, seed=1, device="cuda:0", progress=False, stats=st, **opts)
        rel = float(np.mean((img - ref) ** 2 / denom))
        out[label] = {"render_seconds": st["render_seconds"], "relmse": rel,
                      "efficiency": 1.0 / (rel * st["render_seconds"]), "relmse_estimate": st["relmse_estimate"]}
    try:
        import mitsuba as mi

        mi.set_variant("cuda_ad_rgb")
        ms = mi.load_file(str(ROOT / "scenes" / f"{name}.xml"), width=width, height=height)
        mi.render(ms, spp=4)
        t0 = time.perf_counter()
        img = np.asarray(mi.render(ms, spp=spp), dtype=np.float64)[..., :3]
        seconds = time.perf_counter() - t0
        rel = float(np.mean((img - ref) ** 2 / denom))
        out["mitsuba cuda_ad_rgb"] = {"render_seconds": seconds, "relmse": rel, "efficiency": 1.0 / (rel * seconds)}
    except Exception as exc:  # not installed, or no such variant
        out["mitsuba cuda_ad_rgb"] = {"skipped": f"{type(exc).__name__}: {exc}"[:200]}
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--out", type=Path)
    p.add_argument("--skip-tests", action="store_true")
    a = p.parse_args(argv)
    if not wp.is_cuda_available():
        print("no CUDA device on this machine: nothing to check (run this where a GPU is present)")
        return 0
    t0 = time.perf_counter()
    dev = wp.get_device("cuda:0")
    report = {"machine": f"{dev.name}, {platform.processor() or platform.machine()}, warp {wp.config.version}",
              "cpu_cores": os.cpu_count()}
    if not a.skip_tests:
        report["cuda_tests"] = run_cuda_tests()
    report["cpu_vs_cuda"] = {n: cpu_vs_cuda(n) for n in SEED_SCENES}
    report["speed_vs_error"] = {n: speed_vs_error(n) for n in SEED_SCENES}
    report["seconds"] = time.perf_counter() - t0
    text = json.dumps(report, indent=1)
    print(text)
    if a.out:
        a.out.write_text(text + "\n")
    ok = all(v["ok"] for v in report["cpu_vs_cuda"].values()) and report.get("cuda_tests", {}).get("returncode", 0) in (0, 5)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
