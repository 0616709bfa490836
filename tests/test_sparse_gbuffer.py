"""Sparse G-buffer mode (FoveationConfig.gbuffer = "sparse"): coarse primary rays, the sampling map from them,
the sampled pixels traced with their shading, and the reconstruction from the samples alone. Checked against
the full-resolution G-buffer and reference frame (themselves checked against trimesh / NumPy elsewhere) and
against NumPy / scikit-image / SciPy references of the coarse saliency and the probability map."""

import math

import numpy as np
import pytest
import warp as wp
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import ndimage
from skimage.color import rgb2lab

import foveawarp as fw
from foveawarp.buffers import GBuffer
from foveawarp.kernels.saliency import LAB_STEP_FULL, NORMAL_STEP_FULL, SOBEL_GAIN
from foveawarp.stages.gbuffer import GBufferStage


def sparse_config(**fov):
    return fw.Config().with_(foveation={"gbuffer": "sparse", **fov})


def cell_pixels(n, cell):
    """The middle pixel of each cell along one axis, clamped to the image (independent of the kernel)."""
    return np.minimum(np.arange(-(-n // cell)) * cell + cell // 2, n - 1)


def full_gbuffer(loop, camera, prev_camera):
    g = GBuffer(loop.width, loop.height, loop.device)
    GBufferStage(loop.dscene, loop.width, loop.height, loop.device).run(g, camera, prev_camera)
    return g.numpy()


def srgb_encode(c):
    c = np.clip(c, 0.0, 1.0)
    return np.where(c <= 0.0031308, 12.92 * c, 1.055 * np.power(c, 1.0 / 2.4) - 0.055)


def sobel_max(img):
    """max over channels of the 3x3 Sobel magnitude, replicated borders (scipy 'nearest')."""
    gx = np.stack([ndimage.sobel(img[..., k], axis=1, mode="nearest") for k in range(img.shape[-1])], -1)
    gy = np.stack([ndimage.sobel(img[..., k], axis=0, mode="nearest") for k in range(img.shape[-1])], -1)
    return np.sqrt((gx * gx + gy * gy).max(axis=-1))


def ref_probability(w, h, gaze, fov, fc):
    """Thesis eq. 2 with the falloff normalizer and the full-rate fovea, float64 (pinhole, focal f in pixels)."""
    f = 0.5 * h / math.tan(math.radians(fov) / 2.0)

    def dirs(px, py):
        px, py = np.broadcast_arrays(np.asarray(px, np.float64), np.asarray(py, np.float64))
        return np.stack([px - 0.5 * w, py - 0.5 * h, np.full(px.shape, f)], -1)

    def ang(a, b):
        return np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1)))

    ys, xs = np.mgrid[0:h, 0:w] + 0.5
    g = dirs(gaze[0], gaze[1])
    e = ang(dirs(xs, ys), g[None, None])
    w_min = float(ang(g, dirs(gaze[0] + 1.0, gaze[1])))
    t = np.linspace(0.0, 1.0, 4001)
    ex = np.concatenate([t * w, np.full_like(t, w), t * w, np.zeros_like(t)])
    ey = np.concatenate([np.zeros_like(t), t * h, np.full_like(t, h), t * h])
    e_max = float(ang(dirs(ex, ey), g[None]).max())
    e_norm = min(e_max, fc.falloff_deg) if fc.falloff_deg is not None else e_max
    m, b = fc.mar_slope, fc.mar_fovea_deg
    p = np.clip(1.0 - (m * e + b - w_min) / (m * e_norm + b), fc.effective_min_probability, 1.0)
    return np.where(e <= fc.fovea_deg, 1.0, p), e


