"""Scene-building and statistics helpers for the tests (plain numpy; no Warp here)."""

from __future__ import annotations

import math

import numpy as np

from pathtracer.scene import Camera, Integrator, Material, RectLight, Scene, Sphere, Texture, TriangleMesh

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


# ------------------------------------------------------------------------------------------------
# scene transforms (hard cases: the same scene at other scales and places)

# Scene-model attribute names by how a similarity transform acts on them. transform_scene refuses any other array
# attribute, so a new primitive kind must be added here rather than silently left in place.
_POINT_ATTRS = {"center", "vertices", "points", "origin", "corner", "p0"}
_VECTOR_ATTRS = {"half_u", "half_v", "u", "v", "edge_u", "edge_v", "e1", "e2"}
_NORMAL_ATTRS = {"normal", "normals"}
_LENGTH_ATTRS = {"radius"}
_FRAME_ATTRS = {"rotation"}  # 3x3 object frames: rotated
_SURFACE_ATTRS = {"uvs"}  # texture coordinates: unchanged


def similarity(scale: float = 1.0, translate=(0.0, 0.0, 0.0), rotate=None) -> np.ndarray:
    """4x4 matrix x -> R (scale x) + translate (R a 3x3 rotation, identity by default)."""
    m = np.eye(4)
    r = np.eye(3) if rotate is None else np.asarray(rotate, dtype=np.float64)
    m[:3, :3] = float(scale) * r
    m[:3, 3] = np.asarray(translate, dtype=np.float64)
    return m


def transform_scene(scene: Scene, matrix) -> Scene:
    """A deep copy of ``scene`` with its geometry, lights and camera moved by the similarity ``matrix``
    (uniform scale, rotation, translation): the same picture, in other world coordinates.

    Radiance is invariant under a similarity, so a correct renderer gives the same image within noise. Points and
    centres get the full transform, edge vectors the linear part, normals the rotation, radii and the camera's
    clip distances the scale.
    """
    import copy
    import dataclasses

    m = np.asarray(matrix, dtype=np.float64)
    a, t = m[:3, :3], m[:3, 3]
    s = float(np.linalg.norm(a[:, 0]))
    if not (s > 0 and np.linalg.det(a) > 0 and np.allclose(a.T @ a, s * s * np.eye(3), rtol=1e-12, atol=0)):
        raise ValueError("transform_scene needs a similarity (uniform scale, rotation, translation; no mirroring)")
    rot = a / s
    out = copy.deepcopy(scene)

    def move(obj):
        for f in dataclasses.fields(obj):
            val = getattr(obj, f.name)
            if f.name in _LENGTH_ATTRS:
                setattr(obj, f.name, type(val)(val * s))
            elif f.name in _FRAME_ATTRS and val is not None:
                setattr(obj, f.name, rot @ val)
            elif f.name in _SURFACE_ATTRS:
                continue
            elif isinstance(val, np.ndarray) and val.dtype.kind == "f":
                pts = val.reshape(-1, 3)
                if f.name in _POINT_ATTRS:
                    new = pts @ a.T + t
                elif f.name in _VECTOR_ATTRS:
                    new = pts @ a.T
                elif f.name in _NORMAL_ATTRS:
                    new = pts @ rot.T
                else:
                    raise ValueError(f"transform_scene: unknown array attribute {type(obj).__name__}.{f.name}")
                setattr(obj, f.name, new.reshape(val.shape))

    for f in dataclasses.fields(out):
        items = getattr(out, f.name)
        if isinstance(items, list):
            for obj in items:
                if dataclasses.is_dataclass(obj) and not isinstance(obj, (Material, Texture)):
                    move(obj)
    cam = out.camera
    c2w = np.asarray(cam.to_world, dtype=np.float64).copy()
    c2w[:3, :3] = rot @ c2w[:3, :3]
    c2w[:3, 3] = a @ c2w[:3, 3] + t
    cam.to_world = c2w
    cam.near_clip = cam.near_clip * s
    cam.far_clip = cam.far_clip * s
    return out


