"""Work compaction and reordering of the sampled pixels (thesis A3).

- row CSR (strategy 1): each row's sampled pixels packed to the left of a same-size coordinate buffer; one
  thread block per row, each thread a contiguous segment, placed by a block-local prefix sum;
- block balancing (strategy 2): within a block of rows, the last entry of the longest row moves to the end of
  the shortest row until the lengths differ by at most one;
- global stream compaction, in raster order or over screen tiles taken in Morton order (so that a warp's
  rays are neighbours): three launches, no temporary buffers: (1) ``compact_count_kernel``: every thread
  block counts the set pixels of its run of ``per_thread * block_dim`` consecutive positions of the output
  order; (2) ``block_scan_kernel``: one block turns those counts into exclusive offsets and the total
  (``count[0]``); (3) ``compact_scatter_kernel``: every block recounts its run, takes a block-local exclusive
  prefix sum and writes its flat indices from its offset on (a block of one thread, the CPU, writes
  without recounting). The output order (tile rank, then raster
  inside the tile; or raster) is fixed by the positions, so the list is deterministic.
The compacted count stays on the device (``count[0]``).

Every compaction kernel takes a second mask, ``keep``: a pixel is listed when it is set in both. The frame loop
passes the G-buffer's hit mask, so the sampled pixels whose primary ray missed (their colour is the background,
which the temporal resolve writes without reading the shading) take no lane of the shading launch; a caller with
nothing to drop passes the mask itself.
"""

import warp as wp

# ---------------------------------------------------------------------------------------------------
# strategy 1 / 2: row CSR


@wp.kernel(enable_backward=False)
def rows_compact_kernel(mask: wp.array2d(dtype=wp.uint8), keep: wp.array2d(dtype=wp.uint8),
                        coords: wp.array2d(dtype=wp.vec2i), counts: wp.array(dtype=wp.int32)):
    """Tiled, one block per row (thesis strategy 1): sampled (x, y) (set in ``mask`` and in ``keep``) to the left
    of coords[y], in raster order, count to counts[y]. Thread i takes a contiguous segment of ceil(W / block_dim)
    pixels; one block-local exclusive prefix sum of the segment counts places every segment."""
    y, lane = wp.tid()
    w = mask.shape[1]
    seg = (w + wp.block_dim() - 1) // wp.block_dim()
    x0 = wp.min(lane * seg, w)
    x1 = wp.min(x0 + seg, w)
    # a block of one thread (the CPU) writes while it counts: one walk
    alone = wp.block_dim() == 1
    c = int(0)
    if not alone:
        for x in range(x0, x1):
            if mask[y, x] != wp.uint8(0) and keep[y, x] != wp.uint8(0):
                c += 1
    start = wp.untile(wp.tile_scan_exclusive(wp.tile(c)))
    o = start
    if alone or c > 0:
        for x in range(x0, x1):
            if mask[y, x] != wp.uint8(0) and keep[y, x] != wp.uint8(0):
                coords[y, o] = wp.vec2i(x, y)
                o += 1
    tot = wp.tile_sum(wp.tile(o - start))
    if lane == 0:
        counts[y] = tot[0]


@wp.kernel(enable_backward=False)
def rows_balance_kernel(coords: wp.array2d(dtype=wp.vec2i), counts: wp.array(dtype=wp.int32), block: int):
    """One thread per block of ``block`` rows (thesis strategy 2): move the last entry of the longest row to the
    end of the shortest row until max - min <= 1. Ties pick the lowest row index (both for longest and
    shortest), which fixes the result."""
    b = wp.tid()
    h = counts.shape[0]
    r0 = b * block
    r1 = wp.min(r0 + block, h)
    moving = int(1)
    while moving != 0:
        imax = r0
        imin = r0
        for r in range(r0 + 1, r1):
            if counts[r] > counts[imax]:
                imax = r
            if counts[r] < counts[imin]:
                imin = r
        if counts[imax] - counts[imin] <= 1:
            moving = 0
        else:
            last = counts[imax] - 1
            coords[imin, counts[imin]] = coords[imax, last]
            counts[imin] = counts[imin] + 1
            counts[imax] = last


# ---------------------------------------------------------------------------------------------------
# global stream compaction


