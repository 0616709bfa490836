"""The path integrator inside FrameLoop (``ShadingConfig.integrator = "path"``): the reference frame is the path
stage's own frame, the foveated frame accumulates its samples through the temporal resolve towards the converged
path-traced image (foveawarp.ops.render_converged, its own passes), and what the integrator cannot combine with is
refused by name."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

import foveawarp as fw
from foveawarp.ops import render_converged
from foveawarp.stages.path import PathStage

W, H = 64, 36
PATH = {"integrator": "path", "max_depth": 3, "spp": 2}


def _cornell():
    return fw.load_scene("cornell", area_light=True)


def test_reference_frame_is_the_path_stage_frame(device):
    scene = _cornell()
    loop = fw.FrameLoop(scene, W, H, config=fw.Config().with_(shading=PATH), device=device)
    loop.render_reference(scene.camera)
    got = loop.radiance.numpy().copy()
    stage = PathStage(loop.dscene, loop.config.shading, W, H, device)
    out = wp.zeros((H, W), dtype=wp.vec3, device=device)
    stage.run(scene.camera, loop.frame_index, out)
    want = out.numpy()
    np.testing.assert_array_equal(got, want)
    assert np.isfinite(got).all() and got.max() > 0.0


def _still_series(scene, cfg, device, conv, frames=24):
    loop = fw.FrameLoop(scene, W, H, config=cfg, device=device, policy="foveated")
    lit = conv.sum(-1) > 1e-3
    errs = []
    for i in range(frames):
        f = loop.render(scene.camera, gaze_px=(0.4 * W, 0.5 * H))
        hdr = loop.hdr.numpy()
        assert np.isfinite(hdr).all(), i
        errs.append(float(np.sqrt(np.mean((hdr[lit] - conv[lit]) ** 2))))
        assert f.stats["paths_traced"] == int(loop.reorder.count.numpy()[0]) * PATH["spp"]
        assert "rays_traced" not in f.stats
    return errs, float(hdr[lit].mean() / conv[lit].mean())


def test_foveated_frames_converge_to_the_path_traced_image(device):
    """A still view: the foveated loop's HDR frame gets closer to the converged image as frames accumulate (RMSE
    over the pixels the converged image lights, frame 24 at most 0.6x frame 1), every frame finite, and stats count
    the paths traced. A still view's history is clipped with the wide still box (still_clamp_gamma 100): the mean
    is within 3 % of the converged mean (0.997 measured). With the motion box instead (1.25) clipping pulls the
    heavy-tailed path estimates towards their neighbours: the mean falls below 0.97 (0.917 measured) and the error
    of the last frame is larger."""
    scene = _cornell()
    # the periphery filter off: the temporal accumulation is under test (tests/test_path_filter.py: with it)
    cfg = fw.Config().with_(shading={**PATH, "path_filter": "none"})
    conv = render_converged(scene, scene.camera, W, H, 1024, max_depth=3, device=device, shading=cfg.shading)
    errs, ratio = _still_series(scene, cfg, device, conv)
    assert errs[-1] <= 0.6 * errs[0], errs
    assert abs(ratio - 1.0) < 0.03, ratio
    clipped_errs, clipped_ratio = _still_series(scene, cfg.with_(temporal={"still_clamp_gamma": 1.25}), device, conv)
    assert 0.75 < clipped_ratio < 0.97, clipped_ratio
    assert errs[-1] < clipped_errs[-1], (errs[-1], clipped_errs[-1])


def test_full_policy_frame_is_one_path_traced_frame(device):
    scene = _cornell()
    loop = fw.FrameLoop(scene, W, H, config=fw.Config().with_(shading=PATH), device=device, policy="full")
    f = loop.render(scene.camera, gaze_px=(W / 2, H / 2))
    assert f.stats["paths_traced"] == W * H * PATH["spp"] and f.stats["sampling_rate"] == 1.0
    assert np.isfinite(f.image.numpy()).all()


@pytest.mark.parametrize("over, scene, match", [
    ({"foveation": {"gbuffer": "sparse"}}, "cornell", "gbuffer 'full'"),
    ({"shading": {"indirect": "lighttree"}}, "cornell", "ShadingConfig.indirect must be 'none'"),
])
def test_refused_combinations(over, scene, match):
    """Refused by name: by FrameLoop (what the scene or the G-buffer cannot give the path integrator) or already
    by the Config (settings that exclude each other)."""
    with pytest.raises(ValueError, match=match):
        cfg = fw.Config().with_(shading=PATH).with_(**over)
        fw.FrameLoop(scene, W, H, config=cfg, device="cpu")


def test_frame_budget_moves_paths_to_the_fovea(device):
    """path_budget "frame": the traced pixels share a full-resolution frame's paths by sampling probability, so
    the fovea's pixels get more paths than a full-resolution frame gives them and the periphery fewer per pixel;
    the paths spent are the budget within the stochastic rounding (no pixel at the max_spp cap here), each
    traced pixel at least 1; stats by band add up to the list."""
    scene = _cornell()
    w, h = 160, 90
    cfg = fw.Config().with_(shading={**PATH, "path_budget": "frame", "max_spp": 64})
    loop = fw.FrameLoop(scene, w, h, config=cfg, device=device, policy="foveated")
    for _ in range(3):
        f = loop.render(scene.camera, gaze_px=(0.4 * w, 0.5 * h))
    n = int(loop.reorder.count.numpy()[0])
    idx = loop.reorder.work.numpy()[:n]
    used = loop.path.spp_used.numpy().ravel()[idx]
    p = loop.sampling.probability.numpy().ravel()[idx]
    budget = PATH["spp"] * w * h
    share = budget * p / p.sum()
    assert used.min() >= 1 and used.max() <= 64 and share.max() < 64
    assert abs(int(used.sum()) - budget) <= 4.0 * np.sqrt(n) + np.count_nonzero(share < 1.0)
    np.testing.assert_allclose(used, share, atol=1.0 + 1e-4)  # stochastic rounding of each share
    bands = f.stats["paths_by_band"]
    assert sum(b["paths"] for b in bands.values()) == f.stats["paths_traced"] == int(used.sum())
    assert sum(b["pixels"] for b in bands.values()) == w * h and sum(b["traced"] for b in bands.values()) == n
    # the fovea gets the saved paths: more per pixel than a full-resolution frame, the periphery fewer
    assert bands["0-5"]["paths_per_pixel"] > 2 * PATH["spp"] > 4 * bands["20+"]["paths_per_pixel"]
    assert np.isfinite(f.image.numpy()).all()


def test_budget_config_validated():
    with pytest.raises(ValueError, match="path_budget"):
        fw.ShadingConfig(path_budget="fovea")
    with pytest.raises(ValueError, match="max_spp"):
        fw.ShadingConfig(max_spp=0)
