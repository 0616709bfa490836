"""Temporal resolve (thesis A4): traced pixels blend into their reprojected history, unsampled pixels with a
cache hit reuse it, the rest stay empty (not seeds). History ages out after ``max_frames`` frames."""

import warp as wp

from .sampling import FrameParams


@wp.kernel(enable_backward=False)
def resolve_kernel(
    sample_map: wp.array2d(dtype=wp.uint8),
    cache_hit: wp.array2d(dtype=wp.uint8),
    prev_index: wp.array2d(dtype=wp.int32),
    fresh: wp.array2d(dtype=wp.vec3),
    hist_color_prev: wp.array(dtype=wp.vec3),
    hist_age_prev: wp.array(dtype=wp.int32),
    hist_stale_prev: wp.array(dtype=wp.int32),
    max_frames: int,
    use_history: int,
    out_color: wp.array2d(dtype=wp.vec3),
    out_filled: wp.array2d(dtype=wp.uint8),
    hist_color: wp.array(dtype=wp.vec3),
    hist_age: wp.array(dtype=wp.int32),
    hist_stale: wp.array(dtype=wp.int32),
):
    y, x = wp.tid()
    i = y * out_color.shape[1] + x
    pi = int(-1)
    if use_history != 0 and cache_hit[y, x] != wp.uint8(0):
        pi = prev_index[y, x]
        if pi >= 0:
            if hist_age_prev[pi] <= 0:
                pi = -1
    col = wp.vec3(0.0, 0.0, 0.0)
    age = int(0)
    stale = int(0)
    filled = wp.uint8(0)
    if sample_map[y, x] != wp.uint8(0):
        new = fresh[y, x]
        if pi >= 0:
            # running mean over at most max_frames values: converges on a static view (thesis A4)
            n = wp.min(hist_age_prev[pi], max_frames - 1)
            col = (hist_color_prev[pi] * float(n) + new) / float(n + 1)
            age = n + 1
        else:
            col = new
            age = 1
        filled = wp.uint8(1)
    elif pi >= 0:
        if hist_stale_prev[pi] + 1 < max_frames:
            col = hist_color_prev[pi]
            age = hist_age_prev[pi]
            stale = hist_stale_prev[pi] + 1
            filled = wp.uint8(1)
    out_color[y, x] = col
    out_filled[y, x] = filled
    hist_color[i] = col
    hist_age[i] = age
    hist_stale[i] = stale


@wp.func
def _frac(v: float) -> float:
    return v - wp.floor(v)


@wp.kernel(enable_backward=False)
def refresh_thin_kernel(
    cache_hit: wp.array2d(dtype=wp.uint8),
    prev_index: wp.array2d(dtype=wp.int32),
    hist_age_prev: wp.array(dtype=wp.int32),
    hist_stale_prev: wp.array(dtype=wp.int32),
    frame_params: wp.array(dtype=FrameParams),
    fraction: float,
    keep_stale: int,
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
    if hist_age_prev[pi] <= 0:
        return
    if hist_stale_prev[pi] >= keep_stale:
        return
    fp = frame_params[0]
    shift = _frac(float(fp.rot) * 0.6180339887 + fp.phase)
    h = _frac(_frac(float(x) * 0.7548776662) + _frac(float(y) * 0.5698402910) + shift)
    if h < fraction:
        return
    sample_map[y, x] = wp.uint8(0)
    wp.atomic_sub(num_samples, 0, 1)
