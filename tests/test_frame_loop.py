"""End-to-end FrameLoop: strategies agree, history converges, skips happen when (and only when) they should."""

import math

import numpy as np
import pytest
import warp as wp

import foveawarp as fw
from foveawarp.metrics import psnr

W, H = 96, 64
STRATEGIES = ["none", "rows", "rows+balance", "scan", "tile"]


def _loop(scene="cornell", device="cpu", **stage_overrides):
    """A loop that always renders the foveated frame (these tests study its stages over many frames; the default
    "auto" policy would trace every pixel in its measurement frames and wherever that is cheaper)."""
    cfg = fw.Config().with_(**stage_overrides) if stage_overrides else fw.Config()
    return fw.FrameLoop(scene if not isinstance(scene, str) else fw.load_scene(scene), W, H, config=cfg,
                        device=device, policy="foveated")


def test_all_strategies_give_identical_images(device):
    scene = fw.load_scene("cornell")
    imgs, maps = {}, {}
    for s in STRATEGIES:
        loop = _loop(scene, device, reorder={"strategy": s})
        for i in range(2):
            f = loop.render(scene.camera_at(i / 30), gaze_px=(30.0 + 5 * i, 20.0))
        imgs[s] = f.numpy().copy()
        maps[s] = f.sampling_map.numpy().copy()
    for s in STRATEGIES[1:]:
        np.testing.assert_array_equal(maps[s], maps["none"])
        np.testing.assert_allclose(imgs[s], imgs["none"], atol=1e-6, err_msg=s)


@pytest.mark.parametrize("strategy", STRATEGIES)
def test_only_sampled_pixels_are_traced(strategy, device):
    import warp as wp

    loop = _loop("cornell", device, reorder={"strategy": strategy})
    loop.render(gaze_px=(48.0, 32.0))
    sentinel = np.full((H, W, 3), -7.0, np.float32)
    loop.radiance.assign(sentinel)
    f = loop.render(gaze_px=(48.0, 32.0))
    written = np.any(loop.radiance.numpy() != -7.0, axis=2)
    smap = f.sampling_map.numpy().astype(bool)
    # the compacting strategies list only the sampled pixels that hit (ReorderConfig.skip_misses, the default);
    # the masked launch writes the background at the sampled misses
    hit = loop.gbuffer.hit.numpy().astype(bool)
    np.testing.assert_array_equal(written, smap if strategy == "none" else smap & hit)
    assert f.stats["sampling_rate"] == pytest.approx(smap.mean())


@pytest.mark.parametrize("strategy", ["tile", "rows"])
@pytest.mark.parametrize("shading", [{"ao_samples": 0}, {"ao_samples": 2}, {"indirect": "lighttree"}])
def test_skip_misses_lists_only_hits_and_keeps_the_image(strategy, shading, device):
    """``ReorderConfig.skip_misses`` (the default) lists only the sampled pixels whose primary ray hit: the
    shading writes exactly those, and the images, sampling maps and temporal colours along a moving camera and
    gaze equal those of the loop that lists (and shades) every sampled pixel, bit for bit."""
    scene = fw.load_scene("bunny")
    loops = {k: _loop(scene, device, reorder={"strategy": strategy, "skip_misses": k}, shading=shading)
             for k in (True, False)}
    misses_sampled = 0
    for i in range(6):
        cam, gaze = scene.camera_at(i / 20), (30.0 + 6 * i, 40.0 - 3 * i)
        out = {}
        for k, loop in loops.items():
            loop.radiance.assign(np.full((H, W, 3), -7.0, np.float32))
            f = loop.render(cam, gaze_px=gaze, time=i / 20)
            smap = f.sampling_map.numpy().astype(bool)
            hit = loop.gbuffer.hit.numpy().astype(bool)
            written = np.any(loop.radiance.numpy() != -7.0, axis=2)
            np.testing.assert_array_equal(written, smap & hit if k else smap, err_msg=f"skip_misses={k}, frame {i}")
            out[k] = (f.numpy().copy(), smap, loop.temporal.color.numpy().copy())
        misses_sampled += int((smap & ~hit).sum())
        for a, b in zip(out[True], out[False]):
            np.testing.assert_array_equal(a, b, err_msg=f"frame {i}")
    assert misses_sampled > 0  # the case under test happened: sampled pixels on the background


def test_foveated_close_to_reference_and_fovea_exact(device):
    scene = fw.load_scene("cornell")
    loop = _loop(scene, device)
    ref_loop = _loop(scene, device)
    gaze = (48.0, 32.0)
    for i in range(4):
        f = loop.render(scene.camera, gaze_px=gaze)
    ref = ref_loop.render_reference(scene.camera).numpy()
    img = f.numpy()
    assert np.all(np.isfinite(img))
    p = psnr(img, ref)
    assert p > 28.0, p
    # pixels traced this frame equal the reference exactly (deterministic shading, converged history)
    smap = f.sampling_map.numpy().astype(bool)
    np.testing.assert_allclose(img[smap], ref[smap], atol=2e-6)
    assert 0.05 < f.stats["sampling_rate"] < 1.0  # small images sample densely: 1 px spans ~0.5 deg


def test_history_converges_on_static_view(device):
    # AO noise: a static view must converge towards the many-sample mean
    scene = fw.load_scene("cornell")
    cfg = {"shading": {"ao_samples": 2, "ambient": (0.4, 0.4, 0.4)}, "temporal": {"max_history_frames": 32}}
    loop = _loop(scene, device, **cfg)
    ref_loop = _loop(scene, device, shading={"ao_samples": 256, "ambient": (0.4, 0.4, 0.4)})
    ref = ref_loop.render_reference(scene.camera).numpy()
    errs = []
    for i in range(16):
        f = loop.render(scene.camera, gaze_px=(48.0, 32.0))
        errs.append(psnr(f.numpy(), ref))
    assert errs[-1] > errs[0] + 3.0, errs
    # every surface pixel reuses history on a static view (background pixels have nothing to reuse)
    assert f.stats["cache_hit_rate"] >= 0.98 * f.gbuffer.hit.numpy().astype(bool).mean()


