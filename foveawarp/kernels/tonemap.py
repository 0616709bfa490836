"""Uncharted 2 filmic tone map (Hable 2010) with exposure, white point and display gamma 2.2."""

import warp as wp

from .fpbits import finite_f32


# beyond HABLE_LIMIT_X the curve equals its limit (a (f - e)) / (f a) = 0.9333... to far under a float32 ulp (its
# terms in 1/x are below 1e-17 of it), and the quadratic form below squares x, which overflows float32 past ~1.8e19
# and gave inf / inf (a radiance of 1e38, or one that the exposure took past float max, came out black, not white;
# a white point above it made every pixel black). There the curve takes HABLE_TOP: 10 float32 ulps above the limit
# and 6 above the largest value the float32 formula gives on [0, 1e18] (0x3f6eeef3, at x = 6.15e7, on the CPU), so
# that radiance beyond 1e18 maps to exactly 1 for any white point up to 1e18 (the formula's rounding wobbles by a few
# ulps near its limit). Selects, not branches: the CPU's rows kernels keep their straight-line code.
HABLE_LIMIT_X = wp.constant(1.0e18)
HABLE_TOP = wp.constant(0.9333339333534241)  # float32 0x3f6eeef9


@wp.func
def hable(x: float) -> float:
    a = 0.15
    b = 0.50
    c = 0.10
    d = 0.20
    e = 0.02
    f = 0.30
    big = x > HABLE_LIMIT_X  # (infinity too)
    x = wp.min(x, HABLE_LIMIT_X)
    # ((x(ax + cb) + de) / (x(ax + b) + df)) - e/f over one denominator, so that hable(0) is exactly 0
    return wp.where(big, HABLE_TOP, x * (f * (a * x + c * b) - e * (a * x + b)) / (f * (x * (a * x + b) + d * f)))


# -- the display gamma, t^(1 / 2.2) ------------------------------------------------------------------------------
# The exponent is 1.0f / 2.2f as float32 arithmetic gives it (0x3ee8ba2e = 0.454545438289642333984375, one ulp below
# float32(1 / 2.2)): the value the tone map has always used (``wp.pow(t, 1.0 / 2.2)`` divides at run time in float32).
# On CUDA: powf(t, that exponent), as wp.pow. On the CPU: the same power, correctly rounded, by an algorithm of
# double-precision operations only, without a library call, so that a row of values is one vectorized loop
# (pow_inv22_row): t = 2^e m with m in [sqrt(1/2), sqrt(2)); ln m = 2 atanh(s) with s = (m - 1) / (m + 1),
# |s| <= 0.172, by its odd series to s^19; y = (e + ln m / ln 2) / 2.2; 2^y = 2^n e^(f ln 2) with n the integer
# nearest y, by the Taylor series of e^x to x^12 (|x| <= 0.347), scaled by 2^n through the exponent bits. The
# relative error before the final rounding to float32 is below 1e-12, so the result is the float32 nearest the
# exact power but where that lies within 1e-12 of a rounding midpoint (tests: against float64 NumPy, rounded).
# The libm powf the CPU called before is not correctly rounded: it differs from this in a small fraction of values,
# by one unit in the last place.

_POW_INV22_LAMBDA = """
    auto pw = [](float tf) -> float {
        const double t = (double)tf;
        unsigned long long b;
        __builtin_memcpy(&b, &t, 8);
        const unsigned long long eb = (b >> 52) & 0x7ffULL;
        unsigned long long mb = (b & 0x000fffffffffffffULL) | 0x3ff0000000000000ULL;
        double m;
        __builtin_memcpy(&m, &mb, 8);
        const bool up = m > 1.4142135623730951;
        const double mh = m * 0.5;
        m = up ? mh : m;
        // the exponent as a double without an integer conversion: the bits of 1.5 * 2^52 + e, minus 1.5 * 2^52
        const unsigned long long ebits = 0x4338000000000000ULL + eb - 1023ULL + (up ? 1ULL : 0ULL);
        double ed;
        __builtin_memcpy(&ed, &ebits, 8);
        ed = ed - 6755399441055744.0;
        const double num = m - 1.0;
        const double den = m + 1.0;
        const double s = num / den;
        const double s2 = s * s;
        double p = 1.0 / 19.0;
        p = __builtin_fma(p, s2, 1.0 / 17.0);
        p = __builtin_fma(p, s2, 1.0 / 15.0);
        p = __builtin_fma(p, s2, 1.0 / 13.0);
        p = __builtin_fma(p, s2, 1.0 / 11.0);
        p = __builtin_fma(p, s2, 1.0 / 9.0);
        p = __builtin_fma(p, s2, 1.0 / 7.0);
        p = __builtin_fma(p, s2, 1.0 / 5.0);
        p = __builtin_fma(p, s2, 1.0 / 3.0);
        p = __builtin_fma(p, s2, 1.0);
        const double s2x = s + s;
        const double lnm = s2x * p;
        const double l2 = __builtin_fma(lnm, 1.4426950408889634, ed);
        const double y = l2 * 0.454545438289642333984375;  // the exponent below, exactly
        // n = the integer nearest y (|y| < 70): 1.5 * 2^52 added and taken away rounds it
        const double nb = y + 6755399441055744.0;
        const double n = nb - 6755399441055744.0;
        const double f = y - n;
        const double x = f * 0.6931471805599453;
        double q = 2.08767569878680989792e-9;  // 1 / 12!
        q = __builtin_fma(q, x, 2.50521083854417187751e-8);
        q = __builtin_fma(q, x, 2.75573192239858906526e-7);
        q = __builtin_fma(q, x, 2.75573192239858906526e-6);
        q = __builtin_fma(q, x, 2.48015873015873015873e-5);
        q = __builtin_fma(q, x, 1.98412698412698412698e-4);
        q = __builtin_fma(q, x, 1.38888888888888888889e-3);
        q = __builtin_fma(q, x, 8.33333333333333333333e-3);
        q = __builtin_fma(q, x, 4.16666666666666666667e-2);
        q = __builtin_fma(q, x, 1.66666666666666666667e-1);
        q = __builtin_fma(q, x, 0.5);
        q = __builtin_fma(q, x, 1.0);
        q = __builtin_fma(q, x, 1.0);
        unsigned long long nbits;
        __builtin_memcpy(&nbits, &nb, 8);
        const unsigned long long sbits = (nbits - 0x4338000000000000ULL + 1023ULL) << 52;
        double sc;
        __builtin_memcpy(&sc, &sbits, 8);
        const double r = q * sc;
        const float rf = (float)r;
        // powf's answers outside (0, inf): +-0 -> +0, +-inf -> +inf, NaN -> NaN (quieted, as powf does), finite
        // t < 0 -> NaN; t = 1
        // needs no case (e = 0, m = 1: exactly 1)
        const float inf = __builtin_inff();
        const float other = tf == 0.0f ? 0.0f : (tf != tf ? tf + tf : ((tf == inf || tf == -inf) ? inf
                                                                                                 : __builtin_nanf("")));
        return (tf > 0.0f && tf < inf) ? rf : other;
    };
"""


