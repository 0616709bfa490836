"""Temporal resolve (``stages.temporal``): the kernel against a per-pixel NumPy reference written
from the rule, variance clipping on a step edge, and the frame loop in motion (fovea exact, history never costs)."""

import math

import numpy as np
import pytest
import warp as wp

import foveawarp as fw
from foveawarp.buffers import GBuffer
from foveawarp.metrics import psnr, region_metrics
from foveawarp.stages.temporal import TemporalStage

BG = np.array([0.02, 0.02, 0.03])


def ref_resolve(inp, prev, cfg, use_history, stochastic, samples=1):
    """Per-pixel loop of the rule in TemporalStage's docstring (NumPy, float64); ``samples``: Monte Carlo samples
    per pixel per frame of the stochastic shading."""
    min_age = math.ceil(cfg.stochastic_min_samples / samples) if stochastic else 1
    h, w = inp["hit"].shape
    out = np.zeros((h, w, 3))
    filled = np.zeros((h, w), np.uint8)
    hs_out = np.zeros((h, w, 3))
    for y in range(h):
        for x in range(w):
            if not inp["hit"][y, x]:
                out[y, x] = BG
                filled[y, x] = 1
                continue
            sampled = bool(inp["smap"][y, x])
            if sampled and not stochastic:
                out[y, x] = inp["fresh"][y, x]
                filled[y, x] = 1
                continue
            wsum, hc, hst, age, stale = 0.0, np.zeros(3), np.zeros(3), 1 << 30, 0
            u, v = inp["uv"][y, x]
            if use_history and u > -5e3:
                x0, y0 = math.floor(u - 0.5), math.floor(v - 0.5)
                fx, fy = u - 0.5 - x0, v - 0.5 - y0
                fx = 0.0 if fx < 1 / 128 else (1.0 if fx > 1 - 1 / 128 else fx)
                fy = 0.0 if fy < 1 / 128 else (1.0 if fy > 1 - 1 / 128 else fy)
                for k in range(4):
                    tx, ty = x0 + (k & 1), y0 + (k >> 1)
                    wt = (fx if k & 1 else 1 - fx) * (fy if k >> 1 else 1 - fy)
                    if wt <= 0 or not (0 <= tx < w and 0 <= ty < h):
                        continue
                    j = ty * w + tx
                    ok = (prev["valid"][ty, tx] and prev["age"][j] > 0
                          and abs(prev["depth"][ty, tx] - inp["prev_dist"][y, x]) < cfg.depth_eps_rel * inp["depth"][y, x]
                          and np.dot(prev["normal"][j], inp["normal"][y, x]) >= cfg.normal_cos_min)
                    if ok:
                        wsum += wt
                        hc += wt * prev["color"][j]
                        hst += wt * prev["stoch"][j]
                        age, stale = min(age, prev["age"][j]), max(stale, prev["stale"][j])
            have = wsum > 1e-3
            if have:
                hc, hst = hc / wsum, hst / wsum
            if sampled:
                c, s = inp["fresh"][y, x].astype(np.float64), inp["stoch"][y, x].astype(np.float64)
                if have:
                    nb = [(yy, xx) for yy in range(max(0, y - 2), min(h, y + 3)) for xx in range(max(0, x - 2), min(w, x + 3))
                          if inp["smap"][yy, xx] and inp["hit"][yy, xx]]
                    if len(nb) >= 3:
                        vals = np.array([inp["stoch"][p] for p in nb], np.float64)
                        mu, sd = vals.mean(0), np.sqrt(np.maximum(vals.var(0), 0))
                        lo, hi = mu - cfg.clamp_gamma * sd, mu + cfg.clamp_gamma * sd
                        cen, ext, d = (lo + hi) / 2, (hi - lo) / 2, hst - (lo + hi) / 2
                        t = min([1.0] + [ext[k] / abs(d[k]) for k in range(3) if abs(d[k]) > ext[k]])
                        hst = cen + d * t
                    m = min(age, cfg.max_history_frames - 1)
                    a = max(1.0 / (m + 1), min(np.linalg.norm(inp["vel"][y, x]) * cfg.motion_alpha_per_px, 1.0),
                            1.0 - wsum)
                    sacc = hst + (s - hst) * a
                    c = c - s + sacc
                out[y, x] = c
                filled[y, x] = 1
            elif (have and not inp["moved"][y, x] and stale + 1 < cfg.max_history_frames
                  and (age >= min_age or np.linalg.norm(inp["vel"][y, x]) <= 0.5)):
                out[y, x] = hc
                filled[y, x] = 1
    return out, filled


