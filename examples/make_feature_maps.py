"""Write the small images the feature scenes use (scenes/features/maps/): the envmap scene's sky_sun.exr, a 64 x 32
latitude-longitude sky, blue above the horizon and brown below, with a small bright sun, so that importance
sampling and the bilinear lookup both matter; and the texture scene's tiles.png, an 8 x 6 8-bit sRGB image of
coloured tiles with an asymmetric mark, so that a flipped or shifted lookup shows.

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


def write_serialized(path: Path, meshes: list, version: int = 4) -> None:
    """Mitsuba's serialized format (src/shapes/serialized.cpp): per mesh the header and a zlib stream (flags, name,
    counts, float32 positions, optional normals, uint32 indices), then the meshes' offsets and their count."""
    import struct
    import zlib

    out, offsets = bytearray(), []
    for name, v, f, n in meshes:
        offsets.append(len(out))
        flags = 0x1000 | (0x0001 if n is not None else 0)
        body = struct.pack("<I", flags)
        if version == 4:
            body += name.encode() + b"\0"
        body += struct.pack("<QQ", len(v), len(f)) + np.asarray(v, "<f4").tobytes()
        if n is not None:
            body += np.asarray(n, "<f4").tobytes()
        body += np.asarray(f, "<u4").tobytes()
        out += struct.pack("<hh", 0x041C, version) + zlib.compress(body)
    fmt = "<Q" if version == 4 else "<I"
    for o in offsets:
        out += struct.pack(fmt, o)
    out += struct.pack("<I", len(meshes))
    path.write_bytes(bytes(out))


def tiles(width: int = 8, height: int = 6) -> np.ndarray:
    """8-bit sRGB values (H, W, 3)."""
    y, x = np.mgrid[0:height, 0:width]
    img = np.stack([40 + 200 * (x % 2), 60 + 30 * y, 220 - 25 * x], -1)
    img[0, 0] = (255, 255, 0)  # the top-left texel: v = 0, u = 0 in Mitsuba's convention
    return img.astype(np.uint8)


if __name__ == "__main__":
    from PIL import Image

    import pathtracer

    out = ROOT / "scenes" / "features" / "maps" / "sky_sun.exr"
    out.parent.mkdir(parents=True, exist_ok=True)
    pathtracer.write_image(out, sky_sun())
    print(f"wrote {out}")
    Image.fromarray(tiles()).save(out.parent / "tiles.png")
    print(f"wrote {out.parent / 'tiles.png'}")
    # the teapot as mesh 1 of a two-mesh serialized file (mesh 0: a single triangle), with its vertex normals
    from pathtracer import meshio

    part = meshio.read_mesh(ROOT / "scenes" / "meshes" / "teapot.obj", "obj")[0]
    tri = ("triangle", [[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]], None)
    write_serialized(out.parent / "two_meshes.serialized",
                     [tri, ("teapot", part.vertices, part.faces, part.normals)])
    print(f"wrote {out.parent / 'two_meshes.serialized'}")
