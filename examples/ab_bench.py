"""A/B speed check of two checkouts on the seed scenes: is this one slower than an older one?

    git worktree add /tmp/base 6d19b4c
    python examples/ab_bench.py --base /tmp/base --reps 5 --spp 64

Each scene is rendered by the CLI of both checkouts in turn (base, this, base, this, ...), same spp, seed and
defaults, each in its own process with its own warm kernel cache. It reports the median render seconds of each
(compilation excluded), their ratio, and whether the two images are equal. When they are equal bit for bit, the
error is too, so the time ratio is the efficiency ratio (1 / (relMSE x seconds)); otherwise it reports the relMSE of
each against the other's mean so that a changed estimator shows up instead of hiding in a time ratio.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SCENES = ["cornell_box", "cornell_box_mirror", "teapot_in_box", "open_sky"]


def render(checkout: Path, scene: str, spp: int, out: Path, cache: Path, extra: list[str]) -> float:
    stats = out.with_suffix(".json")
    env = dict(os.environ, WARP_CACHE_PATH=str(cache), PYTHONPATH=str(checkout))
    cmd = [sys.executable, "-m", "pathtracer", str(ROOT / "scenes" / f"{scene}.xml"), "--spp", str(spp),
           "-o", str(out), "--stats", str(stats), "--no-progress", *extra]
    subprocess.run(cmd, cwd=checkout, env=env, check=True, capture_output=True)
    return float(json.loads(stats.read_text())["render_seconds"])


def read_exr(path: Path) -> np.ndarray:
    sys.path.insert(0, str(ROOT))
    from pathtracer.imageio import read_image

    return read_image(str(path))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--base", required=True, help="the older checkout (a git worktree)")
    ap.add_argument("--scenes", nargs="*", default=SCENES)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--json", help="write the figures here")
    ap.add_argument("extra", nargs="*", help="more CLI flags for both (after --)")
    args = ap.parse_args()
    base = Path(args.base).resolve()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for scene in args.scenes:
            times = {"base": [], "this": []}
            imgs = {}
            for who, checkout in (("base", base), ("this", ROOT)):  # warm-up: compile into each cache
                render(checkout, scene, 1, tmp / f"warm_{who}.exr", tmp / f"cache_{who}", args.extra)
            for rep in range(args.reps):
                for who, checkout in (("base", base), ("this", ROOT)):
                    out = tmp / f"{scene}_{who}.exr"
                    times[who].append(render(checkout, scene, args.spp, out, tmp / f"cache_{who}", args.extra))
                    imgs[who] = read_exr(out)
            equal = bool(np.array_equal(imgs["base"], imgs["this"]))
            mb, mt = float(np.median(times["base"])), float(np.median(times["this"]))
            row = {"scene": scene, "spp": args.spp, "base_s": times["base"], "this_s": times["this"],
                   "median_base_s": mb, "median_this_s": mt, "ratio_this_over_base": mt / mb,
                   "images_equal": equal}
            if not equal:
                a, b = imgs["base"], imgs["this"]
                row["rel_diff_mean"] = float(np.mean(np.abs(a - b)) / max(np.mean(np.abs(a)), 1e-12))
            rows.append(row)
            print(f"{scene:20s} base {mb:7.3f} s  this {mt:7.3f} s  ratio {mt / mb:5.3f}  "
                  f"images {'equal' if equal else 'DIFFER'}  (all base {['%.2f' % t for t in times['base']]}, "
                  f"this {['%.2f' % t for t in times['this']]})", flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