def _setup(rng, h, w, device, stochastic, min_samples=4):
    cfg = fw.TemporalConfig(stochastic_min_samples=min_samples)
    st = TemporalStage(w, h, cfg, device)
    n = h * w
    normal = rng.normal(size=(h, w, 3))
    normal[..., 2] = np.abs(normal[..., 2]) + 2.0
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    prev = {"color": rng.random((n, 3)), "stoch": rng.random((n, 3)) * 0.3,
            "normal": np.where(rng.random((n, 1)) < 0.85, normal.reshape(n, 3), -normal.reshape(n, 3)),
            "age": rng.integers(0, 20, n).astype(np.int32), "stale": rng.integers(0, 17, n).astype(np.int32),
            "depth": rng.uniform(2.0, 3.0, (h, w)), "valid": (rng.random((h, w)) < 0.9).astype(np.uint8)}
    # the state every run leaves: non-empty history (age > 0) only where the pixel was filled
    prev["age"] = np.where(prev["valid"].reshape(n) != 0, prev["age"], 0).astype(np.int32)
    st.set_history(color=prev["color"], stoch=prev["stoch"], normal=prev["normal"], age=prev["age"],
                   stale=prev["stale"], depth=prev["depth"], filled=prev["valid"])
    ys, xs = np.mgrid[0:h, 0:w]
    # previous positions up to a few pixels away, a fifth of them within half a pixel (a still pixel)
    motion = rng.uniform(-3.0, 3.0, (h, w, 2)) * np.where(rng.random((h, w, 1)) < 0.2, 0.1, 1.0)
    uv = np.stack([xs + 0.5, ys + 0.5], -1) - motion
    uv[rng.random((h, w)) < 0.05] = -1e4
    uv[0, :3, 0] = xs[0, :3] + 0.5 + 1e-4  # snapped to the own pixel
    uv[0, :3, 1] = 0.5
    depth_cur = rng.uniform(2.0, 3.0, (h, w))
    # prev_dist: near the previous depth of the nearest tap for most pixels (hits), random for others
    near_tap = prev["depth"][np.clip(np.floor(uv[..., 1]).astype(int), 0, h - 1),
                             np.clip(np.floor(uv[..., 0]).astype(int), 0, w - 1)]
    prev_dist = np.where(rng.random((h, w)) < 0.8, near_tap * (1 + rng.uniform(-0.004, 0.004, (h, w))),
                         rng.uniform(2.0, 3.0, (h, w)))
    inp = {"smap": (rng.random((h, w)) < 0.4).astype(np.uint8), "hit": (rng.random((h, w)) < 0.9).astype(np.uint8),
           "normal": normal, "depth": depth_cur, "uv": uv, "prev_dist": prev_dist,
           "moved": (rng.random((h, w)) < 0.1).astype(np.uint8),
           "fresh": rng.random((h, w, 3)).astype(np.float32)}
    inp["stoch"] = (inp["fresh"] * rng.uniform(0, 0.5, (h, w, 1))).astype(np.float32) if stochastic else \
        np.zeros((h, w, 3), np.float32)
    g = GBuffer(w, h, device)
    for k, a in (("hit", inp["hit"]), ("normal", normal), ("depth", depth_cur), ("reproj_uv", uv),
                 ("prev_dist", prev_dist), ("moved", inp["moved"])):
        getattr(g, k).assign(np.asarray(a, dtype=getattr(g, k).numpy().dtype if k in ("hit", "moved") else np.float32))
    arrs = {k: wp.array(inp[k], dtype=wp.vec3, device=device) for k in ("fresh", "stoch")}
    smap = wp.array(inp["smap"], dtype=wp.uint8, device=device)
    # the reference sees the float32 values the kernel sees
    # the velocity the kernel computes (GBuffer.velocity): the pixel centre minus the reprojection, 0 without one
    inp["vel"] = g.velocity.numpy()
    uv32 = np.asarray(uv, np.float32)
    none = (uv32 == np.float32(-1e4)).all(-1)
    np.testing.assert_array_equal(inp["vel"], np.where(none[..., None], np.float32(0),
                                                       np.stack([xs + 0.5, ys + 0.5], -1).astype(np.float32) - uv32))
    for k in ("depth", "prev_dist", "uv", "normal", "vel"):
        inp[k] = np.asarray(inp[k], np.float32).astype(np.float64)
    for k in ("color", "stoch", "normal", "depth"):
        prev[k] = np.asarray(prev[k], np.float32).astype(np.float64)
    return cfg, st, g, inp, prev, arrs, smap


