"""The periphery's history blend of foveated path tracing (``ShadingConfig.path_history``; kernels/atrous.py,
stages/path_filter.py): the kernel against a NumPy transcription of the module docstring's formula (bilinear
reprojection, depth-validated taps, the eccentricity ramp; 1e-5), the cases that leave the frame as it is, an
exponential moving average on a still view, finite output from any input (hypothesis), and inside FrameLoop:
the fovea exactly as without it, a periphery that changes less from frame to frame, and a full-resolution
frame in between emptying the history."""

from __future__ import annotations

import math

import numpy as np
import pytest
import warp as wp
from hypothesis import given, settings
from hypothesis import strategies as st

import foveawarp as fw
from foveawarp.kernels.gbuffer import NO_REPROJ
from foveawarp.kernels.sampling import FrameParams
from foveawarp.metrics import eccentricity_np
from foveawarp.ops import render_converged
from foveawarp.stages.path_filter import PeripheryHistoryStage

W, H, FOV = 40, 24, 60.0
GAZE = (12.3, 9.7)
FOVEA = 5.0
EPS = 0.01


class GB:
    """The G-buffer fields the stage reads."""

    def __init__(self, hit, depth, reproj_uv, prev_dist, d="cpu"):
        self.hit = wp.array(hit.astype(np.uint8), dtype=wp.uint8, device=d)
        self.depth = wp.array(depth.astype(np.float32), dtype=float, device=d)
        self.reproj_uv = wp.array(reproj_uv.astype(np.float32), dtype=wp.vec2, device=d)
        self.prev_dist = wp.array(prev_dist.astype(np.float32), dtype=float, device=d)


def frame_params(d="cpu"):
    fp = FrameParams()
    fp.gaze = wp.vec2(*GAZE)
    fp.tan_half_fov_y = math.tan(math.radians(FOV) / 2)
    return wp.array([fp], dtype=FrameParams, device=d)


def ramp(ecc, fovea):
    return np.clip(ecc / fovea - 1.0, 0.0, 1.0)


def np_blend(cur, hist, hist_depth, hit, depth, uv, prev_dist, weight):
    """The docstring's formula in float64, tap by tap."""
    a_px = weight * ramp(eccentricity_np(W, H, GAZE, FOV), FOVEA)
    out = cur.astype(np.float64).copy()
    for y in range(H):
        for x in range(W):
            if not hit[y, x] or a_px[y, x] <= 0:
                continue
            hv = np_reprojected(hist, hist_depth, uv, prev_dist, depth, x, y)
            if hv is not None:
                out[y, x] = cur[y, x] + (hv - cur[y, x]) * a_px[y, x]
    return out


def np_reprojected(hist, hist_depth, uv, prev_dist, depth, x, y):
    """The previous frame's value at pixel (x, y)'s reprojected position, bilinear over the depth-matching taps,
    renormalized; None without reprojection or matching tap."""
    if (uv[y, x] == NO_REPROJ).all():
        return None
    h, w = hist.shape[:2]
    u, v = uv[y, x, 0] - 0.5, uv[y, x, 1] - 0.5
    x0, y0 = math.floor(u), math.floor(v)
    fx, fy = u - x0, v - y0
    acc, ws = np.zeros(hist.shape[2]), 0.0
    for tx, ty, wt in ((x0, y0, (1 - fx) * (1 - fy)), (x0 + 1, y0, fx * (1 - fy)),
                       (x0, y0 + 1, (1 - fx) * fy), (x0 + 1, y0 + 1, fx * fy)):
        if wt <= 0 or not (0 <= tx < w and 0 <= ty < h):
            continue
        if abs(hist_depth[ty, tx] - prev_dist[y, x]) >= EPS * depth[y, x]:
            continue
        acc += wt * hist[ty, tx]
        ws += wt
    return acc / ws if ws > 1e-6 else None


