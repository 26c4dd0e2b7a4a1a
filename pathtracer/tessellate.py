"""Mitsuba's ``disk`` and ``cylinder`` as fine triangle meshes, in their local frames (the loader applies to_world).

Why meshes: both then reuse every path the triangles already have (the BVH, smooth normals, area lights sampled
by area with MIS), and no kernel grows for two rarely used shapes. The price is a geometric error, kept far below
a pixel and below float32 noise in the emitted power:

- the disk is a regular N-gon (N = ``SEGMENTS``) scaled so that its area equals the disk's (pi r^2): an area
  light emits the same power, and the outline lies within 3.2e-6 r of the circle (``outline_error``);
- the cylinder is an N-sided prism scaled so that its lateral area equals the cylinder's (2 pi r h), with
  radial vertex normals (smooth shading, as Mitsuba's exact normal); its outline lies within 3.2e-6 r.

The disk is cut into rings whose segment count doubles outwards (8, 16, ..., N), so no vertex is shared by more
than 8 triangles: a fan from the centre would put N triangles' boxes around one point and every ray near the
centre would test them all.
"""

from __future__ import annotations

import numpy as np

SEGMENTS = 1024  # outline vertices of a disk and a cylinder


def disk_area_scale(n: int = SEGMENTS) -> float:
    """Radius scale that gives the regular n-gon inscribed in the unit circle the unit disk's area."""
    return float(np.sqrt(2.0 * np.pi / (n * np.sin(2.0 * np.pi / n))))


def cylinder_perimeter_scale(n: int = SEGMENTS) -> float:
    """Radius scale that gives the regular n-gon the unit circle's perimeter (so the prism its lateral area)."""
    return float((np.pi / n) / np.sin(np.pi / n))


def outline_error(scale: float, n: int = SEGMENTS) -> float:
    """Largest distance between the scaled n-gon's outline and the unit circle (vertices at ``scale``, edge
    midpoints at ``scale cos(pi / n)``)."""
    return float(max(scale - 1.0, 1.0 - scale * np.cos(np.pi / n)))


def disk(n: int = SEGMENTS) -> tuple[np.ndarray, np.ndarray]:
    """Mitsuba's unit disk (z = 0, normal +z): (vertices (V, 3), faces (F, 3)) wound counter-clockwise seen from +z.
    ``n`` must be 8 times a power of two."""
    if n < 8 or n & (n - 1):
        raise ValueError("disk segments must be a power of two >= 8")
    k = disk_area_scale(n)
    verts = [np.zeros(3)]
    faces = []
    counts = [8 * 2**j for j in range(int(np.log2(n // 8)) + 1)]
    starts = []
    for c in counts:
        starts.append(len(verts))
        r = k * c / n  # rings of equal segment length: the outermost at radius k
        phi = 2.0 * np.pi * np.arange(c) / c
        verts.extend(np.stack([r * np.cos(phi), r * np.sin(phi), np.zeros(c)], axis=1))
    first = starts[0]
    faces += [(0, first + i, first + (i + 1) % 8) for i in range(8)]
    for (a0, na), b0 in zip(zip(starts, counts), starts[1:]):
        nb = 2 * na
        for i in range(na):
            a, b = a0 + i, a0 + (i + 1) % na
            o0, o1, o2 = b0 + 2 * i, b0 + 2 * i + 1, b0 + (2 * i + 2) % nb
            faces += [(a, o0, o1), (a, o1, b), (b, o1, o2)]
    return np.asarray(verts, dtype=np.float64), np.asarray(faces, dtype=np.int64)


def cylinder(n: int = SEGMENTS) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mitsuba's unit cylinder (radius 1 around z, z in [0, 1], open ends, normals outwards): (vertices, faces,
    vertex normals), faces wound counter-clockwise seen from outside."""
    k = cylinder_perimeter_scale(n)
    phi = 2.0 * np.pi * np.arange(n) / n
    ring = np.stack([np.cos(phi), np.sin(phi), np.zeros(n)], axis=1)
    verts = np.concatenate([k * ring, k * ring + [0.0, 0.0, 1.0]])
    normals = np.concatenate([ring, ring])
    i = np.arange(n)
    j = (i + 1) % n
    faces = np.concatenate([np.stack([i, j, n + j], axis=1), np.stack([i, n + j, n + i], axis=1)])
    return verts, faces.astype(np.int64), normals
