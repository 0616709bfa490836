"""Uncharted 2 filmic tone map (Hable 2010) with exposure, white point and display gamma 2.2."""

import warp as wp

from .fpbits import finite_f32


@wp.func
def hable(x: float) -> float:
    a = 0.15
    b = 0.50
    c = 0.10
    d = 0.20
    e = 0.02
    f = 0.30
    # ((x(ax + cb) + de) / (x(ax + b) + df)) - e/f over one denominator, so that hable(0) is exactly 0
    return x * (f * (a * x + c * b) - e * (a * x + b)) / (f * (x * (a * x + b) + d * f))


@wp.func
def tonemap_value(x: float, exposure: float, white: float) -> float:
    v = wp.max(x, 0.0)
    if not finite_f32(v):  # a bit test (kernels/fpbits.py): wp.isfinite is a library call on the CPU
        v = 0.0
    t = hable(exposure * v) / hable(white)
    t = wp.clamp(t, 0.0, 1.0)
    return wp.pow(t, 1.0 / 2.2)


@wp.func
def tonemap_rgb(c: wp.vec3, exposure: float, white: float) -> wp.vec3:
    """``tonemap_value`` per channel: the display value of linear radiance ``c`` (also applied inside the last
    pass of a frame, the Sibson gather or the full-resolution shading, when nothing runs after it)."""
    return wp.vec3(tonemap_value(c[0], exposure, white), tonemap_value(c[1], exposure, white),
                   tonemap_value(c[2], exposure, white))


@wp.kernel(enable_backward=False)
def tonemap_kernel(hdr: wp.array2d(dtype=wp.vec3), exposure: float, white: float, out: wp.array2d(dtype=wp.vec3),
                   row0: int):
    y, x = wp.tid()
    y += row0  # band offset (foveawarp.parallel)
    out[y, x] = tonemap_rgb(hdr[y, x], exposure, white)
