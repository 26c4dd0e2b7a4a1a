"""The scene loader: Mitsuba 3 XML and Mitsuba-shaped dicts -> Scene (no Warp, no Mitsuba needed)."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pathtracer import meshio
from pathtracer import transform as tf
from pathtracer.errors import SceneError
from pathtracer.loader import load_dict, load_file
from pathtracer.meshio import vertex_normals
from pathtracer.scene import DEFAULT_MATERIAL, Material, Scene

ROOT = Path(__file__).resolve().parents[1]
SCENES = ROOT / "scenes"
DATA = Path(__file__).resolve().parent / "data"
SEED_SCENES = ["cornell_box", "cornell_box_mirror", "teapot_in_box", "open_sky"]

SENSOR = '<sensor type="perspective"><float name="fov" value="45"/></sensor>'


def scene_xml(body: str, sensor: str = SENSOR) -> str:
    return f'<scene version="3.0.0">\n{sensor}\n{body}\n</scene>\n'


def write(tmp_path: Path, text: str | bytes, name: str = "scene.xml") -> Path:
    p = tmp_path / name
    p.write_bytes(text if isinstance(text, bytes) else text.encode())
    return p


def load_xml(tmp_path: Path, body: str, sensor: str = SENSOR, **params) -> Scene:
    return load_file(write(tmp_path, scene_xml(body, sensor)), **params)


def face_normals(mesh) -> np.ndarray:
    v = mesh.vertices
    n = np.cross(v[mesh.faces[:, 1]] - v[mesh.faces[:, 0]], v[mesh.faces[:, 2]] - v[mesh.faces[:, 0]])
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def rot(axis, deg):
    return tf.rotate(axis, deg)


# ---------------------------------------------------------------------------------------------
# transforms


def test_transform_ops_match_hand_computed():
    c, s = math.cos(math.radians(30)), math.sin(math.radians(30))
    np.testing.assert_allclose(rot([0, 1, 0], 30)[:3, :3], [[c, 0, s], [0, 1, 0], [-s, 0, c]], atol=1e-15)
    np.testing.assert_allclose(rot([1, 0, 0], 90) @ [0, 1, 0, 0], [0, 0, 1, 0], atol=1e-15)  # right-handed
    np.testing.assert_allclose(tf.translate([1, 2, 3]) @ [0, 0, 0, 1], [1, 2, 3, 1])
    np.testing.assert_allclose(tf.scale(2), np.diag([2, 2, 2, 1]))
    np.testing.assert_allclose(tf.scale([1, 2, 3]), np.diag([1, 2, 3, 1]))
    # Mitsuba's look_at: columns [left, up, dir, origin]
    m = tf.look_at([0, 0, 7], [0, 0, 4], [0, 1, 0])
    np.testing.assert_allclose(m, [[-1, 0, 0, 0], [0, 1, 0, 0], [0, 0, -1, 7], [0, 0, 0, 1]], atol=1e-15)
    # no up: Mitsuba's coordinate_system(dir)
    np.testing.assert_allclose(tf.look_at([0, 0, 0], [0, 0, 1]), [[0, 1, 0, 0], [-1, 0, 0, 0], [0, 0, 1, 0],
                                                                   [0, 0, 0, 1]], atol=1e-15)
    with pytest.raises(ValueError):
        tf.look_at([0, 0, 0], [0, 0, 1], [0, 0, 2])
    with pytest.raises(ValueError):
        tf.rotate([0, 2, 0], 30)


def test_transform_class_chains_like_mitsuba():
    t = tf.Transform().translate([1, 2, 3]).rotate([0, 1, 0], 30).scale([1, 2, 3])
    np.testing.assert_allclose(t.matrix, tf.translate([1, 2, 3]) @ rot([0, 1, 0], 30) @ tf.scale([1, 2, 3]))
    np.testing.assert_allclose((t @ t.inverse()).matrix, np.eye(4), atol=1e-12)
    n = tf.transform_normals(tf.scale([1, 2, 1]), [[1, 1, 0]])
    np.testing.assert_allclose(n, [[2 / math.sqrt(5), 1 / math.sqrt(5), 0]])


def test_xml_transform_ops_compose_in_document_order(tmp_path):
    body = """<shape type="rectangle"><transform name="to_world">
        <scale x="2" y="3"/>
        <rotate value="0 1 0" angle="30"/>
        <translate value="1, 2, 3"/>
        <matrix value="1 0 0 0  0 0 -1 0  0 1 0 0  0 0 0 1"/>
        <scale value="0.5"/>
        <translate x="-1"/>
        <matrix value="0 -1 0  1 0 0  0 0 1"/>
    </transform></shape>"""
    expect = np.eye(4)
    for op in [tf.scale([2, 3, 1]), rot([0, 1, 0], 30), tf.translate([1, 2, 3]),
               np.array([[1, 0, 0, 0], [0, 0, -1, 0], [0, 1, 0, 0], [0, 0, 0, 1.0]]), tf.scale(0.5),
               tf.translate([-1, 0, 0]), np.array([[0, -1, 0, 0], [1, 0, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])]:
        expect = op @ expect
    mesh = load_xml(tmp_path, body).meshes[0]
    np.testing.assert_allclose(mesh.vertices, tf.transform_points(expect, [[-1, -1, 0], [1, -1, 0], [1, 1, 0],
                                                                            [-1, 1, 0]]), atol=1e-12)


def test_xml_lookat_and_empty_transform(tmp_path):
    sensor = """<sensor type="perspective"><float name="fov" value="45"/><transform name="to_world">
        <lookat origin="1 2 3" target="1 2 0" up="0 1 0"/></transform></sensor>"""
    s = load_xml(tmp_path, "", sensor)
    np.testing.assert_allclose(s.camera.to_world, tf.look_at([1, 2, 3], [1, 2, 0], [0, 1, 0]))
    s = load_xml(tmp_path, '<shape type="cube"><transform name="to_world"/></shape>')
    assert np.abs(s.meshes[0].vertices).max() == 1.0


# ---------------------------------------------------------------------------------------------
# defaults and every supported element


def test_defaults_match_mitsuba(tmp_path):
    s = load_xml(tmp_path, "<shape type=\"sphere\"/>")
    assert (s.width, s.height, s.spp, s.sampler_seed) == (768, 576, 4, 0)
    assert (s.integrator.max_depth, s.integrator.rr_depth, s.integrator.hide_emitters) == (-1, 5, False)
    cam = s.camera
    assert (cam.fov, cam.fov_axis, cam.near_clip, cam.far_clip) == (45.0, "x", 1e-2, 1e4)
    np.testing.assert_array_equal(cam.to_world, np.eye(4))
    (sphere,) = s.spheres
    np.testing.assert_array_equal(sphere.center, [0, 0, 0])
    assert sphere.radius == 1.0
    assert s.materials[sphere.material] == DEFAULT_MATERIAL == Material("diffuse", (0.5, 0.5, 0.5))
    assert s.source.endswith("scene.xml") and not s.lights and not s.meshes


def test_integrator_sensor_sampler_film(tmp_path):
    sensor = """<sensor type="perspective">
        <float name="fov" value="30"/> <string name="fov_axis" value="diagonal"/>
        <float name="near_clip" value="0.5"/> <integer name="far_clip" value="100"/>
        <sampler type="independent"><integer name="sample_count" value="7"/><integer name="seed" value="9"/></sampler>
        <film type="hdrfilm"><integer name="width" value="40"/><integer name="height" value="30"/>
            <string name="pixel_format" value="rgb"/><string name="component_format" value="float32"/>
            <rfilter type="box"/></film>
    </sensor>"""
    body = """<integrator type="path"><integer name="max_depth" value="0"/><integer name="rr_depth" value="2"/>
        <boolean name="hide_emitters" value="True"/></integrator>"""
    s = load_xml(tmp_path, body, sensor)
    assert (s.width, s.height, s.spp, s.sampler_seed) == (40, 30, 7, 9)
    assert (s.integrator.max_depth, s.integrator.rr_depth, s.integrator.hide_emitters) == (0, 2, True)
    assert (s.camera.fov, s.camera.fov_axis, s.camera.near_clip, s.camera.far_clip) == (30, "diagonal", 0.5, 100)


@pytest.mark.parametrize("axis", ["x", "y", "diagonal", "smaller", "larger"])
def test_fov_axes(tmp_path, axis):
    sensor = f'<sensor type="perspective"><float name="fov" value="45"/><string name="fov_axis" value="{axis}"/></sensor>'
    assert load_xml(tmp_path, "", sensor).camera.fov_axis == axis


def test_bsdfs(tmp_path):
    body = """
    <bsdf type="diffuse" id="grey"><float name="reflectance" value="0.25"/></bsdf>
    <shape type="sphere"><ref id="grey"/></shape>
    <shape type="sphere"><bsdf type="diffuse"><rgb name="reflectance" value="0.1 0.2, 0.3"/></bsdf></shape>
    <shape type="sphere"><bsdf type="conductor"/></shape>
    <shape type="sphere"><bsdf type="conductor"><string name="material" value="none"/>
        <rgb name="specular_reflectance" value="0.214, 0.214, 1.0"/></bsdf></shape>
    <shape type="sphere"><bsdf type="twosided"><bsdf type="diffuse"/></bsdf></shape>
    <shape type="sphere"><bsdf type="twosided"><ref id="grey"/></bsdf></shape>
    <shape type="sphere"><bsdf type="twosided"><bsdf type="conductor"/></bsdf></shape>
    <shape type="sphere"><ref name="bsdf" id="grey"/></shape>
    """
    s = load_xml(tmp_path, body)
    got = [s.materials[sp.material] for sp in s.spheres]
    assert got == [
        Material("diffuse", (0.25, 0.25, 0.25)),
        Material("diffuse", (0.1, 0.2, 0.3)),
        Material("mirror", (1.0, 1.0, 1.0)),  # Mitsuba's conductor defaults to material "none"
        Material("mirror", (0.214, 0.214, 1.0)),
        Material("diffuse", (0.5, 0.5, 0.5), twosided=True),
        Material("diffuse", (0.25, 0.25, 0.25), twosided=True),
        Material("mirror", (1.0, 1.0, 1.0), twosided=True),
        Material("diffuse", (0.25, 0.25, 0.25)),
    ]
    assert len(s.materials) == 7  # shared materials are stored once


def test_mitsuba_bsdfs_and_their_defaults(tmp_path):
    body = """
    <shape type="sphere"><bsdf type="dielectric"/></shape>
    <shape type="sphere"><bsdf type="dielectric"><string name="int_ior" value="Water"/><float name="ext_ior" value="1.1"/>
        <rgb name="specular_transmittance" value="0.5, 0.6, 0.7"/></bsdf></shape>
    <shape type="sphere"><bsdf type="thindielectric"><float name="int_ior" value="1.7"/></bsdf></shape>
    <shape type="sphere"><bsdf type="conductor"><string name="material" value="Au"/></bsdf></shape>
    <shape type="sphere"><bsdf type="conductor"><float name="eta" value="1.5"/></bsdf></shape>
    <shape type="sphere"><bsdf type="roughconductor"/></shape>
    <shape type="sphere"><bsdf type="roughconductor"><string name="distribution" value="ggx"/>
        <float name="alpha_u" value="0.3"/><float name="alpha_v" value="0.3"/><boolean name="sample_visible" value="false"/>
        </bsdf></shape>
    <shape type="sphere"><bsdf type="plastic"/></shape>
    <shape type="sphere"><bsdf type="twosided"><bsdf type="plastic"><boolean name="nonlinear" value="true"/>
        <rgb name="specular_reflectance" value="0.5"/></bsdf></bsdf></shape>
    """
    s = load_xml(tmp_path, body)
    got = [s.materials[sp.material] for sp in s.spheres]
    bk7 = 1.5046 / 1.000277  # Mitsuba's defaults: int_ior "bk7", ext_ior "air"
    au = ((0.143036, 0.3753071, 1.442045), (3.982997, 2.385556, 1.603359))  # Mitsuba 3.9.1's RGB gold
    assert got == [
        Material("dielectric", (1.0,) * 3, eta=(bk7,) * 3),
        Material("dielectric", (1.0,) * 3, rgb2=(0.5, 0.6, 0.7), eta=(1.333 / 1.1,) * 3),
        Material("thindielectric", (1.0,) * 3, eta=(1.7 / 1.000277,) * 3),
        Material("conductor", (1.0,) * 3, eta=au[0], k=au[1]),
        Material("conductor", (1.0,) * 3, eta=(1.5,) * 3, k=(1.0,) * 3),  # k defaults to 1 when eta is given
        Material("roughconductor", (1.0,) * 3, eta=(0.0,) * 3, k=(1.0,) * 3, alpha=0.1, distribution="beckmann"),
        Material("roughconductor", (1.0,) * 3, eta=(0.0,) * 3, k=(1.0,) * 3, alpha=0.3, distribution="ggx"),
        Material("plastic", (0.5,) * 3, eta=(1.49 / 1.000277,) * 3),
        Material("plastic", (0.5,) * 3, twosided=True, rgb2=(0.5,) * 3, eta=(1.49 / 1.000277,) * 3, nonlinear=True),
    ]
    assert got[0].is_twosided and not got[3].is_twosided  # glass scatters on both sides
    assert got[7].fdr_int == pytest.approx(0.590479, abs=1e-6)  # Mitsuba's value for its default plastic
    assert got[7].specular_sampling_weight == pytest.approx(2.0 / 3.0)


def test_sphere_center_radius_and_to_world_compose_as_mitsuba(tmp_path):
    body = """<shape type="sphere"><point name="center" x="1" y="0" z="0"/><float name="radius" value="2"/>
        <transform name="to_world"><rotate z="1" angle="90"/><scale value="3"/><translate y="5"/></transform>
        </shape>
        <shape type="sphere"><vector name="center" value="1"/><integer name="radius" value="4"/></shape>"""
    a, b = load_xml(tmp_path, body).spheres
    # to_world @ translate(center) @ scale(radius): centre (1,0,0) -> rotate -> (0,1,0) -> *3 -> +5y
    np.testing.assert_allclose(a.center, [0, 8, 0], atol=1e-12)
    assert a.radius == pytest.approx(6.0)
    np.testing.assert_array_equal(b.center, [1, 1, 1])
    assert b.radius == 4.0


def test_rectangle_vertices_normal_and_winding(tmp_path):
    body = """<shape type="rectangle"/>
        <shape type="rectangle"><transform name="to_world"><scale value="2"/><rotate x="1" angle="-90"/>
            <translate y="-2"/></transform></shape>"""
    plain, floor = load_xml(tmp_path, body).meshes
    np.testing.assert_array_equal(plain.vertices, [[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]])
    assert plain.faces.shape == (2, 3) and plain.normals is None and plain.light == -1
    np.testing.assert_allclose(face_normals(plain), [[0, 0, 1]] * 2)
    np.testing.assert_allclose(face_normals(floor), [[0, 1, 0]] * 2, atol=1e-12)
    assert floor.vertices[:, 1] == pytest.approx([-2] * 4)
    assert np.abs(floor.vertices[:, [0, 2]]).max() == pytest.approx(2)


@pytest.mark.parametrize("ops", ['<scale x="-1"/>', '<scale z="-1"/>', '<scale x="-2" y="3"/><rotate x="1" angle="90"/>',
                                 '<rotate y="1" angle="30"/><scale y="-1"/>'])
def test_mirrored_rectangle_and_cube_keep_the_normal_mitsuba_shades_with(tmp_path, ops):
    """Mitsuba transforms the rectangle's normal (0,0,1) and the cube's normals as normals: the front
    side is the inverse transpose's side even when to_world mirrors. Our winding follows it."""
    body = f"""<shape type="rectangle"><transform name="to_world">{ops}</transform>
        <emitter type="area"><rgb name="radiance" value="2"/></emitter></shape>
        <shape type="cube"><transform name="to_world">{ops}</transform></shape>"""
    s = load_xml(tmp_path, body)
    rect, cube = s.meshes
    to_world = np.eye(4)
    for op in re.findall(r"<(\w+) ([^/]*)/>", ops):
        to_world = _op_matrix(*op) @ to_world
    n_it = tf.normal_matrix(to_world) @ [0, 0, 1]
    n_it /= np.linalg.norm(n_it)
    np.testing.assert_allclose(face_normals(rect), [n_it, n_it], atol=1e-12)
    np.testing.assert_allclose(s.lights[0].normal, n_it, atol=1e-12)
    # cube: every face normal points away from the centre
    centres = cube.vertices[cube.faces].mean(axis=1)
    assert np.all(np.einsum("ij,ij->i", face_normals(cube), centres) > 0)


