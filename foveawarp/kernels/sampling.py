"""Foveated sampling map (ALGORITHMS.md A2): eccentricity, MAR probability (thesis eq. 2), saliency
(thesis eq. 3), stratified binarization with the jitter-block guarantee, and the fused per-frame kernel that
also runs the reprojection cache test (thesis eq. 4).

Geometry: a pinhole camera, square pixels, pixel centres at (x + 0.5, y + 0.5), row 0 at the top. A pixel
position (px, py) maps to the camera-space direction (sx, sy, 1) on the image plane at distance 1, with
``sx = (2 px / W - 1) tan(fov_y / 2) W / H`` and ``sy = (1 - 2 py / H) tan(fov_y / 2)`` (as kernels.camera).

Binarization (``dither_sample``): each aligned ``block`` x ``block`` tile has a rank permutation
``r in [0, K)``, K = block^2, from a blue-noise rank matrix shared by all tiles, rotated by a per-tile random
offset and by a per-frame step coprime with K. A pixel is sampled when ``T = (r + u) / K < P`` with ``u`` a
per-pixel jitter in [0, 1) advanced by a golden-ratio phase every K frames. In a full tile the rank-0 pixel is
always sampled (T < 1/K), so each pixel's long-run rate is exactly ``max(P, 1/K)`` and every full tile holds
at least one sample; partial tiles (right/bottom edges) get their guarantee from ``tile_pass_kernel``.
Over K consecutive frames each pixel takes every rank once: successive frames sample different pixels.
"""

import warp as wp

from .camera import CameraParams, camera_project
from .context import FrameContext
from .fpbits import nan_f32
from .gbuffer import NO_REPROJ, reproj_velocity
from .load import (load_f32, load_i32, load_u8, load_vec2, load_vec3, nine_equal_mask64_i32, nine_equal_mask64_vec3,
                   store_i32, store_u8)
from .reproject import cache_lookup
from .saliency import dof_factor, sobel_lab_by_face, sobel_vec3

# salt of the per-pixel jitter stream (the per-tile rank offsets use the plain seed)
JITTER_SALT = 0x2545F491


@wp.struct
class SamplingParams:
    """Per-stage constants (derived from Config once)."""

    mar_slope: float  # deg / deg
    mar_fovea_deg: float  # deg
    fovea_deg: float  # probability 1 within this eccentricity (the fovea traced at full rate)
    xi: float  # minimum probability, >= 1 / block^2
    foveation: int  # 0: every probability is 1
    use_albedo: int
    use_normal: int
    albedo_gain: float  # albedo_scale / (SOBEL_GAIN * LAB_STEP_FULL)
    normal_gain: float  # normal_scale / (SOBEL_GAIN * NORMAL_STEP_FULL)
    inv_velocity_px: float  # 1 / velocity_scale_px
    sigma1_m: float
    sigma2_m: float
    dof_floor: float
    depth_eps_rel: float
    block: int
    tiles_x: int
    num_ranks: int  # block^2
    block_shift: int  # log2(block) when block is a power of two, else -1 (tile indices by shifts, not divisions)
    seed: int


@wp.struct
class FrameParams:
    """Per-frame values, written on the device by ``frame_setup_kernel``."""

    gaze: wp.vec2  # pixels
    tan_half_fov_y: float
    aspect: float  # width / height
    w_min_deg: float  # angle per pixel at the gaze point
    w_far_deg: float  # MAR at the largest eccentricity on screen
    e_max_deg: float  # largest eccentricity over the screen rectangle
    focus_m: float
    dof_on: int
    use_velocity: int
    object_velocity: int  # 1: velocity = motion of the object itself (camera motion removed via cam_prev)
    cam_prev: CameraParams
    eye_prev: wp.vec3
    do_cache: int
    rot: int  # per-frame rank rotation, in [0, K)
    phase: float  # per-frame jitter phase, in [0, 1)
    xi: float  # this frame's minimum probability (SamplingParams.xi, or higher while a still view converges)
    # eq. 2's plateaus without the arc tangent (pixel_probability): with g x p and g.p of eccentricity_at, a pixel
    # with |g x p|^2 < tan2_fovea (g.p)^2 lies inside the fovea (p = 1), one with |g x p|^2 > tan2_floor (g.p)^2 or
    # g.p <= 0 lies where p is clamped to xi. Both tangents sit ECC_MARGIN_DEG inside the true boundaries, so
    # the pixels they classify get exactly the value the formula gives; -1 disables a test.
    tan2_fovea: float
    tan2_floor: float
    # the same plateaus for whole rows (row_plateau_spans, the CPU's rows kernel): cos^2 of cones ROW_CUSHION_DEG
    # inside the two angles above (float64); -1 disables a span
    row_cos2_fovea: wp.float64
    row_cos2_floor: wp.float64


# -- geometry -----------------------------------------------------------------------------------------------


@wp.func
def plane_dir(px: float, py: float, width: float, height: float, tan_half: float) -> wp.vec3:
    """Unnormalized camera-space direction (sx, sy, 1) through the continuous pixel position (px, py)."""
    return wp.vec3((2.0 * px / width - 1.0) * tan_half * (width / height), (1.0 - 2.0 * py / height) * tan_half, 1.0)


@wp.func
def angle_deg(a: wp.vec3, b: wp.vec3) -> float:
    """Angle between two nonzero vectors in degrees (atan2 form: accurate for small angles too)."""
    return wp.degrees(wp.atan2(wp.length(wp.cross(a, b)), wp.dot(a, b)))


# how far inside eq. 2's plateau boundaries the arc-tangent-free classification stays (degrees): far above the
# float error of either computation (~1e-5 deg), far below anything a sample map could show
ECC_MARGIN_DEG = 1.0e-3
# how far inside those angles the plateaus of a whole row (row_plateau_spans) stay, on top of a pixel at each end
# (degrees): the float32 tests of the pixels it classifies are ~1e-5 deg off the exact angle, and its float64
# root finding far less
ROW_CUSHION_DEG = 1.0e-2
# a row's plateaus are found only for gazes within this many pixels of the screen (larger plane coordinates are
# left to the pixels' own tests)
ROW_GAZE_LIMIT_PX = 1.0e5
# the smallest normal float32 (velocity_may_raise: below it a square's relative error is not bounded by an ulp)
F32_MIN_NORMAL = 1.17549435e-38


