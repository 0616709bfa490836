"""Jump Flooding (Rong & Tan 2006) over a seed mask: the nearest seed of every pixel (ALGORITHMS.md A5).

Buffers hold ``wp.vec2i(x, y)`` of the nearest seed found so far, ``(-1, -1)`` for none. Distances are
Euclidean between pixel centres, compared as exact squared integers. One pass reads 9 pixels at offsets
``{-k, 0, k}^2`` and keeps the nearest seed seen; a candidate replaces the current one only when strictly
nearer, so the result is deterministic and a seed always keeps itself.

Cost is paid at the non-seed pixels only. A seed is its own nearest seed in every pass, so:

* a candidate pixel that is a seed is read from the mask (1 byte) as the seed itself, never from the
  ping-pong buffer, and a seed pixel's pass reads its mask byte and stops;
* the seed entries of the result buffer are written once, by the first pass (``final``), and never again;
  the other buffer's seed entries are never written nor read;
* a non-seed pixel whose current seed is at squared distance 1 (or 2, once a step-1 pass has run) reads
  no tap: nothing can be strictly nearer (see :func:`jfa_visit`);
* the first pass takes its candidates from the mask alone (it is the old "init" pass fused with step 1 of
  the schedule: a non-seed candidate has no seed yet);
* the last pass also writes the squared nearest-seed radius and the Voronoi color (the finite color of the
  nearest seed) of every non-seed pixel (and radius -1 at the seeds: they reach no other pixel), and reduces, per
  ``RTILE`` x ``RTILE`` screen tile, the largest radius (``tile_r2``, no atomics) and the count of pixels
  without a seed; one atomic per tile folds them into the image maxima / count.

Every pixel takes exactly the candidates, in exactly the order, of the plain ping-pong JFA (init pass, then
one pass per step), so the results are identical to it.
"""

import warp as wp

from .fpbits import finite_vec3
from .lanes import LANE_NONE, lane_count, lane_group_max
from .load import load_u8, load_vec3, store_i32, store_vec2i, store_vec3

NO_SEED = wp.constant(-1)
INT_MAX = wp.constant(2147483647)
RTILE = wp.constant(16)  # edge of the screen tiles of the radius reduction (RTILE^2 = 256 = the CUDA block)


@wp.func
def seed_dist2(x: int, y: int, s: wp.vec2i) -> int:
    """Squared distance in pixels^2 from pixel (x, y) to seed ``s`` (int32: exact up to 16384^2 * 2)."""
    dx = s[0] - x
    dy = s[1] - y
    return dx * dx + dy * dy


@wp.func
def finite_or_zero(c: wp.vec3) -> wp.vec3:
    if finite_vec3(c):  # a bit test (kernels/fpbits.py): wp.isfinite is a library call per value on the CPU
        return c
    return wp.vec3(0.0, 0.0, 0.0)


@wp.func
def voronoi_color(color_in: wp.array2d(dtype=wp.vec3), s: wp.vec2i) -> wp.vec3:
    """Finite color of seed ``s`` (0 for no seed, or for a seed whose color is not finite)."""
    if s[0] < 0:
        return wp.vec3(0.0, 0.0, 0.0)
    return finite_or_zero(color_in[s[1], s[0]])


