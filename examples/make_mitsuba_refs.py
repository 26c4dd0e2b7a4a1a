"""Make the small Mitsuba 3 references the test suite compares against (tests/data/refs/), so that the tests need
no Mitsuba: every scene in scenes/ at its own max_depth and as direct lighting (max_depth 2).

    DRJIT_LIBLLVM_PATH=/usr/lib/x86_64-linux-gnu/libLLVM-19.so python examples/make_mitsuba_refs.py

Each reference is the mean of B independent Mitsuba renders (different seeds); beside it goes the per-pixel
variance of that mean (``*_var.exr``), so a test can tell a real difference from the reference's own noise.
Sizes are small (64x48, float32 EXR: about 40 KB each).
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

WIDTH, HEIGHT = 64, 48
SCENES = ["cornell_box", "cornell_box_mirror", "teapot_in_box", "open_sky"]


FEATURES = ROOT / "scenes" / "features"  # one small scene per loader or renderer feature (issue 10)


def cases() -> list[tuple[str, int | None]]:
    """(scene path below scenes/ without .xml, max_depth override): the seed scenes at their own depth (None) and as
    direct lighting (2); each feature scene at its own depth."""
    seed = [(s, d) for s in SCENES for d in (None, 2)]
    return seed + [(f"features/{p.stem}", None) for p in sorted(FEATURES.glob("*.xml"))]


def ref_name(scene: str, max_depth: int | None) -> str:
    scene = scene.replace("features/", "feature_")
    return scene if max_depth is None else f"{scene}_d{max_depth}"


def setup(mi, out_dir: str, width: int, height: int, spp: int, batches: int) -> tuple[Path, dict]:
    """Mitsuba's LLVM variant where DRJIT_LIBLLVM_PATH is set (else scalar), the output folder made, and the
    references' metadata started (also examples/make_gradient_refs.py)."""
    mi.set_variant("llvm_ad_rgb" if os.environ.get("DRJIT_LIBLLVM_PATH") else "scalar_rgb")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    meta = {"width": width, "height": height, "spp": spp, "batches": batches, "mitsuba": mi.__version__,
            "variant": mi.variant(), "refs": {}}
    return out, meta


def main(argv=None) -> int:
    import mitsuba as mi

    import pathtracer

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--spp", type=int, default=65536, help="samples per pixel in all (split into batches)")
    ap.add_argument("--batches", type=int, default=16)
    ap.add_argument("--out", default=str(ROOT / "tests" / "data" / "refs"))
    ap.add_argument("--only", nargs="*", help="make only these references (names as in refs.json); keep the rest")
    a = ap.parse_args(argv)
    out, meta = setup(mi, a.out, WIDTH, HEIGHT, a.spp, a.batches)
    if a.only:
        old = json.loads((out / "refs.json").read_text())
        if (old["width"], old["height"], old["spp"], old["batches"]) != (WIDTH, HEIGHT, a.spp, a.batches):
            raise SystemExit("--only: refs.json was made with other sizes; make them all again")
        meta["refs"] = old["refs"]
    for scene_name, depth in cases():
        if a.only and ref_name(scene_name, depth) not in a.only:
            continue
        params = {"width": str(WIDTH), "height": str(HEIGHT)}
        if depth is not None:
            params["max_depth"] = str(depth)
        scene = mi.load_file(str(ROOT / "scenes" / f"{scene_name}.xml"), **params)
        t0 = time.perf_counter()
        per = a.spp // a.batches
        full = np.stack([np.array(mi.render(scene, spp=per, seed=b), dtype=np.float64) for b in range(a.batches)])
        fmean = full.mean(axis=0).astype(np.float32)
        fvar = (full.var(axis=0, ddof=1) / a.batches).astype(np.float32)
        name = ref_name(scene_name, depth)
        # the integrator's layers (the moment integrator's XYZ and m2_ XYZ), three channels each, in the
        # reference's own file: channels <layer>.X, .Y, .Z beside R, G, B
        aovs = scene.integrator().aov_names()
        layer_names = [aovs[i].rsplit(".", 1)[0] for i in range(0, len(aovs), 3)]
        layers = {n: fmean[..., 3 + 3 * i:6 + 3 * i] for i, n in enumerate(layer_names)}
        layers_var = {n: fvar[..., 3 + 3 * i:6 + 3 * i] for i, n in enumerate(layer_names)}
        mean, var = fmean[..., :3], fvar[..., :3]
        pathtracer.write_image(out / f"{name}.exr", mean, layers=layers or None)
        pathtracer.write_image(out / f"{name}_var.exr", var, layers=layers_var or None)
        meta["refs"][name] = {"scene": f"scenes/{scene_name}.xml", "max_depth": depth,
                              "group": "feature" if scene_name.startswith("features/") else "seed"}
        print(f"{name}: mean {mean.mean():.5f}, {time.perf_counter() - t0:.1f} s", flush=True)
    (out / "refs.json").write_text(json.dumps(meta, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
