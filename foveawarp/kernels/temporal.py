"""Temporal resolve (thesis A4, with the rule of ``stages.temporal``): fresh values where this frame traced,
bilinear depth- and normal-validated history elsewhere, and an accumulated (neighbourhood-clamped) history of
the stochastic shading terms only. History ages out after ``max_frames`` frames without a refresh.

History per pixel (ping-pong, written by each resolve): the colour (also the frame's output), age and staleness
packed in one int32, the normal and (stochastic shading) the stochastic part where age > 0, the filled mask and
the G-buffer depth (also the next frame's cache test inputs)."""

import warp as wp

from .gbuffer import NO_REPROJ, reproj_velocity
from .load import (load1_i32, load1_vec3, load_f32, load_u8, load_vec2, load_vec3, store1_i32, store1_vec3,
                   store_f32, store_u8)
from .sampling import FrameParams, SamplingParams, sampling_tile_row
from .shade import AreaLightParams, LightParams, ShadeParams, list_pixel, shade_pixel

# bilinear fractions closer than this (pixels) to a pixel centre snap to it
SNAP_PX = wp.constant(1.0 / 128.0)


# history state per pixel, packed in one int32: age (frames accumulated, 0 = empty) in the low bits, staleness
# (frames reprojected without a refresh) above; both <= TemporalConfig.max_history_frames <= 1024
META_SHIFT = wp.constant(16)
META_AGE_MASK = wp.constant(0xFFFF)


@wp.struct
class TemporalParams:
    """Constants of the resolve (from ``TemporalConfig``) and the frame's switches."""

    max_frames: int  # history length: running mean over at most this many frames; stale limit
    use_history: int  # 0: first frame, cut, or history disabled
    depth_eps_rel: float  # a history tap's depth must match within this fraction of the current depth
    normal_cos_min: float  # ... and its normal within this cosine
    clamp_gamma: float  # variance clipping box half-width, in standard deviations
    box_radius: int  # the clipping box is over the (2 r + 1)^2 neighbourhood (a runtime value: CUDA does not
    # unroll the window loop, which took 106 registers per thread instead of 72 on sm_90)
    motion_alpha_per_px: float  # weight of the fresh stochastic value per pixel of screen motion
    min_age_reuse: int  # a moving unsampled pixel reuses stochastic history of at least this many accumulated frames
    # (the stochastic kernels; the deterministic one reuses any: TemporalStage.params sets 1 there)
    background: wp.vec3  # radiance of rays that miss


@wp.func
def pack_meta(age: int, stale: int) -> wp.int32:
    return wp.int32(age | (stale << META_SHIFT))


@wp.func
def meta_age(m: wp.int32) -> int:
    return int(m) & META_AGE_MASK


@wp.func
def meta_stale(m: wp.int32) -> int:
    return int(m) >> META_SHIFT


@wp.func
def bilinear_taps(uv: wp.vec2, w: int, h: int):
    """Top-left tap (x0, y0) and fractions (fx, fy) of the bilinear footprint of continuous pixel position uv
    (pixel centres at +0.5). Fractions within ``SNAP_PX`` of a pixel centre snap to it: a static view
    reprojects every pixel onto itself up to float rounding, and without the snap each frame would mix a
    1e-5 share of the neighbours into the history, a blur that compounds over frames."""
    u = uv[0] - 0.5
    v = uv[1] - 0.5
    x0 = int(wp.floor(u))
    y0 = int(wp.floor(v))
    fx = u - float(x0)
    fy = v - float(y0)
    if fx < SNAP_PX:
        fx = 0.0
    elif fx > 1.0 - SNAP_PX:
        fx = 1.0
    if fy < SNAP_PX:
        fy = 0.0
    elif fy > 1.0 - SNAP_PX:
        fy = 1.0
    return x0, y0, fx, fy