def _op_matrix(tag, attrs):
    a = dict(re.findall(r'(\w+)="([^"]*)"', attrs))
    if tag == "scale":
        return tf.scale([float(a.get(k, 1)) for k in "xyz"])
    return tf.rotate([float(a.get(k, 0)) for k in "xyz"], float(a["angle"]))


def test_cube_is_mitsubas_cube(tmp_path):
    (cube,) = load_xml(tmp_path, '<shape type="cube"/>').meshes
    assert cube.vertices.shape == (24, 3) and cube.faces.shape == (12, 3) and cube.normals is None
    # each face normal is one of the 6 axes, each axis twice, pointing outward
    fn = face_normals(cube)
    centres = cube.vertices[cube.faces].mean(axis=1)
    assert np.all(np.einsum("ij,ij->i", fn, centres) > 0)
    axes = sorted(map(tuple, np.round(fn).astype(int)))
    assert axes == sorted([a for a in [(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)]] * 2)
    # the first triangle, as Mitsuba stores it
    np.testing.assert_array_equal(cube.vertices[cube.faces[0]], [[1, -1, -1], [1, -1, 1], [-1, -1, 1]])


def test_area_light_on_rectangle(tmp_path):
    body = """<shape type="rectangle" id="lamp"><transform name="to_world"><scale x="0.5" y="0.25"/>
            <rotate x="1" angle="90"/><translate y="1.999"/></transform>
        <emitter type="area"><rgb name="radiance" value="30 20 10"/></emitter></shape>
        <shape type="rectangle"><emitter type="area"/></shape>
        <shape type="rectangle"><bsdf type="diffuse"/><emitter type="area"><float name="radiance" value="4"/></emitter></shape>"""
    s = load_xml(tmp_path, body)
    lamp, default, with_bsdf = s.meshes
    assert [m.light for m in s.meshes] == [0, 1, 2]
    light = s.lights[0]
    np.testing.assert_allclose(light.center, [0, 1.999, 0])
    np.testing.assert_allclose(light.half_u, [0.5, 0, 0], atol=1e-15)
    np.testing.assert_allclose(light.half_v, [0, 0, 0.25], atol=1e-15)
    np.testing.assert_allclose(light.normal, [0, -1, 0], atol=1e-15)
    assert light.radiance == (30, 20, 10) and light.area == pytest.approx(0.5)
    np.testing.assert_allclose(face_normals(lamp), [light.normal] * 2, atol=1e-12)
    # Mitsuba: an emitter's radiance defaults to 1, and an emitting shape without a bsdf is black
    assert s.lights[1].radiance == (1.0, 1.0, 1.0)
    assert s.materials[default.material] == Material("diffuse", (0.0, 0.0, 0.0))
    assert s.materials[with_bsdf.material] == DEFAULT_MATERIAL
    assert s.lights[2].radiance == (4.0, 4.0, 4.0)
    assert lamp.name == "lamp"


# ---------------------------------------------------------------------------------------------
# meshes


def test_obj_teapot_keeps_file_normals_normalized(tmp_path):
    body = f'<shape type="obj"><string name="filename" value="{SCENES / "meshes/teapot.obj"}"/></shape>'
    (m,) = load_xml(tmp_path, body).meshes
    assert m.vertices.shape == (1292, 3) and m.faces.shape == (2464, 3)
    raw = np.array([line.split()[1:4] for line in (SCENES / "meshes/teapot.obj").read_text().splitlines()
                    if line.startswith("vn ")], dtype=float)
    np.testing.assert_allclose(np.linalg.norm(m.normals, axis=1), 1.0)
    np.testing.assert_allclose(m.normals, raw / np.linalg.norm(raw, axis=1, keepdims=True), atol=1e-12)
    # the file's normals agree with its winding
    assert np.all(np.einsum("ij,ij->i", face_normals(m), m.normals[m.faces].mean(axis=1)) > 0)


def test_mesh_to_world_transforms_normals_with_the_inverse_transpose(tmp_path):
    ops = '<scale x="2" y="0.5"/><rotate z="1" angle="30"/><translate x="1"/>'
    body = f"""<shape type="obj"><string name="filename" value="{DATA / 'quad_vn.obj'}"/>
        <transform name="to_world">{ops}</transform></shape>"""
    (m,) = load_xml(tmp_path, body).meshes
    to_world = tf.translate([1, 0, 0]) @ rot([0, 0, 1], 30) @ tf.scale([2, 0.5, 1])
    np.testing.assert_allclose(m.vertices, tf.transform_points(to_world, [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]]))
    file_normals = np.array([[0, 0, 2], [0, 1, 1], [0, 0, 2], [0, 1, 1]], dtype=float)
    np.testing.assert_allclose(m.normals, tf.transform_normals(to_world, file_normals), atol=1e-12)
    np.testing.assert_array_equal(m.faces, [[0, 1, 2], [0, 2, 3]])  # the quad, fan-split as Mitsuba


def test_mirrored_mesh_with_normals_is_rewound_and_recomputed_is_not(tmp_path):
    body = f"""<shape type="obj"><string name="filename" value="{DATA / 'quad_vn.obj'}"/>
            <transform name="to_world"><scale x="-1"/></transform></shape>
        <shape type="obj"><string name="filename" value="{DATA / 'tetra.obj'}"/>
            <transform name="to_world"><scale x="-1"/></transform></shape>"""
    quad, tetra = load_xml(tmp_path, body).meshes
    # file normals (0,0,1)-ish stay +z under the mirror; the faces are rewound to match (Mitsuba shades by them)
    assert np.all(face_normals(quad) @ [0, 0, 1] > 0)
    # recomputed normals come from the world-space winding, which the mirror turned inside out (as in Mitsuba)
    assert np.all(np.einsum("ij,ij->i", tetra.normals[tetra.faces].mean(axis=1), face_normals(tetra)) > 0)


def test_ply_with_normals_and_quads(tmp_path):
    body = f'<shape type="ply"><string name="filename" value="{DATA / "quad_normals.ply"}"/></shape>'
    (m,) = load_xml(tmp_path, body).meshes
    np.testing.assert_allclose(m.normals, [[0, 0, 1], [0, 0.5 ** 0.5, 0.5 ** 0.5], [0, 0, 1], [0.5 ** 0.5, 0, 0.5 ** 0.5]])
    assert m.faces.shape == (2, 3)


def test_ply_without_normals_gets_mitsuba_vertex_normals(tmp_path):
    body = f'<shape type="ply" id="bunny"><string name="filename" value="{DATA / "bunny_res4_clean.ply"}"/></shape>'
    (m,) = load_xml(tmp_path, body).meshes
    assert m.vertices.shape == (453, 3) and m.faces.shape == (946, 3) and m.name == "bunny"
    np.testing.assert_allclose(m.normals, vertex_normals(m.vertices, m.faces))
    np.testing.assert_allclose(np.linalg.norm(m.normals, axis=1), 1.0)


def test_face_normals_gives_flat_shading(tmp_path):
    body = f"""<shape type="obj"><string name="filename" value="{SCENES / 'meshes/teapot.obj'}"/>
        <boolean name="face_normals" value="true"/><boolean name="flip_tex_coords" value="false"/></shape>
        <shape type="ply"><string name="filename" value="{DATA / 'bunny_res4_clean.ply'}"/>
        <boolean name="face_normals" value="true"/></shape>"""
    assert [m.normals for m in load_xml(tmp_path, body).meshes] == [None, None]


def test_vertex_normals_are_angle_weighted():
    """Mitsuba's recompute_vertex_normals: face normals weighted by the corner angle, zero-area faces skipped."""
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [5, 5, 5], [2, 0, 0]], dtype=float)
    f = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3], [0, 1, 5]])
    n = vertex_normals(v, f)
    np.testing.assert_allclose(n[0], -np.ones(3) / math.sqrt(3))  # three right angles
    w = np.array([math.pi / 3 / math.sqrt(3)] * 3) + [0, -math.pi / 4, -math.pi / 4]
    np.testing.assert_allclose(n[1], w / np.linalg.norm(w))  # 45, 45 and 60 degree corners
    np.testing.assert_allclose(n[4], [1, 0, 0])  # unused vertex: Mitsuba's placeholder
    np.testing.assert_allclose(n[5], [1, 0, 0])  # only on a degenerate face


def test_mesh_filename_is_relative_to_the_scene_file(tmp_path):
    (tmp_path / "m").mkdir()
    (tmp_path / "m" / "t.obj").write_bytes((DATA / "tetra.obj").read_bytes())
    s = load_xml(tmp_path, '<shape type="obj"><string name="filename" value="m/t.obj"/></shape>')
    assert s.meshes[0].faces.shape == (4, 3)


# ---------------------------------------------------------------------------------------------
# parameters, references, dicts


