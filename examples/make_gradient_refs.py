"""Make the Mitsuba 3 forward-mode gradient references (tests/data/grad_refs/): d image / d theta rendered by
Mitsuba's ``prb`` on our scene files, for the test suite to compare ``pathtracer.render_forward`` against.

    DRJIT_LIBLLVM_PATH=/usr/lib/x86_64-linux-gnu/libLLVM-19.so python examples/make_gradient_refs.py

As Mitsuba's documentation gives it: ``mi.load_file(path, optimize=False)``, ``dr.enable_grad(params[key])``,
``params.update()``, ``mi.render(..., integrator=prb)``, ``dr.forward(params[key])``, ``dr.grad(image)``: the tangent
1 in each of the parameter's three channels. Each reference is the mean of B renders of different seeds, with the
per-pixel variance of that mean beside it (``*_var.exr``); 32x24 pixels. Also Mitsuba's own gradient test
configurations (tests/gradient_configs.py: DiffuseAlbedo, DiffuseAlbedoGI, AreaLightRadiance,
DirectlyVisibleAreaLightRadiance), at 64x64, named ``mitsuba_config__<name>``.
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
sys.path.insert(0, str(ROOT / "tests"))
WIDTH, HEIGHT = 32, 24
CASES = [
    ("cornell_box", "red.reflectance.value"),
    ("cornell_box", "light.emitter.radiance.value"),
    ("cornell_box_mirror", "red.reflectance.value"),  # also seen through the mirror sphere
]
# (not the mirror's specular_reflectance: prb differentiates BSDF evaluations, and a delta lobe has none, so
# Mitsuba 3.9 raises "not attached to the AD graph"; tests/test_gradients.py checks ours by central differences)


def ref_name(scene: str, key: str) -> str:
    return f"{scene}__{key.split('.')[0]}_{key.split('.')[-2]}"


def main(argv=None) -> int:
    import drjit as dr
    import mitsuba as mi

    import pathtracer
    from make_mitsuba_refs import setup  # (this script's folder is on sys.path)

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--spp", type=int, default=16384)
    ap.add_argument("--batches", type=int, default=16)
    ap.add_argument("--out", default=str(ROOT / "tests" / "data" / "grad_refs"))
    a = ap.parse_args(argv)
    out, meta = setup(mi, a.out, WIDTH, HEIGHT, a.spp, a.batches)
    from gradient_configs import configs

    jobs = []
    for scene_name, key in CASES:
        path = ROOT / "scenes" / f"{scene_name}.xml"
        ours = pathtracer.load_file(str(path), width=WIDTH, height=HEIGHT)
        jobs.append((ref_name(scene_name, key), key, ours.integrator.max_depth, ours.integrator.rr_depth,
                     lambda path=path: mi.load_file(str(path), optimize=False, width=WIDTH, height=HEIGHT),
                     {"scene": f"scenes/{scene_name}.xml", "key": key}))
    for name, c in configs(mi.ScalarTransform4f).items():
        jobs.append((f"mitsuba_config__{name}", c["key"], c["max_depth"], 5,
                     lambda c=c: mi.load_dict(c["scene"], optimize=False),
                     {"config": name, "key": c["key"], "threshold": c["threshold"]}))
    for name, key, max_depth, rr_depth, load, info in jobs:
        scene = load()
        prb = mi.load_dict({"type": "prb", "max_depth": max_depth, "rr_depth": rr_depth})
        params = mi.traverse(scene)
        t0 = time.perf_counter()
        grads = []
        for b in range(a.batches):
            dr.enable_grad(params[key])
            params.update()
            image = mi.render(scene, params, integrator=prb, spp=a.spp // a.batches, seed=1000 + b)
            dr.forward(params[key])
            grads.append(np.array(dr.grad(image), dtype=np.float64))
            dr.disable_grad(params[key])
        g = np.stack(grads)
        mean = g.mean(axis=0)
        var = g.var(axis=0, ddof=1) / len(g)
        pathtracer.write_image(str(out / f"{name}.exr"), mean.astype(np.float32))
        pathtracer.write_image(str(out / f"{name}_var.exr"), var.astype(np.float32))
        meta["refs"][name] = dict(info, seconds=time.perf_counter() - t0)
        print(f"{name}: |grad| max {np.abs(mean).max():.3f}, mean {mean.mean():.4f}, "
              f"{time.perf_counter() - t0:.1f} s", flush=True)
    (out / "refs.json").write_text(json.dumps(meta, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
