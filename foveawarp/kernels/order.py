"""Thread order of per-pixel CUDA launches: each warp's 32 threads on a block of pixels.

A launch over (H, W) gives a warp 32 pixels of one row. Rays through a compact block (8 x 4, or 16 x 2) spread
less: they are closer together in angle and hit the same parts of the scene, so the lanes of a warp walk more
of the same BVH nodes. The "tiles" launches run ``tile_order_threads(H, W, wlog2)`` threads in one dimension
(blocks of ``2**wlog2`` x ``32 / 2**wlog2`` pixels covering the image padded up to whole blocks); thread ``i``
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


ORDER_WIDTHS = (1, 2, 4, 8, 16, 32)


def order_wlog2(block_width: int) -> int:
    """log2 of a block width in ``ORDER_WIDTHS`` (pixels; the block is 32 / width high)."""
    if not isinstance(block_width, int) or isinstance(block_width, bool) or block_width not in ORDER_WIDTHS:
        raise ValueError(f"block_width must be one of {ORDER_WIDTHS}, got {block_width!r}")
    return int(block_width).bit_length() - 1


def tile_order_threads(height: int, width: int, block_width: int = 8) -> int:
    """Threads of a "tiles" launch over an (height, width) image: whole blocks ``block_width`` x
    ``32 / block_width`` covering it."""
    bh = 32 // block_width
    return -(-int(height) // bh) * -(-int(width) // block_width) * 32
