"""Rectangles and cubes as analytic quads (kernels/quad.py, pathtracer/device_scene.py).

- ``ray_quad`` agrees with a float64 reference on the same float32 data (hit or miss, and t);
- rays exactly through the shared edge of two adjacent quads (the Cornell box's wall corners, a cube's edges)
  always hit one of the two, at every scale;
- a ray leaving a quad never hits it again (even without the skip the integrator adds), at every scale;
- end to end, a scene rendered with its rectangles and cube as quads equals the same scene with them as triangles
  in the BVH: to rounding in the deterministic views, within the noise otherwise.
"""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest
import warp as wp

import pathtracer
from helpers import make_scene, material
from pathtracer.device_scene import DeviceScene, mesh_quads, quad_groups, split_scene
from pathtracer.render import Renderer
from pathtracer.scene import TriangleMesh
from probes import arr, launch, probe_quads, probe_ray_box

ROOT = Path(__file__).resolve().parents[1]
CORNELL = ROOT / "scenes" / "cornell_box.xml"
TEAPOT = ROOT / "scenes" / "teapot_in_box.xml"


def rect_mesh(c, u, v, mat=0, flip=False, shape="rectangle") -> TriangleMesh:
    c, u, v = (np.asarray(x, dtype=np.float64) for x in (c, u, v))
    verts = np.array([c - u - v, c + u - v, c + u + v, c - u + v])
    faces = np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int64)
    if flip:
        faces = faces[:, [0, 2, 1]]
    return TriangleMesh(verts, faces, None, mat, shape=shape)


def quad_scene(meshes) -> "pathtracer.Scene":
    scene = make_scene((0, 0, 10), (0, 0, 0), 30, 4, 4)
    material(scene, "diffuse", 0.5)
    scene.meshes = list(meshes)
    return scene


def all_mesh(scene):
    """The same scene with every rectangle and cube forced into the BVH."""
    s = copy.deepcopy(scene)
    for m in s.meshes:
        m.shape = "mesh"
    return s


def run_probe(ds: DeviceScene, o, d, w=None, direct=None, tmax=None):
    n = len(o)
    w = d if w is None else w
    direct = np.zeros(n, np.int32) if direct is None else direct
    tmax = np.full(n, 3e38, np.float32) if tmax is None else tmax
    outs = launch(probe_quads, n, "cpu",
                  [ds.data, arr(o, wp.vec3, "cpu"), arr(d, wp.vec3, "cpu"), arr(w, wp.vec3, "cpu"),
                   arr(direct, wp.int32, "cpu"), arr(tmax, float, "cpu")],
                  [float, wp.int32, float, wp.vec3, float, wp.int32])
    return dict(zip(["t_direct", "q", "t", "p", "self_t", "q2"], outs))


def unit(v):
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def quad_corners(q) -> np.ndarray:
    c, u, v = q.center, q.half_u, q.half_v
    return np.array([c - u - v, c + u - v, c + u + v, c - u + v])


def shared_edges(quads, tol=1e-9):
    """(i, j, a, b): quads i and j share the edge from corner a to corner b (float64)."""
    out = []
    cs = [quad_corners(q) for q in quads]
    for i in range(len(quads)):
        for j in range(i + 1, len(quads)):
            scale = max(quads[i].scale, quads[j].scale)
            common = [a for a in cs[i] if np.min(np.abs(cs[j] - a).max(axis=1)) <= tol * scale]
            if len(common) == 2:
                out.append((i, j, common[0], common[1]))
    return out


# ------------------------------------------------------------------------------------------------
# the scene split


