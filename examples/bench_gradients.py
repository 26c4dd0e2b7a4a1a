"""Gradient render time against the plain render at equal spp (issue 12: backward at most 2.5x forward).

    python examples/bench_gradients.py --json docs/bench_gradients.json

cornell_box at 128x128, 64 spp, medians of 5 in one process, kernels cached: the plain render (``render``), the
forward-mode derivative image (``render_forward``: the image and its derivative), ``render_backward`` by
path replay (one render, the adjoints gathered in one pass, for one parameter or all of them) and by forward mode
(one render per parameter), and ``render_loss_gradient`` (the image and a loss gradient from two independent
halves of the spp: forward mode for one key, 1.5 renders of path replay for all).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def main() -> None:
    import pathtracer

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--json")
    a = ap.parse_args()
    scene = pathtracer.load_file(str(ROOT / "scenes" / "cornell_box.xml"), width=a.size, height=a.size)
    w = np.ones((a.size, a.size, 3))
    keys = ["red.reflectance.value", "light.emitter.radiance.value"]
    all_keys = list(pathtracer.traverse(scene))
    cases = {
        "render": lambda: pathtracer.render(scene, spp=a.spp, seed=1, progress=False, light_tracing=False),
        "render_forward": lambda: pathtracer.render_forward(scene, keys[0], spp=a.spp, seed=1),
        "render_backward (path replay), 1 key": lambda: pathtracer.render_backward(scene, keys[:1], w, spp=a.spp,
                                                                                  seed=1, method="replay"),
        "render_backward (path replay), all keys": lambda: pathtracer.render_backward(scene, all_keys, w,
                                                                                     spp=a.spp, seed=1,
                                                                                     method="replay"),
        "render_loss_gradient (two halves), 1 key": lambda: pathtracer.render_loss_gradient(
            scene, keys[0], lambda img: w, spp=a.spp, seed=1),
        "render_loss_gradient (two halves), all keys": lambda: pathtracer.render_loss_gradient(
            scene, all_keys, lambda img: w, spp=a.spp, seed=1),
        "render_backward (forward), 2 keys": lambda: pathtracer.render_backward(scene, keys, w, spp=a.spp, seed=1,
                                                                               method="forward"),
    }
    for f in cases.values():
        f()  # compile (cached) and warm up
    times = {k: [] for k in cases}
    for _ in range(a.reps):
        for k, f in cases.items():  # interleaved, so that the machine's load falls on all alike
            t0 = time.perf_counter()
            f()
            times[k].append(time.perf_counter() - t0)
    med = {k: float(np.median(v)) for k, v in times.items()}
    report = {"scene": f"cornell_box {a.size}x{a.size}", "spp": a.spp, "reps": a.reps, "median_seconds": med,
              "seconds": times, "over_render": {k: med[k] / med["render"] for k in med}}
    for k in cases:
        print(f"{k:42s} {med[k]:.3f} s  ({med[k] / med['render']:.2f}x render)")
    if a.json:
        Path(a.json).write_text(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