@wp.func
def jfa_visit(mask: wp.array2d(dtype=wp.uint8), src: wp.array2d(dtype=wp.vec2i), x: int, y: int, step: int,
              from_mask: int, settled: int) -> wp.vec2i:
    """Nearest seed of the NON-seed pixel (x, y) after one pass of step ``step`` (0: no neighbours).

    ``from_mask`` != 0: the first pass (the pixel and its non-seed neighbours have no seed yet, ``src`` is
    not read); else the current entries come from ``src`` (seeds from the mask). A pixel whose current seed
    is at squared distance <= ``settled`` reads no tap: 1 always (only the pixel itself would be strictly
    nearer), 2 once a step-1 pass has run (that pass saw every 4-neighbour seed, the only seeds at squared
    distance 1, so a pixel still at 2 has none)."""
    h = mask.shape[0]
    w = mask.shape[1]
    best = wp.vec2i(NO_SEED, NO_SEED)
    best_d = int(INT_MAX)
    if from_mask == 0:
        best = src[y, x]
        if best[0] >= 0:
            best_d = seed_dist2(x, y, best)
    # a settled pixel is final: no seed can be strictly nearer, so its taps are skipped
    if step > 0 and best_d > settled:
        for j in range(3):
            yy = y + (j - 1) * step
            if yy >= 0 and yy < h:
                for i in range(3):
                    xx = x + (i - 1) * step
                    if xx >= 0 and xx < w and (i != 1 or j != 1):
                        # both loads are independent (no load waits on the mask); a seed's src entry may be
                        # stale and is discarded by the select
                        s = wp.vec2i(NO_SEED, NO_SEED)
                        if from_mask == 0:
                            s = src[yy, xx]
                        s = wp.where(mask[yy, xx] != wp.uint8(0), wp.vec2i(xx, yy), s)
                        if s[0] >= 0:
                            d = seed_dist2(x, y, s)
                            if d < best_d:
                                best_d = d
                                best = s
    return best


# the disc scan in native code: the pixel's mask address is formed once and each offset adds to it, with no
# bounds test where the whole disc lies inside the image (Warp's 2D indexing forms a 64-bit strided address with a
# negative-index wrap per read: most of the scan's instructions on the H100). Any strides.
_NEAREST_IN_DISC_SNIPPET = r"""
    const int h = mask.shape[0];
    const int w = mask.shape[1];
    const int n = offsets.shape[0];
    if (n > 0) {
        const wp::vec2i* offs = (const wp::vec2i*)offsets.data;
        const long long pitch = (long long)mask.strides[0];
        const long long sx = (long long)mask.strides[1];
        const unsigned char* p = (const unsigned char*)mask.data + (long long)y * pitch + (long long)x * sx;
        const wp::vec2i last = offs[n - 1];  // the longest offset: no component exceeds its length
        const int reach = (int)sqrtf((float)(last.c[0] * last.c[0] + last.c[1] * last.c[1])) + 1;
        if (x >= reach && y >= reach && x < w - reach && y < h - reach) {
            // four mask reads in flight per step (the scan is a chain of dependent short loops otherwise); the
            // first nonzero one in offset order is taken, as in the one-at-a-time loop
            int k = 0;
            for (; k + 3 < n; k += 4) {
                const wp::vec2i o0 = offs[k], o1 = offs[k + 1], o2 = offs[k + 2], o3 = offs[k + 3];
                const unsigned char m0 = p[(long long)o0.c[1] * pitch + (long long)o0.c[0] * sx];
                const unsigned char m1 = p[(long long)o1.c[1] * pitch + (long long)o1.c[0] * sx];
                const unsigned char m2 = p[(long long)o2.c[1] * pitch + (long long)o2.c[0] * sx];
                const unsigned char m3 = p[(long long)o3.c[1] * pitch + (long long)o3.c[0] * sx];
                if (m0 != 0) return wp::vec2i(x + o0.c[0], y + o0.c[1]);
                if (m1 != 0) return wp::vec2i(x + o1.c[0], y + o1.c[1]);
                if (m2 != 0) return wp::vec2i(x + o2.c[0], y + o2.c[1]);
                if (m3 != 0) return wp::vec2i(x + o3.c[0], y + o3.c[1]);
            }
            for (; k < n; ++k) {
                const wp::vec2i o = offs[k];
                if (p[(long long)o.c[1] * pitch + (long long)o.c[0] * sx] != 0)
                    return wp::vec2i(x + o.c[0], y + o.c[1]);
            }
        } else {
            for (int k = 0; k < n; ++k) {
                const wp::vec2i o = offs[k];
                const int xx = x + o.c[0];
                const int yy = y + o.c[1];
                if (xx >= 0 && xx < w && yy >= 0 && yy < h
                    && p[(long long)o.c[1] * pitch + (long long)o.c[0] * sx] != 0)
                    return wp::vec2i(xx, yy);
            }
        }
    }
    return wp::vec2i(-1, -1);
"""


