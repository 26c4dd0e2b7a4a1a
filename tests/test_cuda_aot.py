"""CUDA readiness without a GPU: every kernel variant the seed scenes use compiles to a CUDA cubin (sm_90) through
Warp's bundled NVRTC (``wp.compile_aot_module``), so CUDA-only code generation errors turn CI red on a CPU machine.

The variants: each seed scene with the defaults (path tracing with Sobol', and with light tracing where "auto" pilots
it, plus the light tracer's own kernels), the seed's figures' options (debug views, the seed's roulette rule,
independent sampling), the other triangle backend on the teapot, and the forward-mode and one-pass adjoint
(backward) variants of the two Cornell boxes. Cubins are kept under the Warp cache, so a
second run only checks they exist.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import pytest
import warp as wp

import pathtracer
from kernels.integrator import render_kernel
from kernels.light_tracer import fold_pass, light_kernel
from pathtracer.device_scene import DeviceScene

SCENES = Path(__file__).resolve().parents[1] / "scenes"
ARCH = 90
OUT = Path(os.environ["WARP_CACHE_PATH"]) / f"aot_sm{ARCH}"

OPTIONS = {
    "default": {},
    "independent": {"sampler": "independent"},
    "normal view": {"view": "normal"},
    "direction view": {"view": "direction"},
    "seed roulette": {"rr": "seed"},
    "solid-angle lights": {"light_sampling": "solid_angle"},
    "warp triangles": {"triangles": "warp"},
}


def _variants():
    """(id, scene file, features, with the light tracer) for every distinct variant."""
    seen, out = set(), []
    features = sorted((SCENES / "features").glob("*.xml"))  # one scene per feature: its default variant only
    for path in sorted(SCENES.glob("*.xml")) + features:
        scene = pathtracer.load_file(path, width=8, height=6)
        for name, opts in OPTIONS.items():
            if path in features and name != "default":
                continue
            opts = {"sampler": "sobol", **opts}
            f = DeviceScene.features(scene, **opts)
            if name == "warp triangles" and not f.meshes:
                continue
            lt_options = [False]
            if name == "default" and f.mirrors and f.lights:
                lt_options.append(True)  # what render()'s auto pilots
            for lt in lt_options:
                fv = dataclasses.replace(f, light_tracing=lt)
                if fv in seen:
                    continue
                seen.add(fv)
                out.append(pytest.param(fv, id=f"{path.stem}-{name}" + ("-light_tracing" if lt else "")))
        if path.stem in ("cornell_box", "cornell_box_mirror"):  # the gradient variants (pathtracer/gradients.py)
            for mode in ("gradient", "backward"):
                for sampler in ("sobol", "independent"):
                    fv = dataclasses.replace(DeviceScene.features(scene, sampler=sampler), **{mode: True})
                    if fv not in seen:
                        seen.add(fv)
                        out.append(pytest.param(fv, id=f"{path.stem}-{mode}-{sampler}"))
    return out


VARIANTS = _variants()


def _compile(module) -> list[Path]:
    OUT.mkdir(parents=True, exist_ok=True)
    wp.compile_aot_module(module, arch=ARCH, module_dir=str(OUT))
    name = module.get_module_identifier() if hasattr(module, "get_module_identifier") else None
    return [p for p in OUT.glob("*.cubin") if name is None or name in p.name]


def test_there_are_variants_for_every_seed_scene():
    """Each seed scene's default variant is compiled (scenes with equal features share one: the open sky has the
    mirror box's)."""
    compiled = {p.values[0] for p in VARIANTS}
    for stem in ("cornell_box", "cornell_box_mirror", "teapot_in_box", "open_sky"):
        scene = pathtracer.load_file(SCENES / f"{stem}.xml", width=8, height=6)
        assert DeviceScene.features(scene, sampler="sobol") in compiled, stem
    ids = [p.id for p in VARIANTS]
    assert any(i.endswith("-light_tracing") for i in ids) and any("warp triangles" in i for i in ids)


@pytest.mark.parametrize("features", VARIANTS)
def test_variant_compiles_for_cuda(features):
    kernel = render_kernel(features)
    cubins = _compile(kernel.module)
    assert cubins and all(p.stat().st_size > 0 for p in cubins)
    if features.light_tracing:
        assert _compile(light_kernel(features).module)


def test_light_tracer_fold_compiles_for_cuda():
    assert _compile(fold_pass.module)
