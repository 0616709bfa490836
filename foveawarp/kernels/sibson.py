"""Discrete natural-neighbour (Sibson) interpolation of seed colors (ALGORITHMS.md A6).

Discrete Sibson (Park et al. 2006): every pixel q scatters the color of its nearest seed to every pixel p
with ``|p - q| <= r_q`` (``r_q`` = distance from q to its nearest seed, pixels); p averages what it got.
Two forms of the same sum:

* ``sibson_gather_kernel``: the bounded gather of the thesis (Code 4), q in ``[p - J, p + J]^2``. It equals
  the scatter exactly once ``J >= max r_q``; the loop never goes past ``floor(max r_q)`` either, because no
  farther q can reach p.
* ``sibson_scatter_kernel`` + ``sibson_resolve_kernel``: Park's scatter with atomics (the exact reference).

Both read the "Voronoi buffer" written by ``voronoi_finalize_kernel``: per pixel q, ``vec4(rgb, r2)`` with
rgb the (finite) color of q's nearest seed and r2 = ``r_q^2`` in pixels^2 (-1 where q has no seed).
Seeds always output their own color; pixels that received nothing output their Voronoi color (0 without a
seed), so no output is NaN/Inf.
"""

import warp as wp

from .jfa import seed_dist2


@wp.func
def isqrt(n: int) -> int:
    """floor(sqrt(n)) for n >= 0 (0 for n < 0), exact for every int32."""
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


@wp.func
def is_seed(nearest: wp.array2d(dtype=wp.vec2i), x: int, y: int) -> bool:
    s = nearest[y, x]
    return s[0] == x and s[1] == y


@wp.kernel(enable_backward=False)
def voronoi_finalize_kernel(
    nearest: wp.array2d(dtype=wp.vec2i),
    color_in: wp.array2d(dtype=wp.vec3),
    write_out: int,
    vor: wp.array2d(dtype=wp.vec4),
    color_out: wp.array2d(dtype=wp.vec3),
    max_r2: wp.array(dtype=wp.int32),
    max_radius: wp.array(dtype=wp.float32),
    unreached: wp.array(dtype=wp.int32),
):
    """Tiled launch over the flattened image (any block size; 1 on the CPU).

    Writes ``vor`` (and the Voronoi color to ``color_out`` when ``write_out`` != 0), and reduces per block the
    largest r2 (into ``max_r2`` / ``max_radius``, pixels^2 / pixels) and the count of pixels without a seed.
    The three statistics must be zeroed before the launch.
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
        r2w = float(-1.0)
        if s[0] >= 0:
            c = finite_or_zero(color_in[s[1], s[0]])
            r2 = seed_dist2(x, y, s)
            r2w = float(r2)
        else:
            missing = 1
        vor[y, x] = wp.vec4(c[0], c[1], c[2], r2w)
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


@wp.kernel(enable_backward=False)
def sibson_gather_kernel(
    nearest: wp.array2d(dtype=wp.vec2i),
    vor: wp.array2d(dtype=wp.vec4),
    window: int,
    max_r2: wp.array(dtype=wp.int32),
    color_out: wp.array2d(dtype=wp.vec3),
):
    """Bounded Sibson gather (thesis Code 4) with half window ``window`` = J >= 0 pixels."""
    y, x = wp.tid()
    h = vor.shape[0]
    w = vor.shape[1]
    v = vor[y, x]
    own = wp.vec3(v[0], v[1], v[2])
    if is_seed(nearest, x, y):
        color_out[y, x] = own
        return
    # q reaches p only if |p - q|^2 <= r_q^2 <= max_r2: clip the window to that disc
    rmax2 = max_r2[0]
    rw = wp.min(window, isqrt(rmax2))
    y0 = wp.max(-rw, -y)
    y1 = wp.min(rw, h - 1 - y)
    acc = wp.vec3(0.0, 0.0, 0.0)
    n = int(0)
    for dy in range(y0, y1 + 1):
        dxm = wp.min(rw, isqrt(rmax2 - dy * dy))
        x0 = wp.max(-dxm, -x)
        x1 = wp.min(dxm, w - 1 - x)
        for dx in range(x0, x1 + 1):
            q = vor[y + dy, x + dx]
            if float(dx * dx + dy * dy) <= q[3]:
                acc = acc + wp.vec3(q[0], q[1], q[2])
                n = n + 1
    if n > 0:
        color_out[y, x] = acc / float(n)
    else:
        color_out[y, x] = own


@wp.kernel(enable_backward=False)
def sibson_scatter_kernel(
    nearest: wp.array2d(dtype=wp.vec2i),
    vor: wp.array2d(dtype=wp.vec4),
    accum: wp.array2d(dtype=wp.vec4),
):
    """Park et al.'s scatter: q adds ``vec4(color(seed(q)), 1)`` to every p with ``|p - q| <= r_q``.

    ``accum`` must be zeroed first. Cost is the sum of the disc areas (unbounded radius)."""
    y, x = wp.tid()
    h = vor.shape[0]
    w = vor.shape[1]
    s = nearest[y, x]
    if s[0] < 0:
        return
    r2 = seed_dist2(x, y, s)
    v = vor[y, x]
    add = wp.vec4(v[0], v[1], v[2], 1.0)
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
    nearest: wp.array2d(dtype=wp.vec2i),
    vor: wp.array2d(dtype=wp.vec4),
    accum: wp.array2d(dtype=wp.vec4),
    color_out: wp.array2d(dtype=wp.vec3),
):
    """Average of the scattered colors; seeds keep their color; nothing received -> Voronoi color."""
    y, x = wp.tid()
    v = vor[y, x]
    own = wp.vec3(v[0], v[1], v[2])
    a = accum[y, x]
    if is_seed(nearest, x, y) or a[3] <= 0.0:
        color_out[y, x] = own
    else:
        color_out[y, x] = wp.vec3(a[0], a[1], a[2]) / a[3]