def scene_arrays(seed):
    """Random colours and a surface of varying depth moved by a sub-pixel shift (away from the resolve's 1/128
    snap), a background strip, a strip without reprojection and a disoccluded patch (history depth off)."""
    r = np.random.default_rng(seed)
    cur = r.uniform(0.0, 2.0, (H, W, 3))
    hist = r.uniform(0.0, 2.0, (H, W, 3))
    depth = r.uniform(2.0, 3.0, (H, W))
    hit = np.ones((H, W), bool)
    hit[:, -3:] = False
    yy, xx = np.mgrid[0:H, 0:W]
    uv = np.stack([xx + 0.5 + 0.37, yy + 0.5 - 0.21], axis=-1)
    uv[:2] = NO_REPROJ
    prev_dist = depth * (1.0 + r.uniform(-0.004, 0.004, (H, W)))
    hist_depth = np.roll(prev_dist, (0, 0), axis=(0, 1)).copy()
    hist_depth[10:16, 25:33] += 1.0  # disoccluded: no tap matches
    return cur, hist, hist_depth, hit, depth, uv, prev_dist


def run_stage(cur, hist, hist_depth, hit, depth, uv, prev_dist, weight, use_history=True, valid=True):
    d = "cpu"
    st_ = PeripheryHistoryStage(W, H, d, weight, FOVEA, EPS)
    st_.history = wp.array(hist.astype(np.float32), dtype=wp.vec3, device=d)
    st_.history_depth = wp.array(hist_depth.astype(np.float32), dtype=float, device=d)
    st_.valid = wp.array([1 if valid else 0], dtype=wp.int32, device=d)
    out = wp.zeros((H, W), dtype=wp.vec3, device=d)
    src = wp.array(cur.astype(np.float32), dtype=wp.vec3, device=d)
    st_.run(src, GB(hit, depth, uv, prev_dist), frame_params(), out, use_history)
    return out.numpy().astype(np.float64), st_


@pytest.mark.parametrize("weight", [0.5, 0.95])
def test_blend_matches_numpy(weight):
    arrs = scene_arrays(3)
    got, st_ = run_stage(*arrs, weight)
    cur, hist, hist_depth, hit, depth, uv, prev_dist = arrs
    want = np_blend(cur.astype(np.float32), hist.astype(np.float32), hist_depth.astype(np.float32), hit,
                    depth.astype(np.float32), uv.astype(np.float32), prev_dist.astype(np.float32), weight)
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-6)
    # the cases must all occur: blended pixels, the fovea, background, no reprojection, disocclusion
    ecc = eccentricity_np(W, H, GAZE, FOV)
    moved = np.abs(got - cur.astype(np.float32)).max(axis=-1) > 1e-4
    assert moved.sum() > 0.3 * moved.size
    assert (ecc <= FOVEA).sum() > 10 and not moved[ecc <= FOVEA].any()
    assert not moved[~hit].any() and not moved[:2].any() and not moved[11:15, 27:32].any()
    # the output and the depth become the next frame's history
    np.testing.assert_array_equal(st_.history.numpy(), got.astype(np.float32))
    np.testing.assert_array_equal(st_.history_depth.numpy(), depth.astype(np.float32))
    assert st_.valid.numpy()[0] == 1


def test_no_history_leaves_the_frame():
    arrs = scene_arrays(4)
    cur = arrs[0].astype(np.float32)
    for kw in ({"use_history": False}, {"valid": False}):
        got, _ = run_stage(*arrs, 0.9, **kw)
        np.testing.assert_array_equal(got, cur)
    got, st_ = run_stage(*arrs, 0.9)
    st_.reset()
    assert st_.valid.numpy()[0] == 0


def test_still_view_is_an_exponential_moving_average():
    """Reprojection onto the pixel itself: out_t = a h_{t-1} + (1 - a) c_t per pixel, a = weight x ramp."""
    d = "cpu"
    r = np.random.default_rng(5)
    yy, xx = np.mgrid[0:H, 0:W]
    depth = np.full((H, W), 2.0)
    g = GB(np.ones((H, W), bool), depth, np.stack([xx + 0.5, yy + 0.5], -1), depth)
    st_ = PeripheryHistoryStage(W, H, d, 0.8, FOVEA, EPS)
    a = 0.8 * ramp(eccentricity_np(W, H, GAZE, FOV), FOVEA)[..., None]
    out = wp.zeros((H, W), dtype=wp.vec3, device=d)
    ema = None
    for t in range(6):
        c = r.uniform(0, 1, (H, W, 3)).astype(np.float32)
        st_.run(wp.array(c, dtype=wp.vec3, device=d), g, frame_params(), out, t > 0)
        ema = c.astype(np.float64) if ema is None else a * ema + (1 - a) * c
        np.testing.assert_allclose(out.numpy(), ema, rtol=1e-5, atol=1e-6)


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 2**31 - 1), st.sampled_from([np.nan, np.inf, -np.inf, 1e38]),
       st.floats(-50.0, 50.0), st.floats(0.0, 0.95))