@wp.func
def walk_run(mask: wp.array2d(dtype=wp.uint8), keep: wp.array2d(dtype=wp.uint8), g0: int, per_thread: int, n: int,
             tile: int, tiles_x: int,
             tile_order: wp.array(dtype=wp.int32), write: int, o: int, work: wp.array(dtype=wp.int32)) -> int:
    """Visit positions g0, g0 + 1, ... (``per_thread`` of them, below ``n``) of the output order and count
    the pixels set in both ``mask`` and ``keep``; with ``write`` != 0 also store their flat indices y * W + x at
    ``work[o]``, ``work[o + 1]``...

    Output order: ``tile`` 0: raster (position g is pixel g); else tiles in the order ``tile_order`` (row-major
    tile indices), raster order inside a tile, positions that fall outside the image (partial edge tiles)
    skipped. The run is walked as row segments (a plain loop over x each), one division per run."""
    h = mask.shape[0]
    w = mask.shape[1]
    c = int(0)
    remaining = wp.min(per_thread, n - g0)
    if tile == 0:
        y = g0 // w
        x = g0 - y * w
        while remaining > 0:
            seg = wp.min(w - x, remaining)
            for xx in range(x, x + seg):
                if mask[y, xx] != wp.uint8(0) and keep[y, xx] != wp.uint8(0):
                    if write != 0:
                        work[o + c] = y * w + xx
                    c += 1
            remaining -= seg
            x = 0
            y += 1
        return c
    tt = tile * tile
    r = g0 // tt
    l = g0 - r * tt
    j = l // tile
    i = l - j * tile
    while remaining > 0:
        t = tile_order[r]
        ty = t // tiles_x
        seg = wp.min(tile - i, remaining)
        y = ty * tile + j
        if y < h:
            x0 = (t - ty * tiles_x) * tile + i
            for x in range(x0, wp.min(x0 + seg, w)):
                if mask[y, x] != wp.uint8(0) and keep[y, x] != wp.uint8(0):
                    if write != 0:
                        work[o + c] = y * w + x
                    c += 1
        remaining -= seg
        i = 0
        j += 1
        if j == tile:
            j = 0
            r += 1
    return c


@wp.kernel(enable_backward=False)
def compact_count_kernel(mask: wp.array2d(dtype=wp.uint8), keep: wp.array2d(dtype=wp.uint8),
                         tile_order: wp.array(dtype=wp.int32), tile: int,
                         tiles_x: int, n: int, per_thread: int, block_counts: wp.array(dtype=wp.int32)):
    """Tiled: block b counts the set pixels of positions [b * m, (b + 1) * m) of the output order
    (m = block_dim * ``per_thread``; ``n`` positions in all)."""
    blk, lane = wp.tid()
    g0 = (blk * wp.block_dim() + lane) * per_thread
    c = walk_run(mask, keep, g0, per_thread, n, tile, tiles_x, tile_order, 0, 0, block_counts)
    tot = wp.tile_sum(wp.tile(c))
    if lane == 0:
        block_counts[blk] = tot[0]


@wp.kernel(enable_backward=False)
def block_scan_kernel(block_counts: wp.array(dtype=wp.int32), block_offsets: wp.array(dtype=wp.int32),
                      count: wp.array(dtype=wp.int32)):
    """One block: exclusive prefix sums of ``block_counts`` into ``block_offsets`` and the total into
    ``count[0]``. Thread i sums a contiguous segment serially; one block-wide scan joins the segments."""
    _, lane = wp.tid()
    bd = wp.block_dim()
    nb = block_counts.shape[0]
    seg = (nb + bd - 1) // bd
    i0 = wp.min(lane * seg, nb)
    i1 = wp.min(i0 + seg, nb)
    s = int(0)
    for i in range(i0, i1):
        s += block_counts[i]
    e = wp.untile(wp.tile_scan_exclusive(wp.tile(s)))
    tot = wp.tile_sum(wp.tile(s))
    o = e
    for i in range(i0, i1):
        block_offsets[i] = o
        o += block_counts[i]
    if lane == 0:
        count[0] = tot[0]


@wp.kernel(enable_backward=False)
def compact_scatter_kernel(mask: wp.array2d(dtype=wp.uint8), keep: wp.array2d(dtype=wp.uint8),
                           tile_order: wp.array(dtype=wp.int32), tile: int,
                           tiles_x: int, n: int, per_thread: int, block_offsets: wp.array(dtype=wp.int32),
                           work: wp.array(dtype=wp.int32)):
    """Tiled, same blocks as :func:`compact_count_kernel`: flat indices y * W + x of the set pixels of the
    block's positions, in order, from ``block_offsets[b]`` on."""
    blk, lane = wp.tid()
    h = mask.shape[0]
    w = mask.shape[1]
    g0 = (blk * wp.block_dim() + lane) * per_thread
    # a block of one thread (the CPU) knows its offset already: one walk that writes, no recount
    alone = wp.block_dim() == 1
    c = int(0)
    if not alone:
        c = walk_run(mask, keep, g0, per_thread, n, tile, tiles_x, tile_order, 0, 0, work)
    o = block_offsets[blk] + wp.untile(wp.tile_scan_exclusive(wp.tile(c)))
    if alone or c > 0:
        walk_run(mask, keep, g0, per_thread, n, tile, tiles_x, tile_order, 1, o, work)


# ---------------------------------------------------------------------------------------------------
# global stream compaction over the mask read 8 pixels at a time (CUDA, image width a multiple of 8)
#
# The same output order as above, for "scan" and for "tile" with 8 x 8 tiles: there every run of 8 positions
# that starts at a multiple of 8 is 8 horizontally adjacent pixels starting at a multiple of 8 (a raster
# row's, or a tile row's), i.e. one 8-byte word of the mask, which the kernels read as a uint64 view of it
# (word i holds pixels 8 i .. 8 i + 7, little-endian: byte b is pixel 8 i + b, as on x86 and CUDA). A word's
# set pixels are counted with a few integer operations instead of 8 loads and compares (the H100's byte-wise
# kernels above ran 11x and 21x above their DRAM floor: instruction bound).