def test_skips_first_frame_cut_static_pinhole(device):
    scene = fw.load_scene("cornell")
    loop = _loop(scene, device)
    f0 = loop.render(scene.camera)
    sk = f0.stats["skipped"]
    assert sk["reprojection"] == "first frame"
    assert "bvh_refit" in sk and "dof" in sk and "indirect" in sk
    f1 = loop.render(scene.camera)
    assert "reprojection" not in f1.stats["skipped"]
    assert f1.stats["cache_hit_rate"] >= 0.98 * f1.gbuffer.hit.numpy().astype(bool).mean()
    # a large rotation is a cut
    far = fw.Camera(eye=(0, 1, 3.4), target=(3.4, 1, 3.3), fov_y_deg=45)
    f2 = loop.render(far)
    assert f2.stats["skipped"]["reprojection"] == "camera cut"
    assert f2.stats["cache_hit_rate"] < 0.05
    # explicit cut
    f3 = loop.render(far, cut=True)
    assert f3.stats["skipped"]["reprojection"] == "camera cut"


def test_moving_scene_does_not_skip_refit(device):
    scene = fw.load_scene("cornell", motion=True)
    loop = _loop(scene, device)
    loop.render(scene.camera, time=0.0)
    f = loop.render(scene.camera, time=0.1)
    assert "bvh_refit" not in f.stats["skipped"]


def test_foveation_disabled_skips_reorder_and_reconstruction_and_equals_reference(device):
    scene = fw.load_scene("cornell")
    loop = _loop(scene, device, foveation={"enabled": False})
    f = loop.render(scene.camera)
    assert "reorder" in f.stats["skipped"] and "reconstruct" in f.stats["skipped"]
    assert f.stats["sampling_rate"] == 1.0
    ref = _loop(scene, device).render_reference(scene.camera).numpy()
    np.testing.assert_allclose(f.numpy(), ref, atol=1e-6)


def test_indirect_cached_equals_rebuilt(device):
    scene = fw.load_scene("cornell")
    over = {"shading": {"indirect": "lighttree"}, "indirect": {"rsm_size": 32, "limit_level": 4}}
    loop = _loop(scene, device, **over)
    loop.render(scene.camera)
    f = loop.render(scene.camera)
    assert f.stats["skipped"].get("indirect_build") == "light and geometry static"
    cached = f.numpy().copy()
    loop2 = _loop(scene, device, **over)
    loop2.render(scene.camera)
    orig = loop2.indirect.update
    loop2.indirect.update = lambda force=False: orig(force=True)  # the non-skipping path: rebuild every frame
    f2 = loop2.render(scene.camera)
    assert "indirect_build" not in f2.stats["skipped"]
    np.testing.assert_allclose(cached, f2.numpy(), atol=1e-6)


def test_gaze_off_screen_and_nan(device):
    loop = _loop("earth", device)
    f = loop.render(gaze_px=(-5000.0, 1e5))
    assert np.all(np.isfinite(f.numpy()))
    with pytest.raises(ValueError, match="gaze_px"):
        loop.render(gaze_px=(float("nan"), 3.0))


# -- refresh budget: static camera + scene with converged history ------------------------------------------


def _static_run(loop, scene, frames, gazes=None):
    out = []
    for i in range(frames):
        g = (48.0, 32.0) if gazes is None else gazes[i % len(gazes)]
        f = loop.render(scene.camera, gaze_px=g)
        out.append((f.numpy().copy(), dict(f.stats), f.extras["filled"].numpy().astype(bool)))
    return out


def test_refresh_budget_on_static_converged_view_matches_full_sampling_path(device):
    scene = fw.load_scene("cornell")
    n_conv = max(4 * 4, fw.TemporalConfig().max_history_frames)  # block 4: 16 ranks; 16 history frames
    frames = n_conv + 8
    a = _static_run(_loop(scene, device), scene, frames)  # refresh_fraction 0.25 (default)
    b = _static_run(_loop(scene, device, temporal={"refresh_fraction": 1.0}), scene, frames)
    ref = _loop(scene, device).render_reference(scene.camera).numpy()
    for i, ((ia, sa, fa), (ib, sb, fb)) in enumerate(zip(a, b)):
        assert "trace" not in sb["skipped"]
        if i < n_conv:  # not yet converged: identical to the non-skipping path
            assert "trace" not in sa["skipped"], i
            np.testing.assert_array_equal(ia, ib)
            continue
        assert "trace" in sa["skipped"], (i, sa["static_frames"])
        # the refresh budget traces far fewer rays than the normal sampling map
        assert sa["sampling_rate"] < 0.6 * sb["sampling_rate"], (i, sa["sampling_rate"], sb["sampling_rate"])
        # pixels both paths filled agree (history of a static deterministic view is the fresh value)
        both = fa & fb
        assert both.mean() > 0.9
        np.testing.assert_allclose(ia[both], ib[both], atol=2e-5)
        # and the whole frame is at least as close to the full-resolution reference
        # (capped at 100 dB: the non-skipping path now reproduces a static deterministic view exactly)
        assert min(psnr(ia, ref), 100.0) >= min(psnr(ib, ref), 100.0) - 0.5, (i, psnr(ia, ref), psnr(ib, ref))