def test_default_parameters_and_overrides(tmp_path):
    defaults = """<default name="spp" value="16"/><default name="r" value="2"/><default name="rr" value="3"/>
        <default name="hide" value="false"/><default name="mat" value="grey"/>"""
    body = """<integrator type="path"><integer name="rr_depth" value="$rr"/><boolean name="hide_emitters" value="$hide"/>
        </integrator>
        <bsdf type="diffuse" id="grey"/><bsdf type="conductor" id="shiny"/>
        <shape type="sphere"><float name="radius" value="$r"/><ref id="$mat"/></shape>
        <shape type="sphere"><float name="radius" value="$rr"/></shape>"""
    sensor = defaults + """<sensor type="perspective"><float name="fov" value="45"/>
        <sampler type="independent"><integer name="sample_count" value="$spp"/></sampler></sensor>"""
    s = load_xml(tmp_path, body, sensor)
    assert s.spp == 16 and s.spheres[0].radius == 2 and s.spheres[1].radius == 3 and s.integrator.rr_depth == 3
    s = load_xml(tmp_path, body, sensor, spp=3, r=0.5, hide=True, mat="shiny")
    assert s.spp == 3 and s.spheres[0].radius == 0.5 and s.integrator.hide_emitters
    assert s.materials[s.spheres[0].material].kind == "mirror"
    # longest name first: $rr is not $r followed by "r"
    assert s.spheres[1].radius == 3
    # an escaped dollar is kept as a dollar
    s = load_xml(tmp_path, '<bsdf type="diffuse" id="a\\$b"/><shape type="sphere"><ref id="a\\$b"/></shape>')
    assert len(s.spheres) == 1


def test_parameter_errors(tmp_path):
    with pytest.raises(SceneError, match=r'line 3 <float name="radius">: undefined parameter "\$r"'):
        load_xml(tmp_path, '<shape type="sphere"><float name="radius" value="$r"/></shape>')
    with pytest.raises(SceneError, match="parameter.s. spp given but not used"):
        load_xml(tmp_path, "", spp=4)
    with pytest.raises(SceneError, match="give a number, string or bool"):
        load_xml(tmp_path, "", spp=[4])
    # a default only applies after it (Mitsuba parses in document order)
    with pytest.raises(SceneError, match="undefined parameter"):
        load_xml(tmp_path, '<shape type="sphere"><float name="radius" value="$r"/></shape><default name="r" value="1"/>')


def test_references(tmp_path):
    body = """<shape type="sphere"><ref id="later"/></shape>
        <bsdf type="diffuse" id="later"><float name="reflectance" value="0.1"/></bsdf>
        <shape type="sphere"><bsdf type="diffuse" id="inline"><float name="reflectance" value="0.2"/></bsdf></shape>
        <shape type="sphere"><ref id="inline"/></shape>"""
    s = load_xml(tmp_path, body)
    assert [s.materials[sp.material].rgb[0] for sp in s.spheres] == [0.1, 0.2, 0.2]


def cornell_dict(T=tf.Transform, rgb=lambda v: {"type": "rgb", "value": v}) -> dict:
    """scenes/cornell_box.xml written as a dict (T: our Transform or mi.ScalarTransform4f)."""

    def wall(t, bsdf):
        return {"type": "rectangle", "to_world": t, "bsdf": {"type": "ref", "id": bsdf}}

    return {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": 4},
        "sensor": {
            "type": "perspective", "fov": 45, "fov_axis": "y",
            "to_world": T().look_at(origin=[0, 0, 7], target=[0, 0, 4], up=[0, 1, 0]),
            "sampler": {"type": "independent", "sample_count": 100},
            "film": {"type": "hdrfilm", "width": 800, "height": 600, "rfilter": {"type": "box"}},
        },
        "white": {"type": "diffuse", "reflectance": rgb([0.725, 0.71, 0.68])},
        "red": {"type": "diffuse", "reflectance": rgb([0.63, 0.065, 0.05])},
        "green": {"type": "diffuse", "reflectance": rgb([0.14, 0.45, 0.091])},
        "block": {"type": "diffuse", "reflectance": rgb([0.85, 0.75, 0.5])},
        "light_bsdf": {"type": "diffuse", "reflectance": rgb([0.0, 0.0, 0.0])},
        "floor": wall(T().translate([0, -2, 0]).rotate([1, 0, 0], -90).scale(2), "white"),
        "ceiling": wall(T().translate([0, 2, 0]).rotate([1, 0, 0], 90).scale(2), "white"),
        "back_wall": wall(T().translate([0, 0, -2]).scale(2), "white"),
        "left_wall": wall(T().translate([-2, 0, 0]).rotate([0, 1, 0], 90).scale(2), "red"),
        "right_wall": wall(T().translate([2, 0, 0]).rotate([0, 1, 0], -90).scale(2), "green"),
        "light": {"type": "rectangle", "to_world": T().translate([0, 1.999, 0]).rotate([1, 0, 0], 90).scale(0.5),
                  "bsdf": {"type": "ref", "id": "light_bsdf"},
                  "emitter": {"type": "area", "radiance": rgb([30.0, 30.0, 30.0])}},
        "tall_block": {"type": "cube",
                       "to_world": T().translate([-0.65, -1, -0.45]).rotate([0, 1, 0], 18).scale([0.5, 1, 0.5]),
                       "bsdf": {"type": "ref", "id": "block"}},
        "sphere": {"type": "sphere", "center": [0.75, -1.4, 0.55], "radius": 0.6,
                   "bsdf": {"type": "ref", "id": "block"}},
    }


def assert_scenes_equal(a: Scene, b: Scene, atol=1e-12):
    for f in ("width", "height", "spp", "sampler_seed", "integrator", "materials"):
        assert getattr(a, f) == getattr(b, f), f
    assert (a.camera.fov, a.camera.fov_axis, a.camera.near_clip, a.camera.far_clip) == \
        (b.camera.fov, b.camera.fov_axis, b.camera.near_clip, b.camera.far_clip)
    np.testing.assert_allclose(a.camera.to_world, b.camera.to_world, atol=atol)
    assert len(a.spheres) == len(b.spheres) and len(a.meshes) == len(b.meshes) and len(a.lights) == len(b.lights)
    for x, y in zip(a.spheres, b.spheres):
        np.testing.assert_allclose(x.center, y.center, atol=atol)
        assert x.radius == pytest.approx(y.radius) and x.material == y.material
    for x, y in zip(a.meshes, b.meshes):
        np.testing.assert_allclose(x.vertices, y.vertices, atol=atol)
        np.testing.assert_array_equal(x.faces, y.faces)
        assert (x.normals is None) == (y.normals is None)
        if x.normals is not None:
            np.testing.assert_allclose(x.normals, y.normals, atol=atol)
        assert (x.material, x.light, x.name) == (y.material, y.light, y.name)
    for x, y in zip(a.lights, b.lights):
        for f in ("center", "half_u", "half_v", "normal"):
            np.testing.assert_allclose(getattr(x, f), getattr(y, f), atol=atol)
        assert x.radiance == y.radiance


def test_load_dict_equals_load_file():
    from_file = load_file(SCENES / "cornell_box.xml")
    from_dict = load_dict(cornell_dict())
    assert from_dict.source == "<dict>"
    assert_scenes_equal(from_file, from_dict)
    # plain matrices and colours as floats / 3-lists work too
    d = cornell_dict(rgb=lambda v: v if len(set(v)) > 1 else v[0])
    for key in ("floor", "light"):
        d[key]["to_world"] = d[key]["to_world"].matrix.tolist()
    d["sensor"]["to_world"] = np.array(d["sensor"]["to_world"].matrix)
    assert_scenes_equal(from_file, load_dict(d, source="cornell"))


# ---------------------------------------------------------------------------------------------
# the seed scenes


@pytest.mark.parametrize("name", SEED_SCENES)
def test_seed_scenes_load(name):
    s = load_file(SCENES / f"{name}.xml")
    assert (s.width, s.height) == (800, 600)
    assert (s.camera.fov, s.camera.fov_axis) == (45, "y")
    np.testing.assert_allclose(s.camera.to_world @ [0, 0, 0, 1], [0, 0, 7, 1])
    np.testing.assert_allclose(s.camera.to_world @ [0, 0, 1, 0], [0, 0, -1, 0])
    assert s.integrator.max_depth == 4 and s.spp == (50 if name == "teapot_in_box" else 100)
    assert len(s.lights) == 1
    s = load_file(SCENES / f"{name}.xml", spp=2, max_depth=2)
    assert (s.spp, s.integrator.max_depth) == (2, 2)


@pytest.mark.parametrize("name", ["cornell_box", "cornell_box_mirror", "teapot_in_box"])
def test_box_walls_face_into_the_box(name):
    s = load_file(SCENES / f"{name}.xml")
    walls = [m for m in s.meshes if len(m.faces) == 2 and m.light < 0]
    assert len(walls) == 5
    for w in walls:
        centre = w.vertices.mean(axis=0)
        assert np.all(face_normals(w) @ -centre > 0), w.name  # towards the box centre (the origin)
        assert np.abs(w.vertices).max() == pytest.approx(2.0)
    (light,) = s.lights
    np.testing.assert_allclose(light.center, [0, 1.999, 0])
    np.testing.assert_allclose(light.normal, [0, -1, 0], atol=1e-15)
    assert light.area == pytest.approx(1.0)
    assert light.radiance == ((70.0,) * 3 if name == "teapot_in_box" else (30.0,) * 3)
    lamp = next(m for m in s.meshes if m.light == 0)
    assert s.materials[lamp.material] == Material("diffuse", (0.0, 0.0, 0.0))


def test_cornell_block_and_sphere():
    s = load_file(SCENES / "cornell_box.xml")
    block = next(m for m in s.meshes if m.name == "tall_block")
    lo, hi = block.vertices.min(axis=0), block.vertices.max(axis=0)
    assert lo[1] == pytest.approx(-2) and hi[1] == pytest.approx(0)
    unit = np.array([[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)])
    seed = tf.transform_points(tf.translate([-0.65, -1, -0.45]) @ rot([0, 1, 0], 18) @ tf.scale([1, 2, 1]), unit)
    np.testing.assert_allclose(sorted(map(tuple, np.unique(block.vertices.round(12), axis=0))),
                               sorted(map(tuple, seed.round(12))))
    (sphere,) = s.spheres
    np.testing.assert_allclose(sphere.center, [0.75, -1.4, 0.55])
    assert sphere.radius == 0.6 and s.materials[sphere.material] == Material("diffuse", (0.85, 0.75, 0.5))
    mirror = load_file(SCENES / "cornell_box_mirror.xml")
    assert mirror.materials[mirror.spheres[0].material] == Material("mirror", (0.89, 0.89, 0.89))


def test_teapot_scene():
    s = load_file(SCENES / "teapot_in_box.xml")
    teapot = next(m for m in s.meshes if m.name == "teapot")
    assert teapot.faces.shape == (2464, 3) and teapot.normals is not None
    assert s.materials[teapot.material] == Material("mirror", (0.214, 0.214, 1.0))
    assert teapot.vertices[:, 1].min() == pytest.approx(-2.0)  # base on the floor
    assert not s.spheres and len(s.meshes) == 7


def test_open_sky_mirrors_face_the_camera():
    s = load_file(SCENES / "open_sky.xml")
    ground, red, green = s.spheres
    np.testing.assert_allclose(ground.center, [0, -1001, 0])
    assert ground.radius == 1000
    np.testing.assert_allclose([red.center, green.center], [[-1, -0.5, 5], [1, -0.5, 5]])
    r, g = s.materials[red.material].rgb, s.materials[green.material].rgb
    assert r[0] > 10 * max(r[1:]) and g[1] > 10 * max(g[0], g[2]) and max(r + g) < 1
    mirrors = {m.name: m for m in s.meshes if m.light < 0}
    front, back = mirrors["front_mirror"], mirrors["back_mirror"]
    np.testing.assert_allclose(front.vertices[:, 2], 4)
    np.testing.assert_allclose(face_normals(front), [[0, 0, 1]] * 2, atol=1e-12)
    np.testing.assert_allclose(back.vertices[:, 2], 10)
    np.testing.assert_allclose(face_normals(back), [[0, 0, -1]] * 2, atol=1e-12)
    for m in (front, back):
        assert np.ptp(m.vertices[:, 0]) == pytest.approx(5) and np.ptp(m.vertices[:, 1]) == pytest.approx(5)
        assert s.materials[m.material] == Material("mirror", (0.89, 0.89, 0.89))
    (light,) = s.lights
    np.testing.assert_allclose(light.center, [0, 10, 0])
    np.testing.assert_allclose(light.normal, [0, -1, 0], atol=1e-15)
    assert light.area == pytest.approx(100) and light.radiance == (5, 5, 5)


