"""Float classification by a bit test, in native code.

Warp's ``wp.isfinite`` / ``wp.isnan`` on the CPU device are calls into Warp's runtime library (``_wp_isfinite``,
``_wp_isnan``), made per value: a tone-mapped pixel makes three of them. These read the float's exponent bits
instead (all ones: infinite or NaN; and a nonzero mantissa as well: NaN), which gives the same answer for every
float32 value, signed zeros, subnormals, infinities and NaN payloads included, on the CPU and on CUDA.
"""

import warp as wp


@wp.func_native("""
    union { float f; unsigned int u; } b;
    b.f = v;
    return (b.u & 0x7f800000u) != 0x7f800000u;
""")
def finite_f32(v: float) -> bool:
    """``wp.isfinite(v)``: neither infinite nor NaN."""
    ...


@wp.func_native("""
    union { float f; unsigned int u; } b;
    b.f = v;
    return (b.u & 0x7fffffffu) > 0x7f800000u;
""")
def nan_f32(v: float) -> bool:
    """``wp.isnan(v)``."""
    ...


@wp.func
def finite_vec3(c: wp.vec3) -> bool:
    """``wp.isfinite(c)``: every component finite."""
    return finite_f32(c[0]) and finite_f32(c[1]) and finite_f32(c[2])