@wp.func
def tap_ok(tx: int, ty: int, w: int, h: int, dist_prev: float, n: wp.vec3, depth: float, tp: TemporalParams,
           depth_prev: wp.array2d(dtype=float), normal_prev: wp.array(dtype=wp.vec3),
           meta_prev: wp.array(dtype=wp.int32)) -> int:
    """1 when history tap (tx, ty) holds a colour of the same surface: on screen, non-empty history (age > 0,
    which implies it was filled last frame: the resolve writes age > 0 only together with filled = 1), the
    depth the point had there (``dist_prev``) within ``depth_eps_rel * depth``, the normal within
    ``normal_cos_min``."""
    if tx < 0 or ty < 0 or tx >= w or ty >= h:
        return 0
    i = ty * w + tx  # on screen: the unchecked loads (kernels/load.py)
    if meta_age(load1_i32(meta_prev, i)) <= 0:
        return 0
    if not (wp.abs(load_f32(depth_prev, ty, tx) - dist_prev) < tp.depth_eps_rel * depth):
        return 0
    if wp.dot(load1_vec3(normal_prev, i), n) < tp.normal_cos_min:
        return 0
    return 1


@wp.func
def pixel_velocity(reproj_uv: wp.array2d(dtype=wp.vec2), x: int, y: int) -> wp.vec2:
    """``GBuffer.velocity`` at pixel (x, y), its reprojection loaded again where the rule needs it: keeping the
    one loaded for the history taps live to the end cost the deterministic resolve its 32 registers (0.237 ->
    0.262 ms at 3840x2160 on bunny, H100)."""
    return reproj_velocity(load_vec2(reproj_uv, y, x), float(x) + 0.5, float(y) + 0.5)


@wp.func
def clip_to_box(h: wp.vec3, lo: wp.vec3, hi: wp.vec3) -> wp.vec3:
    """Clip h towards the box centre along the segment (variance clipping, Salvi 2016): the result lies in the
    box [lo, hi] and on the line from the centre to h."""
    c = (lo + hi) * 0.5
    e = (hi - lo) * 0.5
    d = h - c
    t = float(1.0)
    for k in range(3):
        a = wp.abs(d[k])
        if a > e[k]:
            t = wp.min(t, e[k] / a)
    return c + d * t


@wp.func
def neighbourhood_box(x: int, y: int, radius: int, sample_map: wp.array2d(dtype=wp.uint8),
                      hit: wp.array2d(dtype=wp.uint8), fresh_stoch: wp.array2d(dtype=wp.vec3), gamma: float):
    """Mean +- gamma * standard deviation of the fresh stochastic values traced this frame on surfaces within the
    (2 radius + 1)^2 window around (x, y), and how many there were."""
    w = sample_map.shape[1]
    h = sample_map.shape[0]
    m1 = wp.vec3(0.0, 0.0, 0.0)
    m2 = wp.vec3(0.0, 0.0, 0.0)
    cnt = int(0)
    for dy in range(-radius, radius + 1):
        yy = y + dy
        if yy >= 0 and yy < h:
            for dx in range(-radius, radius + 1):
                xx = x + dx
                if xx >= 0 and xx < w:
                    # inside the image: the unchecked loads (kernels/load.py)
                    if load_u8(sample_map, yy, xx) != wp.uint8(0) and load_u8(hit, yy, xx) != wp.uint8(0):
                        c = load_vec3(fresh_stoch, yy, xx)
                        m1 += c
                        m2 += wp.cw_mul(c, c)
                        cnt += 1
    mu = m1 / float(wp.max(cnt, 1))
    var = m2 / float(wp.max(cnt, 1)) - wp.cw_mul(mu, mu)
    sd = wp.vec3(wp.sqrt(wp.max(var[0], 0.0)), wp.sqrt(wp.max(var[1], 0.0)), wp.sqrt(wp.max(var[2], 0.0)))
    return mu - sd * gamma, mu + sd * gamma, cnt