def test_loader_shapes_become_quads():
    scene = pathtracer.load_file(CORNELL)
    kinds = {m.name: m.shape for m in scene.meshes}
    assert kinds["floor"] == "rectangle" and kinds["tall_block"] == "cube"
    quads, tri = split_scene(scene)
    assert tri == [] and len(quads) == 6 + 6  # 5 walls, the light, the block's 6 faces
    f = DeviceScene.features(scene)
    assert f.quads and not f.meshes and f.spheres
    for m in scene.meshes:
        qs = mesh_quads(m)
        assert qs is not None and len(qs) == len(m.faces) // 2
        for q, face in zip(qs, m.faces[0::2]):
            # the quad's normal is its triangles' winding normal; its corners are the mesh's vertices
            v = m.vertices
            n = np.cross(v[face[1]] - v[face[0]], v[face[2]] - v[face[0]])
            assert np.allclose(q.normal, unit(n), atol=1e-12)
            for corner in quad_corners(q):
                assert np.min(np.abs(v - corner).max(axis=1)) <= 1e-12 * q.scale
            us, vs = q.duals()
            assert np.allclose([us @ q.half_u, us @ q.half_v, vs @ q.half_u, vs @ q.half_v], [1, 0, 0, 1])
    # the light quad is light 0
    ds = DeviceScene(scene, "cpu")
    lq = ds.data.light_quad.numpy()
    assert lq.shape == (1,) and ds.data.quad_light.numpy()[lq[0]] == 0
    # the teapot stays triangles, the walls do not
    t = pathtracer.load_file(TEAPOT)
    ft = DeviceScene.features(t)
    assert ft.quads and ft.meshes and ft.smooth_normals


def test_what_quads_cannot_represent_stays_triangles():
    trapezoid = TriangleMesh(np.array([[0, 0, 0], [2, 0, 0], [1.5, 1, 0], [0.5, 1, 0]], float),
                             np.array([[0, 1, 2], [0, 2, 3]]), None, 0, shape="rectangle")
    assert mesh_quads(trapezoid) is None
    assert mesh_quads(rect_mesh((0, 0, 0), (1, 0, 0), (0, 1, 0), shape="mesh")) is None
    assert len(mesh_quads(rect_mesh((0, 0, 0), (1, 0, 0), (0.3, 1, 0))) or []) == 1  # sheared: a parallelogram
    scene = quad_scene([trapezoid])
    f = DeviceScene.features(scene)
    assert f.meshes and not f.quads


# ------------------------------------------------------------------------------------------------
# ray_quad against float64


def random_quads(rng, n, scale=1.0):
    quads = []
    for _ in range(n):
        u = rng.normal(size=3) * scale * rng.uniform(0.2, 1.0)
        v = np.cross(u, rng.normal(size=3))
        v = unit(v) * scale * rng.uniform(0.2, 1.0) + 0.3 * rng.uniform(-1, 1) * u  # some shear
        quads.append(rect_mesh(rng.normal(size=3) * scale, u, v, flip=bool(rng.integers(2))))
    return quads


def test_ray_box_against_exact_overlap():
    """ray_box (the cube groups' cull test) says whether the segment [0, tmax] meets the box, against a reference
    that clips the segment exactly (fractions); rays with zero direction components and origins inside included."""
    from fractions import Fraction as F

    rng = np.random.default_rng(41)
    n = 4000
    lo = rng.uniform(-1, 0, (n, 3))
    hi = lo + rng.uniform(0.01, 1, (n, 3))
    o = rng.uniform(-3, 3, (n, 3))
    near = lo - 0.2 + rng.random((n, 3)) * (hi - lo + 0.4)  # aim near the box: about half hit it
    d = unit(near - o)
    d[rng.random((n, 3)) < 0.15] = 0.0  # axis-parallel rays
    d[(d == 0).all(axis=1), 0] = 1.0
    tmax = rng.choice([1e300, 1.0, 3.0], n)

    def exact(k):
        t0, t1 = F(0), F(tmax[k])
        for a in range(3):
            if d[k, a] == 0:
                if not lo[k, a] <= o[k, a] <= hi[k, a]:
                    return 0
                continue
            ta, tb = (F(lo[k, a]) - F(o[k, a])) / F(d[k, a]), (F(hi[k, a]) - F(o[k, a])) / F(d[k, a])
            t0, t1 = max(t0, min(ta, tb)), min(t1, max(ta, tb))
        return int(t0 <= t1)

    ref = np.array([exact(k) for k in range(n)])
    got = launch(probe_ray_box, n, "cpu", [wp.array(x, dtype=wp.vec3d) for x in (o, d, lo, hi)]
                 + [wp.array(tmax, dtype=wp.float64)], [wp.int32])
    assert 0.1 < ref.mean() < 0.9
    assert (got == ref).all()


