"""Albedo demodulation of the reconstruction (``ReconstructionConfig.demodulate``).

The sparse samples carry radiance ``L = E + a * I``: the emission ``E`` of the primary hit, its base colour ``a``
(the G-buffer's per-pixel albedo: texture x factor, or the face's colour) and the light ``I`` it reflects. The
G-buffer knows ``a`` and ``E`` at every pixel, the samples know ``L`` at a few. Interpolating ``L`` blurs the
texture at the sample spacing; interpolating ``I`` and multiplying back by each pixel's own albedo keeps the
texture (and the sharp colour edges of flat-coloured faces) at full resolution, as SVGF does before its filter.

    demodulate:  D = max(L - E, 0) / max(a, ALBEDO_FLOOR)          (per channel, hits only; misses D = L)
    remodulate:  L' = D' * max(a, ALBEDO_FLOOR) + E                 (per channel, hits only; misses L' = D')

``D'`` is the reconstruction (and the optional periphery filter) of ``D``. At a traced pixel ``L' = L`` up to
rounding wherever ``L >= E``, which the camera rays guarantee: they cull the back faces of single-sided emitters,
so the G-buffer's emission is exactly what the path adds at its first vertex. The floor bounds the ratio of two
pixels' albedos, which the remodulation applies to a reflected value, to ``1 / ALBEDO_FLOOR``.
"""

import warp as wp

from .gbuffer import pixel_albedo

ALBEDO_FLOOR = wp.constant(0.05)


@wp.func
def floored(a: wp.vec3) -> wp.vec3:
    return wp.vec3(wp.max(a[0], ALBEDO_FLOOR), wp.max(a[1], ALBEDO_FLOOR), wp.max(a[2], ALBEDO_FLOOR))


@wp.func
def finite_or_zero(c: wp.vec3) -> wp.vec3:
    if wp.isfinite(c[0]) and wp.isfinite(c[1]) and wp.isfinite(c[2]):
        return c
    return wp.vec3(0.0, 0.0, 0.0)


@wp.func
def pixel_albedo_emission(y: int, x: int, textured: int, albedo: wp.array2d(dtype=wp.vec3),
                          emission: wp.array2d(dtype=wp.vec3), face: wp.array2d(dtype=wp.int32),
                          face_albedo: wp.array(dtype=wp.vec3), face_emission: wp.array(dtype=wp.vec3)):
    """A hit pixel's floored albedo and its emission: the textured G-buffer's stored fields, else its face's."""
    a = floored(pixel_albedo(textured, albedo, face_albedo, face, y, x))
    if textured != 0:
        return a, emission[y, x]
    return a, face_emission[face[y, x]]


@wp.kernel(enable_backward=False)
def modulate_kernel(src: wp.array2d(dtype=wp.vec3), hit: wp.array2d(dtype=wp.uint8), textured: int,
                    albedo: wp.array2d(dtype=wp.vec3), emission: wp.array2d(dtype=wp.vec3),
                    face: wp.array2d(dtype=wp.int32), face_albedo: wp.array(dtype=wp.vec3),
                    face_emission: wp.array(dtype=wp.vec3), remodulate: int, out: wp.array2d(dtype=wp.vec3),
                    row0: int):
    """At hits, ``remodulate`` 0: out = max(src - E, 0) / max(a, ALBEDO_FLOOR); 1: out = max(src, 0) *
    max(a, ALBEDO_FLOOR) + E (the module docstring). Misses keep ``src``."""
    y, x = wp.tid()
    y += row0  # band offset (foveawarp.parallel)
    c = src[y, x]
    if hit[y, x] == wp.uint8(0):
        out[y, x] = c
        return
    a, e = pixel_albedo_emission(y, x, textured, albedo, emission, face, face_albedo, face_emission)
    z = wp.vec3(0.0, 0.0, 0.0)
    if remodulate != 0:
        out[y, x] = finite_or_zero(wp.cw_mul(wp.max(c, z), a) + e)
    else:
        out[y, x] = finite_or_zero(wp.cw_div(wp.max(c - e, z), a))