@pytest.mark.parametrize("stochastic,samples,min_samples", [(False, 1, 4), (True, 1, 4), (True, 2, 4), (True, 3, 4),
                                                            (True, 8, 4), (True, 5, 12)])
@pytest.mark.parametrize("use_history", [False, True])
def test_resolve_matches_numpy_rule(device, rng, stochastic, samples, min_samples, use_history):
    h, w = 13, 17
    cfg, st, g, inp, prev, arrs, smap = _setup(rng, h, w, device, stochastic, min_samples)
    st.run(smap, g, arrs["fresh"], arrs["stoch"], use_history=use_history, stochastic=stochastic,
           background=tuple(BG), samples=samples)
    got, filled = st.color.numpy(), st.filled.numpy()
    ref, rfilled = ref_resolve(inp, prev, cfg, use_history, stochastic, samples)
    np.testing.assert_array_equal(filled, rfilled)
    np.testing.assert_allclose(got, ref, atol=2e-5, rtol=1e-5)
    assert np.isfinite(got).all()
    # the rule's cases all occur in this draw
    assert use_history is False or (rfilled.astype(bool) & ~inp["smap"].astype(bool) & inp["hit"].astype(bool)).any()


def test_traced_deterministic_pixels_are_the_fresh_value(device, rng):
    h, w = 13, 17
    cfg, st, g, inp, prev, arrs, smap = _setup(rng, h, w, device, False)
    st.run(smap, g, arrs["fresh"], arrs["stoch"], use_history=True, stochastic=False)
    got = st.color.numpy()
    traced = inp["smap"].astype(bool) & inp["hit"].astype(bool)
    np.testing.assert_array_equal(got[traced], inp["fresh"][traced])