@wp.func
def eccentricity_terms(px: float, py: float, gaze: wp.vec2, width: float, height: float, tan_half: float):
    """(g x p, g.p) for the rays g through the gaze point and p through (px, py): the eccentricity is
    atan2(|g x p|, g.p) (see :func:`eccentricity_at`)."""
    g = plane_dir(gaze[0], gaze[1], width, height, tan_half)
    p = plane_dir(px, py, width, height, tan_half)
    dx = 2.0 * (px - gaze[0]) / width * tan_half * (width / height)
    dy = -2.0 * (py - gaze[1]) / height * tan_half
    # g x d = (-dy, dx, gx dy - gy dx); its z also equals gx py - gy px (g x d = g x p). Take the form whose
    # products are smaller: near the gaze the first (d small), far off screen the second (p small, while
    # gx dy and gy dx are huge and cancel).
    z1 = g[0] * dy - g[1] * dx
    z2 = g[0] * p[1] - g[1] * p[0]
    z = z1
    if wp.abs(g[0] * p[1]) + wp.abs(g[1] * p[0]) < wp.abs(g[0] * dy) + wp.abs(g[1] * dx):
        z = z2
    return wp.vec3(-dy, dx, z), wp.dot(g, p)


@wp.func
def eccentricity_at(px: float, py: float, gaze: wp.vec2, width: float, height: float, tan_half: float) -> float:
    """Angle in degrees at the eye between the rays through the gaze point and through (px, py).

    angle = atan2(|g x p|, g.p) with g x p = g x d, d = p - g formed from pixel differences: full relative
    accuracy near the gaze (small cross product) and, with g.p taken directly and the cross product's z from
    whichever form cancels less, for gazes far off screen too.
    """
    c, d = eccentricity_terms(px, py, gaze, width, height, tan_half)
    return wp.degrees(wp.atan2(wp.length(c), d))


@wp.func
def arc_max_angle_deg(a: wp.vec3, b: wp.vec3, g: wp.vec3) -> float:
    """Largest angle (degrees) between g and the directions along the image-plane segment a -> b.

    The segment is a great-circle arc on the sphere of directions; the angle to g along a great circle peaks
    at the circle's point nearest -g, so the maximum is at an end point or at that point when it lies on the
    arc (which only happens for gazes far off screen, where some angles exceed 90 degrees).
    """
    best = wp.max(angle_deg(a, g), angle_deg(b, g))
    n = wp.cross(a, b)
    nn = wp.dot(n, n)
    if nn > 0.0:
        q = -g + n * (wp.dot(g, n) / nn)  # projection of -g onto the arc's plane
        if wp.dot(wp.cross(a, q), n) > 0.0 and wp.dot(wp.cross(q, b), n) > 0.0:
            best = wp.max(best, angle_deg(q, g))
    return best


@wp.func
def max_eccentricity_deg(gaze: wp.vec2, width: float, height: float, tan_half: float) -> float:
    """Largest eccentricity over the closed screen rectangle [0, W] x [0, H] (its outer edges, not the
    outermost pixel centres): the corners, plus an edge's interior point for gazes far off screen."""
    g = plane_dir(gaze[0], gaze[1], width, height, tan_half)
    c0 = plane_dir(0.0, 0.0, width, height, tan_half)
    c1 = plane_dir(width, 0.0, width, height, tan_half)
    c2 = plane_dir(width, height, width, height, tan_half)
    c3 = plane_dir(0.0, height, width, height, tan_half)
    m = arc_max_angle_deg(c0, c1, g)
    m = wp.max(m, arc_max_angle_deg(c1, c2, g))
    m = wp.max(m, arc_max_angle_deg(c2, c3, g))
    m = wp.max(m, arc_max_angle_deg(c3, c0, g))
    return m


@wp.func
def foveation_prob(e_deg: float, mar_slope: float, mar_fovea_deg: float, w_min_deg: float, w_far_deg: float,
                   xi: float, fovea_deg: float) -> float:
    """Thesis eq. 2: w = m e + b; p = clamp(1 - (w - w_min) / w_far, xi, 1). w_far >= b > 0. Within
    ``fovea_deg`` of the gaze p = 1 (the fovea is traced at full rate)."""
    if e_deg <= fovea_deg:
        return 1.0
    w = mar_slope * e_deg + mar_fovea_deg
    return wp.clamp(1.0 - (w - w_min_deg) / w_far_deg, xi, 1.0)


@wp.func
def pixel_probability(x: int, y: int, w: int, h: int, sp: SamplingParams, fp: FrameParams) -> float:
    """Thesis eq. 2 at pixel (x, y)'s centre for this frame's gaze (with the full-rate fovea). Pixels well inside
    the fovea or well beyond the eccentricity where p reaches xi take their plateau value without the arc
    tangent (FrameParams.tan2_fovea / tan2_floor): the same value, for most of the screen's pixels."""
    c, d = eccentricity_terms(float(x) + 0.5, float(y) + 0.5, fp.gaze, float(w), float(h), fp.tan_half_fov_y)
    c2 = wp.dot(c, c)
    if c2 < 1.0e30 and wp.abs(d) < 1.0e15:  # finite and no overflow in the products below
        dd = d * d
        if d > 0.0 and c2 < fp.tan2_fovea * dd:
            return 1.0
        if fp.tan2_floor >= 0.0 and (d <= 0.0 or c2 > fp.tan2_floor * dd):
            return fp.xi
    e = wp.degrees(wp.atan2(wp.sqrt(c2), d))
    return foveation_prob(e, sp.mar_slope, sp.mar_fovea_deg, fp.w_min_deg, fp.w_far_deg, fp.xi, sp.fovea_deg)


