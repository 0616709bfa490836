"""The display gamma t^(1/2.2) of the tone map (kernels/tonemap.py): correctly rounded on the CPU, powf on CUDA,
and the vectorized row form equal to the per-value one."""

import numpy as np
import pytest
import warp as wp

from foveawarp.kernels.tonemap import pow_inv22, pow_inv22_row, tonemap_linear_rgb, tonemap_rgb

K64 = np.float64(np.float32(1.0) / np.float32(2.2))  # the exponent of wp.pow(t, 1.0 / 2.2): a float32 division


@wp.kernel(enable_backward=False)
def _pow_kernel(t: wp.array(dtype=float), out: wp.array(dtype=float)):
    i = wp.tid()
    out[i] = pow_inv22(t[i])


@wp.kernel(enable_backward=False)
def _pow_rows_kernel(a: wp.array2d(dtype=wp.vec3)):
    y = wp.tid()
    pow_inv22_row(a, y)


@wp.kernel(enable_backward=False)
def _tonemap_both_kernel(c: wp.array2d(dtype=wp.vec3), exposure: float, white: float,
                         whole: wp.array2d(dtype=wp.vec3), linear: wp.array2d(dtype=wp.vec3)):
    y, x = wp.tid()
    whole[y, x] = tonemap_rgb(c[y, x], exposure, white)
    linear[y, x] = tonemap_linear_rgb(c[y, x], exposure, white)


def _reference(t: np.ndarray) -> np.ndarray:
    """float32 of the float64 power (NumPy's float64 pow is within an ulp of double precision, so its rounding to
    float32 is the correctly rounded float32 result but within ~1e-16 of a midpoint); powf's special values."""
    with np.errstate(invalid="ignore"):
        ref = np.power(t.astype(np.float64), K64).astype(np.float32)
    ref[t == 0] = 0.0
    return ref


def _values(rng):
    return np.concatenate([
        rng.random(200_000).astype(np.float32),
        (rng.random(50_000) ** 12).astype(np.float32),  # tiny values down to the float32 denormals
        (1.0 - rng.random(20_000) * 1e-6).astype(np.float32),  # just below 1
        rng.uniform(1.0, 1e30, 5_000).astype(np.float32),
        np.array([0.0, -0.0, 1.0, 1e-45, 1.17549435e-38, 0.5, 0.25, 0.99999994, 3.4028235e38, np.inf, -1.0, -np.inf,
                  np.nan], np.float32),
    ])


def _same(a, b):
    return (a.view(np.uint32) == b.view(np.uint32)) | (np.isnan(a) & np.isnan(b))


def test_pow_inv22_is_correctly_rounded_on_the_cpu(rng):
    """On the CPU every value is the float32 nearest the exact power (bit for bit against float64 NumPy rounded to
    float32), over [0, 1] with tiny and denormal inputs, values just below 1, values above 1, and powf's special
    cases (+-0 -> +0, inf -> inf, NaN -> NaN, negative -> NaN)."""
    t = _values(rng)
    a = wp.array(t, dtype=float, device="cpu")
    out = wp.zeros_like(a)
    wp.launch(_pow_kernel, dim=t.size, inputs=[a], outputs=[out], device="cpu")
    got = out.numpy()
    ref = _reference(t)
    bad = ~_same(got, ref)
    assert not bad.any(), (t[bad][:5], got[bad][:5], ref[bad][:5])
    assert got[t == 0].view(np.uint32).max() == 0  # +0, also for -0
    # a signalling NaN comes back quieted, as from powf
    snan = np.array([0x7F800001, 0x7FA00000, 0xFF800001], np.uint32).view(np.float32)
    a = wp.array(snan, dtype=float, device="cpu")
    out = wp.zeros_like(a)
    wp.launch(_pow_kernel, dim=snan.size, inputs=[a], outputs=[out], device="cpu")
    q = out.numpy()
    assert np.isnan(q).all() and np.all(q.view(np.uint32) & 0x00400000)