# ---------------------------------------------------------------------------------------------
# bad input: every error is one SceneError line naming the file, the element and the problem

S = SENSOR
BAD_XML = [
    # (scene body or whole file, element in the message, problem in the message)
    ('<shape type="sphere"><float name="radious" value="1"/></shape>', '<shape type="sphere">',
     'property "radious" is not supported (supported: center, radius, to_world'),
    ('<shape type="sphere"><float name="radius" value="-1"/></shape>', '<float name="radius">', "radius must be > 0"),
    ('<shape type="sphere"><float name="radius" value="0"/></shape>', '<float name="radius">', "radius must be > 0"),
    ('<shape type="sphere"><float name="radius" value="nan"/></shape>', '<float name="radius">', "not a finite number"),
    ('<shape type="sphere"><float name="radius" value="-inf"/></shape>', '<float name="radius">', "not a finite"),
    ('<shape type="sphere"><float name="radius" value="1e999"/></shape>', '<float name="radius">', "not a finite"),
    ('<shape type="sphere"><float name="radius" value="1.5x"/></shape>', '<float name="radius">', "not a number"),
    ('<shape type="sphere"><string name="radius" value="1"/></shape>', '<string name="radius">', "must be a number"),
    ('<shape type="sphere"><point name="center" value="0 nan 0"/></shape>', '<point name="center">', "not a finite"),
    ('<shape type="sphere"><point name="center" x="1"/></shape>', '<point name="center">', 'missing required attribute "y"'),
    ('<shape type="sphere"><rgb name="center" value="1 2 3"/></shape>', '<rgb name="center">', "must be a point"),
    ('<shape type="sphere"><boolean name="flip_normals" value="true"/></shape>', '<boolean name="flip_normals">',
     "flip_normals=true is not supported"),
    ('<shape type="cylinder"><float name="radius" value="-0.5"/></shape>', '<float name="radius">',
     "radius must be > 0"),
    ('<shape type="cylinder"><point name="p0" value="1, 2, 3"/><point name="p1" value="1, 2, 3"/></shape>',
     '<point name="p1">', "p0 and p1 must differ"),
    ('<shape type="disk"><transform name="to_world"><scale z="0"/></transform></shape>', '<transform name="to_world">',
     "to_world is singular"),
    ('<integrator type="moment"/>', '<integrator type="moment">', "needs a nested integrator"),
    ('<integrator type="moment"><integrator type="path"/><integrator type="direct"/></integrator>',
     '<integrator type="direct">', "only one integrator inside moment"),
    ('<integrator type="moment"><integrator type="moment"><integrator type="path"/></integrator></integrator>',
     '<integrator type="moment">', "cannot nest another moment"),
    ('<shape type="sphere"><transform name="to_world"><scale x="2"/></transform></shape>', '<transform name="to_world">',
     "may only translate, rotate and scale uniformly"),
    ('<shape type="sphere"><transform name="to_world"><scale value="-1"/></transform></shape>',
     '<transform name="to_world">', "must not mirror"),
    ('<shape type="sphere"><emitter type="point"/></shape>', '<emitter type="point">',
     "a shape can only hold an area emitter (a point emitter goes at scene level)"),
    ('<emitter type="constant"/><emitter type="constant"/>', '<emitter type="constant">',
     "only one environment emitter (constant or envmap) is allowed per scene"),
    ('<emitter type="point"><point name="position" value="0, 0, 0"/><transform name="to_world"><translate x="1"/>'
     '</transform></emitter>', '<point name="position">', 'give "position" or "to_world", not both'),
    ('<emitter type="spot"><float name="cutoff_angle" value="0"/></emitter>', '<float name="cutoff_angle">',
     "cutoff_angle must be in (0, 90] degrees"),
    ('<emitter type="spot"><float name="beam_width" value="30"/></emitter>', '<float name="beam_width">',
     "beam_width must be in [0, cutoff_angle = 20.0) degrees"),
    ('<emitter type="directional"><vector name="direction" value="0, 0, 0"/></emitter>', '<vector name="direction">',
     "the direction must not be zero"),
    ('<emitter type="point"><rgb name="intensity" value="-1"/></emitter>', '<rgb name="intensity">',
     "intensity must be >= 0"),
    ('<emitter type="area" id="e"/><shape type="sphere"><ref id="e"/></shape><shape type="sphere"><ref id="e"/>'
     '</shape>', '<emitter type="area" id="e">', "an area emitter can be attached to one shape only"),
    ('<shape type="rectangle"><emitter type="projector"/></shape>', '<emitter type="projector">',
     'emitter type "projector" is not supported (supported: area, constant, directional, envmap, point, spot)'),
    ('<shape type="rectangle"><emitter type="envmap"/></shape>', '<emitter type="envmap">',
     "a shape can only hold an area emitter"),
    ('<emitter type="envmap"/>', '<emitter type="envmap">', 'envmap needs "filename"'),
    ('<emitter type="envmap"><string name="filename" value="nope.exr"/></emitter>', '<string name="filename">',
     'envmap "nope.exr": cannot read'),
    ('<emitter type="envmap"><string name="filename" value="sky.tga"/></emitter>', '<string name="filename">',
     "only OpenEXR (.exr), Radiance HDR (.hdr) and PNG maps are supported"),
    ('<emitter type="envmap"><string name="filename" value="a.exr"/><float name="scale" value="-1"/></emitter>',
     '<float name="scale">', "scale must be >= 0"),
    ('<emitter type="envmap"><string name="filename" value="a.exr"/><transform name="to_world"><scale value="2"/>'
     '</transform></emitter>', '<transform name="to_world">', "may only rotate"),
    ('<emitter type="constant"/><emitter type="envmap"><string name="filename" value="a.exr"/></emitter>',
     '<emitter type="envmap">', "only one environment emitter"),
    ('<shape type="rectangle"><emitter type="area"><rgb name="radiance" value="-1 1 1"/></emitter></shape>',
     '<rgb name="radiance">', "radiance must be >= 0"),
    ('<shape type="rectangle"><emitter type="area"/><emitter type="area"/></shape>', '<emitter type="area">',
     "only one emitter"),
    ('<shape type="rectangle"><bsdf type="diffuse"/><bsdf type="diffuse"/></shape>', '<bsdf type="diffuse">',
     "only one bsdf"),
    ('<shape type="rectangle"><transform name="to_world"><scale z="0"/></transform></shape>',
     '<transform name="to_world">', "singular"),
    ('<shape type="rectangle"><transform name="to_world"><matrix value="1 0 0 0 0 1 0 0 0 0 1 0 0 0 1 1"/>'
     '</transform></shape>', '<transform name="to_world">', "must be affine"),
    ('<shape type="rectangle"><transform name="to_world"><rotate y="2" angle="30"/></transform></shape>',
     "<rotate>", "must be a unit vector"),
    ('<shape type="rectangle"><transform name="to_world"><rotate y="1"/></transform></shape>', "<rotate>",
     'missing required attribute "angle"'),
    ('<shape type="rectangle"><transform name="to_world"><rotate angle="30"/></transform></shape>', "<rotate>",
     "rotation axis cannot be zero"),
    ('<shape type="rectangle"><transform name="to_world"><translate value="1 2"/></transform></shape>',
     "<translate>", "must have 1 or 3 numbers"),
    ('<shape type="rectangle"><transform name="to_world"><translate value="1 2 3" x="1"/></transform></shape>',
     "<translate>", 'cannot mix "value"'),
    ('<shape type="rectangle"><transform name="to_world"><matrix value="1 2 3"/></transform></shape>', "<matrix>",
     "must have 16 or 9 numbers"),
    ('<shape type="rectangle"><transform name="to_world"><lookat origin="0 0 0" target="0 0 0"/></transform></shape>',
     "<lookat>", "invalid lookat"),
    ('<shape type="rectangle"><transform name="to_world"><shear value="1"/></transform></shape>', "<shear>",
     "cannot appear inside <transform>"),
    ('<shape type="rectangle"><translate value="1"/></shape>', "<translate>", "can only appear inside a <transform>"),
    ('<shape type="rectangle"><transform name="toWorld"/></shape>', '<shape type="rectangle">',
     'property "toWorld" is not supported'),
    ('<shape type="torus"/>', '<shape type="torus">',
     'shape type "torus" is not supported (supported: cube, cylinder, disk, obj'),
    ('<shape type="shapegroup"/>', '<shape type="shapegroup">', 'shape type "shapegroup" is not supported'),
    ('<shape/>', "<shape>", 'missing required attribute "type"'),
    ('<shape type="sphere" foo="1"/>', '<shape type="sphere">', 'unexpected attribute "foo"'),
    ('<shape type="sphere"><foo/></shape>', "<foo>", "unknown element <foo>"),
    ('<shape type="sphere"><texture type="bitmap" name="x"/></shape>', '<texture type="bitmap" name="x">',
     "a texture cannot appear inside"),
    ('<bsdf type="diffuse"><spectrum name="reflectance" type="blackbody"/></bsdf>',
     '<spectrum type="blackbody" name="reflectance">', 'spectrum plugins (<spectrum type="blackbody">) are not supported'),
    ('<shape type="sphere"><bsdf type="diffuse"><spectrum name="reflectance" value="1.5"/></bsdf></shape>',
     '<spectrum name="reflectance">', "reflectance must lie in [0, 1]"),
    ('<include filename="other.xml"/>', '<include filename="other.xml">', 'included file "other.xml" not found'),
    ('<scene version="3.0.0"/>', "<scene>", "<scene> can only be the root element"),
    ('<shape type="sphere"><ref id="nope"/></shape>', '<ref id="nope">', 'reference to unknown id "nope"'),
    ('<shape type="sphere" id="s"/><shape type="sphere"><ref id="s"/></shape>', '<shape type="sphere" id="s">',
     "a shape cannot appear inside"),
    ('<bsdf type="diffuse" id="a"/><bsdf type="diffuse" id="a"/>', '<bsdf type="diffuse" id="a">', "given twice"),
    ('<bsdf type="diffuse" id="a"/><shape type="sphere"><bsdf type="diffuse" id="a"/></shape>',
     '<bsdf type="diffuse" id="a">', 'duplicate id "a"'),
    ('<bsdf type="twosided" id="t"><ref id="t"/></bsdf>', '<bsdf type="twosided" id="t">', "cannot contain itself"),
    ('<bsdf type="sphere"/>', '<bsdf type="sphere">', 'bsdf type "sphere" is not supported (supported: conductor, '
                                                      'dielectric, diffuse, plastic, roughconductor'),
    ('<bsdf type="roughdielectric"/>', '<bsdf type="roughdielectric">', 'bsdf type "roughdielectric" is not supported'),
    ('<bsdf type="roughconductor"><float name="alpha" value="-0.1"/></bsdf>', '<float name="alpha">',
     "alpha must be >= 0"),
    ('<bsdf type="roughconductor"><float name="alpha_u" value="0.1"/><float name="alpha_v" value="0.3"/></bsdf>',
     '<float name="alpha_u">', "anisotropic roughness"),
    ('<bsdf type="roughconductor"><float name="alpha_u" value="0.1"/></bsdf>', '<float name="alpha_u">',
     "alpha_u and alpha_v go together"),
    ('<bsdf type="roughconductor"><string name="distribution" value="phong"/></bsdf>', '<string name="distribution">',
     'unknown distribution "phong" (supported: beckmann, ggx)'),
    ('<bsdf type="roughconductor"><texture name="alpha" type="checkerboard"/></bsdf>', '<texture',
     "alpha: a texture is not supported here"),
    ('<bsdf type="conductor"><string name="material" value="Unobtainium"/></bsdf>', '<string name="material">',
     'unknown conductor material "Unobtainium"'),
    ('<bsdf type="conductor"><string name="material" value="au"/></bsdf>', '<string name="material">',
     'did you mean "Au"?'),
    ('<bsdf type="conductor"><string name="material" value="Au"/><float name="eta" value="1"/></bsdf>',
     '<string name="material">', "give either a material or eta and k, not both"),
    ('<bsdf type="conductor"><rgb name="k" value="-1 1 1"/></bsdf>', '<rgb name="k">', "k must be >= 0"),
    ('<bsdf type="dielectric"><string name="int_ior" value="glass"/></bsdf>', '<string name="int_ior">',
     'unknown int_ior "glass" (known: vacuum'),
    ('<bsdf type="dielectric"><float name="ext_ior" value="-1"/></bsdf>', '<float name="ext_ior">', "ext_ior must be > 0"),
    ('<bsdf type="thindielectric"><rgb name="specular_transmittance" value="2"/></bsdf>',
     '<rgb name="specular_transmittance">', "must lie in [0, 1]"),
    ('<bsdf type="plastic"><float name="int_ior" value="1.000277"/></bsdf>', '<float name="int_ior">',
     "plastic needs int_ior and ext_ior to differ"),
    ('<bsdf type="plastic"><float name="alpha" value="0.1"/></bsdf>', '<bsdf type="plastic">',
     'property "alpha" is not supported'),
    ('<bsdf type="diffuse"><rgb name="reflectance" value="1.5 0 0"/></bsdf>', '<rgb name="reflectance">',
     "reflectance must lie in [0, 1]"),
    ('<bsdf type="diffuse"><rgb name="reflectance" value="1 2"/></bsdf>', '<rgb name="reflectance">',
     "must have 1 or 3 numbers"),
    ('<bsdf type="diffuse"><point name="reflectance" value="1"/></bsdf>', '<point name="reflectance">',
     "must be an <rgb> or a <float>"),
    ('<bsdf type="diffuse"><float name="reflectance" value="0.5"/><float name="reflectance" value="0.5"/></bsdf>',
     '<float name="reflectance">', '"reflectance" is given twice'),
    ('<bsdf type="diffuse"><bsdf type="diffuse"/></bsdf>', '<bsdf type="diffuse">', "a bsdf cannot appear inside"),
    ('<bsdf type="twosided"/>', '<bsdf type="twosided">', "twosided needs one nested bsdf"),
    ('<bsdf type="twosided"><bsdf type="diffuse"/><bsdf type="conductor"/></bsdf>', '<bsdf type="conductor">',
     "two different bsdfs"),
    ('<bsdf type="twosided"><bsdf type="twosided"><bsdf type="diffuse"/></bsdf></bsdf>', '<bsdf type="twosided">',
     "cannot be nested in a twosided"),
    ('<film type="hdrfilm"/>', '<film type="hdrfilm">', "must be nested in the sensor"),
    ('<integrator type="volpath"/>', '<integrator type="volpath">', 'integrator type "volpath" is not supported '
                                                                   '(supported: direct, moment, path)'),
    ('<integrator type="direct"><integer name="emitter_samples" value="0"/></integrator>',
     '<integer name="emitter_samples">', "emitter_samples must be > 0"),
    ('<integrator type="direct"><integer name="shading_samples" value="2"/><integer name="bsdf_samples" value="1"/>'
     '</integrator>', '<integer name="shading_samples">', "not both"),
    ('<integrator type="direct"><boolean name="hide_emitters" value="true"/></integrator>',
     '<boolean name="hide_emitters">', "not supported for direct"),
    ('<integrator type="path"/><integrator type="path"/>', '<integrator type="path">', "only one integrator"),
    ('<integrator type="path"><integer name="max_depth" value="-2"/></integrator>', '<integer name="max_depth">',
     "max_depth must be -1 (unlimited) or >= 0"),
    ('<integrator type="path"><integer name="max_depth" value="4.0"/></integrator>', '<integer name="max_depth">',
     "is not an integer"),
    ('<integrator type="path"><float name="max_depth" value="4"/></integrator>', '<float name="max_depth">',
     "must be an integer"),
    ('<integrator type="path"><integer name="rr_depth" value="0"/></integrator>', '<integer name="rr_depth">',
     "rr_depth must be > 0"),
    ('<integrator type="path"><boolean name="hide_emitters" value="1"/></integrator>',
     '<boolean name="hide_emitters">', "is not a boolean"),
    ('<float name="x" value="1"/>', '<float name="x">', '"x" cannot appear at scene level'),
    ('<ref id="x"/>', '<ref id="x">', "a ref cannot appear at scene level"),
    ('<default name="" value="1"/>', '<default name="">', "parameter name is empty"),
    ('<default name="a"/>', '<default name="a">', 'missing required attribute "value"'),
    ('<shape type="obj"/>', '<shape type="obj">', 'obj needs "filename"'),
    ('<shape type="obj"><string name="filename" value="missing.obj"/></shape>', '<shape type="obj">',
     'mesh file "missing.obj" cannot be read'),
    ('<shape type="ply"><string name="filename" value="."/></shape>', '<shape type="ply">', 'mesh file "." cannot'),
    (f'<shape type="ply"><string name="filename" value="{DATA / "body_comment.ply"}"/></shape>', '<shape type="ply">',
     "could not be read as PLY"),
    (f'<shape type="ply"><string name="filename" value="{DATA / "tetra.obj"}"/></shape>', '<shape type="ply">',
     "could not be read as PLY"),
]
BAD_SENSOR = [
    ('<sensor type="perspective"><string name="focal_length" value="3.5cm"/></sensor>',
     '<string name="focal_length">', 'focal_length "3.5cm" must be a positive length in mm (e.g. "50mm")'),
    ('<sensor type="perspective"><float name="fov" value="45"/><string name="focal_length" value="50mm"/></sensor>',
     '<string name="focal_length">', 'give "fov" or "focal_length", not both'),
    ('<sensor type="perspective"><string name="fov_axis" value="y"/></sensor>', '<string name="fov_axis">',
     'fov_axis applies to "fov" only'),
    ('<sensor type="perspective"><float name="fov" value="45"/><float name="aperture_radius" value="0.1"/></sensor>',
     '<sensor type="perspective">', 'property "aperture_radius" is not supported'),
    ('<sensor type="perspective"><float name="fov" value="45"/><float name="principal_point_offset_x" value="0.1"/>'
     '</sensor>', '<float name="principal_point_offset_x">', "off-centre projection) is not supported"),
    ('<sensor type="thinlens"><float name="fov" value="45"/></sensor>', '<sensor type="thinlens">',
     'needs "aperture_radius"'),
    ('<sensor type="thinlens"><float name="fov" value="45"/><float name="aperture_radius" value="-1"/></sensor>',
     '<float name="aperture_radius">', "aperture_radius must be >= 0 (got -1.0)"),
    ('<sensor type="thinlens"><float name="fov" value="45"/><float name="aperture_radius" value="0.1"/>'
     '<float name="focus_distance" value="0"/></sensor>', '<float name="focus_distance">', "focus_distance must be > 0"),
    ('<sensor type="perspective"><float name="fov" value="45"/><film type="hdrfilm"><integer name="crop_width" '
     'value="10"/></film></sensor>', '<integer name="crop_width">', "a crop window other than the whole film"),
    ('<sensor type="perspective"><float name="fov" value="45"/><film type="hdrfilm"><string name="file_format" '
     'value="png"/></film></sensor>', '<string name="file_format">', 'file_format "png" is not one of'),
    ('<sensor type="perspective"><float name="fov" value="180"/></sensor>', '<float name="fov">', "in (0, 180)"),
    ('<sensor type="perspective"><float name="fov" value="45"/><string name="fov_axis" value="z"/></sensor>',
     '<string name="fov_axis">', 'fov_axis "z" is not one of x, y, diagonal, smaller, larger'),
    ('<sensor type="perspective"><float name="fov" value="45"/><float name="near_clip" value="0"/></sensor>',
     '<float name="near_clip">', "near_clip must be > 0"),
    ('<sensor type="perspective"><float name="fov" value="45"/><float name="far_clip" value="0.001"/></sensor>',
     '<float name="far_clip">', "far_clip must be > near_clip"),
    ('<sensor type="perspective"><float name="fov" value="45"/><transform name="to_world"><scale value="2"/>'
     '</transform></sensor>', '<transform name="to_world">', "scale factors are not allowed"),
    ('<sensor type="orthographic"/>', '<sensor type="orthographic">', 'sensor type "orthographic" is not supported '
                                                                     '(supported: perspective, thinlens)'),
    ('<sensor type="perspective"><float name="fov" value="45"/><sampler type="independent">'
     '<integer name="sample_count" value="0"/></sampler></sensor>', '<integer name="sample_count">',
     "sample_count must be in [1,"),
    ('<sensor type="perspective"><float name="fov" value="45"/><sampler type="independent">'
     '<integer name="seed" value="-1"/></sampler></sensor>', '<integer name="seed">', "seed must be in [0,"),
    ('<sensor type="perspective"><float name="fov" value="45"/><sampler type="stratified"/></sensor>',
     '<sampler type="stratified">', 'sampler type "stratified" is not supported (supported: independent)'),
    ('<sensor type="perspective"><float name="fov" value="45"/><film type="hdrfilm">'
     '<integer name="width" value="0"/></film></sensor>', '<integer name="width">', "width must be in [1,"),
    ('<sensor type="perspective"><float name="fov" value="45"/><film type="hdrfilm">'
     '<integer name="height" value="-3"/></film></sensor>', '<integer name="height">', "height must be in [1,"),
    ('<sensor type="perspective"><float name="fov" value="45"/><film type="hdrfilm">'
     '<string name="pixel_format" value="rgba"/></film></sensor>', '<string name="pixel_format">',
     'pixel_format "rgba" is not supported (supported: rgb)'),
    ('<sensor type="perspective"><float name="fov" value="45"/><film type="hdrfilm">'
     '<string name="component_format" value="uint8"/></film></sensor>', '<string name="component_format">',
     "not supported (supported: float16, float32)"),
    ('<sensor type="perspective"><float name="fov" value="45"/><film type="hdrfilm">'
     '<rfilter type="mitchell"/></film></sensor>', '<rfilter type="mitchell">',
     'rfilter type "mitchell" is not supported (supported: box, gaussian, tent)'),
    ('<sensor type="perspective"><float name="fov" value="45"/><film type="hdrfilm">'
     '<rfilter type="gaussian"><float name="stddev" value="-0.5"/></rfilter></film></sensor>',
     '<float name="stddev">', "stddev must be in (0, 64] pixels (got -0.5)"),
    ('<sensor type="perspective"><float name="fov" value="45"/><film type="hdrfilm">'
     '<rfilter type="tent"><float name="radius" value="0"/></rfilter></film></sensor>',
     '<float name="radius">', "radius must be in (0, 64] pixels (got 0.0)"),
    ('<sensor type="perspective"><float name="fov" value="45"/><film type="hdrfilm"/><film type="hdrfilm"/>'
     '</sensor>', '<film type="hdrfilm">', "only one film"),
    ('<sensor type="perspective"><float name="fov" value="45"/><shape type="sphere"/></sensor>',
     '<shape type="sphere">', "a shape cannot appear inside"),
]
BAD_FILES = [
    # (whole file, element, problem)
    (b"", "", "the file is empty"),
    (b"  \n\t ", "", "the file is empty"),
    (b"\x00\x01\x02\xff binary", "", "binary data"),
    (b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR", "", "binary data"),
    (b"hello, world", "line 1", "malformed XML: syntax error"),
    (b'<scene version="3.0.0">', "line 1", "malformed XML: no element found"),
    (b'<scene version="3.0.0"><shape type="sphere"></scene>', "line 1", "malformed XML: mismatched tag"),
    (b'<scene version="3.0.0"/><scene version="3.0.0"/>', "line 1", "malformed XML: junk after document element"),
    (b'<?xml version="1.0"?><!DOCTYPE scene [<!ENTITY a "b">]><scene version="3.0.0"/>', "line 1",
     "<!DOCTYPE> declarations are not supported"),
    (b"<scene/>", "line 1 <scene>", 'missing required attribute "version"'),
    (b'<scene version="3.0"/>', "line 1 <scene>", 'invalid version "3.0"'),
    (b'<scene version="0.6.0"><shape type="sphere"><float name="uoffset" value="1"/></shape></scene>',
     '<float name="uoffset">', "texture coordinate transforms are not supported"),
    (b'<scene version="3.0.0" type="x"/>', "line 1 <scene", 'unexpected attribute "type"'),
    (b'<shape version="3.0.0" type="sphere"/>', '<shape type="sphere">', "the root element must be <scene"),
    (b'<scene version="3.0.0"/>', "line 1 <scene>", "the scene has no sensor"),
    (('<scene version="3.0.0">' + S + S + "</scene>").encode(), '<sensor type="perspective">',
     "only one sensor is supported"),
]


def _check_error(err: SceneError, path: Path, element: str, problem: str):
    msg = str(err)
    assert "\n" not in msg
    assert msg.startswith(f"{path}: "), msg
    assert element in err.element, (element, msg)
    assert problem in err.problem, (problem, msg)


@pytest.mark.parametrize("body,element,problem", BAD_XML, ids=[c[2][:40] for c in BAD_XML])
def test_bad_scene_bodies(tmp_path, body, element, problem):
    p = write(tmp_path, scene_xml(body))
    with pytest.raises(SceneError) as e:
        load_file(p)
    _check_error(e.value, p, element, problem)
    if element.startswith("<"):
        assert re.match(r"line \d+ <", e.value.element), e.value.element


@pytest.mark.parametrize("sensor,element,problem", BAD_SENSOR, ids=[c[2][:40] for c in BAD_SENSOR])
def test_bad_sensors(tmp_path, sensor, element, problem):
    p = write(tmp_path, scene_xml("", sensor))
    with pytest.raises(SceneError) as e:
        load_file(p)
    _check_error(e.value, p, element, problem)


@pytest.mark.parametrize("data,element,problem", BAD_FILES, ids=[c[2][:40] for c in BAD_FILES])
def test_bad_files(tmp_path, data, element, problem):
    p = write(tmp_path, data)
    with pytest.raises(SceneError) as e:
        load_file(p)
    _check_error(e.value, p, element, problem)


def test_error_names_the_right_line(tmp_path):
    text = scene_xml('<shape type="sphere">\n\n  <float name="radious" value="1"/>\n</shape>')
    with pytest.raises(SceneError, match=r'scene.xml: line 3 <shape type="sphere">: property "radious"'):
        load_file(write(tmp_path, text))
    with pytest.raises(SceneError, match=r'line 5 <float name="radius">: radius must be > 0'):
        load_file(write(tmp_path, text.replace("radious", "radius").replace('value="1"', 'value="-1"')))


def test_missing_and_unreadable_scene_files(tmp_path):
    with pytest.raises(SceneError, match="nope.xml: cannot read the file"):
        load_file(tmp_path / "nope.xml")
    with pytest.raises(SceneError, match="cannot read the file"):
        load_file(tmp_path)


@pytest.mark.parametrize("content,problem", [
    (b"", "is empty"), (b"\x00\x01garbage\xff", "is binary data"), (b"hello\nworld\n", "has no faces"),
    (b"v 0 0 0\nv 1 0 0\n", "has no faces"), (b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n", "could not be read as OBJ"),
    (b"v 0 0 nan\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "has a vertex position that is NaN or infinite"),
    (b"v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 0\nf 1//1 2//1 3//1\n", "has a vertex normal that is zero"),
])
def test_bad_obj_files(tmp_path, content, problem):
    write(tmp_path, content, "m.obj")
    p = write(tmp_path, scene_xml('<shape type="obj"><string name="filename" value="m.obj"/></shape>'))
    with pytest.raises(SceneError) as e:
        load_file(p)
    _check_error(e.value, p, '<shape type="obj">', f'mesh file "m.obj" {problem}')


SHARED_MESHES = Path(__file__).resolve().parents[2] / "shared" / "data" / "meshes"
SIMPLE_OBJS = {
    "unused vertices, CRLF": b"v 0 0 0\r\nv 9 9 9\r\nv 1 0 0\r\nv 0 1 0\r\nf 1 3 4\r\nf 4 3 1\r\n",
    "normals": b"v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 2\nvn 0 1 1\nvn 1 0 1\ns 1\nf 1//1 2//2 3//3\n",
    "colours": b"# c\nv 0 0 0 1 0 0\nv 1 0 0 0 1 0\nv 0 1 0 0 0 1\nf 3 2 1\n",
}


def _assert_trimesh_arrays(ours, data: bytes, kind: str):
    """``ours`` (one reader's parts) are exactly what trimesh reads from ``data``: one part, the same positions,
    faces and normals, no uv."""
    theirs = meshio.read_with_trimesh(data, kind)
    assert ours is not None and len(ours) == len(theirs) == 1
    a, b = ours[0], theirs[0]
    np.testing.assert_array_equal(a.vertices, b.vertices)
    np.testing.assert_array_equal(a.faces, b.faces)
    assert (a.normals is None) == (b.normals is None)
    if a.normals is not None:
        np.testing.assert_array_equal(a.normals, b.normals)
    assert a.uv is None and b.uv is None


@pytest.mark.parametrize("name", ["teapot.obj", "teapot_6k.obj", "bunny.obj", *SIMPLE_OBJS])
def test_simple_obj_reader_gives_trimesh_arrays(name):
    """The OBJ files read without trimesh give exactly trimesh's arrays (positions, faces, normals, no uv)."""
    if name in SIMPLE_OBJS:
        data = SIMPLE_OBJS[name]
    else:
        if not (SHARED_MESHES / name).exists():
            pytest.fail(f"shared data not present: {SHARED_MESHES / name}")
        data = (SHARED_MESHES / name).read_bytes()
    _assert_trimesh_arrays(meshio.read_simple_obj(data), data, "obj")


TRI = b"v 0 0 0\nv 1 0 0\nv 0 1 0\n"


@pytest.mark.parametrize("data", [
    TRI + b"f 1/1 2/2 3/3\nvt 0 0\n", TRI + b"f -3 -2 -1\n", TRI + b"f 1 2 3 # comment\n", TRI + b"v 1 1 0\nf 1 2 3 4\n",
    b"o a\n" + TRI + b"f 1 2 3\n", b"usemtl m\n" + TRI + b"f 1 2 3\n", TRI + b"g g\nf 1 2 3\n",
    TRI + b"vn 0 0 1\nvn 0 0 1\nvn 0 0 1\nf 1//1 2// 3//3\n", TRI + b"vn 0 0 1\nf 1//1 2//1 3//1\n",
    TRI + b"f 1 2 4\n", TRI + b"f 1 2 3.5\n", b"v 0 0 0 1\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", TRI,
    TRI + b"  f 1 2 3\n", TRI + b"f 1 2 3\nf\n",
])
def test_simple_obj_reader_leaves_everything_else_to_trimesh(data):
    assert meshio.read_simple_obj(data) is None


def test_loading_the_teapot_scene_does_not_import_trimesh():
    """trimesh's import (with scipy's) was about a second of every teapot process."""
    import subprocess
    import sys

    code = ("import sys, pathtracer; pathtracer.load_file(sys.argv[1], width=8, height=6); "
            "print('trimesh' in sys.modules)")
    r = subprocess.run([sys.executable, "-c", code, str(SCENES / "teapot_in_box.xml")], capture_output=True,
                       text=True, check=True)
    assert r.stdout.strip().splitlines()[-1] == "False"


def _ply(vprops=(("float", "x"), ("float", "y"), ("float", "z")), verts=None, faces=None, fmt="<", count="uchar",
         index="int", index_name="vertex_indices", head=b"", nl=b"\n", tail=b"", extra=b""):
    """A binary PLY written by hand: a triangle-and-quad-free tetrahedron unless told otherwise."""
    verts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float) if verts is None else np.asarray(verts)
    faces = [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]] if faces is None else faces
    types = {"float": "f4", "double": "f8", "uchar": "u1", "int": "i4", "uint": "u4", "short": "i2"}
    name = "binary_little_endian" if fmt == "<" else "binary_big_endian"
    header = [b"ply", f"format {name} 1.0".encode()] + ([head] if head else []) + [f"element vertex {len(verts)}".encode()]
    header += [f"property {t} {n}".encode() for t, n in vprops] + [f"element face {len(faces)}".encode(),
                                                                     f"property list {count} {index} {index_name}".encode()]
    header = nl.join(header + ([extra] if extra else []) + [b"end_header"]) + nl
    vdt = np.dtype([(n, fmt + types[t]) for t, n in vprops])
    v = np.zeros(len(verts), vdt)
    for k, (_, n) in enumerate(vprops):
        v[n] = verts[:, k] if k < verts.shape[1] else 0.5 + k
    body = v.tobytes()
    for f in faces:
        body += np.array([len(f)], fmt + types[count]).tobytes() + np.array(f, fmt + types[index]).tobytes()
    return header + body + tail


NORMALS = (("float", "x"), ("float", "y"), ("float", "z"), ("float", "nx"), ("float", "ny"), ("float", "nz"))
SIMPLE_PLYS = {
    "triangles": _ply(),
    "normals": _ply(NORMALS, verts=np.array([[0, 0, 0, 0, 0, 1], [1, 0, 0, 0, 1, 0], [0, 1, 0, 1, 0, 0],
                                             [0, 0, 1, 1, 1, 1]], float)),
    "double, big-endian, uint": _ply((("double", "x"), ("double", "y"), ("double", "z")), fmt=">", index="uint"),
    "vertex_index, comments, CRLF": _ply(index_name="vertex_index", head=b"comment made by hand", nl=b"\r\n"),
    "quads": _ply(verts=np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1]], float),
                  faces=[[0, 1, 2, 3], [0, 1, 4, 3]]),
}