@wp.func
def cone_row_span(cos2: wp.float64, gu: wp.float64, gv: wp.float64, vy: wp.float64) -> wp.vec3d:
    """Where the image-plane row (u, vy, 1) crosses the cone of directions within angle a (cos2 = cos^2 a,
    a < 90 deg) of g = (gu, gv, 1): (lo, hi, state) with the row's points at angle <= a exactly those with
    lo <= u <= hi (state 1; lo or hi may be infinite), none (state 0), or not found (state -1: a near-degenerate
    quadratic, left to the pixels' own tests).

    angle(p, g) <= a  <=>  g.p > 0 and (g.p)^2 >= cos2 |g|^2 |p|^2, a quadratic q(u) <= 0 on the row; the cone's
    forward half (g.p > 0) meets the row in one interval (the cone is convex), the backward half is dropped."""
    G = gu * gu + gv * gv + wp.float64(1.0)
    L = gv * vy + wp.float64(1.0)  # g.p = gu u + L
    qa = cos2 * G - gu * gu
    qb = wp.float64(-2.0) * gu * L
    qc = cos2 * G * (vy * vy + wp.float64(1.0)) - L * L
    inf = wp.float64(1.0e300)
    if not (wp.abs(qa) > wp.float64(1.0e-9) * cos2 * G):  # also NaN
        return wp.vec3d(wp.float64(0.0), wp.float64(0.0), wp.float64(-1.0))
    disc = qb * qb - wp.float64(4.0) * qa * qc
    if qa > wp.float64(0.0):
        if disc < wp.float64(0.0):
            return wp.vec3d(wp.float64(0.0), wp.float64(0.0), wp.float64(0.0))  # q > 0 on the whole row
    elif not (disc > wp.float64(0.0)):
        return wp.vec3d(wp.float64(0.0), wp.float64(0.0), wp.float64(-1.0))
    sq = wp.sqrt(disc)
    # the two roots without cancellation
    qq = wp.float64(-0.5) * (qb + wp.where(qb < wp.float64(0.0), -sq, sq))
    r1 = wp.float64(0.0)
    r2 = wp.float64(0.0)
    if qq != wp.float64(0.0):
        r1 = qq / qa
        r2 = qc / qq
    lo = wp.min(r1, r2)
    hi = wp.max(r1, r2)
    if qa > wp.float64(0.0):
        # q <= 0 on [lo, hi]: one half of the cone (the row's crossing of the plane g.p = 0 has q > 0)
        if gu * (wp.float64(0.5) * (lo + hi)) + L > wp.float64(0.0):
            return wp.vec3d(lo, hi, wp.float64(1.0))
        return wp.vec3d(wp.float64(0.0), wp.float64(0.0), wp.float64(0.0))
    # q <= 0 outside (lo, hi): a ray in each half; gu != 0 here (qa < 0), and g.p grows with u when gu > 0
    if gu > wp.float64(0.0):
        return wp.vec3d(hi, inf, wp.float64(1.0))
    return wp.vec3d(-inf, lo, wp.float64(1.0))


@wp.func
def span_pixel(u: wp.float64, u0: wp.float64, du: wp.float64, w: int) -> wp.float64:
    """The pixel coordinate x (centres at integers) of plane coordinate u, clamped to [-4, w + 4]."""
    return wp.clamp((u - u0) / du, wp.float64(-4.0), wp.float64(w + 4))


@wp.func
def row_plateau_spans(y: int, w: int, h: int, fp: FrameParams) -> wp.vec4i:
    """Row y's pixels whose probability is a plateau of eq. 2, found once for the row: (f0, f1, v0, v1) with
    every pixel x < f0 or x > f1 at p = xi and every pixel v0 <= x <= v1 at p = 1 (the values
    ``pixel_probability`` gives them); the pixels in between are left to it. No span: (0, w - 1, 0, -1).

    The spans come from the cones ``FrameParams.row_cos2_floor`` / ``row_cos2_fovea`` (ROW_CUSHION_DEG inside the
    pixels' own plateau tests, which in turn lie ECC_MARGIN_DEG inside eq. 2's boundaries), solved in float64
    (``cone_row_span``) and narrowed by one more pixel at each end. A pixel counted in a span is thus at least
    ROW_CUSHION_DEG beyond its plateau test's angle, far more than that test's float32 error: the test returns the
    plateau, and so would eq. 2 itself. Gazes more than ROW_GAZE_LIMIT_PX off the screen get no spans."""
    f0 = int(0)
    f1 = w - 1
    v0 = int(0)
    v1 = int(-1)
    gx = fp.gaze[0]
    gy = fp.gaze[1]
    if not (wp.abs(gx) < ROW_GAZE_LIMIT_PX and wp.abs(gy) < ROW_GAZE_LIMIT_PX):  # also NaN
        return wp.vec4i(f0, f1, v0, v1)
    if fp.row_cos2_floor < wp.float64(0.0) and fp.row_cos2_fovea < wp.float64(0.0):
        return wp.vec4i(f0, f1, v0, v1)
    t = wp.float64(fp.tan_half_fov_y)
    sx = t * wp.float64(w) / wp.float64(h)
    gu = (wp.float64(2.0) * wp.float64(gx) / wp.float64(w) - wp.float64(1.0)) * sx
    gv = (wp.float64(1.0) - wp.float64(2.0) * wp.float64(gy) / wp.float64(h)) * t
    vy = (wp.float64(1.0) - wp.float64(2.0) * (wp.float64(y) + wp.float64(0.5)) / wp.float64(h)) * t
    du = wp.float64(2.0) * sx / wp.float64(w)  # u of pixel x is u0 + x du
    u0 = (wp.float64(1.0) / wp.float64(w) - wp.float64(1.0)) * sx
    if fp.row_cos2_floor >= wp.float64(0.0):
        sp = cone_row_span(fp.row_cos2_floor, gu, gv, vy)
        if sp[2] == wp.float64(0.0):
            f0 = w  # the whole row lies beyond the floor's cone
            f1 = -1
        elif sp[2] > wp.float64(0.0):
            f0 = int(wp.floor(span_pixel(sp[0], u0, du, w) - wp.float64(1.0)))
            f1 = int(wp.ceil(span_pixel(sp[1], u0, du, w) + wp.float64(1.0)))
    if fp.row_cos2_fovea >= wp.float64(0.0):
        sp = cone_row_span(fp.row_cos2_fovea, gu, gv, vy)
        if sp[2] > wp.float64(0.0):
            v0 = int(wp.ceil(span_pixel(sp[0], u0, du, w) + wp.float64(1.0)))
            v1 = int(wp.floor(span_pixel(sp[1], u0, du, w) - wp.float64(1.0)))
    return wp.vec4i(f0, f1, v0, v1)