def _make_resolve_kernels(stochastic: bool, boxed: bool = False):
    """The resolve, specialised at compile time on the shading kind (``stochastic``: the shading has Monte
    Carlo terms, ``fresh_stoch`` holds them). The deterministic kernel (the default shading) has no
    stochastic history, no neighbourhood box and no clipping, and computes the velocity only where the rule
    needs it; both kinds are this one body, so the rule stands once. Returns (pixel kernel, rows kernel,
    per-pixel func): a thread per pixel (CUDA), and a thread per row looping over its pixels (the CPU:
    ``parallel.launch_rows``).

    ``boxed`` (stochastic only): the clip box of each traced pixel is read from ``box_lo`` / ``box_hi``, where
    ``stoch_box_list_kernel`` wrote it over the list of traced pixels, instead of being gathered here (on CUDA
    the gather's 25 taps, run by the few traced threads of a warp, held every warp of the image: 0.40 of
    0.71 ms at 3840x2160 on cornell, H100); the same values, so the same result. Only the pixel kernel
    (rows kernel None). The other kinds never read ``box_lo`` / ``box_hi``.

    Outputs: ``out_color`` (flat) is both the frame's resolved colour and the colour history; ``out_filled``,
    ``out_depth`` (the G-buffer depth, kept as the next frame's previous depth); ``out_meta`` (age, stale);
    ``out_normal`` and ``out_stoch`` (flat) are written only where the history is non-empty (age > 0), the
    only place the next resolve reads them."""

    @wp.func
    def resolve_pixel(
        x: int,
        y: int,
        tp: TemporalParams,
        sample_map: wp.array2d(dtype=wp.uint8),
        hit: wp.array2d(dtype=wp.uint8),
        normal: wp.array2d(dtype=wp.vec3),
        depth: wp.array2d(dtype=float),
        reproj_uv: wp.array2d(dtype=wp.vec2),
        prev_dist: wp.array2d(dtype=float),
        moved: wp.array2d(dtype=wp.uint8),
        fresh: wp.array2d(dtype=wp.vec3),
        fresh_stoch: wp.array2d(dtype=wp.vec3),
        depth_prev: wp.array2d(dtype=float),
        normal_prev: wp.array(dtype=wp.vec3),
        meta_prev: wp.array(dtype=wp.int32),
        color_prev: wp.array(dtype=wp.vec3),
        stoch_prev: wp.array(dtype=wp.vec3),
        out_color: wp.array(dtype=wp.vec3),
        out_filled: wp.array2d(dtype=wp.uint8),
        out_depth: wp.array2d(dtype=float),
        out_normal: wp.array(dtype=wp.vec3),
        out_meta: wp.array(dtype=wp.int32),
        out_stoch: wp.array(dtype=wp.vec3),
        box_lo: wp.array2d(dtype=wp.vec3),
        box_hi: wp.array2d(dtype=wp.vec3),
    ):
        w = out_filled.shape[1]
        h = out_filled.shape[0]
        i = y * w + x
        zero = wp.vec3(0.0, 0.0, 0.0)
        # (y, x) is a pixel and i its flat index: the unchecked loads and stores of kernels/load.py
        d = load_f32(depth, y, x)
        store_f32(out_depth, y, x, d)
        # what this pixel shows and keeps: colour, stochastic part, age, staleness, filled (written once, below)
        n = zero
        col = zero
        st = zero
        age = int(0)
        stale = int(0)
        filled = wp.uint8(0)
        sampled = load_u8(sample_map, y, x) != wp.uint8(0)
        if load_u8(hit, y, x) == wp.uint8(0):
            # a miss shows the background: exact without tracing (the G-buffer's primary ray already missed)
            col = tp.background
            filled = wp.uint8(1)
        elif wp.static(not stochastic) and sampled:
            # deterministic shading: the fresh value is the answer; history would only add error
            n = load_vec3(normal, y, x)
            col = load_vec3(fresh, y, x)
            age = 1
            filled = wp.uint8(1)
        else:
            n = load_vec3(normal, y, x)
            # bilinear history at the reprojected position, each tap validated by depth and normal
            wsum = float(0.0)
            hc = zero
            hs = zero
            age_h = int(1 << 30)
            stale_h = int(0)
            uv = load_vec2(reproj_uv, y, x)
            if tp.use_history != 0 and uv[0] > 0.5 * NO_REPROJ and uv[1] > 0.5 * NO_REPROJ:
                x0, y0, fx, fy = bilinear_taps(uv, w, h)
                dp = load_f32(prev_dist, y, x)
                for k in range(4):
                    tx = x0 + (k & 1)
                    ty = y0 + (k >> 1)
                    wx = fx
                    if (k & 1) == 0:
                        wx = 1.0 - fx
                    wy = fy
                    if (k >> 1) == 0:
                        wy = 1.0 - fy
                    wt = wx * wy
                    if wt > 0.0:
                        if tap_ok(tx, ty, w, h, dp, n, d, tp, depth_prev, normal_prev, meta_prev) != 0:
                            j = ty * w + tx
                            mj = load1_i32(meta_prev, j)
                            wsum += wt
                            hc += load1_vec3(color_prev, j) * wt
                            if wp.static(stochastic):
                                hs += load1_vec3(stoch_prev, j) * wt
                            age_h = wp.min(age_h, meta_age(mj))
                            stale_h = wp.max(stale_h, meta_stale(mj))
            have = wsum > 1.0e-3
            if have:
                hc = hc / wsum
                if wp.static(stochastic):
                    hs = hs / wsum
            if sampled:
                # stochastic shading (the deterministic kernel took the branch above): fresh deterministic
                # part + accumulated, neighbourhood-clipped stochastic part
                col = load_vec3(fresh, y, x)
                age = 1
                if wp.static(stochastic):
                    st = load_vec3(fresh_stoch, y, x)
                    if have:
                        if wp.static(boxed):
                            lo = load_vec3(box_lo, y, x)
                            hi = load_vec3(box_hi, y, x)
                            if lo[0] <= hi[0]:  # an empty box: fewer than 3 traced neighbours, no clipping
                                hs = clip_to_box(hs, lo, hi)
                        else:
                            lo, hi, cnt = neighbourhood_box(x, y, tp.box_radius, sample_map, hit, fresh_stoch,
                                                             tp.clamp_gamma)
                            if cnt >= 3:
                                hs = clip_to_box(hs, lo, hi)
                        m = wp.min(age_h, tp.max_frames - 1)
                        alpha = 1.0 / float(m + 1)
                        speed = wp.length(pixel_velocity(reproj_uv, x, y))
                        alpha = wp.max(alpha, wp.min(speed * tp.motion_alpha_per_px, 1.0))
                        alpha = wp.max(alpha, 1.0 - wsum)  # partly disoccluded footprint: trust the fresh value more
                        s_acc = hs + (st - hs) * alpha
                        col = col - st + s_acc
                        st = s_acc
                        age = m + 1
                filled = wp.uint8(1)
            elif have:
                if load_u8(moved, y, x) == wp.uint8(0):
                    # the minimum age binds only stochastic history (deterministic: any accepted tap has age >= 1)
                    young_ok = True
                    if wp.static(stochastic):
                        young_ok = age_h >= tp.min_age_reuse
                        if not young_ok:
                            # still (screen motion <= half a pixel): computed only where the rule depends on it
                            young_ok = wp.length(pixel_velocity(reproj_uv, x, y)) <= 0.5
                    if stale_h + 1 < tp.max_frames and young_ok:
                        col = hc
                        st = hs
                        age = age_h
                        stale = stale_h + 1
                        filled = wp.uint8(1)
        store1_vec3(out_color, i, col)
        store_u8(out_filled, y, x, filled)
        store1_i32(out_meta, i, pack_meta(age, stale))
        if age > 0:
            store1_vec3(out_normal, i, n)
            if wp.static(stochastic):
                store1_vec3(out_stoch, i, st)


    # CUDA: no grid-stride loop (sm_90 registers per thread: deterministic 32, full occupancy; stochastic 72
    # uncapped, 48 with the cap below (80 B spilled), boxed 40; the single kernel this replaces used 136, so an SM
    # held one block of 256 threads)
    def make(rows: bool):
        kind = ("resolve_stoch_boxed" if boxed else "resolve_stoch") if stochastic else "resolve"

        # the stochastic kinds at most 48 registers per thread on CUDA (H100, 3840x2160, 8 AO rays: the gathering
        # kernel 0.71 -> 0.58 ms on cornell, 1.02 -> 0.83 ms on city, same values; no change on the boxed one)
        @wp.kernel(enable_backward=False, name=f"{kind}_rows_kernel" if rows else f"{kind}_kernel", grid_stride=False,
                   cuda_max_registers=48 if stochastic else None)
        def resolve(
            tp: TemporalParams,
            sample_map: wp.array2d(dtype=wp.uint8),
            hit: wp.array2d(dtype=wp.uint8),
            normal: wp.array2d(dtype=wp.vec3),
            depth: wp.array2d(dtype=float),
            reproj_uv: wp.array2d(dtype=wp.vec2),
            prev_dist: wp.array2d(dtype=float),
            moved: wp.array2d(dtype=wp.uint8),
            fresh: wp.array2d(dtype=wp.vec3),
            fresh_stoch: wp.array2d(dtype=wp.vec3),
            depth_prev: wp.array2d(dtype=float),
            normal_prev: wp.array(dtype=wp.vec3),
            meta_prev: wp.array(dtype=wp.int32),
            color_prev: wp.array(dtype=wp.vec3),
            stoch_prev: wp.array(dtype=wp.vec3),
            out_color: wp.array(dtype=wp.vec3),
            out_filled: wp.array2d(dtype=wp.uint8),
            out_depth: wp.array2d(dtype=float),
            out_normal: wp.array(dtype=wp.vec3),
            out_meta: wp.array(dtype=wp.int32),
            out_stoch: wp.array(dtype=wp.vec3),
            box_lo: wp.array2d(dtype=wp.vec3),
            box_hi: wp.array2d(dtype=wp.vec3),
            row0: int,
        ):
            if wp.static(rows):
                y = wp.tid() + row0  # band offset (foveawarp.parallel)
                for x in range(out_filled.shape[1]):
                    resolve_pixel(x, y, tp, sample_map, hit, normal, depth, reproj_uv, prev_dist, moved,
                                  fresh, fresh_stoch, depth_prev, normal_prev, meta_prev, color_prev, stoch_prev,
                                  out_color, out_filled, out_depth, out_normal, out_meta, out_stoch, box_lo, box_hi)
            else:
                y, x = wp.tid()
                y += row0  # band offset (foveawarp.parallel)
                resolve_pixel(x, y, tp, sample_map, hit, normal, depth, reproj_uv, prev_dist, moved, fresh,
                              fresh_stoch, depth_prev, normal_prev, meta_prev, color_prev, stoch_prev, out_color,
                              out_filled, out_depth, out_normal, out_meta, out_stoch, box_lo, box_hi)

        return resolve

    return make(False), None if boxed else make(True), resolve_pixel


