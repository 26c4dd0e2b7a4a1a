"""Emitter samplers of kernels/lights.py through a probe kernel (probes.probe_lights)."""

from __future__ import annotations

import numpy as np
import warp as wp

from probes import probe_lights


def run(device, n=4096, x=(0.0, 0.0, 0.0), c=(0.0, 0.0, 3.0), r=1.0, cos_t=None):
    rng = np.random.default_rng(7)
    us = rng.random((n, 2)).astype(np.float32)
    cos_t = np.cos(np.radians(np.linspace(0, 30, n))).astype(np.float32) if cos_t is None else cos_t
    cdf = np.array([9.0, 0.2, 0.5, 1.0, 9.0], np.float32)  # light with faces 1..3 (entries 0 and 4: other lights)
    outs = [wp.zeros(n, dtype=t, device=device) for t in (wp.vec3, wp.vec3, float, float, wp.vec3, int)]
    wp.launch(probe_lights, n, inputs=[wp.vec3(*x), wp.vec3(*c), r, wp.array(us, dtype=wp.vec2, device=device),
                                       wp.array(cos_t, dtype=float, device=device)],
              outputs=outs[:4] + [outs[4], wp.array(cdf, dtype=float, device=device), outs[5]], device=device)
    return us, cos_t, [o.numpy() for o in outs]


def test_sphere_cone_samples_lie_on_the_visible_cap_with_the_cone_density(device):
    us, _, (p, nrm, inv, *_rest) = run(device)
    c = np.array([0.0, 0.0, 3.0])
    assert np.allclose(np.linalg.norm(p - c, axis=1), 1.0, atol=1e-5)
    assert np.allclose(nrm, p - c, atol=1e-5)
    assert np.all(np.einsum("ij,ij->i", nrm, -p) > -1e-6)  # the normal faces the shading point: the visible side
    sin2 = 1.0 / 9.0
    assert np.allclose(inv, 2 * np.pi * (1 - np.sqrt(1 - sin2)), rtol=1e-5)
    # directions uniform in the cone: cos(theta) uniform on [cos_max, 1], so E[cos] is their midpoint
    cos = p[:, 2] / np.linalg.norm(p, axis=1)
    assert abs(cos.mean() - (1 + np.sqrt(1 - sin2)) / 2) < 3 * np.std(cos) / np.sqrt(len(cos))


def test_no_cone_sample_from_inside_the_sphere(device):
    _, _, (_, _, inv, *_rest) = run(device, x=(0.0, 0.0, 2.5))
    assert np.all(inv == 0.0)


def test_spot_falloff_is_mitsubas_linear_profile(device):
    angles = np.radians([0.0, 14.9, 16.0, 17.5, 19.99, 20.0, 25.0])
    _, _, outs = run(device, n=len(angles), cos_t=np.cos(angles).astype(np.float32))
    # Mitsuba 3.9.1 (cutoff 20, beam 15 degrees): 1 in the beam, 0.8 at 16, 0.5 at 17.5, 0 at and beyond the cutoff
    np.testing.assert_allclose(outs[3], [1.0, 1.0, 0.8, 0.5, 0.002, 0.0, 0.0], atol=2e-3)


def test_triangle_samples_are_uniform_and_cdf_picks_by_mass(device):
    us, _, (*_a, tri, picked) = run(device, x=(0.2, 0.2, 1.0))
    assert np.all(tri[:, 0] >= -1e-7) and np.all(tri[:, 1] >= -1e-7) and np.all(tri.sum(axis=1) <= 1 + 1e-6)
    assert abs(tri[:, 0].mean() - 1 / 3) < 0.02 and abs(tri[:, 1].mean() - 1 / 3) < 0.02  # the centroid
    expect = np.where(us[:, 0] < 0.2, 1, np.where(us[:, 0] < 0.5, 2, 3))
    np.testing.assert_array_equal(picked, expect)
