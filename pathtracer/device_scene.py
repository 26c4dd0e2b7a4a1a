"""Uploads a ``Scene`` to one Warp device: the one ``wp.Mesh`` of every triangle, and flat arrays for the rest."""

from __future__ import annotations

import numpy as np
import warp as wp

from kernels.integrator import RR_RULES, VIEWS, Features
from kernels.types import CameraData, SceneData
from pathtracer.scene import MIRROR, Scene


def _vec3(a, device) -> wp.array:
    return wp.array(np.asarray(a, dtype=np.float32).reshape(-1, 3), dtype=wp.vec3, device=device)


def _arr(a, dtype, device) -> wp.array:
    np_dtype = np.int32 if dtype == wp.int32 else np.float32
    return wp.array(np.asarray(a, dtype=np_dtype).reshape(-1), dtype=dtype, device=device)


def _face_normals(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return np.divide(n, length, out=np.zeros_like(n), where=length > 0)


class DeviceScene:
    """Device-side copy of a scene; keeps the arrays (and the BVH) alive while kernels use them."""

    def __init__(self, scene: Scene, device: str):
        self.device = device
        tri = [m for m in scene.meshes if len(m.faces)]
        if tri:
            offsets = np.cumsum([0] + [len(m.vertices) for m in tri[:-1]])
            points = np.concatenate([m.vertices for m in tri])
            faces = np.concatenate([m.faces + off for m, off in zip(tri, offsets)])
            face_material = np.concatenate([np.full(len(m.faces), m.material) for m in tri])
            face_light = np.concatenate([np.full(len(m.faces), m.light) for m in tri])
            corner = []
            for m in tri:
                if m.normals is not None:
                    corner.append(m.normals[m.faces].reshape(-1, 3))
                else:
                    corner.append(np.repeat(_face_normals(m.vertices, m.faces), 3, axis=0))
            corner_normals = np.concatenate(corner)
        else:
            points = np.zeros((0, 3))
            faces = np.zeros((0, 3), dtype=np.int64)
            face_material = face_light = np.zeros(0)
            corner_normals = np.zeros((0, 3))

        d = SceneData()
        self.points = _vec3(points, device)
        self.indices = _arr(faces, wp.int32, device)
        self.mesh = wp.Mesh(points=self.points, indices=self.indices) if len(faces) else None
        d.mesh = self.mesh.id if self.mesh is not None else wp.uint64(0)
        d.points = self.points
        d.indices = self.indices
        d.face_material = _arr(face_material, wp.int32, device)
        d.face_light = _arr(face_light, wp.int32, device)
        d.corner_normals = _vec3(corner_normals, device)

        d.sphere_center = _vec3([s.center for s in scene.spheres], device)
        d.sphere_radius = _arr([s.radius for s in scene.spheres], wp.float32, device)
        d.sphere_material = _arr([s.material for s in scene.spheres], wp.int32, device)
        d.num_spheres = len(scene.spheres)

        d.mat_kind = _arr([m.code for m in scene.materials], wp.int32, device)
        d.mat_rgb = _vec3([m.rgb for m in scene.materials], device)
        d.mat_twosided = _arr([int(m.twosided) for m in scene.materials], wp.int32, device)

        lights = scene.lights
        d.light_center = _vec3([l.center for l in lights], device)
        d.light_half_u = _vec3([l.half_u for l in lights], device)
        d.light_half_v = _vec3([l.half_v for l in lights], device)
        d.light_normal = _vec3([l.normal for l in lights], device)
        d.light_radiance = _vec3([l.radiance for l in lights], device)
        d.light_area = _arr([l.area for l in lights], wp.float32, device)
        d.num_lights = len(lights)
        self.data = d
        self.camera = camera_data(scene)

    @staticmethod
    def features(scene: Scene, view: str = "radiance", rr: str = "throughput") -> Features:
        """The compile-time features ``scene`` needs: nothing it does not use."""
        used = {s.material for s in scene.spheres} | {m.material for m in scene.meshes if len(m.faces)}
        return Features(
            meshes=scene.triangle_count > 0,
            spheres=len(scene.spheres) > 0,
            mirrors=any(scene.materials[i].code == MIRROR for i in used),
            smooth_normals=any(m.normals is not None and len(m.faces) for m in scene.meshes),
            lights=len(scene.lights) > 0,
            view=VIEWS[view],
            rr=RR_RULES[rr],
        )


def camera_data(scene: Scene) -> CameraData:
    cam = scene.camera
    c = CameraData()
    m = np.asarray(cam.to_world, dtype=np.float64)
    c.origin = wp.vec3(*m[:3, 3].astype(np.float32))
    c.to_world = wp.mat33(*m[:3, :3].astype(np.float32).reshape(-1))
    c.tan_x, c.tan_y = (float(t) for t in cam.tan_half_fov(scene.width, scene.height))
    c.near_clip = float(cam.near_clip)
    c.far_clip = float(cam.far_clip)
    c.width = scene.width
    c.height = scene.height
    return c
