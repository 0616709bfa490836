"""Unit normals in 32 bits: octahedral mapping, two 16-bit signed-normalised coordinates.

The temporal history keeps each pixel's normal only to validate a history tap against the current normal
(``kernels.temporal.tap_ok``: a cosine threshold). Twelve bytes of float32 per normal, written and read back every
frame over every pixel, were a quarter of the resolve's DRAM traffic; four bytes hold the direction to within
7e-5 rad (at most 6.3e-5 over 200,000 random unit vectors, ``tests/test_octnormal.py`` checks 1e-4), far below
any useful threshold.

Encoding: ``n / (|x| + |y| + |z|)`` lies on the octahedron ``|u| + |v| + |w| = 1``; the upper half (w >= 0) maps
to the square by (u, v), the lower half is folded over the square's diagonals. u and v are rounded to multiples
of 1/32767 and stored as int16 in the low (u) and high (v) half of a uint32. Decoding unfolds and normalises. A
zero vector encodes as (0, 0), which decodes to +z (never NaN).
"""

import warp as wp

OCT_SCALE = wp.constant(32767.0)


@wp.func
def _sign_nz(v: float) -> float:
    """+1 for v >= 0, -1 otherwise (the fold's sign; 0 counts as positive)."""
    if v < 0.0:
        return -1.0
    return 1.0


@wp.func
def oct_encode(n: wp.vec3) -> wp.uint32:
    """``n`` (any finite vector; unit in use) as a packed octahedral direction."""
    s = wp.abs(n[0]) + wp.abs(n[1]) + wp.abs(n[2])
    inv = 1.0 / wp.max(s, 1.0e-30)
    u = n[0] * inv
    v = n[1] * inv
    if n[2] < 0.0:
        fu = (1.0 - wp.abs(v)) * _sign_nz(u)
        fv = (1.0 - wp.abs(u)) * _sign_nz(v)
        u = fu
        v = fv
    qu = int(wp.round(wp.clamp(u, -1.0, 1.0) * OCT_SCALE))
    qv = int(wp.round(wp.clamp(v, -1.0, 1.0) * OCT_SCALE))
    return wp.uint32(qu & 0xFFFF) | (wp.uint32(qv & 0xFFFF) << wp.uint32(16))


@wp.func
def oct_decode(p: wp.uint32) -> wp.vec3:
    """The unit vector of packed direction ``p`` (``oct_encode``'s inverse up to its rounding)."""
    b = int(p)
    qu = b & 0xFFFF
    qv = (b >> 16) & 0xFFFF
    if qu >= 0x8000:
        qu -= 0x10000
    if qv >= 0x8000:
        qv -= 0x10000
    u = float(qu) / OCT_SCALE
    v = float(qv) / OCT_SCALE
    w = 1.0 - wp.abs(u) - wp.abs(v)
    if w < 0.0:
        fu = (1.0 - wp.abs(v)) * _sign_nz(u)
        fv = (1.0 - wp.abs(u)) * _sign_nz(v)
        u = fu
        v = fv
    d = wp.vec3(u, v, w)
    return d / wp.max(wp.length(d), 1.0e-30)  # |d| >= 1/sqrt(3) by construction; the guard keeps it a theorem


@wp.kernel(enable_backward=False)
def oct_encode_kernel(n: wp.array(dtype=wp.vec3), out: wp.array(dtype=wp.uint32)):
    i = wp.tid()
    out[i] = oct_encode(n[i])


@wp.kernel(enable_backward=False)
def oct_decode_kernel(p: wp.array(dtype=wp.uint32), out: wp.array(dtype=wp.vec3)):
    i = wp.tid()
    out[i] = oct_decode(p[i])