@wp.func_native(_NEAREST_IN_DISC_SNIPPET)
def nearest_in_disc(mask: wp.array2d(dtype=wp.uint8), x: int, y: int, offsets: wp.array(dtype=wp.vec2i)) -> wp.vec2i:
    """Nearest seed of the NON-seed pixel (x, y) by a scan of ``offsets`` (every offset of the disc the block
    guarantee bounds, sorted by squared length, then dy, then dx): the first seed met is a nearest one, exact
    (the "disc" variant). (-1, -1) when the disc holds no seed (the guarantee does not hold there). Native code
    (see ``_NEAREST_IN_DISC_SNIPPET``); ``offsets`` must be contiguous (the stage's own array)."""
    ...


@wp.func
def last_pass_seed(mask: wp.array2d(dtype=wp.uint8), src: wp.array2d(dtype=wp.vec2i), x: int, y: int, step: int,
                   from_mask: int, settled: int, offsets: wp.array(dtype=wp.vec2i)) -> wp.vec2i:
    """The last pass's nearest seed of a non-seed pixel: the disc scan when ``step`` < 0, else a JFA pass."""
    if step < 0:
        return nearest_in_disc(mask, x, y, offsets)
    return jfa_visit(mask, src, x, y, step, from_mask, settled)


@wp.func
def last_pass_pixel(mask: wp.array2d(dtype=wp.uint8), src: wp.array2d(dtype=wp.vec2i), x: int, y: int, step: int,
                    from_mask: int, settled: int, color_in: wp.array2d(dtype=wp.vec3), color_mode: int,
                    offsets: wp.array(dtype=wp.vec2i), nearest: wp.array2d(dtype=wp.vec2i),
                    r2_out: wp.array2d(dtype=wp.int32), color_out: wp.array2d(dtype=wp.vec3)) -> int:
    """The last pass at pixel (x, y), shared by the tiled and the band kernels: writes its outputs there and
    returns its r_q^2 (>= 0), -1 for a non-seed pixel without a seed, -2 for a seed."""
    # (y, x) is a pixel and a found seed lies in the image: the unchecked loads and stores (kernels/load.py)
    if load_u8(mask, y, x) != wp.uint8(0):
        if from_mask != 0:
            store_vec2i(nearest, y, x, wp.vec2i(x, y))
        store_i32(r2_out, y, x, -1)  # a seed reaches no other pixel: the gather's taps need not read the mask
        if color_mode == 2:
            store_vec3(color_out, y, x, finite_or_zero(load_vec3(color_in, y, x)))
        return -2
    s = last_pass_seed(mask, src, x, y, step, from_mask, settled, offsets)
    store_vec2i(nearest, y, x, s)
    r2 = int(-1)
    c = wp.vec3(0.0, 0.0, 0.0)
    if s[0] >= 0:
        r2 = seed_dist2(x, y, s)
        if color_mode != 0:
            c = finite_or_zero(load_vec3(color_in, s[1], s[0]))
    store_i32(r2_out, y, x, r2)
    if color_mode != 0:
        # voronoi_color's value (the seed's finite color, 0 without one) by the unchecked load: the seed this pass
        # found lies in the image; voronoi_color keeps the checked read for user-given nearest maps
        store_vec3(color_out, y, x, c)
    return r2