resolve_kernel, resolve_rows_kernel, _resolve_pixel = _make_resolve_kernels(False)
resolve_stoch_kernel, resolve_stoch_rows_kernel, _ = _make_resolve_kernels(True)
resolve_stoch_boxed_kernel, _, _ = _make_resolve_kernels(True, boxed=True)


@wp.kernel(enable_backward=False)
def misses_seen_kernel(hit: wp.array2d(dtype=wp.uint8), seen: wp.array2d(dtype=wp.vec3),
                       color: wp.array2d(dtype=wp.vec3), row0: int):
    """Each miss's colour: what the G-buffer's primary ray saw past the scene (``seen``, a textured scene's
    G-buffer ``emission``: its environment along the pixel-centre ray), exact without tracing."""
    y, x = wp.tid()
    y += row0  # band offset (foveawarp.parallel)
    if hit[y, x] == wp.uint8(0):
        color[y, x] = seen[y, x]


@wp.kernel(enable_backward=False)
def stoch_box_list_kernel(
    tp: TemporalParams,
    work: wp.array(dtype=wp.int32),
    count: wp.array(dtype=wp.int32),
    width: int,
    sample_map: wp.array2d(dtype=wp.uint8),
    hit: wp.array2d(dtype=wp.uint8),
    fresh_stoch: wp.array2d(dtype=wp.vec3),
    box_lo: wp.array2d(dtype=wp.vec3),
    box_hi: wp.array2d(dtype=wp.vec3),
):
    """The variance clipping box (``neighbourhood_box``) of each traced surface pixel of the flat list
    ``work[0:count[0]]`` (pixel indices y * width + x), written at the pixel to ``box_lo`` / ``box_hi`` for
    ``resolve_stoch_boxed_kernel``; fewer than 3 traced neighbours: an empty box (lo = 1 > hi = 0), which the
    resolve reads as no clipping. A thread per traced pixel, so a warp's threads all gather."""
    i = wp.tid()
    if i >= count[0]:
        return
    x, y = list_pixel(work[i], width)
    if hit[y, x] == wp.uint8(0):
        return  # a miss is the background: the resolve reads no box there
    lo, hi, cnt = neighbourhood_box(x, y, tp.box_radius, sample_map, hit, fresh_stoch, tp.clamp_gamma)
    if cnt < 3:
        lo = wp.vec3(1.0, 1.0, 1.0)
        hi = wp.vec3(0.0, 0.0, 0.0)
    box_lo[y, x] = lo
    box_hi[y, x] = hi


