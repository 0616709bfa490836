"""Discrete natural-neighbour (Sibson) interpolation of seed colors (ALGORITHMS.md A6).

Discrete Sibson (Park et al. 2006): every pixel q scatters the color of its nearest seed to every pixel p
with ``|p - q| <= r_q`` (``r_q`` = distance from q to its nearest seed, pixels); p averages what it got.
Two forms of the same sum:

* ``sibson_gather_kernel``: the bounded gather of the thesis (Code 4), q in ``[p - J, p + J]^2``. It equals
  the scatter exactly once ``J >= max r_q``. The loop never visits a q that cannot reach p: q reaches p only
  when ``|p - q|^2 <= r_q^2 <= R^2``, where R^2 is the largest r_q^2 of the ``RTILE`` x ``RTILE`` screen tiles
  that the window overlaps (``tile_r2``, at most the image's largest), so the window is clipped to the disc
  of radius R. Every q that reaches p is still visited, in the same raster order, so the sum is the same.
* ``sibson_scatter_kernel`` + ``sibson_resolve_kernel``: Park's scatter with atomics (the exact reference).

Both read what the last JFA pass (``kernels/jfa.py``) leaves: the seed mask (nonzero = seed), ``r2`` = ``r_q^2``
in pixels^2 at the non-seed pixels (exact int32; -1 where q has no seed) and -1 at the seeds (a seed's r_q is 0:
it reaches no pixel but itself, which keeps its own color), ``vor`` (the finite color of q's nearest seed; 0
where q has none) at the non-seed pixels only, and ``tile_r2``. A tap of the gather reads the 4-byte r2, and the
12-byte color only at the taps that cover p; the mask is read once, at p. Seeds output their own (finite)
color after one mask read; pixels that received nothing output their Voronoi color (0 without a seed); a
sum that overflows float32 (colors near float max) is redone with scaled terms, so no output is NaN/Inf.
"""

import warp as wp

from .fpbits import finite_vec3
from .jfa import RTILE, finite_or_zero
from .load import load_i32, load_u8, load_vec3, store_vec3
from .tonemap import pow_inv22_row, tonemap_linear_rgb, tonemap_rgb


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


# largest finite float32: the overflow-safe mean clamps to it (a mean of finite values is finite)
F32_MAX = wp.constant(3.4028234663852886e38)


# the tap loop of the gather: a tap is one int32 read, the row's address is formed once and each tap offsets it
# (Warp's 2D indexing recomputes a 64-bit strided address with a negative-index wrap per tap: about half of the
# gather's instructions on the H100). Rows must be contiguous (``strides[1]`` = element size), as the stage's own
# ``radius_sq`` and ``voronoi_color`` are.
_DISC_SUM_SNIPPET = r"""
    const int h = r2.shape[0];
    const int w = r2.shape[1];
    const int y0 = -rw > -y ? -rw : -y;
    const int y1 = rw < h - 1 - y ? rw : h - 1 - y;
    const char* rbase = (const char*)r2.data;
    const char* vbase = (const char*)vor.data;
    const size_t rpitch = (size_t)r2.strides[0];
    const size_t vpitch = (size_t)vor.strides[0];
    float ax = 0.0f, ay = 0.0f, az = 0.0f;
    int n = 0;
    for (int dy = y0; dy <= y1; ++dy) {
        const int dy2 = dy * dy;
        const int m = rmax2 - dy2;
        int dxm = 0;  // min(rw, isqrt(m)), 0 for m <= 0 (isqrt below)
        if (m > 0) {
            if (rw <= 16) {  // the small windows of the block guarantee: count down from rw, no square root
                dxm = rw;
                while (dxm * dxm > m) --dxm;
            } else {
                int s = (int)sqrtf((float)m);
                while (s * s > m) --s;
                while ((s + 1) * (s + 1) <= m) ++s;
                dxm = rw < s ? rw : s;
            }
        }
        const int x0 = -dxm > -x ? -dxm : -x;
        const int x1 = dxm < w - 1 - x ? dxm : w - 1 - x;
        const int qy = y + dy;
        const int* rrow = (const int*)(rbase + (size_t)qy * rpitch) + x;
        const wp::vec3* vrow = (const wp::vec3*)(vbase + (size_t)qy * vpitch) + x;
        for (int dx = x0; dx <= x1; ++dx) {
            if (dx * dx + dy2 <= rrow[dx]) {
                const wp::vec3 c = vrow[dx];
                ax = ax + c.c[0] * scale;
                ay = ay + c.c[1] * scale;
                az = az + c.c[2] * scale;
                n = n + 1;
            }
        }
    }
    return wp::vec4(ax, ay, az, (float)n);
"""