def test_cube_groups_box_every_face():
    """Each cube's six quads form one group whose padded box holds every corner with margin; lone rectangles have
    no box (their own test is as cheap)."""
    scene = pathtracer.load_file(str(CORNELL), width=8, height=8)
    quads, _ = split_scene(scene)
    end, lo, hi = quad_groups(quads)
    boxed = np.flatnonzero(end >= 0)
    assert len(boxed) == 1 and end[boxed[0]] - boxed[0] == 6  # the tall block
    a, b = boxed[0], end[boxed[0]]
    corners = np.array([q.center + su * q.half_u + sv * q.half_v for q in quads[a:b] for su in (-1, 1)
                        for sv in (-1, 1)])
    assert (corners > lo[a] + 1e-12).all() and (corners < hi[a] - 1e-12).all()
    assert (hi[a] - lo[a] < np.ptp(corners, axis=0) + 1e-6).all()


def test_ray_quad_matches_float64_reference():
    rng = np.random.default_rng(1)
    nq, n = 64, 200_000
    ds = DeviceScene(quad_scene(random_quads(rng, nq)), "cpu")
    c, nrm, us, vs = (getattr(ds.data, k).numpy().astype(np.float64)
                      for k in ("quad_center", "quad_normal", "quad_ustar", "quad_vstar"))
    k = np.arange(n) % nq
    o = rng.normal(size=(n, 3)) * 4.0
    # half the rays aimed near the quad (many hits and near-edge misses), half random
    target = c[k] + rng.uniform(-1.3, 1.3, (n, 1)) * ds.data.quad_half_u.numpy()[k] \
        + rng.uniform(-1.3, 1.3, (n, 1)) * ds.data.quad_half_v.numpy()[k]
    d = np.where(np.arange(n)[:, None] % 2 == 0, target - o, rng.normal(size=(n, 3)))
    d = unit(d).astype(np.float32).astype(np.float64)
    o = o.astype(np.float32).astype(np.float64)
    tmax = np.where(np.arange(n) % 7 == 0, rng.uniform(0, 8, n), 3e38).astype(np.float32)
    res = run_probe(ds, o, d, direct=k.astype(np.int32), tmax=tmax)
    # reference on the same float32 data, in float64
    dn = np.einsum("ij,ij->i", d, nrm[k])
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.einsum("ij,ij->i", c[k] - o, nrm[k]) / dn
    local = t[:, None] * d - (c[k] - o)
    s = np.einsum("ij,ij->i", local, us[k])
    r = np.einsum("ij,ij->i", local, vs[k])
    ref_hit = (t > 0) & (t < tmax) & (np.abs(s) <= 1) & (np.abs(r) <= 1)
    got_hit = res["t_direct"] > 0
    assert np.all((res["t_direct"] == -1) | got_hit)
    agree = (ref_hit == got_hit).mean()
    both = ref_hit & got_hit
    rel = np.abs(res["t_direct"][both] - t[both]) / t[both]
    print(f"\n[quads] hit rate {ref_hit.mean():.3f}, agreement {agree:.6f}, t rel error: median {np.median(rel):.2g},"
          f" 99.9% {np.quantile(rel, 0.999):.2g}, max {rel.max():.2g}")
    assert agree >= 0.9999  # measured: 1.0 (float64 arithmetic)
    assert ref_hit.mean() > 0.2
    # disagreements only right at an edge: the reference's s or r within 1e-4 of +-1
    bad = ref_hit != got_hit
    assert np.all(np.minimum(np.abs(np.abs(s[bad]) - 1), np.abs(np.abs(r[bad]) - 1)) <= 1e-4)
    # t: computed in float64, so only the float32 rounding of the result remains
    assert rel.max() <= 1e-6