@wp.func
def shade_resolve_row(
    y: int,
    sp: ShadeParams,
    pos: wp.array2d(dtype=wp.vec3),
    face_albedo: wp.array(dtype=wp.vec3),
    face: wp.array2d(dtype=wp.int32),
    lights: wp.array(dtype=LightParams),
    area_lights: wp.array(dtype=AreaLightParams),
    face_emission: wp.array(dtype=wp.vec3),
    tp: TemporalParams,
    sample_map: wp.array2d(dtype=wp.uint8),
    hit: wp.array2d(dtype=wp.uint8),
    normal: wp.array2d(dtype=wp.vec3),
    depth: wp.array2d(dtype=float),
    reproj_uv: wp.array2d(dtype=wp.vec2),
    prev_dist: wp.array2d(dtype=float),
    moved: wp.array2d(dtype=wp.uint8),
    fresh: wp.array2d(dtype=wp.vec3),
    fresh_stoch: wp.array2d(dtype=wp.vec3),
    depth_prev: wp.array2d(dtype=float),
    normal_prev: wp.array(dtype=wp.vec3),
    meta_prev: wp.array(dtype=wp.int32),
    color_prev: wp.array(dtype=wp.vec3),
    stoch_prev: wp.array(dtype=wp.vec3),
    out_color: wp.array(dtype=wp.vec3),
    out_filled: wp.array2d(dtype=wp.uint8),
    out_depth: wp.array2d(dtype=float),
    out_normal: wp.array(dtype=wp.vec3),
    out_meta: wp.array(dtype=wp.int32),
    out_stoch: wp.array(dtype=wp.vec3),
):
    """Row ``y`` of ``shade_resolve_rows_kernel``: each sampled pixel shaded into ``fresh`` / ``fresh_stoch``, then
    every pixel resolved. A pixel's resolve reads its own sample flag and fresh value only."""
    for x in range(out_filled.shape[1]):
        if sample_map[y, x] != wp.uint8(0):
            shade_pixel(sp, x, y, pos, normal, face_albedo, face, hit, lights, area_lights, face_emission, fresh,
                        fresh_stoch)
        _resolve_pixel(x, y, tp, sample_map, hit, normal, depth, reproj_uv, prev_dist, moved, fresh,
                       fresh_stoch, depth_prev, normal_prev, meta_prev, color_prev, stoch_prev, out_color,
                       out_filled, out_depth, out_normal, out_meta, out_stoch, fresh, fresh)


