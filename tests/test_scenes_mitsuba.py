"""Cross-checks against Mitsuba 3 itself: our scenes load there unchanged and mean the same thing.

Skipped when mitsuba is not installed. Geometry is compared by casting the same camera rays in
Mitsuba (scalar_rgb) and through our Scene (brute-force float64 intersection here): hit distance,
the normal Mitsuba shades with, emitter or not, and the BSDF.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from pathtracer import transform as tf
from pathtracer.loader import load_dict, load_file
from pathtracer.scene import Scene

mi = pytest.importorskip("mitsuba")
mi.set_variant("scalar_rgb")

from test_loader import DATA, SCENES, SEED_SCENES, assert_scenes_equal, cornell_dict  # noqa: E402

# ---------------------------------------------------------------------------------------------
# brute-force intersection with our Scene


def _hit_meshes(scene: Scene, o, d):
    best = (np.inf, None)
    for m in scene.meshes:
        v0, v1, v2 = (m.vertices[m.faces[:, i]] for i in range(3))
        e1, e2 = v1 - v0, v2 - v0
        p = np.cross(d, e2)
        det = np.einsum("ij,ij->i", e1, p)
        with np.errstate(all="ignore"):
            inv = 1.0 / det
            s = o - v0
            u = np.einsum("ij,ij->i", s, p) * inv
            q = np.cross(s, e1)
            v = (q @ d) * inv
            t = np.einsum("ij,ij->i", e2, q) * inv
            ok = (np.abs(det) > 1e-14) & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 1e-9)
        if ok.any():
            i = np.flatnonzero(ok)[np.argmin(t[ok])]
            if t[i] < best[0]:
                fn = np.cross(e1[i], e2[i])
                fn /= np.linalg.norm(fn)
                if m.normals is None:
                    n = fn
                else:
                    f = m.faces[i]
                    n = (1 - u[i] - v[i]) * m.normals[f[0]] + u[i] * m.normals[f[1]] + v[i] * m.normals[f[2]]
                    n /= np.linalg.norm(n)
                best = (t[i], (m.material, m.light, n))
    return best


def _hit_spheres(scene: Scene, o, d):
    best = (np.inf, None)
    for s in scene.spheres:
        oc = o - s.center
        b = oc @ d
        c = oc @ oc - s.radius ** 2
        disc = b * b - c
        if disc < 0:
            continue
        for t in (-b - np.sqrt(disc), -b + np.sqrt(disc)):
            if t > 1e-9 and t < best[0]:
                n = (o + t * d - s.center) / s.radius
                best = (t, (s.material, -1, n))
                break
    return best


def trace(scene: Scene, o, d):
    """(t, material index, light index, shading normal) of the nearest hit, or None."""
    o, d = np.asarray(o, float), np.asarray(d, float)
    a, b = _hit_meshes(scene, o, d), _hit_spheres(scene, o, d)
    t, hit = min(a, b, key=lambda x: x[0])
    return None if hit is None else (t, *hit)


def camera_rays(sensor, nx=20, ny=15):
    for j in range(ny):
        for i in range(nx):
            ray, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f((i + 0.5) / nx, (j + 0.5) / ny), mi.Point2f(0.5, 0.5))
            yield np.array(ray.o, dtype=float), np.array(ray.d, dtype=float)


def compare_hits(ours: Scene, theirs, rays, min_hits=1):
    hits = 0
    for o, d in rays:
        si = theirs.ray_intersect(mi.Ray3f(o, d))
        mine = trace(ours, o, d)
        assert si.is_valid() == (mine is not None), (o, d)
        if mine is None:
            continue
        hits += 1
        t, mat, light, n = mine
        assert t == pytest.approx(si.t, rel=1e-4, abs=1e-4)
        np.testing.assert_allclose(n, np.array(si.sh_frame.n), atol=2e-3)
        emitter = si.emitter(theirs)
        assert (emitter is not None) == (light >= 0)
        if emitter is not None:
            lit = ours.lights[light]
            front = float(np.dot(-d, lit.normal)) > 0
            le = np.array(emitter.eval(si))  # Mitsuba's emitted radiance toward -d
            np.testing.assert_allclose(le, lit.radiance if front else (0, 0, 0), rtol=1e-6)
        material = ours.materials[mat]
        bsdf = si.bsdf()
        name = str(bsdf).split("[")[0]
        params = mi.traverse(bsdf)
        if material.twosided:
            assert name == "TwoSided"
            name = str(bsdf).split("brdf[0] = ")[1].split("[")[0]
            params = {k.split(".", 1)[1]: params[k] for k in params.keys() if k.startswith("brdf_0.")}
        if material.kind == "diffuse":
            assert name == "SmoothDiffuse"
            np.testing.assert_allclose(np.array(params["reflectance.value"]) * np.ones(3), material.rgb, rtol=1e-6)
        else:
            assert name == "SmoothConductor"
            assert (params["eta.value"], params["k.value"]) == (0.0, 1.0)  # material "none": a perfect mirror
            np.testing.assert_allclose(np.array(params["specular_reflectance.value"]) * np.ones(3), material.rgb,
                                       rtol=1e-6)
    assert hits >= min_hits


# ---------------------------------------------------------------------------------------------
# the seed scenes


@pytest.fixture(scope="module", params=SEED_SCENES)
def both(request):
    path = SCENES / f"{request.param}.xml"
    return request.param, load_file(path), mi.load_file(str(path), optimize=False)


def test_seed_scene_summary_matches_mitsuba(both):
    name, ours, theirs = both
    assert len(theirs.emitters()) == len(ours.lights) == 1
    assert len(theirs.shapes()) == len(ours.meshes) + len(ours.spheres)
    assert {m.name for m in ours.meshes} <= {s.id() for s in theirs.shapes()}
    lo = np.min([m.vertices.min(axis=0) for m in ours.meshes] + [s.center - s.radius for s in ours.spheres], axis=0)
    hi = np.max([m.vertices.max(axis=0) for m in ours.meshes] + [s.center + s.radius for s in ours.spheres], axis=0)
    bbox = theirs.bbox()
    np.testing.assert_allclose(lo, np.array(bbox.min), rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(hi, np.array(bbox.max), rtol=1e-5, atol=1e-5)
    sensor = theirs.sensors()[0]
    np.testing.assert_allclose(ours.camera.to_world, np.array(sensor.world_transform().matrix), atol=1e-6)
    assert list(sensor.film().size()) == [ours.width, ours.height]
    assert sensor.sampler().sample_count() == ours.spp
    assert f"max_depth = {ours.integrator.max_depth}" in str(theirs.integrator())
    assert f"rr_depth = {ours.integrator.rr_depth}" in str(theirs.integrator())
    x_fov = float(str(sensor).split("x_fov = ")[1].split(",")[0])
    tx, _ = ours.camera.tan_half_fov(ours.width, ours.height)
    assert np.degrees(2 * np.arctan(tx)) == pytest.approx(x_fov, rel=1e-5)
    assert "BoxFilter" in str(sensor.film())


def test_seed_scene_rays_match_mitsuba(both):
    name, ours, theirs = both
    compare_hits(ours, theirs, camera_rays(theirs.sensors()[0]), min_hits=100)


def test_camera_rays_follow_our_camera_convention(both):
    """Mitsuba's ray through film position (u, v) (v = 0 at the top) is to_world @ ((1-2u) tx, (1-2v) ty, 1)."""
    _, ours, theirs = both
    sensor = theirs.sensors()[0]
    tx, ty = ours.camera.tan_half_fov(ours.width, ours.height)
    for u, v in [(0.1, 0.2), (0.5, 0.5), (0.9, 0.05), (0.3, 0.95)]:
        ray, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f(u, v), mi.Point2f(0.5, 0.5))
        local = np.array([(1 - 2 * u) * tx, (1 - 2 * v) * ty, 1.0])
        d = ours.camera.to_world[:3, :3] @ (local / np.linalg.norm(local))
        np.testing.assert_allclose(np.array(ray.d), d, atol=1e-6)


