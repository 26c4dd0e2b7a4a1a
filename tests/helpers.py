"""Scene-building and statistics helpers for the tests (plain numpy; no Warp here)."""

from __future__ import annotations

import math

import numpy as np

from pathtracer.scene import Camera, Integrator, Material, RectLight, Scene, Sphere, TriangleMesh

# ------------------------------------------------------------------------------------------------
# cameras and scenes


def lookat(origin, target, up=(0.0, 1.0, 0.0)) -> np.ndarray:
    """4x4 camera-to-world of Mitsuba's lookat: columns (left, up, forward, origin)."""
    o, t, u = (np.asarray(x, dtype=np.float64) for x in (origin, target, up))
    d = t - o
    d /= np.linalg.norm(d)
    left = np.cross(u, d)
    left /= np.linalg.norm(left)
    new_up = np.cross(d, left)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = left, new_up, d, o
    return m


def make_scene(origin, target, fov, width, height, up=(0.0, 1.0, 0.0), fov_axis="x", max_depth=-1,
               rr_depth=5, near_clip=1e-2, far_clip=1e4) -> Scene:
    cam = Camera(lookat(origin, target, up), float(fov), fov_axis, near_clip=near_clip, far_clip=far_clip)
    return Scene(camera=cam, width=width, height=height, spp=1,
                 integrator=Integrator(max_depth=max_depth, rr_depth=rr_depth))


def material(scene: Scene, kind: str, rgb, twosided: bool = False) -> int:
    if np.isscalar(rgb):
        rgb = (rgb, rgb, rgb)
    return scene.add_material(Material(kind, tuple(float(c) for c in rgb), twosided))


def add_rect(scene: Scene, center, half_u, half_v, normal, mat: int, radiance=None, name: str = "") -> int:
    """Parallelogram ``center + s half_u + t half_v`` (s, t in [-1, 1]) as two triangles facing ``normal``.

    With ``radiance`` it is also a one-sided RectLight emitting to the side of ``normal``. Returns the mesh index.
    """
    c, u, v, n = (np.asarray(x, dtype=np.float64) for x in (center, half_u, half_v, normal))
    n = n / np.linalg.norm(n)
    verts = np.array([c - u - v, c + u - v, c + u + v, c - u + v])
    return _add_quad(scene, verts, n, mat, radiance, name, (c, u, v))


def add_quad(scene: Scene, corners, normal, mat: int, radiance=None, name: str = "") -> int:
    """Quad from 4 exact corners in order (a parallelogram), facing ``normal``; light optional as add_rect."""
    verts = np.asarray(corners, dtype=np.float64).reshape(4, 3)
    n = np.asarray(normal, dtype=np.float64)
    n = n / np.linalg.norm(n)
    c = verts.mean(axis=0)
    u = 0.5 * (verts[1] - verts[0])
    v = 0.5 * (verts[3] - verts[0])
    return _add_quad(scene, verts, n, mat, radiance, name, (c, u, v))


def _add_quad(scene, verts, n, mat, radiance, name, cuv) -> int:
    faces = np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int64)
    if np.dot(np.cross(verts[1] - verts[0], verts[2] - verts[0]), n) < 0:
        faces = faces[:, ::-1].copy()
    light = -1
    if radiance is not None:
        if np.isscalar(radiance):
            radiance = (radiance, radiance, radiance)
        c, u, v = cuv
        scene.lights.append(RectLight(c.copy(), u.copy(), v.copy(), n.copy(), tuple(float(x) for x in radiance)))
        light = len(scene.lights) - 1
    scene.meshes.append(TriangleMesh(verts, faces, None, mat, light=light, name=name))
    return len(scene.meshes) - 1


def square(scene: Scene, center, side: float, normal, mat: int, radiance=None) -> int:
    """The seed's Square(center, side, normal): ref (0,1,0) if |n.x| > 0.9 else (1,0,0), t = n x ref, b = n x t."""
    n = np.asarray(normal, dtype=np.float64)
    n = n / np.linalg.norm(n)
    ref = np.array([0.0, 1.0, 0.0]) if abs(n[0]) > 0.9 else np.array([1.0, 0.0, 0.0])
    t = np.cross(n, ref)
    t /= np.linalg.norm(t)
    b = np.cross(n, t)
    b /= np.linalg.norm(b)
    return add_rect(scene, center, t * side / 2, b * side / 2, n, mat, radiance)