def test_refresh_budget_never_when_view_or_scene_changes(device):
    scene = fw.load_scene("cornell")
    loop = _loop(scene, device)
    for i in range(24):  # the camera moves a little every frame
        f = loop.render(scene.camera_at(i / 120.0), gaze_px=(48.0, 32.0))
        assert "trace" not in f.stats["skipped"], i
        assert f.stats["static_frames"] == 0
    moving = fw.load_scene("cornell", motion=True)
    loop = _loop(moving, device)
    for i in range(24):  # static camera, a moving object
        f = loop.render(moving.camera, gaze_px=(48.0, 32.0), time=i / 30.0)
        assert "trace" not in f.stats["skipped"], i
    # a converged static view, then a cut: the count restarts and the full map is traced again
    loop = _loop(scene, device)
    for i in range(18):
        f = loop.render(scene.camera, gaze_px=(48.0, 32.0))
    assert "trace" in f.stats["skipped"]
    f = loop.render(scene.camera, gaze_px=(48.0, 32.0), cut=True)
    assert "trace" not in f.stats["skipped"] and f.stats["static_frames"] == 0
    f = loop.render(scene.camera, gaze_px=(48.0, 32.0))
    assert "trace" not in f.stats["skipped"] and f.stats["static_frames"] == 1


def test_refresh_budget_with_moving_gaze_keeps_quality(device):
    # the gaze may move in a static view: history stays valid, only the sampling map follows the gaze
    scene = fw.load_scene("cornell")
    gazes = [(10.0, 10.0), (80.0, 50.0), (48.0, 32.0), (-200.0, 30.0)]
    a = _static_run(_loop(scene, device), scene, 24, gazes)
    b = _static_run(_loop(scene, device, temporal={"refresh_fraction": 1.0}), scene, 24, gazes)
    ref = _loop(scene, device).render_reference(scene.camera).numpy()
    assert "trace" in a[-1][1]["skipped"]
    for (ia, sa, _), (ib, sb, _) in zip(a[-4:], b[-4:]):
        assert np.isfinite(ia).all()
        assert psnr(ia, ref) >= psnr(ib, ref) - 0.5


def test_refresh_fraction_zero_traces_only_pixels_without_history(device):
    scene = fw.load_scene("cornell")
    loop = _loop(scene, device, temporal={"refresh_fraction": 0.0})
    out = _static_run(loop, scene, 20)
    img, st, filled = out[-1]
    hit = loop.gbuffer.hit.numpy().astype(bool)
    smap = loop.sampling.sample_map.numpy().astype(bool)
    hits = loop.sampling.cache_hit.numpy().astype(bool)
    assert st["sampling_rate"] == pytest.approx(smap.mean())
    # traced: the sampled pixels without history (here the background: it has no cache test), and of the
    # surface pixels only the few whose history is about to expire
    assert (~hits).sum() == (~hit).sum()
    assert (smap & hits).sum() <= 0.01 * smap.size, (smap & hits).sum()
    ref = _loop(scene, device).render_reference(scene.camera).numpy()
    assert psnr(img, ref) > 60.0


# -- CUDA graph of the steady-state frame -------------------------------------------------------------------


def _replayed_vs_eager(scene, g, e, *, frames: int, still_from: int, atol: float, extras: bool = False) -> list:
    """Render ``frames`` frames with loop ``g`` (graphs or CPU replays on) and ``e`` (graph=False) along the scene's
    camera path, still from frame ``still_from`` on, with a moving gaze; assert the outputs agree (images within
    ``atol``, sampling maps and skipped stages exactly; ``extras``: sparse colour, filled mask and sampling rate
    exactly too); return ``g``'s ``stats["graph"]`` per frame and its last frame."""
    states = []
    for i in range(frames):
        j = min(i, still_from)
        cam, t, gaze = scene.camera_at(j / 60.0), j / 30.0, (20.0 + 2 * i, 30.0 - i)
        fg = g.render(cam, gaze_px=gaze, time=t)
        fe = e.render(cam, gaze_px=gaze, time=t)
        states.append(fg.stats["graph"])
        assert fe.stats["graph"] == "eager"
        np.testing.assert_array_equal(fg.sampling_map.numpy(), fe.sampling_map.numpy(), err_msg=str(i))
        np.testing.assert_allclose(fg.numpy(), fe.numpy(), rtol=0.0, atol=atol, err_msg=str(i))
        assert fg.stats["skipped"] == fe.stats["skipped"]
        if extras:
            for k in ("sparse", "filled"):
                np.testing.assert_array_equal(fg.extras[k].numpy(), fe.extras[k].numpy(), err_msg=f"{k} {i}")
            assert fg.stats["sampling_rate"] == fe.stats["sampling_rate"]
    return states, fg


def test_graph_is_off_with_timing_and_when_asked():
    scene = fw.load_scene("cornell")
    timed = fw.FrameLoop(scene, 32, 24, device="cpu", timing=True, policy="foveated")
    off = fw.FrameLoop(scene, 32, 24, device="cpu", timing=False, graph=False, policy="foveated")
    on = fw.FrameLoop(scene, 32, 24, device="cpu", timing=False, policy="foveated")
    states = []
    for i in range(8):
        cam = scene.camera_at(i / 60.0)
        states.append((timed.render(cam).stats["graph"], off.render(cam).stats["graph"], on.render(cam).stats["graph"]))
    assert [s[0] for s in states] == ["eager"] * 8
    assert [s[1] for s in states] == ["eager"] * 8
    # the CPU records its frame body's launches (parallel.record) and replays them, as CUDA captures a graph: the
    # first frame (no history) and the two history parities each run eagerly once, then are recorded once
    assert [s[2] for s in states] == ["warm-up"] * 3 + ["captured"] * 2 + ["replayed"] * 3
    with pytest.raises(ValueError, match="graph"):
        fw.FrameLoop(scene, 32, 24, device="cpu", graph="yes")