@wp.func
def velocity_may_raise(v: wp.vec2, inv_velocity_px: float, s: float) -> int:
    """0 when the V term min(|v| inv_velocity_px, 1) cannot exceed ``s`` > 0, so that max(s, V) = s: the squared
    test |v|^2 inv^2 < s^2 (1 - 2^-18) in float32, whose rounding (each of its products, and the length's square
    root and product, within an ulp) is far inside that margin; 1 otherwise: also for a non-finite or tiny s, a
    non-finite |v|^2, and a |v|^2 or inv^2 below the smallest normal float (where the square's relative error is no
    longer small; |v|^2 = 0 is exact and skips). Skips the square root where the term cannot win: the same max."""
    if s >= 1.0e-10:
        d2 = v[0] * v[0] + v[1] * v[1]
        i2 = inv_velocity_px * inv_velocity_px
        if i2 >= F32_MIN_NORMAL and (d2 >= F32_MIN_NORMAL or d2 == 0.0):
            if d2 * i2 < (s * s) * 0.9999961853027344:
                return 0
    return 1


@wp.func
def saliency_velocity(fp: FrameParams, position: wp.array2d(dtype=wp.vec3), y: int, x: int, uv: wp.vec2,
                      px: float, py: float) -> wp.vec2:
    """The screen velocity of the V term at G-buffer entry [y, x], whose primary ray passed through (px, py) and
    reprojects to ``uv``: the G-buffer's (``reproj_velocity``), or with ``fp.object_velocity`` the object's own
    motion (where the point would be in the previous frame had it not moved, minus where it was; camera motion
    removed). The position (12 bytes a pixel) is read only with object motion."""
    if fp.object_velocity == 0:
        return reproj_velocity(uv, px, py)
    v = wp.vec2(0.0, 0.0)
    pr = camera_project(fp.cam_prev, load_vec3(position, y, x))
    if pr[2] > 0.0 and uv[0] > 0.5 * NO_REPROJ:
        v = wp.vec2(pr[0] - uv[0], pr[1] - uv[1])
    return v


# -- binarization -------------------------------------------------------------------------------------------


@wp.func
def tile_rank_offset(seed: int, tile: int, num_ranks: int) -> int:
    s = wp.rand_init(seed, tile)
    if (num_ranks & (num_ranks - 1)) == 0:
        # a power of two: the draw's low bits are its remainder (randi(s, 0, K) is the unsigned draw mod K)
        return wp.randi(s) & (num_ranks - 1)
    return wp.randi(s, 0, num_ranks)


@wp.func
def tile_of(x: int, y: int, sp: SamplingParams):
    """(x // block, y // block) for x, y >= 0: shifts when the block is a power of two (CPU integer division is
    slow; the values are the same)."""
    if sp.block_shift >= 0:
        return x >> sp.block_shift, y >> sp.block_shift
    return x // sp.block, y // sp.block


@wp.func
def tile_rank_shift(tx: int, ty: int, sp: SamplingParams, rot: int) -> int:
    """(tile offset + rot) mod K of tile (tx, ty) this frame: what ``rank_in_tile`` adds to the blue-noise rank
    (each term in [0, K), so the remainder is one subtraction). The same for the K pixels of a tile: the CPU's
    rows kernel computes it once per tile."""
    r = tile_rank_offset(sp.seed, ty * sp.tiles_x + tx, sp.num_ranks) + rot
    if r >= sp.num_ranks:
        r -= sp.num_ranks
    return r


@wp.func
def rank_shifted(x: int, y: int, tx: int, ty: int, ranks: wp.array2d(dtype=wp.int32), sp: SamplingParams,
                 shift: int) -> int:
    """Rank in [0, K) of pixel (x, y) of tile (tx, ty) with the tile's ``tile_rank_shift``: (blue-noise rank +
    shift) mod K."""
    k = sp.block
    r = load_i32(ranks, y - ty * k, x - tx * k) + shift
    if r >= sp.num_ranks:
        r -= sp.num_ranks
    return r


@wp.func
def rank_in_tile(x: int, y: int, tx: int, ty: int, ranks: wp.array2d(dtype=wp.int32), sp: SamplingParams,
                 rot: int) -> int:
    """Rank in [0, K) of pixel (x, y) of tile (tx, ty) this frame: (blue-noise rank + tile offset + rot) mod K,
    each term in [0, K), so the remainder is at most two subtractions (``rank_shifted`` of the tile's
    ``tile_rank_shift``: the same value)."""
    k = sp.block
    r = load_i32(ranks, y - ty * k, x - tx * k) + tile_rank_offset(sp.seed, ty * sp.tiles_x + tx, sp.num_ranks) + rot
    if r >= sp.num_ranks:
        r -= sp.num_ranks
    if r >= sp.num_ranks:
        r -= sp.num_ranks
    return r


@wp.func
def dither_rank(x: int, y: int, ranks: wp.array2d(dtype=wp.int32), sp: SamplingParams, rot: int) -> int:
    """Rank in [0, K) of pixel (x, y) within its aligned block x block tile this frame (a permutation)."""
    tx, ty = tile_of(x, y, sp)
    return rank_in_tile(x, y, tx, ty, ranks, sp, rot)


@wp.func
def dither_sample(p: float, x: int, y: int, width: int, height: int, ranks: wp.array2d(dtype=wp.int32),
                  sp: SamplingParams, rot: int, phase: float) -> wp.uint8:
    """1 when pixel (x, y) is sampled at probability p this frame (stratified threshold, see module doc)."""
    return dither_sample_shifted(p, x, y, width, height, ranks, sp, rot, phase, -1)


@wp.func
def dither_sample_shifted(p: float, x: int, y: int, width: int, height: int, ranks: wp.array2d(dtype=wp.int32),
                          sp: SamplingParams, rot: int, phase: float, shift: int) -> wp.uint8:
    """``dither_sample`` with the pixel's ``tile_rank_shift`` given (``shift`` >= 0; -1: computed here when
    needed)."""
    if p >= 1.0:  # the fovea and saturated saliency: no rank or jitter needed
        return wp.uint8(1)
    tx, ty = tile_of(x, y, sp)
    r = int(0)
    if shift < 0:
        r = rank_in_tile(x, y, tx, ty, ranks, sp, rot)
    else:
        r = rank_shifted(x, y, tx, ty, ranks, sp, shift)
    k = sp.block
    if r == 0 and (tx + 1) * k <= width and (ty + 1) * k <= height:  # a full tile's rank 0: always sampled
        return wp.uint8(1)
    # the threshold t = (r + u) / K with the jitter u in [0, 1] lies between r / K and (r + 1) / K, rounding
    # included (adding u >= 0 and dividing by K > 0 are monotone in float arithmetic): the pixel's probability
    # decides it without the jitter unless it falls in between (for most pixels it does not: their hashes are
    # skipped, the result is the same)
    fk = float(sp.num_ranks)
    if float(r) / fk >= p:
        return wp.uint8(0)
    if float(r + 1) / fk < p:
        return wp.uint8(1)
    s = wp.rand_init(sp.seed ^ JITTER_SALT, y * width + x)
    u = wp.randf(s) + phase
    if u >= 1.0:
        u = u - 1.0
    t = (float(r) + u) / fk
    if t < p:
        return wp.uint8(1)
    return wp.uint8(0)