@wp.func
def tile_slot_pixel(k: int, ty: int, tx: int) -> wp.vec2i:
    """(x, y) of slot ``k`` (row-major) of screen tile (ty, tx)."""
    ly = k // RTILE
    return wp.vec2i(tx * RTILE + (k - ly * RTILE), ty * RTILE + ly)


@wp.func
def publish_tile_stats(lane: int, ty: int, tx: int, r2max: int, missing: int, tile_r2: wp.array2d(dtype=wp.int32),
                       max_r2: wp.array(dtype=wp.int32), max_radius: wp.array(dtype=wp.float32),
                       unreached: wp.array(dtype=wp.int32)):
    """The end of a tiled kernel's screen tile (one block): the block's largest ``r2max`` and summed ``missing``
    (cooperative reductions: every thread of the block calls this) go to ``tile_r2[ty, tx]`` and, by lane 0's
    atomics, into the image statistics."""
    tmax = wp.tile_max(wp.tile(r2max))
    tmiss = wp.tile_sum(wp.tile(missing))
    if lane == 0:
        m = tmax[0]
        tile_r2[ty, tx] = m
        if m > 0:
            wp.atomic_max(max_r2, 0, m)
            wp.atomic_max(max_radius, 0, wp.sqrt(float(m)))
        if tmiss[0] > 0:
            wp.atomic_add(unreached, 0, tmiss[0])


@wp.kernel(enable_backward=False)
def jfa_pass_kernel(
    mask: wp.array2d(dtype=wp.uint8),
    src: wp.array2d(dtype=wp.vec2i),
    step: int,
    from_mask: int,
    settled: int,
    final: wp.array2d(dtype=wp.vec2i),
    dst: wp.array2d(dtype=wp.vec2i),
    max_r2: wp.array(dtype=wp.int32),
    max_radius: wp.array(dtype=wp.float32),
    unreached: wp.array(dtype=wp.int32),
    row0: int,
):
    """One pass that is not the last. With ``from_mask`` != 0 (the first pass) it also writes every seed's
    entry of ``final`` (the buffer the last pass writes) and zeroes the statistics the last pass reduces
    into (a later launch on the same stream, so no race)."""
    y, x = wp.tid()
    y += row0  # band offset (foveawarp.parallel)
    if from_mask != 0 and x == 0 and y == 0:
        max_r2[0] = 0
        max_radius[0] = 0.0
        unreached[0] = 0
    if mask[y, x] != wp.uint8(0):
        if from_mask != 0:
            final[y, x] = wp.vec2i(x, y)
        return
    dst[y, x] = jfa_visit(mask, src, x, y, step, from_mask, settled)


