"""The gallery (docs/gallery.md): feature scenes rendered by us and by Mitsuba 3 side by side, with the measured
bias ratio of the two.

    DRJIT_LIBLLVM_PATH=/usr/lib/x86_64-linux-gnu/libLLVM-19.so python examples/gallery.py

Each image is the mean of B independent batches (seeds) from each renderer; the per-pixel variance of each mean
comes from its batches. The bias ratio is relMSE(ours, Mitsuba) / (the relMSE their noise alone explains):
mean over pixels and channels of (ours - theirs)^2 / (ref^2 + 0.01), over the same of (var_ours + var_theirs).
About 1 means the two images differ by their noise only; a bias shows as a ratio well above 1.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

SCENES = [  # (feature scene, what it shows)
    ("bsdf_glass", "glass: dielectric spheres (bk7, water) and a thin dielectric pane"),
    ("bsdf_metal", "metal: smooth gold and copper, rough GGX aluminium and Beckmann chrome"),
    ("bsdf_plastic", "plastic: smooth plastic, nonlinear with a tinted coat, two-sided"),
    ("envmap", "an envmap: a lat-long sky with a sun, on diffuse and rough silver"),
    ("area_lights_shapes", "mesh lights: an emitting teapot (obj), cube and sphere"),
    ("textures", "a textured floor: checkerboard and bitmaps on rectangles, a cube and spheres"),
]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--width", type=int, default=160)
    ap.add_argument("--height", type=int, default=120)
    ap.add_argument("--spp", type=int, default=2048, help="samples per pixel per renderer (split into batches)")
    ap.add_argument("--batches", type=int, default=16)
    ap.add_argument("--out", default=str(ROOT / "docs" / "gallery"))
    ap.add_argument("--only", nargs="*", help="these scenes only, printed, not written to docs/gallery.md")
    a = ap.parse_args(argv)

    import mitsuba as mi

    import pathtracer

    mi.set_variant("llvm_ad_rgb" if os.environ.get("DRJIT_LIBLLVM_PATH") else "scalar_rgb")
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    per = a.spp // a.batches
    rows = []
    for name, what in SCENES:
        if a.only and name not in a.only:
            continue
        path = ROOT / "scenes" / "features" / f"{name}.xml"
        params = {"width": a.width, "height": a.height}
        scene = pathtracer.load_file(path, **params)
        t0 = time.perf_counter()
        ours = np.stack([pathtracer.render(scene, spp=per, seed=b, progress=False).astype(np.float64)
                         for b in range(a.batches)])
        t_ours = time.perf_counter() - t0
        mscene = mi.load_file(str(path), **{k: str(v) for k, v in params.items()})
        t0 = time.perf_counter()
        theirs = np.stack([np.array(mi.render(mscene, spp=per, seed=1000 + b), dtype=np.float64)[..., :3]
                           for b in range(a.batches)])
        t_theirs = time.perf_counter() - t0
        m_o, m_t = ours.mean(0), theirs.mean(0)
        v = ours.var(0, ddof=1) / a.batches + theirs.var(0, ddof=1) / a.batches
        denom = m_t * m_t + 0.01
        ratio = float(np.mean((m_o - m_t) ** 2 / denom) / np.mean(v / denom))
        z_mean = float((ours.mean(axis=(1, 2, 3)).mean() - theirs.mean(axis=(1, 2, 3)).mean()) / np.sqrt(
            ours.mean(axis=(1, 2, 3)).var(ddof=1) / a.batches + theirs.mean(axis=(1, 2, 3)).var(ddof=1) / a.batches))
        side = np.concatenate([m_o, np.ones((a.height, 4, 3)), m_t], axis=1).astype(np.float32)
        pathtracer.write_image(out / f"{name}.png", side)
        rows.append({"scene": name, "what": what, "bias_ratio": ratio, "image_mean_z": z_mean,
                     "seconds_ours": t_ours, "seconds_mitsuba": t_theirs})
        print(f"{name}: bias ratio {ratio:.3f}, image mean z {z_mean:+.2f}, ours {t_ours:.1f} s, "
              f"Mitsuba {t_theirs:.1f} s", flush=True)
    if a.only:
        return 0
    meta = {"width": a.width, "height": a.height, "spp": a.spp, "batches": a.batches, "mitsuba": mi.__version__,
            "variant": mi.variant(), "scenes": rows}
    (out / "gallery.json").write_text(json.dumps(meta, indent=1))
    lines = ["# Gallery: feature scenes, ours (left) and Mitsuba 3 (right)", "",
             f"Made by `python examples/gallery.py`: {a.width}x{a.height}, {a.spp} spp each in {a.batches} batches, "
             f"Mitsuba {mi.__version__} `{mi.variant()}`. The bias ratio is relMSE(ours, Mitsuba) over the relMSE "
             "that the two images' own noise explains (1: they differ by noise only). The image mean z compares "
             "the two images' means with their batch errors. Timings include each renderer's kernel compile on its "
             "first batch and are not a speed comparison (see docs/performance.md for that).", "",
             "| scene | shows | bias ratio | image mean z |", "|---|---|---|---|"]
    lines += [f"| `scenes/features/{r['scene']}.xml` | {r['what']} | {r['bias_ratio']:.3f} | {r['image_mean_z']:+.2f} |"
              for r in rows]
    lines.append("")
    for r in rows:
        lines += [f"## {r['scene']}", "", r["what"], "", f"![{r['scene']}: ours left, Mitsuba right](gallery/{r['scene']}.png)", ""]
    (ROOT / "docs" / "gallery.md").write_text("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