# -- kernels ------------------------------------------------------------------------------------------------


@wp.kernel(enable_backward=False)
def frame_setup_kernel(
    ctx: FrameContext,  # the frame context: gaze, this frame's field of view, the previous camera
    width: int,
    height: int,
    mar_slope: float,
    mar_fovea_deg: float,
    falloff_deg: float,  # eccentricity of the eq. 2 normalizer; >= e_max: the thesis's (largest on screen)
    focus_mode: int,  # 0: no DoF factor, 1: fixed focus_m, 2: depth at the gaze pixel (screen-clamped)
    focus_m: float,
    depth: wp.array2d(dtype=float),
    hit: wp.array2d(dtype=wp.uint8),
    use_velocity: int,
    object_velocity: int,  # 1: the previous camera (ctx.cam_prev) removes camera motion from the velocity term
    do_cache: int,  # 1: the cache test runs, against the previous eye (ctx.cam_prev.eye)
    rot: int,
    phase: float,
    xi: float,
    fovea_deg: float,
    out: wp.array(dtype=FrameParams),
):
    """One thread: derive the per-frame scalars on the device from the frame context and the stage's settings (no
    host round trip for the focus depth)."""
    gaze_x = ctx.gaze[0]
    gaze_y = ctx.gaze[1]
    tan_half_fov_y = ctx.cam.tan_half_fov_y
    fw = float(width)
    fh = float(height)
    f = FrameParams()
    f.gaze = wp.vec2(gaze_x, gaze_y)
    f.tan_half_fov_y = tan_half_fov_y
    f.aspect = fw / fh
    g = plane_dir(gaze_x, gaze_y, fw, fh, tan_half_fov_y)
    step = wp.vec3(2.0 / fw * tan_half_fov_y * (fw / fh), 0.0, 0.0)  # one pixel to the right on the plane
    f.w_min_deg = wp.degrees(wp.atan2(wp.length(wp.cross(g, step)), wp.dot(g, g) + wp.dot(g, step)))
    f.e_max_deg = max_eccentricity_deg(f.gaze, fw, fh, tan_half_fov_y)
    f.w_far_deg = mar_slope * wp.min(f.e_max_deg, falloff_deg) + mar_fovea_deg
    f.dof_on = 0
    f.focus_m = focus_m
    if focus_mode == 1:
        f.dof_on = 1
    elif focus_mode == 2:
        gx = wp.clamp(int(wp.floor(wp.clamp(gaze_x, -1.0, fw))), 0, depth.shape[1] - 1)
        gy = wp.clamp(int(wp.floor(wp.clamp(gaze_y, -1.0, fh))), 0, depth.shape[0] - 1)
        if hit[gy, gx] != wp.uint8(0):
            f.dof_on = 1
            f.focus_m = depth[gy, gx]
    f.use_velocity = use_velocity
    f.object_velocity = object_velocity
    f.cam_prev = CameraParams()
    if object_velocity != 0:
        f.cam_prev = ctx.cam_prev
    f.eye_prev = wp.vec3(0.0, 0.0, 0.0)
    if do_cache != 0:
        f.eye_prev = ctx.cam_prev.eye
    f.do_cache = do_cache
    f.rot = rot
    f.phase = phase
    f.xi = xi
    # eq. 2's plateaus (pixel_probability): inside fovea_deg p = 1; beyond e_floor, where
    # 1 - (m e + b - w_min) / w_far falls to xi, p = xi (and e > fovea_deg there too)
    f.tan2_fovea = -1.0
    f.row_cos2_fovea = wp.float64(-1.0)
    lo = fovea_deg - ECC_MARGIN_DEG
    if lo > 0.0 and lo < 89.0:
        t = wp.tan(wp.radians(lo))
        f.tan2_fovea = t * t
        if lo > ROW_CUSHION_DEG:
            c = wp.cos(wp.float64(lo - ROW_CUSHION_DEG) * wp.float64(wp.pi / 180.0))
            f.row_cos2_fovea = c * c
    f.tan2_floor = -1.0
    f.row_cos2_floor = wp.float64(-1.0)
    e_floor = ((1.0 - xi) * f.w_far_deg + f.w_min_deg - mar_fovea_deg) / mar_slope
    hi = wp.max(e_floor, fovea_deg) + ECC_MARGIN_DEG
    if hi > 0.0 and hi < 89.0:
        t = wp.tan(wp.radians(hi))
        f.tan2_floor = t * t
        c = wp.cos(wp.float64(hi + ROW_CUSHION_DEG) * wp.float64(wp.pi / 180.0))
        f.row_cos2_floor = c * c
    out[0] = f


@wp.kernel(enable_backward=False)
def eccentricity_kernel(frame: wp.array(dtype=FrameParams), out: wp.array2d(dtype=float), row0: int):
    y, x = wp.tid()
    y += row0  # band offset (foveawarp.parallel)
    fp = frame[0]
    fw = float(out.shape[1])
    fh = float(out.shape[0])
    out[y, x] = eccentricity_at(float(x) + 0.5, float(y) + 0.5, fp.gaze, fw, fh, fp.tan_half_fov_y)


@wp.kernel(enable_backward=False)
def probability_kernel(sp: SamplingParams, frame: wp.array(dtype=FrameParams), out: wp.array2d(dtype=float), row0: int):
    y, x = wp.tid()
    y += row0  # band offset (foveawarp.parallel)
    fp = frame[0]
    fw = float(out.shape[1])
    fh = float(out.shape[0])
    e = eccentricity_at(float(x) + 0.5, float(y) + 0.5, fp.gaze, fw, fh, fp.tan_half_fov_y)
    out[y, x] = foveation_prob(e, sp.mar_slope, sp.mar_fovea_deg, fp.w_min_deg, fp.w_far_deg, sp.xi, sp.fovea_deg)


