"""Image-quality metrics on the device: SSIM by separable Gaussian passes and deterministic float64 sums.

The SSIM is the one scikit-image computes with ``gaussian_weights=True, sigma=1.5, use_sample_covariance=False,
data_range=1``: an 11-tap Gaussian (truncated at 3.5 sigma) applied with the "reflect" (half-sample symmetric)
border of ``scipy.ndimage`` to x, y, x^2, y^2 and xy, then Wang et al. 2004 eq. 13 per channel, averaged over
the channels. Everything is float64 (the variances are differences of nearly equal moments).

Sums are deterministic: each thread of ``metric_sums_kernel`` adds a column strip of ``rows`` rows in order into
its own slot, and ``sum_blocks_kernel`` then adds fixed blocks of slots in order, level by level.
"""

from typing import Any

import warp as wp

# slots of one row of sums (float64); region k in [0, MAX_REGIONS) has REGION0 + 3k (pixel count),
# REGION0 + 3k + 1 (squared error summed over the channels) and REGION0 + 3k + 2 (SSIM map)
SUM_D2 = wp.constant(0)  # squared error, all pixels and channels
# SSIM map over the interior (the window radius cropped off every side), as scikit-image's mean
SUM_SSIM_CROP = wp.constant(1)
N_CROP = wp.constant(2)  # pixels of that interior
NONFINITE_A = wp.constant(3)  # non-finite input values of a (replaced by 0 in every pass)
NONFINITE_B = wp.constant(4)
REGION0 = wp.constant(5)
MAX_REGIONS = wp.constant(4)
NUM_SUMS = wp.constant(5 + 3 * 4)


@wp.func
def reflect_index(i: int, n: int) -> int:
    """scipy.ndimage mode "reflect": ... 1 0 | 0 1 ... n-1 | n-1 n-2 ... (repeated for windows wider than n)."""
    j = i
    while j < 0 or j >= n:
        if j < 0:
            j = -j - 1
        else:
            j = 2 * n - 1 - j
    return j


@wp.func
def finite_or_zero(v: wp.float64) -> wp.float64:
    if wp.isfinite(v):
        return v
    return wp.float64(0.0)


@wp.func
def load_rgb(img: wp.array2d(dtype=Any), y: int, x: int) -> wp.vec3d:
    v = wp.vec3d(img[y, x])
    return wp.vec3d(finite_or_zero(v[0]), finite_or_zero(v[1]), finite_or_zero(v[2]))


@wp.func
def count_nonfinite(img: wp.array2d(dtype=Any), y: int, x: int) -> wp.float64:
    v = wp.vec3d(img[y, x])
    n = wp.float64(0.0)
    for c in range(3):
        if not wp.isfinite(v[c]):
            n += wp.float64(1.0)
    return n


@wp.kernel(enable_backward=False)
def ssim_rows_kernel(
    a: wp.array2d(dtype=Any),
    b: wp.array2d(dtype=Any),
    weights: wp.array(dtype=wp.float64),
    radius: int,
    mx: wp.array2d(dtype=wp.vec3d),
    my: wp.array2d(dtype=wp.vec3d),
    mxx: wp.array2d(dtype=wp.vec3d),
    myy: wp.array2d(dtype=wp.vec3d),
    mxy: wp.array2d(dtype=wp.vec3d),
):
    """Horizontal Gaussian pass of x, y, x^2, y^2, xy (per channel)."""
    y, x = wp.tid()
    w = a.shape[1]
    sx = wp.vec3d()
    sy = wp.vec3d()
    sxx = wp.vec3d()
    syy = wp.vec3d()
    sxy = wp.vec3d()
    for k in range(2 * radius + 1):
        xi = reflect_index(x + k - radius, w)
        wk = weights[k]
        va = load_rgb(a, y, xi)
        vb = load_rgb(b, y, xi)
        sx += wk * va
        sy += wk * vb
        sxx += wk * wp.cw_mul(va, va)
        syy += wk * wp.cw_mul(vb, vb)
        sxy += wk * wp.cw_mul(va, vb)
    mx[y, x] = sx
    my[y, x] = sy
    mxx[y, x] = sxx
    myy[y, x] = syy
    mxy[y, x] = sxy


@wp.func
def ssim_from_moments(ux: wp.float64, uy: wp.float64, uxx: wp.float64, uyy: wp.float64, uxy: wp.float64,
                      c1: wp.float64, c2: wp.float64) -> wp.float64:
    # Wang et al. 2004 eq. 13 with population (co)variances
    vx = uxx - ux * ux
    vy = uyy - uy * uy
    vxy = uxy - ux * uy
    two = wp.float64(2.0)
    num = (two * ux * uy + c1) * (two * vxy + c2)
    den = (ux * ux + uy * uy + c1) * (vx + vy + c2)
    s = num / den
    if not wp.isfinite(s):  # only for inputs beyond ~1e75, where the float64 moments overflow
        s = wp.float64(0.0)
    return s


@wp.func
def ssim_at(mx: wp.array2d(dtype=wp.vec3d), my: wp.array2d(dtype=wp.vec3d), mxx: wp.array2d(dtype=wp.vec3d),
            myy: wp.array2d(dtype=wp.vec3d), mxy: wp.array2d(dtype=wp.vec3d), weights: wp.array(dtype=wp.float64),
            radius: int, y: int, x: int, c1: wp.float64, c2: wp.float64) -> wp.float64:
    """Vertical Gaussian pass at (y, x) and the SSIM map value there (mean over the three channels)."""
    h = mx.shape[0]
    ux = wp.vec3d()
    uy = wp.vec3d()
    uxx = wp.vec3d()
    uyy = wp.vec3d()
    uxy = wp.vec3d()
    for k in range(2 * radius + 1):
        yi = reflect_index(y + k - radius, h)
        wk = weights[k]
        ux += wk * mx[yi, x]
        uy += wk * my[yi, x]
        uxx += wk * mxx[yi, x]
        uyy += wk * myy[yi, x]
        uxy += wk * mxy[yi, x]
    s = wp.float64(0.0)
    for c in range(3):
        s += ssim_from_moments(ux[c], uy[c], uxx[c], uyy[c], uxy[c], c1, c2)
    return s / wp.float64(3.0)


