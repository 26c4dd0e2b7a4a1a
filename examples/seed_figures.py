"""Reproduce the seed write-up's figures 1-9 (table in ../shared/SCENES.md) from the scene files in scenes/.

    python examples/seed_figures.py                 # every figure at the write-up's size (800x600) into docs/figures
    python examples/seed_figures.py 5 6 --scale 0.25 --out out/figs   # figures 5 and 6 at 200x150

The seed's "N bounces" is max_depth N + 1; figure 8's "max 100 bounces with Russian roulette" uses the seed's
roulette rule (stop with probability 0.2 after the first bounce).
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


SEED_LIGHT_SAMPLES = 8  # the write-up's K (our default is 1, see docs/performance.md)


@dataclass(frozen=True)
class Figure:
    name: str
    scene: str
    spp: int
    max_depth: int
    view: str = "radiance"
    rr: str = "throughput"
    what: str = ""


FIGURES = {
    "1": Figure("fig1_ray_direction", "cornell_box.xml", 1, 2, view="direction", what="debug: ray direction 0.5 dir + 0.5"),
    "2": Figure("fig2_normals", "cornell_box.xml", 1, 2, view="normal", what="debug: shading normals"),
    "3": Figure("fig3_antialiased", "cornell_box.xml", 10, 2, view="normal", what="anti-aliasing: jittered normals"),
    "4": Figure("fig4_direct", "cornell_box.xml", 10, 2, what="direct light (1 bounce)"),
    "5": Figure("fig5_soft_shadows", "cornell_box.xml", 100, 2, what="soft shadows (1 bounce)"),
    "6": Figure("fig6_global_illumination", "cornell_box.xml", 100, 4, what="global illumination (3 bounces)"),
    "7": Figure("fig7_mirror_sphere", "cornell_box_mirror.xml", 100, 4, what="mirror sphere (3 bounces)"),
    "8": Figure("fig8_russian_roulette", "cornell_box_mirror.xml", 500, 101, rr="seed",
                what="Russian roulette (max 100 bounces)"),
    "9c": Figure("fig9c_mirror_teapot", "teapot_in_box.xml", 50, 4, what="mirror teapot (3 bounces)"),
}


def command_line(key: str) -> str:
    """The CLI command that renders figure ``key`` at full size."""
    f = FIGURES[key]
    cmd = (f"pathtracer scenes/{f.scene} -o docs/figures/{f.name}.png --spp {f.spp} --max-depth {f.max_depth} "
           f"--light-samples {SEED_LIGHT_SAMPLES}")
    if f.view != "radiance":
        cmd += f" --view {f.view}"
    if f.rr != "throughput":
        cmd += f" --rr {f.rr}"
    return cmd


def render_figure(key: str, scale: float, out: Path, spp_scale: float = 1.0) -> Path:
    import pathtracer

    f = FIGURES[key]
    scene = pathtracer.load_file(ROOT / "scenes" / f.scene)
    scene.width = max(1, round(scene.width * scale))
    scene.height = max(1, round(scene.height * scale))
    spp = max(1, round(f.spp * spp_scale))
    stats: dict = {}
    t0 = time.perf_counter()
    image = pathtracer.render(scene, spp=spp, max_depth=f.max_depth, view=f.view, rr=f.rr, stats=stats,
                              light_samples=SEED_LIGHT_SAMPLES, progress=False)
    path = out / f"{f.name}.png"
    pathtracer.write_image(str(path), image, display=f.view != "radiance")
    print(f"figure {key:>2}: {path} {scene.width}x{scene.height} {spp} spp, {stats['seconds']:.1f} s render, "
          f"{time.perf_counter() - t0:.1f} s total")
    return path


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description="Reproduce the seed's figures.")
    ap.add_argument("figures", nargs="*", help=f"figure keys (default all): {' '.join(FIGURES)}")
    ap.add_argument("--scale", type=float, default=1.0, help="image size relative to 800x600")
    ap.add_argument("--spp-scale", type=float, default=1.0, help="sample count relative to the write-up's")
    ap.add_argument("--out", default=str(ROOT / "docs" / "figures"))
    ap.add_argument("--commands", action="store_true", help="print the CLI command of each figure and exit")
    a = ap.parse_args(argv)
    keys = a.figures or list(FIGURES)
    unknown = [k for k in keys if k not in FIGURES]
    if unknown:
        ap.error(f"unknown figure {unknown[0]!r} (known: {' '.join(FIGURES)})")
    if a.commands:
        for k in keys:
            print(f"{k}: {command_line(k)}")
        return 0
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    for k in keys:
        render_figure(k, a.scale, out, a.spp_scale)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
