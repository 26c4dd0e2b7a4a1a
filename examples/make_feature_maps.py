"""Write the small environment map the envmap feature scene uses (scenes/features/maps/sky_sun.exr): a 64 x 32
latitude-longitude sky, blue above the horizon and brown below, with a small bright sun, so that importance
sampling and the bilinear lookup both matter.

    python examples/make_feature_maps.py
"""

from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def sky_sun(width: int = 64, height: int = 32) -> np.ndarray:
    v = np.arange(height) / (height - 1)  # Mitsuba's rows: v = i / (H - 1), the first row the +y pole
    u = (np.arange(width) + 0.5) / width
    theta = np.pi * v[:, None]
    phi = 2 * np.pi * u[None, :]
    d = np.stack([np.sin(theta) * np.sin(phi), np.cos(theta) + 0 * phi, -np.sin(theta) * np.cos(phi)], -1)
    up = np.clip(d[..., 1], 0, 1)[..., None]
    img = np.where(d[..., 1:2] > 0, (0.3 + 0.7 * up) * np.array([0.35, 0.55, 1.0]), np.array([0.25, 0.18, 0.1]))
    sun = np.array([0.5, 0.6, 0.62])
    sun /= np.linalg.norm(sun)
    img = img + 40.0 * (d @ sun > 0.985)[..., None] * np.array([1.0, 0.9, 0.7])
    return img.astype(np.float32)


if __name__ == "__main__":
    import pathtracer

    out = ROOT / "scenes" / "features" / "maps" / "sky_sun.exr"
    out.parent.mkdir(parents=True, exist_ok=True)
    pathtracer.write_image(out, sky_sun())
    print(f"wrote {out}")