def _icosphere_ply():
    import trimesh

    return trimesh.exchange.ply.export_ply(trimesh.creation.icosphere(subdivisions=3), encoding="binary")


@pytest.mark.parametrize("name", [*SIMPLE_PLYS, "icosphere (trimesh's export)"])
def test_simple_ply_reader_gives_trimesh_arrays(name):
    """The binary PLY files read without trimesh give exactly trimesh's arrays (positions, faces, normals)."""
    data = SIMPLE_PLYS[name] if name in SIMPLE_PLYS else _icosphere_ply()
    _assert_trimesh_arrays(meshio.read_simple_ply(data), data, "ply")


@pytest.mark.parametrize("data", [
    _ply().replace(b"binary_little_endian", b"ascii", 1),
    _ply((("float", "x"), ("float", "y"), ("float", "z"), ("uchar", "red"))),
    _ply((("float", "x"), ("float", "y"), ("float", "z"), ("float", "u"), ("float", "v"))),
    _ply((("float", "x"), ("float", "y"))),
    _ply(faces=[[0, 2, 1], [0, 1, 3, 2]]),
    _ply(faces=[[0, 2, 1], [0, 1], [0, 1, 3, 2]]),  # as many bytes as three triangles
    _ply(count="int"),
    _ply(index="short"),
    _ply(index_name="vertex_ids"),
    _ply(tail=b"\0"),
    _ply(extra=b"element edge 0\nproperty int vertex1"),
    _ply(faces=[]),
    _ply()[:-3],
    b"not a ply at all",
])
def test_simple_ply_reader_leaves_everything_else_to_trimesh(data):
    assert meshio.read_simple_ply(data) is None


