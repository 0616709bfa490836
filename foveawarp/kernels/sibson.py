"""Discrete natural-neighbour (Sibson) interpolation of seed colors (ALGORITHMS.md A6).

Discrete Sibson (Park et al. 2006): every pixel q scatters the color of its nearest seed to every pixel p
with ``|p - q| <= r_q`` (``r_q`` = distance from q to its nearest seed, pixels); p averages what it got.
Two forms of the same sum:

* ``sibson_gather_kernel``: the bounded gather of the thesis (Code 4), q in ``[p - J, p + J]^2``. It equals
  the scatter exactly once ``J >= max r_q``; the loop never goes past ``floor(max r_q)`` either, because no
  farther q can reach p.
* ``sibson_scatter_kernel`` + ``sibson_resolve_kernel``: Park's scatter with atomics (the exact reference).

Both read the Voronoi buffers written by ``voronoi_finalize_kernel``: per pixel q, ``vor_color`` (the finite
color of q's nearest seed; 0 where q has none) and ``vor_r2`` = ``r_q^2`` in pixels^2 (exact int32; 0 exactly
at seeds; -1 where q has no seed). The gather reads the 4-byte r2 at every tap and the color only at the taps
that cover p. Seeds always output their own color; pixels that received nothing output their Voronoi color
(0 without a seed); a sum that overflows float32 (colors near float max) is redone with scaled terms, so no
output is NaN/Inf.
"""

import warp as wp

from .jfa import seed_dist2


@wp.func
def isqrt(n: int) -> int:
    """floor(sqrt(n)); 0 for n <= 0. Exact for n < 46340^2, which covers every squared distance of a
    16384 x 16384 image ((r + 1)^2 would overflow int32 above)."""
    if n <= 0:
        return 0
    r = int(wp.sqrt(float(n)))
    while r * r > n:
        r = r - 1
    while (r + 1) * (r + 1) <= n:
        r = r + 1
    return r


@wp.func
def finite_or_zero(c: wp.vec3) -> wp.vec3:
    if wp.isfinite(c[0]) and wp.isfinite(c[1]) and wp.isfinite(c[2]):
        return c
    return wp.vec3(0.0, 0.0, 0.0)


@wp.kernel(enable_backward=False)
def voronoi_finalize_kernel(
    nearest: wp.array2d(dtype=wp.vec2i),
    color_in: wp.array2d(dtype=wp.vec3),
    write_out: int,
    vor_color: wp.array2d(dtype=wp.vec3),
    vor_r2: wp.array2d(dtype=wp.int32),
    color_out: wp.array2d(dtype=wp.vec3),
    max_r2: wp.array(dtype=wp.int32),
    max_radius: wp.array(dtype=wp.float32),
    unreached: wp.array(dtype=wp.int32),
):
    """Tiled launch over the flattened image (any block size; 1 on the CPU).

    Writes ``vor_color`` / ``vor_r2`` (and the Voronoi color to ``color_out`` when ``write_out`` != 0), and
    reduces per block the largest r2 (into ``max_r2`` / ``max_radius``, pixels^2 / pixels) and the count of
    pixels without a seed (into ``unreached``). The three statistics must be zeroed before the launch.
    """
    blk, lane = wp.tid()
    h = nearest.shape[0]
    w = nearest.shape[1]
    idx = blk * wp.block_dim() + lane
    r2 = int(0)
    missing = int(0)
    if idx < h * w:
        y = idx // w
        x = idx - y * w
        s = nearest[y, x]
        c = wp.vec3(0.0, 0.0, 0.0)
        r2w = int(-1)
        if s[0] >= 0:
            c = finite_or_zero(color_in[s[1], s[0]])
            r2 = seed_dist2(x, y, s)
            r2w = r2
        else:
            missing = 1
        vor_color[y, x] = c
        vor_r2[y, x] = r2w
        if write_out != 0:
            color_out[y, x] = c
    # cooperative block reductions: every thread of the block reaches them
    tmax = wp.tile_max(wp.tile(r2))
    tmiss = wp.tile_sum(wp.tile(missing))
    if lane == 0:
        m = tmax[0]
        if m > 0:
            wp.atomic_max(max_r2, 0, m)
            wp.atomic_max(max_radius, 0, wp.sqrt(float(m)))
        if tmiss[0] > 0:
            wp.atomic_add(unreached, 0, tmiss[0])


# largest finite float32: the overflow-safe mean clamps to it (a mean of finite values is finite)
F32_MAX = wp.constant(3.4028234663852886e38)


