"""Two threads against one, with and without the lone thread's clock advantage.

    python examples/thread_scaling.py [--spp 128] [--pairs 5] [--light-tracing] [scene ...]

On the 2-core machine this project runs on, a lone thread sometimes runs 20-25% faster than either of two busy
threads (the two-thread time stays steady), so a plain wall-clock ratio swings from run to run. This script measures,
in pairs back to back: one thread alone, one thread while a spin loop keeps the other core busy (the same clock as
with two threads), and two threads. It prints both ratios (medians over the pairs). Same seed and spp throughout:
the images are bit-identical.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import pathtracer  # noqa: E402


def measure(name: str, spp: int, pairs: int, width: int = 128, height: int = 96, light_tracing: bool = False) -> dict:
    """Median seconds of ``spp`` passes alone, beside a busy core and with two threads (light tracing on or off: what
    "auto" picks on the mirror scenes)."""
    scene = pathtracer.load_file(ROOT / "scenes" / f"{name}.xml", width=width, height=height)
    one = pathtracer.Renderer(scene, threads=1, light_tracing=light_tracing)
    two = pathtracer.Renderer(scene, threads=2, light_tracing=light_tracing)
    one.render_passes(count=2)
    two.render_passes(count=2)
    alone, loaded, both = [], [], []
    for k in range(pairs):
        alone.append(one.render_passes(seed=k, count=spp).seconds)
        spin = subprocess.Popen([sys.executable, "-c", "while True: pass"])
        try:
            time.sleep(0.2)
            loaded.append(one.render_passes(seed=k, count=spp).seconds)
        finally:
            spin.kill()
            spin.wait()
        both.append(two.render_passes(seed=k, count=spp).seconds)
    med = {k: float(np.median(v)) for k, v in (("alone", alone), ("loaded", loaded), ("two", both))}
    return med | {"ratio_alone": med["alone"] / med["two"], "ratio_equal_clock": med["loaded"] / med["two"]}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scenes", nargs="*", default=["cornell_box", "cornell_box_mirror", "teapot_in_box", "open_sky"])
    ap.add_argument("--spp", type=int, default=128)
    ap.add_argument("--pairs", type=int, default=5)
    ap.add_argument("--light-tracing", action="store_true", help="with the light tracer (the mirror scenes' auto pick)")
    a = ap.parse_args(argv)
    for name in a.scenes:
        m = measure(name, a.spp, a.pairs, light_tracing=a.light_tracing)
        label = f"{name} (light tracing)" if a.light_tracing else name
        print(f"{label}: 1 thread alone {m['alone']:.3f} s, 1 thread beside a busy core {m['loaded']:.3f} s, "
              f"2 threads {m['two']:.3f} s: {m['ratio_alone']:.2f}x plain, {m['ratio_equal_clock']:.2f}x at equal clock",
              flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