@pytest.mark.needs_cuda
def test_pow_inv22_on_cuda_is_powf():
    """On CUDA the gamma is powf (CUDA's: within 2 ulp of the exact power), as ``wp.pow(t, 1.0 / 2.2)``."""
    rng = np.random.default_rng(7)
    t = rng.random(100_000).astype(np.float32)
    a = wp.array(t, dtype=float, device="cuda:0")
    out = wp.zeros_like(a)
    wp.launch(_pow_kernel, dim=t.size, inputs=[a], outputs=[out], device="cuda:0")
    got = out.numpy()
    ulps = np.abs(got.view(np.int32).astype(np.int64) - _reference(t).view(np.int32).astype(np.int64))
    assert ulps.max() <= 2


@pytest.mark.parametrize("strided", [False, True])
def test_pow_inv22_row_equals_the_value_form(rng, strided):
    """``pow_inv22_row`` (one vectorized loop over a row's channels, in place) gives each value ``pow_inv22``
    gives it, on rows of contiguous pixels and of strided ones (every other pixel of a wider array)."""
    h, w = 7, 301
    t = _values(rng)[: h * w * 3 * 2]
    t = np.resize(t, h * w * 3 * 2).reshape(h, 2 * w, 3)
    full = wp.array(t, dtype=wp.vec3, device="cpu")
    a = full[:, ::2] if strided else wp.array(t[:, :w], dtype=wp.vec3, device="cpu")
    src = a.numpy().copy()
    assert (a.strides[1] != 12) == strided
    wp.launch(_pow_rows_kernel, dim=h, inputs=[a], device="cpu")
    got = a.numpy().reshape(-1)
    flat = wp.array(src.reshape(-1), dtype=float, device="cpu")
    one = wp.zeros_like(flat)
    wp.launch(_pow_kernel, dim=flat.shape[0], inputs=[flat], outputs=[one], device="cpu")
    assert _same(got, one.numpy()).all()
    assert _same(got, _reference(src.reshape(-1))).all()
    if strided:  # the pixels in between are untouched
        assert np.array_equal(full.numpy()[:, 1::2], t[:, 1::2], equal_nan=True)


def test_tonemap_is_the_gamma_of_the_linear_curve(device, rng):
    """``tonemap_rgb`` = ``pow_inv22`` of ``tonemap_linear_rgb`` (what the rows kernels store before their row's
    gamma), on every device; the linear curve lies in [0, 1] for any input, infinities and NaN included."""
    c = rng.uniform(-1.0, 50.0, (13, 17, 3)).astype(np.float32)
    c[0, :4] = [[np.inf, 0, 1], [np.nan, 2, 3], [-np.inf, 1e30, 0], [3.4e38, 1e-40, -0.0]]
    ca = wp.array(c, dtype=wp.vec3, device=device)
    whole = wp.zeros((13, 17), dtype=wp.vec3, device=device)
    lin = wp.zeros((13, 17), dtype=wp.vec3, device=device)
    wp.launch(_tonemap_both_kernel, dim=(13, 17), inputs=[ca, 1.3, 11.2], outputs=[whole, lin], device=device)
    lv = lin.numpy().reshape(-1)
    assert np.all((lv >= 0.0) & (lv <= 1.0))
    flat = wp.array(lv, dtype=float, device=device)
    g = wp.zeros_like(flat)
    wp.launch(_pow_kernel, dim=lv.size, inputs=[flat], outputs=[g], device=device)
    assert _same(whole.numpy().reshape(-1), g.numpy()).all()