@wp.func_native(_DISC_SUM_SNIPPET)
def disc_sum(vor: wp.array2d(dtype=wp.vec3), r2: wp.array2d(dtype=wp.int32), x: int, y: int, rw: int, rmax2: int,
             scale: float) -> wp.vec4:
    """(sum of ``scale * vor[q]``, count) over the non-seed q within the half window ``rw`` whose disc
    covers the non-seed p = (x, y) (``|p - q|^2 <= r_q^2``; offsets also clipped to ``rmax2`` >= every such
    r_q^2). Raster order over (dy, dx). A tap reads only ``r2``: it is -1 at the seeds (the last JFA pass writes
    it so), and no offset's squared length is below 0. Native code (see ``_DISC_SUM_SNIPPET``); both arrays'
    rows must be contiguous."""
    ...


@wp.func
def disc_mean(vor: wp.array2d(dtype=wp.vec3), r2: wp.array2d(dtype=wp.int32), x: int, y: int, rw: int,
              rmax2: int) -> wp.vec3:
    """Mean of the colors q scatters onto the non-seed p (see :func:`disc_sum`); p's Voronoi color when
    none does (0 without a seed).

    Finite for any finite colors: when the plain float32 sum overflows (colors near float max), the sum is
    taken again with every term scaled by 0.5 / n, then doubled and clamped to +-float max."""
    s = disc_sum(vor, r2, x, y, rw, rmax2, 1.0)
    n = s[3]
    if n <= 0.0:
        return vor[y, x]
    out = wp.vec3(s[0], s[1], s[2]) / n
    if finite_vec3(out):
        return out
    t = disc_sum(vor, r2, x, y, rw, rmax2, 0.5 / n)
    return wp.vec3(wp.clamp(2.0 * t[0], -F32_MAX, F32_MAX), wp.clamp(2.0 * t[1], -F32_MAX, F32_MAX),
                   wp.clamp(2.0 * t[2], -F32_MAX, F32_MAX))


@wp.func
def display_value(c: wp.vec3, exposure: float, white: float, gamma_later: int) -> wp.vec3:
    """The tone-mapped display value of ``c``, or (``gamma_later`` != 0) its linear curve, whose gamma the rows
    kernel applies to the whole row afterwards (``pow_inv22_row``)."""
    if gamma_later != 0:
        return tonemap_linear_rgb(c, exposure, white)
    return tonemap_rgb(c, exposure, white)


