"""Edge-avoiding a-trous filtering of a path-traced frame's periphery (Dammertz et al. 2010; the spatial filter of
SVGF, Schied et al. 2017, with its variance-guided luminance stop as an option).

One iteration ``k`` (step ``s = 2^k`` pixels) replaces each pixel's radiance by the normalized weighted sum over the
5 x 5 taps ``q = p + s (i, j)``, ``i, j`` in -2..2, inside the image:

    w(p, q) = h(i) h(j) * w_z * w_n * w_l,    h = (1/16, 1/4, 3/8, 1/4, 1/16)  (the B3 spline)
    w_z = exp(-|z_p - z_q| / (SIGMA_Z z_p s))           (relative depth, looser at wider steps)
    w_n = max(0, n_p . n_q)^SIGMA_N                     (normals)
    w_l = exp(-|l_p - l_q| / (SIGMA_L (l_p + l_q) / 2 + L_EPS))  (relative luminance: keeps strong edges of light)

and a tap whose hit flag differs from the pixel's (a surface next to the background) has weight 0.

With ``ShadingConfig.path_filter_guide = "variance"`` the luminance stop is SVGF's instead,

    w_l = exp(-|l_p - l_q| / (SIGMA_LV sqrt(var_p) + L_EPS)),

guided by the temporal variance of each pixel's luminance: the stop widens with a pixel's noise, so noise is
still averaged, and narrows where the light is clean, whose edges it keeps (the relative stop lets a shadow's
other side in at any step). Before the filter, each surface pixel's luminance moments
``(m1, m2, n)`` are carried over from the previous frame (reprojected as the periphery's history below, bilinear
over depth-matching taps): ``m_k <- m_k + (l^k - m_k) a`` with ``a = max(alpha, 1 / n)``, ``n`` counting the
frames; ``var = m2 - m1^2`` once ``n >= MOMENTS_MIN_FRAMES``, before that (and where the history fails) the
relative stop above. Each iteration then carries the variance of its weighted mean, ``sum w^2 var_q / (sum w)^2``.

Background pixels are left as they are. After the last iteration each pixel is blended with its unfiltered value by its
eccentricity ``e`` from the gaze: the filtered value's weight is 0 within ``fovea_deg`` and grows linearly to 1 at
``2 fovea_deg`` (``filter_ramp``), so the exact fovea stays as traced.

The periphery's history (``ShadingConfig.path_history`` = ``a``, off at 0): then each surface pixel's output is

    out = c + (h - c) * a * filter_ramp(e, fovea_deg)

with ``c`` the filtered value and ``h`` the previous frame's output at the pixel's reprojected position
(``GBuffer.reproj_uv``), bilinear over the taps whose stored depth matches the point's previous distance
(``GBuffer.prev_dist``) within ``depth_eps_rel`` of its depth, renormalized; with no such tap, a miss, no
reprojection or no history (first frame, cut, a full-resolution frame before) ``out = c``.
"""

import warp as wp

from .gbuffer import NO_REPROJ
from .load import load_f32, load_vec3
from .sampling import FrameParams, eccentricity_at
from .temporal import bilinear_taps

# the edge-stopping constants: depth relative to the pixel's depth per pixel of step, the normals' exponent and
# the relative luminance difference
SIGMA_Z = wp.constant(0.01)
SIGMA_N = wp.constant(32.0)  # pow32 below hard-codes this exponent
SIGMA_L = wp.constant(1.0)
L_EPS = wp.constant(1.0e-4)
# the variance-guided luminance stop's width in standard deviations (SVGF's sigma_l) and the frames of moments it
# needs before it trusts them
SIGMA_LV = wp.constant(4.0)
MOMENTS_MIN_FRAMES = wp.constant(4.0)


@wp.func
def b3(i: int) -> float:
    """The B3-spline tap weight of offset i in -2..2."""
    a = wp.abs(i)
    if a == 0:
        return 0.375
    if a == 1:
        return 0.25
    return 0.0625


@wp.func
def pow32(c: float) -> float:
    """``c ** SIGMA_N`` for SIGMA_N = 32, by five squarings."""
    c2 = c * c
    c4 = c2 * c2
    c8 = c4 * c4
    c16 = c8 * c8
    return c16 * c16