# a module of its own: only the CPU launches it, so CUDA never compiles it (in the temporal module it cost every CUDA
# build of that module an sm_90 kernel of 232 registers)
@wp.kernel(enable_backward=False, module="unique")
def shade_resolve_rows_kernel(
    spa: wp.array(dtype=ShadeParams),
    pos: wp.array2d(dtype=wp.vec3),
    face_albedo: wp.array(dtype=wp.vec3),
    face: wp.array2d(dtype=wp.int32),
    lights: wp.array(dtype=LightParams),
    area_lights: wp.array(dtype=AreaLightParams),
    face_emission: wp.array(dtype=wp.vec3),
    tp: TemporalParams,
    sample_map: wp.array2d(dtype=wp.uint8),
    hit: wp.array2d(dtype=wp.uint8),
    normal: wp.array2d(dtype=wp.vec3),
    depth: wp.array2d(dtype=float),
    reproj_uv: wp.array2d(dtype=wp.vec2),
    prev_dist: wp.array2d(dtype=float),
    moved: wp.array2d(dtype=wp.uint8),
    fresh: wp.array2d(dtype=wp.vec3),
    fresh_stoch: wp.array2d(dtype=wp.vec3),
    depth_prev: wp.array2d(dtype=float),
    normal_prev: wp.array(dtype=wp.vec3),
    meta_prev: wp.array(dtype=wp.int32),
    color_prev: wp.array(dtype=wp.vec3),
    stoch_prev: wp.array(dtype=wp.vec3),
    out_color: wp.array(dtype=wp.vec3),
    out_filled: wp.array2d(dtype=wp.uint8),
    out_depth: wp.array2d(dtype=float),
    out_normal: wp.array(dtype=wp.vec3),
    out_meta: wp.array(dtype=wp.int32),
    out_stoch: wp.array(dtype=wp.vec3),
    row0: int,
):
    """The CPU's masked shading and deterministic resolve of one row in one launch (a thread per row, in bands:
    ``parallel.launch``): each sampled pixel is shaded into ``fresh`` / ``fresh_stoch`` (``shade_pixel``, as
    ``shade_masked_rows_kernel`` does), then every pixel of the row is resolved (``resolve_rows_kernel``). The
    deterministic resolve reads ``fresh`` at its own pixel only, so each pixel's inputs are final when it is
    resolved, and the values are those of the two launches (tests compare whole frames)."""
    shade_resolve_row(wp.tid() + row0, spa[0], pos, face_albedo, face, lights, area_lights, face_emission, tp,
                      sample_map, hit, normal, depth, reproj_uv, prev_dist, moved, fresh, fresh_stoch, depth_prev,
                      normal_prev, meta_prev, color_prev, stoch_prev, out_color, out_filled, out_depth, out_normal,
                      out_meta, out_stoch)