@wp.func
def sibson_gather_pixel(
    x: int,
    y: int,
    mask: wp.array2d(dtype=wp.uint8),
    vor: wp.array2d(dtype=wp.vec3),
    r2: wp.array2d(dtype=wp.int32),
    tile_r2: wp.array2d(dtype=wp.int32),
    color_in: wp.array2d(dtype=wp.vec3),
    window: int,
    max_r2: wp.array(dtype=wp.int32),
    exposure: float,
    white: float,
    to_display: int,
    color_out: wp.array2d(dtype=wp.vec3),
    display: wp.array2d(dtype=wp.vec3),
    gamma_later: int,
):
    """Bounded Sibson gather at pixel (x, y) (``sibson_gather_kernel`` documents it); ``gamma_later`` != 0: the
    display value is stored before its gamma (``tonemap_linear_rgb``), which the rows kernel applies to the whole
    row afterwards (``pow_inv22_row``)."""
    # (y, x) is a pixel and every tile index below lies in the tile grid: the unchecked loads (kernels/load.py)
    if load_u8(mask, y, x) != wp.uint8(0):  # a seed keeps its color
        c = finite_or_zero(load_vec3(color_in, y, x))
        store_vec3(color_out, y, x, c)
        if to_display != 0:
            store_vec3(display, y, x, display_value(c, exposure, white, gamma_later))
        return
    # q reaches p only if |p - q|^2 <= r_q^2 <= max_r2: clip the window to that disc ...
    rw = wp.min(window, isqrt(max_r2[0]))
    # ... and to the disc of the largest r_q^2 of the screen tiles the window overlaps (<= max_r2)
    h = mask.shape[0]
    w = mask.shape[1]
    loc = int(0)
    for ty in range(wp.max(y - rw, 0) // RTILE, wp.min(y + rw, h - 1) // RTILE + 1):
        for tx in range(wp.max(x - rw, 0) // RTILE, wp.min(x + rw, w - 1) // RTILE + 1):
            loc = wp.max(loc, load_i32(tile_r2, ty, tx))
    rw = wp.min(rw, isqrt(loc))
    c = disc_mean(vor, r2, x, y, rw, loc)
    store_vec3(color_out, y, x, c)
    if to_display != 0:
        store_vec3(display, y, x, display_value(c, exposure, white, gamma_later))




def _make_sibson_gather(rows: bool):
    """``sibson_gather_kernel`` (a thread per pixel) or ``sibson_gather_rows_kernel`` (a thread per row, the
    CPU: ``parallel.launch_rows``)."""

    @wp.kernel(enable_backward=False, name="sibson_gather_rows_kernel" if rows else "sibson_gather_kernel")
    def sibson_gather(
        mask: wp.array2d(dtype=wp.uint8),
        vor: wp.array2d(dtype=wp.vec3),
        r2: wp.array2d(dtype=wp.int32),
        tile_r2: wp.array2d(dtype=wp.int32),
        color_in: wp.array2d(dtype=wp.vec3),
        window: int,
        max_r2: wp.array(dtype=wp.int32),
        exposure: float,
        white: float,
        to_display: int,
        color_out: wp.array2d(dtype=wp.vec3),
        display: wp.array2d(dtype=wp.vec3),
        row0: int,
    ):
        """Bounded Sibson gather (thesis Code 4) with half window ``window`` = J >= 0 pixels; ``to_display`` != 0:
        also the tone-mapped value into ``display`` (the frame's last pass: no separate tone-map pass)."""
        if wp.static(rows):
            y = wp.tid() + row0  # band offset (foveawarp.parallel)
            for x in range(mask.shape[1]):
                sibson_gather_pixel(x, y, mask, vor, r2, tile_r2, color_in, window, max_r2, exposure, white,
                                    to_display, color_out, display, 1)
            if to_display != 0:
                pow_inv22_row(display, y)  # the row's display gamma, one vectorized loop
        else:
            y, x = wp.tid()
            y += row0  # band offset (foveawarp.parallel)
            sibson_gather_pixel(x, y, mask, vor, r2, tile_r2, color_in, window, max_r2, exposure, white, to_display,
                                color_out, display, 0)

    return sibson_gather


sibson_gather_kernel = _make_sibson_gather(False)
sibson_gather_rows_kernel = _make_sibson_gather(True)


@wp.kernel(enable_backward=False)
def sibson_scatter_kernel(
    mask: wp.array2d(dtype=wp.uint8),
    vor: wp.array2d(dtype=wp.vec3),
    r2: wp.array2d(dtype=wp.int32),
    accum: wp.array2d(dtype=wp.vec4),
):
    """Park et al.'s scatter: each non-seed q adds ``vec4(color(seed(q)), 1)`` to every p with
    ``|p - q| <= r_q`` (a seed's disc is itself, which keeps its color anyway).

    ``accum`` must be zeroed first. Cost is the sum of the disc areas, about N / seed density taps in all for
    N pixels: slow with few seeds at large sizes (a lone seed makes it quadratic in N)."""
    y, x = wp.tid()
    if mask[y, x] != wp.uint8(0):
        return
    h = mask.shape[0]
    w = mask.shape[1]
    rq2 = r2[y, x]
    if rq2 < 0:
        return
    c = vor[y, x]
    add = wp.vec4(c[0], c[1], c[2], 1.0)
    r = isqrt(rq2)
    y0 = wp.max(-r, -y)
    y1 = wp.min(r, h - 1 - y)
    for dy in range(y0, y1 + 1):
        dxm = isqrt(rq2 - dy * dy)
        x0 = wp.max(-dxm, -x)
        x1 = wp.min(dxm, w - 1 - x)
        for dx in range(x0, x1 + 1):
            wp.atomic_add(accum, y + dy, x + dx, add)


@wp.kernel(enable_backward=False)
def sibson_resolve_kernel(
    mask: wp.array2d(dtype=wp.uint8),
    vor: wp.array2d(dtype=wp.vec3),
    r2: wp.array2d(dtype=wp.int32),
    color_in: wp.array2d(dtype=wp.vec3),
    accum: wp.array2d(dtype=wp.vec4),
    max_r2: wp.array(dtype=wp.int32),
    color_out: wp.array2d(dtype=wp.vec3),
    row0: int,
):
    """Average of the scattered colors; seeds keep their color; nothing received -> Voronoi color. Where the
    scattered float32 sum overflowed (colors near float max), the pixel gathers the same terms itself with
    the overflow-safe :func:`disc_mean` (window = the largest radius, so the same set of senders)."""
    y, x = wp.tid()
    y += row0  # band offset (foveawarp.parallel)
    if mask[y, x] != wp.uint8(0):
        color_out[y, x] = finite_or_zero(color_in[y, x])
        return
    a = accum[y, x]
    if a[3] <= 0.0:
        color_out[y, x] = vor[y, x]
    else:
        c = wp.vec3(a[0], a[1], a[2]) / a[3]
        if not finite_vec3(c):
            rmax2 = max_r2[0]
            c = disc_mean(vor, r2, x, y, isqrt(rmax2), rmax2)
        color_out[y, x] = c
