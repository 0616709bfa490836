"""Work compaction and reordering of the sampled pixels (thesis A3).

- row CSR (strategy 1): each row's sampled pixels packed to the left of a same-size coordinate buffer;
- block balancing (strategy 2): within a block of rows, the last entry of the longest row moves to the end of
  the shortest row until the lengths differ by at most one;
- global stream compaction: flags -> exclusive scan -> scatter of flat indices (raster order), or the same over
  screen tiles taken in Morton order so that a warp's rays are neighbours.
The compacted count stays on the device (``count[0]``).
"""

import warp as wp


# ---------------------------------------------------------------------------------------------------
# strategy 1 / 2: row CSR


@wp.kernel(enable_backward=False)
def rows_compact_kernel(mask: wp.array2d(dtype=wp.uint8), coords: wp.array2d(dtype=wp.vec2i),
                        counts: wp.array(dtype=wp.int32)):
    """One thread per row: sampled (x, y) to the left of coords[y], count to counts[y] (thesis strategy 1)."""
    y = wp.tid()
    w = mask.shape[1]
    n = int(0)
    for x in range(w):
        if mask[y, x] != wp.uint8(0):
            coords[y, n] = wp.vec2i(x, y)
            n += 1
    counts[y] = n


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


@wp.kernel(enable_backward=False)
def flags_kernel(mask: wp.array2d(dtype=wp.uint8), flags: wp.array(dtype=wp.int32)):
    y, x = wp.tid()
    v = int(0)
    if mask[y, x] != wp.uint8(0):
        v = 1
    flags[y * mask.shape[1] + x] = v


@wp.kernel(enable_backward=False)
def scatter_kernel(flags: wp.array(dtype=wp.int32), offsets: wp.array(dtype=wp.int32),
                   work: wp.array(dtype=wp.int32)):
    i = wp.tid()
    if flags[i] != 0:
        work[offsets[i]] = i


@wp.kernel(enable_backward=False)
def total_kernel(flags: wp.array(dtype=wp.int32), offsets: wp.array(dtype=wp.int32),
                 count: wp.array(dtype=wp.int32)):
    n = flags.shape[0]
    if n == 0:
        count[0] = 0
    else:
        count[0] = offsets[n - 1] + flags[n - 1]


@wp.kernel(enable_backward=False)
def tile_count_kernel(mask: wp.array2d(dtype=wp.uint8), tile_order: wp.array(dtype=wp.int32), tile: int,
                      tiles_x: int, tile_counts: wp.array(dtype=wp.int32)):
    """One thread per tile, taken in Morton rank order: number of sampled pixels in the tile."""
    r = wp.tid()
    t = tile_order[r]
    ty = t // tiles_x
    tx = t - ty * tiles_x
    h = mask.shape[0]
    w = mask.shape[1]
    n = int(0)
    for j in range(tile):
        y = ty * tile + j
        if y < h:
            for i in range(tile):
                x = tx * tile + i
                if x < w:
                    if mask[y, x] != wp.uint8(0):
                        n += 1
    tile_counts[r] = n


@wp.kernel(enable_backward=False)
def tile_scatter_kernel(mask: wp.array2d(dtype=wp.uint8), tile_order: wp.array(dtype=wp.int32), tile: int,
                        tiles_x: int, tile_offsets: wp.array(dtype=wp.int32), work: wp.array(dtype=wp.int32)):
    """One thread per tile: write the tile's sampled flat indices (raster order inside the tile) at its offset."""
    r = wp.tid()
    t = tile_order[r]
    ty = t // tiles_x
    tx = t - ty * tiles_x
    h = mask.shape[0]
    w = mask.shape[1]
    o = tile_offsets[r]
    for j in range(tile):
        y = ty * tile + j
        if y < h:
            for i in range(tile):
                x = tx * tile + i
                if x < w:
                    if mask[y, x] != wp.uint8(0):
                        work[o] = y * w + x
                        o += 1
