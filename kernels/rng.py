"""Counter-based random numbers: every draw is a hash of (pixel, pass, seed, dimension).

There is no stream state to overlap: two different (pixel, pass, seed) keys never share a sequence, and
the same key always gives the same numbers on every device and whatever the launch order or thread count.
The hash is pcg4d (Jarzynski and Olano, "Hash Functions for GPU Rendering", JCGT 2020).
"""

import warp as wp


@wp.func
def pcg4d(v: wp.vec4ui) -> wp.vec4ui:
    """pcg4d: 4 x 32 bits in, 4 x 32 well-mixed bits out."""
    v = v * wp.uint32(1664525) + wp.vec4ui(wp.uint32(1013904223))
    x = v[0]
    y = v[1]
    z = v[2]
    w = v[3]
    x += y * w
    y += z * x
    z += x * y
    w += y * z
    x = x ^ (x >> wp.uint32(16))
    y = y ^ (y >> wp.uint32(16))
    z = z ^ (z >> wp.uint32(16))
    w = w ^ (w >> wp.uint32(16))
    x += y * w
    y += z * x
    z += x * y
    w += y * z
    return wp.vec4ui(x, y, z, w)


@wp.func
def bits_to_unit(x: wp.uint32) -> float:
    """Top 24 bits as a float in [0, 1 - 2^-24]: exactly representable, never 1."""
    return float(x >> wp.uint32(8)) * (1.0 / 16777216.0)


@wp.func
def rand4(key: wp.vec3ui, dim: wp.uint32) -> wp.vec4:
    """Four independent uniforms in [0, 1) for sample dimension ``dim`` of the path keyed by ``key``."""
    h = pcg4d(wp.vec4ui(key[0], key[1], key[2], dim))
    return wp.vec4(bits_to_unit(h[0]), bits_to_unit(h[1]), bits_to_unit(h[2]), bits_to_unit(h[3]))
