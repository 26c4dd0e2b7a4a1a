"""One-pass reverse mode for the backward (path replay) variants: each path's share of the loss gradient, gathered
while the path is traced, so that most paths are traced once instead of twice.

With sampling detached, a path's radiance is a sum of contributions c_j, each the product of the reflectances of
the vertices before it (and of its own vertex, for next-event estimation). d c_j / d rho_m is c_j times
A_m(j) = sum over the vertices at material m up to j of 1 / rho_m (per channel). The path keeps a few entries in
registers: per material met, A_m and G_m = sum_j c_j A_m(j), the latter advanced whenever A changes ("flush":
everything gathered since the last change, times the A it was gathered under); per parallelogram light, G_l = sum
of the throughputs that multiply its radiance. At the end of the path each entry's dLoss/dpixel * G goes into the
adjoints once. A path that meets more than ``ADJ_CAP`` materials and lights in all overflows: it is then replayed
with its radiance known, as Vicini et al.'s path replay does (kernels/integrator.py: ``replay``), and its entries
are dropped, so every path's gradient is exact either way.
"""

import warp as wp

ADJ_CAP = 8  # entries a path holds in registers; more (a path through many materials) is replayed instead
vec_keys = wp.types.vector(length=ADJ_CAP, dtype=wp.int32)
mat_entries = wp.types.matrix(shape=(ADJ_CAP, 3), dtype=wp.float32)


@wp.func
def adjoint_slot(keys: vec_keys, n: int, key: int) -> int:
    """The entry of ``key`` among the first ``n``; else ``n`` (a new entry: the caller stores ``key`` there), which
    is ``ADJ_CAP`` when the entries are full. Keys: a material's index, or -1 - l for parallelogram light l."""
    for e in range(n):
        if keys[e] == key:
            return e
    return n


@wp.func
def inverse_reflectance(rho: wp.vec3) -> wp.vec3:
    """1 / rho per channel, 0 where rho is 0 (a black channel carries nothing after it, so no share either, as in
    path replay's L_rem / rho)."""
    inv = wp.vec3(0.0)
    for c in range(3):
        if rho[c] > 0.0:
            inv[c] = 1.0 / rho[c]
    return inv