@wp.func
def luminance(c: wp.vec3) -> float:
    return 0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]


@wp.func
def filter_ramp(e_deg: float, fovea_deg: float) -> float:
    """The filtered value's weight at eccentricity ``e_deg``: 0 up to ``fovea_deg``, 1 from ``2 fovea_deg``, linear
    between (a step at 0 for ``fovea_deg`` 0)."""
    if not (fovea_deg > 0.0):
        return 1.0
    return wp.clamp(e_deg / fovea_deg - 1.0, 0.0, 1.0)


@wp.func
def _history_tap(hist: wp.array2d(dtype=wp.vec3), hist_depth: wp.array2d(dtype=float), tx: int, ty: int,
                 wt: float, dist_prev: float, tol: float):
    """(weight x colour, weight) of history tap (tx, ty) of bilinear weight ``wt``: 0 off screen or where its
    stored depth is not ``dist_prev`` within ``tol``."""
    z = wp.vec3(0.0, 0.0, 0.0)
    if wt <= 0.0 or tx < 0 or ty < 0 or tx >= hist.shape[1] or ty >= hist.shape[0]:
        return z, 0.0
    if not (wp.abs(load_f32(hist_depth, ty, tx) - dist_prev) < tol):
        return z, 0.0
    return load_vec3(hist, ty, tx) * wt, wt


@wp.func
def reprojected_history(hist: wp.array2d(dtype=wp.vec3), hist_depth: wp.array2d(dtype=float),
                        reproj_uv: wp.array2d(dtype=wp.vec2), prev_dist: wp.array2d(dtype=float),
                        depth: wp.array2d(dtype=float), x: int, y: int, depth_eps_rel: float):
    """(value, found) of the previous frame's ``hist`` at pixel (x, y)'s reprojected position: bilinear over the
    taps whose stored depth matches the point's previous distance within ``depth_eps_rel`` of its depth,
    renormalized; found 0 without reprojection or matching tap, or for a non-finite value."""
    z = wp.vec3(0.0, 0.0, 0.0)
    uv = reproj_uv[y, x]
    if uv[0] == NO_REPROJ and uv[1] == NO_REPROJ:
        return z, 0
    x0, y0, fx, fy = bilinear_taps(uv, hist.shape[1], hist.shape[0])
    dp = prev_dist[y, x]
    tol = depth_eps_rel * depth[y, x]
    c00, w00 = _history_tap(hist, hist_depth, x0, y0, (1.0 - fx) * (1.0 - fy), dp, tol)
    c10, w10 = _history_tap(hist, hist_depth, x0 + 1, y0, fx * (1.0 - fy), dp, tol)
    c01, w01 = _history_tap(hist, hist_depth, x0, y0 + 1, (1.0 - fx) * fy, dp, tol)
    c11, w11 = _history_tap(hist, hist_depth, x0 + 1, y0 + 1, fx * fy, dp, tol)
    ws = w00 + w10 + w01 + w11
    if not (ws > 1.0e-6):
        return z, 0
    hv = (c00 + c10 + c01 + c11) / ws
    if wp.isfinite(hv[0]) and wp.isfinite(hv[1]) and wp.isfinite(hv[2]):
        return hv, 1
    return z, 0