# the CPU's sampling pass, masked shading and deterministic resolve in one launch over rows of tiles (a module of its
# own, like the kernel above: CUDA never builds it)
@wp.kernel(enable_backward=False, module="unique")
def sample_shade_resolve_rows_kernel(
    s_params: SamplingParams,
    s_frame: wp.array(dtype=FrameParams),
    s_ranks: wp.array2d(dtype=wp.int32),
    s_lab: wp.array2d(dtype=wp.vec3),
    s_position: wp.array2d(dtype=wp.vec3),
    s_depth_prev: wp.array2d(dtype=float),
    s_valid_prev: wp.array2d(dtype=wp.uint8),
    s_face_lab: wp.array(dtype=wp.vec3),
    s_lab_by_face: int,
    s_dummy: wp.array2d(dtype=float),
    s_cache_hit: wp.array2d(dtype=wp.uint8),
    s_prev_index: wp.array2d(dtype=wp.int32),
    s_tile_counts: wp.array2d(dtype=wp.vec2i),
    spa: wp.array(dtype=ShadeParams),
    pos: wp.array2d(dtype=wp.vec3),
    face_albedo: wp.array(dtype=wp.vec3),
    face: wp.array2d(dtype=wp.int32),
    lights: wp.array(dtype=LightParams),
    area_lights: wp.array(dtype=AreaLightParams),
    face_emission: wp.array(dtype=wp.vec3),
    tp: TemporalParams,
    sample_map: wp.array2d(dtype=wp.uint8),
    hit: wp.array2d(dtype=wp.uint8),
    normal: wp.array2d(dtype=wp.vec3),
    depth: wp.array2d(dtype=float),
    reproj_uv: wp.array2d(dtype=wp.vec2),
    prev_dist: wp.array2d(dtype=float),
    moved: wp.array2d(dtype=wp.uint8),
    fresh: wp.array2d(dtype=wp.vec3),
    fresh_stoch: wp.array2d(dtype=wp.vec3),
    depth_prev: wp.array2d(dtype=float),
    normal_prev: wp.array(dtype=wp.vec3),
    meta_prev: wp.array(dtype=wp.int32),
    color_prev: wp.array(dtype=wp.vec3),
    stoch_prev: wp.array(dtype=wp.vec3),
    out_color: wp.array(dtype=wp.vec3),
    out_filled: wp.array2d(dtype=wp.uint8),
    out_depth: wp.array2d(dtype=float),
    out_normal: wp.array(dtype=wp.vec3),
    out_meta: wp.array(dtype=wp.int32),
    out_stoch: wp.array(dtype=wp.vec3),
    row0: int,
):
    """Tile row ``wp.tid() + row0``: ``sampling_rows_kernel``'s frame pass (``sampling_tile_row``: the sample map,
    cache test and tile guarantee of its ``block`` rows, writing ``sample_map``) and then
    ``shade_resolve_rows_kernel``'s work on the same rows, which read only their own pixels' sample flags: the
    values of the two launches, without the second pass over the rows (its G-buffer reads then find the rows in
    this core's cache) or the wait between the launches. The sampling pass reads ``s_depth_prev`` /
    ``s_valid_prev`` (the history the resolve reads, which it does not write) and the G-buffer; ``s_*`` are its
    arguments that the resolve does not share."""
    ty = wp.tid() + row0  # band offset (foveawarp.parallel)
    sampling_tile_row(ty, s_params, s_frame, s_ranks, s_lab, normal, depth, hit, s_position, reproj_uv, prev_dist,
                      s_depth_prev, s_valid_prev, 0, face, s_face_lab, s_lab_by_face, s_dummy, s_dummy, sample_map,
                      s_cache_hit, s_prev_index, s_tile_counts)
    sp = spa[0]
    k = s_params.block
    for y in range(ty * k, wp.min(ty * k + k, out_filled.shape[0])):
        shade_resolve_row(y, sp, pos, face_albedo, face, lights, area_lights, face_emission, tp, sample_map, hit,
                          normal, depth, reproj_uv, prev_dist, moved, fresh, fresh_stoch, depth_prev, normal_prev,
                          meta_prev, color_prev, stoch_prev, out_color, out_filled, out_depth, out_normal, out_meta,
                          out_stoch)