def test_loading_a_binary_ply_scene_does_not_import_trimesh(tmp_path):
    """As for the teapot's OBJ: trimesh's import was about a second of every process with a PLY mesh."""
    import subprocess
    import sys

    (tmp_path / "m.ply").write_bytes(SIMPLE_PLYS["normals"])
    p = write(tmp_path, scene_xml('<shape type="ply"><string name="filename" value="m.ply"/></shape>'))
    code = ("import sys, pathtracer; s = pathtracer.load_file(sys.argv[1]); "
            "print(len(s.meshes[0].faces), 'trimesh' in sys.modules)")
    r = subprocess.run([sys.executable, "-c", code, str(p)], capture_output=True, text=True, check=True)
    assert r.stdout.strip().splitlines()[-1] == "4 False"


def test_shared_bunny_ply_with_body_comments_is_rejected(tmp_path):
    """data/meshes/bunny_res4.ply has 'comment' lines among its faces: Mitsuba refuses it too."""
    bunny = Path(__file__).resolve().parents[2] / "shared" / "data" / "meshes" / "bunny_res4.ply"
    if not bunny.exists():
        pytest.fail(f"shared data not present: {bunny} (CI and the README's test command run with ../shared "
                    f"beside the repository)")
    p = write(tmp_path, scene_xml(f'<shape type="ply"><string name="filename" value="{bunny}"/></shape>'))
    with pytest.raises(SceneError, match="could not be read as PLY"):
        load_file(p)


