"""Rays per second on one CPU core: our 4-wide tree ("wide"), Warp's wp.Mesh + mesh_query_ray ("warp") and Embree 4
(through embreex, the `bench` extra), side by side on the same rays in one run; and the watertightness of each.

Ray sets (closest hit, unit directions, float32):
- bunny random: the shared Stanford bunny (69k triangles), origins on a sphere of its box diagonal's radius around
  it, aimed at uniform points in its box (about 60% hit);
- teapot camera: the camera rays of scenes/teapot_in_box.xml (jittered, every pixel), against every triangle of the
  scene (its box triangulated as Mitsuba would, plus the teapot);
- teapot bounce: cosine-weighted diffuse bounces from where those camera rays hit, offset off the surface.

Leaks: rays from outside a closed icosphere (82k triangles) aimed exactly at each of its vertices, and at random
points on its edges; a ray leaks if it misses or hits beyond its target.

Timing: rounds of each ray set, the backends one after the other in every round; rays/s is the median over
rounds, the ratios the median of per-round ratios (robust to the shared VM's drifting clock).
A Warp CPU launch runs on one core; embreex's ``run`` loops over single rays (rtcIntersect1) on one thread.

Set-up (--setup): load + tree + upload against triangle count, next to trimesh's load plus wp.Mesh's build.

    python examples/bench_rays.py [--rounds 9] [--out docs] [--setup [SUBDIV ...]]
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import warp as wp  # noqa: E402

from pathtracer.warp_setup import init_warp  # noqa: E402

init_warp()

import trimesh  # noqa: E402

import pathtracer  # noqa: E402
from kernels.triangle import mesh_closest  # noqa: E402
from kernels.triangle_warp import warp_mesh_closest  # noqa: E402
from kernels.types import SceneData  # noqa: E402
from pathtracer.device_scene import TriangleData  # noqa: E402

BUNNY = ROOT.parent / "shared" / "data" / "meshes" / "bunny.obj"


@wp.kernel(enable_backward=False)
def trace_wide(scene: SceneData, o: wp.array(dtype=wp.vec3), d: wp.array(dtype=wp.vec3),
               out_t: wp.array(dtype=float), out_face: wp.array(dtype=wp.int32)):
    i = wp.tid()
    q = mesh_closest(scene, o[i], d[i], 3.0e38)
    out_t[i] = q.t
    out_face[i] = q.face


@wp.kernel(enable_backward=False)
def trace_warp(scene: SceneData, o: wp.array(dtype=wp.vec3), d: wp.array(dtype=wp.vec3),
               out_t: wp.array(dtype=float), out_face: wp.array(dtype=wp.int32)):
    i = wp.tid()
    q = warp_mesh_closest(scene, o[i], d[i], 3.0e38)
    out_t[i] = q.t
    out_face[i] = q.face


def unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


class Backends:
    """The three tracers over one triangle soup (float32 vertices), each returning (t, face) with face -1 on a miss."""

    def __init__(self, verts: np.ndarray, faces: np.ndarray, origin_hint: np.ndarray):
        self.verts = np.asarray(verts, np.float32)
        self.faces = np.asarray(faces, np.int64)
        self.wide, self.warp = SceneData(), SceneData()
        self._keep = [TriangleData(self.wide, self.verts, self.faces, origin_hint, "cpu", "wide"),
                      TriangleData(self.warp, self.verts, self.faces, origin_hint, "cpu", "warp")]
        self.embree = None
        try:
            from embreex import rtcore_scene
            from embreex.mesh_construction import TriangleMesh

            self.embree = rtcore_scene.EmbreeScene()
            TriangleMesh(self.embree, self.verts[self.faces])
        except ImportError:
            pass

    def names(self):
        return ["wide", "warp"] + (["embree"] if self.embree is not None else [])

    def upload(self, o, d):
        return (wp.array(o.astype(np.float32), dtype=wp.vec3), wp.array(d.astype(np.float32), dtype=wp.vec3),
                wp.zeros(len(o), dtype=float), wp.zeros(len(o), dtype=wp.int32), o.astype(np.float32),
                d.astype(np.float32))

    def trace(self, name, rays):
        """(seconds, t, face) of one pass over ``rays`` (from ``upload``)."""
        oa, da, t, face, o32, d32 = rays
        if name == "embree":
            t0 = time.perf_counter()
            res = self.embree.run(o32, d32, output=1)
            seconds = time.perf_counter() - t0
            hit = res["geomID"] >= 0
            return seconds, np.where(hit, res["tfar"], np.inf), np.where(hit, res["primID"], -1)
        kernel, data = (trace_wide, self.wide) if name == "wide" else (trace_warp, self.warp)
        t0 = time.perf_counter()
        wp.launch(kernel, dim=len(o32), inputs=[data, oa, da], outputs=[t, face], device="cpu")
        seconds = time.perf_counter() - t0
        f = face.numpy().copy()
        return seconds, np.where(f >= 0, t.numpy(), np.inf), f


def bunny_rays(rng, n):
    m = trimesh.load(BUNNY, force="mesh", process=False)
    v = np.asarray(m.vertices, np.float64)
    lo, hi = v.min(axis=0), v.max(axis=0)
    c, r = 0.5 * (lo + hi), float(np.linalg.norm(hi - lo))
    o = c + unit(rng.normal(size=(n, 3))) * r
    d = unit(lo + rng.random((n, 3)) * (hi - lo) - o)
    return np.asarray(m.vertices), np.asarray(m.faces), o, d, c + r


def scene_triangles(scene):
    offsets = np.cumsum([0] + [len(m.vertices) for m in scene.meshes[:-1]])
    verts = np.concatenate([m.vertices for m in scene.meshes])
    faces = np.concatenate([m.faces + off for m, off in zip(scene.meshes, offsets)])
    return verts, faces


def camera_rays(scene, rng):
    cam = scene.camera
    m = np.asarray(cam.to_world, np.float64)
    tx, ty = cam.tan_half_fov(scene.width, scene.height)
    col, row = np.meshgrid(np.arange(scene.width), np.arange(scene.height))
    px = (col.ravel() + rng.random(col.size)) / scene.width
    py = (row.ravel() + rng.random(row.size)) / scene.height
    local = np.stack([(1 - 2 * px) * tx, (1 - 2 * py) * ty, np.ones(px.size)], axis=1)  # +x is image left
    d = unit(local @ m[:3, :3].T)
    return np.broadcast_to(m[:3, 3], d.shape).copy(), d


def bounce_rays(backends, o, d, rng):
    """Cosine-weighted directions around the face normal (facing the incoming ray) at each hit of (o, d)."""
    _, t, face = backends.trace("wide", backends.upload(o, d))
    hit = face >= 0
    tri = backends.verts[backends.faces[face[hit]]].astype(np.float64)
    n = unit(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]))
    n = np.where((np.einsum("ij,ij->i", n, d[hit]) > 0)[:, None], -n, n)
    p = o[hit] + t[hit, None] * d[hit]
    u1, u2 = rng.random(len(n)), rng.random(len(n))
    a = unit(np.cross(n, np.where(np.abs(n[:, :1]) > 0.9, [0.0, 1.0, 0.0], [1.0, 0.0, 0.0])))
    b = np.cross(n, a)
    r, phi = np.sqrt(u1), 2 * np.pi * u2
    w = (r * np.cos(phi))[:, None] * a + (r * np.sin(phi))[:, None] * b + np.sqrt(1 - u1)[:, None] * n
    scale = np.abs(p).max(axis=1, keepdims=True)
    return p + n * (64 * 2.0**-23 * scale), unit(w)


def leak_rays(rng):
    m = trimesh.creation.icosphere(subdivisions=6, radius=1.0)
    v = np.asarray(m.vertices, np.float32).astype(np.float64)
    edges = np.asarray(m.edges_unique)
    s = rng.random(len(edges))[:, None]
    on_edges = (v[edges[:, 0]] + s * (v[edges[:, 1]] - v[edges[:, 0]])).astype(np.float32).astype(np.float64)
    targets = {"vertex": v, "edge": on_edges}
    rays = {}
    for kind, tgt in targets.items():
        o = tgt + 2.0 * unit(tgt + 0.15 * rng.normal(size=tgt.shape))  # outside, within ~30 deg of the normal
        rays[kind] = (o, unit(tgt - o), np.linalg.norm(tgt - o, axis=1))
    return np.asarray(m.vertices), np.asarray(m.faces), rays


def run(rounds: int, n_random: int) -> dict:
    rng = np.random.default_rng(0)
    sets = {}
    if BUNNY.exists():
        v, f, o, d, hint = bunny_rays(rng, n_random)
        bb = Backends(v, f, hint)
        sets["bunny random"] = (bb, bb.upload(o, d), len(f))
    else:
        print(f"skipping the bunny: {BUNNY} not found", file=sys.stderr)
    scene = pathtracer.load_file(ROOT / "scenes" / "teapot_in_box.xml", width=256, height=192)
    v, f = scene_triangles(scene)
    tb = Backends(v, f, np.asarray(scene.camera.to_world)[:3, 3])
    o, d = camera_rays(scene, rng)
    sets["teapot camera"] = (tb, tb.upload(o, d), len(f))
    bo, bd = bounce_rays(tb, o, d, rng)
    sets["teapot bounce"] = (tb, tb.upload(bo, bd), len(f))

    results = {}
    for name, (backends, rays, ntri) in sets.items():
        names = backends.names()
        agree = {}
        ref_t = None
        for b in names:  # warm-up (JIT) and agreement with ours
            _, t, face = backends.trace(b, rays)
            if ref_t is None:
                ref_t, ref_hit = t, face >= 0
            agree[b] = float(np.mean((face >= 0) == ref_hit))
        secs = {b: [] for b in names}
        for _ in range(rounds):
            for b in names:
                secs[b].append(backends.trace(b, rays)[0])
        n = len(rays[4])
        s = {b: np.array(v) for b, v in secs.items()}
        row = {"rays": n, "triangles": ntri, "hit_fraction": float(ref_hit.mean()),
               "mrays_per_s": {b: n / float(np.median(v)) / 1e6 for b, v in s.items()},
               "hit_agreement_with_wide": agree,
               "wide_over": {b: float(np.median(s[b] / s["wide"])) for b in names if b != "wide"}}
        results[name] = row
        print(f"{name}: {n} rays, {ntri} triangles, " + ", ".join(
            f"{b} {r:.2f} M rays/s" for b, r in row["mrays_per_s"].items()) + "; wide / " + ", ".join(
            f"{b} {r:.2f}" for b, r in row["wide_over"].items()), flush=True)

    v, f, lrays = leak_rays(rng)
    lb = Backends(v, f, np.array([3.0, 3.0, 3.0]))
    leaks = {}
    for b in lb.names():
        leaks[b] = {}
        for kind, (o, d, dist) in lrays.items():
            _, t, face = lb.trace(b, lb.upload(o, d))
            bad = (face < 0) | (t > dist * (1 + 1e-5))
            leaks[b][kind] = [int(bad.sum()), len(o)]
    print("leaks (icosphere, 82k triangles): " + "; ".join(
        f"{b}: " + ", ".join(f"{k} {x[0]}/{x[1]}" for k, x in v.items()) for b, v in leaks.items()))
    return {"machine": f"{platform.processor() or platform.machine()}, {platform.python_version()}, "
                       f"warp {wp.config.version}", "rounds": rounds, "sets": results, "leaks": leaks}


SETUP_SCENE = """<scene version="3.0.0">
    <sensor type="perspective"><float name="fov" value="45"/>
        <transform name="to_world"><lookat origin="0, 0, 4" target="0, 0, 0" up="0, 1, 0"/></transform>
        <film type="hdrfilm"><integer name="width" value="160"/><integer name="height" value="120"/>
            <rfilter type="box"/></film></sensor>
    <shape type="ply"><string name="filename" value="{ply}"/></shape>
    <shape type="rectangle"><transform name="to_world"><translate value="0, 0, -2"/><scale value="3"/></transform>
        <emitter type="area"><rgb name="radiance" value="1"/></emitter></shape>