@wp.func
def disc_sum(vor_color: wp.array2d(dtype=wp.vec3), vor_r2: wp.array2d(dtype=wp.int32), x: int, y: int, rw: int,
             rmax2: int, scale: float) -> wp.vec4:
    """(sum of ``scale * vor_color[q]``, count) over the q within the half window ``rw`` whose disc covers
    p = (x, y) (``|p - q|^2 <= r_q^2``; offsets also clipped to ``rmax2`` >= every r_q^2)."""
    h = vor_r2.shape[0]
    w = vor_r2.shape[1]
    y0 = wp.max(-rw, -y)
    y1 = wp.min(rw, h - 1 - y)
    acc = wp.vec3(0.0, 0.0, 0.0)
    n = int(0)
    for dy in range(y0, y1 + 1):
        dxm = wp.min(rw, isqrt(rmax2 - dy * dy))
        x0 = wp.max(-dxm, -x)
        x1 = wp.min(dxm, w - 1 - x)
        for dx in range(x0, x1 + 1):
            if dx * dx + dy * dy <= vor_r2[y + dy, x + dx]:
                acc = acc + vor_color[y + dy, x + dx] * scale
                n = n + 1
    return wp.vec4(acc[0], acc[1], acc[2], float(n))


@wp.func
def disc_mean(vor_color: wp.array2d(dtype=wp.vec3), vor_r2: wp.array2d(dtype=wp.int32), x: int, y: int, rw: int,
              rmax2: int) -> wp.vec3:
    """Mean of the colors q scatters onto p (see :func:`disc_sum`); the Voronoi color when none does.

    Finite for any finite colors: when the plain float32 sum overflows (colors near float max), the sum is
    taken again with every term scaled by 0.5 / n, then doubled and clamped to +-float max."""
    s = disc_sum(vor_color, vor_r2, x, y, rw, rmax2, 1.0)
    n = s[3]
    if n <= 0.0:
        return vor_color[y, x]
    out = wp.vec3(s[0], s[1], s[2]) / n
    if wp.isfinite(out):
        return out
    t = disc_sum(vor_color, vor_r2, x, y, rw, rmax2, 0.5 / n)
    return wp.vec3(wp.clamp(2.0 * t[0], -F32_MAX, F32_MAX), wp.clamp(2.0 * t[1], -F32_MAX, F32_MAX),
                   wp.clamp(2.0 * t[2], -F32_MAX, F32_MAX))


@wp.kernel(enable_backward=False)
def sibson_gather_kernel(
    vor_color: wp.array2d(dtype=wp.vec3),
    vor_r2: wp.array2d(dtype=wp.int32),
    window: int,
    max_r2: wp.array(dtype=wp.int32),
    color_out: wp.array2d(dtype=wp.vec3),
):
    """Bounded Sibson gather (thesis Code 4) with half window ``window`` = J >= 0 pixels."""
    y, x = wp.tid()
    if vor_r2[y, x] == 0:  # a seed keeps its color
        color_out[y, x] = vor_color[y, x]
        return
    # q reaches p only if |p - q|^2 <= r_q^2 <= max_r2: clip the window to that disc
    rmax2 = max_r2[0]
    rw = wp.min(window, isqrt(rmax2))
    color_out[y, x] = disc_mean(vor_color, vor_r2, x, y, rw, rmax2)


@wp.kernel(enable_backward=False)
def sibson_scatter_kernel(
    vor_color: wp.array2d(dtype=wp.vec3),
    vor_r2: wp.array2d(dtype=wp.int32),
    accum: wp.array2d(dtype=wp.vec4),
):
    """Park et al.'s scatter: q adds ``vec4(color(seed(q)), 1)`` to every p with ``|p - q| <= r_q``.

    ``accum`` must be zeroed first. Cost is the sum of the disc areas, about N / seed density taps in all for
    N pixels: slow with few seeds at large sizes (a lone seed makes it quadratic in N)."""
    y, x = wp.tid()
    h = vor_r2.shape[0]
    w = vor_r2.shape[1]
    r2 = vor_r2[y, x]
    if r2 < 0:
        return
    c = vor_color[y, x]
    add = wp.vec4(c[0], c[1], c[2], 1.0)
    r = isqrt(r2)
    y0 = wp.max(-r, -y)
    y1 = wp.min(r, h - 1 - y)
    for dy in range(y0, y1 + 1):
        dxm = isqrt(r2 - dy * dy)
        x0 = wp.max(-dxm, -x)
        x1 = wp.min(dxm, w - 1 - x)
        for dx in range(x0, x1 + 1):
            wp.atomic_add(accum, y + dy, x + dx, add)


@wp.kernel(enable_backward=False)
def sibson_resolve_kernel(
    vor_color: wp.array2d(dtype=wp.vec3),
    vor_r2: wp.array2d(dtype=wp.int32),
    accum: wp.array2d(dtype=wp.vec4),
    max_r2: wp.array(dtype=wp.int32),
    color_out: wp.array2d(dtype=wp.vec3),
):
    """Average of the scattered colors; seeds keep their color; nothing received -> Voronoi color. Where the
    scattered float32 sum overflowed (colors near float max), the pixel gathers the same terms itself with
    the overflow-safe :func:`disc_mean` (window = the largest radius, so the same set of senders)."""
    y, x = wp.tid()
    own = vor_color[y, x]
    a = accum[y, x]
    if vor_r2[y, x] == 0 or a[3] <= 0.0:
        color_out[y, x] = own
    else:
        c = wp.vec3(a[0], a[1], a[2]) / a[3]
        if not wp.isfinite(c):
            rmax2 = max_r2[0]
            c = disc_mean(vor_color, vor_r2, x, y, isqrt(rmax2), rmax2)
        color_out[y, x] = c