# ------------------------------------------------------------------------------------------------
# watertight shared edges


def edge_rays(rng, quads, edges, per_edge, dist_lo, dist_hi, along):
    """Rays aimed at points of shared edges (end points included) and rounded to float32, going along both quads'
    normals (``along`` +1) or against them (-1): o = p - dist d. Returns o, d (float64 holding float32 values)."""
    os_, ds_ = [], []
    for i, j, a, b in edges:
        lam = np.concatenate([[0.0, 1.0], rng.uniform(0, 1, per_edge - 2)])
        p = a + lam[:, None] * (b - a)
        na, nb = quads[i].normal, quads[j].normal
        w = along * (rng.uniform(0.05, 1, (per_edge, 1)) * na + rng.uniform(0.05, 1, (per_edge, 1)) * nb)
        w += 0.3 * rng.normal(size=(per_edge, 3)) * np.linalg.norm(w, axis=1, keepdims=True)
        w = unit(w)
        keep = (along * (w @ na) > 1e-3) & (along * (w @ nb) > 1e-3)
        dist = np.exp(rng.uniform(np.log(dist_lo), np.log(dist_hi), per_edge))
        os_.append((p - dist[:, None] * w)[keep])
        ds_.append(w[keep])
    o = np.concatenate(os_).astype(np.float32).astype(np.float64)
    d = unit(np.concatenate(ds_)).astype(np.float32).astype(np.float64)
    return o, d


def inside(quads, o, outward: bool, margin: float) -> np.ndarray:
    """Origins behind every quad's plane (outward normals) or in front of every one (inward), by ``margin``."""
    sd = np.stack([(o - q.center) @ q.normal for q in quads], axis=1)
    return (-sd > margin).all(axis=1) if outward else (sd > margin).all(axis=1)


def reference_nearest(quads, o, d, edge_tol=1e-9):
    """Nearest quad along each float32 ray, in float64 on the float64 quads: (q, t, ambiguous), ambiguous where a
    quad at or before the nearest hit has the ray within ``edge_tol`` (relative) of its border."""
    ts, ms = [], []
    for q in quads:
        us, vs = q.duals()
        with np.errstate(divide="ignore", invalid="ignore"):
            t = ((q.center - o) @ q.normal) / (d @ q.normal)
            loc = t[:, None] * d - (q.center - o)
        ts.append(t)
        ms.append(np.maximum(np.abs(loc @ us), np.abs(loc @ vs)))
    t, m = np.stack(ts, axis=1), np.stack(ms, axis=1)
    hit = (t > 0) & (m <= 1)
    th = np.where(hit, t, np.inf)
    q = np.where(hit.any(axis=1), th.argmin(axis=1), -1)
    tq = th.min(axis=1)
    amb = ((t > 0) & (np.abs(m - 1) < edge_tol) & (t <= tq[:, None] * (1 + 1e-9))).any(axis=1)
    return q, tq, amb


def check_edge_rays(ds, o, d, what, closed):
    """The kernel's nearest quad is the float64 reference's (or one at the same distance, at corners); where the
    rays come from inside a closed set of quads (``closed``), every one of them hits, edge-ambiguous ones too."""
    res = run_probe(ds, o, d)
    q, t = res["q"], res["t"]
    rq, rt, amb = reference_nearest(ds.quads, o, d)
    assert amb.mean() < 0.01
    same = (q == rq) | ((q >= 0) & (rq >= 0) & (np.abs(t - rt) <= 1e-6 * rt))
    bad = ~same & ~amb
    assert not bad.any(), f"{what}: {bad.sum()} of {len(q)} rays: kernel quad {q[bad][:8]} t {t[bad][:8]}, " \
                          f"reference quad {rq[bad][:8]} t {rt[bad][:8]}"
    if closed:  # edge-ambiguous rays included: never both quads missed
        must = (rq >= 0) | amb
        assert must.mean() > 0.99
        assert (q[must] >= 0).all(), f"{what}: {np.sum(q[must] < 0)} of {must.sum()} rays slipped through an edge"
    return (q >= 0).mean()


