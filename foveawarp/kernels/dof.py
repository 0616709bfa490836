"""Depth of field by pixel-intensity scatter (Lee, Kim, Choi; ALGORITHMS.md B) and a thin-lens distributed
ray tracer used as its reference.

Scatter model: every source pixel p is a disc of radius ``R_p = max(C_p / 2, 0.5)`` pixels carrying the
weight ``A = K / (pi R_p^2)``; a receiver q accumulates ``sum A I_p`` and ``sum A`` over the sources whose disc
covers it (``|p - q|^2 <= R_p^2`` with integer pixel offsets) and outputs their ratio.

Buffers written by :func:`dof_prepare_kernel`, read by the scatter and the gather:
  coc  (H, W) float : C_p, the clamped circle-of-confusion diameter in pixels.
  pm   (H, W) vec4  : (A_p I_p, A_p), the premultiplied source with the receiver-independent weight
                      ``A_p = K_p / (pi R_p^2)`` (K_p = (Z_f / Z_p)^gamma or 1), stored times 2^-27
                      (``WEIGHT_SCALE``) so that it never overflows.
  geo  (H, W) vec2  : (R_p^2, c_bg): c_bg = C_p >= 0 marks a background source (Z_p >= Z_f) whose weight is
                      multiplied by the background-leak factor W(C_p, C_q) at each receiver; c_bg = -1 marks a
                      source with a fixed weight.
The gather (:func:`dof_gather_kernel`) visits, for each receiver, the disc of offsets bounded by its tile's
dilated max floor(R^2), so it sums exactly the terms the scatter (:func:`dof_scatter_kernel`) adds.
"""

import warp as wp

from .camera import CameraParams, camera_ray_dir
from .gbuffer import shading_normal
from .shade import AreaLightParams, LightParams, ShadeParams, shade_point
from .tonemap import tonemap_value

# largest foreground amplification K = (Z_f / Z_p)^gamma; keeps float sums finite when Z_p -> 0
K_MAX = wp.constant(1.0e8)
# every weight A = K / (pi R^2) <= K_MAX / (pi / 4) < 2^27 is stored times 2^-27 (exact: a power of two), so that
# A I stays finite for any finite color and the sums overflow only for colors near float max; the ratio
# sum(A I) / sum(A) does not change
WEIGHT_SCALE = wp.constant(7.450580596923828e-09)
# the gather's second pass when a sum still overflowed: every term times 2^-16 (a receiver sums at most
# (2 * 64 + 1)^2 < 2^16 sources), so the sums of finite terms stay finite
OVERFLOW_SCALE = wp.constant(1.52587890625e-05)
# focus depths are clamped to [F (1 + FOCUS_MIN_REL), FOCUS_FAR_M] on the device (NaN -> FOCUS_FAR_M)
FOCUS_FAR_M = wp.constant(1.0e30)
FOCUS_MIN_REL = wp.constant(1.0e-4)
# golden angle in radians (Fibonacci spiral lens samples)
GOLDEN_ANGLE = wp.constant(2.39996322972865332)
LENS_SEED = wp.constant(90210)


@wp.struct
class DofParams:
    coc_scale: float  # E * F * px_per_m: C = coc_scale |Z - Z_f| / (Z (Z_f - F)), pixels * metres
    focal_m: float  # F, metres, > 0
    max_coc_px: float  # clamp of C in pixels, > 0
    gamma: float  # foreground amplification exponent, >= 0
    eps_px: float  # loose in-focus range of the background-leak fix, pixels, > 0
    fg_fix: int  # 1: K = (Z_f / Z_p)^gamma for Z_p < Z_f
    bg_fix: int  # 1: K = W(C_p, C_q) for Z_p >= Z_f
    use_hit: int  # 1: pixels with hit == 0 are background at infinite depth
    tan_half_fov_y: float  # > 0: input depth is the distance from the eye, converted to view depth; 0: view depth
    aspect: float  # width / height (used with tan_half_fov_y)
    width: int
    height: int


