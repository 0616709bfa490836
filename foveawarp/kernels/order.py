"""Thread order of per-pixel CUDA launches: each warp's 32 threads on a block of pixels.

A launch over (H, W) gives a warp 32 pixels of one row. Rays through a compact block (8 x 4, or 16 x 2) spread
less: they are closer together in angle and hit the same parts of the scene, so the lanes of a warp walk more
of the same BVH nodes. The "tiles" launches run ``_util.tile_order_threads(H, W, block_width)`` threads in one
dimension (blocks of ``2**wlog2`` x ``32 / 2**wlog2`` pixels covering the image padded up to whole blocks, with
``wlog2 = _util.order_wlog2(block_width)``); thread ``i``
takes pixel ``tile_order_pixel(i, W, wlog2)`` and skips it when it lies outside the image. A pixel's result does
not depend on the order, only the speed does.
"""

import warp as wp


@wp.func
def tile_order_pixel(i: int, width: int, wlog2: int) -> wp.vec2i:
    """(x, y) of thread ``i``: warp ``i // 32`` covers block ``i // 32`` of a row-major grid of blocks
    ``2**wlog2`` pixels wide and ``32 / 2**wlog2`` high (``wlog2`` in [0, 5]), ``ceil(width / 2**wlog2)`` blocks
    across; lane ``i % 32`` takes the block's pixels in row-major order. x may reach past ``width - 1`` and y past
    the image's last row (the padding): the caller skips those."""
    t = i >> 5
    lane = i & 31
    bw = 1 << wlog2
    bx = (width + bw - 1) >> wlog2
    by = t // bx
    return wp.vec2i(((t - by * bx) << wlog2) + (lane & (bw - 1)), (by << (5 - wlog2)) + (lane >> wlog2))