@pytest.mark.parametrize("over, scene_kw, threads", [
    ({}, {}, 3),
    ({"shading": {"ao_samples": 2}, "dof": {"aperture_m": 0.02}, "temporal": {"max_history_frames": 4}},
     {"motion": True}, 2),
    ({"reorder": {"strategy": "tile"}, "shading": {"ao_samples": 2}}, {"motion": True}, 2),
    ({"reorder": {"strategy": "rows"}, "temporal": {"max_history_frames": 4}}, {}, 1),
    ({"reorder": {"strategy": "scan"}, "shading": {"indirect": "lighttree"}}, {}, 2),
    ({"reconstruction": {"jfa_variant": "1+jfa"}}, {"motion": True}, 2),
    ({"foveation": {"gbuffer": "sparse"}}, {"motion": True}, 2),
])
def test_cpu_replay_equals_eager_launches(over, scene_kw, threads):
    """The CPU's recorded frame body replays each frame's camera, gaze, frame index (AO noise) and object motion:
    images, sampling maps, histories and stats are identical to eager launches over a moving sequence, through a
    still phase (the refresh with a short history)."""
    scene = fw.load_scene("cornell", **scene_kw)
    cfg = fw.Config().with_(**over) if over else fw.Config()
    g = fw.FrameLoop(scene, W, H, config=cfg, device="cpu", timing=False, policy="foveated", cpu_threads=threads)
    e = fw.FrameLoop(scene, W, H, config=cfg, device="cpu", timing=False, graph=False, policy="foveated",
                     cpu_threads=threads)
    states, _ = _replayed_vs_eager(scene, g, e, frames=24, still_from=10, atol=0.0, extras=True)
    assert "captured" in states and states.count("replayed") >= 12, states


def test_cpu_replay_follows_the_thread_count():
    """A recording is split for the thread count it was made with: a loop whose ``cpu_threads`` changes records
    anew, and the frames stay equal to eager ones."""
    scene = fw.load_scene("cornell")
    g = fw.FrameLoop(scene, W, H, device="cpu", timing=False, policy="foveated")
    e = fw.FrameLoop(scene, W, H, device="cpu", timing=False, graph=False, policy="foveated")
    states = []
    for i, n in enumerate([2] * 6 + [3] * 4 + [1] * 3):
        g.cpu_threads = e.cpu_threads = n
        fg = g.render(scene.camera_at(i / 60.0), gaze_px=(30.0 + i, 20.0), time=i / 30.0)
        fe = e.render(scene.camera_at(i / 60.0), gaze_px=(30.0 + i, 20.0), time=i / 30.0)
        states.append(fg.stats["graph"])
        np.testing.assert_array_equal(fg.numpy(), fe.numpy(), err_msg=str(i))
    # the first frame and the two history parities: eager, recorded, replayed; at 3 threads, and at 1, each
    # parity is recorded again
    assert states == (["warm-up"] * 3 + ["captured"] * 2 + ["replayed"] + ["captured"] * 2 + ["replayed"] * 2
                      + ["captured"] * 2 + ["replayed"]), states


@pytest.mark.needs_cuda
@pytest.mark.parametrize("strategy", ["tile", "none", "rows"])
def test_graph_replay_equals_eager_launches(strategy):
    """The captured body replays each frame's camera, gaze, frame index (AO noise) and object motion: images
    and sampling maps are identical to eager launches over a moving sequence, through a refresh phase."""
    scene = fw.load_scene("cornell", motion=True)
    over = {"reorder": {"strategy": strategy}, "shading": {"ao_samples": 2},
            "dof": {"aperture_m": 0.02}, "temporal": {"max_history_frames": 4}}
    cfg = fw.Config().with_(**over)
    g = fw.FrameLoop(scene, W, H, config=cfg, device="cuda:0", timing=False, policy="foveated")
    e = fw.FrameLoop(scene, W, H, config=cfg, device="cuda:0", timing=False, graph=False, policy="foveated")
    states, fg = _replayed_vs_eager(scene, g, e, frames=40, still_from=12, atol=1e-6)
    assert "captured" in states and states.count("replayed") >= 25, states
    assert any("trace" in s for s in [fg.stats["skipped"]])  # the refresh phase was reached (and replayed)


# -- the cost policy (never slower than full resolution) ------------------------------------------


def test_policy_full_equals_reference_and_validation():
    scene = fw.load_scene("cornell")
    loop = fw.FrameLoop(scene, W, H, device="cpu", policy="full")
    f = loop.render(scene.camera, gaze_px=(10.0, 10.0))
    assert f.stats["sampling_rate"] == 1.0 and f.stats["policy"]["path"] == "full"
    assert "foveation" in f.stats["skipped"]
    ref = _loop(scene, "cpu").render_reference(scene.camera).numpy()
    np.testing.assert_allclose(f.numpy(), ref, atol=1e-6)
    with pytest.raises(ValueError, match="policy"):
        fw.FrameLoop(scene, W, H, device="cpu", policy="fastest")
    # the default is the cost policy, with or without per-stage timing, on the CPU device as on CUDA (never
    # slower than full resolution by default); an explicit policy wins
    assert fw.FrameLoop(scene, 8, 8, device="cpu").policy == "auto"
    assert fw.FrameLoop(scene, 8, 8, device="cpu", timing=True).policy == "auto"
    assert fw.FrameLoop(scene, 8, 8, device="cpu", timing=False).policy == "auto"
    assert fw.FrameLoop(scene, 8, 8, device="cpu", timing=False, policy="foveated").policy == "foveated"


