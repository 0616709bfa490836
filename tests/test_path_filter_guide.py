"""The a-trous filter's variance guide (``ShadingConfig.path_filter_guide = "variance"``; kernels/atrous.py,
stages/path_filter.py): the temporal luminance moments and one guided iteration against NumPy transcriptions of
the module docstring (1e-5), what the guide is for (a clean edge of light kept where the relative stop blurs it,
strong noise still averaged), finite output from any input (hypothesis), and inside FrameLoop: the fovea exactly as
with the relative stop, the periphery no further from the converged image, eager and replayed frames alike, and
a full-resolution frame in between restarting the moments."""

from __future__ import annotations

import math

import numpy as np
import pytest
import warp as wp
from hypothesis import given, settings
from hypothesis import strategies as st
from test_path_filter import inputs, np_atrous
from test_path_history import EPS, FOVEA, GB, H, W, frame_params, np_reprojected, scene_arrays

import foveawarp as fw
from foveawarp.kernels.atrous import MOMENTS_MIN_FRAMES, luminance_moments_kernel
from foveawarp.kernels.atrous_guided import atrous_guided_kernel
from foveawarp.metrics import eccentricity_np
from foveawarp.ops import render_converged
from foveawarp.stages.path_filter import PathFilterStage

LUM = np.array([0.2126, 0.7152, 0.0722])
ALPHA = PathFilterStage.MOMENTS_ALPHA


def np_moments(cur, hit, depth, uv, prev_dist, hist, hist_depth, use):
    """(moments, variance) of the docstring in float64, tap by tap."""
    h, w, _ = cur.shape
    lum = cur @ LUM
    mom = np.stack([lum, lum * lum, np.ones_like(lum)], axis=-1)
    for y in range(h):
        for x in range(w):
            if not use or not hit[y, x]:
                continue
            hm = np_reprojected(hist, hist_depth, uv, prev_dist, depth, x, y)
            if hm is not None:
                n = min(max(hm[2], 0.0), 1e6) + 1.0
                a = max(ALPHA, 1.0 / n)
                mom[y, x] = (hm[0] + (lum[y, x] - hm[0]) * a, hm[1] + (lum[y, x] ** 2 - hm[1]) * a, n)
    var = np.where(mom[..., 2] >= MOMENTS_MIN_FRAMES, np.maximum(mom[..., 1] - mom[..., 0] ** 2, 0.0), -1.0)
    return mom, var


def arr(a, dtype, d="cpu"):
    return wp.array(np.ascontiguousarray(a).astype(np.float32 if dtype is not wp.uint8 else np.uint8), dtype=dtype,
                    device=d)


def run_guided(c, var, z, n, hit, step):
    src, vsrc = arr(c, wp.vec3), arr(var, float)
    dst, vdst = wp.zeros_like(src), wp.zeros_like(vsrc)
    wp.launch(atrous_guided_kernel, dim=c.shape[:2],
              inputs=[src, vsrc, arr(z, float), arr(n, wp.vec3), arr(hit, wp.uint8), step, dst, vdst, 0],
              device="cpu")
    return dst.numpy().astype(np.float64), vdst.numpy().astype(np.float64)


@pytest.mark.parametrize("step", [1, 2, 4])
def test_one_guided_iteration_matches_numpy(step):
    c, z, n, hit = inputs(7 + step)
    r = np.random.default_rng(step)
    var = r.uniform(0.0, 0.5, c.shape[:2]) ** 2
    var[r.uniform(size=var.shape) < 0.25] = -1.0  # unknown: the relative stop
    var[0, :3] = 0.0  # known and exact: only equal luminances weigh
    got, gvar = run_guided(c, var, z, n, hit, step)
    f = lambda a: a.astype(np.float32).astype(np.float64)  # noqa: E731
    want, wvar = np_atrous(f(c), f(z), f(n), hit, step, f(var))
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(gvar, wvar, rtol=1e-5, atol=1e-9)
    assert (gvar[var < 0] == -1.0).all() and (gvar[(var >= 0) & hit] >= 0).all()


def run_moments(cur, hit, depth, uv, prev_dist, hist, hist_depth, use=True, valid=True):
    d = "cpu"
    mom, var = wp.zeros((H, W), dtype=wp.vec3, device=d), wp.zeros((H, W), dtype=float, device=d)
    wp.launch(luminance_moments_kernel, dim=(H, W),
              inputs=[arr(cur, wp.vec3), arr(hit, wp.uint8), arr(depth, float), arr(uv, wp.vec2),
                      arr(prev_dist, float), arr(hist, wp.vec3), arr(hist_depth, float),
                      wp.array([int(valid)], dtype=wp.int32, device=d), int(use), ALPHA, EPS, mom, var, 0],
              device=d)
    return mom.numpy().astype(np.float64), var.numpy().astype(np.float64)