@wp.func_native("""
#if defined(__CUDA_ARCH__)
    const float k = 0.454545438289642333984375f;  // the exponent below, exactly
    return wp::pow(t, k);
#else
""" + _POW_INV22_LAMBDA + """
    return pw(t);
#endif
""")
def pow_inv22(t: float) -> float:
    """t^(1/2.2), the exponent 1.0f / 2.2f in float32: ``wp.pow(t, 1.0 / 2.2)`` on CUDA, the correctly
    rounded power on the CPU (see the comment above; powf's values for zeros, infinities, NaN and negative t)."""
    ...


@wp.func_native("""
#if !defined(__CUDA_ARCH__)
""" + _POW_INV22_LAMBDA + """
    float* row = (float*)((char*)a.data + (size_t)y * (size_t)a.strides[0]);
    const int w = a.shape[1];
    if (a.strides[1] == 12) {
        const int n = 3 * w;
        for (int i = 0; i < n; ++i)
            row[i] = pw(row[i]);
    } else {
        for (int i = 0; i < w; ++i) {
            float* v = (float*)((char*)row + (size_t)i * (size_t)a.strides[1]);
            v[0] = pw(v[0]);
            v[1] = pw(v[1]);
            v[2] = pw(v[2]);
        }
    }
#endif
""")
def pow_inv22_row(a: wp.array2d(dtype=wp.vec3), y: int):
    """``pow_inv22`` of every channel of row ``y`` of ``a``, in place, as one loop the compiler vectorizes (the CPU;
    nothing on CUDA, where no kernel calls it)."""
    ...


@wp.func
def tonemap_linear(x: float, exposure: float, white: float) -> float:
    """``tonemap_value`` before the display gamma: the filmic curve of the exposed radiance, clamped to [0, 1]."""
    v = wp.max(x, 0.0)
    if not finite_f32(v):  # a bit test (kernels/fpbits.py): wp.isfinite is a library call on the CPU
        v = 0.0
    t = hable(exposure * v) / hable(white)
    return wp.clamp(t, 0.0, 1.0)


@wp.func
def tonemap_value(x: float, exposure: float, white: float) -> float:
    return pow_inv22(tonemap_linear(x, exposure, white))


@wp.func
def tonemap_rgb(c: wp.vec3, exposure: float, white: float) -> wp.vec3:
    """``tonemap_value`` per channel: the display value of linear radiance ``c`` (also applied inside the last
    pass of a frame, the Sibson gather or the full-resolution shading, when nothing runs after it)."""
    return wp.vec3(tonemap_value(c[0], exposure, white), tonemap_value(c[1], exposure, white),
                   tonemap_value(c[2], exposure, white))


@wp.func
def tonemap_linear_rgb(c: wp.vec3, exposure: float, white: float) -> wp.vec3:
    """``tonemap_linear`` per channel: ``tonemap_rgb`` before the display gamma (a CPU rows kernel stores these for
    a row and applies ``pow_inv22_row`` to it)."""
    return wp.vec3(tonemap_linear(c[0], exposure, white), tonemap_linear(c[1], exposure, white),
                   tonemap_linear(c[2], exposure, white))


@wp.kernel(enable_backward=False)
def tonemap_kernel(hdr: wp.array2d(dtype=wp.vec3), exposure: float, white: float, out: wp.array2d(dtype=wp.vec3),
                   row0: int):
    y, x = wp.tid()
    y += row0  # band offset (foveawarp.parallel)
    out[y, x] = tonemap_rgb(hdr[y, x], exposure, white)


@wp.kernel(enable_backward=False)
def tonemap_rows_kernel(hdr: wp.array2d(dtype=wp.vec3), exposure: float, white: float, out: wp.array2d(dtype=wp.vec3),
                        row0: int):
    """``tonemap_kernel`` for the CPU (``parallel.launch_rows``): a thread per row stores the row's linear curve,
    then applies the display gamma to the whole row in one vectorized loop (``pow_inv22_row``): the same values."""
    y = wp.tid() + row0  # band offset (foveawarp.parallel)
    for x in range(out.shape[1]):
        out[y, x] = tonemap_linear_rgb(hdr[y, x], exposure, white)
    pow_inv22_row(out, y)

