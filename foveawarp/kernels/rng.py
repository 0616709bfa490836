"""Deterministic per-pixel random streams and sampling helpers."""

import warp as wp


@wp.func
def pixel_rng(seed: int, frame: int, pixel: int) -> wp.uint32:
    """A random state that depends only on (seed, frame, pixel): the same on CPU and CUDA."""
    return wp.rand_init(seed * 7919 + frame * 104729, pixel)


@wp.func
def onb_from(n: wp.vec3, a: float, b: float, c: float) -> wp.vec3:
    """Vector with coordinates (a, b, c) in an orthonormal basis whose third axis is the unit vector n."""
    s = 1.0
    if n[2] < 0.0:
        s = -1.0
    k = -1.0 / (s + n[2])
    m = n[0] * n[1] * k
    t = wp.vec3(1.0 + s * n[0] * n[0] * k, s * m, -s * n[0])
    bt = wp.vec3(m, s + n[1] * n[1] * k, -n[1])
    return a * t + b * bt + c * n


@wp.func
def cosine_hemisphere(n: wp.vec3, u1: float, u2: float) -> wp.vec3:
    """Cosine-weighted direction about the unit normal n."""
    r = wp.sqrt(u1)
    phi = 2.0 * wp.pi * u2
    z = wp.sqrt(wp.max(0.0, 1.0 - u1))
    return onb_from(n, r * wp.cos(phi), r * wp.sin(phi), z)