def tile_counts(mask, k):
    h, w = mask.shape
    ty, tx = -(-h // k), -(-w // k)
    pad = np.zeros((ty * k, tx * k), dtype=np.int64)
    pad[:h, :w] = mask
    return pad.reshape(ty, k, tx, k).sum(axis=(1, 3))


@pytest.mark.parametrize("size,cell", [((64, 48), 4), ((50, 37), 3), ((40, 30), 1)])
def test_coarse_gbuffer_is_the_full_gbuffer_at_cell_centres(device, size, cell):
    w, h = size
    loop = fw.FrameLoop("cornell", w, h, config=sparse_config(coarse_cell=cell), device=device, timing=False,
                        policy="foveated")
    cam = loop.scene.camera_at(0.3)
    loop.render(cam, gaze_px=(w * 0.3, h * 0.6), time=0.3)
    full = full_gbuffer(loop, cam, cam)
    coarse = loop.sparse.coarse.numpy()
    ys, xs = cell_pixels(h, cell), cell_pixels(w, cell)
    assert coarse["depth"].shape == (len(ys), len(xs))
    for k in ("position", "normal", "depth", "albedo", "face", "hit"):
        np.testing.assert_allclose(coarse[k], full[k][np.ix_(ys, xs)], rtol=0, atol=1e-6, err_msg=k)


def test_sampled_pixels_equal_full_resolution_tracing(device):
    w, h = 80, 60
    cfg = sparse_config()
    loop = fw.FrameLoop("cornell", w, h, config=cfg, device=device, timing=False, policy="foveated")
    ref = fw.FrameLoop("cornell", w, h, config=cfg, device=device, timing=False, policy="full")
    sc = loop.scene
    for i in range(3):
        t = 0.1 * (i + 1)
        cam, prev = sc.camera_at(t), sc.camera_at(t - 0.1) if i else sc.camera_at(t)
        f = loop.render(cam, gaze_px=(20.0 + 15 * i, 30.0), time=t)
        r = ref.render_reference(cam, time=t)
        m = f.sampling_map.numpy().astype(bool)
        assert 0 < m.sum() < w * h
        g, gr = loop.gbuffer.numpy(), ref.gbuffer.numpy()
        for k in ("position", "normal", "depth", "albedo", "face", "hit"):
            np.testing.assert_allclose(g[k][m], gr[k][m], rtol=0, atol=1e-6, err_msg=k)
        # the traced pixels' radiance is the reference's, and the reconstruction keeps it (seeds are exact)
        rad, rad_ref = loop.radiance.numpy(), ref.radiance.numpy()
        np.testing.assert_allclose(rad[m], rad_ref[m], rtol=0, atol=1e-6)
        np.testing.assert_allclose(loop.recon.numpy()[m], rad_ref[m], rtol=0, atol=1e-5)
        np.testing.assert_allclose(f.image.numpy()[m], r.image.numpy()[m], rtol=0, atol=1e-5)


def test_coarse_saliency_matches_numpy_reference(device):
    w, h, cell = 96, 64, 4
    cfg = sparse_config(coarse_cell=cell)
    loop = fw.FrameLoop("cornell", w, h, config=cfg, device=device, timing=False, policy="foveated")
    cam = loop.scene.camera_at(0.0)
    loop.render(cam, gaze_px=(48.0, 32.0))  # first frame: nothing moved, no velocity term
    c = loop.sparse.coarse.numpy()
    sc = cfg.saliency
    lab = rgb2lab(srgb_encode(c["albedo"].astype(np.float64)))
    d_a = np.minimum(sc.albedo_scale / (SOBEL_GAIN * LAB_STEP_FULL) * sobel_max(lab), 1.0)
    d_n = np.minimum(sc.normal_scale / (SOBEL_GAIN * NORMAL_STEP_FULL) * sobel_max(c["normal"].astype(np.float64)),
                     1.0)
    ref = np.maximum(d_a, d_n)
    got = loop.sparse.coarse_saliency.numpy()
    assert ref.max() > 0.5  # the cornell box has edges: the test sees them
    np.testing.assert_allclose(got, ref, rtol=0, atol=2e-4)


@pytest.mark.parametrize("gaze", [(30.0, 20.0), (-40.0, 90.0), (95.0, 0.0)])
def test_probability_and_map_follow_eq2_raised_to_the_cell_saliency(device, gaze):
    w, h, cell = 96, 72, 4
    cfg = sparse_config(coarse_cell=cell)
    loop = fw.FrameLoop("cornell", w, h, config=cfg, device=device, timing=False, policy="foveated")
    cam = loop.scene.camera_at(0.0)
    loop.render(cam, gaze_px=gaze)
    fc = cfg.foveation
    p_ref, e = ref_probability(w, h, gaze, cam.fov_y_deg, fc)
    clear = np.abs(e - fc.fovea_deg) > 1e-3
    s = loop.sampling
    assert np.abs(s.probability.numpy() - p_ref)[clear].max() < 2e-5
    cs = loop.sparse.coarse_saliency.numpy()
    up = cs[np.minimum(np.arange(h) // cell, cs.shape[0] - 1)][:, np.minimum(np.arange(w) // cell, cs.shape[1] - 1)]
    sal_ref = np.clip(np.maximum(p_ref, up), fc.effective_min_probability, 1.0)
    assert np.abs(s.saliency.numpy() - sal_ref)[clear].max() < 2e-5
    m = s.sample_map.numpy()
    assert tile_counts(m, fc.block).min() >= 1
    assert (m[s.saliency.numpy() >= 1.0] == 1).all()  # probability 1 is always traced
    assert int(s.num_samples.numpy()[0]) == int(m.sum())
    assert int(s.num_cache_hits.numpy()[0]) == 0


@settings(max_examples=8, deadline=None)
@given(w=st.integers(5, 41), h=st.integers(3, 29), cell=st.integers(1, 9), block=st.integers(1, 6),
       gx=st.floats(-200.0, 200.0), gy=st.floats(-200.0, 200.0), ao=st.sampled_from([0, 2]))
def test_sparse_frames_are_finite_and_keep_the_block_guarantee(w, h, cell, block, gx, gy, ao):
    cfg = fw.Config().with_(foveation={"gbuffer": "sparse", "coarse_cell": cell, "block": block},
                            shading={"ao_samples": ao})
    loop = fw.FrameLoop("cornell", w, h, config=cfg, device="cpu", timing=False, policy="foveated")
    sc = loop.scene
    for i in range(2):
        f = loop.render(sc.camera_at(0.2 * i), gaze_px=(gx, gy), time=0.2 * i)
        img = f.image.numpy()
        assert np.isfinite(img).all() and img.min() >= 0.0 and img.max() <= 1.0
        m = f.sampling_map.numpy()
        assert tile_counts(m, block).min() >= 1
        ns = int(m.sum())
        coarse = (-(-w // cell)) * (-(-h // cell))
        assert f.stats["rays_traced"] == coarse + ns * (1 + loop._rays_per_sample())
        assert "temporal" in f.stats["skipped"] and "gbuffer" in f.stats["skipped"]


def test_sparse_quality_in_motion_is_close_to_the_full_mode():
    """Over a moving camera and gaze, the sparse mode's PSNR against full-resolution tracing stays within a few
    dB of the full G-buffer mode's (it has no per-pixel history), and both stay well above a blurred frame's."""
    from foveawarp.metrics import psnr

    w, h = 128, 72
    out = {}
    for mode in ("full", "sparse"):
        cfg = fw.Config().with_(foveation={"gbuffer": mode})
        loop = fw.FrameLoop("cornell", w, h, config=cfg, device="cpu", timing=False, policy="foveated")
        ref = fw.FrameLoop("cornell", w, h, config=cfg, device="cpu", timing=False, policy="full")
        vals = []
        for i in range(8):
            t = (i + 1) / 30.0
            cam = loop.scene.camera_at(t)
            img = loop.render(cam, gaze_px=(40.0 + 6 * i, 36.0), time=t).image.numpy()
            vals.append(psnr(ref.render_reference(cam, time=t).image.numpy(), img))
        out[mode] = float(np.mean(vals))
    assert out["sparse"] > 30.0
    assert out["sparse"] > out["full"] - 6.0


def test_sparse_mode_validation():
    with pytest.raises(ValueError, match="FoveationConfig.gbuffer"):
        fw.FoveationConfig(gbuffer="dense")
    with pytest.raises(ValueError, match="FoveationConfig.coarse_cell"):
        fw.FoveationConfig(coarse_cell=0)
    with pytest.raises(ValueError, match="FoveationConfig.coarse_cell"):
        fw.FoveationConfig(coarse_cell=65)
    cfg = fw.Config().with_(foveation={"gbuffer": "sparse"}, dof={"aperture_m": 0.02, "focus_depth_m": 2.0})
    with pytest.raises(ValueError, match="DofConfig.aperture_m"):
        fw.FrameLoop("cornell", 32, 24, config=cfg, device="cpu")


def test_sparse_graph_replay_equals_eager_on_cuda():
    # CUDA graphs exist only on CUDA (the CPU device always launches eagerly)
    if not wp.is_cuda_available():
        pytest.skip("needs a CUDA device: CUDA graph capture and replay")
    w, h = 160, 90
    cfg = sparse_config()
    a = fw.FrameLoop("cornell", w, h, config=cfg, device="cuda:0", timing=False, graph=True, policy="foveated")
    b = fw.FrameLoop("cornell", w, h, config=cfg, device="cuda:0", timing=False, graph=False, policy="foveated")
    states = []
    for i in range(5):
        t = (i + 1) / 30.0
        cam = a.scene.camera_at(t)
        fa = a.render(cam, gaze_px=(50.0 + 5 * i, 40.0), time=t)
        fb = b.render(cam, gaze_px=(50.0 + 5 * i, 40.0), time=t)
        states.append(fa.stats["graph"])
        np.testing.assert_array_equal(fa.image.numpy(), fb.image.numpy())
    assert "replayed" in states


def test_sparse_mode_sibson_window():
    from foveawarp.frame_loop import SPARSE_SIBSON_WINDOW

    a = fw.FrameLoop("cornell", 32, 24, config=sparse_config(), device="cpu", timing=False, policy="foveated")
    a._ensure_foveated_stages()
    assert a.reconstruct.window == SPARSE_SIBSON_WINDOW == 2
    b = fw.FrameLoop("cornell", 32, 24, config=sparse_config().with_(reconstruction={"sibson_window": 5}),
                     device="cpu", timing=False, policy="foveated")
    b._ensure_foveated_stages()
    assert b.reconstruct.window == 5
    c = fw.FrameLoop("cornell", 32, 24, device="cpu", timing=False, policy="foveated")  # full mode: block-exact J
    c._ensure_foveated_stages()
    assert c.reconstruct.window == 4