@wp.kernel(enable_backward=False)
def threshold_kernel(
    probability: wp.array2d(dtype=float),
    ranks: wp.array2d(dtype=wp.int32),
    sp: SamplingParams,
    frame: wp.array(dtype=FrameParams),
    out_sample: wp.array2d(dtype=wp.uint8),
    row0: int,
):
    y, x = wp.tid()
    y += row0  # band offset (foveawarp.parallel)
    fp = frame[0]
    out_sample[y, x] = dither_sample(probability[y, x], x, y, probability.shape[1], probability.shape[0], ranks, sp,
                                     fp.rot, fp.phase)


@wp.func
def tile_guarantee(ty: int, tx: int, ranks: wp.array2d(dtype=wp.int32), sp: SamplingParams,
                   frame: wp.array(dtype=FrameParams), sample: wp.array2d(dtype=wp.uint8),
                   cache_hit: wp.array2d(dtype=wp.uint8)) -> wp.vec2i:
    """Aligned tile (ty, tx): (samples, cache hits) in it, after a tile with no sample (only partial tiles at
    the right/bottom edges can have none) gets its lowest-rank pixel sampled (written to ``sample``)."""
    n = int(0)
    nc = int(0)
    k = sp.block
    x0 = tx * k
    y0 = ty * k
    x1 = wp.min(x0 + k, sample.shape[1])
    y1 = wp.min(y0 + k, sample.shape[0])
    for yy in range(y0, y1):
        for xx in range(x0, x1):  # inside the image: the unchecked loads (kernels/load.py)
            if load_u8(sample, yy, xx) != wp.uint8(0):
                n = n + 1
            if load_u8(cache_hit, yy, xx) != wp.uint8(0):
                nc = nc + 1
    if n == 0:
        rot = frame[0].rot
        best = sp.num_ranks
        bx = x0
        by = y0
        for yy in range(y0, y1):
            for xx in range(x0, x1):
                r = dither_rank(xx, yy, ranks, sp, rot)
                if r < best:
                    best = r
                    bx = xx
                    by = yy
        sample[by, bx] = wp.uint8(1)
        n = 1
    return wp.vec2i(n, nc)


@wp.kernel(enable_backward=False)
def tile_pass_kernel(
    ranks: wp.array2d(dtype=wp.int32),
    sp: SamplingParams,
    frame: wp.array(dtype=FrameParams),
    num_tiles_y: int,
    sample: wp.array2d(dtype=wp.uint8),
    cache_hit: wp.array2d(dtype=wp.uint8),
    num_samples: wp.array(dtype=wp.int32),
    num_cache_hits: wp.array(dtype=wp.int32),
):
    """Launched with ``wp.launch_tiled``: one thread per aligned tile (tile ``b * block_dim + lane`` in raster
    order) runs ``tile_guarantee``. Counts are summed over the thread block first, so the counters see one
    atomic add per block instead of one per tile."""
    b, lane = wp.tid()
    i = b * wp.block_dim() + lane
    n = int(0)
    nc = int(0)
    if i < num_tiles_y * sp.tiles_x:
        ty = i // sp.tiles_x
        c = tile_guarantee(ty, i - ty * sp.tiles_x, ranks, sp, frame, sample, cache_hit)
        n = c[0]
        nc = c[1]
    tn = wp.tile_sum(wp.tile(n))
    tc = wp.tile_sum(wp.tile(nc))
    if lane == 0:
        wp.atomic_add(num_samples, 0, wp.int32(tn[0]))
        wp.atomic_add(num_cache_hits, 0, wp.int32(tc[0]))


@wp.kernel(enable_backward=False)
def tile_pass_bands_kernel(
    ranks: wp.array2d(dtype=wp.int32),
    sp: SamplingParams,
    frame: wp.array(dtype=FrameParams),
    sample: wp.array2d(dtype=wp.uint8),
    cache_hit: wp.array2d(dtype=wp.uint8),
    tile_counts: wp.array2d(dtype=wp.vec2i),
    row0: int,
):
    """``tile_pass_kernel`` for the CPU's band-parallel launches (``foveawarp.parallel``): thread (ty, tx) runs
    ``tile_guarantee`` on tile (ty, tx) and writes its (samples, cache hits) to ``tile_counts`` (no atomics);
    ``tile_counts_sum_kernel`` then adds them to the counters."""
    ty, tx = wp.tid()
    ty += row0  # band offset (foveawarp.parallel)
    tile_counts[ty, tx] = tile_guarantee(ty, tx, ranks, sp, frame, sample, cache_hit)


@wp.kernel(enable_backward=False)
def tile_counts_sum_kernel(tile_counts: wp.array2d(dtype=wp.vec2i), accumulate: int,
                           num_samples: wp.array(dtype=wp.int32), num_cache_hits: wp.array(dtype=wp.int32)):
    """One thread: the per-tile counts of ``tile_pass_bands_kernel`` (or the per-tile-row sums of
    ``sampling_rows_kernel``) summed into the counters, added to them (``accumulate`` != 0: equal to the tiled
    kernel's atomic adds) or written (0: no zeroing needed first). Integer sums."""
    n = int(0)
    nc = int(0)
    for ty in range(tile_counts.shape[0]):
        for tx in range(tile_counts.shape[1]):
            c = tile_counts[ty, tx]
            n += c[0]
            nc += c[1]
    if accumulate != 0:
        n += num_samples[0]
        nc += num_cache_hits[0]
    num_samples[0] = n
    num_cache_hits[0] = nc