def test_timing_reports_only_stages_that_ran(device):
    """timing=True synchronizes and reports ``ms_<stage>`` only for the stages a frame runs: a full-resolution
    frame through ``render`` times the same stages as ``render_reference`` (so the policy's full path pays no
    more synchronizations than the reference), a foveated frame its own, and a skipped stage has no time."""
    scene = fw.load_scene("cornell")
    keys = lambda st: sorted(k for k in st if k.startswith("ms_") and k != "ms_frame")  # noqa: E731
    full = fw.FrameLoop(scene, W, H, device=device, policy="full")
    ref = fw.FrameLoop(scene, W, H, device=device)
    fov = fw.FrameLoop(scene, W, H, device=device, policy="foveated")
    for i in range(2):
        cam = scene.camera_at(i / 30.0)
        f, r, v = full.render(cam), ref.render_reference(cam), fov.render(cam)
    assert keys(r.stats) == ["ms_gbuffer", "ms_shade"]
    assert keys(f.stats) == keys(r.stats)
    shade_in_resolve = fov._shade_in_resolve(v.stats["strategy"])
    want = {"ms_gbuffer", "ms_sampling", "ms_temporal", "ms_reconstruct"}
    want |= set() if shade_in_resolve else {"ms_shade"}
    want |= {"ms_reorder"} if v.stats["strategy"] in ("scan", "tile", "rows", "rows+balance") else set()
    assert set(keys(v.stats)) == want
    assert all(v.stats[k] >= 0.0 for k in want) and v.stats["ms_frame"] >= max(v.stats[k] for k in want)
    # an animated scene times its refit; a light-tree scene its indirect stages; depth of field its pass
    moving = fw.FrameLoop(fw.load_scene("cornell", motion=True), W, H, device=device, policy="full")
    assert "ms_scene" in moving.render(scene.camera, time=0.1).stats
    lt = fw.FrameLoop(scene, W, H, device=device, config=fw.Config().with_(shading={"indirect": "lighttree"}),
                      policy="foveated")
    st = lt.render(scene.camera).stats
    assert {"ms_indirect_build", "ms_indirect"} <= set(st)
    assert ("ms_tonemap" in st) == (not lt._tonemap_fused(st["strategy"]))
    dof = fw.FrameLoop(scene, W, H, device=device, config=fw.Config().with_(dof={"aperture_m": 0.05}))
    st = dof.render_reference(scene.camera).stats
    assert {"ms_dof", "ms_tonemap"} <= set(st) and "ms_indirect" not in st


@pytest.mark.parametrize("shading", ["default", "ao8"])
def test_gpu_timing_times_the_same_stages_of_the_same_frames(device, shading):
    """timing="gpu" launches what timing=True launches (the same images, bit for bit) and reports the same
    ``ms_<stage>`` keys; on CUDA they are CUDA-event spans of disjoint parts of the frame, so they are finite, >= 0
    and sum to at most the frame's wall time; the events are reused frame after frame (8 AO rays: the list's
    lights on a second stream at this size, joined inside the shade stage)."""
    scene = fw.load_scene("cornell")
    cfg = fw.Config().with_(shading={"ao_samples": 8}) if shading == "ao8" else fw.Config()
    keys = lambda st: sorted(k for k in st if k.startswith("ms_") and k != "ms_frame")  # noqa: E731
    for policy in ("foveated", "full"):
        sync = fw.FrameLoop(scene, W, H, config=cfg, device=device, policy=policy, timing=True)
        gpu = fw.FrameLoop(scene, W, H, config=cfg, device=device, policy=policy, timing="gpu")
        assert gpu.timing is True and gpu._timing_gpu == wp.get_device(device).is_cuda
        pools = []
        for i in range(4):
            cam = scene.camera_at(i / 30.0)
            a, b = sync.render(cam, gaze_px=(40.0, 30.0)), gpu.render(cam, gaze_px=(40.0, 30.0))
            np.testing.assert_array_equal(a.image.numpy(), b.image.numpy())
            assert keys(a.stats) == keys(b.stats) and keys(b.stats)
            ms = [b.stats[k] for k in keys(b.stats)]
            assert all(math.isfinite(v) and v >= 0.0 for v in ms)
            assert sum(ms) <= b.stats["ms_frame"] * 1.01 + 0.01
            assert gpu._stage_events == []
            pools.append(len(gpu._stage_ev_pool))
        assert pools[-1] == pools[-2]  # no new events once warm
        r = gpu.render_reference(scene.camera)
        assert keys(r.stats) == ["ms_gbuffer", "ms_shade"] and all(r.stats[k] >= 0.0 for k in keys(r.stats))


def test_policy_auto_measures_both_paths_and_renders_the_cheaper():
    scene = fw.load_scene("cornell")
    loop = fw.FrameLoop(scene, W, H, device="cpu", policy="auto")
    n = loop.POLICY_WARM + loop.POLICY_TIMED
    m = loop.POLICY_WARM_AGAIN + loop.POLICY_TIMED
    assert loop.policy_measurement_frames() == 2 * n + 3 * m
    paths = []
    for i in range(2 * n + 3 * m + 3):
        f = loop.render(scene.camera_at(i / 60.0), gaze_px=(48.0, 32.0))
        paths.append(f.stats["policy"]["path"])
        if paths[-1] == "foveated" and i > 0 and paths[-2] == "full":
            # the full-resolution frame before it is its history (no cut)
            assert f.stats["history_seeded"] and "reprojection" not in f.stats["skipped"]
        else:
            assert not f.stats["history_seeded"]
    assert paths[:n] == ["foveated"] * n and paths[n:2 * n] == ["full"] * n
    est = f.stats["policy"]
    assert est["foveated_ms"] > 0 and est["full_ms"] > 0
    # a measurement that is not clear-cut times both paths again, in the other order
    # (and, if foveation wins that, the full path a third time)
    end = {2: 2 * n, 4: 2 * n + 2 * m, 5: 2 * n + 3 * m}[est["blocks"]]
    if est["blocks"] >= 4:
        assert paths[2 * n:end] == ["full"] * m + ["foveated"] * m + ["full"] * m * (est["blocks"] - 4)
    cheaper = "foveated" if est["foveated_ms"] < (1 - loop.POLICY_MARGIN) * est["full_ms"] else "full"
    assert (est["blocks"] == 5) == (cheaper == "foveated" and est["blocks"] != 2)
    assert paths[end:] == [cheaper] * (len(paths) - end)
    if cheaper == "full":
        assert "cheaper" in f.stats["skipped"]["foveation"] and "ms" in f.stats["skipped"]["foveation"]