def test_light_seen_from_below_in_mitsuba_and_ours():
    """From a floor corner towards the light: it emits downwards, with the same radiance in both."""
    o = np.array([1.7, -1.9, 1.7])
    d = np.array([0.2, 1.999, 0.1]) - o
    d /= np.linalg.norm(d)
    for name, le in [("cornell_box", 30.0), ("teapot_in_box", 70.0)]:
        ours = load_file(SCENES / f"{name}.xml")
        theirs = mi.load_file(str(SCENES / f"{name}.xml"), optimize=False)
        compare_hits(ours, theirs, [(o, d)])
        si = theirs.ray_intersect(mi.Ray3f(o, d))
        assert si.shape.id() == "light"
        assert np.array(si.emitter(theirs).eval(si)) == pytest.approx([le] * 3)
        assert trace(ours, o, d)[2] == 0  # our light 0


# ---------------------------------------------------------------------------------------------
# shapes, transforms and meshes


def _random_rays(rng, n, target_scale=1.0, distance=6.0):
    for _ in range(n):
        o = rng.normal(size=3)
        o *= distance / np.linalg.norm(o)
        d = rng.normal(size=3) * 0.3 * target_scale - o
        yield o, d / np.linalg.norm(d)


MIRRORS = ["", '<scale x="-1"/>', '<scale x="-2" y="0.5"/><rotate x="1" angle="90"/>',
           '<rotate value="0.6 0 0.8" angle="33"/><scale y="-1.5" z="0.7"/><translate value="0.1 0.2 0.3"/>']