@pytest.mark.parametrize("scale", [2.0**-10, 1.0, 2.0**13])
def test_rays_through_shared_edges_never_slip_through(scale):
    rng = np.random.default_rng(int(scale * 1024))
    scene = pathtracer.load_file(CORNELL)
    shift = np.array([3.0, -2.0, 1.0]) * scale * 8  # off the origin too: edges far from 0 in float32
    for m in scene.meshes:
        m.vertices = m.vertices * scale + shift
    walls = [m for m in scene.meshes if m.shape == "rectangle" and m.light < 0]
    cube = [m for m in scene.meshes if m.shape == "cube"]
    # the box's five walls from inside (their normals point in): 8 shared edges, every ray must stop there
    ds = DeviceScene(quad_scene(walls), "cpu")
    edges = shared_edges(ds.quads)
    assert len(edges) == 8
    o, d = edge_rays(rng, ds.quads, edges, 2000, 1e-3 * scale, 4.0 * scale, along=-1)
    keep = inside(ds.quads, o, outward=False, margin=1e-6 * scale)
    assert keep.mean() > 0.5
    check_edge_rays(ds, o[keep], d[keep], "box corners", closed=True)
    # rays exactly through the edges in float32: dyadic origins and edge points (the walls are at +-2 scale + shift,
    # up to float64 rounding of the rotations), d = p - o exact and not normalised (p at t = 1)
    n = 20_000
    grid = scale / 256
    o = shift + np.round(rng.uniform(-1.99, 1.99, (n, 3)) * scale / grid) * grid
    p = np.round(rng.uniform(-2, 2, (n, 3)) * scale / grid) * grid
    pair = rng.integers(0, 3, n)  # which two coordinates sit on the box: an edge
    side = np.where(rng.integers(0, 2, (n, 2)) == 0, -2.0, 2.0) * scale
    for k, (a1, a2) in enumerate([(0, 1), (1, 2), (0, 2)]):
        sel = pair == k
        p[sel, a1], p[sel, a2] = side[sel, 0], side[sel, 1]
    p[:, 2] = np.minimum(p[:, 2], 0.0)  # the front (z = +2) is open: keep to edges of the walls there are
    p += shift
    d = p - o
    assert np.array_equal(d.astype(np.float32).astype(np.float64), d)  # exact in float32
    res = run_probe(ds, o, d)
    assert (res["q"] >= 0).all(), f"{np.sum(res['q'] < 0)} of {n} rays exactly through an edge slipped through"
    assert np.allclose(res["t"], 1.0, rtol=1e-6, atol=0)
    # the rotated block (normals out): 12 edges; from inside every ray must stop at the edge, from outside (near and
    # from 1e3 times its size) about half the float32 rays pass just outside it: the kernel must say as float64 does
    ds = DeviceScene(quad_scene(cube), "cpu")
    edges = shared_edges(ds.quads)
    assert len(edges) == 12
    o, d = edge_rays(rng, ds.quads, edges, 2000, 1e-3 * scale, 2.0 * scale, along=1)
    keep = inside(ds.quads, o, outward=True, margin=1e-6 * scale)
    assert keep.mean() > 0.3
    assert check_edge_rays(ds, o[keep], d[keep], "cube edges from inside", closed=True) == 1.0
    o, d = edge_rays(rng, ds.quads, edges, 2000, 1e-3 * scale, 1e3 * scale, along=-1)
    hit_rate = check_edge_rays(ds, o, d, "cube edges from outside", closed=False)
    assert hit_rate > 0.2