BYTE_LSB = wp.constant(wp.uint64(0x0101010101010101))


@wp.func
def word_of(k: int, tile: int, tiles_x: int, words_x: int, h: int, tile_order: wp.array(dtype=wp.int32)) -> int:
    """Word index (into the (H * W / 8,) uint64 view) of the ``k``-th run of 8 output positions, -1 when the
    run lies below the image (a partial bottom tile). ``tile`` 0: raster (run k is word k); 8: tile rank
    k / 8 in ``tile_order``, its row k % 8."""
    if tile == 0:
        return k
    t = tile_order[k >> 3]
    ty = t // tiles_x
    y = ty * 8 + (k & 7)
    if y >= h:
        return -1
    return y * words_x + (t - ty * tiles_x)


@wp.func
def set_bytes(v: wp.uint64) -> wp.uint64:
    """``v`` with each byte replaced by 1 where it is nonzero, 0 where it is zero (the OR of each byte's 8 bits
    folded into its lowest bit; the shifts bring higher bytes' bits only into bits that the final mask drops)."""
    t = v | (v >> wp.uint64(4))
    t = t | (t >> wp.uint64(2))
    t = t | (t >> wp.uint64(1))
    return t & BYTE_LSB


@wp.func
def count_set(v: wp.uint64) -> int:
    """Number of nonzero bytes of ``v`` (the byte sum of :func:`set_bytes`, gathered in the top byte)."""
    return int((set_bytes(v) * BYTE_LSB) >> wp.uint64(56))


@wp.func
def walk_words(mask64: wp.array(dtype=wp.uint64), keep64: wp.array(dtype=wp.uint64), k0: int, words: int,
               nwords: int, tile: int, tiles_x: int, words_x: int, h: int, tile_order: wp.array(dtype=wp.int32),
               write: int, o: int, work: wp.array(dtype=wp.int32)) -> int:
    """Runs k0 .. k0 + words - 1 (below ``nwords``): count their pixels set in both ``mask64`` and ``keep64``; with
    ``write`` != 0 also store the flat pixel indices from ``work[o]`` on, in order."""
    c = int(0)
    for k in range(k0, wp.min(k0 + words, nwords)):
        i = word_of(k, tile, tiles_x, words_x, h, tile_order)
        if i >= 0:
            v = set_bytes(mask64[i]) & set_bytes(keep64[i])
            if v != wp.uint64(0):
                if write != 0:
                    for b in range(8):
                        if ((v >> wp.uint64(8 * b)) & wp.uint64(1)) != wp.uint64(0):
                            work[o + c] = i * 8 + b
                            c += 1
                else:
                    c += count_set(v)
    return c


@wp.kernel(enable_backward=False)
def compact_count_words_kernel(mask64: wp.array(dtype=wp.uint64), keep64: wp.array(dtype=wp.uint64),
                               tile_order: wp.array(dtype=wp.int32), tile: int,
                               tiles_x: int, words_x: int, h: int, nwords: int, words: int,
                               block_counts: wp.array(dtype=wp.int32)):
    """:func:`compact_count_kernel` over 8-pixel words: block b counts runs [b * m, (b + 1) * m) of the output
    order (m = block_dim * ``words``; ``nwords`` runs in all)."""
    blk, lane = wp.tid()
    k0 = (blk * wp.block_dim() + lane) * words
    c = walk_words(mask64, keep64, k0, words, nwords, tile, tiles_x, words_x, h, tile_order, 0, 0, block_counts)
    tot = wp.tile_sum(wp.tile(c))
    if lane == 0:
        block_counts[blk] = tot[0]


@wp.kernel(enable_backward=False)
def compact_scatter_words_kernel(mask64: wp.array(dtype=wp.uint64), keep64: wp.array(dtype=wp.uint64),
                                 tile_order: wp.array(dtype=wp.int32),
                                 tile: int, tiles_x: int, words_x: int, h: int, nwords: int, words: int,
                                 block_offsets: wp.array(dtype=wp.int32), work: wp.array(dtype=wp.int32)):
    """:func:`compact_scatter_kernel` over 8-pixel words (same blocks as :func:`compact_count_words_kernel`)."""
    blk, lane = wp.tid()
    k0 = (blk * wp.block_dim() + lane) * words
    alone = wp.block_dim() == 1
    c = int(0)
    if not alone:
        c = walk_words(mask64, keep64, k0, words, nwords, tile, tiles_x, words_x, h, tile_order, 0, 0, work)
    o = block_offsets[blk] + wp.untile(wp.tile_scan_exclusive(wp.tile(c)))
    if alone or c > 0:
        walk_words(mask64, keep64, k0, words, nwords, tile, tiles_x, words_x, h, tile_order, 1, o, work)