@pytest.mark.parametrize("ops", MIRRORS)
@pytest.mark.parametrize("shape", [
    '<shape type="rectangle"><transform name="to_world">{ops}</transform><emitter type="area">'
    '<rgb name="radiance" value="2 3 4"/></emitter></shape>',
    '<shape type="rectangle"><transform name="to_world">{ops}</transform><bsdf type="twosided">'
    '<bsdf type="diffuse"/></bsdf></shape>',
    '<shape type="cube"><transform name="to_world">{ops}</transform></shape>',
    '<shape type="obj"><string name="filename" value="{data}/quad_vn.obj"/><transform name="to_world">{ops}'
    '</transform><bsdf type="conductor"/></shape>',
    '<shape type="obj"><string name="filename" value="{data}/tetra.obj"/><transform name="to_world">{ops}'
    '</transform></shape>',
    '<shape type="obj"><string name="filename" value="{data}/tetra.obj"/><boolean name="face_normals" '
    'value="true"/><transform name="to_world">{ops}</transform></shape>',
    '<shape type="obj"><string name="filename" value="{tmp}/teapot_no_normals.obj"/><transform name="to_world">'
    '<translate y="-0.5"/>{ops}</transform></shape>',
    '<shape type="obj"><string name="filename" value="{scenes}/meshes/teapot.obj"/><transform name="to_world">'
    '<translate y="-0.5"/>{ops}</transform></shape>',
], ids=["light", "twosided", "cube", "quad_vn", "tetra", "tetra_flat", "teapot_recomputed", "teapot"])
def test_shapes_match_mitsuba_under_any_to_world(tmp_path, shape, ops):
    """Same hits, and the same shading normal (the side Mitsuba treats as the front), even when mirrored."""
    text = (SCENES / "meshes/teapot.obj").read_text().splitlines()
    (tmp_path / "teapot_no_normals.obj").write_text("\n".join(
        line.split("//")[0] if not line.startswith("f ") else " ".join(t.split("/")[0] for t in line.split())
        for line in text if not line.startswith("vn ")))
    body = shape.format(ops=ops, data=DATA, scenes=SCENES, tmp=tmp_path)
    path = tmp_path / "s.xml"
    path.write_text(f'<scene version="3.0.0"><sensor type="perspective"><float name="fov" value="45"/></sensor>'
                    f"{body}</scene>")
    ours, theirs = load_file(path), mi.load_file(str(path), optimize=False)
    compare_hits(ours, theirs, _random_rays(np.random.default_rng(len(body) + len(ops)), 150), min_hits=10)


def test_recomputed_vertex_normals_match_mitsuba():
    """Angle-weighted, in world space. Vertices only on pairs of opposite duplicate faces (the shared bunny
    has some) have no defined normal: Mitsuba's float32 sum gives noise there, so they are left out."""
    T = mi.ScalarTransform4f
    for tw in [T(), T().rotate([0.6, 0, 0.8], 33).scale([1, -1.5, 0.7]).translate([0.1, 0.2, 0.3])]:
        d = {"type": "scene", "s": {"type": "ply", "filename": str(DATA / "bunny_res4_clean.ply"), "to_world": tw}}
        params = mi.traverse(mi.load_dict(d, optimize=False).shapes()[0])
        theirs = np.array(params["vertex_normals"]).reshape(-1, 3)
        faces = np.array(params["faces"]).reshape(-1, 3)
        (mesh,) = load_dict({**d, "cam": {"type": "perspective", "fov": 45}}).meshes
        np.testing.assert_array_equal(mesh.faces, faces)
        np.testing.assert_allclose(mesh.vertices, np.array(params["vertex_positions"]).reshape(-1, 3), atol=1e-5)
        count = Counter(tuple(sorted(f)) for f in faces.tolist())
        good = sorted({v for key, n in count.items() if n == 1 for v in key})
        assert len(good) > 400
        np.testing.assert_allclose(mesh.normals[good], theirs[good], atol=2e-4)


def test_spheres_match_mitsuba(tmp_path):
    body = """<shape type="sphere"><point name="center" value="1 0 0"/><float name="radius" value="0.5"/>
        <transform name="to_world"><rotate z="1" angle="40"/><scale value="2"/><translate y="0.3"/></transform></shape>
        <shape type="sphere"><transform name="to_world"><scale value="0.7"/><translate x="-1.5"/></transform></shape>"""
    path = tmp_path / "s.xml"
    path.write_text(f'<scene version="3.0.0"><sensor type="perspective"><float name="fov" value="45"/></sensor>'
                    f"{body}</scene>")
    ours, theirs = load_file(path), mi.load_file(str(path), optimize=False)
    compare_hits(ours, theirs, _random_rays(np.random.default_rng(1), 200, target_scale=3), min_hits=50)


