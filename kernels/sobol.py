"""Owen-scrambled, shuffled Sobol' points: a low-discrepancy drop-in for ``rng.rand4``.

Following Brent Burley, "Practical Hash-based Owen Scrambling", JCGT 9(4), 2020 (https://jcgt.org/published/0009/04/01/):

* ``sobol(index, dim)``: the unscrambled Sobol' sequence, dims 0..3, 32 bits. Dim 0 is van der Corput (bit reversal);
  dims 1..3 use the Joe-Kuo direction numbers (new-joe-kuo-6.21201, its dims 2..4), generated in a short loop from
  each primitive polynomial and its initial m values, so the module needs no table or array argument.
* ``nested_uniform_scramble(x, seed)``: a hash-based Owen (nested uniform) scramble, the Laine-Karras permutation with
  Burley's improved constants applied to the bit-reversed value. It is a bijection whose top k output bits depend only
  on the top k input bits (and the seed), so it maps each elementary interval onto another one of the same size: any
  (t, m, s)-net stays a (t, m, s)-net.
* ``sobol4(key, dim)``: the same contract as ``rand4``. ``key = (pixel, pass, seed)``; the pass is the sample index of
  a 2-D Sobol' sequence (lanes 0, 1; lanes 2, 3 are independent uniforms, which the integrator never reads) that is
  shuffled (the index is Owen-scrambled too) and scrambled with seeds hashed from (pixel, seed, dim): every ``dim``
  gets its own independently randomised sequence (Burley's padding).

Properties (tests/test_sobol.py checks them):

* every single point is uniformly distributed in [0, 1)^4 over the random seeds, so a pass-by-pass estimator stays
  unbiased exactly as with ``rand4``;
* for one pixel and dim, the first 2^k passes are an aligned block of 2^k indices of the Sobol' sequence (the index
  scramble is nested too), so coordinates (0, 1) form a (0, k, 2)-net: every 2^-a x 2^-(k-a) box holds exactly one
  point, and each of the two coordinates alone is stratified into 2^k equal intervals.

Passes of one pixel are not independent any more (they are negatively correlated, which is the point): a standard error
estimated from the spread of the passes over-estimates the true error. Stratification is best at powers of two.
"""

import warp as wp

from kernels.rng import bits_to_unit, pcg4d, rand4

SOBOL_SALT = wp.constant(wp.uint32(0x5B0B01))  # keeps the seed hash apart from rand4's (pixel, pass, seed, dim)

# 32-bit literals as uint32 constants: a bare wp.uint32(0xAAAAAAAA) is emitted as an int32 literal (a C++ narrowing
# warning on every compile), a wp.constant as "2863311530u".
_M1_HI = wp.constant(wp.uint32(0xAAAAAAAA))
_M1_LO = wp.constant(wp.uint32(0x55555555))
_M2_HI = wp.constant(wp.uint32(0xCCCCCCCC))
_M2_LO = wp.constant(wp.uint32(0x33333333))
_M4_HI = wp.constant(wp.uint32(0xF0F0F0F0))
_M4_LO = wp.constant(wp.uint32(0x0F0F0F0F))
_M8_HI = wp.constant(wp.uint32(0xFF00FF00))
_M8_LO = wp.constant(wp.uint32(0x00FF00FF))
_LK1 = wp.constant(wp.uint32(0x6C50B47C))
_LK2 = wp.constant(wp.uint32(0xB82F1E52))
_LK3 = wp.constant(wp.uint32(0xC7AFE638))
_LK4 = wp.constant(wp.uint32(0x8D22F6E6))
_GOLDEN = wp.constant(wp.uint32(0x9E3779B9))
_FMIX1 = wp.constant(wp.uint32(0x85EBCA6B))
_FMIX2 = wp.constant(wp.uint32(0xC2B2AE35))
_ALL_ONES = wp.constant(wp.uint32(0xFFFFFFFF))
_TOP_BIT = wp.constant(wp.uint32(0x80000000))


@wp.func
def reverse_bits(x: wp.uint32) -> wp.uint32:
    """The 32 bits of ``x`` in reverse order."""
    x = ((x & _M1_HI) >> wp.uint32(1)) | ((x & _M1_LO) << wp.uint32(1))
    x = ((x & _M2_HI) >> wp.uint32(2)) | ((x & _M2_LO) << wp.uint32(2))
    x = ((x & _M4_HI) >> wp.uint32(4)) | ((x & _M4_LO) << wp.uint32(4))
    x = ((x & _M8_HI) >> wp.uint32(8)) | ((x & _M8_LO) << wp.uint32(8))
    return (x >> wp.uint32(16)) | (x << wp.uint32(16))