BAD_DICTS = [
    # (scene dict, element, problem)
    ([], "", "a scene must be a dict"),
    ({"type": "shape"}, "scene dict", 'must have "type": "scene"'),
    ({"type": "scene"}, "scene dict", "the scene has no sensor"),
    ({"type": "scene", "cam": {"type": "perspective", "fov": "45"}}, "['cam']['fov']", "fov must be a number"),
    ({"type": "scene", "cam": {"type": "perspective", "fov": True}}, "['cam']['fov']", "fov must be a number"),
    ({"type": "scene", "cam": {"type": "perspective", "fov": float("nan")}}, "['cam']['fov']", "finite"),
    ({"type": "scene", "cam": {"type": "perspective", "fov": 45, "to_world": [[1, 2], [3, 4]]}},
     "['cam']['to_world']", "must be a 4x4 matrix"),
    ({"type": "scene", "cam": {"type": "perspective", "fov": 45, "to_world": "identity"}},
     "['cam']['to_world']", "must be a 4x4 matrix or a transform"),
    ({"type": "scene", "cam": {"type": "perspective", "fov": 45, "film": {"type": "hdrfilm", "width": 4.0}}},
     "['cam']['film']['width']", "width must be an integer"),
    ({"type": "scene", "cam": {"type": "perspective", "fov": 45}, "s": {"type": "sphere", "radious": 1}},
     "['s'] (type \"sphere\")", 'property "radious" is not supported'),
    ({"type": "scene", "cam": {"type": "perspective", "fov": 45}, "s": {"type": "sphere", "center": [0, 0]}},
     "['s']['center']", "must be a point"),
    ({"type": "scene", "cam": {"type": "perspective", "fov": 45}, "s": {"type": "sphere", "bsdf": {"type": "ref",
                                                                                                "id": "x"}}},
     "['s']['bsdf']", 'reference to unknown id "x"'),
    ({"type": "scene", "cam": {"type": "perspective", "fov": 45}, "s": {"type": "sphere", "bsdf": {
        "type": "diffuse", "reflectance": {"type": "bitmap", "filename": "a.png"}}}},
     "['s']['bsdf']['reflectance']['filename']", 'bitmap "a.png": cannot read'),
    ({"type": "scene", "cam": {"type": "perspective", "fov": 45}, "s": {"type": "sphere", "bsdf": {
        "type": "diffuse", "reflectance": {"type": "mesh_attribute"}}}},
     "['s']['bsdf']['reflectance']", 'texture type "mesh_attribute" is not supported (supported: bitmap, checkerboard)'),
    ({"type": "scene", "cam": {"type": "perspective", "fov": 45}, "s": {"type": "sphere", "bsdf": {
        "type": "dielectric", "specular_transmittance": {"type": "checkerboard"}}}},
     "['s']['bsdf']['specular_transmittance']", "a texture is not supported here"),
    ({"type": "scene", "cam": {"type": "perspective", "fov": 45}, "s": {"type": "sphere", "bsdf": {
        "type": "diffuse", "reflectance": {"type": "rgb", "value": [0.1, 0.2]}}}},
     "['s']['bsdf']['reflectance']", "must be an rgb value"),
    ({"type": "scene", "cam": {"type": "perspective", "fov": 45}, "l": {"type": "point", "position": [0, 0, 0],
                                                                          "to_world": np.eye(4)}},
     "['l']['position']", 'give "position" or "to_world", not both'),
    ({"type": "scene", "cam": {"type": "perspective", "fov": 45}, "x": {"type": "blah"}},
     "['x'] (type \"blah\")", 'unknown plugin type "blah"'),
    ({"type": "scene", "cam": {"type": "perspective", "fov": 45}, "x": 3}, "['x']", '"x" cannot appear at scene level'),
    ({"type": "scene", "cam": {"type": "perspective", "fov": 45}, "r": {"type": "rectangle", "emitter": {
        "type": "area", "radiance": {"type": "spectrum", "wavelengths": [500.0], "values": [1.0]}}}},
     "['r']['emitter']['radiance']", "radiance:"),
]


@pytest.mark.parametrize("d,element,problem", BAD_DICTS, ids=[c[2][:40] for c in BAD_DICTS])
def test_bad_dicts(d, element, problem):
    with pytest.raises(SceneError) as e:
        load_dict(d, source="mydict")
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith("mydict: ")
    assert element in e.value.element and problem in e.value.problem, msg


def test_dict_nested_ids_and_transforms():
    d = {"type": "scene", "cam": {"type": "perspective", "fov": 45, "to_world": tf.Transform().translate([0, 0, 3])},
         "a": {"type": "sphere", "bsdf": {"type": "diffuse", "id": "m", "reflectance": 0.3}},
         "b": {"type": "sphere", "mybsdf": {"type": "ref", "id": "m"}, "center": np.array([1.0, 2, 3]),
               "radius": np.float32(2)}}
    s = load_dict(d)
    assert s.spheres[0].material == s.spheres[1].material and s.materials[0].rgb == (0.3, 0.3, 0.3)
    np.testing.assert_array_equal(s.spheres[1].center, [1, 2, 3])
    np.testing.assert_array_equal(s.camera.to_world[:3, 3], [0, 0, 3])


# ---------------------------------------------------------------------------------------------
# fuzz: mutated scene files raise SceneError or load, never anything else

FUZZ_BASE = f"""<scene version="3.0.0">
    <default name="spp" value="4"/>
    <integrator type="path"><integer name="max_depth" value="3"/></integrator>
    <sensor type="perspective">
        <float name="fov" value="45"/><string name="fov_axis" value="y"/>
        <transform name="to_world"><lookat origin="0, 0, 7" target="0, 0, 4" up="0, 1, 0"/></transform>
        <sampler type="independent"><integer name="sample_count" value="$spp"/></sampler>
        <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="6"/><rfilter type="box"/></film>
    </sensor>
    <bsdf type="diffuse" id="white"><rgb name="reflectance" value="0.7, 0.7, 0.7"/></bsdf>
    <shape type="rectangle">
        <transform name="to_world"><scale value="2"/><rotate x="1" angle="-90"/><translate y="-2"/></transform>
        <ref name="bsdf" id="white"/>
    </shape>
    <shape type="rectangle">
        <transform name="to_world"><scale value="0.5"/><rotate x="1" angle="90"/><translate y="1.999"/></transform>
        <emitter type="area"><rgb name="radiance" value="30"/></emitter>
    </shape>
    <shape type="cube"><transform name="to_world"><scale x="0.5" y="1" z="0.5"/><matrix value="1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1"/></transform>
        <bsdf type="twosided"><bsdf type="conductor"><rgb name="specular_reflectance" value="0.9"/></bsdf></bsdf></shape>
    <shape type="sphere"><point name="center" value="0.75, -1.4, 0.55"/><float name="radius" value="0.6"/></shape>
    <shape type="obj"><string name="filename" value="{DATA / 'tetra.obj'}"/><boolean name="face_normals" value="false"/></shape>
</scene>
"""

# the elements of issue 10 (Mitsuba scenes in the wild): every bsdf, texture, emitter and integrator it added
FUZZ_BASE_FEATURES = f"""<scene version="3.0.0">
    <default name="spp" value="4"/>
    <integrator type="moment"><integrator type="direct" name="d"><integer name="emitter_samples" value="1"/></integrator>
        </integrator>
    <sensor type="thinlens">
        <float name="fov" value="45"/><float name="aperture_radius" value="0.05"/><float name="focus_distance" value="5"/>
        <transform name="to_world"><lookat origin="0, 0, 7" target="0, 0, 4" up="0, 1, 0"/></transform>
        <sampler type="independent"><integer name="sample_count" value="$spp"/></sampler>
        <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="6"/>
            <rfilter type="gaussian"><float name="stddev" value="0.5"/></rfilter></film>
    </sensor>
    <texture type="bitmap" id="tiles"><string name="filename" value="{ROOT / 'scenes' / 'features' / 'maps' / 'tiles.png'}"/>
        <string name="wrap_mode" value="mirror"/></texture>
    <emitter type="envmap"><string name="filename" value="{ROOT / 'scenes' / 'features' / 'maps' / 'sky_sun.exr'}"/>
        <float name="scale" value="0.5"/></emitter>
    <emitter type="spot"><float name="cutoff_angle" value="30"/><rgb name="intensity" value="2"/></emitter>
    <emitter type="point"><point name="position" value="0, 3, 0"/></emitter>
    <shape type="rectangle"><transform name="to_world"><scale value="2"/><rotate x="1" angle="-90"/></transform>
        <bsdf type="plastic"><texture type="checkerboard" name="diffuse_reflectance">
            <transform name="to_uv"><scale x="4" y="4"/></transform></texture>
            <float name="int_ior" value="1.5"/></bsdf></shape>
    <shape type="sphere"><float name="radius" value="0.5"/><bsdf type="dielectric"><string name="int_ior" value="water"/></bsdf></shape>
    <shape type="sphere"><point name="center" value="1, 0, 0"/><bsdf type="roughconductor"><string name="material" value="Au"/>
        <string name="distribution" value="ggx"/><float name="alpha" value="0.2"/></bsdf></shape>
    <shape type="sphere"><point name="center" value="-1, 0, 0"/><bsdf type="diffuse"><ref name="reflectance" id="tiles"/></bsdf></shape>
    <shape type="cube"><bsdf type="conductor"><rgb name="eta" value="0.2, 0.9, 1.1"/><rgb name="k" value="3.9, 2.4, 2.1"/></bsdf></shape>
    <shape type="rectangle"><bsdf type="thindielectric"><rgb name="specular_transmittance" value="0.9"/></bsdf></shape>
    <shape type="sphere"><point name="center" value="0, 2, 0"/><float name="radius" value="0.2"/>
        <emitter type="area"><rgb name="radiance" value="5"/></emitter></shape>
    <shape type="sphere"><point name="center" value="0, -2, 0"/><bsdf type="roughplastic"><float name="alpha" value="0.3"/>
        <string name="distribution" value="ggx"/></bsdf></shape>
    <shape type="serialized"><string name="filename" value="{ROOT / 'scenes' / 'features' / 'maps' / 'two_meshes.serialized'}"/>
        <integer name="shape_index" value="1"/></shape>
    <shape type="disk"><boolean name="flip_normals" value="true"/><transform name="to_world"><scale x="2" y="0.5"/>
        <translate y="3"/></transform><emitter type="area"><rgb name="radiance" value="3"/></emitter></shape>
    <shape type="cylinder"><point name="p0" value="-1, -1, 0"/><point name="p1" value="1, -1, 0"/>
        <float name="radius" value="0.1"/><bsdf type="diffuse"/></shape>
</scene>
"""

_TOKENS = ["nan", "inf", "-inf", "-1", "0", "1e309", "-0.5", "3", "1 2", "true", "x", "", "$spp", "$nope",
           "sphere", "rectangle", "area", "white", "1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1", "99999999999999999999999",
           "ggx", "Au", "bk7", "tiles", "clamp", "nearest", "dielectric", "checkerboard", "bitmap", "envmap",
           "roughplastic", "serialized"]


_KINDS = ["attr_value"] * 4 + ["number"] * 4 + ["attr_name", "delete_attr", "delete_elem", "dup_elem",
                                                  "rename_elem", "move_elem", "bytes", "truncate"]


@st.composite
def _mutated_scene(draw, base=FUZZ_BASE):
    text = base
    for _ in range(draw(st.integers(1, 3))):
        kind = draw(st.sampled_from(_KINDS))
        attrs = list(re.finditer(r'(\w+)="([^"]*)"', text))
        elems = list(re.finditer(r"<(\w+)[^<>]*/>", text))
        if kind == "attr_value" and attrs:
            m = draw(st.sampled_from(attrs))
            text = text[:m.start(2)] + draw(st.sampled_from(_TOKENS)) + text[m.end(2):]
        elif kind == "attr_name" and attrs:
            m = draw(st.sampled_from(attrs))
            text = text[:m.start(1)] + draw(st.sampled_from(["name", "value", "type", "id", "x", "foo"])) + text[m.end(1):]
        elif kind == "delete_attr" and attrs:
            m = draw(st.sampled_from(attrs))
            text = text[:m.start()] + text[m.end():]
        elif kind == "delete_elem" and elems:
            m = draw(st.sampled_from(elems))
            text = text[:m.start()] + text[m.end():]
        elif kind == "dup_elem" and elems:
            m = draw(st.sampled_from(elems))
            text = text[:m.end()] + m.group(0) + text[m.end():]
        elif kind == "move_elem" and elems:
            m, to = draw(st.sampled_from(elems)), draw(st.sampled_from(elems))
            text = text[:m.start()] + text[m.end():]
            at = min(to.start(), len(text))
            text = text[:at] + m.group(0) + text[at:]
        elif kind == "rename_elem" and elems:
            m = draw(st.sampled_from(elems))
            new = draw(st.sampled_from(["shape", "bsdf", "emitter", "float", "rgb", "point", "ref", "transform",
                                        "scale", "sensor", "film", "foo", "scene", "default", "integer", "lookat"]))
            text = text[:m.start(1)] + new + text[m.end(1):]
        elif kind == "number" and re.search(r"\d", text):
            m = draw(st.sampled_from(list(re.finditer(r"-?\d+(\.\d+)?", text))))
            value = draw(st.one_of(st.floats(allow_nan=True, allow_infinity=True).map(repr),
                                   st.integers(-10**30, 10**30).map(str)))
            text = text[:m.start()] + value + text[m.end():]
        elif kind == "truncate":
            text = text[:draw(st.integers(0, len(text)))]
        elif kind == "bytes":
            pos = draw(st.integers(0, len(text)))
            junk = draw(st.binary(min_size=1, max_size=8)).decode("latin-1")
            text = text[:pos] + junk + text[pos:]
    return text.encode("latin-1", errors="replace")


