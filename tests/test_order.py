"""Thread order of the "tiles" launches (kernels/order.py): every pixel once, warps on 8 x 4 blocks, and the
G-buffer and the full-frame shading in that order equal to the row order, bit for bit, on every device."""

import numpy as np
import pytest
import warp as wp

import foveawarp as fw
from foveawarp.kernels.order import tile_order_pixel, tile_order_threads


@wp.kernel(enable_backward=False)
def _order_kernel(width: int, xy: wp.array(dtype=wp.vec2i)):
    i = wp.tid()
    xy[i] = tile_order_pixel(i, width)


@pytest.mark.parametrize("h, w", [(1, 1), (4, 8), (5, 9), (36, 64), (17, 3), (1080, 1920)])
def test_tile_order_covers_every_pixel_once_in_warp_blocks(device, h, w):
    n = tile_order_threads(h, w)
    assert n % 32 == 0 and n >= h * w
    xy = wp.zeros(n, dtype=wp.vec2i, device=device)
    wp.launch(_order_kernel, dim=n, inputs=[w], outputs=[xy], device=device)
    xy = xy.numpy()
    inside = (xy[:, 0] < w) & (xy[:, 1] < h)
    assert (xy >= 0).all()
    # the inside threads hit every pixel exactly once
    flat = xy[inside, 1] * w + xy[inside, 0]
    np.testing.assert_array_equal(np.sort(flat), np.arange(h * w))
    # NumPy's own layout: warp k covers block (k % bx, k // bx), lane l its pixel (l % 8, l // 8)
    bx = -(-w // 8)
    k, lane = np.divmod(np.arange(n), 32)
    want = np.stack([(k % bx) * 8 + lane % 8, (k // bx) * 4 + lane // 8], axis=1)
    np.testing.assert_array_equal(xy, want)
    # the padding is only the last partial block row / column
    assert n == -(-h // 4) * 4 * bx * 8


@pytest.mark.parametrize("size", [(37, 23), (64, 36)])
@pytest.mark.parametrize("shading", ["default", "ao2"])
def test_tiles_order_renders_the_same_frames(device, size, shading, monkeypatch):
    """G-buffer and reference shading launched as warps on 8 x 4 blocks (the CUDA default) against the row
    order: every G-buffer field and the reference image equal bit for bit, odd sizes included; and the foveated
    frame that reads that G-buffer. The CPU runs the per-pixel kernels here instead of its row kernels."""
    from foveawarp import parallel
    from foveawarp.stages.gbuffer import GBufferStage
    from foveawarp.stages.shade import ShadeStage

    w, h = size
    cfg = fw.Config() if shading == "default" else fw.Config().with_(shading={"ao_samples": 2})
    scene = fw.load_scene("cornell")
    monkeypatch.setattr(parallel, "ROW_KERNELS", False)
    got = {}
    saved = GBufferStage.tile_order, ShadeStage.tile_order
    try:
        for order in (False, True):
            GBufferStage.tile_order = ShadeStage.tile_order = order
            loop = fw.FrameLoop(scene, w, h, config=cfg, device=device, policy="foveated", cpu_threads=1,
                                graph=False)
            assert loop.gbuffer_stage._kernel.key.endswith("tiles_kernel") == order
            ref = loop.render_reference(scene.camera).numpy().copy()
            g = loop.gbuffer.numpy()
            frame = loop.render(scene.camera).numpy().copy()
            got[order] = [ref, frame] + [np.ascontiguousarray(g[k]) for k in sorted(g)]
    finally:
        GBufferStage.tile_order, ShadeStage.tile_order = saved
    for a, b in zip(got[False], got[True]):
        assert a.tobytes() == b.tobytes()