@pytest.mark.parametrize("shading", [{}, {"ao_samples": 4}])
def test_foveated_frame_after_full_frame_reprojects_it(device, shading):
    """When the policy switches from full resolution back to foveation, the last full frame becomes the history
    (its temporal resolve with every pixel traced: each pixel's exact value, one frame old) instead of a cut:
    the first foveated frame reuses it (cache hits), is closer to the reference than the same frame after a cut,
    and the seeded history is the full frame's radiance and depth."""
    scene = fw.load_scene("cornell")
    cfg = fw.Config().with_(shading=shading) if shading else fw.Config()
    loops = {k: fw.FrameLoop(scene, W, H, config=cfg, device=device, policy="full", timing=False)
             for k in ("seeded", "cut", "probe")}
    ref = fw.FrameLoop(scene, W, H, config=cfg, device=device, timing=False)
    for i in range(4):
        for lp in loops.values():
            f = lp.render(scene.camera_at(i / 30.0), gaze_px=(40.0, 30.0))
            assert not f.stats["history_seeded"]
    # the seed alone: the history equals the last full frame's (deterministic part, depth, every pixel filled)
    probe = loops["probe"]
    assert probe._seed_history()
    hist = probe.temporal.history()
    rad, depth = probe.radiance.numpy(), probe.gbuffer.depth.numpy()
    np.testing.assert_array_equal(hist["depth"], depth)
    assert hist["filled"].all()
    hit = probe.gbuffer.hit.numpy() != 0
    np.testing.assert_allclose(hist["color"][hit], rad[hit], rtol=0, atol=1e-6)
    for lp in loops.values():
        lp.policy = "foveated"
    cam = scene.camera_at(4 / 30.0)
    a = loops["seeded"].render(cam, gaze_px=(40.0, 30.0))
    b = loops["cut"].render(cam, gaze_px=(40.0, 30.0), cut=True)
    r = ref.render_reference(cam).numpy()
    assert a.stats["history_seeded"] and "reprojection" not in a.stats["skipped"]
    assert not b.stats["history_seeded"] and b.stats["skipped"]["reprojection"] == "camera cut"
    assert a.stats["cache_hit_rate"] > 0.5 and b.stats["cache_hit_rate"] == 0.0
    assert psnr(a.numpy(), r) > psnr(b.numpy(), r) + 1.0
    # foveation disabled: full frames follow each other with no seeding (nothing reads the history)
    off = fw.FrameLoop(scene, W, H, config=cfg.with_(foveation={"enabled": False}), device=device, timing=False)
    for i in range(3):
        assert not off.render(scene.camera_at(i / 30.0)).stats["history_seeded"]


@pytest.mark.parametrize("choice", ["foveated", "full"])
def test_policy_check_remeasures_a_wrong_choice(device, choice):
    """The policy watches the chosen path's frames (wall times on the CPU device, CUDA event spans on CUDA without
    timing): when the median of POLICY_WATCH of them contradicts the choice, the next measurement starts at once
    (not POLICY_PERIOD frames later), no sooner than POLICY_RECHECK_MIN frames after the last one began; a choice
    the frames confirm is kept."""
    scene = fw.load_scene("cornell")
    loop = fw.FrameLoop(scene, 32, 24, device=device, policy="auto", timing=False, cpu_threads=1)
    pol = loop.cost_policy
    pol.CLEAR = 0.0  # no confirming blocks: this test is about the check (test_policy_confirms_...)
    sync = lambda: wp.synchronize_device(device)  # noqa: E731 (a frame done before the next: its span is read)
    n = 2 * (loop.POLICY_WARM + loop.POLICY_TIMED)
    for i in range(n + 1):
        st = loop.render(scene.camera_at(i / 60.0)).stats
    assert st["policy"]["trigger"] == "first frames" and st["policy"]["rechecks"] == 0
    if device.startswith("cuda"):  # the measurement's timed frames left their GPU spans
        assert 0 < st["policy"]["foveated_gpu_ms"] <= st["policy"]["foveated_ms"]
    # a wrong choice: the other path's estimates far below anything a frame costs
    other = "full_ms" if choice == "foveated" else "foveated_ms"
    gpu = other.replace("_ms", "_gpu_ms")
    # (the watch compares with the pooled medians, reference; the decision's estimates, estimates, are reported)
    pol.choice, pol.reference[other], pol.reference[gpu] = choice, 1e-6, 1e-6

    def path(i):
        p = loop.render(scene.camera_at(i / 60.0)).stats["policy"]["path"]
        sync()
        return p

    # the first check that may act: at POLICY_RECHECK_MIN frames after the last measurement began; on CUDA the
    # watch samples one frame in POLICY_WATCH_EVERY, so its POLICY_WATCH samples take longer to gather
    every = loop.POLICY_WATCH_EVERY if pol.by_events else 1
    latest = max(loop.POLICY_RECHECK_MIN, n + loop.POLICY_WATCH * every + every)
    paths, i = [], n + 1
    while pol.rechecks == 0:
        paths.append(path(i))
        i += 1
        assert i <= latest + 1, "no re-measurement"
    start = i - 1  # the frame at which the measurement restarted (its first frame is rendered)
    assert loop.POLICY_RECHECK_MIN <= start <= latest
    # the re-measurement: its short form (POLICY_CLEAR 0 makes any two unequal estimates clear-cut)
    m = loop.POLICY_WARM_AGAIN + loop.POLICY_TIMED_CLEAR
    paths += [path(i + k) for k in range(2 * m - 1)]
    assert pol.length == (loop.POLICY_WARM_AGAIN, loop.POLICY_TIMED_CLEAR) and m < n // 2
    assert paths == [choice] * (start - n - 1) + ["foveated"] * m + ["full"] * m
    st = loop.render(scene.camera_at(1.0)).stats["policy"]
    assert st["rechecks"] == 1 and st["trigger"].startswith(f"check: the {choice} frames measured")
    assert st["measured_at_frame"] == start + 2 * m and st[other] > 1e-6
    # a choice its frames confirm stays until the period
    pol.choice, pol.reference[other], pol.reference[gpu] = choice, 1e9, 1e9
    for i in range(loop.POLICY_RECHECK_MIN + 2 * loop.POLICY_WATCH * every):
        st = loop.render(scene.camera_at(1.0 + i / 60.0)).stats["policy"]
        sync()
        assert st["path"] == choice and st["rechecks"] == 1