@wp.func
def atrous_pixel(src: wp.array2d(dtype=wp.vec3), depth: wp.array2d(dtype=float), normal: wp.array2d(dtype=wp.vec3),
                 hit: wp.array2d(dtype=wp.uint8), step: int, x: int, y: int, var: wp.array2d(dtype=float),
                 guided: int):
    """Pixel (x, y) of one a-trous iteration of step ``step`` (the module docstring): (its value, the variance
    of its luminance). ``guided`` 0: the relative luminance stop, variance 0; 1: the variance-guided stop
    (``var`` the luminance variance, negative where unknown, which falls back to the relative stop)."""
    h = src.shape[0]
    w = src.shape[1]
    c = src[y, x]
    hp = hit[y, x]
    vp = float(0.0)
    if guided != 0:
        vp = var[y, x]
    if hp == wp.uint8(0):
        return c, vp
    zp = depth[y, x]
    np_ = normal[y, x]
    lp = luminance(c)
    inv_z = 1.0 / wp.max(SIGMA_Z * wp.abs(zp) * float(step), 1.0e-20)
    inv_lv = float(-1.0)  # 1 / (SIGMA_LV sqrt(var_p)) when guided by a known variance
    if guided != 0 and vp >= 0.0:
        inv_lv = 1.0 / (SIGMA_LV * wp.sqrt(vp) + L_EPS)
    acc = wp.vec3(0.0, 0.0, 0.0)
    wsum = float(0.0)
    vsum = float(0.0)
    for j in range(-2, 3):
        qy = y + j * step
        if qy >= 0 and qy < h:
            for i in range(-2, 3):
                qx = x + i * step
                if qx >= 0 and qx < w:
                    if hit[qy, qx] == hp:
                        cq = src[qy, qx]
                        lq = luminance(cq)
                        # w_z w_l as one exponential and w_n = cos^32 by five squarings, not two exps and a pow:
                        # 3 iterations at 960x540 on one CPU thread 1193 -> 811 ms, results within 1e-6 relative
                        ez = wp.abs(zp - depth[qy, qx]) * inv_z
                        el = float(0.0)
                        if inv_lv >= 0.0:
                            el = wp.abs(lp - lq) * inv_lv
                        else:
                            el = wp.abs(lp - lq) / (SIGMA_L * 0.5 * wp.abs(lp + lq) + L_EPS)
                        wt = b3(i) * b3(j) * wp.exp(-(ez + el)) * pow32(wp.max(wp.dot(np_, normal[qy, qx]), 0.0))
                        if wp.isfinite(wt) and wt > 0.0:
                            acc += cq * wt
                            wsum += wt
                            if guided != 0:
                                vsum += wt * wt * wp.max(var[qy, qx], 0.0)
    if wsum > 0.0:
        out = acc / wsum
        if wp.isfinite(out[0]) and wp.isfinite(out[1]) and wp.isfinite(out[2]):
            c = out
            if vp >= 0.0:
                vp = vsum / (wsum * wsum)  # SVGF: the variance of the weighted mean of independent taps
    return c, vp


@wp.kernel(enable_backward=False)
def atrous_kernel(src: wp.array2d(dtype=wp.vec3), depth: wp.array2d(dtype=float), normal: wp.array2d(dtype=wp.vec3),
                  hit: wp.array2d(dtype=wp.uint8), step: int, dst: wp.array2d(dtype=wp.vec3), row0: int):
    """One a-trous iteration of step ``step`` from ``src`` into ``dst`` (the module docstring)."""
    y, x = wp.tid()
    y += row0  # band offset (foveawarp.parallel)
    c, v = atrous_pixel(src, depth, normal, hit, step, x, y, depth, 0)  # guided 0: its var array is not read
    dst[y, x] = c


@wp.kernel(enable_backward=False)
def luminance_moments_kernel(cur: wp.array2d(dtype=wp.vec3), hit: wp.array2d(dtype=wp.uint8),
                             depth: wp.array2d(dtype=float), reproj_uv: wp.array2d(dtype=wp.vec2),
                             prev_dist: wp.array2d(dtype=float), hist: wp.array2d(dtype=wp.vec3),
                             hist_depth: wp.array2d(dtype=float), valid: wp.array(dtype=wp.int32),
                             use_history: int, alpha: float, depth_eps_rel: float,
                             mom: wp.array2d(dtype=wp.vec3), var: wp.array2d(dtype=float), row0: int):
    """The temporal moments of each surface pixel's luminance (the module docstring): ``mom`` = (m1, m2, n) from
    ``cur`` and the reprojected ``hist``, ``var`` = m2 - m1^2 once n >= MOMENTS_MIN_FRAMES, else -1 (unknown)."""
    y, x = wp.tid()
    y += row0  # band offset (foveawarp.parallel)
    l = luminance(cur[y, x])
    if not wp.isfinite(l):
        l = 0.0
    m = wp.vec3(l, l * l, 1.0)
    if use_history != 0 and valid[0] != 0 and hit[y, x] != wp.uint8(0):
        hm, found = reprojected_history(hist, hist_depth, reproj_uv, prev_dist, depth, x, y, depth_eps_rel)
        if found != 0:
            n = wp.min(wp.max(hm[2], 0.0), 1.0e6) + 1.0
            a = wp.max(alpha, 1.0 / n)  # a plain mean over the first 1 / alpha frames, then exponential
            m = wp.vec3(hm[0] + (l - hm[0]) * a, hm[1] + (l * l - hm[1]) * a, n)
    mom[y, x] = m
    v = float(-1.0)
    if m[2] >= MOMENTS_MIN_FRAMES:
        v = wp.max(m[1] - m[0] * m[0], 0.0)
        if not wp.isfinite(v):
            v = -1.0
    var[y, x] = v


