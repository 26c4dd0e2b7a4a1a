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
  a 4-D Sobol' sequence that is shuffled (the index is Owen-scrambled too) and scrambled with seeds hashed from
  (pixel, seed, dim): every ``dim`` gets its own independently randomised 4-D sequence (Burley's padding).

Properties (tests/test_sobol.py checks them):

* every single point is uniformly distributed in [0, 1)^4 over the random seeds, so a pass-by-pass estimator stays
  unbiased exactly as with ``rand4``;
* for one pixel and dim, the first 2^k passes are an aligned block of 2^k indices of the Sobol' sequence (the index
  scramble is nested too), so coordinates (0, 1) form a (0, k, 2)-net: every 2^-a x 2^-(k-a) box holds exactly one
  point, and each coordinate alone is stratified into 2^k equal intervals.

Passes of one pixel are not independent any more (they are negatively correlated, which is the point): a standard error
estimated from the spread of the passes over-estimates the true error. Stratification is best at powers of two.
"""

import warp as wp

from kernels.rng import bits_to_unit, pcg4d

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
def hash_combine(seed: wp.uint32, v: wp.uint32) -> wp.uint32:
    """boost::hash_combine, as in Burley's listing. Weak on its own: finish with ``hash_u32`` before use as a seed."""
    return seed ^ (v + _GOLDEN + (seed << wp.uint32(6)) + (seed >> wp.uint32(2)))


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
def scrambled_coordinate(index: wp.uint32, coord: int, seed: wp.uint32) -> float:
    """Coordinate ``coord`` of Sobol' point ``index``, Owen-scrambled with its own seed, as a float in [0, 1)."""
    # Each coordinate needs its own independent scramble. hash_combine alone gives the four coordinates seeds with
    # related low bits (bit 0, which flips the top output bit, always differs between coordinates 0 and 1), so the
    # scrambles would be coupled; the finaliser makes the seeds independent-looking.
    s = hash_u32(hash_combine(seed, wp.uint32(coord)))
    return bits_to_unit(nested_uniform_scramble(sobol(index, coord), s))


@wp.func
def sobol4(key: wp.vec3ui, dim: wp.uint32) -> wp.vec4:
    """Drop-in for ``rand4``: point ``key[1]`` (the pass) of a shuffled, Owen-scrambled 4-D Sobol' sequence of its own
    for pixel ``key[0]``, seed ``key[2]`` and dimension ``dim``. Each point is uniform on [0, 1)^4; the first 2^k
    passes of one (pixel, seed, dim) are a (0, k, 2)-net in coordinates (0, 1) and stratified in each coordinate."""
    h = pcg4d(wp.vec4ui(key[0], key[2], dim, SOBOL_SALT))
    index = nested_uniform_scramble(key[1], h[0])  # shuffle: a nested permutation of the pass indices
    return wp.vec4(
        scrambled_coordinate(index, 0, h[1]),
        scrambled_coordinate(index, 1, h[1]),
        scrambled_coordinate(index, 2, h[1]),
        scrambled_coordinate(index, 3, h[1]),
    )