# ------------------------------------------------------------------------------------------------
# no self-intersection


@pytest.mark.parametrize("scale", [1e-3, 1e-1, 1.0, 1e2, 1e4])
def test_a_ray_leaving_a_quad_never_hits_it_again(scale):
    """Inside a closed cube (the block, normals out): every camera-like ray hits a face; a ray spawned from there
    into the cube (offset as the integrator does) hits another face, and the face it left not even without the
    integrator's skip."""
    rng = np.random.default_rng(7)
    scene = pathtracer.load_file(CORNELL)
    cube = [m for m in scene.meshes if m.shape == "cube"][0]
    cube.vertices = (cube.vertices - cube.vertices.mean(axis=0)) * scale + np.array([1.0, 2.0, -3.0]) * scale * 5
    ds = DeviceScene(quad_scene([cube]), "cpu")
    centre = np.mean([q.center for q in ds.quads], axis=0)
    n = 100_000
    o = centre + rng.uniform(-0.2, 0.2, (n, 3)) * scale
    d = unit(rng.normal(size=(n, 3)))
    w = unit(rng.normal(size=(n, 3)))
    res = run_probe(ds, o, d, w)
    q = res["q"]
    assert (q >= 0).all()
    nrm = ds.data.quad_normal.numpy()[q]
    into = np.einsum("ij,ij->i", w, nrm) < 0  # spawned into the cube
    assert into.mean() > 0.4
    assert (res["self_t"][into] < 0).all(), np.sum(res["self_t"][into] >= 0)
    assert (res["self_t"][~into] < 0).all()
    # from inside a closed cube, the spawned ray always finds another face (no leak at edges and corners)
    assert ((res["q2"][into] >= 0) & (res["q2"][into] != q[into])).all()
    assert (res["q2"][~into] == -1).all()  # leaving the cube through the face: nothing else to hit


# ------------------------------------------------------------------------------------------------
# end to end: quads == triangles


def small(path, w=32, h=24):
    scene = pathtracer.load_file(path)
    scene.width, scene.height = w, h
    return scene


@pytest.mark.parametrize("path", [CORNELL, TEAPOT], ids=["cornell", "teapot"])
def test_quads_render_as_the_triangles_did(path):
    scene = small(path)
    tri = all_mesh(scene)
    assert Renderer(scene, device="cpu").features.quads and not Renderer(tri, device="cpu").features.quads

    def rend(s, **kw):
        return pathtracer.render(s, device="cpu", progress=False, **kw)

    # normal view and max_depth 1: deterministic, equal to rounding but for a few pixels on primitive borders
    for kw in ({"view": "normal", "spp": 2}, {"max_depth": 1, "spp": 2}):
        a, b = rend(scene, **kw), rend(tri, **kw)
        differ = (np.abs(a - b) > 1e-5 * np.maximum(1, np.abs(b))).any(axis=2)
        assert differ.mean() <= 0.01, (kw, differ.mean())
    # radiance: per-pixel z-test with the estimator's own variance (16 replicates: 15 degrees of freedom per
    # pixel, not the default 3), and the image means
    for depth in (4, -1):
        ra = Renderer(scene, device="cpu", max_depth=depth, replicates=16).render_passes(seed=3, count=64)
        rb = Renderer(tri, device="cpu", max_depth=depth, replicates=16).render_passes(seed=4, count=64)
        var = ra.variance_of_mean + rb.variance_of_mean
        z = (ra.mean - rb.mean) / np.sqrt(var + 1e-12)
        frac = (np.abs(z) <= 4.0).mean()
        zm = (ra.mean.mean() - rb.mean.mean()) / np.sqrt(var.sum() / var.size**2)
        print(f"\n[quads] {path.name} max_depth {depth}: |z| <= 4 in {frac:.4f} of pixel channels, "
              f"image mean z = {zm:+.2f}")
        assert frac >= 0.995
        assert abs(zm) <= 4.0
