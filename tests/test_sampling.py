"""Foveation probability (thesis eq. 2) and the stratified sampling map, against independent NumPy references."""

import math

import numpy as np
import pytest
import warp as wp
from hypothesis import given, settings
from hypothesis import strategies as st

import foveawarp as fw
from foveawarp import ops
from foveawarp.buffers import GBuffer
from foveawarp.stages.sampling import SamplingStage, dither_ranks, rank_step

# ---------------------------------------------------------------------------------------------------------------
# independent references (float64): a pinhole with focal length f = (H / 2) / tan(fov_y / 2) in pixels; the ray
# through pixel position (px, py) is (px - W/2, py - H/2, f) (flipping y would not change any angle)


def ref_dirs(px, py, w, h, fov_y_deg):
    f = 0.5 * h / math.tan(math.radians(fov_y_deg) / 2.0)
    px, py = np.broadcast_arrays(np.asarray(px, np.float64), np.asarray(py, np.float64))
    return np.stack([px - 0.5 * w, py - 0.5 * h, np.full(px.shape, f)], axis=-1)


def ref_angle_deg(a, b):
    c = np.linalg.norm(np.cross(a, b), axis=-1)
    return np.degrees(np.arctan2(c, np.sum(a * b, axis=-1)))


def ref_eccentricity(w, h, gaze, fov):
    ys, xs = np.mgrid[0:h, 0:w] + 0.5
    g = ref_dirs(gaze[0], gaze[1], w, h, fov)
    return ref_angle_deg(ref_dirs(xs, ys, w, h, fov), g[None, None, :])


def ref_emax(w, h, gaze, fov, n=20001):
    """Largest eccentricity over the screen rectangle, by brute force along its four edges."""
    t = np.linspace(0.0, 1.0, n)
    xs = np.concatenate([t * w, np.full(n, w), t * w, np.zeros(n)])
    ys = np.concatenate([np.zeros(n), t * h, np.full(n, h), t * h])
    g = ref_dirs(gaze[0], gaze[1], w, h, fov)
    return float(ref_angle_deg(ref_dirs(xs, ys, w, h, fov), g[None, :]).max())


def ref_probability(w, h, gaze, fov, m, b, xi, falloff=None):
    e = ref_eccentricity(w, h, gaze, fov)
    g = ref_dirs(gaze[0], gaze[1], w, h, fov)
    g1 = ref_dirs(gaze[0] + 1.0, gaze[1], w, h, fov)
    w_min = float(ref_angle_deg(g, g1))
    e_norm = ref_emax(w, h, gaze, fov)
    if falloff is not None:
        e_norm = min(e_norm, falloff)
    w_far = m * e_norm + b
    return np.clip(1.0 - (m * e + b - w_min) / w_far, xi, 1.0)