@wp.func
def eccentricity_deg(x: int, y: int, half_w: wp.float64, half_h: wp.float64, gx: wp.float64, gy: wp.float64,
                     focal_px: wp.float64, gaze_norm: wp.float64, rad_to_deg: wp.float64) -> wp.float64:
    """Angle between the rays through the pixel centre and through the gaze point (pinhole, square pixels), in the
    same operation order as metrics.eccentricity_np."""
    px = (wp.float64(x) + wp.float64(0.5)) - half_w
    py = (wp.float64(y) + wp.float64(0.5)) - half_h
    ff = focal_px * focal_px
    dot = px * gx + py * gy + ff
    n1 = wp.sqrt(px * px + py * py + ff)
    cosang = wp.clamp(dot / (n1 * gaze_norm), wp.float64(-1.0), wp.float64(1.0))
    return wp.acos(cosang) * rad_to_deg


@wp.func
def in_range(e: wp.float64, lo: wp.float64, hi: wp.float64) -> wp.float64:
    if e >= lo and e < hi:
        return wp.float64(1.0)
    return wp.float64(0.0)


@wp.kernel(enable_backward=False)
def metric_sums_kernel(
    a: wp.array2d(dtype=Any),
    b: wp.array2d(dtype=Any),
    rows: int,
    use_ssim: int,
    mx: wp.array2d(dtype=wp.vec3d),
    my: wp.array2d(dtype=wp.vec3d),
    mxx: wp.array2d(dtype=wp.vec3d),
    myy: wp.array2d(dtype=wp.vec3d),
    mxy: wp.array2d(dtype=wp.vec3d),
    weights: wp.array(dtype=wp.float64),
    radius: int,
    c1: wp.float64,
    c2: wp.float64,
    use_mask: int,
    mask: wp.array2d(dtype=wp.uint8),
    n_regions: int,
    region_lo: wp.array(dtype=wp.float64),
    region_hi: wp.array(dtype=wp.float64),
    half_w: wp.float64,
    half_h: wp.float64,
    gx: wp.float64,
    gy: wp.float64,
    focal_px: wp.float64,
    gaze_norm: wp.float64,
    rad_to_deg: wp.float64,
    out: wp.array2d(dtype=wp.float64),
):
    """Sums of one column strip (``rows`` rows from chunk * rows) into out[chunk * width + x, :].

    Region membership: ``use_mask`` = 1: region 0 is mask != 0; else region k is
    region_lo[k] <= eccentricity < region_hi[k] for k < n_regions (regions may overlap)."""
    chunk, x = wp.tid()
    h = a.shape[0]
    w = a.shape[1]
    y0 = chunk * rows
    y1 = wp.min(y0 + rows, h)
    d2_all = wp.float64(0.0)
    s_crop = wp.float64(0.0)
    n_crop = wp.float64(0.0)
    bad_a = wp.float64(0.0)
    bad_b = wp.float64(0.0)
    cnt = wp.vec4d()
    d2r = wp.vec4d()
    sr = wp.vec4d()
    for y in range(y0, y1):
        bad_a += count_nonfinite(a, y, x)
        bad_b += count_nonfinite(b, y, x)
        d = load_rgb(a, y, x) - load_rgb(b, y, x)
        d2 = wp.dot(d, d)
        d2_all += d2
        s = wp.float64(0.0)
        if use_ssim != 0:
            s = ssim_at(mx, my, mxx, myy, mxy, weights, radius, y, x, c1, c2)
            if y >= radius and y < h - radius and x >= radius and x < w - radius:
                s_crop += s
                n_crop += wp.float64(1.0)
        m = wp.vec4d()
        if use_mask != 0:
            if mask[y, x] != wp.uint8(0):
                m[0] = wp.float64(1.0)
        else:
            e = eccentricity_deg(x, y, half_w, half_h, gx, gy, focal_px, gaze_norm, rad_to_deg)
            for k in range(n_regions):
                m[k] = in_range(e, region_lo[k], region_hi[k])
        cnt += m
        d2r += d2 * m
        sr += s * m
    i = chunk * w + x
    out[i, SUM_D2] = d2_all
    out[i, SUM_SSIM_CROP] = s_crop
    out[i, N_CROP] = n_crop
    out[i, NONFINITE_A] = bad_a
    out[i, NONFINITE_B] = bad_b
    for k in range(MAX_REGIONS):
        out[i, REGION0 + 3 * k] = cnt[k]
        out[i, REGION0 + 3 * k + 1] = d2r[k]
        out[i, REGION0 + 3 * k + 2] = sr[k]


@wp.kernel(enable_backward=False)
def sum_blocks_kernel(src: wp.array2d(dtype=wp.float64), n: int, block: int, dst: wp.array2d(dtype=wp.float64)):
    """dst[j, k] = sum of src[j * block + t, k] for t in [0, block), in order (rows past n skipped)."""
    j, k = wp.tid()
    t0 = j * block
    t1 = wp.min(t0 + block, n)
    s = wp.float64(0.0)
    for t in range(t0, t1):
        s += src[t, k]
    dst[j, k] = s
