"""Spawning rays off a surface without re-hitting it, at any scene scale.

A fixed epsilon fails at large coordinates (TESTING.md: 52% self-hits at |p| ~ 1e4 with 1e-4). The
error of a computed hit point is a few float32 ulps of the coordinates it was computed from, so the
offset is a fixed number of ulps of that magnitude (the idea of Waechter and Binder, Ray Tracing Gems
ch. 6, applied to the largest coordinate rather than per component, which also covers points near 0).
"""

import warp as wp

OFFSET_ULPS = wp.constant(64.0)
FLT_EPS = wp.constant(1.1920929e-07)  # 2^-23


@wp.func
def max_abs(v: wp.vec3) -> float:
    return wp.max(wp.abs(v[0]), wp.max(wp.abs(v[1]), wp.abs(v[2])))


@wp.func
def offset_origin(p: wp.vec3, n: wp.vec3, scale: float, toward: wp.vec3) -> wp.vec3:
    """``p`` pushed along unit normal ``n`` to the side that direction ``toward`` points to.

    ``scale`` is the magnitude of the coordinates p was computed from (at least max_abs(p)).
    """
    mag = OFFSET_ULPS * FLT_EPS * wp.max(scale, max_abs(p))
    if wp.dot(toward, n) < 0.0:
        mag = -mag
    return p + mag * n
