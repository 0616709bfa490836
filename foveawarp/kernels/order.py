"""Thread order of per-pixel CUDA launches: each warp's 32 threads on an 8 x 4 block of pixels.

A launch over (H, W) gives a warp 32 pixels of one row. Rays through an 8 x 4 block spread less (a block's
rays are closer together in angle and in what they hit), so the lanes of a warp walk more of the same BVH nodes.
The "tiles" launches run ``tile_order_threads(H, W)`` threads in one dimension (the blocks cover the image
padded up to whole blocks); thread ``i`` takes pixel ``tile_order_pixel(i, W)`` and skips it when it lies
outside the image. Each pixel's result does not depend on the order, only the speed does.
"""

import warp as wp

ORDER_TW = wp.constant(8)  # block width, pixels
ORDER_TH = wp.constant(4)  # block height, pixels (ORDER_TW * ORDER_TH = 32 = a warp)


@wp.func
def tile_order_pixel(i: int, width: int) -> wp.vec2i:
    """(x, y) of thread ``i``: warp ``i // 32`` covers block ``i // 32`` of a row-major grid of 8 x 4 blocks
    ``ceil(width / 8)`` wide, lane ``i % 32`` its pixel in row-major order. x may reach past ``width - 1``, y past
    the image's last row (the padding): the caller skips those."""
    t = i >> 5
    lane = i & 31
    bx = (width + ORDER_TW - 1) // ORDER_TW
    by = t // bx
    return wp.vec2i((t - by * bx) * ORDER_TW + (lane & 7), by * ORDER_TH + (lane >> 3))


def tile_order_threads(height: int, width: int) -> int:
    """Threads of a "tiles" launch over an (height, width) image: whole 8 x 4 blocks covering it."""
    return -(-int(height) // 4) * -(-int(width) // 8) * 32