def _drive_policy(loop, block_ms, skip=()):
    """Run ``loop``'s policy state machine (no rendering) through one measurement, giving each timed frame of
    the k-th block the time ``block_ms[k]`` (a list per block, cycled); the timed frames ``(block, k)`` in
    ``skip`` record nothing (a frame whose time was lost). Returns the paths of the frames up to and including
    the first frame after the decision."""
    pol, paths, counts = loop.cost_policy, [], {}
    for i in range(loop.POLICY_PERIOD):
        path, timed, _ = pol.next_frame(i)
        paths.append(path)
        if "measured_at_frame" in pol.estimates:
            return paths
        # the block of frame i, from the schedule as it stands after this frame's call
        ends = np.cumsum([w + t for _, w, t in pol.schedule])
        block = int(np.searchsorted(ends, i, side="right"))
        assert pol.schedule[block][0] == path
        if timed:
            k = counts.get(block, 0)
            if (block, k) not in skip:
                pol.record(path, block_ms[block][k % len(block_ms[block])])
            counts[block] = k + 1
    raise AssertionError("no decision within a period")


@pytest.mark.parametrize("case", ["inflated_full", "clear", "close_kept", "lost_frame", "inflated_full_twice",
                                  "close_full"])
def test_policy_confirms_a_close_measurement(case):
    """A measurement whose paths are not clear-cut (neither POLICY_CLEAR cheaper) times both again in the other
    order, and each path's estimate is the lower of its two block medians (NumPy, here); if foveation then wins by
    the margin, the full path is timed a third time and its estimate is the lowest of its three medians. A
    clear-cut measurement decides after its two blocks, a close choice of full resolution after four. The watch's
    yardsticks are each path's median over all its timed frames. A timed frame whose time was lost shifts no other
    frame into another block. The state machine is driven with set frame times (no rendering)."""
    loop = fw.FrameLoop("cornell", 16, 8, device="cpu", policy="auto")
    n = loop.POLICY_WARM + loop.POLICY_TIMED
    m = loop.POLICY_WARM_AGAIN + loop.POLICY_TIMED
    blocks = {
        # the full path's first block slowed by a transient: alone it would pick foveation (1.0 < 0.95 * 1.2)
        "inflated_full": [[1.0, 1.02, 0.98], [1.2, 1.25, 1.19], [0.9, 0.91, 0.89], [1.01, 1.0, 1.03]],
        "clear": [[0.5, 0.52, 0.49], [1.0, 1.01, 0.99]],
        "close_kept": [[1.0, 1.01, 0.99], [1.2, 1.22, 1.18], [1.21, 1.2, 1.19], [1.3, 1.31, 1.29],
                       [1.25, 1.24, 1.26]],
        # block 0's first timed frame lost: block 1's frames must stay in block 1
        "lost_frame": [[0.7, 1.02, 0.98], [1.2, 1.25, 1.19], [0.9, 0.91, 0.89], [1.01, 1.0, 1.03]],
        # one transient over both back-to-back full blocks (H100: 2.01 against 1.68 ms): the third
        # full block, later, decides
        "inflated_full_twice": [[1.0, 1.02, 0.98], [1.2, 1.25, 1.19], [1.22, 1.21, 1.2], [1.01, 1.0, 1.03],
                                [0.9, 0.91, 0.89]],
        # close, and full resolution is the cheaper: chosen after four blocks (never slower than the reference)
        "close_full": [[1.0, 1.02, 0.98], [0.98, 0.99, 0.97], [0.97, 0.99, 0.98], [1.01, 1.0, 1.03]],
    }[case]
    skip = {(0, 0)} if case == "lost_frame" else set()
    paths = _drive_policy(loop, blocks, skip)
    pol = loop.cost_policy
    est = pol.estimates
    t = loop.POLICY_TIMED
    kept = [[b[k % len(b)] for k in range(t) if (j, k) not in skip] for j, b in enumerate(blocks)]
    meds = [float(np.median(v)) for v in kept]
    nb = len(blocks)
    order = ["foveated"] * n + ["full"] * n + ["full"] * m + ["foveated"] * m + ["full"] * m
    frames = {2: 2 * n, 4: 2 * n + 2 * m, 5: 2 * n + 3 * m}[nb]
    assert est["blocks"] == nb and len(paths) == frames + 1 and paths[:frames] == order[:frames]
    fov_blocks, full_blocks = {2: ((0,), (1,)), 4: ((0, 3), (1, 2)), 5: ((0, 3), (1, 2, 4))}[nb]
    fov, full = min(meds[j] for j in fov_blocks), min(meds[j] for j in full_blocks)
    assert est["foveated_ms"] == pytest.approx(fov) and est["full_ms"] == pytest.approx(full)
    pooled = {"foveated_ms": float(np.median(sum((kept[j] for j in fov_blocks), []))),
              "full_ms": float(np.median(sum((kept[j] for j in full_blocks), [])))}
    assert pol.reference == pytest.approx(pooled)
    expect = "foveated" if fov < (1 - loop.POLICY_MARGIN) * full else "full"
    assert pol.choice == expect and paths[-1] == expect
    assert expect == {"inflated_full": "full", "clear": "foveated", "close_kept": "foveated",
                      "lost_frame": "full", "inflated_full_twice": "full", "close_full": "full"}[case]
    # the two back-to-back full blocks alone would have chosen foveation
    if case == "inflated_full_twice":
        assert fov < (1 - loop.POLICY_MARGIN) * min(meds[1], meds[2])