def tile_counts(mask, k):
    h, w = mask.shape
    ty, tx = -(-h // k), -(-w // k)
    pad = np.zeros((ty * k, tx * k), dtype=np.int64)
    pad[:h, :w] = mask
    return pad.reshape(ty, k, tx, k).sum(axis=(1, 3))


W, H = 96, 72
GAZES = [(48.0, 36.0), (0.0, 0.0), (96.0, 72.0), (13.25, 60.5), (-50.0, 30.0), (296.0, 172.0), (-960.0, 36.0),
         (48.0, -5000.0)]


# ---------------------------------------------------------------------------------------------------------------
# eccentricity and eq. 2


@pytest.mark.parametrize("fov", [30.0, 60.0, 110.0])
def test_eccentricity_matches_reference(device, fov):
    for w, h in ((W, H), (37, 53)):
        for gx, gy in GAZES:
            gaze = (gx * w / W, gy * h / H)
            got = ops.eccentricity_deg(w, h, gaze, fov, device=device)
            ref = ref_eccentricity(w, h, gaze, fov)
            assert got.shape == (h, w) and got.dtype == np.float32
            err = np.abs(got - ref).max()
            assert err < 1e-4, f"gaze {gaze} fov {fov}: max error {err} deg"


def test_far_off_screen_gaze_uses_edge_interior_maximum():
    # gaze 10 screen widths to the left: the largest eccentricity lies mid-way along the right edge, not at a
    # corner; the reference finds it by brute force, so a corners-only w_far would fail test_probability below
    w, h, fov, gaze = W, H, 60.0, (-960.0, 36.0)
    g = ref_dirs(*gaze, w, h, fov)
    corners = ref_dirs(np.array([0, w, 0, w]), np.array([0, 0, h, h]), w, h, fov)
    assert ref_emax(w, h, gaze, fov) > ref_angle_deg(corners, g[None]).max() + 0.5


@pytest.mark.parametrize("m,b,xi", [(0.028, 1.0 / 48.0, 0.05), (0.022, 0.03, 0.3), (0.2, 0.5, 0.0)])
def test_foveation_probability_matches_reference(device, m, b, xi):
    for gaze in GAZES:
        for fov in (45.0, 100.0):
            got = ops.foveation_probability(W, H, gaze, fov, mar_slope=m, mar_fovea_deg=b, min_probability=xi,
                                            device=device)
            ref = ref_probability(W, H, gaze, fov, m, b, xi)
            assert np.abs(got - ref).max() < 2e-5, (gaze, fov)
            assert got.min() >= xi - 1e-7 and got.max() <= 1.0


@pytest.mark.parametrize("falloff", [0.5, 5.0, 12.0, 179.0])
def test_foveation_probability_with_falloff_matches_reference(device, falloff):
    m, b, xi = 0.028, 1.0 / 48.0, 0.05
    for gaze in GAZES[:5]:
        got = ops.foveation_probability(W, H, gaze, 60.0, mar_slope=m, mar_fovea_deg=b, min_probability=xi,
                                        falloff_deg=falloff, device=device)
        ref = ref_probability(W, H, gaze, 60.0, m, b, xi, falloff)
        assert np.abs(got - ref).max() < 2e-5, (gaze, falloff)
        base = ops.foveation_probability(W, H, gaze, 60.0, mar_slope=m, mar_fovea_deg=b, min_probability=xi,
                                         device=device)
        assert np.all(got <= base + 1e-6)  # a nearer falloff never raises the probability
    with pytest.raises(ValueError, match="falloff_deg"):
        ops.foveation_probability(W, H, (1, 1), 60.0, mar_slope=m, mar_fovea_deg=b, min_probability=xi,
                                  falloff_deg=0.0, device=device)
    with pytest.raises(ValueError, match="falloff_deg"):
        fw.FoveationConfig(falloff_deg=float("nan"))


@pytest.mark.parametrize("fovea", [0.0, 2.5, 5.0, 30.0])
def test_foveation_probability_full_rate_fovea(device, fovea):
    """FoveationConfig.fovea_deg: probability 1 where the (independently computed) eccentricity is <= fovea_deg,
    eq. 2 elsewhere; the SamplingStage then samples every pixel of the fovea in every frame."""
    m, b, xi = 0.028, 1.0 / 48.0, 0.05
    for gaze in GAZES[:5]:
        got = ops.foveation_probability(W, H, gaze, 60.0, mar_slope=m, mar_fovea_deg=b, min_probability=xi,
                                        falloff_deg=20.0, fovea_deg=fovea, device=device)
        ref = ref_probability(W, H, gaze, 60.0, m, b, xi, 20.0)
        e = ref_eccentricity(W, H, gaze, 60.0)
        inside = e <= fovea
        clear = np.abs(e - fovea) > 1e-3  # float32 eccentricity vs float64 at the boundary
        ref = np.where(inside, 1.0, ref)
        assert np.abs(got - ref)[clear].max() < 2e-5, (gaze, fovea)
    with pytest.raises(ValueError, match="fovea_deg"):
        ops.foveation_probability(W, H, (1, 1), 60.0, mar_slope=m, mar_fovea_deg=b, min_probability=xi,
                                  fovea_deg=-1.0, device=device)
    cfg = fw.Config().with_(foveation={"fovea_deg": 10.0, "falloff_deg": 12.0})
    st = SamplingStage(96, 64, cfg, device=device)
    gb = GBuffer(96, 64, device)
    cam = fw.Camera(eye=(0, 0, 3), target=(0, 0, 0), fov_y_deg=60.0)
    e = ref_eccentricity(96, 64, (40.0, 30.0), 60.0)
    for i in range(3):
        st.run(gb, cam, (40.0, 30.0), i, moving=False, first_frame=True)
        smap = st.sample_map.numpy().astype(bool)
        assert smap[e <= 10.0 - 1e-3].all()


def test_falloff_lowers_the_frame_loop_sampling_rate(device):
    scene = fw.load_scene("eyechart")
    rates = {}
    for fo in (None, 10.0):
        cfg = fw.Config().with_(foveation={"falloff_deg": fo})
        loop = fw.FrameLoop(scene, 160, 90, config=cfg, device=device)
        rates[fo] = loop.render(scene.camera, gaze_px=(80.0, 45.0)).stats["sampling_rate"]
    assert rates[10.0] < 0.8 * rates[None], rates


def test_probability_is_one_at_the_gaze_and_falls_off(device):
    p = ops.foveation_probability(320, 180, (160.0, 90.0), 60.0, mar_slope=0.028, mar_fovea_deg=1 / 48,
                                  min_probability=0.05, device=device)
    assert p[90, 160] == 1.0
    assert p[0, 0] < 0.6 and p[0, 0] == pytest.approx(p[179, 319], abs=1e-6)


def test_invalid_inputs_raise():
    with pytest.raises(ValueError, match="gaze_px"):
        ops.eccentricity_deg(W, H, (float("nan"), 3.0), 60.0, device="cpu")
    with pytest.raises(ValueError, match="gaze_px"):
        ops.foveation_probability(W, H, (1.0, float("inf")), 60.0, mar_slope=0.03, mar_fovea_deg=0.02,
                                  min_probability=0.1, device="cpu")
    with pytest.raises(ValueError, match="fov_y_deg"):
        ops.eccentricity_deg(W, H, (1.0, 2.0), 180.0, device="cpu")
    with pytest.raises(ValueError, match="mar_slope"):
        ops.foveation_probability(W, H, (1.0, 2.0), 60.0, mar_slope=0.0, mar_fovea_deg=0.02, min_probability=0.1)
    with pytest.raises(ValueError, match="min_probability"):
        ops.foveation_probability(W, H, (1.0, 2.0), 60.0, mar_slope=0.1, mar_fovea_deg=0.02, min_probability=1.5)
    with pytest.raises(ValueError, match="block"):
        ops.sample_map(np.ones((4, 4)), block=0)
    with pytest.raises(ValueError, match="probability"):
        ops.sample_map(np.full((4, 4), np.nan), block=2)


@settings(max_examples=25, deadline=None)
@given(gx=st.floats(-1e9, 1e9), gy=st.floats(-1e9, 1e9), fov=st.floats(1.0, 179.0),
       xi=st.floats(0.0, 1.0), m=st.floats(1e-4, 1.0), b=st.floats(1e-4, 1.0))
def test_probability_finite_for_any_gaze(gx, gy, fov, xi, m, b):
    p = ops.foveation_probability(17, 11, (gx, gy), fov, mar_slope=m, mar_fovea_deg=b, min_probability=xi,
                                  device="cpu")
    e = ops.eccentricity_deg(17, 11, (gx, gy), fov, device="cpu")
    assert np.isfinite(p).all() and np.isfinite(e).all()
    assert p.min() >= np.float32(xi) - 1e-6 and p.max() <= 1.0
    assert e.min() >= 0.0 and e.max() <= 180.0


# ---------------------------------------------------------------------------------------------------------------
# binarization


def test_dither_ranks_are_blue_noise_permutations():
    for k in range(1, 17):
        r = dither_ranks(k)
        assert r.shape == (k, k) and sorted(r.ravel().tolist()) == list(range(k * k))
    for k in (3, 4, 5, 8, 16):
        r = dither_ranks(k)
        n = k * k
        for m in range(2, n + 1):
            ys, xs = np.nonzero(r < m)
            dx = np.abs(xs[:, None] - xs[None, :])
            dy = np.abs(ys[:, None] - ys[None, :])
            d = np.hypot(np.minimum(dx, k - dx), np.minimum(dy, k - dy)) + np.eye(m) * 1e9
            # the m lowest ranks are spread out: their closest toroidal pair is at least half the spacing of a
            # perfect lattice of m points (a random permutation fails this for every k here)
            assert d.min() >= 0.5 * math.sqrt(n / m), (k, m, d.min())
    for n in (1, 4, 9, 16, 25, 64, 4096):
        s = rank_step(n)
        assert n == 1 or math.gcd(s, n) == 1


@pytest.mark.parametrize("k,w,h", [(4, 64, 48), (4, 61, 45), (3, 50, 31), (5, 23, 17), (1, 9, 7)])
def test_every_tile_has_a_sample(device, k, w, h):
    rng = np.random.default_rng(k * 1000 + w)
    maps = {"zero": np.zeros((h, w)), "xi": np.full((h, w), 1.0 / (k * k)), "random": rng.random((h, w)) ** 3}
    for name, p in maps.items():
        for f in range(0, 40, 7):
            m = ops.sample_map(p, block=k, frame_index=f, seed=3, device=device)
            assert m.dtype == np.uint8 and m.shape == (h, w)
            assert tile_counts(m, k).min() >= 1, (name, f)
    # p = 0: exactly one sample per tile (the rank-0 pixel of a full tile, the forced pixel of a partial one)
    m = ops.sample_map(np.zeros((h, w)), block=k, frame_index=5, device=device)
    assert (tile_counts(m, k) == 1).all()
    assert ops.sample_map(np.ones((h, w)), block=k, device=device).all()


@settings(max_examples=20, deadline=None)
@given(w=st.integers(1, 40), h=st.integers(1, 40), k=st.integers(1, 9), f=st.integers(0, 10**6),
       seed=st.integers(0, 2**31 - 1), p=st.floats(-1.0, 2.0))
def test_tile_guarantee_property(w, h, k, f, seed, p):
    m = ops.sample_map(np.full((h, w), p), block=k, frame_index=f, seed=seed, device="cpu")
    assert tile_counts(m, k).min() >= 1
    if p >= 1.0:
        assert m.all()


def test_constant_probability_is_stratified_per_tile(device):
    # every full 4 x 4 tile gets floor(16 p) or floor(16 p) + 1 samples (white noise would spread 0 .. 16)
    k, h, w = 4, 48, 64
    for p in (0.1, 0.3, 0.55, 0.9):
        for f in (0, 1, 17):
            c = tile_counts(ops.sample_map(np.full((h, w), p), block=k, frame_index=f, device=device), k)
            lo = math.floor(16 * p)
            assert c.min() >= lo and c.max() <= lo + 1, (p, f, c.min(), c.max())
            assert abs(c.mean() / 16.0 - p) < 1.0 / 16.0


def test_rate_converges_to_probability(device):
    k, h, w = 4, 48, 64
    rng = np.random.default_rng(7)
    ys, xs = np.mgrid[0:h, 0:w]
    # smooth map over [1/16, 1] plus a noisy patch
    p = 1.0 / 16 + (15.0 / 16) * (0.5 + 0.5 * np.sin(xs / 9.0) * np.cos(ys / 7.0))
    p[10:20, 30:50] = 1.0 / 16 + (15.0 / 16) * rng.random((10, 20))
    frames = 128
    acc = np.zeros((h, w))
    for f in range(frames):
        acc += ops.sample_map(p, block=k, frame_index=f, seed=11, device=device)
    rate = acc / frames
    err = np.abs(rate - p)
    assert err.mean() < 0.006, err.mean()
    assert err.max() < 0.025, err.max()
    assert abs(rate.mean() - p.mean()) < 0.002


def test_below_floor_rate_is_floor(device):
    # a map below 1 / k^2 is raised to it (the tile guarantee), exactly over k^2 frames
    k, h, w = 4, 32, 32
    p = np.full((h, w), 0.01)
    acc = sum(ops.sample_map(p, block=k, frame_index=f, device=device).astype(np.int64) for f in range(16))
    assert (acc == 1).all()  # each pixel sampled exactly once in 16 frames


def test_maps_differ_frame_to_frame(device):
    k, h, w = 4, 48, 64
    p = np.full((h, w), 0.25)
    prev = ops.sample_map(p, block=k, frame_index=0, device=device)
    for f in range(1, 6):
        cur = ops.sample_map(p, block=k, frame_index=f, device=device)
        overlap = (cur & prev).sum() / max(prev.sum(), 1)
        assert overlap < 0.5, (f, overlap)  # independent draws would overlap by ~0.25; a frozen map by 1
        prev = cur
    a = ops.sample_map(p, block=k, frame_index=3, seed=1, device=device)
    b = ops.sample_map(p, block=k, frame_index=3, seed=2, device=device)
    assert (a != b).any()
    assert (a == ops.sample_map(p, block=k, frame_index=3, seed=1, device=device)).all()


# ---------------------------------------------------------------------------------------------------------------
# stage


def _synthetic_gbuffer(w, h, device, depth=3.0):
    g = GBuffer(w, h, device)
    g.depth.fill_(depth)
    g.hit.fill_(1)
    g.normal.fill_(wp.vec3(0.0, 0.0, 1.0))
    g.albedo.fill_(wp.vec3(0.5, 0.5, 0.5))
    return g


def test_stage_probability_matches_op_and_counters(device):
    cfg = fw.Config()
    cam = fw.Camera(fov_y_deg=50.0)
    g = _synthetic_gbuffer(W, H, device)
    stage = SamplingStage(W, H, cfg, device=device)
    for f, gaze in enumerate([(10.0, 20.0), (-40.0, 90.0)]):
        stage.run(g, cam, gaze, f, moving=False, first_frame=True)
        fc = cfg.foveation  # the defaults: falloff_deg 12, full-rate fovea of 5 deg
        ref = ref_probability(W, H, gaze, 50.0, fc.mar_slope, fc.mar_fovea_deg, fc.effective_min_probability,
                              fc.falloff_deg)
        e = ref_eccentricity(W, H, gaze, 50.0)
        ref = np.where(e <= fc.fovea_deg, 1.0, ref)
        clear = np.abs(e - fc.fovea_deg) > 1e-3
        prob = stage.probability.numpy()
        assert np.abs(prob - ref)[clear].max() < 2e-5
        # uniform albedo and normals, no motion, pinhole: saliency is the foveation probability
        assert np.abs(stage.saliency.numpy() - prob).max() == 0.0
        s = stage.sample_map.numpy()
        assert tile_counts(s, cfg.foveation.block).min() >= 1
        st_ = stage.stats()
        assert st_["num_samples"] == int(s.sum())
        assert st_["num_cache_hits"] == 0 == int(stage.cache_hit.numpy().sum())
        assert set(st_["skipped"]) == {"cache_test", "saliency.velocity", "saliency.dof"}


def test_stage_disabled_foveation_samples_everything(device):
    cfg = fw.Config().with_(foveation={"enabled": False})
    g = _synthetic_gbuffer(40, 30, device)
    stage = SamplingStage(40, 30, cfg, device=device)
    stage.run(g, fw.Camera(), (3.0, 4.0), 0, moving=True, first_frame=True)
    assert stage.sample_map.numpy().all()
    assert (stage.probability.numpy() == 1.0).all() and (stage.saliency.numpy() == 1.0).all()
    assert stage.stats()["num_samples"] == 40 * 30
    assert "foveation" in stage.skipped


def test_stage_rejects_bad_arguments(device):
    g = _synthetic_gbuffer(16, 12, device)
    stage = SamplingStage(16, 12, fw.Config(), device=device)
    with pytest.raises(ValueError, match="gaze_px"):
        stage.run(g, fw.Camera(), (float("nan"), 1.0), 0, moving=False, first_frame=True)
    with pytest.raises(ValueError, match="eye_prev"):
        stage.run(g, fw.Camera(), (1.0, 1.0), 1, moving=False, first_frame=False)
    with pytest.raises(ValueError, match="frame_index"):
        stage.run(g, fw.Camera(), (1.0, 1.0), -1, moving=False, first_frame=True)
    with pytest.raises(ValueError, match="gbuffer"):
        stage.run(_synthetic_gbuffer(8, 8, device), fw.Camera(), (1.0, 1.0), 0, moving=False, first_frame=True)


FRAMES = list(enumerate([(10.0, 20.0), (50.0, 30.0), (90.0, 5.0)]))  # (frame index, gaze)


def test_set_frame_then_launch_equals_run(device):
    g = _synthetic_gbuffer(W, H, device)
    cam = fw.Camera(fov_y_deg=50.0)
    a = SamplingStage(W, H, fw.Config(), device=device)
    b = SamplingStage(W, H, fw.Config(), device=device)
    for f, gaze in FRAMES:
        a.run(g, cam, gaze, f, moving=False, first_frame=True)
        b.set_frame(g, cam, gaze, f, moving=False, first_frame=True)
        b.launch(g)
        assert (a.sample_map.numpy() == b.sample_map.numpy()).all()
        assert (a.saliency.numpy() == b.saliency.numpy()).all()


def _textured_gbuffer(w, h, device, rng):
    """Varied albedo, normals and depth (saliency terms active), reprojection within a pixel or so of the own
    pixel and prev_dist equal to the depth: cache hits wherever the previous frame's depth was the same."""
    g = _synthetic_gbuffer(w, h, device)
    g.albedo.assign(rng.random((h, w, 3)).astype(np.float32))
    n = rng.normal(size=(h, w, 3))
    n[..., 2] = np.abs(n[..., 2]) + 1.0
    g.normal.assign((n / np.linalg.norm(n, axis=-1, keepdims=True)).astype(np.float32))
    ys, xs = np.mgrid[0:h, 0:w]
    uv = np.stack([xs + 0.5 + rng.uniform(-1.2, 1.2, (h, w)), ys + 0.5 + rng.uniform(-1.2, 1.2, (h, w))], -1)
    g.reproj_uv.assign(uv.astype(np.float32))
    g.depth.fill_(3.0)
    g.prev_dist.fill_(3.0)
    return g


def test_launch_with_given_previous_frame_equals_end_frame(device, rng):
    """``launch(depth_prev=, valid_prev=)`` (FrameLoop passes the temporal history's depth and filled mask)
    gives the cache test exactly what ``end_frame`` would have kept."""
    g = _textured_gbuffer(W, H, device, rng)
    cam = fw.Camera(fov_y_deg=50.0)
    mask = wp.array((rng.random((H, W)) < 0.7).astype(np.uint8), dtype=wp.uint8, device=device)
    depth = wp.clone(g.depth)
    a = SamplingStage(W, H, fw.Config(), device=device)
    b = SamplingStage(W, H, fw.Config(), device=device)
    a.run(g, cam, (10.0, 20.0), 0, moving=False, first_frame=True)
    a.end_frame(g, mask)
    kw = dict(moving=False, first_frame=False, eye_prev=cam.eye)
    a.run(g, cam, (30.0, 20.0), 1, **kw)
    b.set_frame(g, cam, (30.0, 20.0), 1, **kw)
    b.launch(g, depth_prev=depth, valid_prev=mask)
    for k in ("sample_map", "cache_hit", "prev_index"):
        np.testing.assert_array_equal(getattr(a, k).numpy(), getattr(b, k).numpy())
    hits = a.cache_hit.numpy()
    assert 0 < hits.sum() < hits.size
    assert a.stats()["num_cache_hits"] == b.stats()["num_cache_hits"] == int(hits.sum())


def test_maps_on_request_are_the_frames_own(device, rng):
    """The probability and saliency maps are computed on request: after each ``run`` they are that frame's
    (equal to a stage that ran only that frame), and the frame's sample map is exactly the stratified
    binarization (``ops.sample_map``) of the reported saliency."""
    g = _textured_gbuffer(W, H, device, rng)
    cam = fw.Camera(fov_y_deg=50.0)
    cfg = fw.Config()
    st_ = SamplingStage(W, H, cfg, device=device)
    seen = []
    for f, gaze in FRAMES:
        st_.run(g, cam, gaze, f, moving=False, first_frame=True)
        if f == 1:
            continue  # a frame whose maps nobody reads
        one = SamplingStage(W, H, cfg, device=device)
        one.run(g, cam, gaze, f, moving=False, first_frame=True)
        p, s = st_.probability.numpy().copy(), st_.saliency.numpy().copy()
        np.testing.assert_array_equal(p, one.probability.numpy())
        np.testing.assert_array_equal(s, one.saliency.numpy())
        assert (s > p).any() and (s >= p).all()  # the gradient terms raise it
        ref = ops.sample_map(s, block=cfg.foveation.block, frame_index=f, seed=0, device=device)
        np.testing.assert_array_equal(st_.sample_map.numpy(), ref)
        seen.append(p)
    assert not np.array_equal(seen[0], seen[1])


def test_map_buffers_hand_the_maps_to_another_pass(device, rng):
    """A pass that writes the maps itself (the sparse G-buffer's) gets them from ``map_buffers``; the
    properties then return what it wrote, and compute nothing over it after later frames."""
    g = _textured_gbuffer(W, H, device, rng)
    cam = fw.Camera(fov_y_deg=50.0)
    st_ = SamplingStage(W, H, fw.Config(), device=device)
    prob, sal = st_.map_buffers()
    for f, gaze in FRAMES:
        st_.run(g, cam, gaze, f, moving=False, first_frame=True)
        prob.fill_(0.25 + f)
        sal.fill_(0.5 + f)
        assert st_.probability is prob and st_.saliency is sal
        assert (st_.probability.numpy() == 0.25 + f).all() and (st_.saliency.numpy() == 0.5 + f).all()


@pytest.mark.needs_cuda
def test_launch_replays_as_a_cuda_graph():
    dev = "cuda:0"
    g = _synthetic_gbuffer(W, H, dev)
    cam = fw.Camera(fov_y_deg=50.0)
    ref = SamplingStage(W, H, fw.Config(), device=dev)
    st_ = SamplingStage(W, H, fw.Config(), device=dev)
    st_.run(g, cam, (1.0, 1.0), 0, moving=False, first_frame=True)  # load the modules before capturing
    with wp.ScopedCapture(dev) as capture:
        st_.launch(g)
    for f, gaze in FRAMES:
        ref.run(g, cam, gaze, f, moving=False, first_frame=True)
        st_.set_frame(g, cam, gaze, f, moving=False, first_frame=True)
        wp.capture_launch(capture.graph)
        assert (ref.sample_map.numpy() == st_.sample_map.numpy()).all()
        assert (ref.probability.numpy() == st_.probability.numpy()).all()
        assert ref.stats()["num_samples"] == st_.stats()["num_samples"]


def test_eccentricity_far_off_screen_gaze_has_no_cancellation(device):
    # a stress-suite case: a plain z of g x d cancels for gazes far off screen (7.25 deg error on these cases)
    rng = np.random.default_rng(7)
    cases = [(64, 1, 170.0, (1.52e27, -3.61e22)), (1, 64, 170.0, (1.01e22, -2.47e12))]
    for _ in range(20):
        cases.append((int(rng.integers(1, 80)), int(rng.integers(1, 60)), float(rng.uniform(1.0, 179.0)),
                      tuple(float(rng.choice([-1, 1]) * 10 ** rng.uniform(2, 30)) for _ in range(2))))
    for w, h, fov, gaze in cases:
        got = ops.eccentricity_deg(w, h, gaze, fov, device=device)
        clamped = (min(max(gaze[0], -1e6), w + 1e6), min(max(gaze[1], -1e6), h + 1e6))
        err = np.abs(got - ref_eccentricity(w, h, clamped, fov)).max()
        assert err < 5e-4, (w, h, fov, gaze, err)


# -- eq. 2's plateaus without the arc tangent (pixel_probability) -------------------------------------------------

from foveawarp.kernels.sampling import (  # noqa: E402
    FrameParams,
    SamplingParams,
    dither_rank,
    eccentricity_at,
    foveation_prob,
    pixel_probability,
)


@wp.kernel(enable_backward=False)
def _probability_both_ways_kernel(sp: SamplingParams, frame: wp.array(dtype=FrameParams),
                                  fast: wp.array2d(dtype=float), slow: wp.array2d(dtype=float)):
    y, x = wp.tid()
    fp = frame[0]
    w = fast.shape[1]
    h = fast.shape[0]
    fast[y, x] = pixel_probability(x, y, w, h, sp, fp)
    e = eccentricity_at(float(x) + 0.5, float(y) + 0.5, fp.gaze, float(w), float(h), fp.tan_half_fov_y)
    slow[y, x] = foveation_prob(e, sp.mar_slope, sp.mar_fovea_deg, fp.w_min_deg, fp.w_far_deg, fp.xi, sp.fovea_deg)


def _both_ways(device, w, h, fov, gaze, cfg, min_probability=None):
    cam = fw.Camera(fov_y_deg=fov)
    stage = SamplingStage(w, h, cfg, device=device)
    stage.set_frame(_synthetic_gbuffer(w, h, device), cam, gaze, 0, moving=False, first_frame=True,
                    min_probability=min_probability)
    fast = wp.zeros((h, w), dtype=float, device=device)
    slow = wp.zeros((h, w), dtype=float, device=device)
    wp.launch(_probability_both_ways_kernel, dim=(h, w), inputs=[stage.params, stage.frame_params],
              outputs=[fast, slow], device=device)
    return fast.numpy(), slow.numpy(), stage.frame_params.numpy()[0]


@pytest.mark.parametrize("fovea,falloff", [(5.0, 12.0), (0.0, 12.0), (5.0, None), (30.0, 12.0), (2.0, 0.5)])
def test_plateau_shortcut_equals_the_formula(device, fovea, falloff):
    """Inside the fovea and beyond the eccentricity where p reaches xi, pixel_probability skips the arc tangent:
    its value equals eccentricity_at + foveation_prob bit for bit at every pixel, and with the defaults both
    plateaus are in use (their tangents are set)."""
    cfg = fw.Config().with_(foveation={"fovea_deg": fovea, "falloff_deg": falloff})
    for gaze in [(40.0, 30.0), (3.0, 60.0), (-500.0, 20.0)]:
        fast, slow, fp = _both_ways(device, 96, 64, 60.0, gaze, cfg)
        assert np.array_equal(fast, slow)
    if fovea > 0.0:
        assert fp["tan2_fovea"] > 0.0
    if falloff is not None:
        assert fp["tan2_floor"] > 0.0


@settings(max_examples=30, deadline=None)
@given(gx=st.floats(-1e6, 1e6), gy=st.floats(-1e6, 1e6), fov=st.floats(1.0, 179.0), m=st.floats(0.001, 1.0),
       b=st.floats(0.001, 1.0), xi=st.floats(0.0, 1.0), fovea=st.floats(0.0, 180.0),
       falloff=st.one_of(st.none(), st.floats(0.01, 180.0)), boost=st.one_of(st.none(), st.floats(0.0, 1.0)))
def test_plateau_shortcut_property(gx, gy, fov, m, b, xi, fovea, falloff, boost):
    """Any gaze, field of view, MAR line, floor, fovea and falloff: the shortcut never changes a value."""
    cfg = fw.Config().with_(foveation={"mar_slope": m, "mar_fovea_deg": b, "min_probability": xi,
                                       "fovea_deg": fovea, "falloff_deg": falloff})
    fast, slow, _ = _both_ways("cpu", 23, 17, fov, (gx, gy), cfg, min_probability=boost)
    assert np.array_equal(fast, slow)
    assert np.all(np.isfinite(fast))


# -- the per-pixel rank against an independent NumPy model of its definition -------------------------------------


def _pcg(v):
    v = np.asarray(v, dtype=np.uint64) & 0xFFFFFFFF
    b = (v * 747796405 + 2891336453) & 0xFFFFFFFF
    c = (((b >> ((b >> 28) + 4)) ^ b) * 277803737) & 0xFFFFFFFF
    return (c >> 22) ^ c


@wp.kernel(enable_backward=False)
def _rank_kernel(sp: SamplingParams, ranks: wp.array2d(dtype=wp.int32), rot: int, out: wp.array2d(dtype=wp.int32)):
    y, x = wp.tid()
    out[y, x] = dither_rank(x, y, ranks, sp, rot)


@pytest.mark.parametrize("k", [1, 2, 3, 4, 5, 6, 8, 16])
def test_dither_rank_matches_numpy_model(device, k):
    """rank = (blue-noise rank + tile offset + rot) mod K, tile offset = Warp's PCG draw (rand_init(seed, tile),
    then randi mod K), for power-of-two blocks (shift and mask path) and others (division path)."""
    from foveawarp.stages.sampling import sampling_params

    w, h, seed = 37, 29, 12345
    cfg = fw.Config().with_(foveation={"block": k})
    sp = sampling_params(cfg, w, h, seed=seed)
    assert (sp.block_shift >= 0) == ((k & (k - 1)) == 0)
    nr = dither_ranks(k)
    ranks = wp.array(nr.astype(np.int32), dtype=wp.int32, device=device)
    out = wp.zeros((h, w), dtype=wp.int32, device=device)
    kk = k * k
    ys, xs = np.mgrid[0:h, 0:w]
    tile = (ys // k) * ((w + k - 1) // k) + xs // k
    off = _pcg(_pcg(np.uint64(seed) + _pcg(tile))) % kk  # rand_init(seed, tile), then randi's draw, mod K
    for rot in sorted({0, kk // 2, kk - 1}):
        wp.launch(_rank_kernel, dim=(h, w), inputs=[sp, ranks, rot], outputs=[out], device=device)
        ref = (nr[ys % k, xs % k] + off.astype(np.int64) + rot) % kk
        assert np.array_equal(out.numpy(), ref)


# -- the CPU's one-launch frame pass (rows of tiles) against the per-pixel kernel + tile pass --------------------


@pytest.mark.parametrize("w,h,k", [(61, 45, 4), (64, 48, 4), (50, 31, 3), (23, 17, 5)])
@pytest.mark.parametrize("threads", [1, 3])
@pytest.mark.parametrize("flat", [False, True])
def test_cpu_rows_pass_equals_pixel_kernel_and_tile_pass(rng, w, h, k, threads, flat):
    """On the CPU ``SamplingStage.launch`` runs the map and the tile guarantee as one launch over rows of tiles
    (``sampling_rows_kernel``, each tile's rank shift computed once per row of it): the sample map, cache hits,
    previous-pixel indices and counters equal the per-pixel kernel (the CUDA path) followed by the tile pass,
    partial tiles included, at 1 and 3 threads. ``flat``: the right part of the G-buffer is one flat, still
    surface, so its pixels are thresholded below probability 1 (the ranks and jitter decide)."""
    from foveawarp import parallel
    from foveawarp.kernels.sampling import sampling_map_kernel
    from foveawarp.stages.sampling import launch_tile_pass

    dev = wp.get_device("cpu")
    g = _textured_gbuffer(w, h, "cpu", rng)
    x0 = w // 3
    if flat:
        for a, v in ((g.albedo, (0.4, 0.5, 0.6)), (g.normal, (0.0, 0.0, 1.0))):
            arr = a.numpy()
            arr[:, x0:] = v
            a.assign(arr)
        uv = g.reproj_uv.numpy()
        ys, xs = np.mgrid[0:h, x0:w]
        uv[:, x0:, 0], uv[:, x0:, 1] = xs + 0.5, ys + 0.5
        g.reproj_uv.assign(uv)
    # flat: a steep MAR, so that pixels this coarse fall below probability 1 away from the gaze
    fov = {"block": k, "mar_slope": 0.5, "fovea_deg": 2.0, "falloff_deg": 10.0} if flat else {"block": k}
    cfg = fw.Config().with_(foveation=fov)
    stage = SamplingStage(w, h, cfg, device="cpu")
    cam = fw.Camera(fov_y_deg=50.0)
    stage.run(g, cam, (w * 0.3, h * 0.6), 0, moving=False, first_frame=True)
    stage.end_frame(g)
    stage.set_frame(g, cam, (w * 0.6, h * 0.4), 1, moving=True, first_frame=False, eye_prev=cam.eye)
    with parallel.cpu_threads(threads):
        stage.launch(g)
    got = [a.numpy().copy() for a in (stage.sample_map, stage.cache_hit, stage.prev_index)]
    counts = (int(stage.num_samples.numpy()[0]), int(stage.num_cache_hits.numpy()[0]))
    # the same frame through the per-pixel kernel and the tile pass
    lab = wp.zeros((h, w), dtype=wp.vec3, device="cpu")
    from foveawarp.kernels.saliency import lab_kernel
    wp.launch(lab_kernel, dim=(h, w), inputs=[g.albedo], outputs=[lab, 0], device="cpu")
    sm = wp.zeros((h, w), dtype=wp.uint8, device="cpu")
    ch = wp.zeros((h, w), dtype=wp.uint8, device="cpu")
    pi = wp.zeros((h, w), dtype=wp.int32, device="cpu")
    ns = wp.zeros(1, dtype=wp.int32, device="cpu")
    nc = wp.zeros(1, dtype=wp.int32, device="cpu")
    dummy = wp.zeros((1, 1), dtype=float, device="cpu")
    wp.launch(sampling_map_kernel, dim=(h, w),
              inputs=[stage.params, stage.frame_params, stage.ranks, lab, g.normal, g.depth, g.hit, g.position,
                      g.reproj_uv, g.prev_dist, stage.depth_prev, stage.valid_prev, 0, g.face,
                      stage._no_face_lab, 0],
              outputs=[dummy, dummy, sm, ch, pi, stage.tile_counts, 0], device="cpu")
    with parallel.cpu_threads(1):
        launch_tile_pass(stage.ranks, stage.params, stage.frame_params, stage.tiles, sm, ch, ns, nc, dev)
    for a, b in zip(got, (sm.numpy(), ch.numpy(), pi.numpy())):
        assert np.array_equal(a, b)
    assert counts == (int(ns.numpy()[0]), int(nc.numpy()[0])) == (int(got[0].sum()), int(got[1].sum()))
    assert tile_counts(got[0], k).min() >= 1 and 0 < counts[1]
    if flat:  # the flat part is thresholded: some of its pixels sampled, most not
        part = got[0][1:-1, x0 + 1:-1]
        assert 0 < part.mean() < 0.6, part.mean()


# -- the stratified threshold against an independent NumPy model (the jitter skipped where it cannot decide) -------

from foveawarp.kernels.sampling import JITTER_SALT, dither_sample, dither_sample_shifted, tile_rank_shift  # noqa: E402


@wp.kernel(enable_backward=False)
def _dither_kernel(sp: SamplingParams, ranks: wp.array2d(dtype=wp.int32), rot: int, phase: float,
                   p: wp.array2d(dtype=float), out: wp.array2d(dtype=wp.uint8), out_shifted: wp.array2d(dtype=wp.uint8)):
    y, x = wp.tid()
    w = p.shape[1]
    h = p.shape[0]
    out[y, x] = dither_sample(p[y, x], x, y, w, h, ranks, sp, rot, phase)
    tx = x // sp.block
    ty = y // sp.block
    out_shifted[y, x] = dither_sample_shifted(p[y, x], x, y, w, h, ranks, sp, rot, phase,
                                              tile_rank_shift(tx, ty, sp, rot))


def _dither_model(p, k, w, h, seed, rot, phase):
    """sampled = (r + u) / K < p, or rank 0 of a full tile; u = Warp's randf of rand_init(seed ^ salt, y w + x)
    plus the phase, wrapped into [0, 1); float32 arithmetic as the kernel's."""
    from foveawarp.stages.sampling import dither_ranks

    kk = k * k
    ys, xs = np.mgrid[0:h, 0:w]
    tile = (ys // k) * ((w + k - 1) // k) + xs // k
    off = _pcg(_pcg(np.uint64(seed) + _pcg(tile))) % kk
    r = (dither_ranks(k)[ys % k, xs % k] + off.astype(np.int64) + rot) % kk
    state = _pcg((np.uint64(seed ^ JITTER_SALT) & 0xFFFFFFFF) + _pcg((ys * w + xs).astype(np.uint64)))
    u = (_pcg(state) >> 8).astype(np.float32) * np.float32(1.0 / 16777216.0)
    u = (u + np.float32(phase)).astype(np.float32)
    u = np.where(u >= 1.0, u - np.float32(1.0), u).astype(np.float32)
    t = ((r.astype(np.float32) + u) / np.float32(kk)).astype(np.float32)
    full = ((xs // k + 1) * k <= w) & ((ys // k + 1) * k <= h)
    return ((t < p) | ((r == 0) & full)).astype(np.uint8), r


@pytest.mark.parametrize("k", [2, 3, 4, 8])
@pytest.mark.parametrize("phase", [0.0, 0.618034, 0.99999994])
def test_dither_sample_matches_numpy_model(device, rng, k, phase):
    """The threshold decides as (r + u) / K < p with u the per-pixel jitter (NumPy model of Warp's PCG draws), for
    probabilities at and one ulp around r / K and (r + 1) / K (where skipping the jitter would go wrong first),
    0, 1 and random ones; with the tile shift given (the CPU's rows kernel) and computed (the pixel kernel)."""
    from foveawarp.stages.sampling import dither_ranks, sampling_params

    w, h, seed, rot = 45, 31, 777, 5 % (k * k)
    cfg = fw.Config().with_(foveation={"block": k})
    sp = sampling_params(cfg, w, h, seed=seed)
    kk = k * k
    _, r = _dither_model(np.zeros((h, w), np.float32), k, w, h, seed, rot, phase)
    edge = np.where(rng.random((h, w)) < 0.5, r, r + 1).astype(np.float32) / np.float32(kk)
    nudge = rng.integers(-1, 2, (h, w))
    p = np.where(nudge < 0, np.nextafter(edge, np.float32(0)), np.where(nudge > 0, np.nextafter(edge, np.float32(2)), edge))
    pick = rng.random((h, w))
    p = np.where(pick < 0.15, rng.random((h, w)), p)
    p = np.where((pick >= 0.15) & (pick < 0.2), 0.0, np.where((pick >= 0.2) & (pick < 0.25), 1.0, p)).astype(np.float32)
    want, _ = _dither_model(p, k, w, h, seed, rot, phase)
    out = wp.zeros((h, w), dtype=wp.uint8, device=device)
    out_s = wp.zeros((h, w), dtype=wp.uint8, device=device)
    ranks = wp.array(dither_ranks(k).astype(np.int32), dtype=wp.int32, device=device)
    wp.launch(_dither_kernel, dim=(h, w), inputs=[sp, ranks, rot, float(phase), wp.array(p, dtype=float, device=device)],
              outputs=[out, out_s], device=device)
    assert np.array_equal(out.numpy(), want)
    assert np.array_equal(out_s.numpy(), want)
    assert 0 < want.mean() < 1


# -- the plateaus of a whole row (row_plateau_spans, the CPU's rows kernel) ---------------------------------------

from foveawarp.kernels.sampling import row_plateau_spans  # noqa: E402


@wp.kernel(enable_backward=False)
def _row_spans_kernel(frame: wp.array(dtype=FrameParams), spans: wp.array2d(dtype=wp.int32),
                      row_p: wp.array2d(dtype=float)):
    y, x = wp.tid()
    fp = frame[0]
    w = row_p.shape[1]
    s = row_plateau_spans(y, w, row_p.shape[0], fp)
    if x < 4:
        spans[y, x] = s[x]
    p = float(-1.0)
    if x < s[0] or x > s[1]:
        p = fp.xi
    elif x >= s[2] and x <= s[3]:
        p = 1.0
    row_p[y, x] = p


def _row_spans(device, w, h, fov, gaze, cfg, min_probability=None):
    fast, slow, fp = _both_ways(device, w, h, fov, gaze, cfg, min_probability=min_probability)
    cam = fw.Camera(fov_y_deg=fov)
    stage = SamplingStage(w, h, cfg, device=device)
    stage.set_frame(_synthetic_gbuffer(w, h, device), cam, gaze, 0, moving=False, first_frame=True,
                    min_probability=min_probability)
    spans = wp.zeros((h, 4), dtype=wp.int32, device=device)
    row_p = wp.zeros((h, w), dtype=float, device=device)
    wp.launch(_row_spans_kernel, dim=(h, w), inputs=[stage.frame_params], outputs=[spans, row_p], device=device)
    return row_p.numpy(), slow, spans.numpy(), fp


def _plateau_angles(fp):
    """(lo, hi) in degrees: the pixels' own plateau tests' angles, from their float32 tangents (-1: off)."""
    lo = math.degrees(math.atan(math.sqrt(fp["tan2_fovea"]))) if fp["tan2_fovea"] >= 0.0 else None
    hi = math.degrees(math.atan(math.sqrt(fp["tan2_floor"]))) if fp["tan2_floor"] >= 0.0 else None
    return lo, hi


@pytest.mark.parametrize("fov", [20.0, 60.0, 110.0, 170.0])
@pytest.mark.parametrize("gaze", [(80.0, 45.0), (3.0, 88.0), (-40.0, 45.0), (80.0, -300.0), (400.0, 500.0)])
def test_row_plateau_spans_hold_the_pixels_values(device, fov, gaze):
    """The CPU rows kernel's per-row plateaus (``row_plateau_spans``): every pixel they classify has the value
    ``pixel_probability`` and eq. 2 give it (bit for bit), and lies beyond the plateau test's angle by the
    independent NumPy float64 eccentricity; they classify every pixel more than two and a half pixels' angle beyond it
    (the spans are in use, not empty), and no pixel of a row outside the spans."""
    w, h = 160, 90
    cfg = fw.Config().with_(foveation={"fovea_deg": 5.0, "falloff_deg": 12.0})
    row_p, slow, spans, fp = _row_spans(device, w, h, fov, gaze, cfg)
    cl = row_p >= 0.0
    assert np.array_equal(row_p[cl], slow[cl])
    e = ref_eccentricity(w, h, gaze, fov)
    lo, hi = _plateau_angles(fp)
    # two and a half pixels at the centre of the view (the widest pixel there), in degrees: the spans give up one
    m = 2.5 * math.degrees(math.atan(2.0 * math.tan(math.radians(fov) / 2.0) / h))
    floor = row_p == fp["xi"]
    fovea = row_p == 1.0
    if hi is None:
        assert not floor.any()
    else:
        assert np.all(e[floor] > hi)
        if (e > hi + m).any():
            assert floor[e > hi + m].all()
    if lo is None:
        assert not fovea.any()
    else:
        assert np.all(e[fovea] < lo)
        if (e < lo - m).any():
            assert fovea[e < lo - m].all()
    if fov == 60.0 and gaze == (80.0, 45.0):  # both spans are in use here
        assert (e > hi + m).mean() > 0.2 and (e < lo - m).any()


def test_row_plateau_spans_off_when_the_plateaus_are(device):
    """No fovea and, with a shallow MAR line, a floor beyond 89 degrees or none: the spans classify no pixel
    where the pixels' own tests have no plateau, and any they classify has the formula's value."""
    cfg = fw.Config().with_(foveation={"fovea_deg": 0.0, "falloff_deg": None, "mar_slope": 0.001})
    row_p, slow, spans, fp = _row_spans(device, 96, 64, 170.0, (48.0, 32.0), cfg)
    assert fp["row_cos2_fovea"] < 0.0
    if fp["row_cos2_floor"] < 0.0:
        assert np.all(row_p < 0.0)
    cl = row_p >= 0.0
    assert np.array_equal(row_p[cl], slow[cl])


@settings(max_examples=40, deadline=None)
@given(gx=st.floats(-1e6, 1e6), gy=st.floats(-1e6, 1e6), fov=st.floats(1.0, 179.0), m=st.floats(0.001, 1.0),
       b=st.floats(0.001, 1.0), xi=st.floats(0.0, 1.0), fovea=st.floats(0.0, 180.0),
       falloff=st.one_of(st.none(), st.floats(0.01, 180.0)), boost=st.one_of(st.none(), st.floats(0.0, 1.0)),
       w=st.integers(1, 40), h=st.integers(1, 40))
def test_row_plateau_spans_property(gx, gy, fov, m, b, xi, fovea, falloff, boost, w, h):
    """Any gaze (far off screen included), field of view, MAR line, floor, fovea, falloff and image size: a pixel
    the spans classify has the value of the formula."""
    cfg = fw.Config().with_(foveation={"mar_slope": m, "mar_fovea_deg": b, "min_probability": xi,
                                       "fovea_deg": fovea, "falloff_deg": falloff})
    row_p, slow, spans, fp = _row_spans("cpu", w, h, fov, (gx, gy), cfg, min_probability=boost)
    cl = row_p >= 0.0
    assert np.array_equal(row_p[cl], slow[cl])


from foveawarp.kernels.sampling import velocity_may_raise  # noqa: E402


@wp.kernel(enable_backward=False)
def _velocity_term_kernel(v: wp.array(dtype=wp.vec2), inv: wp.array(dtype=float), s: wp.array(dtype=float),
                          may: wp.array(dtype=wp.int32), raised: wp.array(dtype=float)):
    i = wp.tid()
    may[i] = velocity_may_raise(v[i], inv[i], s[i])
    raised[i] = wp.max(s[i], wp.min(wp.length(v[i]) * inv[i], 1.0))


def _velocity_term(device, v, inv, s):
    n = len(s)
    may = wp.zeros(n, dtype=wp.int32, device=device)
    raised = wp.zeros(n, dtype=float, device=device)
    wp.launch(_velocity_term_kernel, dim=n,
              inputs=[wp.array(np.asarray(v, np.float32), dtype=wp.vec2, device=device),
                      wp.array(np.asarray(inv, np.float32), dtype=float, device=device),
                      wp.array(np.asarray(s, np.float32), dtype=float, device=device)],
              outputs=[may, raised], device=device)
    return may.numpy(), raised.numpy()


def test_velocity_skip_only_where_the_term_cannot_win(device, rng):
    """``velocity_may_raise`` returns 0 only where max(s, min(|v| inv, 1)) is s (the term's square root is then
    skipped): around the boundary |v| inv = s within a few ulps, and for tiny, huge and non-finite inputs. Most
    terms well below s are skipped, and a term above s never is (NumPy float64 |v| inv against s)."""
    n = 20000
    s = rng.uniform(1e-3, 1.0, n).astype(np.float32)
    inv = np.float32(1.0 / 32.0) * np.ones(n, np.float32)
    ang = rng.uniform(0, 2 * np.pi, n)
    # |v| inv = s (1 + eps), eps from -1e-5 to 1e-5 and a wide spread
    eps = np.where(rng.random(n) < 0.5, rng.uniform(-1e-5, 1e-5, n), rng.uniform(-0.9, 2.0, n))
    r = s.astype(np.float64) * (1.0 + eps) / inv.astype(np.float64)
    v = np.stack([r * np.cos(ang), r * np.sin(ang)], -1).astype(np.float32)
    extra_v = [(0.0, 0.0), (1e-30, 0.0), (1e30, 1e30), (np.inf, 0.0), (np.nan, 1.0), (3.0, 4.0), (3.0, 4.0),
               (1e-20, 1e-20)]
    extra_s = [0.0, 1e-12, 0.5, 0.5, 0.5, 0.0, np.nan, 1e-9]
    # an inverse scale whose square is a denormal (a velocity scale of 1.7e22 px, allowed by the config): the
    # squared test loses its precision there, so it must not skip (|v| inv = 1.05 s below); and a |v|^2 that is a
    # denormal with a huge inverse scale
    extra_v += [(4.34e18, 0.0), (1.0e-20, 0.0), (1.3e-20, 0.0)]
    extra_s += [np.float32(2.0 ** -12), 1.1e-10, 1.2e-10]
    extra_inv = [1.0 / 32.0] * 8 + [5.9069734e-23, 1.0e10, 1.0e10]
    v = np.concatenate([v, np.asarray(extra_v, np.float32)])
    s = np.concatenate([s, np.asarray(extra_s, np.float32)])
    inv = np.concatenate([inv, np.asarray(extra_inv, np.float32)])
    may, raised = _velocity_term(device, v, inv, s)
    skipped = may == 0
    same = (raised == s) | (np.isnan(raised) & np.isnan(s))
    assert np.all(same[skipped])
    term = np.hypot(v[:, 0].astype(np.float64), v[:, 1].astype(np.float64)) * inv.astype(np.float64)
    assert np.all(may[term > s.astype(np.float64) * (1 + 1e-6)] == 1)
    low = term[:n] < s[:n].astype(np.float64) * 0.999
    assert skipped[:n][low].mean() == 1.0 and low.mean() > 0.1