@wp.func
def effective_focus(focus: float, focal: float) -> float:
    """Focus depth Z_f in metres, clamped into (F, FOCUS_FAR_M] so that the CoC scale stays finite."""
    if wp.isnan(focus):
        return FOCUS_FAR_M
    return wp.clamp(focus, focal * (1.0 + FOCUS_MIN_REL), FOCUS_FAR_M)


@wp.func
def coc_px(z: float, zf: float, coc_scale: float, focal: float, max_coc: float) -> float:
    """Circle-of-confusion diameter in pixels of a point at view depth ``z`` metres, clamped to ``max_coc``.

    ``C = E F / (Z_f - F) * |Z - Z_f| / Z * px_per_m`` (ALGORITHMS B), evaluated as
    ``|a / Z_f - a / Z|`` with ``a = coc_scale * Z_f / (Z_f - F)``, so that Z = +inf gives the finite far
    limit and a tiny Z (denormal: 1 / Z overflows) still gives the formula's value when that is finite.
    ``z <= 0`` (at or behind the lens) and NaN give ``max_coc``.
    """
    if not (coc_scale > 0.0):
        return 0.0
    if not (z > 0.0):
        return max_coc
    a = coc_scale * (zf / (zf - focal))
    c = wp.abs(a / zf - a / z)
    if not (c < max_coc):
        c = max_coc
    return c


@wp.func
def view_depth(p: DofParams, d: float, x: int, y: int) -> float:
    """View depth in metres of pixel (x, y) given its depth ``d``: as is, or the distance from the eye times
    the cosine between the pixel's ray and the view axis, ``1 / sqrt(1 + s_x^2 + s_y^2)``."""
    if p.tan_half_fov_y > 0.0:
        sx = (2.0 * (float(x) + 0.5) / float(p.width) - 1.0) * p.tan_half_fov_y * p.aspect
        sy = (1.0 - 2.0 * (float(y) + 0.5) / float(p.height)) * p.tan_half_fov_y
        return d / wp.sqrt(1.0 + sx * sx + sy * sy)
    return d


@wp.func
def disc_reach(r2: float) -> int:
    """Largest integer n >= 0 with n^2 <= r2: the farthest row/column offset the disc test can accept."""
    n = int(wp.floor(wp.sqrt(wp.max(r2, 0.0))))
    if float((n + 1) * (n + 1)) <= r2:
        n = n + 1
    if n > 0 and float(n * n) > r2:
        n = n - 1
    return n


@wp.func
def background_weight(c_p: float, c_q: float, eps: float) -> float:
    """W_q = 1 - lerp(clamp((C_p - C_q) / eps), 0, clamp(C_q / eps - 1)) (Lee et al. sec. 4.2)."""
    a = wp.clamp((c_p - c_q) / eps, 0.0, 1.0)
    t = wp.clamp(c_q / eps - 1.0, 0.0, 1.0)
    return 1.0 - a * (1.0 - t)


@wp.func
def resolve(acc: wp.vec4, fallback: wp.vec3) -> wp.vec3:
    """Normalized color ``acc.xyz / acc.w``; the (sanitized) source color where the weight is 0 or the
    result is not finite."""
    out = fallback
    if not wp.isfinite(out):
        out = wp.vec3(0.0, 0.0, 0.0)
    if acc[3] > 0.0:
        c = wp.vec3(acc[0], acc[1], acc[2]) / acc[3]
        if wp.isfinite(c):
            out = c
    return out


@wp.kernel(enable_backward=False)
def coc_kernel(p: DofParams, focus: wp.array(dtype=float), depth: wp.array2d(dtype=float),
               out: wp.array2d(dtype=float),
               row0: int,
):
    """C for every pixel of a view-depth image (no hit mask)."""
    y, x = wp.tid()
    y += row0  # band offset (foveawarp.parallel)
    zf = effective_focus(focus[0], p.focal_m)
    out[y, x] = coc_px(view_depth(p, depth[y, x], x, y), zf, p.coc_scale, p.focal_m, p.max_coc_px)


