"""Render one scene file with our renderer and with Mitsuba 3, and say whether they agree within their noise.

    python examples/compare_mitsuba.py scenes/cornell_box.xml --spp 1024 --width 200 --height 150 --out out/cmp

Both renderers read the same file. For each, the per-pixel variance of the mean comes from B independent batches
(different seeds), so the script can say how much of the difference noise explains:

    relMSE        = mean((ours - mitsuba)^2 / (mitsuba^2 + 0.01))              (TESTING.md's metric)
    noise floor   = mean((var_ours + var_mitsuba) / (mitsuba^2 + 0.01))        (its expectation if both are unbiased)
    ratio         = relMSE / noise floor      (about 1 when the two agree; > 1.5 means a real difference)
    z pass rate   = share of pixel channels with |ours - mitsuba| <= 4 sqrt(var_ours + var_mitsuba)

It writes both images (EXR), a difference image (PNG, red where ours is brighter, blue where darker, scaled by
the pixel's noise) and a JSON line with the figures. Mitsuba is an optional extra: `pip install mitsuba`; the
variant defaults to scalar_rgb, or llvm_ad_rgb with DRJIT_LIBLLVM_PATH set (much faster).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def batch_stats(images: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Mean of B batch means and the variance of that mean."""
    stack = np.stack(images).astype(np.float64)
    b = len(images)
    return stack.mean(axis=0), stack.var(axis=0, ddof=1) / b


def render_ours(path: str, params: dict, spp: int, batches: int, max_depth: int | None, rr: str | None,
                light_tracing: bool = False):
    import pathtracer

    scene = pathtracer.load_file(path, **params)
    r = pathtracer.Renderer(scene, max_depth=max_depth, rr=rr, light_tracing=light_tracing)
    per = spp // batches
    images, t = [], 0.0
    for b in range(batches):
        sums = r.render_passes(seed=b, first_pass=0, count=per, progress=False)
        t += sums.seconds
        images.append(sums.mean)
    return images, t, r.compile_seconds


def render_mitsuba(path: str, params: dict, spp: int, batches: int, max_depth: int | None, variant: str):
    import mitsuba as mi

    mi.set_variant(variant)
    if max_depth is not None:
        params = dict(params, max_depth=str(max_depth))
    scene = mi.load_file(path, **{k: str(v) for k, v in params.items()})
    per = spp // batches
    images, t = [], 0.0
    mi.render(scene, spp=1, seed=10_000)  # JIT warm-up (llvm): not timed
    for b in range(batches):
        t0 = time.perf_counter()
        img = np.array(mi.render(scene, spp=per, seed=b), dtype=np.float32)
        t += time.perf_counter() - t0
        images.append(img[..., :3])
    return images, t


def compare(ours: np.ndarray, var_o: np.ndarray, ref: np.ndarray, var_r: np.ndarray) -> dict:
    denom = ref * ref + 0.01
    rel_mse = float(np.mean((ours - ref) ** 2 / denom))
    floor = float(np.mean((var_o + var_r) / denom))
    sigma = np.sqrt(var_o + var_r)
    diff = np.abs(ours - ref)
    ok = np.where(sigma > 0, diff <= 4 * sigma, diff <= 1e-6 * (np.abs(ref) + 1e-6))
    return {"relmse": rel_mse, "noise_floor": floor, "ratio": rel_mse / floor if floor > 0 else float("inf"),
            "z_pass_rate": float(ok.mean()), "mean_ours": float(ours.mean()), "mean_mitsuba": float(ref.mean())}


def difference_png(path: Path, ours, var_o, ref, var_r) -> None:
    from PIL import Image

    z = (ours - ref).mean(axis=2) / np.sqrt((var_o + var_r).mean(axis=2) + 1e-12)
    z = np.clip(z / 4.0, -1, 1)
    rgb = np.zeros(z.shape + (3,), np.uint8)
    rgb[..., 0] = (np.maximum(z, 0) * 255).astype(np.uint8)
    rgb[..., 2] = (np.maximum(-z, 0) * 255).astype(np.uint8)
    Image.fromarray(rgb).save(path)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scene")
    ap.add_argument("--spp", type=int, default=1024, help="samples per pixel for each renderer (split in batches)")
    ap.add_argument("--batches", type=int, default=16, help="independent batches (seeds) for the variance")
    ap.add_argument("--max-depth", type=int, default=None, help="override the file's max_depth in both")
    ap.add_argument("--width", type=int, default=None)
    ap.add_argument("--height", type=int, default=None)
    ap.add_argument("--light-tracing", action="store_true", help="our caustics from light paths")
    ap.add_argument("--rr", default=None, help="our roulette rule (default: the file's, throughput)")
    ap.add_argument("--variant", default=None, help="Mitsuba variant (default llvm_ad_rgb if DRJIT_LIBLLVM_PATH "
                                                    "is set, else scalar_rgb)")
    ap.add_argument("--out", default="out/compare", help="folder for images and the JSON result")
    ap.add_argument("-D", action="append", default=[], metavar="NAME=VALUE", help="scene parameter")
    a = ap.parse_args(argv)
    params = dict(kv.split("=", 1) for kv in a.D)
    if a.width:
        params["width"] = str(a.width)
    if a.height:
        params["height"] = str(a.height)
    if a.max_depth is not None:
        params["max_depth"] = str(a.max_depth)
    variant = a.variant or ("llvm_ad_rgb" if os.environ.get("DRJIT_LIBLLVM_PATH") else "scalar_rgb")
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    stem = Path(a.scene).stem + (f"_d{a.max_depth}" if a.max_depth is not None else "")

    import pathtracer

    ours_imgs, t_ours, t_compile = render_ours(a.scene, params, a.spp, a.batches, None, a.rr, a.light_tracing)
    mi_imgs, t_mi = render_mitsuba(a.scene, params, a.spp, a.batches, None, variant)
    ours, var_o = batch_stats(ours_imgs)
    ref, var_r = batch_stats(mi_imgs)
    result = compare(ours, var_o, ref, var_r)
    result.update(scene=a.scene, spp=a.spp, batches=a.batches, params=params, variant=variant,
                  seconds_ours=t_ours, seconds_mitsuba=t_mi, compile_seconds_ours=t_compile,
                  shape=list(ours.shape))
    pathtracer.write_image(str(out / f"{stem}_ours.exr"), ours.astype(np.float32))
    pathtracer.write_image(str(out / f"{stem}_mitsuba.exr"), ref.astype(np.float32))
    difference_png(out / f"{stem}_diff.png", ours, var_o, ref, var_r)
    with open(out / f"{stem}.json", "w") as f:
        json.dump(result, f, indent=1)
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