@wp.func
def sobol(index: wp.uint32, dim: int) -> wp.uint32:
    """Unscrambled Sobol' point ``index``, coordinate ``dim`` in 0..3, as 32 fixed-point bits.

    Direction numbers v_k = m_k 2^(32-k): the first s from the table, then the Sobol' recurrence
    v_k = a_1 v_(k-1) ^ ... ^ a_(s-1) v_(k-s+1) ^ v_(k-s) ^ (v_(k-s) >> s) for the primitive polynomial
    x^s + a_1 x^(s-1) + ... + a_(s-1) x + 1. Joe-Kuo dims 2, 3, 4 (our 1, 2, 3): (s, a, m) = (1, 0, [1]),
    (2, 1, [1, 3]), (3, 1, [1, 3, 1]). The loop stops at the highest set bit of ``index``. Other dims: as dim 1.
    """
    if dim == 0:
        return reverse_bits(index)
    s = int(1)
    a1 = wp.uint32(0)  # all ones where the coefficient is 1: a mask, not a branch
    a2 = wp.uint32(0)
    m2 = wp.uint32(0)
    m3 = wp.uint32(0)
    if dim == 2:
        s = 2
        a1 = _ALL_ONES
        m2 = wp.uint32(3)
    if dim == 3:
        s = 3
        a2 = _ALL_ONES
        m2 = wp.uint32(3)
        m3 = wp.uint32(1)
    result = wp.uint32(0)
    v1 = wp.uint32(0)  # v_(k-1)
    v2 = wp.uint32(0)  # v_(k-2)
    v3 = wp.uint32(0)  # v_(k-3)
    i = index
    k = int(1)
    while i != wp.uint32(0):
        v = wp.uint32(0)
        if k == 1:
            v = _TOP_BIT  # m_1 = 1 for every dimension
        elif k == 2 and s >= 2:
            v = m2 << wp.uint32(30)
        elif k == 3 and s >= 3:
            v = m3 << wp.uint32(29)
        else:
            vs = v1
            if s == 2:
                vs = v2
            if s == 3:
                vs = v3
            v = (a1 & v1) ^ (a2 & v2) ^ vs ^ (vs >> wp.uint32(s))
        if (i & wp.uint32(1)) != wp.uint32(0):
            result = result ^ v
        v3 = v2
        v2 = v1
        v1 = v
        i = i >> wp.uint32(1)
        k += 1
    return result


_M16_LO = wp.constant(wp.uint32(0x0000FFFF))


@wp.func
def pascal_reversed(index: wp.uint32) -> wp.uint32:
    """``reverse_bits(sobol(index, 1))`` in five steps.

    Dim 1's direction numbers, read LSB-first, are the polynomials (1 + x)^k over GF(2) (v_k = v_(k-1) ^
    (v_(k-1) >> 1)), so the reversed point is B(1 + x) for B(y) = sum of index bit k times y^k: a Taylor shift by
    one. With (1 + x)^(2^j) = 1 + x^(2^j), B(1 + x) for B = B0 + x^h B1 is B0(1 + x) + (1 + x^h) B1(1 + x): shift both
    halves of every block, then add the high half into the low one, for blocks of 2, 4, ..., 32 bits.
    """
    x = index
    x = x ^ ((x >> wp.uint32(1)) & _M1_LO)
    x = x ^ ((x >> wp.uint32(2)) & _M2_LO)
    x = x ^ ((x >> wp.uint32(4)) & _M4_LO)
    x = x ^ ((x >> wp.uint32(8)) & _M8_LO)
    x = x ^ ((x >> wp.uint32(16)) & _M16_LO)
    return x


@wp.func
def sobol_dim1(index: wp.uint32) -> wp.uint32:
    """``sobol(index, 1)`` without the general recurrence (see ``pascal_reversed``)."""
    return reverse_bits(pascal_reversed(index))


@wp.func
def laine_karras_permutation(x: wp.uint32, seed: wp.uint32) -> wp.uint32:
    """Burley's improved Laine-Karras hash: bit k of the result depends only on bits 0..k of ``x`` (and the seed)."""
    x += seed
    x = x ^ (x * _LK1)
    x = x ^ (x * _LK2)
    x = x ^ (x * _LK3)
    x = x ^ (x * _LK4)
    return x