@wp.kernel(enable_backward=False)
def dof_prepare_kernel(
    p: DofParams,
    focus: wp.array(dtype=float),
    color: wp.array2d(dtype=wp.vec3),
    depth: wp.array2d(dtype=float),
    hit: wp.array2d(dtype=wp.uint8),
    out_coc: wp.array2d(dtype=float),
    out_pm: wp.array2d(dtype=wp.vec4),
    out_geo: wp.array2d(dtype=wp.vec2),
    row0: int,
):
    """Per source pixel: C_p, the premultiplied weighted color and the disc geometry (module docstring)."""
    y, x = wp.tid()
    y += row0  # band offset (foveawarp.parallel)
    zf = effective_focus(focus[0], p.focal_m)
    z = view_depth(p, depth[y, x], x, y)
    if wp.isnan(z) or z < 0.0:
        z = 0.0
    if p.use_hit != 0:
        if hit[y, x] == wp.uint8(0):
            z = wp.inf
    c = coc_px(z, zf, p.coc_scale, p.focal_m, p.max_coc_px)
    r = wp.max(0.5 * c, 0.5)
    k = float(1.0)
    c_bg = float(-1.0)
    if z < zf:
        if p.fg_fix != 0:
            # virtual visibility V = (Z_f / Z_p)^gamma (Lee et al. sec. 4.1), bounded for Z_p -> 0
            k = wp.min(wp.pow(zf / wp.max(z, 1.0e-30), p.gamma), K_MAX)
    else:
        if p.bg_fix != 0:
            c_bg = c
    a = k / (wp.pi * r * r) * WEIGHT_SCALE
    col = color[y, x]
    if not wp.isfinite(col):
        col = wp.vec3(0.0, 0.0, 0.0)
    out_coc[y, x] = c
    out_pm[y, x] = wp.vec4(col[0] * a, col[1] * a, col[2] * a, a)
    out_geo[y, x] = wp.vec2(r * r, c_bg)


@wp.func
def isqrt(n: int) -> int:
    """floor(sqrt(n)) for 0 <= n < 2^24; -1 for n < 0 (an empty range)."""
    if n < 0:
        return -1
    r = int(wp.floor(wp.sqrt(float(n))))
    if (r + 1) * (r + 1) <= n:
        r = r + 1
    if r * r > n:
        r = r - 1
    return r


@wp.kernel(enable_backward=False)
def dof_tile_r2_kernel(geo: wp.array2d(dtype=wp.vec2), tile: int, out_r2: wp.array2d(dtype=wp.int32)):
    """Largest floor(R_p^2) (pixels^2) of the sources in each ``tile`` x ``tile`` screen tile. For integer
    offsets, ``dx^2 + dy^2 <= R_p^2`` holds exactly when ``dx^2 + dy^2 <= floor(R_p^2)``."""
    ty, tx = wp.tid()
    h = geo.shape[0]
    w = geo.shape[1]
    m = int(0)
    for y in range(ty * tile, wp.min((ty + 1) * tile, h)):
        for x in range(tx * tile, wp.min((tx + 1) * tile, w)):
            m = wp.max(m, int(wp.floor(geo[y, x][0])))
    out_r2[ty, tx] = m


@wp.kernel(enable_backward=False)
def dof_tile_dilate_kernel(r2: wp.array2d(dtype=wp.int32), k: int, out_window: wp.array2d(dtype=wp.int32)):
    """Gather bound of each tile: the largest floor(R^2) over the tiles within ``k`` tiles (Chebyshev).

    A source p covering receiver q has ``|p - q| <= R_p``; with ``k = ceil(max R / tile)`` p's tile is within
    k tiles of q's, so the bound of q's tile is >= floor(R_p^2) and its disc window holds p."""
    ty, tx = wp.tid()
    nty = r2.shape[0]
    ntx = r2.shape[1]
    m = int(0)
    for j in range(wp.max(ty - k, 0), wp.min(ty + k, nty - 1) + 1):
        for i in range(wp.max(tx - k, 0), wp.min(tx + k, ntx - 1) + 1):
            m = wp.max(m, r2[j, i])
    out_window[ty, tx] = m