@pytest.mark.parametrize("use", [True, False])
def test_moments_match_numpy(use):
    cur, hist3, hist_depth, hit, depth, uv, prev_dist = scene_arrays(5)
    r = np.random.default_rng(1)
    m1 = r.uniform(0.0, 1.5, (H, W))
    hist = np.stack([m1, m1 * m1 + r.uniform(0.0, 0.3, (H, W)), r.integers(0, 9, (H, W)).astype(float)], axis=-1)
    f = lambda a: a.astype(np.float32).astype(np.float64)  # noqa: E731
    got, gvar = run_moments(cur, hit, depth, uv, prev_dist, hist, hist_depth, use)
    want, wvar = np_moments(f(cur), hit, f(depth), f(uv), f(prev_dist), f(hist), f(hist_depth), use)
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-6)
    away = np.abs(want[..., 2] - MOMENTS_MIN_FRAMES) > 1e-3  # float32 rounding decides at the threshold itself
    np.testing.assert_allclose(gvar[away], wvar[away], rtol=1e-4, atol=1e-6)
    fresh = got[..., 2] == 1.0
    if use:  # carried over where the history holds, afresh on background, no reprojection and disocclusion
        assert (~fresh).sum() > 0.5 * fresh.size and (gvar >= 0).sum() > 0.2 * gvar.size
        assert fresh[~hit].all() and fresh[:2].all() and fresh[11:15, 27:32].all()
    else:
        assert fresh.all() and (gvar == -1.0).all()


def still_stage(iterations, fovea_deg, guide):
    """A stage over one still, flat surface facing the camera: (stage, its G-buffer, an output frame)."""
    d = "cpu"
    stage = PathFilterStage(W, H, d, iterations, fovea_deg, guide, EPS)
    yy, xx = np.mgrid[0:H, 0:W]
    uv = np.stack([xx + 0.5, yy + 0.5], axis=-1)
    depth = np.full((H, W), 2.0)
    g = GB(np.ones((H, W), bool), depth, uv, depth)
    g.normal = arr(np.tile([0.0, 0.0, 1.0], (H, W, 1)), wp.vec3)
    return stage, g, wp.zeros((H, W), dtype=wp.vec3, device=d)


def test_moments_of_a_still_noisy_pixel_give_its_variance():
    """80 frames of one still surface whose luminance is Gaussian (mean 0.5, sd 0.1) per pixel and frame: the
    moments' variance is the noise's, within 35 % over the image (an exponential window of about 10 frames)."""
    stage, g, out = still_stage(1, FOVEA, "variance")
    r = np.random.default_rng(4)
    for k in range(80):
        lum = 0.5 + 0.1 * r.standard_normal((H, W))
        stage.run(arr(np.repeat(lum[..., None], 3, axis=2), wp.vec3), g, frame_params(), out, k > 0)
    var = stage.variance[0].numpy()
    assert (var >= 0).all()
    assert 0.65 * 0.01 < float(np.mean(var)) < 1.35 * 0.01
    stage.reset()
    stage.run(arr(np.full((H, W, 3), 0.5), wp.vec3), g, frame_params(), out, True)
    assert (stage.variance[0].numpy() == -1.0).all()  # reset: the moments start afresh


def filter_twice(img, guide, frames=8, iterations=5):
    """The stage's output after ``frames`` still frames of ``img`` plus fresh noise (sd 0.02 per frame), the
    fovea far off-image so every pixel is filtered in full."""
    stage, g, out = still_stage(iterations, 0.0, guide)
    r = np.random.default_rng(9)
    for k in range(frames):
        noisy = img + 0.02 * r.standard_normal(img.shape[:2])[..., None]
        stage.run(arr(noisy, wp.vec3), g, frame_params(), out, k > 0)
    return out.numpy().astype(np.float64)