def test_tonemap_stage_rows_kernel_equals_the_pixel_kernel(rng):
    """On the CPU ``TonemapStage`` runs ``tonemap_rows_kernel`` (the row's gamma as one loop): the same values as
    ``tonemap_kernel``, at 1 and 3 threads, with infinities and NaN among the inputs."""
    import foveawarp as fw
    from foveawarp import parallel
    from foveawarp.kernels.tonemap import tonemap_kernel
    from foveawarp.stages.tonemap import TonemapStage

    h, w = 11, 37
    c = rng.uniform(-1.0, 40.0, (h, w, 3)).astype(np.float32)
    c[0, :3] = [[np.inf, 0, 1], [np.nan, 2, 3], [-np.inf, 1e30, 0]]
    hdr = wp.array(c, dtype=wp.vec3, device="cpu")
    sc = fw.ShadingConfig(exposure=1.7, white_point=9.0)
    want = wp.zeros((h, w), dtype=wp.vec3, device="cpu")
    wp.launch(tonemap_kernel, dim=(h, w), inputs=[hdr, 1.7, 9.0], outputs=[want, 0], device="cpu")
    for n in (1, 3):
        out = wp.zeros((h, w), dtype=wp.vec3, device="cpu")
        with parallel.cpu_threads(n):
            TonemapStage(sc, w, h, "cpu").run(hdr, out)
        assert out.numpy().tobytes() == want.numpy().tobytes()


def _hable64(x):
    """The Hable curve in float64, written independently of the kernel: x (p x + q) / (r x^2 + s x + t), and its
    limit p / r where x^2 would overflow."""
    a, b, c, d, e, f = 0.15, 0.50, 0.10, 0.20, 0.02, 0.30
    x = np.asarray(x, np.float64)
    big = x > 1e150
    xs = np.where(big, 1.0, x)
    val = xs * (a * (f - e) * xs + b * (f * c - e)) / (f * a * xs * xs + f * b * xs + f * d * f)
    return np.where(big, (f - e) / f, val)


@pytest.mark.parametrize("white", [11.2, 1.0e-3, 6.1538372e7, 1.0e10, 1.0e17, 1.0e18, 1.0e25, 3.0e38])
def test_tonemap_huge_radiance_and_white_point(device, white):
    """Radiance up to float max (and exposures that push it past float max) maps to the curve's limit, white for
    a finite white point, not to 0 (x^2 / white^2 would reach inf / inf); a white point beyond float32's square
    root does not blacken the image. Against the float64 curve (1e-5 relative) and the display gamma."""
    vals = np.array([0.0, 1e-3, 0.3, 1.0, 11.2, 1e3, 1e9, 1e17, 1e18, 2e18, 1e19, 1e20, 1e30, 1e38, 3.4028235e38],
                    np.float32)
    c = np.repeat(vals[None, :, None], 3, axis=2).astype(np.float32)
    for exposure in (2.0, 1e10):
        cw = wp.array(c, dtype=wp.vec3, device=device)
        whole = wp.zeros(c.shape[:2], dtype=wp.vec3, device=device)
        linear = wp.zeros(c.shape[:2], dtype=wp.vec3, device=device)
        wp.launch(_tonemap_both_kernel, dim=c.shape[:2], inputs=[cw, exposure, white, whole, linear], device=device)
        lin = linear.numpy()[0, :, 0]
        x = vals.astype(np.float64) * np.float64(np.float32(exposure))
        want = np.clip(_hable64(x) / _hable64(np.float64(np.float32(white))), 0.0, 1.0)
        assert np.all(np.isfinite(lin)) and np.all(np.isfinite(whole.numpy()))
        np.testing.assert_allclose(lin, want, rtol=1e-5, atol=1e-7, err_msg=f"exposure {exposure}, white {white}")
        if white <= 1e18:
            # a white point the curve reaches: radiance beyond 1e18 (exposed) is exactly white, also for the white
            # points where the float32 curve's rounding lies above its value at 1e18 (6.15e7 the highest of them)
            assert np.all(lin[x > 1e18] == 1.0), lin
        np.testing.assert_allclose(whole.numpy()[0, :, 0], np.power(lin.astype(np.float64), K64), rtol=3e-7, atol=0)


def test_tonemap_config_bounds_to_float32():
    """An exposure or white point beyond float32's largest value is refused by name (the kernels hold them in
    float32: an exposure that became inf there turned black pixels into inf * 0 = NaN); float32's largest is
    accepted."""
    import foveawarp as fw

    for name in ("exposure", "white_point"):
        with pytest.raises(ValueError, match=f"ShadingConfig.{name} must be in"):
            fw.ShadingConfig(**{name: 1e39})
        fw.ShadingConfig(**{name: float(np.finfo(np.float32).max)})