</scene>
"""


def warm_memory(gib: float) -> float:
    """Touch ``gib`` GiB once and free it; returns the seconds per GiB it took. A VM whose host backs its memory
    lazily (these Firecracker VMs) pays 2-3 s per GiB the first time the guest touches a page, and whichever set-up
    runs first on fresh memory pays it: at 5.2M triangles that was a 2.51x against 1.31x on warm memory. A machine
    in use has paid it long ago, so the set-up figures are taken after this."""
    t0 = time.perf_counter()
    a = np.ones(int(gib * (1 << 30)) // 8)
    del a
    return (time.perf_counter() - t0) / gib


def setup_times(subdivisions=(4, 6, 8, 9), workdir: Path | None = None) -> list[dict]:
    """Scene set-up against triangle count: an icosphere PLY in a scene file, loaded (ours: file, parse, vertex
    normals) and uploaded (ours: the box tree, the leaves, the device arrays), against trimesh's load and
    wp.Mesh's build of the same triangles. Each figure is the fastest of two runs."""
    import tempfile

    from pathtracer.device_scene import DeviceScene

    workdir = Path(tempfile.mkdtemp()) if workdir is None else workdir
    rows = []
    for s in subdivisions:
        m = trimesh.creation.icosphere(subdivisions=s, radius=1.0)
        ply = workdir / f"ico{s}.ply"
        m.export(ply)
        xml = workdir / f"ico{s}.xml"
        xml.write_text(SETUP_SCENE.format(ply=ply))
        best = {}
        for _ in range(2):
            t0 = time.perf_counter()
            tm = trimesh.load(ply, process=False, force="mesh")
            t1 = time.perf_counter()
            wp_mesh = wp.Mesh(points=wp.array(np.asarray(tm.vertices, np.float32), dtype=wp.vec3, device="cpu"),
                              indices=wp.array(np.asarray(tm.faces, np.int32).reshape(-1), dtype=int, device="cpu"))
            t2 = time.perf_counter()
            scene = pathtracer.load_file(xml)
            t3 = time.perf_counter()
            ds = DeviceScene(scene, "cpu")
            t4 = time.perf_counter()
            for k, v in {"trimesh_load": t1 - t0, "wp_mesh_build": t2 - t1, "our_load": t3 - t2,
                         "our_bvh_upload": t4 - t3}.items():
                best[k] = min(best.get(k, np.inf), v)
            del wp_mesh, ds
        row = {"triangles": len(m.faces), **best}
        row["ready"] = row["our_load"] + row["our_bvh_upload"]
        row["ready_over_trimesh_plus_wp_mesh"] = row["ready"] / (row["trimesh_load"] + row["wp_mesh_build"])
        rows.append(row)
        print(f"set-up, {len(m.faces)} triangles: ours {row['ready']:.2f} s (load {row['our_load']:.2f} + tree and "
              f"upload {row['our_bvh_upload']:.2f}), trimesh {row['trimesh_load']:.2f} + wp.Mesh "
              f"{row['wp_mesh_build']:.2f}: ratio {row['ready_over_trimesh_plus_wp_mesh']:.2f}", flush=True)
    return rows


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--rounds", type=int, default=9)
    p.add_argument("--rays", type=int, default=200_000, help="random bunny rays per round")
    p.add_argument("--out", type=Path, help="write bench_rays.json there")
    p.add_argument("--warm-memory", type=float, default=8.0, metavar="GIB",
                   help="touch this much memory once before the set-up runs (default 8; 0: none)")
    p.add_argument("--setup", type=int, nargs="*", metavar="SUBDIV",
                   help="also time scene set-up on icospheres of these subdivisions (default 4 6 8 9: 5k to 5.2M "
                   "triangles)")
    a = p.parse_args(argv)
    report = run(a.rounds, a.rays)
    if a.setup is not None:
        if a.warm_memory > 0:
            report["warm_memory"] = {"gib": a.warm_memory, "seconds_per_gib": warm_memory(a.warm_memory)}
            print(f"touched {a.warm_memory:g} GiB first: {report['warm_memory']['seconds_per_gib']:.2f} s per GiB",
                  flush=True)
        report["setup"] = setup_times(tuple(a.setup) or (4, 6, 8, 9))
    if a.out is not None:
        a.out.mkdir(parents=True, exist_ok=True)
        (a.out / "bench_rays.json").write_text(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
