"""Regression cases for bugs the numerical stress suite (tests/stress) found; one test per bug."""

import numpy as np
import pytest
from scipy import ndimage

from foveawarp import ops

F32_MAX = float(np.finfo(np.float32).max)


@pytest.mark.parametrize("window", [None, 1, 3])
def test_sibson_colors_near_float_max_stay_finite(device, window):
    """kernels/sibson.py: the float32 sum of seed colors near float max overflowed to Inf (exact scatter and
    bounded gather alike). Found as: one seed in a 1 x 3 image, color 3.4e38."""
    m = np.zeros((1, 3), bool)
    m[0, 0] = True
    col = np.zeros((1, 3, 3), np.float32)
    col[0, 0] = (F32_MAX, -F32_MAX, 0.5 * F32_MAX)
    out = ops.sibson(col, m, window=window, device=device)
    assert np.isfinite(out).all()
    np.testing.assert_allclose(out, np.broadcast_to(col[0, 0], out.shape), rtol=1e-6)


def test_sibson_colors_near_float_max_mean(device):
    """The overflow-safe mean equals the float64 mean of what each pixel receives (two seeds, Park scatter)."""
    h, w = 5, 9
    m = np.zeros((h, w), bool)
    m[2, 0] = m[2, 8] = True
    col = np.zeros((h, w, 3), np.float32)
    col[2, 0] = F32_MAX
    col[2, 8] = 0.75 * F32_MAX
    _, (iy, ix) = ndimage.distance_transform_edt(~m, return_indices=True)
    near = np.stack([ix, iy], -1).astype(np.int32)
    exact = ops.sibson(col, m, nearest=near, device=device)
    gather = ops.sibson(col, m, nearest=near, window=16, device=device)
    assert np.isfinite(exact).all() and np.isfinite(gather).all()
    # float64 Park scatter
    yy, xx = np.mgrid[0:h, 0:w]
    r2 = (near[..., 0] - xx) ** 2 + (near[..., 1] - yy) ** 2
    vc = col[near[..., 1], near[..., 0]].astype(np.float64)
    acc = np.zeros((h, w, 3))
    cnt = np.zeros((h, w))
    for qy in range(h):
        for qx in range(w):
            cover = (yy - qy) ** 2 + (xx - qx) ** 2 <= r2[qy, qx]
            acc[cover] += vc[qy, qx]
            cnt[cover] += 1
    ref = np.where(m[..., None], vc, acc / cnt[..., None])
    np.testing.assert_allclose(exact, ref, rtol=1e-5)
    np.testing.assert_allclose(gather, ref, rtol=1e-5)


def test_coc_denormal_depth_follows_the_formula(device):
    """kernels/dof.py coc_px: for a depth below ~3e-39 m, 1 / Z overflowed and the CoC became the clamp
    value (3e38 unclamped) instead of the formula's finite value. Found as: f = 1e-4, focus 1.0001e-4,
    aperture 1e-9, px_per_m 1e-3, depth 1.4e-45 -> 3e38 instead of ~7.1e32."""
    f, zf, e, k = 1e-4, 1e-4 * (1 + 1e-3), 1e-9, 1e-3
    z = np.array([np.float32(1.4e-45), np.float32(1e-40), 1e-20, 1.0], dtype=np.float32)
    c = ops.circle_of_confusion_px(z, focal_length_m=f, focus_depth_m=zf, aperture_m=e, px_per_m=k,
                                   device=device)
    ref = e * f * k / (zf - f) * np.abs(z.astype(np.float64) - zf) / z.astype(np.float64)
    np.testing.assert_allclose(c, ref, rtol=1e-3)
    assert c[0] < 1e33


def _scatter_model(col, z, coc, zf, gamma):
    """float64 scatter (no hit mask, foreground fix on, background fix off)."""
    h, w = z.shape
    r = np.maximum(0.5 * coc.astype(np.float64).ravel(), 0.5)
    zz = z.astype(np.float64).ravel()
    k = np.where(zz < zf, np.minimum((zf / np.maximum(zz, 1e-30)) ** gamma, 1e8), 1.0)
    a = k / (np.pi * r * r)
    yy, xx = np.mgrid[0:h, 0:w]
    py, px = yy.ravel(), xx.ravel()
    d2 = (py[:, None] - py[None, :]) ** 2 + (px[:, None] - px[None, :]) ** 2
    wgt = np.where(d2 <= (r * r)[:, None], a[:, None], 0.0)
    return ((wgt.T @ col.reshape(-1, 3).astype(np.float64)) / wgt.sum(axis=0)[:, None]).reshape(h, w, 3)


@pytest.mark.parametrize("lo,hi", [(32.0, 33.0), (36.0, 38.5)])
def test_dof_gather_huge_colors_are_blurred(device, lo, hi):
    """kernels/dof.py: with foreground weights up to K = 1e8, A I overflowed float32 for colors above ~3e30
    and the gather fell back to the unblurred source color (finite but wrong). Found as: 8 x 8 image, colors
    1e32..1e33, every other row at 1 mm in front of a 5 m focus, gamma 16."""
    rng = np.random.default_rng(0)
    h = w = 8
    col = (10.0 ** rng.uniform(lo, hi, (h, w, 3))).astype(np.float32)
    z = np.full((h, w), 1e-3, np.float32)
    z[::2] = 5.0
    lens = dict(focal_length_m=0.05, focus_depth_m=5.0, aperture_m=0.02, px_per_m=2e4, max_coc_px=16.0)
    out = ops.dof_scatter(col, z, gamma=16.0, background_fix=False, device=device, **lens)
    coc = ops.circle_of_confusion_px(z, device=device, **lens)
    assert np.isfinite(out).all()
    np.testing.assert_allclose(out, _scatter_model(col, z, coc, 5.0, 16.0), rtol=1e-4)
    assert not np.allclose(out, col)
