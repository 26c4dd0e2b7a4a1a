"""Textures and surface uv (kernels/textures.py) against the values Mitsuba 3.9.1 gives
(docs/mitsuba_semantics/study_bsdfs.md section 6), through a probe kernel."""

from __future__ import annotations

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


def probe(scene, quad=(), sphere=(), p=(), tex=(), uv=()):
    n = max(len(quad), len(tex))
    quad = list(quad) + [-1] * (n - len(quad))
    sphere = list(sphere) + [-1] * (n - len(sphere))
    p = list(p) + [(0.0, 0.0, 0.0)] * (n - len(p))
    tex = list(tex) + [0] * (n - len(tex))
    uv = list(uv) + [(0.0, 0.0)] * (n - len(uv))
    ds = DeviceScene(scene, "cpu")
    return launch(probe_textures, n, "cpu", [ds.data, arr(quad, wp.int32, "cpu"), arr(sphere, wp.int32, "cpu"),
                                              arr(p, wp.vec3, "cpu"), arr(tex, wp.int32, "cpu"),
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
        ({"type": "bitmap", "filename": "x.tga"}, "only OpenEXR (.exr), PNG and JPEG"),
        ({"type": "bitmap", "filename": "x.png", "wrap_mode": "tile"}, 'unknown wrap_mode "tile"'),
        ({"type": "checkerboard", "color0": 2.0}, "color0 must lie in [0, 1]"),
    ]
    for tex, problem in cases:
        d = dict(base, s={"type": "sphere", "bsdf": {"type": "diffuse", "reflectance": tex}})
        with pytest.raises(SceneError) as e:
            load_dict(d)
        assert problem in str(e.value) and "\n" not in str(e.value), str(e.value)
    d = dict(base, s={"type": "obj", "filename": "x.obj",
                      "bsdf": {"type": "diffuse", "reflectance": {"type": "checkerboard"}}})
    with pytest.raises(SceneError, match="textured bsdf on a obj is not supported yet"):
        load_dict(d)


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
