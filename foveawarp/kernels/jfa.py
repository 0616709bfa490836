"""Jump Flooding (Rong & Tan 2006) over a seed mask: the nearest seed of every pixel (ALGORITHMS.md A5).

Buffers hold ``wp.vec2i(x, y)`` of the nearest seed found so far, ``(-1, -1)`` for none. Distances are
Euclidean between pixel centres, compared as exact squared integers. One pass reads 9 pixels at offsets
``{-k, 0, k}^2`` and keeps the nearest seed seen; a candidate replaces the current one only when strictly
nearer, so the result is deterministic and a seed always keeps itself.
"""

import warp as wp

NO_SEED = wp.constant(-1)


@wp.func
def seed_dist2(x: int, y: int, s: wp.vec2i) -> int:
    """Squared distance in pixels^2 from pixel (x, y) to seed ``s`` (int32: exact up to 16384^2 * 2)."""
    dx = s[0] - x
    dy = s[1] - y
    return dx * dx + dy * dy


@wp.kernel(enable_backward=False)
def jfa_init_kernel(seed_mask: wp.array2d(dtype=wp.uint8), nearest: wp.array2d(dtype=wp.vec2i)):
    """Seeds point at themselves, every other pixel at (-1, -1)."""
    y, x = wp.tid()
    if seed_mask[y, x] != wp.uint8(0):
        nearest[y, x] = wp.vec2i(x, y)
    else:
        nearest[y, x] = wp.vec2i(NO_SEED, NO_SEED)


@wp.kernel(enable_backward=False)
def jfa_step_kernel(src: wp.array2d(dtype=wp.vec2i), step: int, dst: wp.array2d(dtype=wp.vec2i)):
    """One jump-flooding pass with step ``step`` pixels (>= 1): ``dst`` = nearest of the 9 candidates."""
    y, x = wp.tid()
    h = src.shape[0]
    w = src.shape[1]
    best = src[y, x]
    best_d = int(2147483647)
    if best[0] >= 0:
        best_d = seed_dist2(x, y, best)
    for j in range(3):
        yy = y + (j - 1) * step
        if yy >= 0 and yy < h:
            for i in range(3):
                xx = x + (i - 1) * step
                if xx >= 0 and xx < w and (i != 1 or j != 1):
                    s = src[yy, xx]
                    if s[0] >= 0:
                        d = seed_dist2(x, y, s)
                        if d < best_d:
                            best_d = d
                            best = s
    dst[y, x] = best
