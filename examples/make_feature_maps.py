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
    counts, float32 positions, optional normals and texture coordinates, uint32 indices), then the meshes' offsets
    and their count. ``meshes``: (name, vertices, faces, normals or None[, uv or None])."""
    import struct
    import zlib

    out, offsets = bytearray(), []
    for name, v, f, n, *rest in meshes:
        uv = rest[0] if rest else None
        offsets.append(len(out))
        flags = 0x1000 | (0x0001 if n is not None else 0) | (0x0002 if uv is not None else 0)
        body = struct.pack("<I", flags)
        if version == 4:
            body += name.encode() + b"\0"
        body += struct.pack("<QQ", len(v), len(f)) + np.asarray(v, "<f4").tobytes()
        if n is not None:
            body += np.asarray(n, "<f4").tobytes()
        if uv is not None:
            body += np.asarray(uv, "<f4").tobytes()
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


def uv_sphere_obj(n_phi: int = 24, n_theta: int = 12) -> str:
    """A unit sphere as an OBJ with its own texture coordinates (u = phi / 2 pi, v = theta / pi as written, so
    flip_tex_coords matters) and normals: the seam at phi = 0 shares positions but not vt indices, so it is split
    into two vertices there, as Mitsuba and trimesh both do."""
    lines = ["# uv sphere: written by examples/make_feature_maps.py"]
    for j in range(n_theta + 1):
        for i in range(n_phi + 1):
            th, ph = np.pi * j / n_theta, 2 * np.pi * (i % n_phi) / n_phi
            x, y, z = np.sin(th) * np.cos(ph), np.cos(th), np.sin(th) * np.sin(ph)
            if i < n_phi:
                lines.append(f"v {x:.6f} {y:.6f} {z:.6f}")
                lines.append(f"vn {x:.6f} {y:.6f} {z:.6f}")
    for j in range(n_theta + 1):
        for i in range(n_phi + 1):
            lines.append(f"vt {i / n_phi:.6f} {j / n_theta:.6f}")

    def corner(i, j):
        v = j * n_phi + (i % n_phi) + 1
        return f"{v}/{j * (n_phi + 1) + i + 1}/{v}"

    for j in range(n_theta):
        for i in range(n_phi):
            a, b, c, d = corner(i, j), corner(i + 1, j), corner(i + 1, j + 1), corner(i, j + 1)
            if j > 0:
                lines.append(f"f {a} {b} {c}")
            if j < n_theta - 1:
                lines.append(f"f {a} {c} {d}")
    return "\n".join(lines) + "\n"


def wavy_grid(n: int = 12):
    """A gently curved n x n grid over [-1, 1]^2 in xz with per-vertex uv in [0, 1]^2: (vertices, faces, uv)."""
    t = np.linspace(-1.0, 1.0, n + 1)
    x, z = np.meshgrid(t, t)
    y = 0.15 * np.sin(2.0 * x) * np.cos(1.5 * z)
    v = np.stack([x, y, z], -1).reshape(-1, 3)
    uv = np.stack([(x + 1) / 2, (z + 1) / 2], -1).reshape(-1, 2)
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, d = idx[:-1, :-1], idx[:-1, 1:], idx[1:, 1:], idx[1:, :-1]
    f = np.concatenate([np.stack([a, c, b], -1).reshape(-1, 3), np.stack([a, d, c], -1).reshape(-1, 3)])
    return v, f, uv


def ply_with_uv(v: np.ndarray, f: np.ndarray, uv: np.ndarray) -> str:
    head = ["ply", "format ascii 1.0", f"element vertex {len(v)}", "property float x", "property float y",
            "property float z", "property float u", "property float v", f"element face {len(f)}",
            "property list uchar int vertex_indices", "end_header"]
    body = [f"{p[0]:.6f} {p[1]:.6f} {p[2]:.6f} {t[0]:.6f} {t[1]:.6f}" for p, t in zip(v, uv)]
    body += [f"3 {a} {b} {c}" for a, b, c in f]
    return "\n".join(head + body) + "\n"


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
    # textured meshes (scenes/features/textures_meshes.xml): an OBJ sphere with vt and a seam, a PLY grid with u, v,
    # and a serialized grid with texture coordinates
    (out.parent / "uv_sphere.obj").write_text(uv_sphere_obj())
    gv, gf, guv = wavy_grid()
    (out.parent / "uv_grid.ply").write_text(ply_with_uv(gv, gf, guv))
    write_serialized(out.parent / "uv_grid.serialized", [("grid", gv, gf, None, guv)])
    print(f"wrote {out.parent / 'uv_sphere.obj'}, uv_grid.ply and uv_grid.serialized")