def test_variance_clipping_on_a_step_edge(device):
    """A static view of a step edge whose stochastic history is wrong on one side (as after a lighting change):
    the history is clipped into the box of the fresh neighbourhood, so the output leaves it by no more than
    the fresh values' own spread, while a history consistent with the fresh values is kept as is."""
    h, w = 12, 16
    st = TemporalStage(w, h, fw.TemporalConfig(), device)
    fresh = np.zeros((h, w, 3), np.float32)
    fresh[:, : w // 2] = 0.2
    fresh[:, w // 2:] = 0.8
    rng = np.random.default_rng(3)
    fresh += rng.normal(0, 0.01, fresh.shape).astype(np.float32)
    hist = np.zeros((h * w, 3), np.float32)
    hist.reshape(h, w, 3)[:, : w // 2] = 0.2  # consistent
    hist.reshape(h, w, 3)[:, w // 2:] = 0.2  # the right half's history is stale: 0.2 instead of 0.8
    st.set_history(color=hist, stoch=hist, normal=np.tile([0.0, 0.0, 1.0], (h * w, 1)),
                   age=np.full(h * w, 15, np.int32), stale=np.zeros(h * w, np.int32),
                   depth=np.full((h, w), 2.0), filled=np.ones((h, w), np.uint8))
    g = GBuffer(w, h, device)
    g.hit.fill_(1)
    g.normal.fill_(wp.vec3(0.0, 0.0, 1.0))
    g.depth.fill_(2.0)
    g.prev_dist.fill_(2.0)
    ys, xs = np.mgrid[0:h, 0:w]
    g.reproj_uv.assign(np.stack([xs + 0.5, ys + 0.5], -1).astype(np.float32))
    smap = wp.array(np.ones((h, w), np.uint8), dtype=wp.uint8, device=device)
    f = wp.array(fresh, dtype=wp.vec3, device=device)
    st.run(smap, g, f, f, use_history=True, stochastic=True)
    out = st.color.numpy()
    right = out[2:-2, w // 2 + 2: -2]
    assert right.min() > 0.75, right.min()  # unclipped, 15/16 of a 0.2 history would give ~0.24
    left = out[2:-2, 2: w // 2 - 2]
    # consistent history is kept: the left half is the running mean, much smoother than the fresh noise
    assert np.abs(left - 0.2).max() < np.abs(fresh[2:-2, 2: w // 2 - 2] - 0.2).max()


def _gaze(i, n, w, h):
    t = i / n
    return (w * (0.5 + 0.3 * math.sin(2 * math.pi * t)), h * (0.5 + 0.2 * math.sin(4 * math.pi * t + 0.5)))


@pytest.mark.parametrize("scene_name", ["city", "earth"])
def test_history_never_costs_in_motion_and_fovea_exact(scene_name):
    """Along the scene's own camera path with a moving gaze (and the earth spinning): every frame with history is
    within 0.3 dB of (or above) the same frame without history, and the fovea (<= 5 deg) equals the reference
    (deterministic shading, fovea traced at full rate)."""
    w, h, n = 160, 90, 20
    scene = fw.load_scene(scene_name)
    on = fw.FrameLoop(scene, w, h, device="cpu")
    off = fw.FrameLoop(scene, w, h, config=fw.Config().with_(temporal={"enabled": False}), device="cpu")
    ref = fw.FrameLoop(scene, w, h, device="cpu")
    gains = []
    for i in range(n):
        t = i / 30.0
        cam, g = scene.camera_at(t), _gaze(i, n, w, h)
        r = ref.render_reference(cam, time=t).numpy().copy()
        a = on.render(cam, gaze_px=g, time=t)
        m = region_metrics(a.numpy(), r, g, cam.fov_y_deg)
        assert m["psnr_fovea"] == np.inf, (i, m["psnr_fovea"])
        b = off.render(cam, gaze_px=g, time=t).numpy()
        gains.append(min(m["psnr"], 100.0) - min(psnr(b, r), 100.0))
    assert min(gains) >= -0.3, gains
    if scene_name == "city":  # static geometry: history helps (the spinning earth's moving surface gets none)
        assert np.mean(gains) > 1.0, gains


def test_still_stochastic_view_converges_with_progressive_sampling():
    """With 4 AO rays on a still view, frame 29 is >= 3 dB closer to a converged (256-ray) reference
    than frame 0; while converging the sampling floor is raised (reported), afterwards the refresh budget
    thins the samples again."""
    w, h = 128, 72
    scene = fw.load_scene("cornell")
    cfg = fw.Config().with_(shading={"ao_samples": 4, "ambient": (0.3, 0.3, 0.3)})
    # the foveated frame every time (the default "auto" policy traces every pixel in its measurement frames)
    loop = fw.FrameLoop(scene, w, h, config=cfg, device="cpu", policy="foveated")
    conv = fw.FrameLoop(scene, w, h, config=cfg.with_(shading={"ao_samples": 256}), device="cpu")
    ref = conv.render_reference(scene.camera).numpy()
    rates, ps, boosted = [], [], []
    for i in range(30):
        f = loop.render(scene.camera, gaze_px=(64.0, 36.0))
        rates.append(f.stats["sampling_rate"])
        boosted.append("foveation.min_probability" in f.stats["skipped"])
        ps.append(psnr(f.numpy(), ref))
    assert ps[29] >= ps[0] + 3.0, (ps[0], ps[29])
    n = fw.TemporalConfig().max_history_frames
    assert not boosted[0] and all(boosted[2:n]) and not any(boosted[n + 2:])
    assert min(rates[2:n]) > max(rates[0], rates[-1])
    # deterministic shading never raises the floor
    d = fw.FrameLoop(scene, w, h, device="cpu")
    for i in range(4):
        fd = d.render(scene.camera, gaze_px=(64.0, 36.0))
        assert "foveation.min_probability" not in fd.stats["skipped"]


# -- storage of the history: what the resolve does not read must hold by construction ---------------------------


@pytest.mark.parametrize("stochastic", [False, True])
@pytest.mark.parametrize("use_history", [False, True])
def test_resolve_leaves_age_only_where_filled(device, rng, stochastic, use_history):
    """The resolve reads no previous filled mask: a tap with age > 0 counts as filled. Every run must leave
    age > 0 only where it wrote filled = 1 (any inputs), keep the G-buffer depth as the next previous depth,
    and hand out its colour history as the frame's colour."""
    h, w = 13, 17
    cfg, st, g, inp, prev, arrs, smap = _setup(rng, h, w, device, stochastic)
    for _ in range(3):
        st.run(smap, g, arrs["fresh"], arrs["stoch"], use_history=use_history, stochastic=stochastic,
               background=tuple(BG))
        hist = st.history()
        age = hist["age"].reshape(h, w)
        assert ((age > 0) <= (hist["filled"] != 0)).all()
        assert (age > 0).any()
        np.testing.assert_array_equal(hist["depth"], g.depth.numpy())
        np.testing.assert_array_equal(hist["color"], st.color.numpy())
        np.testing.assert_array_equal(hist["filled"], st.filled.numpy())


def test_frame_loop_history_invariants_in_motion():
    """Along a moving sequence (deterministic and 2 AO rays, a small fovea so that history is reused): age > 0
    only where filled, the temporal depth is the frame's G-buffer depth (the next cache test's previous depth),
    and the frame's sparse colour and filled mask are the history's current slot."""
    w, h = 96, 64
    scene = fw.load_scene("cornell")
    for over in ({}, {"shading": {"ao_samples": 2}}):
        cfg = fw.Config().with_(foveation={"fovea_deg": 1.0, "falloff_deg": 4.0}, **over)
        loop = fw.FrameLoop(scene, w, h, config=cfg, device="cpu", cpu_threads=1)
        reused = 0
        for i in range(4):
            cam = scene.camera
            cam = fw.Camera(eye=(cam.eye[0] + 0.04 * i, cam.eye[1], cam.eye[2]), target=cam.target, up=cam.up,
                            fov_y_deg=cam.fov_y_deg)
            f = loop.render(cam, gaze_px=(20.0 + 5 * i, 20.0))
            hist = loop.temporal.history()
            filled = hist["filled"] != 0
            assert ((hist["age"].reshape(h, w) > 0) <= filled).all()
            np.testing.assert_array_equal(hist["depth"], loop.gbuffer.depth.numpy())
            np.testing.assert_array_equal(f.extras["sparse"].numpy(), hist["color"])
            np.testing.assert_array_equal(f.extras["filled"].numpy(), hist["filled"])
            reused += int((filled & (f.sampling_map.numpy() == 0) & (loop.gbuffer.hit.numpy() != 0)).sum())
        assert reused > 0  # history was reused, so the invariants were exercised on reprojected pixels


def test_shading_kind_change_forgets_history(device, rng):
    """History written by the deterministic resolve has no stochastic part: the first stochastic run after a
    deterministic one (and the reverse) resolves as without history, and the history is used again after."""
    h, w = 13, 17
    cfg, st, g, inp, prev, arrs, smap = _setup(rng, h, w, device, True)
    load = dict(color=prev["color"], stoch=prev["stoch"], normal=prev["normal"], age=prev["age"],
                stale=prev["stale"], depth=prev["depth"], filled=prev["valid"])
    args = (smap, g, arrs["fresh"], arrs["stoch"])

    def run(stage, **kw):
        stage.run(*args, background=tuple(BG), **kw)
        return stage.color.numpy().copy()

    fresh_stage = TemporalStage(w, h, cfg, device)
    without = {k: run(fresh_stage, use_history=False, stochastic=k) for k in (False, True)}
    with_hist = {}
    for k in (False, True):
        s2 = TemporalStage(w, h, cfg, device)
        s2.set_history(**load)
        with_hist[k] = run(s2, use_history=True, stochastic=k)
        assert not np.array_equal(with_hist[k], without[k])  # history matters in this draw
    for first in (False, True):
        s3 = TemporalStage(w, h, cfg, device)
        s3.set_history(**load)
        run(s3, use_history=True, stochastic=first)
        s3.set_history(**load)
        np.testing.assert_array_equal(run(s3, use_history=True, stochastic=not first), without[not first])
        s3.set_history(**load)  # same kind again: the history counts
        np.testing.assert_array_equal(run(s3, use_history=True, stochastic=not first), with_hist[not first])


def test_set_history_rejects_age_without_filled(device):
    st = TemporalStage(4, 3, fw.TemporalConfig(), device)
    z = np.zeros(12)
    with pytest.raises(ValueError, match="filled"):
        st.set_history(color=np.zeros((12, 3)), stoch=np.zeros((12, 3)), normal=np.zeros((12, 3)),
                       age=np.ones(12, np.int32), stale=z.astype(np.int32), depth=np.zeros((3, 4)),
                       filled=np.zeros((3, 4), np.uint8))


@pytest.mark.parametrize("scene", ["cornell", "eyechart"])
def test_shading_in_the_resolve_equals_two_passes(monkeypatch, scene):
    """The CPU's fused launch (deterministic shading: the masked shading of each sampled pixel just before its
    resolve, ``TemporalStage.run(shade=...)``) against the two launches it replaces: whole moving-camera frames,
    byte for byte (display image, shaded radiance, history colour / filled / depth), at 1 and 3 threads."""
    from foveawarp.frame_loop import FrameLoop

    w, h = 61, 35

    def frames(threads):
        fl = fw.FrameLoop(scene, w, h, device="cpu", cpu_threads=threads, timing=False, policy="foveated")
        out, fused = [], []
        for i in range(5):
            fr = fl.render(fl.scene.camera_at(0.07 * i), gaze_px=(w * (0.2 + 0.12 * i), h * 0.5), time=0.07 * i)
            fused.append(fl._shade_in_resolve(fr.stats["strategy"]))
            out += [a.numpy().tobytes() for a in (fr.image, fl.radiance, fl.temporal.color, fl.temporal.filled,
                                                    fl.temporal.depth)]
        return out, fused

    for threads in (1, 3):
        one, fused = frames(threads)
        assert all(fused)
        monkeypatch.setattr(FrameLoop, "_shade_in_resolve", lambda self, strategy: False)
        two, fused = frames(threads)
        monkeypatch.undo()
        assert not any(fused)
        for i, (a, b) in enumerate(zip(one, two)):
            assert a == b, (threads, i)


def test_shading_in_the_resolve_rejected_where_it_cannot_run(device):
    """``run(shade=...)`` needs the CPU's rows kernels and deterministic shading: anything else is a ValueError
    naming ``shade``."""
    fl = fw.FrameLoop("cornell", 24, 16, device=device, timing=False, policy="foveated")
    fl.render(fl.scene.camera_at(0.0), gaze_px=(12, 8))
    st = fl.temporal
    args = (fl.sampling.sample_map, fl.gbuffer, fl.radiance, fl.radiance_stoch)
    assert st.can_shade(True) is False
    with pytest.raises(ValueError, match="shade must be None"):
        st.run(*args, stochastic=True, shade=fl.shade)
    if wp.get_device(device).is_cuda:
        assert st.can_shade(False) is False
        with pytest.raises(ValueError, match="shade must be None"):
            st.run(*args, shade=fl.shade)


@pytest.mark.parametrize("scene", ["cornell", "city"])
def test_clip_boxes_by_list_equal_the_gathered_ones(monkeypatch, scene):
    """Stochastic shading with a flat list of traced pixels (reorder "tile"): the clip boxes gathered by a launch
    over the list (``stoch_box_list_kernel`` + ``resolve_stoch_boxed_kernel``, the CUDA path, run here on the
    CPU) give the frames of the per-pixel gather, byte for byte: display image, history colour, stochastic
    history, filled mask, over moving frames."""
    w, h = 57, 33
    cfg = fw.Config().with_(shading={"ao_samples": 2}, reorder={"strategy": "tile"})

    def frames(by_list):
        monkeypatch.setattr(TemporalStage, "list_boxes_on_cpu", by_list)
        fl = fw.FrameLoop(scene, w, h, config=cfg, device="cpu", timing=False, policy="foveated")
        out = []
        for i in range(6):
            fr = fl.render(fl.scene.camera_at(0.06 * i), gaze_px=(w * (0.2 + 0.1 * i), h * 0.5), time=0.06 * i)
            assert fr.stats["strategy"] == "tile"
            st = fl.temporal
            out += [a.numpy().tobytes() for a in (fr.image, st.color, st.filled, st._stoch[st._cur])]
        return out, fl.temporal._box is not None

    listed, used = frames(True)
    assert used
    gathered, used = frames(False)
    assert not used
    assert listed == gathered


def test_clip_box_list_kernel_against_numpy(rng):
    """``stoch_box_list_kernel`` against a NumPy box (mean +- gamma sd over the traced surface pixels of the 5 x 5
    window, float64, rtol 1e-5): listed surface pixels get their box, listed ones with fewer than 3 traced
    neighbours the empty box (lo > hi), misses and unlisted pixels nothing."""
    from foveawarp.kernels.temporal import TemporalParams, stoch_box_list_kernel

    h, w = 19, 23
    smap = (rng.random((h, w)) < 0.3).astype(np.uint8)
    smap[0:4, 0:4] = 0
    smap[1, 1] = 1  # alone in its corner: fewer than 3 traced neighbours
    hit = (rng.random((h, w)) < 0.85).astype(np.uint8)
    hit[1, 1] = 1
    stoch = rng.random((h, w, 3)).astype(np.float32)
    work = np.flatnonzero(smap.ravel()).astype(np.int32)
    tp = TemporalParams()
    tp.box_radius = 2
    tp.clamp_gamma = 1.25
    lo = wp.full((h, w), wp.vec3(-7.0, -7.0, -7.0), dtype=wp.vec3, device="cpu")
    hi = wp.full((h, w), wp.vec3(-7.0, -7.0, -7.0), dtype=wp.vec3, device="cpu")
    wp.launch(stoch_box_list_kernel, dim=h * w,
              inputs=[tp, wp.array(np.resize(work, h * w), dtype=wp.int32, device="cpu"),
                      wp.array([len(work)], dtype=wp.int32, device="cpu"), w,
                      wp.array(smap, dtype=wp.uint8, device="cpu"), wp.array(hit, dtype=wp.uint8, device="cpu"),
                      wp.array(stoch, dtype=wp.vec3, device="cpu")],
              outputs=[lo, hi], device="cpu")
    lo, hi = lo.numpy(), hi.numpy()
    traced = (smap != 0) & (hit != 0)
    for y in range(h):
        for x in range(w):
            if not (smap[y, x] and hit[y, x]):
                assert (lo[y, x] == -7).all() and (hi[y, x] == -7).all()
                continue
            win = traced[max(y - 2, 0):y + 3, max(x - 2, 0):x + 3]
            vals = stoch[max(y - 2, 0):y + 3, max(x - 2, 0):x + 3][win].astype(np.float64)
            if len(vals) < 3:
                assert lo[y, x][0] > hi[y, x][0]
                continue
            mu, sd = vals.mean(0), np.sqrt(np.maximum((vals ** 2).mean(0) - vals.mean(0) ** 2, 0))
            np.testing.assert_allclose(lo[y, x], mu - 1.25 * sd, rtol=1e-5, atol=1e-5)
            np.testing.assert_allclose(hi[y, x], mu + 1.25 * sd, rtol=1e-5, atol=1e-5)
    assert lo[1, 1][0] > hi[1, 1][0]


def test_stochastic_min_age_counts_samples():
    """The minimum age of reused moving stochastic history is the samples it must hold over the samples per
    frame, rounded up, at least one frame; the TemporalStage's parameters carry it, and bad counts are refused."""
    from foveawarp.stages.temporal import stochastic_min_age

    for need, spp, want in ((8, 8, 1), (8, 4, 2), (8, 3, 3), (8, 2, 4), (8, 1, 8), (8, 64, 1), (1, 1, 1), (4096, 1, 4096),
                            (4, 2**31 - 1, 1)):
        assert stochastic_min_age(need, spp) == want, (need, spp)
    for need, spp, name in ((0, 1, "min_samples"), (4097, 1, "min_samples"), (2.5, 1, "min_samples"),
                            (4, 0, "samples_per_pixel"), (4, -3, "samples_per_pixel"), (4, True, "samples_per_pixel")):
        with pytest.raises(ValueError, match=name):
            stochastic_min_age(need, spp)
    st = TemporalStage(8, 4, fw.TemporalConfig(stochastic_min_samples=12), "cpu")
    assert st.params(use_history=True, stochastic=True, samples=5).min_age_reuse == 3
    assert st.params(use_history=True, stochastic=False, samples=5).min_age_reuse == 1
    g = GBuffer(8, 4, "cpu")
    z = wp.zeros((4, 8), dtype=wp.vec3, device="cpu")
    m = wp.zeros((4, 8), dtype=wp.uint8, device="cpu")
    for bad in (0, -1, 2**31, 2.5, True):
        with pytest.raises(ValueError, match="samples"):
            st.run(m, g, z, z, stochastic=True, samples=bad)
    for bad in (0, 4097, 1.5):
        with pytest.raises(ValueError, match="TemporalConfig.stochastic_min_samples"):
            fw.TemporalConfig(stochastic_min_samples=bad)


@pytest.mark.parametrize("ao,area,want", [(0, False, 1), (3, False, 3), (8, False, 8), (2, True, 2 + 4)])
def test_frame_loop_passes_its_samples_per_pixel(monkeypatch, ao, area, want):
    """FrameLoop hands the temporal resolve its Monte Carlo samples per pixel (AO rays plus the area lights'
    samples; 1 for deterministic shading): the frame-loop side of the stochastic rule."""
    scene = fw.scenes.cornell(area_light=area)
    cfg = fw.Config().with_(shading={"ao_samples": ao, "area_light_samples": 4})
    loop = fw.FrameLoop(scene, 48, 27, config=cfg, device="cpu", policy="foveated")
    assert loop.shade.stochastic_samples() == want - (1 if ao == 0 and not area else 0)
    got = []
    orig = TemporalStage.run

    def spy(self, *a, **k):
        got.append((k.get("stochastic"), k.get("samples")))
        return orig(self, *a, **k)

    monkeypatch.setattr(TemporalStage, "run", spy)
    for i in range(3):
        loop.render(scene.camera_at(i / 30.0), gaze_px=(24, 13), time=i / 30.0)
    assert got and all(s == want for _, s in got), got
    assert all(st == (ao > 0 or area) for st, _ in got), got