def _make_sampling_pixel(rows: bool):
    """``sampling_map_pixel``: the fused per-pixel pass, for the pixel kernel (CUDA) or the CPU's rows kernel
    (``rows``: it also takes the row's plateau value ``p_row`` and skips the V term's square root where the term
    cannot raise the saliency, ``velocity_may_raise``; the same values, tests compare the two kernels)."""

    @wp.func
    def sampling_map_pixel(
        x: int,
        y: int,
        sp: SamplingParams,
        fp: FrameParams,
        ranks: wp.array2d(dtype=wp.int32),
        lab: wp.array2d(dtype=wp.vec3),
        normal: wp.array2d(dtype=wp.vec3),
        depth: wp.array2d(dtype=float),
        hit: wp.array2d(dtype=wp.uint8),
        position: wp.array2d(dtype=wp.vec3),
        reproj_uv: wp.array2d(dtype=wp.vec2),
        prev_dist: wp.array2d(dtype=float),
        depth_prev: wp.array2d(dtype=float),
        valid_prev: wp.array2d(dtype=wp.uint8),
        maps_only: int,
        face: wp.array2d(dtype=wp.int32),
        face_lab: wp.array(dtype=wp.vec3),
        lab_by_face: int,
        out_probability: wp.array2d(dtype=float),
        out_saliency: wp.array2d(dtype=float),
        out_sample: wp.array2d(dtype=wp.uint8),
        out_cache_hit: wp.array2d(dtype=wp.uint8),
        out_prev_index: wp.array2d(dtype=wp.int32),
        shift: int,
        p_row: float,
        flat: int,
    ):
        """The fused per-pixel pass at pixel (x, y) (``sampling_map_kernel`` documents it); ``shift``: the pixel's
        tile's ``tile_rank_shift``, or -1 (computed when the pixel needs it); ``p_row``: the pixel's eq. 2 probability
        when its row's plateau spans hold it (``row_plateau_spans``), or -1 (computed here); ``flat`` (the rows
        kernel; 0 elsewhere): bit 0 set when the face's 3x3 taps are all equal, bit 1 when the normal's are
        (``nine_equal_mask64_*``), whose gradients are then 0 without their per-pixel tests."""
        w = depth.shape[1]
        h = depth.shape[0]
        # (y, x) is a pixel: the unchecked loads and stores of kernels/load.py for the per-pixel values
        hit_px = load_u8(hit, y, x)
        uv = load_vec2(reproj_uv, y, x)
        p = float(1.0)
        s = float(1.0)
        if sp.foveation != 0:
            if wp.static(rows):
                if p_row >= 0.0:
                    p = p_row
                else:
                    p = pixel_probability(x, y, w, h, sp, fp)
            else:
                p = pixel_probability(x, y, w, h, sp, fp)
            s = p
            # thesis eq. 3: F = max(dA, dN, V, p) * F_DoF, each term normalized to [0, 1]; once the max is 1 the
            # remaining terms cannot change it (the fovea skips them). The terms' inputs are read as soon as p < 1
            # (not after the previous term), so their loads do not wait on each other; each term still enters
            # only while s < 1, as the equation has it.
            ga = float(0.0)
            gn = float(0.0)
            v = wp.vec2(0.0, 0.0)
            if p < 1.0:
                if sp.use_albedo != 0:
                    if lab_by_face != 0:
                        if (flat & 1) == 0:
                            ga = sobel_lab_by_face(face, face_lab, x, y)
                    else:
                        ga = sobel_vec3(lab, x, y)
                if sp.use_normal != 0 and (flat & 2) == 0:
                    gn = sobel_vec3(normal, x, y)
                if hit_px != wp.uint8(0) and fp.use_velocity != 0:
                    v = saliency_velocity(fp, position, y, x, uv, float(x) + 0.5, float(y) + 0.5)
            if sp.use_albedo != 0 and s < 1.0:
                s = wp.max(s, wp.min(sp.albedo_gain * ga, 1.0))
            if sp.use_normal != 0 and s < 1.0:
                s = wp.max(s, wp.min(sp.normal_gain * gn, 1.0))
            if hit_px != wp.uint8(0):
                if wp.static(rows):
                    if fp.use_velocity != 0 and s < 1.0 and velocity_may_raise(v, sp.inv_velocity_px, s) != 0:
                        s = wp.max(s, wp.min(wp.length(v) * sp.inv_velocity_px, 1.0))
                elif fp.use_velocity != 0 and s < 1.0:
                    s = wp.max(s, wp.min(wp.length(v) * sp.inv_velocity_px, 1.0))
                if fp.dof_on != 0:
                    s = s * dof_factor(load_f32(depth, y, x), fp.focus_m, sp.sigma1_m, sp.sigma2_m, sp.dof_floor)
            s = wp.clamp(s, fp.xi, 1.0)
            if nan_f32(s):  # a bit test (kernels/fpbits.py)
                s = 1.0
        if maps_only != 0:
            out_probability[y, x] = p
            out_saliency[y, x] = s
            return
        store_u8(out_sample, y, x, dither_sample_shifted(s, x, y, w, h, ranks, sp, fp.rot, fp.phase, shift))
        idx = int(-1)
        if fp.do_cache != 0:
            idx = cache_lookup(uv, load_f32(prev_dist, y, x), hit_px, load_f32(depth, y, x), depth_prev, valid_prev,
                               sp.depth_eps_rel)
        store_i32(out_prev_index, y, x, idx)
        store_u8(out_cache_hit, y, x, wp.where(idx >= 0, wp.uint8(1), wp.uint8(0)))

    return sampling_map_pixel


_sampling_pixel_rows = _make_sampling_pixel(True)


