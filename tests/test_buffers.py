"""Frame.numpy() and GBuffer.numpy() keep the data: the arrays they return are copies, which the next render does
not change (on the CPU device ``wp.array.numpy()`` is a view of the loop's own buffer)."""

import numpy as np

import foveawarp as fw


def test_frame_numpy_is_a_copy_the_next_render_leaves_alone(device):
    scene = fw.load_scene("cornell")
    loop = fw.FrameLoop(scene, 32, 24, device=device, timing=False, policy="foveated")
    f0 = loop.render(scene.camera_at(0.0), gaze_px=(8.0, 12.0), time=0.0)
    img, live = f0.numpy(), f0.image.numpy()
    kept = img.copy()
    gb = f0.gbuffer.numpy()
    depth = gb["depth"].copy()
    assert img.shape == (24, 32, 3) and img.dtype == np.float32 and np.array_equal(img, live)
    # a different camera and gaze: the loop's buffers change, the returned arrays do not
    f1 = loop.render(scene.camera_at(1.5), gaze_px=(28.0, 4.0), time=1.5)
    assert not np.array_equal(f1.numpy(), kept), "the second frame should differ from the first"
    assert np.array_equal(img, kept) and np.array_equal(gb["depth"], depth)
    assert not np.shares_memory(img, f1.image.numpy())