def test_finite_for_any_history(seed, bad, shift, weight):
    """Non-finite or huge history, depths of zero, reprojections far off screen: the output stays finite."""
    cur, hist, hist_depth, hit, depth, uv, prev_dist = scene_arrays(seed % 1000)
    r = np.random.default_rng(seed)
    hist[r.uniform(size=(H, W)) < 0.3] = bad
    depth[r.uniform(size=(H, W)) < 0.1] = 0.0
    uv = uv + shift
    got, _ = run_stage(cur, hist, hist_depth, hit, depth, uv, prev_dist, weight)
    assert np.isfinite(got).all()


def test_config_validated():
    for bad in (-0.1, 0.96, float("nan")):
        with pytest.raises(ValueError, match=r"path_history must be (a finite number )?in \[0\.0, 0\.95\]"):
            fw.ShadingConfig(path_history=bad)


LW, LH = 160, 90
PATH = {"integrator": "path", "max_depth": 3, "spp": 1}


def test_frame_loop_steadies_the_periphery_only(device):
    """Two loops, the same seeds, with and without the history (0.75), along cornell's camera path: pixels
    within 5 degrees of the gaze are identical; beyond 10 degrees the mean change from frame to frame falls below
    0.7 of the loop without it (0.54 measured) and the last frame's error against the converged image
    (RMSE of x / (1 + x)) does not grow by more than 5 % (0.0298 against 0.0308 measured)."""
    scene = fw.load_scene("cornell", area_light=True)
    gaze = (0.35 * LW, 0.45 * LH)
    out, change = {}, {}
    for ph in (0.0, 0.75):
        cfg = fw.Config().with_(shading={**PATH, "path_history": ph})
        loop = fw.FrameLoop(scene, LW, LH, config=cfg, device=device, policy="foveated")
        assert (loop.path_history is not None) == (ph > 0)
        frames = []
        for i in range(8):
            cam = scene.camera_at(i / 30.0)
            loop.render(cam, gaze_px=gaze)
            frames.append(loop.hdr.numpy().copy())
        out[ph] = frames[-1]
        v = np.stack(frames[2:])
        assert np.isfinite(v).all()
        ecc = eccentricity_np(LW, LH, gaze, cam.fov_y_deg)
        far = ecc >= 10.0
        tm = v / (1.0 + v)
        change[ph] = float(np.abs(np.diff(tm, axis=0))[:, far].mean())
    fovea = ecc <= 5.0
    assert fovea.sum() > 20
    np.testing.assert_array_equal(out[0.75][fovea], out[0.0][fovea])
    assert change[0.75] < 0.7 * change[0.0], change
    conv = render_converged(scene, cam, LW, LH, 256, max_depth=3, device=device,
                            shading=fw.Config().with_(shading=PATH).shading)
    err = {ph: float(np.sqrt(np.mean((out[ph][far] / (1 + out[ph][far]) - conv[far] / (1 + conv[far])) ** 2)))
           for ph in out}
    assert err[0.75] < 1.05 * err[0.0], err


def test_a_full_resolution_frame_resets_the_history():
    """A full-resolution frame between foveated ones (the policy switched) empties the history: the next
    foveated frame is the filtered frame itself; the one after blends again."""
    scene = fw.load_scene("cornell", area_light=True)
    cfg = fw.Config().with_(shading={**PATH, "path_history": 0.75})
    loop = fw.FrameLoop(scene, 64, 36, config=cfg, device="cpu", policy="foveated")
    gaze = (20.0, 18.0)
    for i in range(3):
        loop.render(scene.camera_at(i / 30.0), gaze_px=gaze)
    assert loop.path_history.valid.numpy()[0] == 1
    assert not np.array_equal(loop.held.numpy(), loop.filtered.numpy())
    loop.policy = "full"
    loop.render(scene.camera_at(3 / 30.0), gaze_px=gaze)
    assert loop.path_history.valid.numpy()[0] == 0
    loop.policy = "foveated"
    loop.render(scene.camera_at(4 / 30.0), gaze_px=gaze)
    np.testing.assert_array_equal(loop.held.numpy(), loop.filtered.numpy())
    loop.render(scene.camera_at(5 / 30.0), gaze_px=gaze)
    assert not np.array_equal(loop.held.numpy(), loop.filtered.numpy())
