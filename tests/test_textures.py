"""Textures and surface uv (kernels/textures.py) against the values Mitsuba 3.9.1 gives
(docs/mitsuba_semantics/study_bsdfs.md section 6), through a probe kernel."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from pathtracer import load_dict
from pathtracer import transform as tf
from pathtracer.device_scene import DeviceScene
from pathtracer.errors import SceneError
from probes import arr, launch, probe_textures

import warp as wp


def scene_with(tmp_path, textures: dict, shapes: dict):
    d = {"type": "scene", "sensor": {"type": "perspective", "fov": 40,
                                     "film": {"type": "hdrfilm", "width": 8, "height": 8}}}
    for i, (name, tex) in enumerate(textures.items()):
        d[f"s{i}"] = {"type": "sphere", "center": [10.0 * (i + 1), 0, 0], "bsdf": {"type": "diffuse", "reflectance": tex}}
    d.update(shapes)
    return load_dict(d, source=str(tmp_path / "probe"))


def probe(scene, quad=(), sphere=(), p=(), tex=(), uv=(), face=(), bary=()):
    n = max(len(quad), len(tex), len(face))
    quad = list(quad) + [-1] * (n - len(quad))
    sphere = list(sphere) + [-1] * (n - len(sphere))
    p = list(p) + [(0.0, 0.0, 0.0)] * (n - len(p))
    face = list(face) + [0] * (n - len(face))
    bary = list(bary) + [(0.0, 0.0)] * (n - len(bary))
    tex = list(tex) + [0] * (n - len(tex))
    uv = list(uv) + [(0.0, 0.0)] * (n - len(uv))
    ds = DeviceScene(scene, "cpu")
    return launch(probe_textures, n, "cpu", [ds.data, arr(quad, wp.int32, "cpu"), arr(sphere, wp.int32, "cpu"),
                                              arr(p, wp.vec3, "cpu"), arr(face, wp.int32, "cpu"),
                                              arr(bary, wp.vec2, "cpu"), arr(tex, wp.int32, "cpu"),
                                              arr(uv, wp.vec2, "cpu")], [wp.vec2, wp.vec3])


def test_checkerboard_cells_as_mitsuba(tmp_path):
    s = scene_with(tmp_path, {"c": {"type": "checkerboard"}}, {})
    uvs = [(0.25, 0.25), (0.75, 0.25), (0.25, 0.75), (0.75, 0.75), (0.5, 0.5), (1.25, -0.25)]
    _, val = probe(s, tex=[0] * len(uvs), uv=uvs)
    assert np.allclose(val[:, 0], [0.4, 0.2, 0.2, 0.4, 0.4, 0.2], atol=1e-7)


def test_bitmap_lookup_as_mitsuba(tmp_path):
    img = np.zeros((2, 2, 3), np.uint8)
    img[0, 0] = (255, 0, 0)  # top-left: v = 0
    img[0, 1] = (0, 255, 0)
    img[1, 0] = (128, 128, 128)
    Image.fromarray(img).save(tmp_path / "t.png")
    f = str(tmp_path / "t.png")
    s = scene_with(tmp_path, {"b": {"type": "bitmap", "filename": f},
                              "n": {"type": "bitmap", "filename": f, "filter_type": "nearest"},
                              "c": {"type": "bitmap", "filename": f, "wrap_mode": "clamp"}}, {})
    uv = [(0.25, 0.25), (0.5, 0.25), (0.1, 0.1), (0.1, 0.9), (0.0, 0.25), (0.0, 0.25)]
    _, val = probe(s, tex=[0, 0, 1, 1, 0, 2], uv=uv)
    assert np.allclose(val[0], (1, 0, 0), atol=1e-6)  # a texel centre: exactly the texel, sRGB-decoded
    assert np.allclose(val[1], (0.5, 0.5, 0), atol=1e-6)  # midway red | green: interpolated in linear space
    assert np.allclose(val[2], (1, 0, 0)) and np.allclose(val[3], 0.215861, atol=1e-5)  # 128 -> Mitsuba's 0.215861
    assert np.allclose(val[4], (0.5, 0.5, 0), atol=1e-6)  # repeat: u = 0 is halfway between the last and first
    assert np.allclose(val[5], (1, 0, 0), atol=1e-6)  # clamp: the first column


def test_sphere_and_rectangle_uv_as_mitsuba(tmp_path):
    shapes = {"ball": {"type": "sphere", "center": [0, 0, 0], "radius": 2.0},
              "rect": {"type": "rectangle", "to_world": tf.translate([0, 0, -5]) @ tf.rotate([0, 0, 1], 30)
                       @ tf.scale([2, 3, 1])}}
    s = scene_with(tmp_path, {"c": {"type": "checkerboard"}}, shapes)  # sphere 0 carries it: ours is sphere 1
    pts = [(2, 0, 0), (0, 2, 0), (-2, 0, 0), (0, -2, 0), (0, 0, 2), (0, 0, -2)]
    local = np.array([0.9, 0.2, 0.0])  # Mitsuba: local (0.9, 0.2) -> uv (0.95, 0.6)
    world = tf.transform_points(shapes["rect"]["to_world"], local[None])[0]
    uv, _ = probe(s, quad=[-1] * 6 + [0], sphere=[1] * 6 + [-1], p=pts + [tuple(world)])
    assert np.allclose(uv[:4], [(0, 0.5), (0.25, 0.5), (0.5, 0.5), (0.75, 0.5)], atol=1e-6)
    assert uv[4, 1] == pytest.approx(0.0, abs=1e-6) and uv[5, 1] == pytest.approx(1.0, abs=1e-6)
    assert np.allclose(uv[6], (0.95, 0.6), atol=1e-5)


def test_texture_errors_are_one_line(tmp_path):
    base = {"type": "scene", "sensor": {"type": "perspective", "fov": 40}}
    cases = [
        ({"type": "bitmap", "filename": str(tmp_path / "missing.png")}, "cannot read"),
        ({"type": "bitmap"}, 'bitmap needs "filename"'),
        ({"type": "bitmap", "filename": "x.tga"}, "only OpenEXR (.exr), Radiance HDR (.hdr), PNG and JPEG"),
        ({"type": "bitmap", "filename": "x.png", "wrap_mode": "tile"}, 'unknown wrap_mode "tile"'),
        ({"type": "checkerboard", "color0": 2.0}, "color0 must lie in [0, 1]"),
    ]
    for tex, problem in cases:
        d = dict(base, s={"type": "sphere", "bsdf": {"type": "diffuse", "reflectance": tex}})
        with pytest.raises(SceneError) as e:
            load_dict(d)
        assert problem in str(e.value) and "\n" not in str(e.value), str(e.value)
    d = dict(base, s={"type": "disk", "bsdf": {"type": "diffuse", "reflectance": {"type": "checkerboard"}}})
    with pytest.raises(SceneError, match="textured bsdf on a disk is not supported yet"):
        load_dict(d)


TRI_OBJ = """v 0 0 0
v 1 0 0
v 0 1 0
v 1 1 0
vn 0 0 1
vt 0.1 0.2
vt 0.9 0.3
vt 0.2 0.8
vt 0.7 0.7
f 1/1/1 2/2/1 3/3/1
f 2/4/1 4/2/1 3/3/1
"""


def mesh_probe(tmp_path, shape: dict, faces, barys):
    """surface_uv on the mesh of ``shape`` (the scene's only triangle mesh: its faces come first)."""
    s = scene_with(tmp_path, {}, {"m": dict(shape, bsdf={"type": "diffuse", "reflectance": {"type": "checkerboard"}})})
    uv, _ = probe(s, face=faces, bary=barys)
    return s, uv


def test_mesh_uv_interpolates_the_files_coordinates_as_mitsuba(tmp_path):
    (tmp_path / "t.obj").write_text(TRI_OBJ)
    # OBJ: v flipped by default (flip_tex_coords true); corner weights (b0, b1) on the file's corners 0 and 1
    _, uv = mesh_probe(tmp_path, {"type": "obj", "filename": str(tmp_path / "t.obj")}, [0, 0, 0, 1],
                       [(1, 0), (0, 1), (0.2, 0.3), (1, 0)])
    vt = np.array([[0.1, 0.8], [0.9, 0.7], [0.2, 0.2], [0.7, 0.3]])  # 1 - v
    assert np.allclose(uv, [vt[0], vt[1], 0.2 * vt[0] + 0.3 * vt[1] + 0.5 * vt[2], vt[3]], atol=1e-6)
    _, uv = mesh_probe(tmp_path, {"type": "obj", "filename": str(tmp_path / "t.obj"), "flip_tex_coords": False},
                       [0], [(1, 0)])
    assert np.allclose(uv[0], (0.1, 0.2), atol=1e-6)
    # PLY: not flipped by default (Mitsuba 3.9), whichever of Mitsuba's three property names the file uses
    for names in (("u", "v"), ("s", "t"), ("texture_u", "texture_v")):
        (tmp_path / "t.ply").write_text(
            "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
            f"property float {names[0]}\nproperty float {names[1]}\nelement face 1\n"
            "property list uchar int vertex_indices\nend_header\n0 0 0 0.1 0.2\n1 0 0 0.3 0.4\n0 1 0 0.5 0.6\n"
            "3 0 1 2\n")
        _, uv = mesh_probe(tmp_path, {"type": "ply", "filename": str(tmp_path / "t.ply")}, [0, 0], [(0, 1), (0, 0)])
        assert np.allclose(uv, [(0.3, 0.4), (0.5, 0.6)], atol=1e-6), names


def test_serialized_texture_coordinates_are_read_unflipped(tmp_path):
    # the feature scene's grid, written by examples/make_feature_maps.py both ways: uv ((x + 1) / 2, (z + 1) / 2)
    maps = Path(__file__).resolve().parents[1] / "scenes" / "features" / "maps"
    probes = dict(faces=[0, 0, 0, 150], barys=[(1, 0), (0, 1), (0, 0), (0.25, 0.25)])
    _, uv_s = mesh_probe(tmp_path, {"type": "serialized", "filename": str(maps / "uv_grid.serialized")}, **probes)
    _, uv_p = mesh_probe(tmp_path, {"type": "ply", "filename": str(maps / "uv_grid.ply")}, **probes)
    assert np.allclose(uv_s[:3], [(0, 0), (1 / 12, 1 / 12), (1 / 12, 0)], atol=1e-6)
    assert np.allclose(uv_s, uv_p, atol=2e-6)


def test_mesh_without_texture_coordinates_gets_mitsubas_barycentric_uv(tmp_path):
    # uv = (b1, b2) on the file's corners, also where a mirroring to_world reverses our winding (the file has
    # normals, so we keep it facing them) and the corners 1 and 2 trade places
    (tmp_path / "n.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nvn 0 0 1\nf 1//1 2//1 3//1\n"
                                    "f 2//1 4//1 3//1\n")
    for mirror in (False, True):
        to_world = tf.scale([-1, 1, 1]) if mirror else np.eye(4)
        s, uv = mesh_probe(tmp_path, {"type": "obj", "filename": str(tmp_path / "n.obj"), "to_world": to_world},
                           [0, 0, 0, 1], [(1, 0), (0, 1), (0.2, 0.3), (0, 0)])
        file_corner = [(0, 0), (1, 0), (0, 1)]
        ours = [file_corner[k] for k in ([0, 2, 1] if mirror else [0, 1, 2])]
        b = np.array([[1, 0, 0], [0, 1, 0], [0.2, 0.3, 0.5], [0, 0, 1]])
        assert np.allclose(uv, b @ np.array(ours), atol=1e-6), mirror
        mesh = s.meshes[-1]
        assert len(mesh.vertices) == 6 and len(mesh.faces) == 2  # one vertex per corner: uv per corner
        assert np.allclose(mesh.normals, [0, 0, 1])


def test_jpeg_bitmaps_read_as_srgb_like_png(tmp_path):
    """A JPEG texture (4 of 25 public scenes use one) is decoded to 8 bits and read as sRGB, as Mitsuba reads 8-bit
    images: flat 8x8 blocks of 128 come back as Mitsuba's 0.215861 (JPEG is exact on a flat block)."""
    img = np.full((16, 16, 3), 128, np.uint8)
    img[:8, :8] = (200, 60, 30)
    Image.fromarray(img).save(tmp_path / "t.jpg", quality=100)
    s = scene_with(tmp_path, {"j": {"type": "bitmap", "filename": str(tmp_path / "t.jpg"),
                                    "filter_type": "nearest"}}, {})
    _, val = probe(s, tex=[0, 0], uv=[(0.75, 0.75), (0.25, 0.25)])
    assert np.allclose(val[0], 0.215861, atol=1e-5)
    decoded = np.asarray(Image.open(tmp_path / "t.jpg").convert("RGB"), dtype=np.float64)[4, 4] / 255.0
    assert np.allclose(val[1], np.where(decoded <= 0.04045, decoded / 12.92, ((decoded + 0.055) / 1.055) ** 2.4),
                       atol=1e-6)