@wp.func
def nested_uniform_scramble(x: wp.uint32, seed: wp.uint32) -> wp.uint32:
    """Hash-based Owen scramble of a 32-bit fixed-point value: top k output bits depend only on the top k input bits."""
    return reverse_bits(laine_karras_permutation(reverse_bits(x), seed))


@wp.func
def hash_u32(x: wp.uint32) -> wp.uint32:
    """MurmurHash3's 32-bit finaliser: a bijection with full avalanche."""
    x = x ^ (x >> wp.uint32(16))
    x = x * _FMIX1
    x = x ^ (x >> wp.uint32(13))
    x = x * _FMIX2
    x = x ^ (x >> wp.uint32(16))
    return x


@wp.func
def sobol4(key: wp.vec3ui, dim: wp.uint32) -> wp.vec4:
    """Drop-in for ``rand4``: point ``key[1]`` (the pass) of a shuffled, Owen-scrambled Sobol' sequence of its own
    for pixel ``key[0]``, seed ``key[2]`` and dimension ``dim``. Each point is uniform on [0, 1)^4; the first 2^k
    passes of one (pixel, seed, dim) are a (0, k, 2)-net in lanes (0, 1) and stratified in each of them.

    Lanes 0 and 1 are Sobol' dims 0 and 1 (the integrator uses only these two: a light or a bounce direction, a
    camera jitter, a roulette draw). Lanes 2 and 3 are independent uniforms, as in ``rand4``: Sobol' dims 2 and 3
    by the general recurrence of ``sobol`` made a Sobol' path 1.5x slower than an independent one, for lanes
    nothing reads."""
    h = pcg4d(wp.vec4ui(key[0], key[2], dim, SOBOL_SALT))
    index = nested_uniform_scramble(key[1], h[0])  # shuffle: a nested permutation of the pass indices
    # lanes 2, 3: independent uniforms from the pixel's fourth hash and the pass (hash_u32 is a bijection, so no two
    # passes share them); lanes 0, 1 scramble with the second and third hashes (independent seeds)
    g = hash_u32(h[3] ^ hash_u32(key[1] + _GOLDEN))
    # nested_uniform_scramble(x, s) = reverse(LK(reverse(x), s)): with reverse(sobol(i, 0)) = i and
    # reverse(sobol(i, 1)) = pascal_reversed(i), the inner reversals cancel
    return wp.vec4(
        bits_to_unit(reverse_bits(laine_karras_permutation(index, h[1]))),
        bits_to_unit(reverse_bits(laine_karras_permutation(pascal_reversed(index), h[2]))),
        bits_to_unit(g),
        bits_to_unit(hash_u32(g ^ _FMIX1)),
    )



# Path vertices whose sample dimensions come from Sobol' points; deeper ones use rand4 (Burley's padding with
# independent points). Vertices 0 and 1 (the camera jitter, and the light samples and bounce at the first two hits)
# are where stratification pays; deeper dims carry little variance and a Sobol' draw costs ~3x an independent one.
# (By depth, not by dimension index: a dimension cut-off would hand the first bounce to rand4 whenever K >= 3.)
SOBOL_DEPTH = wp.constant(2)


@wp.func
def padded_sobol4(key: wp.vec3ui, dim: wp.uint32, depth: int) -> wp.vec4:
    """``sobol4`` for draws at path vertices below SOBOL_DEPTH, ``rand4`` deeper: each dim stays an independently
    randomised uniform point, so estimators stay unbiased exactly as with either."""
    if depth < SOBOL_DEPTH:
        return sobol4(key, dim)
    return rand4(key, dim)


@wp.func
def independent4(key: wp.vec3ui, dim: wp.uint32, depth: int) -> wp.vec4:
    """``rand4`` with ``padded_sobol4``'s signature (the integrator picks one of the two at compile time)."""
    return rand4(key, dim)


_REPLICATE_SALT = wp.constant(wp.uint32(0x52E9C4A7))


@wp.func
def replicate_seed(seed: wp.uint32, replicate: wp.uint32) -> wp.uint32:
    """The scramble seed of replicate ``replicate`` of ``seed``: an independent randomisation of the same
    Sobol' sequence (Owen 1997: independent replicates of a scrambled net give an unbiased variance estimate)."""
    return hash_u32(seed ^ hash_u32(replicate ^ _REPLICATE_SALT))