def _make_last_pass(form: str):
    """The last pass (``step`` 0 when the schedule is empty; -1: the "disc" variant's scan of ``offsets``) in
    three launch forms that write the same values (tests compare them):

    * ``jfa_last_pass_kernel`` ("tiled", ``wp.launch_tiled``): block b covers the RTILE x RTILE screen tile b
      (row-major over the tile grid); with fewer threads than RTILE^2 (the CPU runs 1) each thread takes every
      block_dim-th pixel of the tile. Cooperative block reductions give the tile's largest r2 and count of pixels
      without a seed; one atomic per tile folds them into the image statistics.
    * ``jfa_last_pass_atomic_kernel`` ("atomic", a thread per pixel): each non-seed pixel with a seed makes its own
      atomic maximum on its tile's entry of ``tile_r2`` (zeroed before the launch), and goes into the image
      statistics only when it raised the tile's maximum; a pixel without a seed counts itself into ``unreached``.
      No per-block reductions (they cost a whole-image pass of their own: 0.105 of the tiled kernel's 0.171 ms at
      3840x2160, H100); for masks with few non-seed pixels (deterministic shading): with many, the atomics queue
      on each tile's entry.
    * ``jfa_last_pass_lanes_kernel`` ("lanes", a thread per pixel): the lanes of a warp in the same screen tile
      first reduce their largest radius (``kernels/lanes.py``) and one of them makes the atomic, so a warp along a
      row makes one per tile it spans. Only the lanes with something to fold take part (a warp of seeds skips
      both). A raised tile maximum goes into the image maxima only when above the value last seen there (a stale
      read costs an atomic, never a value: the maxima only grow). CUDA's form for many non-seed pixels (H100, 4K,
      8 AO rays: 0.23-0.26 against 0.30-0.32 ms for the tiled kernel and 0.32-0.38 for the atomic one).

    Each writes ``nearest`` and ``r2_out`` (r_q^2, -1 without a seed) at the non-seed pixels, -1 to ``r2_out`` at
    the seeds (seed entries of ``nearest`` too when ``from_mask`` != 0, i.e. this is also the first pass),
    ``tile_r2`` (the tile's largest r2, 0 when none) and, by ``color_mode``: 1: the Voronoi color (finite color of
    the nearest seed, 0 without one) of the non-seed pixels to ``color_out`` (the gather's ``vor`` buffer); 2: the
    Voronoi color of every pixel (seeds: their own) to ``color_out`` (the Voronoi fill); 0: no color.
    ``max_r2`` / ``max_radius`` / ``unreached`` must be zero before the launch; the kernels have the same
    arguments."""
    tiled = form == "tiled"
    lanes = form == "lanes"

    @wp.kernel(enable_backward=False, name="jfa_last_pass_kernel" if tiled else f"jfa_last_pass_{form}_kernel")
    def last_pass(
        mask: wp.array2d(dtype=wp.uint8),
        src: wp.array2d(dtype=wp.vec2i),
        step: int,
        from_mask: int,
        settled: int,
        color_in: wp.array2d(dtype=wp.vec3),
        color_mode: int,
        offsets: wp.array(dtype=wp.vec2i),
        nearest: wp.array2d(dtype=wp.vec2i),
        r2_out: wp.array2d(dtype=wp.int32),
        tile_r2: wp.array2d(dtype=wp.int32),
        color_out: wp.array2d(dtype=wp.vec3),
        max_r2: wp.array(dtype=wp.int32),
        max_radius: wp.array(dtype=wp.float32),
        unreached: wp.array(dtype=wp.int32),
    ):
        if wp.static(tiled):
            blk, lane = wp.tid()
            h = mask.shape[0]
            w = mask.shape[1]
            tiles_x = tile_r2.shape[1]
            ty = blk // tiles_x
            tx = blk - ty * tiles_x
            bd = wp.block_dim()
            r2max = int(0)
            missing = int(0)
            for k in range(lane, RTILE * RTILE, bd):
                p = tile_slot_pixel(k, ty, tx)
                if p[1] < h and p[0] < w:
                    r2 = last_pass_pixel(mask, src, p[0], p[1], step, from_mask, settled, color_in, color_mode,
                                         offsets, nearest, r2_out, color_out)
                    r2max = wp.max(r2max, r2)
                    if r2 == -1:
                        missing += 1
            # cooperative block reductions: every thread of the block reaches them
            publish_tile_stats(lane, ty, tx, r2max, missing, tile_r2, max_r2, max_radius, unreached)
        else:
            y, x = wp.tid()
            r2 = last_pass_pixel(mask, src, x, y, step, from_mask, settled, color_in, color_mode, offsets, nearest,
                                 r2_out, color_out)
            if r2 > 0:
                m = r2
                if wp.static(lanes):
                    m = lane_group_max((y // RTILE) * tile_r2.shape[1] + x // RTILE, r2)
                if m != LANE_NONE:
                    old = wp.atomic_max(tile_r2, y // RTILE, x // RTILE, m)
                    raised = m > old
                    if wp.static(lanes):
                        raised = raised and m > max_r2[0]
                    if raised:
                        wp.atomic_max(max_r2, 0, m)
                        wp.atomic_max(max_radius, 0, wp.sqrt(float(m)))
            elif r2 == -1:
                miss = 1
                if wp.static(lanes):
                    miss = lane_count(1)
                if miss > 0:
                    wp.atomic_add(unreached, 0, miss)

    return last_pass


jfa_last_pass_kernel = _make_last_pass("tiled")
jfa_last_pass_atomic_kernel = _make_last_pass("atomic")
jfa_last_pass_lanes_kernel = _make_last_pass("lanes")


@wp.kernel(enable_backward=False)
def jfa_last_pass_bands_kernel(
    mask: wp.array2d(dtype=wp.uint8),
    src: wp.array2d(dtype=wp.vec2i),
    step: int,
    from_mask: int,
    settled: int,
    color_in: wp.array2d(dtype=wp.vec3),
    color_mode: int,
    offsets: wp.array(dtype=wp.vec2i),
    nearest: wp.array2d(dtype=wp.vec2i),
    r2_out: wp.array2d(dtype=wp.int32),
    tile_r2: wp.array2d(dtype=wp.int32),
    color_out: wp.array2d(dtype=wp.vec3),
    tile_miss: wp.array2d(dtype=wp.int32),
    row0: int,
):
    """``jfa_last_pass_kernel`` for the CPU's band-parallel launches (``foveawarp.parallel``): no tiles, no
    atomics. A 1-D launch over the screen tiles in row-major order (bands of tiles, not of tile rows: 640x360 has
    only 23 tile rows, too few to spread over 16 threads): thread i runs the same per-pixel step over screen tile
    (i // tiles across, i % tiles across) and writes the same ``nearest``, ``r2_out``, ``color_out`` and
    ``tile_r2``, plus its count of pixels without a seed to ``tile_miss``; ``jfa_tile_stats_kernel`` then
    reduces ``tile_r2`` / ``tile_miss`` into the statistics (equal to the tiled kernel's atomics: integer max
    and sum, and sqrt of the max r2)."""
    i = wp.tid() + row0  # band offset (foveawarp.parallel)
    ntx = tile_r2.shape[1]
    ty = i // ntx
    tx = i - ty * ntx
    h = mask.shape[0]
    w = mask.shape[1]
    r2max = int(0)
    missing = int(0)
    # one flat loop over the tile, row-major: RTILE^2 = 256 iterations is above Warp's unroll limit, so the
    # per-pixel step is emitted once (two nested 16-iteration loops were unrolled into 256 inlined copies,
    # which NVRTC took minutes to compile for CUDA, where this kernel never runs)
    for k in range(RTILE * RTILE):
        p = tile_slot_pixel(k, ty, tx)
        if p[1] < h and p[0] < w:
            r2 = last_pass_pixel(mask, src, p[0], p[1], step, from_mask, settled, color_in, color_mode, offsets,
                                 nearest, r2_out, color_out)
            r2max = wp.max(r2max, r2)
            if r2 == -1:
                missing += 1
    tile_r2[ty, tx] = r2max
    tile_miss[ty, tx] = missing


@wp.kernel(enable_backward=False)
def jfa_tile_stats_kernel(
    tile_r2: wp.array2d(dtype=wp.int32),
    tile_miss: wp.array2d(dtype=wp.int32),
    max_r2: wp.array(dtype=wp.int32),
    max_radius: wp.array(dtype=wp.float32),
    unreached: wp.array(dtype=wp.int32),
):
    """One thread: fold the per-tile results of ``jfa_last_pass_bands_kernel`` into the statistics as the
    tiled kernel's atomics do (max into ``max_r2`` and ``max_radius``, add into ``unreached``)."""
    m = int(0)
    miss = int(0)
    for ty in range(tile_r2.shape[0]):
        for tx in range(tile_r2.shape[1]):
            m = wp.max(m, tile_r2[ty, tx])
            miss += tile_miss[ty, tx]
    if m > 0:
        max_r2[0] = wp.max(max_r2[0], m)
        max_radius[0] = wp.max(max_radius[0], wp.sqrt(float(m)))
    if miss > 0:
        unreached[0] = unreached[0] + miss


@wp.kernel(enable_backward=False)
def voronoi_from_nearest_kernel(
    given: wp.array2d(dtype=wp.vec2i),
    color_in: wp.array2d(dtype=wp.vec3),
    seeds: wp.array2d(dtype=wp.uint8),
    nearest: wp.array2d(dtype=wp.vec2i),
    r2_out: wp.array2d(dtype=wp.int32),
    vor: wp.array2d(dtype=wp.vec3),
    tile_r2: wp.array2d(dtype=wp.int32),
    max_r2: wp.array(dtype=wp.int32),
    max_radius: wp.array(dtype=wp.float32),
    unreached: wp.array(dtype=wp.int32),
):
    """What :func:`jfa_last_pass_kernel` leaves behind, from a given nearest map instead of JFA (the ops'
    ``nearest=`` argument): ``nearest`` = ``given``, ``seeds`` = the pixels that are their own nearest seed,
    ``r2_out`` (-1 at the seeds) and ``vor`` (color mode 1) at the other pixels, ``tile_r2`` and the statistics (zeroed before
    the launch). Same tiling."""
    blk, lane = wp.tid()
    h = given.shape[0]
    w = given.shape[1]
    tiles_x = tile_r2.shape[1]
    ty = blk // tiles_x
    tx = blk - ty * tiles_x
    bd = wp.block_dim()
    r2max = int(0)
    missing = int(0)
    for k in range(lane, RTILE * RTILE, bd):
        p = tile_slot_pixel(k, ty, tx)
        x = p[0]
        y = p[1]
        if y < h and x < w:
            s = given[y, x]
            nearest[y, x] = s
            if s[0] == x and s[1] == y:
                seeds[y, x] = wp.uint8(1)
                r2_out[y, x] = -1
            else:
                seeds[y, x] = wp.uint8(0)
                r2 = int(-1)
                if s[0] >= 0:
                    r2 = seed_dist2(x, y, s)
                    r2max = wp.max(r2max, r2)
                else:
                    missing += 1
                r2_out[y, x] = r2
                vor[y, x] = voronoi_color(color_in, s)
    publish_tile_stats(lane, ty, tx, r2max, missing, tile_r2, max_r2, max_radius, unreached)


@wp.kernel(enable_backward=False)
def voronoi_fill_kernel(
    mask: wp.array2d(dtype=wp.uint8),
    nearest: wp.array2d(dtype=wp.vec2i),
    color_in: wp.array2d(dtype=wp.vec3),
    color_out: wp.array2d(dtype=wp.vec3),
    row0: int,
):
    """Voronoi (nearest-seed) color of every pixel; seeds keep their own (finite) color."""
    y, x = wp.tid()
    y += row0  # band offset (foveawarp.parallel)
    if mask[y, x] != wp.uint8(0):
        color_out[y, x] = finite_or_zero(color_in[y, x])
    else:
        color_out[y, x] = voronoi_color(color_in, nearest[y, x])


@wp.kernel(enable_backward=False)
def voronoi_color_kernel(
    mask: wp.array2d(dtype=wp.uint8),
    nearest: wp.array2d(dtype=wp.vec2i),
    color_in: wp.array2d(dtype=wp.vec3),
    vor: wp.array2d(dtype=wp.vec3),
    row0: int,
):
    """Voronoi color (color mode 1 of :func:`jfa_last_pass_kernel`) of the non-seed pixels, for a
    ``run_interpolate`` whose colors the last pass did not see."""
    y, x = wp.tid()
    y += row0  # band offset (foveawarp.parallel)
    if mask[y, x] == wp.uint8(0):
        vor[y, x] = voronoi_color(color_in, nearest[y, x])