def test_the_guide_keeps_a_clean_edge_of_light_that_the_relative_stop_blurs():
    """A shadow edge (luminance 1 against 0.3, barely noisy) after 5 iterations: next to the edge the relative
    stop lets the other side in (its weight exp(-0.7 / 0.65) ~ 0.34 per tap), the variance guide does not."""
    img = np.where((np.arange(W) < W // 2)[None, :, None], 1.0, 0.3) * np.ones((H, W, 3))
    err = {g: np.abs(filter_twice(img, g) - img)[:, W // 2 - 2:W // 2 + 2].max() for g in ("relative", "variance")}
    assert err["variance"] < 0.05 and err["relative"] > 0.1, err


def test_the_guide_still_averages_strong_noise():
    """A flat surface under strong noise (luminance 0.5, sd 0.25 a frame), 3 iterations after 12 frames: the
    guide's stop widens with the noise, so its residual error stays near the relative stop's (0.85x, 1.08x and
    1.23x at seeds 2, 3, 4; bound 1.3x at seed 2), an order of magnitude below the unfiltered noise."""
    r = np.random.default_rng(2)
    res = {}
    for guide in ("relative", "variance"):
        stage, g, out = still_stage(3, 0.0, guide)
        for k in range(12):
            lum = np.clip(0.5 + 0.25 * r.standard_normal((H, W)), 0.0, None)
            stage.run(arr(np.repeat(lum[..., None], 3, axis=2), wp.vec3), g, frame_params(), out, k > 0)
        res[guide] = float(np.sqrt(np.mean((out.numpy()[4:-4, 4:-4] - 0.5) ** 2)))
    assert res["variance"] < 1.3 * res["relative"] and res["variance"] < 0.05, res


@settings(max_examples=25, deadline=None)
@given(st.lists(st.sampled_from([0.0, 1.0, 1e38, -1e38, math.inf, -math.inf, math.nan, 1e-30]), min_size=4,
                max_size=4), st.integers(0, 3))
def test_any_input_gives_finite_output(bad, seed):
    """NaN, Inf or float32's extremes in the frame and in the moments' history, an off-screen reprojection:
    the filtered frame and the variances stay finite (the frame's own bad pixels aside)."""
    cur, hist3, hist_depth, hit, depth, uv, prev_dist = scene_arrays(seed)
    cur[3, 5], cur[7, 9] = bad[0], bad[1]
    hist = np.stack([hist3[..., 0], hist3[..., 1], np.full((H, W), 6.0)], axis=-1)
    hist[4, 4], hist[8, 20, 2] = bad[2], bad[3]
    uv[12, 12] = (-1e9, 1e9)
    mom, var = run_moments(cur, hit, depth, uv, prev_dist, hist, hist_depth)
    assert np.isfinite(var).all() and np.isfinite(mom[..., 2]).all()
    n = np.tile([0.0, 0.0, 1.0], (H, W, 1))
    clean = cur.copy()
    clean[~np.isfinite(clean)] = 0.0
    clean = np.clip(clean, -1e30, 1e30)
    out, vout = run_guided(clean, var, depth, n, hit, 1)
    assert np.isfinite(out).all() and np.isfinite(vout).all()


PATH = {"integrator": "path", "max_depth": 3, "rr_depth": 5, "spp": 2}


def test_frame_loop_fovea_unchanged_periphery_no_worse():
    """Cornell along its path (64x36, CPU): the fovea is bit-identical with either stop; beyond 10 degrees the
    frame's error against a 256-path converged frame is within 5 % of the relative stop's; eager and replayed
    (timing=False) frames are bit-identical; a full-resolution frame in between restarts the moments."""
    scene = fw.load_scene("cornell", area_light=True)
    w, h = 64, 36
    gaze = (0.35 * w, 0.5 * h)
    imgs, errs = {}, {}
    conv = None
    for guide in ("relative", "variance"):
        for timing in (True, False):
            cfg = fw.Config().with_(shading={**PATH, "path_filter_guide": guide})
            loop = fw.FrameLoop(scene, w, h, config=cfg, device="cpu", policy="foveated", timing=timing)
            for i in range(10):
                loop.render(scene.camera_at(i / 30.0), gaze_px=gaze, time=i / 30.0)
            imgs[guide, timing] = loop.hdr.numpy().copy()
        if conv is None:
            shading = fw.Config().with_(shading=PATH).shading
            conv = render_converged(scene, scene.camera_at(9 / 30.0), w, h, 256, max_depth=3, device="cpu",
                                    shading=shading)
        ecc = eccentricity_np(w, h, gaze, scene.camera.fov_y_deg)
        tm = lambda x: x / (1.0 + x)  # noqa: E731
        errs[guide] = float(np.sqrt(np.mean((tm(imgs[guide, True]) - tm(conv))[ecc > 10] ** 2)))
    ecc = eccentricity_np(w, h, gaze, scene.camera.fov_y_deg)
    fovea = ecc <= 5.0
    assert fovea.sum() > 10
    np.testing.assert_array_equal(imgs["relative", True][fovea], imgs["variance", True][fovea])
    assert not np.array_equal(imgs["relative", True], imgs["variance", True])
    np.testing.assert_array_equal(imgs["variance", True], imgs["variance", False])
    assert errs["variance"] <= 1.05 * errs["relative"], errs
    # a full-resolution frame between foveated ones restarts the moments
    loop = fw.FrameLoop(scene, w, h, config=fw.Config().with_(shading={**PATH, "path_filter_guide": "variance"}),
                        device="cpu", policy="foveated")
    for i in range(5):
        loop.render(scene.camera, gaze_px=gaze)
    assert int(loop.path_filter.valid.numpy()[0]) == 1
    assert loop.path_filter.moments.numpy()[..., 2].max() == pytest.approx(5.0)
    loop.policy = "full"
    loop.render(scene.camera, gaze_px=gaze)
    assert int(loop.path_filter.valid.numpy()[0]) == 0
    loop.policy = "foveated"
    loop.render(scene.camera, gaze_px=gaze)
    assert loop.path_filter.moments.numpy()[..., 2].max() == 1.0
    assert (loop.path_filter.variance[0].numpy() == -1.0).all()


def test_config_validated():
    with pytest.raises(ValueError, match=r"path_filter_guide must be one of \['relative', 'variance'\]"):
        fw.ShadingConfig(path_filter_guide="svgf")
    assert fw.ShadingConfig().path_filter_guide == "relative"
