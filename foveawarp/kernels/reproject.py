"""Reprojection cache test (thesis eq. 4, after Nehab et al. 2007; ALGORITHMS.md A2.6).

A pixel's history is reusable (a cache hit) when all of these hold:
    * the current pixel hit a surface (``hit != 0``);
    * its previous-frame pixel position ``uv_prev`` (the G-buffer's ``reproj_uv``, continuous pixels, centre
      of pixel (x, y) at (x + 0.5, y + 0.5)) lies on screen: ``0 <= u < width`` and ``0 <= v < height``;
    * the previous pixel, looked up by nearest pixel ``(floor(u), floor(v))``, held a valid color;
    * ``|depth_prev(uv_prev) - dist_prev| < depth_eps_rel * depth`` (the absolute value, as clarified in
      ALGORITHMS.md; ``depth`` is the current distance from the eye, metres, so the tolerance scales with
      distance like the depth precision of the G-buffer). ``dist_prev`` is the surface point's distance from
      the previous eye: thesis eq. 4 writes ``|pos - eye_prev|`` (the current position), which is right for
      static geometry; for a moving object the frame loop passes the G-buffer's ``prev_dist``, the distance of
      the same point at the object's previous transform, so moving objects keep their history.
"""

import warp as wp

from .load import load_f32, load_u8


@wp.func
def cache_lookup(
    uv: wp.vec2,
    dist_prev: float,
    hit: wp.uint8,
    depth: float,
    depth_prev: wp.array2d(dtype=float),
    valid_prev: wp.array2d(dtype=wp.uint8),
    eps_rel: float,
) -> int:
    """Flat index ``iy * width + ix`` of the previous pixel on a cache hit, -1 on a miss."""
    h = depth_prev.shape[0]
    w = depth_prev.shape[1]
    # the previous pixel's values are loaded before the tests, so the two loads do not wait on each other:
    # at uv clamped to the screen (in bounds for any uv, NaN and infinities included; on screen the same pixel)
    u = wp.min(uv[0], float(w - 1))
    if not (u >= 0.0):
        u = 0.0
    v = wp.min(uv[1], float(h - 1))
    if not (v >= 0.0):
        v = 0.0
    ix = int(wp.floor(u))
    iy = int(wp.floor(v))
    valid = load_u8(valid_prev, iy, ix)  # clamped on screen: the unchecked loads (kernels/load.py)
    dprev = load_f32(depth_prev, iy, ix)
    if hit == wp.uint8(0):
        return -1
    # written so that NaN coordinates fail too
    if not (uv[0] >= 0.0 and uv[0] < float(w) and uv[1] >= 0.0 and uv[1] < float(h)):
        return -1
    if valid == wp.uint8(0):
        return -1
    x = dprev - dist_prev  # thesis eq. 4
    if wp.abs(x) < eps_rel * depth:
        return iy * w + ix
    return -1


@wp.kernel(enable_backward=False)
def cache_test_kernel(
    reproj_uv: wp.array2d(dtype=wp.vec2),
    position: wp.array2d(dtype=wp.vec3),
    hit: wp.array2d(dtype=wp.uint8),
    depth: wp.array2d(dtype=float),
    depth_prev: wp.array2d(dtype=float),
    valid_prev: wp.array2d(dtype=wp.uint8),
    eye_prev: wp.vec3,
    eps_rel: float,
    out_hit: wp.array2d(dtype=wp.uint8),
    out_prev_index: wp.array2d(dtype=wp.int32),
    row0: int,
):
    y, x = wp.tid()
    y += row0  # band offset (foveawarp.parallel)
    idx = cache_lookup(reproj_uv[y, x], wp.length(position[y, x] - eye_prev), hit[y, x], depth[y, x], depth_prev,
                       valid_prev, eps_rel)
    out_prev_index[y, x] = wp.int32(idx)
    if idx >= 0:
        out_hit[y, x] = wp.uint8(1)
    else:
        out_hit[y, x] = wp.uint8(0)