def add_furnace_cube(scene: Scene, half: float, mat: int, radiance) -> None:
    """Six inward-facing faces of the cube [-half, half]^3, built from the 8 exact corners (watertight edges),
    each one a one-sided light of ``radiance`` (None: no lights) with material ``mat``."""
    h = float(half)
    for axis in range(3):
        for sign in (-1.0, 1.0):
            a1, a2 = [k for k in range(3) if k != axis]
            corners = []
            for s1, s2 in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
                p = np.zeros(3)
                p[axis], p[a1], p[a2] = sign * h, s1 * h, s2 * h
                corners.append(p)
            n = np.zeros(3)
            n[axis] = -sign  # inward
            add_quad(scene, corners, n, mat, radiance)


def add_sphere(scene: Scene, center, radius: float, mat: int) -> None:
    scene.spheres.append(Sphere(np.asarray(center, dtype=np.float64), float(radius), mat))


# ------------------------------------------------------------------------------------------------
# analytic truths


def square_axis_irradiance(L: float, s: float, h: float) -> float:
    """TESTING.md truth 1: on-axis irradiance at height h under a square of half-side s: 4 L X atan(X)."""
    x = s / math.sqrt(h * h + s * s)
    return 4.0 * L * x * math.atan(x)


def polygon_irradiance(L: float, p, n, vertices) -> float:
    """Lambert's formula: E = (L/2) |sum_i Theta_i (Gamma_i . n)| for a polygon seen from point p, normal n."""
    p, n = np.asarray(p, float), np.asarray(n, float)
    u = [np.asarray(v, float) - p for v in vertices]
    u = [x / np.linalg.norm(x) for x in u]
    total = 0.0
    for i in range(len(u)):
        a, b = u[i], u[(i + 1) % len(u)]
        theta = math.acos(np.clip(np.dot(a, b), -1.0, 1.0))
        g = np.cross(a, b)
        total += theta * np.dot(g / np.linalg.norm(g), n)
    return 0.5 * L * abs(total)


def furnace_radiance(Le: float, albedo: float, max_depth: int) -> float:
    """Radiance everywhere in the furnace (TESTING.md truth 2) for the integrator's max_depth.

    kernels/integrator.py counts emission at the first hit (vertex 0) and does next-event estimation at diffuse
    vertices with depth + 1 < max_depth, i.e. at vertices 0 .. D - 2: N = D - 1 diffuse bounces, and
    L = Le (1 + a + ... + a^(D-1)) = Le (1 - a^D) / (1 - a). Unlimited (-1): Le / (1 - a).
    """
    if max_depth < 0:
        return Le / (1.0 - albedo)
    return Le * sum(albedo**k for k in range(max_depth))


# ------------------------------------------------------------------------------------------------
# statistics


def batch_z(values, expected: float) -> tuple[float, float, float]:
    """Mean of B independent batch estimates, its standard error from their spread, and z against ``expected``.

    A zero standard error gives z = 0 on an exact match and inf otherwise.
    """
    v = np.asarray(values, dtype=np.float64).reshape(-1)
    assert v.size >= 2
    mean = float(v.mean())
    se = float(v.std(ddof=1) / math.sqrt(v.size))
    if se == 0.0:
        return mean, se, 0.0 if mean == expected else math.inf
    return mean, se, (mean - expected) / se


def chi2_upper(dof: int, z: float = 4.0) -> float:
    """An upper bound for a chi-square(dof) statistic: Wilson-Hilferty quantile at ``z`` standard normals.

    z = 4 is a one-sided tail probability of about 3e-5.
    """
    k = float(dof)
    return k * (1.0 - 2.0 / (9.0 * k) + z * math.sqrt(2.0 / (9.0 * k))) ** 3


def chi2_stat(counts, expected) -> float:
    counts = np.asarray(counts, dtype=np.float64)
    expected = np.asarray(expected, dtype=np.float64)
    return float(((counts - expected) ** 2 / expected).sum())