@wp.func
def _frac(v: float) -> float:
    return v - wp.floor(v)


@wp.kernel(enable_backward=False)
def refresh_thin_kernel(
    cache_hit: wp.array2d(dtype=wp.uint8),
    prev_index: wp.array2d(dtype=wp.int32),
    meta_prev: wp.array(dtype=wp.int32),
    frame_params: wp.array(dtype=FrameParams),
    fraction: float,
    keep_stale: int,
    keep_young: int,
    sample_map: wp.array2d(dtype=wp.uint8),
    num_samples: wp.array(dtype=wp.int32),
):
    """Refresh budget for a static view with converged history: of this frame's samples, keep only those
    without usable history (no cache hit, empty history, or history ``keep_stale`` frames or more
    unrefreshed) and a ``fraction`` of the rest, picked by a per-frame shifted R2 low-discrepancy pattern
    (spread evenly over the image, every pixel in turn). Dropped samples reuse their history instead."""
    y, x = wp.tid()
    if sample_map[y, x] == wp.uint8(0):
        return
    if cache_hit[y, x] == wp.uint8(0):
        return
    pi = prev_index[y, x]
    if pi < 0:
        return
    m = meta_prev[pi]
    if meta_age(m) <= 0:
        return
    if meta_stale(m) >= keep_stale:
        return
    if meta_age(m) < keep_young:  # stochastic shading: still converging
        return
    fp = frame_params[0]
    shift = _frac(float(fp.rot) * 0.6180339887 + fp.phase)
    h = _frac(_frac(float(x) * 0.7548776662) + _frac(float(y) * 0.5698402910) + shift)
    if h < fraction:
        return
    sample_map[y, x] = wp.uint8(0)
    wp.atomic_sub(num_samples, 0, 1)