@wp.func
def sampling_tile_row(
    ty: int,
    sp: SamplingParams,
    frame: wp.array(dtype=FrameParams),
    ranks: wp.array2d(dtype=wp.int32),
    lab: wp.array2d(dtype=wp.vec3),
    normal: wp.array2d(dtype=wp.vec3),
    depth: wp.array2d(dtype=float),
    hit: wp.array2d(dtype=wp.uint8),
    position: wp.array2d(dtype=wp.vec3),
    reproj_uv: wp.array2d(dtype=wp.vec2),
    prev_dist: wp.array2d(dtype=float),
    depth_prev: wp.array2d(dtype=float),
    valid_prev: wp.array2d(dtype=wp.uint8),
    maps_only: int,
    face: wp.array2d(dtype=wp.int32),
    face_lab: wp.array(dtype=wp.vec3),
    lab_by_face: int,
    out_probability: wp.array2d(dtype=float),
    out_saliency: wp.array2d(dtype=float),
    out_sample: wp.array2d(dtype=wp.uint8),
    out_cache_hit: wp.array2d(dtype=wp.uint8),
    out_prev_index: wp.array2d(dtype=wp.int32),
    tile_counts: wp.array2d(dtype=wp.vec2i),
):
    """``sampling_rows_kernel``'s work for tile row ``ty`` (its ``block`` pixel rows, then the tile guarantee of its
    tiles and their counts into ``tile_counts[ty, 0]``): also run by the CPU's fused launch of the sampling pass with
    the masked shading and resolve (``kernels/temporal.py``)."""
    fp = frame[0]
    k = sp.block
    y1 = wp.min(ty * k + k, depth.shape[0])
    w = depth.shape[1]
    for y in range(ty * k, y1):
        # the row's eq. 2 plateaus are found once for the row (row_plateau_spans)
        spans = wp.vec4i(0, w - 1, 0, -1)
        if sp.foveation != 0:
            spans = row_plateau_spans(y, w, depth.shape[0], fp)
        # a tile's rank shift is computed once per row of it, as x enters the tile
        shift = int(0)
        tx = int(-1)
        next_tile = int(0)
        # the Sobel terms' nine-equal tests, 64 pixels at a time (nine_equal_mask64_*)
        want_face = sp.foveation != 0 and sp.use_albedo != 0 and lab_by_face != 0
        want_normal = sp.foveation != 0 and sp.use_normal != 0
        mf = wp.uint64(0)
        mn = wp.uint64(0)
        for x in range(w):
            if (x & 63) == 0:
                if want_face:
                    mf = nine_equal_mask64_i32(face, y, x)
                if want_normal:
                    mn = nine_equal_mask64_vec3(normal, y, x)
            if x == next_tile:
                tx += 1
                next_tile += k
                shift = tile_rank_shift(tx, ty, sp, fp.rot)
            flat = int(mf & wp.uint64(1)) | (int(mn & wp.uint64(1)) << 1)
            mf = mf >> wp.uint64(1)
            mn = mn >> wp.uint64(1)
            p_row = float(-1.0)
            if x < spans[0] or x > spans[1]:
                p_row = fp.xi
            elif x >= spans[2] and x <= spans[3]:
                p_row = 1.0
            _sampling_pixel_rows(x, y, sp, fp, ranks, lab, normal, depth, hit, position, reproj_uv, prev_dist,
                                 depth_prev, valid_prev, maps_only, face, face_lab, lab_by_face, out_probability,
                                 out_saliency, out_sample, out_cache_hit, out_prev_index, shift, p_row, flat)
    if maps_only == 0:
        c = wp.vec2i(0, 0)
        for tx in range(sp.tiles_x):
            c += tile_guarantee(ty, tx, ranks, sp, frame, out_sample, out_cache_hit)
        tile_counts[ty, 0] = c


def _make_sampling_map(rows: bool):
    """``sampling_map_kernel`` (a thread per pixel, CUDA) or ``sampling_rows_kernel`` (the CPU: a thread per row
    of ``block``-row tiles, launched over ``tiles_y`` in bands by ``foveawarp.parallel``, that runs the pixel pass
    over its rows and then ``tile_guarantee`` on its tiles, writing the sum of their (samples, cache hits) to
    ``tile_counts[ty, 0]`` ((tiles_y, 1) vec2i) for ``tile_counts_sum_kernel``: the map and the tile pass in one
    launch, with the same values as the two; the pixel kernel does not touch ``tile_counts``)."""

    sampling_map_pixel = _make_sampling_pixel(rows)

    # CUDA: no grid-stride loop and at most 48 registers per thread (sm_90: 64 uncapped, 72 with the grid-stride
    # loop; 48 still spills nothing): 5 blocks of 256 threads per SM instead of 3 (occupancy 62% instead of 37%)
    @wp.kernel(enable_backward=False, grid_stride=False, cuda_max_registers=48,
               name="sampling_rows_kernel" if rows else "sampling_map_kernel")
    def sampling_map(
        sp: SamplingParams,
        frame: wp.array(dtype=FrameParams),
        ranks: wp.array2d(dtype=wp.int32),
        lab: wp.array2d(dtype=wp.vec3),
        normal: wp.array2d(dtype=wp.vec3),
        depth: wp.array2d(dtype=float),
        hit: wp.array2d(dtype=wp.uint8),
        position: wp.array2d(dtype=wp.vec3),
        reproj_uv: wp.array2d(dtype=wp.vec2),
        prev_dist: wp.array2d(dtype=float),
        depth_prev: wp.array2d(dtype=float),
        valid_prev: wp.array2d(dtype=wp.uint8),
        maps_only: int,
        face: wp.array2d(dtype=wp.int32),
        face_lab: wp.array(dtype=wp.vec3),
        lab_by_face: int,
        out_probability: wp.array2d(dtype=float),
        out_saliency: wp.array2d(dtype=float),
        out_sample: wp.array2d(dtype=wp.uint8),
        out_cache_hit: wp.array2d(dtype=wp.uint8),
        out_prev_index: wp.array2d(dtype=wp.int32),
        tile_counts: wp.array2d(dtype=wp.vec2i),
        row0: int,
    ):
        """Fused per-pixel pass: eq. 2 probability, eq. 3 saliency, stratified threshold, eq. 4 cache test.

        ``maps_only`` 0 (the frame): writes ``out_sample``, ``out_cache_hit`` and ``out_prev_index`` only. 1: writes
        only ``out_probability`` and ``out_saliency``, the values the frame pass thresholds (the stage computes
        them on request: nothing in the frame reads them).

        ``lab`` is the CIE-Lab albedo from ``saliency.lab_kernel`` (any (H, W) vec3 array when use_albedo is 0);
        with ``lab_by_face`` != 0 the albedo gradient reads the G-buffer's ``face`` and the scene's per-face Lab
        table ``face_lab`` instead (``saliency.face_lab_kernel``: the same values, no prepass).
        Background pixels (hit == 0) have albedo 0 and normal 0 in the G-buffer; they take part in the gradient
        terms as such (so silhouettes are sampled on both sides) but get no velocity term and no DoF factor (a
        miss has no surface depth or motion).
        """
        if wp.static(rows):
            sampling_tile_row(wp.tid() + row0, sp, frame, ranks, lab, normal, depth, hit, position, reproj_uv,
                              prev_dist, depth_prev, valid_prev, maps_only, face, face_lab, lab_by_face,
                              out_probability, out_saliency, out_sample, out_cache_hit, out_prev_index, tile_counts)
        else:
            y, x = wp.tid()
            y += row0  # band offset (foveawarp.parallel)
            sampling_map_pixel(x, y, sp, frame[0], ranks, lab, normal, depth, hit, position, reproj_uv,
                               prev_dist, depth_prev, valid_prev, maps_only, face, face_lab, lab_by_face,
                               out_probability, out_saliency, out_sample, out_cache_hit, out_prev_index, -1, -1.0, 0)

    return sampling_map


sampling_map_kernel = _make_sampling_map(False)
sampling_rows_kernel = _make_sampling_map(True)