@wp.func
def gather_disc(p: DofParams, coc: wp.array2d(dtype=float), pm: wp.array2d(dtype=wp.vec4),
                geo: wp.array2d(dtype=wp.vec2), x: int, y: int, m: int, scale: float) -> wp.vec4:
    """Sum of ``scale`` times the weighted sources whose disc covers receiver (x, y), over the offsets with
    ``dx^2 + dy^2 <= m`` (pixels^2)."""
    c_q = coc[y, x]
    wn = isqrt(m)
    acc = wp.vec4(0.0, 0.0, 0.0, 0.0)
    for sy in range(wp.max(y - wn, 0), wp.min(y + wn, p.height - 1) + 1):
        dy = sy - y
        xr = isqrt(m - dy * dy)
        for sx in range(wp.max(x - xr, 0), wp.min(x + xr, p.width - 1) + 1):
            dx = sx - x
            g = geo[sy, sx]
            if float(dx * dx + dy * dy) <= g[0]:
                s = pm[sy, sx] * scale
                if g[1] >= 0.0:
                    s = s * background_weight(g[1], c_q, p.eps_px)
                acc += s
    return acc


@wp.kernel(enable_backward=False)
def dof_gather_kernel(
    p: DofParams,
    coc: wp.array2d(dtype=float),
    pm: wp.array2d(dtype=wp.vec4),
    geo: wp.array2d(dtype=wp.vec2),
    window: wp.array2d(dtype=wp.int32),
    tile: int,
    color: wp.array2d(dtype=wp.vec3),
    out: wp.array2d(dtype=wp.vec3),
    row0: int,
):
    """Each receiver q sums the sources p whose disc covers it (the scatter, computed as a gather), visiting
    the offsets with ``dx^2 + dy^2 <= m``, m = its tile's dilated bound of floor(R^2).

    ``out`` may be ``color``: a thread reads ``color`` only at its own pixel."""
    y, x = wp.tid()
    y += row0  # band offset (foveawarp.parallel)
    m = window[y // tile, x // tile]
    acc = gather_disc(p, coc, pm, geo, x, y, m, 1.0)
    if not wp.isfinite(acc):  # a sum overflowed (colors near float max): again with scaled terms
        acc = gather_disc(p, coc, pm, geo, x, y, m, OVERFLOW_SCALE)
    out[y, x] = resolve(acc, color[y, x])


@wp.kernel(enable_backward=False)
def dof_scatter_kernel(
    p: DofParams,
    coc: wp.array2d(dtype=float),
    pm: wp.array2d(dtype=wp.vec4),
    geo: wp.array2d(dtype=wp.vec2),
    accum: wp.array2d(dtype=wp.vec4),
):
    """Each source p adds its weighted color to every receiver its disc covers (atomics; the reference)."""
    y, x = wp.tid()
    g = geo[y, x]
    s = pm[y, x]
    n = disc_reach(g[0])
    for ry in range(wp.max(y - n, 0), wp.min(y + n, p.height - 1) + 1):
        dy = ry - y
        for rx in range(wp.max(x - n, 0), wp.min(x + n, p.width - 1) + 1):
            dx = rx - x
            if float(dx * dx + dy * dy) <= g[0]:
                v = s
                if g[1] >= 0.0:
                    v = s * background_weight(g[1], coc[ry, rx], p.eps_px)
                wp.atomic_add(accum, ry, rx, v)


@wp.kernel(enable_backward=False)
def dof_normalize_kernel(accum: wp.array2d(dtype=wp.vec4), color: wp.array2d(dtype=wp.vec3),
                         out: wp.array2d(dtype=wp.vec3),
                         row0: int,
):
    y, x = wp.tid()
    y += row0  # band offset (foveawarp.parallel)
    out[y, x] = resolve(accum[y, x], color[y, x])


@wp.kernel(enable_backward=False)
def dof_focus_at_pixel_kernel(
    p: DofParams,
    depth: wp.array2d(dtype=float),
    hit: wp.array2d(dtype=wp.uint8),
    gaze_x: float,
    gaze_y: float,
    out_focus: wp.array(dtype=float),
):
    """out_focus[0] = view depth (metres) at the pixel holding the gaze point (clamped onto the screen);
    FOCUS_FAR_M where that pixel is a miss or its depth is not positive and finite."""
    gx = gaze_x
    gy = gaze_y
    if wp.isnan(gx):
        gx = 0.5 * float(p.width)
    if wp.isnan(gy):
        gy = 0.5 * float(p.height)
    gx = wp.clamp(gx, 0.0, float(p.width) - 0.5)
    gy = wp.clamp(gy, 0.0, float(p.height) - 0.5)
    x = wp.clamp(int(gx), 0, p.width - 1)
    y = wp.clamp(int(gy), 0, p.height - 1)
    is_hit = int(1)
    if p.use_hit != 0:
        if hit[y, x] == wp.uint8(0):
            is_hit = 0
    f = FOCUS_FAR_M
    if is_hit != 0:
        z = view_depth(p, depth[y, x], x, y)
        if z > 0.0 and z < FOCUS_FAR_M:
            f = z
    out_focus[0] = f


# ---------------------------------------------------------------------------------------------------------
# thin-lens reference (distributed ray tracing, Cook et al. 1984)


@wp.kernel(enable_backward=False)
def thin_lens_kernel(
    sp: ShadeParams,
    cam: CameraParams,
    lens_radius_m: float,
    focus_m: float,
    samples: int,
    max_t: float,
    mesh: wp.uint64,
    indices: wp.array(dtype=wp.int32),
    vnormals: wp.array(dtype=wp.vec3),
    smooth: wp.array(dtype=wp.uint8),
    face_albedo: wp.array(dtype=wp.vec3),
    lights: wp.array(dtype=LightParams),
    area_lights: wp.array(dtype=AreaLightParams),
    face_emission: wp.array(dtype=wp.vec3),
    exposure: float,
    white: float,
    out_hdr: wp.array2d(dtype=wp.vec3),
    out_display: wp.array2d(dtype=wp.vec3),
    row0: int,
):
    """Average linear radiance over ``samples`` points of a lens disc of radius ``lens_radius_m`` (world units)
    centred on the eye in the (right, up) plane, every ray aimed at the point of the focal plane (view depth
    ``focus_m``) seen through the pixel centre; then the tone map.

    Lens points follow a Fibonacci spiral (area-uniform on the disc) rotated by a per-pixel random angle.
    Sample s of pixel i is shaded with random-stream index ``i + s * W * H`` (sample 0 matches the pinhole
    shading of the same pixel). With a zero offset the ray is the pinhole ray itself."""
    y, x = wp.tid()
    y += row0  # band offset (foveawarp.parallel)
    npix = cam.width * cam.height
    pixel = y * cam.width + x
    d0 = camera_ray_dir(cam, float(x) + 0.5, float(y) + 0.5)
    fp = cam.eye + d0 * (focus_m / wp.dot(d0, cam.forward))
    rng = wp.rand_init(LENS_SEED, pixel)
    rot = 2.0 * wp.pi * wp.randf(rng)
    acc = wp.vec3(0.0, 0.0, 0.0)
    for s in range(samples):
        rr = wp.sqrt((float(s) + 0.5) / float(samples)) * lens_radius_m
        phi = float(s) * GOLDEN_ANGLE + rot
        o = cam.eye
        d = d0
        if rr > 0.0:
            o = cam.eye + (cam.right * wp.cos(phi) + cam.up * wp.sin(phi)) * rr
            d = wp.normalize(fp - o)
        q = wp.mesh_query_ray(mesh, o, d, max_t)
        if q.result:
            hp = o + d * q.t
            fn = q.normal
            if wp.dot(fn, d) > 0.0:
                fn = -fn
            n = shading_normal(mesh, q.face, q.u, q.v, fn, vnormals, smooth, indices)
            spl = sp
            spl.eye = o
            acc += shade_point(spl, pixel + s * npix, hp, n, face_albedo[q.face], q.face, lights, area_lights,
                               face_emission)
        else:
            acc += sp.background
    hdr = acc / float(wp.max(samples, 1))
    out_hdr[y, x] = hdr
    out_display[y, x] = wp.vec3(tonemap_value(hdr[0], exposure, white), tonemap_value(hdr[1], exposure, white),
                                tonemap_value(hdr[2], exposure, white))