def test_transform_ops_match_mitsuba():
    T = mi.ScalarTransform4f
    rng = np.random.default_rng(7)
    for _ in range(20):
        v, a = rng.normal(size=3), rng.normal(size=3)
        a /= np.linalg.norm(a)
        angle = float(rng.uniform(-360, 360))
        np.testing.assert_allclose(tf.translate(v), np.array(T().translate(v.tolist()).matrix), atol=1e-6)
        np.testing.assert_allclose(tf.scale(v), np.array(T().scale(v.tolist()).matrix), atol=1e-6)
        np.testing.assert_allclose(tf.rotate(a, angle), np.array(T().rotate(a.tolist(), angle).matrix), atol=1e-6)
        o, t, u = rng.normal(size=(3, 3))
        np.testing.assert_allclose(tf.look_at(o, t, u), np.array(T().look_at(o.tolist(), t.tolist(), u.tolist()).matrix),
                                   atol=1e-5)
        ours = tf.Transform().translate(v).rotate(a, angle).scale(u)
        theirs = T().translate(v.tolist()).rotate(a.tolist(), angle).scale(u.tolist())
        np.testing.assert_allclose(ours.matrix, np.array(theirs.matrix), atol=1e-5)


def test_xml_transform_composition_matches_mitsuba(tmp_path):
    ops = """<scale x="0.5" y="2"/><rotate value="0, 0.6, 0.8" angle="-70"/><translate value="1 2 3"/>
        <matrix value="0 -1 0 0  1 0 0 0  0 0 1 0  0 0 0 1"/><scale value="1.5"/><rotate x="1" angle="10"/>
        <lookat origin="1 1 1" target="0 0 0" up="0 1 0"/><translate z="-4"/>"""
    path = tmp_path / "s.xml"
    path.write_text(f'<scene version="3.0.0"><sensor type="perspective"><float name="fov" value="45"/></sensor>'
                    f'<shape type="cube"><transform name="to_world">{ops}</transform></shape></scene>')
    ours, theirs = load_file(path), mi.load_file(str(path), optimize=False)
    params = mi.traverse(theirs.shapes()[0])
    np.testing.assert_allclose(ours.meshes[0].vertices, np.array(params["vertex_positions"]).reshape(-1, 3), atol=1e-5)
    np.testing.assert_array_equal(ours.meshes[0].faces, np.array(params["faces"]).reshape(-1, 3))


def test_load_dict_with_mitsuba_transforms_matches_file_and_mitsuba():
    d = cornell_dict(T=mi.ScalarTransform4f)
    assert_scenes_equal(load_file(SCENES / "cornell_box.xml"), load_dict(d), atol=1e-6)
    theirs = mi.load_dict(d, optimize=False)
    ours = load_dict(d)
    compare_hits(ours, theirs, camera_rays(theirs.sensors()[0], 12, 9), min_hits=50)


def test_mitsuba_defaults_we_rely_on():
    """The Mitsuba behaviour the loader copies, checked against the installed Mitsuba."""
    conductor = mi.traverse(mi.load_dict({"type": "conductor"}))
    assert (conductor["eta.value"], conductor["k.value"]) == (0.0, 1.0)  # material "none"
    scene = mi.load_dict({"type": "scene", "r": {"type": "rectangle", "emitter": {"type": "area"}}}, optimize=False)
    assert "value=1.000000" in str(scene.emitters()[0])  # radiance defaults to 1
    assert mi.traverse(scene.shapes()[0].bsdf())["reflectance.value"] == 0.0  # an emitter's default bsdf is black
    assert "max_depth = 4294967295" in str(mi.load_dict({"type": "path"}))  # -1: unlimited
    film = mi.load_dict({"type": "hdrfilm"})
    assert list(film.size()) == [768, 576] and "GaussianFilter" in str(film.rfilter())
    assert mi.load_dict({"type": "independent"}).sample_count() == 4
    with pytest.raises(RuntimeError, match="Scale factors"):
        mi.load_dict({"type": "perspective", "fov": 45, "to_world": mi.ScalarTransform4f().scale(2)})


def test_mitsuba_also_refuses_the_shared_bunny_ply():
    bunny = Path(__file__).resolve().parents[2] / "shared" / "data" / "meshes" / "bunny_res4.ply"
    if not bunny.exists():
        pytest.fail(f"shared data not present: {bunny} (CI and the README's test command run with ../shared "
                    f"beside the repository)")
    with pytest.raises(RuntimeError, match="could not parse"):
        mi.load_dict({"type": "ply", "filename": str(bunny)})