@settings(max_examples=300, deadline=None, derandomize=True, database=None, suppress_health_check=list(HealthCheck))
@given(data=_mutated_scene(), with_param=st.booleans())
def test_fuzz_mutated_scenes_raise_only_scene_errors(tmp_path_factory, data, with_param):
    path = tmp_path_factory.mktemp("fuzz") / "scene.xml"
    path.write_bytes(data)
    try:
        scene = load_file(path, **({"spp": 2} if with_param else {}))
    except SceneError as e:
        assert "\n" not in str(e) and str(e).startswith(str(path))
    else:
        assert isinstance(scene, Scene) and scene.spp > 0 and scene.width > 0
        for m in scene.meshes:
            assert np.all(np.isfinite(m.vertices))


@settings(max_examples=200, deadline=None, derandomize=True, database=None, suppress_health_check=list(HealthCheck))
@given(data=_mutated_scene(FUZZ_BASE_FEATURES), with_param=st.booleans())
def test_fuzz_mutated_feature_scenes_raise_only_scene_errors(tmp_path_factory, data, with_param):
    """The same on a scene with the bsdfs, textures, emitters, filter, lens and integrator of issue 10."""
    test_fuzz_mutated_scenes_raise_only_scene_errors.hypothesis.inner_test(tmp_path_factory, data, with_param)


def test_fuzz_feature_base_scene_loads(tmp_path):
    s = load_file(write(tmp_path, FUZZ_BASE_FEATURES))
    assert len(s.textures) == 2 and s.envmap is not None and s.integrator.kind == "direct"
    assert s.integrator.layer_names == ("d", "m2_d")
    assert {m.name for m in s.meshes} >= {"disk", "cylinder"} and len(s.mesh_lights) == 1
    assert {m.kind for m in s.materials} >= {"plastic", "dielectric", "roughconductor", "conductor", "thindielectric",
                                             "roughplastic"}


def test_fuzz_base_scene_loads(tmp_path):
    s = load_file(write(tmp_path, FUZZ_BASE))
    assert len(s.meshes) == 4 and len(s.spheres) == 1 and len(s.lights) == 1


_VALUES = st.one_of(
    st.none(), st.booleans(), st.integers(-(10**400), 10**400), st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=5), st.sampled_from(["ref", "rgb", "sphere", "diffuse", "white", "area", "scene"]),
    st.lists(st.floats(-2, 2), max_size=5), st.just(np.full((4, 4), np.nan)), st.just(np.eye(3)),
    st.fixed_dictionaries({"type": st.sampled_from(["rgb", "ref", "diffuse", "area", "blah", "box"])}),
)


@st.composite
def _mutated_dict(draw):
    d = cornell_dict()
    for _ in range(draw(st.integers(1, 3))):
        node, path = d, []
        while True:  # walk down to a random key
            key = draw(st.sampled_from(sorted(node)))
            if isinstance(node[key], dict) and draw(st.booleans()):
                node = node[key]
                continue
            break
        action = draw(st.sampled_from(["set", "delete", "add"]))
        if action == "set":
            node[key] = draw(_VALUES)
        elif action == "delete":
            del node[key]
        else:
            node[draw(st.sampled_from(["radius", "x", "id", "bsdf", "emitter", "to_world", "fov"]))] = draw(_VALUES)
    return d


@settings(max_examples=200, deadline=None, derandomize=True, database=None, suppress_health_check=list(HealthCheck))
@given(d=_mutated_dict())
def test_fuzz_mutated_dicts_raise_only_scene_errors(d):
    try:
        scene = load_dict(d)
    except SceneError as e:
        assert "\n" not in str(e) and str(e).startswith("<dict>")
    else:
        assert isinstance(scene, Scene)


# x field of view (degrees) that Mitsuba 3.9.1 computes (sensor.x_fov) for these sensors on a 300 x 200 film
# (measured with mi.load_string, see parse_fov in src/render/sensor.cpp)
MITSUBA_X_FOV = [
    ("", 39.5978),  # neither fov nor focal_length: "50mm", a diagonal field of view
    ('<string name="focal_length" value="35mm"/>', 54.4322),
    ('<string name="focal_length" value="50"/>', 39.5978),
    ('<float name="fov" value="45"/><string name="fov_axis" value="y"/>', 63.7071),
    ('<float name="fov" value="45"/><string name="fov_axis" value="diagonal"/>', 38.0327),
]


@pytest.mark.parametrize("props,x_fov", MITSUBA_X_FOV, ids=["default", "35mm", "50", "y", "diagonal"])
def test_field_of_view_as_mitsuba(tmp_path, props, x_fov):
    film = '<film type="hdrfilm"><integer name="width" value="300"/><integer name="height" value="200"/></film>'
    s = load_xml(tmp_path, "", f'<sensor type="perspective">{props}{film}</sensor>')
    tan_x, _ = s.camera.tan_half_fov(s.width, s.height)
    assert abs(np.degrees(2 * np.arctan(tan_x)) - x_fov) < 1e-3


def test_thinlens_and_accepted_film_properties(tmp_path):
    film = ('<film type="hdrfilm"><integer name="width" value="30"/><integer name="height" value="20"/>'
            '<string name="file_format" value="rgbe"/><boolean name="banner" value="false"/>'
            '<boolean name="sample_border" value="true"/><integer name="crop_width" value="30"/></film>')
    s = load_xml(tmp_path, "", f'<sensor type="thinlens"><float name="fov" value="30"/>'
                               f'<float name="aperture_radius" value="0.2"/>{film}</sensor>')
    assert s.camera.aperture_radius == 0.2 and s.camera.focus_distance == 1e4  # Mitsuba: far_clip by default
    assert s.sample_border and s.rfilter.kind == "gaussian"
    p = load_xml(tmp_path, "", '<sensor type="perspective"><float name="fov" value="30"/>'
                               '<float name="focus_distance" value="3"/></sensor>')
    assert p.camera.aperture_radius == 0.0  # accepted and unused by a pinhole, as in Mitsuba


def test_what_we_read_page_is_generated_from_the_plugin_table():
    """docs/what_we_read.md is pathtracer.plugin_docs' output (regenerate: python -m pathtracer.plugin_docs >
    docs/what_we_read.md), so the page cannot drift from what the loader reads."""
    from pathtracer import loader, plugin_docs

    page = (Path(__file__).parents[1] / "docs" / "what_we_read.md").read_text()
    assert page == plugin_docs.markdown()
    for t, p in loader.PLUGINS.items():
        assert f"| `{t}` |" in page
        assert all(f"`{k}`" in page for k in p.props)


def test_serialized_meshes_and_their_errors(tmp_path):
    maps = ROOT / "scenes" / "features" / "maps"
    body = f'<shape type="serialized"><string name="filename" value="{maps / "two_meshes.serialized"}"/>' \
           '<integer name="shape_index" value="1"/></shape>'
    s = load_xml(tmp_path, body)
    teapot = meshio.read_mesh(ROOT / "scenes" / "meshes" / "teapot.obj", "obj")[0]
    assert np.allclose(s.meshes[0].vertices, teapot.vertices, atol=1e-6)  # float32 in the file
    assert np.array_equal(s.meshes[0].faces, teapot.faces) and s.meshes[0].normals is not None
    data = (maps / "two_meshes.serialized").read_bytes()
    cases = [(data[:8], 0, "truncated or corrupt"), (b"\x00\x00" + data[2:], 0, "bad header"),
             (data, 2, "shape_index 2 is out of range"), (data, -1, "shape_index must be >= 0")]
    for i, (blob, index, problem) in enumerate(cases):
        f = tmp_path / f"bad{i}.serialized"
        f.write_bytes(blob)
        with pytest.raises(SceneError) as e:
            load_xml(tmp_path, f'<shape type="serialized"><string name="filename" value="{f}"/>'
                               f'<integer name="shape_index" value="{index}"/></shape>')
        assert problem in str(e.value) and "\n" not in str(e.value), str(e.value)


# --- disk and cylinder (pathtracer/tessellate.py) ------------------------------------------------------------------

def test_tessellated_disk_and_cylinder_keep_area_and_outline():
    from pathtracer import tessellate

    v, f = tessellate.disk()
    tri = v[f]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    assert np.all(cross[:, 2] > 0)  # wound counter-clockwise seen from +z
    assert abs(cross[:, 2].sum() / 2 - np.pi) < 1e-12  # the disk's area
    r = np.linalg.norm(v[:, :2], axis=1)
    assert r.max() - 1 <= tessellate.outline_error(tessellate.disk_area_scale()) + 1e-15
    assert np.bincount(f.ravel()).max() <= 8  # no fan: at most eight triangles around a vertex
    v, f, n = tessellate.cylinder()
    tri = v[f]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    assert np.all(np.einsum("ij,ij->i", cross, tri.mean(axis=1) * [1, 1, 0]) > 0)  # outwards
    assert abs(np.linalg.norm(cross, axis=1).sum() / 2 - 2 * np.pi) < 1e-9  # the lateral area 2 pi r h
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0)
    assert tessellate.outline_error(tessellate.cylinder_perimeter_scale()) < 3.2e-6


def test_cylinder_placement_and_flip_normals_as_mitsuba(tmp_path):
    """p0, p1 and radius place the prism around the axis from p0 to p1 (Mitsuba: to_world @ translate(p0) @
    to_frame(axis) @ scale(radius, radius, length)); flip_normals turns normals and winding inwards."""
    body = ('<shape type="cylinder" id="c"><point name="p0" value="1, 2, 3"/><point name="p1" value="1, 5, 7"/>'
            '<float name="radius" value="0.25"/>{}</shape>')
    for flip in (False, True):
        extra = '<boolean name="flip_normals" value="true"/>' if flip else ""
        s = load_file(write(tmp_path, scene_xml(body.format(extra))))
        m = [m for m in s.meshes if m.name == "c"][0]
        p0, axis = np.array([1, 2, 3.0]), np.array([0, 3, 4.0]) / 5
        rel = m.vertices - p0
        along = rel @ axis
        assert np.allclose(sorted(set(np.round(along, 9))), [0, 5])
        radial = rel - np.outer(along, axis)
        dist = np.linalg.norm(radial, axis=1)
        assert np.allclose(dist, 0.25, rtol=1e-5)
        outward = np.einsum("ij,ij->i", m.normals, radial / dist[:, None])
        assert np.allclose(outward, -1.0 if flip else 1.0)
        tri = m.vertices[m.faces]
        wind = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        mid = tri.mean(axis=1) - p0
        side = np.einsum("ij,ij->i", wind, mid - np.outer(mid @ axis, axis))
        assert np.all(side < 0) if flip else np.all(side > 0)


def test_disk_light_faces_where_mitsuba_says(tmp_path):
    """An emitting disk is a mesh light whose winding gives Mitsuba's normal: to_world's normal transform of +z,
    turned by flip_normals, and unchanged in sense by a mirroring to_world."""
    for transform, flip, expect in [("", False, [0, 0, 1]), ("", True, [0, 0, -1]),
                                    ('<transform name="to_world"><scale z="-1"/></transform>', False, [0, 0, -1]),
                                    ('<transform name="to_world"><scale x="-1"/></transform>', False, [0, 0, 1]),
                                    ('<transform name="to_world"><rotate x="1" angle="90"/></transform>', False,
                                     [0, -1, 0])]:
        extra = '<boolean name="flip_normals" value="true"/>' if flip else ""
        body = (f'<shape type="disk" id="d">{transform}{extra}<emitter type="area"><rgb name="radiance" value="1"/>'
                f'</emitter></shape>')
        s = load_file(write(tmp_path, scene_xml(body)))
        m = s.meshes[s.mesh_lights[0].mesh]
        tri = m.vertices[m.faces]
        wind = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        wind /= np.linalg.norm(wind, axis=1)[:, None]
        np.testing.assert_allclose(wind, np.broadcast_to(expect, wind.shape), atol=1e-9)
        assert abs(np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum() / 2
                   - np.pi) < 1e-9


def test_radiance_hdr_maps_load_as_envmaps():
    """Mitsuba reads .hdr envmaps (two of the public scenes use them): so do we, pixel for pixel (bitmaps read
    .hdr files through the same reader; a reflectance must still lie in [0, 1])."""
    from pathtracer.imageio import read_image

    hdr = str(Path(__file__).parent / "data" / "hdr" / "rle_16x9.hdr")
    s = load_dict({"type": "scene", "sensor": {"type": "perspective", "fov": 40},
                   "sky": {"type": "envmap", "filename": hdr, "scale": 2.0}})
    assert np.array_equal(s.envmap.image, read_image(hdr)) and s.envmap.scale == 2.0
    with pytest.raises(SceneError, match="a reflectance texture must lie in"):
        load_dict({"type": "scene", "sensor": {"type": "perspective", "fov": 40},
                   "ball": {"type": "sphere", "bsdf": {"type": "diffuse", "reflectance": {
                       "type": "bitmap", "filename": hdr}}}})
