"""Uploads a ``Scene`` to one Warp device: rectangles and cubes as analytic quads, one box tree
(``pathtracer.bvh``) over every other triangle, and flat arrays for the rest."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import warp as wp

from kernels.integrator import LIGHT_SAMPLINGS, RR_RULES, SAMPLERS, TRIANGLES, VIEWS, Features
from kernels.bsdfs import DISTRIBUTIONS
from kernels.mesh import INSIDE_ULPS
from kernels.offset import FLT_EPS
from kernels.types import CameraData, SceneData
from kernels.triangle import STACK_SIZE, STACK_SLACK
from pathtracer.bvh import BoxTree, WideTree, build_tree, collapse_wide, leaf_lanes
from pathtracer.errors import RenderError
from pathtracer.meshio import join_arrays
from pathtracer.microfacet_tables import external_transmittance, internal_reflectance
from pathtracer.rfilter import filter_cdf
from pathtracer.scene import MIRROR, Scene, TriangleMesh


def _vec3(a, device) -> wp.array:
    # on the CPU the array wraps the numpy buffer (Warp keeps a reference): no second copy of millions of vertices
    return wp.array(np.ascontiguousarray(a, dtype=np.float32).reshape(-1, 3), dtype=wp.vec3, device=device,
                    copy=device != "cpu")


def _vec3d(a, device) -> wp.array:
    return wp.array(np.asarray(a, dtype=np.float64).reshape(-1, 3), dtype=wp.vec3d, device=device)


def _vec2d(a, device) -> wp.array:
    return wp.array(np.asarray(a, dtype=np.float64).reshape(-1, 2), dtype=wp.vec2d, device=device)


def quad_inside(half_u: np.ndarray, half_v: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """(n, 2) bounds on |s|, |r| of a quad's hit records (kernels/quad.py: quad_hit): INSIDE_ULPS float32 ulps of
    the quad's coordinates (``scale``, float32 as on the device) inside each edge, measured across the edge."""
    e = (np.float32(INSIDE_ULPS) * np.float32(FLT_EPS)
         * np.asarray(scale, dtype=np.float32)).astype(np.float64)
    area = np.linalg.norm(np.cross(half_u, half_v), axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.stack([1.0 - e * np.linalg.norm(half_v, axis=1) / area,
                         1.0 - e * np.linalg.norm(half_u, axis=1) / area], axis=1).reshape(-1, 2)


def _arr(a, dtype, device) -> wp.array:
    np_dtype = np.int32 if dtype == wp.int32 else np.float32
    return wp.array(np.ascontiguousarray(a, dtype=np_dtype).reshape(-1), dtype=dtype, device=device,
                    copy=device != "cpu")


def _face_normals(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return np.divide(n, length, out=np.zeros_like(n), where=length > 0)


def triangle_box_pad(points: np.ndarray, camera_origin) -> float:
    """How far every triangle's box is grown so that the BVH's float32 slab test never rejects a box its ray meets.

    The slab test computes each t as (lower - o) / d: a relative error of a few float32 ulps of |t|, i.e. an
    absolute error of a few ulps of the coordinates involved. For ray origins and vertices within
    max |coordinate| <= R, R the largest coordinate of the meshes and the camera, |t| <= 2 sqrt(3) R, and
    2^-18 R (32 ulps of R) leaves a factor of about 5 over the error bound. (A ray from a surface much farther out,
    say a huge ground sphere, gets a proportionally thinner margin: R is not taken over those, which would make the
    boxes overlap.) The cost is a few extra candidate triangles near each box, tested by the watertight test.
    """
    r = float(np.abs(points).max()) if len(points) else 0.0
    r = max(r, float(np.abs(np.asarray(camera_origin, dtype=np.float64)).max()))
    return 2.0**-18 * r


def _triangle_tree(points: np.ndarray, faces: np.ndarray, pad: float) -> BoxTree:
    """The box tree over the faces' float32 boxes grown by ``pad`` (rounded outward)."""
    p32 = np.asarray(points, dtype=np.float32)  # the coordinates the kernels test
    a, b, c = p32[faces[:, 0]], p32[faces[:, 1]], p32[faces[:, 2]]
    lo = np.minimum(np.minimum(a, b), c).astype(np.float64)  # (a reduction over a length-3 axis is 5x slower)
    hi = np.maximum(np.maximum(a, b), c).astype(np.float64)
    lo = np.nextafter((lo - pad).astype(np.float32), np.float32(-np.inf))
    hi = np.nextafter((hi + pad).astype(np.float32), np.float32(np.inf))
    return build_tree(lo, hi)


def leaf_soa(points: np.ndarray, faces: np.ndarray, tree: WideTree) -> tuple[np.ndarray, np.ndarray]:
    """(9 leaves, 4) corner coordinates of each leaf block's triangles, lane by lane (NaN in unused lanes), as
    ``kernels.triangle.leaf_closest`` reads them; and (4 leaves,) the face in each lane (-1 unused)."""
    from kernels.bvh_build import leaf_soa as kernel

    lanes = leaf_lanes(tree).astype(np.int32).reshape(-1)  # 4 per leaf
    soa = wp.empty(9 * (len(lanes) // 4), dtype=wp.vec4, device="cpu")  # the kernel writes every entry
    wp.launch(kernel, dim=len(lanes) // 4, device="cpu",
              inputs=[wp.array(np.ascontiguousarray(points, dtype=np.float32), dtype=wp.vec3, device="cpu"),
                      wp.array(np.ascontiguousarray(faces, dtype=np.int32).reshape(-1), dtype=wp.int32,
                               device="cpu"), wp.array(lanes, dtype=wp.int32, device="cpu")], outputs=[soa])
    return soa.numpy().reshape(-1, 4), lanes


QUAD_SHAPES = ("rectangle", "cube")
PARALLELOGRAM_TOL = 1e-7  # relative: far below float32 resolution
RECTANGLE_TOL = 1e-6  # relative: |half_u . half_v| <= this |half_u| |half_v| makes a light a rectangle


def is_rectangle(half_u, half_v) -> bool:
    """Are the parallelogram's edges orthogonal (within ``RECTANGLE_TOL``) and non-degenerate?"""
    hu, hv = np.asarray(half_u, dtype=np.float64), np.asarray(half_v, dtype=np.float64)
    lu, lv = float(np.linalg.norm(hu)), float(np.linalg.norm(hv))
    return lu > 0 and lv > 0 and abs(float(np.dot(hu, hv))) <= RECTANGLE_TOL * lu * lv


@dataclass
class Quad:
    """One parallelogram ``center + s half_u + r half_v`` (|s|, |r| <= 1) with the winding normal of its triangles."""

    center: np.ndarray
    half_u: np.ndarray
    half_v: np.ndarray
    normal: np.ndarray
    scale: float  # largest absolute corner coordinate
    material: int
    light: int
    group: int = 0  # the shape it comes from: the quads of one shape are consecutive and share a bounding box
    uv: np.ndarray | None = None  # 3x2: texture coordinates uv = uv[0] + s uv[1] + r uv[2] (None: no uvs)

    def duals(self) -> tuple[np.ndarray, np.ndarray]:
        """(ustar, vstar): s = (p - center) . ustar, r = (p - center) . vstar for p on the plane."""
        det = float(np.dot(self.normal, np.cross(self.half_u, self.half_v)))
        return np.cross(self.half_v, self.normal) / det, np.cross(self.normal, self.half_u) / det


_QUAD_MEMO: dict = {}  # content key -> mesh_quads' answer; an optimisation loop rebuilds the same box every iteration
_QUAD_MEMO_SIZE = 4096


def mesh_quads(m: TriangleMesh) -> list[Quad] | None:
    """The parallelograms a rectangle or cube mesh is made of (faces 2k and 2k+1 share a diagonal), or None when the
    mesh is not one, or its triangles do not pair into non-degenerate parallelograms (then it stays triangles)."""
    if m.shape not in QUAD_SHAPES or m.normals is not None or len(m.faces) % 2 or not len(m.faces):
        return None
    v = np.asarray(m.vertices, dtype=np.float64)
    f = np.asarray(m.faces, dtype=np.int64)
    uv = None if m.uvs is None else np.asarray(m.uvs, dtype=np.float64)
    key = (v.shape, v.tobytes(), f.shape, f.tobytes(), None if uv is None else (uv.shape, uv.tobytes()), m.material,
           m.light)
    if key not in _QUAD_MEMO:
        if len(_QUAD_MEMO) >= _QUAD_MEMO_SIZE:
            _QUAD_MEMO.clear()
        _QUAD_MEMO[key] = _mesh_quads(m)
    quads = _QUAD_MEMO[key]
    return None if quads is None else [dataclasses.replace(q) for q in quads]


def _mesh_quads(m: TriangleMesh) -> list[Quad] | None:
    quads = []
    v = m.vertices
    for f0, f1 in zip(m.faces[0::2], m.faces[1::2]):
        shared = [i for i in f0 if i in f1]
        if len(shared) != 2 or len(set(f0)) != 3 or len(set(f1)) != 3:
            return None
        a, c = v[shared[0]], v[shared[1]]
        b = v[[i for i in f0 if i not in shared][0]]
        d = v[[i for i in f1 if i not in shared][0]]
        corners = np.array([a, b, c, d])
        scale = float(np.abs(corners).max())
        if not np.abs(a + c - b - d).max() <= PARALLELOGRAM_TOL * scale:
            return None
        n0 = np.cross(v[f0[1]] - v[f0[0]], v[f0[2]] - v[f0[0]])
        n1 = np.cross(v[f1[1]] - v[f1[0]], v[f1[2]] - v[f1[0]])
        len0 = float(np.linalg.norm(n0))
        if not (len0 > 0 and np.dot(n0, n1) > 0):
            return None
        uv = None
        if m.uvs is not None:  # the same affine map as the corners': a (-1, -1), b (1, -1), c (1, 1), d (-1, 1)
            ta, tc = m.uvs[shared[0]], m.uvs[shared[1]]
            tb = m.uvs[[i for i in f0 if i not in shared][0]]
            td = m.uvs[[i for i in f1 if i not in shared][0]]
            uv = np.array([(ta + tb + tc + td) / 4, 0.25 * ((tb - ta) + (tc - td)), 0.25 * ((td - ta) + (tc - tb))])
        q = Quad(center=corners.mean(axis=0), half_u=0.25 * ((b - a) + (c - d)), half_v=0.25 * ((d - a) + (c - b)),
                 normal=n0 / len0, scale=scale, material=m.material, light=m.light, uv=uv)
        det = float(np.dot(q.normal, np.cross(q.half_u, q.half_v)))
        if not abs(det) > 1e-6 * float(np.linalg.norm(q.half_u) * np.linalg.norm(q.half_v)):
            return None
        quads.append(q)
    return quads


def split_scene(scene: Scene) -> tuple[list[Quad], list[TriangleMesh]]:
    """Rectangles and cubes as analytic quads; every other (non-empty) mesh stays triangles in the BVH."""
    quads, tri = [], []
    for m in scene.meshes:
        if not len(m.faces):
            continue
        q = mesh_quads(m)
        if q is None:
            tri.append(m)
        else:
            group = quads[-1].group + 1 if quads else 0
            quads += [dataclasses.replace(x, group=group) for x in q]
    return quads, tri


GROUP_BOX_PAD = 1e-9  # relative to the group's size and position: far above float64 rounding in the slab test


def quad_groups(quads: list[Quad]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per quad: the end of its group if it starts a group of several quads (one shape: a cube), else -1; and that
    group's bounding box padded by ``GROUP_BOX_PAD`` (zeros elsewhere)."""
    n = len(quads)
    end = np.full(n, -1)
    lo = np.zeros((n, 3))
    hi = np.zeros((n, 3))
    ids = np.array([q.group for q in quads], dtype=np.int64)
    starts = np.flatnonzero(np.r_[True, ids[1:] != ids[:-1]]) if n else np.zeros(0, np.int64)
    for a, b in zip(starts, np.r_[starts[1:], n]):
        if b - a < 2:
            continue  # a lone rectangle: its own test is as cheap as a box test
        corners = np.concatenate([[q.center + su * q.half_u + sv * q.half_v for su in (-1, 1) for sv in (-1, 1)]
                                  for q in quads[a:b]])
        pad = GROUP_BOX_PAD * (float(np.abs(corners).max()) + float(np.ptp(corners, axis=0).max()))
        end[a] = b
        lo[a] = corners.min(axis=0) - pad
        hi[a] = corners.max(axis=0) + pad
    return end, lo, hi


class TriangleData:
    """The triangle part of a ``SceneData``, filled in place: vertices and faces, and either our 4-wide tree
    ("wide") or a ``wp.Mesh`` ("warp"); keeps the device arrays alive. ``camera_origin`` enters the boxes' padding
    (``triangle_box_pad``)."""

    def __init__(self, d: SceneData, points: np.ndarray, faces: np.ndarray, camera_origin, device: str,
                 triangles: str = "wide", source: str = "scene"):
        # the kernels' float32 points and int32 corners, made once: the tree, the leaves and the device share them
        points32 = np.ascontiguousarray(points, dtype=np.float32).reshape(-1, 3)
        faces32 = np.ascontiguousarray(faces, dtype=np.int32).reshape(-1, 3)
        self.points = _vec3(points32, device)
        self.indices = _arr(faces32, wp.int32, device)
        self.tree = None
        self.mesh = None
        d.bvh_root = -1  # an empty slot
        d.mesh_id = wp.uint64(0)
        if len(faces) and triangles == "warp":
            self.mesh = wp.Mesh(points=self.points, indices=self.indices)
            d.mesh_id = self.mesh.id
        elif len(faces):
            self.box_pad = triangle_box_pad(points, camera_origin)
            self.tree = collapse_wide(_triangle_tree(points32, faces32, self.box_pad))
            if self.tree.stack_bound + STACK_SLACK >= STACK_SIZE:
                raise RenderError(f"{source}: the triangle tree is too deep for the traversal's stack "
                                  f"({self.tree.stack_bound} + {STACK_SLACK} entries, {STACK_SIZE} available)")
            d.bvh_root = self.tree.root
        t = self.tree
        d.bvh_boxes = wp.array(t.boxes if t else np.zeros((0, 4), np.float32), dtype=wp.vec4, device=device)
        d.bvh_child = wp.array(t.child if t else np.zeros((0, 4), np.int32), dtype=wp.vec4i, device=device)
        soa, lane_face = leaf_soa(points32, faces32, t) if t else (np.zeros((0, 4)), [])
        d.tri_soa = wp.array(np.ascontiguousarray(soa, dtype=np.float32), dtype=wp.vec4, device=device,
                             copy=device != "cpu")
        d.tri_face = _arr(lane_face, wp.int32, device)
        d.points = self.points
        d.indices = self.indices


class DeviceScene:
    """Device-side copy of a scene; keeps the arrays (and the BVH) alive while kernels use them."""

    def __init__(self, scene: Scene, device: str, triangles: str = "wide"):
        """``triangles``: "wide" (our 4-wide tree, kernels/triangle.py) or "warp" (a wp.Mesh, kernels/triangle_warp.py)."""
        if triangles not in TRIANGLES:
            raise RenderError(f"unknown triangle backend {triangles!r} (supported: {', '.join(TRIANGLES)})")
        self.device = device
        quads, tri = split_scene(scene)
        if tri:
            offsets = np.cumsum([0] + [len(m.vertices) for m in tri[:-1]])
            points = join_arrays([m.vertices for m in tri])
            faces = join_arrays([m.faces + off if off else m.faces for m, off in zip(tri, offsets)])
            face_material = join_arrays([np.full(len(m.faces), m.material, dtype=np.int32) for m in tri])
            # a rectangle or cube left as triangles names its parallelogram light; a mesh light comes after the
            # parallelograms and the spheres
            emits = {id(scene.meshes[l.mesh]): len(scene.lights) + len(scene.sphere_lights) + k
                     for k, l in enumerate(scene.mesh_lights)}
            face_light = join_arrays([np.full(len(m.faces), emits.get(id(m), m.light), dtype=np.int32) for m in tri])
            corner = []  # float32 before the gather: a 5M-triangle mesh's corners are 190 MB so, 380 MB in float64
            for m in tri:
                if m.normals is not None:
                    corner.append(np.asarray(m.normals, np.float32)[m.faces].reshape(-1, 3))
                else:
                    corner.append(np.repeat(_face_normals(m.vertices, m.faces).astype(np.float32), 3, axis=0))
            corner_normals = join_arrays(corner)
            # texture coordinates per corner, only where a texture reads them (Mitsuba's (0, 0) where a mesh has none)
            corner_uv = np.zeros((0, 2))
            if scene.textures:
                corner_uv = np.concatenate([m.uvs[m.faces].reshape(-1, 2) if m.uvs is not None
                                            else np.zeros((3 * len(m.faces), 2)) for m in tri])
        else:
            points = np.zeros((0, 3))
            faces = np.zeros((0, 3), dtype=np.int64)
            face_material = face_light = np.zeros(0)
            corner_normals = np.zeros((0, 3))
            corner_uv = np.zeros((0, 2))

        d = SceneData()
        self.triangles = TriangleData(d, points, faces, np.asarray(scene.camera.to_world)[:3, 3], device, triangles,
                                      scene.source)
        self.tree = self.triangles.tree
        d.face_material = _arr(face_material, wp.int32, device)
        d.face_light = _arr(face_light, wp.int32, device)
        d.corner_normals = _vec3(corner_normals, device)
        d.corner_uv = wp.array(np.asarray(corner_uv, dtype=np.float32).reshape(-1, 2), dtype=wp.vec2, device=device)

        d.sphere_center = _vec3([s.center for s in scene.spheres], device)
        d.sphere_radius = _arr([s.radius for s in scene.spheres], wp.float32, device)
        d.sphere_material = _arr([s.material for s in scene.spheres], wp.int32, device)
        rots = [np.linalg.inv(s.rotation) if s.rotation is not None else np.eye(3) for s in scene.spheres]
        d.sphere_to_local = wp.array(np.array(rots, dtype=np.float32).reshape(-1, 3, 3), dtype=wp.mat33, device=device)
        d.num_spheres = len(scene.spheres)

        self.quads = quads
        center, normal, half_u, half_v = (np.array([getattr(q, k) for q in quads], dtype=np.float64).reshape(-1, 3)
                                          for k in ("center", "normal", "half_u", "half_v"))
        # Quad.duals for all quads at once (one call per quad cost more than the rest of the upload)
        det = np.einsum("ij,ij->i", normal, np.cross(half_u, half_v))[:, None]
        d.quad_center = _vec3d(center, device)
        d.quad_normal = _vec3d(normal, device)
        d.quad_half_u = _vec3d(half_u, device)
        d.quad_half_v = _vec3d(half_v, device)
        d.quad_ustar = _vec3d(np.cross(half_v, normal) / det, device)
        d.quad_vstar = _vec3d(np.cross(normal, half_u) / det, device)
        d.quad_scale = _arr([q.scale for q in quads], wp.float32, device)
        d.quad_dual_len = _vec2d(np.stack([np.linalg.norm(d.quad_ustar.numpy(), axis=1),
                                           np.linalg.norm(d.quad_vstar.numpy(), axis=1)], axis=1), device)
        d.quad_inside = _vec2d(quad_inside(half_u, half_v, d.quad_scale.numpy()), device)
        d.quad_material = _arr([q.material for q in quads], wp.int32, device)
        d.quad_light = _arr([q.light for q in quads], wp.int32, device)
        uvs = np.array([q.uv if q.uv is not None else np.zeros((3, 2)) for q in quads], dtype=np.float32).reshape(-1, 2)
        d.quad_uv = wp.array(uvs, dtype=wp.vec2, device=device)
        d.num_quads = len(quads)
        end, lo, hi = quad_groups(quads)
        d.quad_group_end = _arr(end, wp.int32, device)
        d.quad_box_lo = _vec3d(lo, device)
        d.quad_box_hi = _vec3d(hi, device)
        light_quad = np.full(len(scene.lights), -1)
        for i, q in enumerate(quads):
            if q.light >= 0:
                light_quad[q.light] = i

        d.mat_kind = _arr([m.code for m in scene.materials], wp.int32, device)
        d.mat_rgb = _vec3([m.rgb for m in scene.materials], device)
        d.mat_twosided = _arr([int(m.is_twosided) for m in scene.materials], wp.int32, device)
        d.mat_rgb2 = _vec3([m.rgb2 for m in scene.materials], device)
        d.mat_eta = _vec3([m.eta for m in scene.materials], device)
        d.mat_k = _vec3([m.k for m in scene.materials], device)
        params = [[m.alpha, DISTRIBUTIONS[m.distribution],
                   m.specular_sampling_weight if m.kind in ("plastic", "roughplastic") else 0.0,
                   m.fdr_int if m.kind == "plastic" else (
                       internal_reflectance(m.alpha, m.distribution, m.eta[0]) if m.kind == "roughplastic" else 0.0)]
                  for m in scene.materials]
        d.mat_param = wp.array(np.array(params, dtype=np.float32).reshape(-1, 4), dtype=wp.vec4, device=device)
        d.mat_nonlinear = _arr([int(m.nonlinear) for m in scene.materials], wp.int32, device)
        d.mat_texture = _arr([m.texture for m in scene.materials], wp.int32, device)
        tables, starts = [], []
        for m in scene.materials:
            starts.append(64 * len(tables))
            if m.kind == "roughplastic":
                tables.append(external_transmittance(m.alpha, m.distribution, m.eta[0]))
        d.mat_table = _arr(starts, wp.int32, device)
        d.rough_tables = wp.array(np.concatenate(tables).astype(np.float32) if tables else np.zeros(0, np.float32),
                                  dtype=wp.float32, device=device)
        fill_textures(d, scene.textures, device)

        lights = scene.lights
        d.light_center = _vec3([l.center for l in lights], device)
        d.light_half_u = _vec3([l.half_u for l in lights], device)
        d.light_half_v = _vec3([l.half_v for l in lights], device)
        d.light_normal = _vec3([l.normal for l in lights], device)
        # parallelograms, then sphere lights, then mesh lights (the order the hits' light indices assume)
        d.light_radiance = _vec3([l.radiance for l in lights] + [l.radiance for l in scene.sphere_lights]
                                 + [l.radiance for l in scene.mesh_lights], device)
        d.light_area = _arr([l.area for l in lights], wp.float32, device)
        d.num_lights = len(lights)
        d.light_quad = _arr(light_quad, wp.int32, device)
        d.light_rect = _arr([int(is_rectangle(l.half_u, l.half_v)) for l in lights], wp.int32, device)
        self._other_lights(d, scene, tri, device)
        self.data = d
        self.camera = camera_data(scene, device)

    def _other_lights(self, d: SceneData, scene: Scene, tri: list[TriangleMesh], device):
        """Sphere, mesh, point, spot and directional lights and the environment (kernels/lights.py)."""
        n_rect = len(scene.lights)
        sphere_light = np.full(len(scene.spheres), -1)
        for j, l in enumerate(scene.sphere_lights):
            sphere_light[l.sphere] = n_rect + j
        d.sphere_light = _arr(sphere_light, wp.int32, device)
        d.sl_sphere = _arr([l.sphere for l in scene.sphere_lights], wp.int32, device)
        d.num_sphere_lights = len(scene.sphere_lights)

        face_offset, off = {}, 0
        for m in tri:
            face_offset[id(m)] = off
            off += len(m.faces)
        faces, cdf, start, count, area = [], [], [], [], []
        for l in scene.mesh_lights:
            m = scene.meshes[l.mesh]
            a = 0.5 * np.linalg.norm(np.cross(m.vertices[m.faces[:, 1]] - m.vertices[m.faces[:, 0]],
                                              m.vertices[m.faces[:, 2]] - m.vertices[m.faces[:, 0]]), axis=1)
            start.append(len(faces))
            count.append(len(m.faces))
            area.append(float(a.sum()))
            c = np.cumsum(a) / a.sum()
            c[-1] = 1.0
            cdf.extend(c.tolist())
            faces.extend((face_offset[id(m)] + np.arange(len(m.faces))).tolist())
        d.ml_face = _arr(faces, wp.int32, device)
        d.ml_cdf = _arr(cdf, wp.float32, device)
        d.ml_start = _arr(start, wp.int32, device)
        d.ml_count = _arr(count, wp.int32, device)
        d.ml_area = _arr(area, wp.float32, device)
        d.num_mesh_lights = len(scene.mesh_lights)

        d.pl_position = _vec3([l.position for l in scene.point_lights], device)
        d.pl_intensity = _vec3([l.intensity for l in scene.point_lights], device)
        d.num_point_lights = len(scene.point_lights)
        spots = scene.spot_lights
        d.spot_position = _vec3([l.position for l in spots], device)
        d.spot_to_local = wp.array(np.array([np.linalg.inv(l.to_world) for l in spots], dtype=np.float32).reshape(
            -1, 3, 3), dtype=wp.mat33, device=device)
        d.spot_intensity = _vec3([l.intensity for l in spots], device)
        cone = [[np.cos(np.radians(l.cutoff_angle)), np.radians(l.cutoff_angle), np.radians(l.beam_width),
                 np.cos(np.radians(l.beam_width))] for l in spots]
        d.spot_cone = wp.array(np.array(cone, dtype=np.float32).reshape(-1, 4), dtype=wp.vec4, device=device)
        d.num_spot_lights = len(spots)
        d.dl_direction = _vec3([l.direction for l in scene.directional_lights], device)
        d.dl_irradiance = _vec3([l.irradiance for l in scene.directional_lights], device)
        d.num_directional_lights = len(scene.directional_lights)
        d.env_radiance = wp.vec3(*(scene.environment or (0.0, 0.0, 0.0)))
        em = scene.envmap
        img = np.zeros((2, 1, 3), np.float32) if em is None else np.ascontiguousarray(em.image, np.float32)
        d.env_image = wp.array(img.reshape(-1, 3), dtype=wp.vec3, device=device)
        d.env_height, d.env_width = int(img.shape[0]), int(img.shape[1])
        rot = np.eye(3) if em is None else np.asarray(em.to_world, np.float64)
        d.env_to_world = wp.mat33(*rot.astype(np.float32).reshape(-1))
        d.env_to_local = wp.mat33(*np.linalg.inv(rot).astype(np.float32).reshape(-1))
        d.env_scale = 1.0 if em is None else float(em.scale)
        row_cdf, col_cdf = envmap_cdfs(img)
        d.env_row_cdf = wp.array(row_cdf, dtype=wp.float32, device=device)
        d.env_col_cdf = wp.array(col_cdf, dtype=wp.float32, device=device)

    @staticmethod
    def features(scene: Scene, view: str = "radiance", rr: str = "throughput", sampler: str = "independent",
                 count_rays: bool = False, light_sampling: str = "area", triangles: str = "wide") -> Features:
        """The compile-time features ``scene`` needs: nothing it does not use."""
        used = {s.material for s in scene.spheres} | {m.material for m in scene.meshes if len(m.faces)}
        quads, tri = split_scene(scene)
        kinds = {scene.materials[i].kind for i in used}
        return Features(
            meshes=len(tri) > 0,
            spheres=len(scene.spheres) > 0,
            mirrors=any(scene.materials[i].code == MIRROR for i in used),
            dielectrics="dielectric" in kinds,
            thin_dielectrics="thindielectric" in kinds,
            conductors="conductor" in kinds,
            plastics="plastic" in kinds,
            rough_conductors="roughconductor" in kinds,
            rough_plastics="roughplastic" in kinds,
            smooth_normals=any(m.normals is not None for m in tri),
            lights=len(scene.lights) > 0,
            quads=len(quads) > 0,
            view=VIEWS[view],
            rr=RR_RULES[rr],
            sampler=SAMPLERS[sampler],
            light_sampling=LIGHT_SAMPLINGS[light_sampling],
            count_rays=count_rays,
            triangles=TRIANGLES[triangles],
            pixel_filter=not scene.rfilter.is_box,
            thin_lens=scene.camera.aperture_radius > 0,
            sphere_lights=len(scene.sphere_lights) > 0,
            mesh_lights=len(scene.mesh_lights) > 0,
            point_lights=len(scene.point_lights) > 0,
            spot_lights=len(scene.spot_lights) > 0,
            directional_lights=len(scene.directional_lights) > 0,
            environment=scene.environment is not None,
            envmap=scene.envmap is not None,
            textures=any(scene.materials[i].texture >= 0 for i in used),
            moments=scene.integrator.moment is not None and view == "radiance",
        )


WRAPS = {"repeat": 0, "mirror": 1, "clamp": 2}


def fill_textures(d: SceneData, textures: list, device) -> None:
    """The textures' tables (kernels/textures.py): kind, uv transform, colours and the bitmaps' texels, all
    bitmaps in one array."""
    d.tex_kind = _arr([0 if t.kind == "checkerboard" else 1 for t in textures], wp.int32, device)
    d.tex_uv_u = _vec3([t.to_uv[0] for t in textures], device)
    d.tex_uv_v = _vec3([t.to_uv[1] for t in textures], device)
    d.tex_color0 = _vec3([t.color0 for t in textures], device)
    d.tex_color1 = _vec3([t.color1 for t in textures], device)
    starts, sizes, modes, texels, n = [], [], [], [], 0
    for t in textures:
        img = t.image if t.image is not None else np.zeros((0, 0, 3), np.float32)
        starts.append(n)
        sizes.append((img.shape[1], img.shape[0]))
        modes.append((int(t.filter == "nearest"), WRAPS[t.wrap]))
        texels.append(img.reshape(-1, 3))
        n += img.shape[0] * img.shape[1]
    d.tex_start = _arr(starts, wp.int32, device)
    d.tex_size = wp.array(np.array(sizes, dtype=np.int32).reshape(-1, 2), dtype=wp.vec2i, device=device)
    d.tex_mode = wp.array(np.array(modes, dtype=np.int32).reshape(-1, 2), dtype=wp.vec2i, device=device)
    d.tex_texels = _vec3(np.concatenate(texels) if texels else np.zeros((0, 3)), device)


def envmap_cdfs(img: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The sampling tables of kernels/envmap.py for an (H, W, 3) map: cells between texel rows i and i + 1 and
    over u in [j / W, (j + 1) / W), each weighed by the largest luminance of the texels its bilinear radiance
    mixes (rows i, i + 1; columns j - 1 .. j + 1) times the largest sin(theta) over it, so that no cell whose
    radiance is positive anywhere has probability 0. Returns the row CDF (H - 1) and per-row column CDFs."""
    h, w = img.shape[:2]
    lum = img.astype(np.float64) @ np.array([0.212671, 0.715160, 0.072169])
    pair = np.maximum(lum[:-1], lum[1:])  # (H - 1, W)
    near = np.maximum(pair, np.maximum(np.roll(pair, 1, axis=1), np.roll(pair, -1, axis=1)))
    v0 = np.arange(h - 1) / (h - 1)
    v1 = np.arange(1, h) / (h - 1)
    sin_max = np.where((v0 <= 0.5) & (v1 >= 0.5), 1.0, np.maximum(np.sin(np.pi * v0), np.sin(np.pi * v1)))
    weight = near * sin_max[:, None]
    rows = weight.sum(axis=1)
    if rows.sum() <= 0:  # an all-black map: nothing to sample, any valid table will do
        weight = np.ones_like(weight)
        rows = weight.sum(axis=1)
    row_cdf = np.cumsum(rows) / rows.sum()
    row_cdf[-1] = 1.0
    safe = np.where(rows > 0, rows, 1.0)[:, None]
    col_cdf = np.cumsum(np.where(rows[:, None] > 0, weight, 1.0 / w), axis=1) / np.where(rows > 0, safe[:, 0], 1.0)[:, None]
    col_cdf[:, -1] = 1.0
    return row_cdf.astype(np.float32), col_cdf.reshape(-1).astype(np.float32)


def camera_data(scene: Scene, device=None) -> CameraData:
    cam = scene.camera
    c = CameraData()
    m = np.asarray(cam.to_world, dtype=np.float64)
    c.origin = wp.vec3(*m[:3, 3].astype(np.float32))
    c.to_world = wp.mat33(*m[:3, :3].astype(np.float32).reshape(-1))
    c.to_local = wp.mat33(*np.linalg.inv(m[:3, :3]).astype(np.float32).reshape(-1))
    c.tan_x, c.tan_y = (float(t) for t in cam.tan_half_fov(scene.width, scene.height))
    c.near_clip = float(cam.near_clip)
    c.far_clip = float(cam.far_clip)
    c.width = scene.width
    c.height = scene.height
    f = scene.rfilter
    table = np.zeros(0, dtype=np.float32) if f.is_box else filter_cdf(f).astype(np.float32)
    c.filter_cdf = wp.array(table, dtype=wp.float32, device=device)
    c.filter_radius = float(f.radius)
    # Mitsuba: border_size = ceil(radius - 0.5 - 2 RayEpsilon), 0 for the box
    c.filter_border = int(np.ceil(f.radius - 0.5 - 2 * 2.0**-24)) if scene.sample_border and not f.is_box else 0
    c.aperture_radius = float(cam.aperture_radius)
    c.focus_distance = float(cam.focus_distance)
    return c