# ------------------------------------------------------------------------------------------------
# two noisy images of the same quantity


def compare_within_noise(a, b, z_max: float = 4.0) -> dict:
    """Per-pixel, per-channel z of the difference of two independent renders (anything with ``mean`` and
    ``variance_of_mean``, e.g. ``PassSum``), and the z of the mean difference over the whole image.

    A value whose two variances are both 0 has z = 0 when the values are equal and inf otherwise.
    Images are (H, W, C). Returns pass_rate (fraction of values with |z| <= z_max), max_abs_z, mean_z (whole-image
    mean difference over its standard error, counting the channels of a pixel as fully correlated), n (number of
    values) and rel_diff (mean difference over the mean of the two images).
    """
    ma, mb = np.asarray(a.mean, np.float64), np.asarray(b.mean, np.float64)
    va, vb = np.asarray(a.variance_of_mean, np.float64), np.asarray(b.variance_of_mean, np.float64)
    diff = ma - mb
    var = va + vb
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.where(var > 0, diff / np.sqrt(var), np.where(diff == 0, 0.0, np.inf))
    az = np.abs(z)
    n = diff.size
    # The channels of a pixel share their paths (in a grey scene they are equal), so the whole-image mean is taken
    # over pixels of channel means, whose standard error is bounded by the mean of the channel standard errors.
    px_diff = diff.reshape(-1, diff.shape[-1]).mean(axis=1)
    px_se = np.sqrt(var.reshape(-1, var.shape[-1])).mean(axis=1)
    mean_se = math.sqrt(float((px_se**2).sum())) / len(px_se)
    mean_diff = float(px_diff.mean())
    if mean_se > 0:
        mean_z = mean_diff / mean_se
    else:
        mean_z = 0.0 if mean_diff == 0 else math.inf
    scale = 0.5 * (abs(float(ma.mean())) + abs(float(mb.mean())))
    return dict(pass_rate=float((az <= z_max).mean()), max_abs_z=float(az.max()), mean_z=float(mean_z), n=n,
                rel_diff=mean_diff / scale if scale > 0 else 0.0, z=z)


def camera_directions(scene: Scene, col, row, jx, jy) -> np.ndarray:
    """World-space unit directions of the camera rays through film points (col + jx, row + jy), row 0 at the top:
    the mapping of kernels/camera.py (Mitsuba's frame, local +x is image left), in float64."""
    tan_x, tan_y = scene.camera.tan_half_fov(scene.width, scene.height)
    fx = (np.asarray(col, np.float64) + jx) / scene.width
    fy = (np.asarray(row, np.float64) + jy) / scene.height
    local = np.stack(np.broadcast_arrays((1.0 - 2.0 * fx) * tan_x, (1.0 - 2.0 * fy) * tan_y, 1.0), axis=-1)
    d = local @ np.asarray(scene.camera.to_world, np.float64)[:3, :3].T
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def pixel_average(scene: Scene, f, sub: int = 8, with_variance: bool = False):
    """(H, W, ...) mean of ``f(directions)`` over a sub x sub grid of film points in every pixel (midpoint rule).

    with_variance: also return the variance of f over those points, which is the variance of one jittered sample
    of the pixel when f is deterministic per ray (the normal view, the emission seen directly).
    """
    rows, cols = np.mgrid[0:scene.height, 0:scene.width]
    offs = (np.arange(sub) + 0.5) / sub
    acc = acc2 = None
    for jy in offs:
        for jx in offs:
            v = np.asarray(f(camera_directions(scene, cols, rows, jx, jy)), np.float64)
            acc = v if acc is None else acc + v
            acc2 = v * v if acc2 is None else acc2 + v * v
    mean = acc / (sub * sub)
    if not with_variance:
        return mean
    return mean, np.maximum(acc2 / (sub * sub) - mean * mean, 0.0)