@wp.kernel(enable_backward=False)
def blend_by_eccentricity_kernel(frame: wp.array(dtype=FrameParams), unfiltered: wp.array2d(dtype=wp.vec3),
                                 filtered: wp.array2d(dtype=wp.vec3), fovea_deg: float,
                                 out: wp.array2d(dtype=wp.vec3), row0: int):
    """out = lerp(unfiltered, filtered, filter_ramp(eccentricity, fovea_deg)) per pixel."""
    y, x = wp.tid()
    y += row0  # band offset (foveawarp.parallel)
    fp = frame[0]
    e = eccentricity_at(float(x) + 0.5, float(y) + 0.5, fp.gaze, float(out.shape[1]), float(out.shape[0]),
                        fp.tan_half_fov_y)
    a = filter_ramp(e, fovea_deg)
    u = unfiltered[y, x]
    out[y, x] = u + (filtered[y, x] - u) * a


@wp.kernel(enable_backward=False)
def periphery_history_kernel(frame: wp.array(dtype=FrameParams), cur: wp.array2d(dtype=wp.vec3),
                             hit: wp.array2d(dtype=wp.uint8), depth: wp.array2d(dtype=float),
                             reproj_uv: wp.array2d(dtype=wp.vec2), prev_dist: wp.array2d(dtype=float),
                             hist: wp.array2d(dtype=wp.vec3), hist_depth: wp.array2d(dtype=float),
                             valid: wp.array(dtype=wp.int32), use_history: int, weight: float, fovea_deg: float,
                             depth_eps_rel: float, out: wp.array2d(dtype=wp.vec3), row0: int):
    """The periphery's history blend of the module docstring: ``cur`` -> ``out``; ``hist`` and ``hist_depth``
    hold the previous frame's output and G-buffer depth, ``valid[0]`` 1 when they do."""
    y, x = wp.tid()
    y += row0  # band offset (foveawarp.parallel)
    c = cur[y, x]
    out[y, x] = c
    if use_history == 0 or valid[0] == 0 or hit[y, x] == wp.uint8(0):
        return
    w = cur.shape[1]
    h = cur.shape[0]
    fp = frame[0]
    e = eccentricity_at(float(x) + 0.5, float(y) + 0.5, fp.gaze, float(w), float(h), fp.tan_half_fov_y)
    a = weight * filter_ramp(e, fovea_deg)
    if not (a > 0.0):
        return
    hv, found = reprojected_history(hist, hist_depth, reproj_uv, prev_dist, depth, x, y, depth_eps_rel)
    if found != 0:
        out[y, x] = c + (hv - c) * a


@wp.kernel(enable_backward=False)
def keep_history_kernel(src: wp.array2d(dtype=wp.vec3), depth: wp.array2d(dtype=float),
                        hist: wp.array2d(dtype=wp.vec3), hist_depth: wp.array2d(dtype=float),
                        valid: wp.array(dtype=wp.int32), row0: int):
    """The frame's output and depth become the next frame's history (``valid[0] = 1``)."""
    y, x = wp.tid()
    y += row0  # band offset (foveawarp.parallel)
    hist[y, x] = src[y, x]
    hist_depth[y, x] = depth[y, x]
    if y == 0 and x == 0:
        valid[0] = 1