def test_policy_measurement_length():
    """The first measurement renders POLICY_WARM + POLICY_TIMED frames of each path; a later one 1 untimed frame
    per path and, after clear-cut estimates (the cheaper path >= POLICY_CLEAR cheaper), POLICY_TIMED_CLEAR timed
    ones, else POLICY_TIMED."""
    loop = fw.FrameLoop(fw.load_scene("cornell"), 16, 16, device="cpu", policy="auto")
    pol = loop.cost_policy
    assert pol.measurement_length() == (loop.POLICY_WARM, loop.POLICY_TIMED)
    for fov, full, timed in ((1.0, 2.0, loop.POLICY_TIMED_CLEAR), (2.0, 1.0, loop.POLICY_TIMED_CLEAR),
                             (1.0, 1.2, loop.POLICY_TIMED), (1.2, 1.0, loop.POLICY_TIMED),
                             (0.75, 1.0, loop.POLICY_TIMED), (0.7499, 1.0, loop.POLICY_TIMED_CLEAR)):
        pol.estimates = {"foveated_ms": fov, "full_ms": full}
        assert pol.measurement_length() == (loop.POLICY_WARM_AGAIN, timed), (fov, full)
    assert loop.POLICY_WARM_AGAIN + loop.POLICY_TIMED_CLEAR < loop.POLICY_WARM + loop.POLICY_TIMED


def test_auto_reorder_strategy_resolves_per_device(device):
    """ReorderConfig.strategy "auto" (the default) runs "tile" on CUDA and "none" on the CPU; the image equals the
    explicit strategy's, and the resolved name is what stats report."""
    from foveawarp.config import resolve_reorder_strategy

    assert fw.Config().reorder.strategy == "auto"
    want = "tile" if device.startswith("cuda") else "none"
    assert resolve_reorder_strategy("auto", device) == want
    for s in STRATEGIES:
        assert resolve_reorder_strategy(s, device) == s
    with pytest.raises(ValueError, match="ReorderConfig.strategy"):
        resolve_reorder_strategy("fastest", device)
    scene = fw.load_scene("cornell")
    imgs = {}
    for s in ("auto", want):
        loop = _loop(scene, device, reorder={"strategy": s})
        for i in range(2):
            f = loop.render(scene.camera_at(i / 30), gaze_px=(40.0 + 3 * i, 30.0))
        assert f.stats["strategy"] == want
        imgs[s] = f.numpy().copy()
    np.testing.assert_array_equal(imgs["auto"], imgs[want])


@pytest.mark.parametrize("policy", ["foveated", "full"])
def test_tone_map_fused_into_the_last_pass(device, policy):
    """Without DoF (and, at full resolution, without indirect light) the last pass writes the display image: it
    equals the tone-map kernel applied to the HDR result bit for bit (and a NumPy Hable curve within 1e-6); with
    DoF the separate pass runs."""
    import warp as wp

    from foveawarp.kernels.tonemap import tonemap_kernel

    scene = fw.load_scene("cornell")
    for dof in (False, True):
        over = {"dof": {"aperture_m": 0.05}} if dof else {}
        loop = fw.FrameLoop(scene, W, H, config=fw.Config().with_(**over), device=device, policy=policy)
        for i in range(3):
            f = loop.render(scene.camera_at(i / 30), gaze_px=(40.0 + 2 * i, 30.0))
        assert ("tonemap" in f.stats["skipped"]) == (not dof)
        hdr = loop.dof_out if dof else loop.hdr
        sc = loop.config.shading
        again = wp.zeros((H, W), dtype=wp.vec3, device=device)
        wp.launch(tonemap_kernel, dim=(H, W), inputs=[hdr, float(sc.exposure), float(sc.white_point)],
                  outputs=[again, 0], device=device)
        np.testing.assert_array_equal(f.numpy(), again.numpy())

        def hable(x):
            a, b, c, d, e, g = 0.15, 0.50, 0.10, 0.20, 0.02, 0.30
            return x * (g * (a * x + c * b) - e * (a * x + b)) / (g * (x * (a * x + b) + d * g))

        v = np.maximum(hdr.numpy().astype(np.float64), 0.0)
        want = np.clip(hable(sc.exposure * v) / hable(sc.white_point), 0.0, 1.0) ** (1.0 / 2.2)
        np.testing.assert_allclose(f.numpy(), want, atol=1e-6, rtol=0)


def test_render_reference_tone_map_fused(device):
    """render_reference writes the display image from its shading pass when nothing follows (no DoF, no indirect
    light): equal bit for bit to the tone-map kernel applied to its radiance; with DoF the separate pass runs on
    the DoF output."""
    import warp as wp

    from foveawarp.kernels.tonemap import tonemap_kernel

    scene = fw.load_scene("cornell")
    for over, src in (({}, "radiance"), ({"dof": {"aperture_m": 0.05}}, "dof_out")):
        loop = fw.FrameLoop(scene, W, H, config=fw.Config().with_(**over), device=device)
        f = loop.render_reference(scene.camera_at(0.2), gaze_px=(40.0, 30.0))
        sc = loop.config.shading
        again = wp.zeros((H, W), dtype=wp.vec3, device=device)
        wp.launch(tonemap_kernel, dim=(H, W), inputs=[getattr(loop, src), float(sc.exposure), float(sc.white_point)],
                  outputs=[again, 0], device=device)
        np.testing.assert_array_equal(f.numpy(), again.numpy())
