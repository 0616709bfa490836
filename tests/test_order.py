"""Thread order of the "tiles" launches (kernels/order.py): every pixel once, each warp on one block, and the
G-buffer and the full-frame shading in those orders equal to the row order, bit for bit, on every device."""

import numpy as np
import pytest
import warp as wp

import foveawarp as fw
from foveawarp._util import ORDER_WIDTHS, order_wlog2, tile_order_threads
from foveawarp.kernels.order import tile_order_pixel


@wp.kernel(enable_backward=False)
def _order_kernel(width: int, wlog2: int, xy: wp.array(dtype=wp.vec2i)):
    i = wp.tid()
    xy[i] = tile_order_pixel(i, width, wlog2)


@pytest.mark.parametrize("bw", [8, 16, 32, 1])
@pytest.mark.parametrize("h, w", [(1, 1), (4, 8), (5, 9), (36, 64), (17, 3), (1080, 1920)])
def test_tile_order_covers_every_pixel_once_in_warp_blocks(device, h, w, bw):
    n = tile_order_threads(h, w, bw)
    assert n % 32 == 0 and n >= h * w
    xy = wp.zeros(n, dtype=wp.vec2i, device=device)
    wp.launch(_order_kernel, dim=n, inputs=[w, order_wlog2(bw)], outputs=[xy], device=device)
    xy = xy.numpy()
    inside = (xy[:, 0] < w) & (xy[:, 1] < h)
    assert (xy >= 0).all()
    # the inside threads hit every pixel exactly once
    flat = xy[inside, 1] * w + xy[inside, 0]
    np.testing.assert_array_equal(np.sort(flat), np.arange(h * w))
    # NumPy's own layout: warp k covers block (k % bx, k // bx), lane l its pixel (l % bw, l // bw)
    bh = 32 // bw
    bx = -(-w // bw)
    k, lane = np.divmod(np.arange(n), 32)
    want = np.stack([(k % bx) * bw + lane % bw, (k // bx) * bh + lane // bw], axis=1)
    np.testing.assert_array_equal(xy, want)
    # the padding is only the last partial block row / column
    assert n == -(-h // bh) * bh * bx * bw


def test_order_width_is_checked(device):
    """The block widths and the stages' ``order_width`` (0 or a block width), named in the error."""
    from foveawarp.stages.gbuffer import GBufferStage
    from foveawarp.stages.shade import ShadeStage

    assert [order_wlog2(b) for b in ORDER_WIDTHS] == [0, 1, 2, 3, 4, 5]
    for bad in (0, 3, 64, 8.0, "8", True):
        with pytest.raises(ValueError, match="block_width"):
            order_wlog2(bad)
    loop = fw.FrameLoop("cornell", 16, 8, device=device)
    for cls, name in ((GBufferStage, "GBufferStage.order_width"), (ShadeStage, "ShadeStage.order_width")):
        saved = cls.order_width
        try:
            for bad in (3, 64, -8, 8.5, "8", None, True):
                cls.order_width = bad
                with pytest.raises(ValueError, match=name.replace(".", r"\.") + r".*0 \(the row launch\)"):
                    if cls is GBufferStage:
                        GBufferStage(loop.dscene, 16, 8, device)
                    else:
                        loop.shade.full(loop.gbuffer, loop.radiance, loop.radiance_stoch)
        finally:
            cls.order_width = saved


@pytest.mark.parametrize("size", [(37, 23), (64, 36)])
@pytest.mark.parametrize("scene_name, shading", [("cornell", "default"), ("cornell", "ao2"), ("room", "default")])
def test_tiles_order_renders_the_same_frames(device, size, scene_name, shading, monkeypatch):
    """G-buffer and reference shading launched with each warp on an 8 x 4 block (the CUDA default) or a 16 x 2
    one against the row order: every G-buffer field and the reference image equal bit for bit, odd sizes
    included; and the foveated frame that reads that G-buffer. The textured room's G-buffer (its material fields
    included) takes the same orders. The CPU runs the per-pixel kernels here instead of its row kernels."""
    from foveawarp import parallel
    from foveawarp.stages.gbuffer import GBufferStage
    from foveawarp.stages.shade import ShadeStage

    w, h = size
    cfg = fw.Config() if shading == "default" else fw.Config().with_(shading={"ao_samples": 2})
    scene = fw.load_scene(scene_name)
    monkeypatch.setattr(parallel, "ROW_KERNELS", False)
    got = {}
    saved = GBufferStage.order_width, ShadeStage.order_width
    try:
        for order in (0, 8, 16):
            GBufferStage.order_width = ShadeStage.order_width = order
            loop = fw.FrameLoop(scene, w, h, config=cfg, device=device, policy="foveated", cpu_threads=1,
                                graph=False)
            assert loop.gbuffer_stage._kernel.key.endswith("tiles_kernel") == (order != 0)
            ref = loop.render_reference(scene.camera).numpy().copy()
            g = loop.gbuffer.numpy()
            frame = loop.render(scene.camera).numpy().copy()
            got[order] = [ref, frame] + [np.ascontiguousarray(g[k]) for k in sorted(g)]
            if scene_name == "room":
                assert loop.gbuffer.textured
                got[order] += [loop.gbuffer.material.numpy().copy(), loop.gbuffer.emission.numpy().copy()]
    finally:
        GBufferStage.order_width, ShadeStage.order_width = saved
    for order in (8, 16):
        for a, b in zip(got[0], got[order]):
            assert a.tobytes() == b.tobytes()


@pytest.mark.parametrize("threads", [1, 4])
def test_order_width_set_on_a_built_stage_takes_effect(device, threads, monkeypatch):
    """``order_width`` changed on a G-buffer stage after construction (to another width, to the row launch and
    back) still writes every pixel, equal to a stage built with that width; the CPU runs the per-pixel kernels here
    in bands of threads (``row0`` is a range of threads for the tiles kernel)."""
    from foveawarp import parallel
    from foveawarp.buffers import GBuffer
    from foveawarp.stages.gbuffer import GBufferStage

    monkeypatch.setattr(parallel, "ROW_KERNELS", False)
    w, h = 37, 23
    loop = fw.FrameLoop("cornell", w, h, device=device, cpu_threads=threads)
    cam = loop.scene.camera
    ref = GBuffer(w, h, loop.device)
    st = GBufferStage(loop.dscene, w, h, loop.device)
    with parallel.cpu_threads(threads):
        st.order_width = 0
        st.run(ref, cam, cam)
        want = ref.numpy()
        for bw in (16, 0, 4, 8):
            g = GBuffer(w, h, loop.device)
            st.order_width = bw
            st.run(g, cam, cam)
            got = g.numpy()
            for k in want:
                assert np.ascontiguousarray(got[k]).tobytes() == np.ascontiguousarray(want[k]).tobytes(), (bw, k)
        st.order_width = 12
        with pytest.raises(ValueError, match=r"GBufferStage\.order_width.*12"):
            st.run(g, cam, cam)
