"""Saliency terms (thesis eq. 3) against skimage / SciPy / NumPy references, and the stage's combination."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import ndimage
from skimage.color import rgb2lab

import foveawarp as fw
from foveawarp import ops
from foveawarp.buffers import GBuffer
from foveawarp.kernels.saliency import LAB_STEP_FULL, NORMAL_STEP_FULL
from foveawarp.stages.sampling import SamplingStage

# ---------------------------------------------------------------------------------------------------------------
# references


def srgb_encode(c):
    """Linear -> sRGB-encoded (IEC 61966-2-1); skimage's rgb2lab decodes this again before XYZ."""
    c = np.asarray(c, dtype=np.float64)
    return np.where(c <= 0.0031308, 12.92 * c, 1.055 * np.power(np.maximum(c, 0.0), 1.0 / 2.4) - 0.055)


def sobel_max(img):
    """max over channels of hypot(d/dy, d/dx) with scipy's Sobel (mode 'reflect')."""
    mags = [np.hypot(ndimage.sobel(img[..., c], axis=0), ndimage.sobel(img[..., c], axis=1))
            for c in range(img.shape[-1])]
    return np.max(mags, axis=0)


def ref_eccentricity(w, h, gaze, fov):
    f = 0.5 * h / math.tan(math.radians(fov) / 2.0)
    ys, xs = np.mgrid[0:h, 0:w] + 0.5
    p = np.stack([xs - w / 2, ys - h / 2, np.full(xs.shape, f)], -1)
    g = np.array([gaze[0] - w / 2, gaze[1] - h / 2, f])
    return np.degrees(np.arctan2(np.linalg.norm(np.cross(p, g), axis=-1), p @ g))


def ref_p(w, h, gaze, fov, fc):
    f = 0.5 * h / math.tan(math.radians(fov) / 2.0)
    g = np.array([gaze[0] - w / 2, gaze[1] - h / 2, f])
    g1 = g + np.array([1.0, 0.0, 0.0])
    w_min = np.degrees(np.arctan2(np.linalg.norm(np.cross(g, g1)), g @ g1))
    corners = np.array([[-w / 2, -h / 2, f], [w / 2, -h / 2, f], [-w / 2, h / 2, f], [w / 2, h / 2, f]])
    e_max = np.degrees(np.arctan2(np.linalg.norm(np.cross(corners, g), axis=-1), corners @ g)).max()  # gaze on screen
    w_far = fc.mar_slope * e_max + fc.mar_fovea_deg
    e = ref_eccentricity(w, h, gaze, fov)
    return np.clip(1.0 - (fc.mar_slope * e + fc.mar_fovea_deg - w_min) / w_far, fc.effective_min_probability, 1.0)


def ref_saliency(gb, gaze, fov, cfg, *, moving, focus=None, vel=None):
    """clip(max(dA, dN, V, p) * F_DoF, xi, 1) from the G-buffer arrays (NumPy dict)."""
    sc, fc = cfg.saliency, cfg.foveation
    h, w = gb["depth"].shape
    p = ref_p(w, h, gaze, fov, fc)
    dA = np.clip(sc.albedo_scale * sobel_max(rgb2lab(srgb_encode(gb["albedo"]))) / (4.0 * LAB_STEP_FULL), 0, 1)
    dN = np.clip(sc.normal_scale * sobel_max(gb["normal"].astype(np.float64)) / (4.0 * NORMAL_STEP_FULL), 0, 1)
    hit = gb["hit"] != 0
    v = gb["velocity"] if vel is None else vel
    V = np.where(hit, np.clip(np.linalg.norm(v, axis=-1) / sc.velocity_scale_px, 0, 1), 0.0) if moving else 0.0
    F = np.maximum.reduce([p, dA * sc.use_albedo, dN * sc.use_normal, np.broadcast_to(V, p.shape)])
    if focus is not None:
        t = np.clip((np.abs(gb["depth"] - focus) - sc.sigma1_m) / sc.sigma2_m, 0.0, 1.0)
        F = F * np.where(hit, 1.0 - (1.0 - sc.dof_floor) * t, 1.0)
    return np.clip(F, fc.effective_min_probability, 1.0), p


# ---------------------------------------------------------------------------------------------------------------
# single terms


def test_lab_matches_skimage(device, rng):
    a = rng.random((24, 32, 3))
    a[0, :8] = 0.0
    a[1, :8] = 1.0
    a[2, :8] = rng.random((8, 3)) * 0.01  # below the Lab knee (Y < 0.008856)
    got = ops.albedo_to_lab(a, device=device)
    ref = rgb2lab(srgb_encode(a))
    assert got.shape == (24, 32, 3)
    assert np.abs(got - ref).max() < 2e-3  # Lab units (L in [0, 100])


def test_albedo_gradient_matches_scipy_sobel(device, rng):
    a = ndimage.gaussian_filter(rng.random((30, 41, 3)), (2, 2, 0))
    a[10:20, 5:15] = (0.63, 0.065, 0.05)  # a hard red patch
    got = ops.albedo_gradient(a, device=device)
    ref = sobel_max(rgb2lab(srgb_encode(a)))
    assert np.allclose(got, ref, rtol=1e-4, atol=5e-3), np.abs(got - ref).max()
    assert ref.max() > 100.0  # the patch edge is a real edge


def test_normal_gradient_matches_scipy_sobel(device, rng):
    n = rng.normal(size=(27, 33, 3))
    n[3:9, 3:9] = 0.0  # zero normals (G-buffer misses)
    got = ops.normal_gradient(n, device=device)
    assert np.allclose(got, sobel_max(n), rtol=1e-5, atol=1e-5)


def test_dof_factor_matches_reference(device):
    d = np.linspace(0.0, 12.0, 241).reshape(1, -1).repeat(2, axis=0)
    for s1, s2, fl in ((0.5, 2.0, 0.0), (0.0, 0.1, 0.3), (1.0, 5.0, 1.0)):
        got = ops.dof_sampling_factor(d, focus_depth_m=4.0, sigma1_m=s1, sigma2_m=s2, dof_floor=fl, device=device)
        dist = np.abs(d - 4.0)
        ref = np.where(dist <= s1, 1.0, np.where(dist >= s1 + s2, fl, 1.0 - (1.0 - fl) * (dist - s1) / s2))
        assert np.abs(got - ref).max() < 1e-5
    with pytest.raises(ValueError, match="sigma2_m"):
        ops.dof_sampling_factor(d, focus_depth_m=4.0, sigma1_m=0.5, sigma2_m=0.0, dof_floor=0.0)


# ---------------------------------------------------------------------------------------------------------------
# the fused stage pass


def _scene_like_gbuffer(w, h, rng):
    ys, xs = np.mgrid[0:h, 0:w]
    albedo = ndimage.gaussian_filter(rng.random((h, w, 3)), (3, 3, 0)).astype(np.float32)
    albedo[h // 4: h // 2, w // 5: w // 2] = (0.14, 0.45, 0.091)
    n = np.stack([np.sin(xs / 7.0), np.cos(ys / 5.0), np.ones_like(xs, dtype=np.float64)], -1)
    n[:, w // 2:] = (1.0, 0.0, 0.2)  # a crease
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    depth = (1.0 + 7.0 * xs / w + 0.5 * ys / h).astype(np.float32)
    vel = np.stack([np.sin(ys / 6.0) * 6.0, np.cos(xs / 8.0) * 3.0], -1).astype(np.float32)
    hit = np.ones((h, w), np.uint8)
    hit[: h // 5, -w // 4:] = 0  # background corner
    miss = hit == 0
    albedo[miss], n[miss], depth[miss], vel[miss] = 0.0, 0.0, 100.0, 0.0
    uv = _centres(h, w) - vel  # the G-buffer keeps the reprojection; its velocity is the centre minus that
    uv[miss] = -1e4
    return {"albedo": albedo, "normal": n.astype(np.float32), "depth": depth, "velocity": _velocity_of(uv),
            "hit": hit, "position": np.zeros((h, w, 3), np.float32), "reproj_uv": uv}


def _centres(h, w):
    ys, xs = np.mgrid[0:h, 0:w]
    return np.stack([xs + 0.5, ys + 0.5], -1).astype(np.float32)


def _velocity_of(uv):
    """GBuffer.velocity from reproj_uv (float32, as kernels.gbuffer.reproj_velocity): the pixel centre minus the
    previous position, 0 where there is none (-1e4)."""
    uv = np.asarray(uv, np.float32)
    none = (uv[..., 0] == np.float32(-1e4)) & (uv[..., 1] == np.float32(-1e4))
    return np.where(none[..., None], np.float32(0.0), _centres(*uv.shape[:2]) - uv).astype(np.float32)


def _gbuffer(arrs, device):
    """A GBuffer holding ``arrs`` (its velocity, not stored, must be the one its ``reproj_uv`` gives)."""
    h, w = arrs["depth"].shape
    g = GBuffer(w, h, device)
    for k, v in arrs.items():
        if k != "velocity":
            getattr(g, k).assign(v)
    if "velocity" in arrs:
        np.testing.assert_array_equal(arrs["velocity"], _velocity_of(arrs["reproj_uv"]))
        np.testing.assert_array_equal(g.velocity.numpy(), arrs["velocity"])  # the derivation, bit for bit
    return g


CFG = fw.Config().with_(foveation={"mar_slope": 0.3, "min_probability": 0.05, "block": 4, "falloff_deg": None, "fovea_deg": 0.0},
                        saliency={"albedo_scale": 2.0, "normal_scale": 1.0, "velocity_scale_px": 8.0,
                                  "sigma1_m": 0.5, "sigma2_m": 2.0, "dof_floor": 0.1},
                        dof={"aperture_m": 0.01})


def test_stage_saliency_matches_reference(device, rng):
    w, h, fov = 64, 48, 90.0
    arrs = _scene_like_gbuffer(w, h, rng)
    g = _gbuffer(arrs, device)
    cam = fw.Camera(fov_y_deg=fov)
    stage = SamplingStage(w, h, CFG, device=device)
    gaze = (20.3, 30.7)
    focus = float(arrs["depth"][30, 20])
    stage.run(g, cam, gaze, 0, moving=True, first_frame=True)
    assert "saliency.dof" not in stage.skipped and "saliency.velocity" not in stage.skipped
    ref, p = ref_saliency(arrs, gaze, fov, CFG, moving=True, focus=focus)
    got = stage.saliency.numpy()
    assert np.abs(stage.probability.numpy() - p).max() < 2e-5
    assert np.abs(got - ref).max() < 2e-4, np.abs(got - ref).max()
    # every term mattered somewhere (the test would notice a term missing)
    for kw in ({"moving": False, "focus": focus}, {"moving": True, "focus": None}):
        other, _ = ref_saliency(arrs, gaze, fov, CFG, **kw)
        assert np.abs(other - ref).max() > 0.05
    no_albedo = CFG.with_(saliency={"use_albedo": False})
    assert np.abs(ref_saliency(arrs, gaze, fov, no_albedo, moving=True, focus=focus)[0] - ref).max() > 0.05
    # the skip switches: no motion, pinhole camera
    stage.run(g, cam, gaze, 1, moving=False, first_frame=True)
    assert "saliency.velocity" in stage.skipped
    ref2, _ = ref_saliency(arrs, gaze, fov, CFG, moving=False, focus=focus)
    assert np.abs(stage.saliency.numpy() - ref2).max() < 2e-4
    pin = SamplingStage(w, h, CFG.with_(dof={"aperture_m": 0.0}), device=device)
    pin.run(g, cam, gaze, 0, moving=True, first_frame=True)
    assert pin.skipped["saliency.dof"].startswith("pinhole")
    ref3, _ = ref_saliency(arrs, gaze, fov, CFG, moving=True, focus=None)
    assert np.abs(pin.saliency.numpy() - ref3).max() < 2e-4


def test_stage_focus_sources(device, rng):
    w, h, fov = 64, 48, 90.0
    arrs = _scene_like_gbuffer(w, h, rng)
    g = _gbuffer(arrs, device)
    cam = fw.Camera(fov_y_deg=fov)
    # gaze on a background pixel: no surface to focus on, the DoF factor is 1 this frame
    stage = SamplingStage(w, h, CFG, device=device)
    gaze = (w - 3.5, 2.5)
    stage.run(g, cam, gaze, 0, moving=False, first_frame=True)
    ref, _ = ref_saliency(arrs, gaze, fov, CFG, moving=False, focus=None)
    assert np.abs(stage.saliency.numpy() - ref).max() < 2e-4
    # a configured focus distance wins over the gaze depth
    fixed = CFG.with_(dof={"focus_depth_m": 4.0})
    stage = SamplingStage(w, h, fixed, device=device)
    stage.run(g, cam, gaze, 0, moving=False, first_frame=True)
    ref, _ = ref_saliency(arrs, gaze, fov, fixed, moving=False, focus=4.0)
    assert np.abs(stage.saliency.numpy() - ref).max() < 2e-4


def test_object_velocity_removes_camera_motion(device, rng):
    w, h, fov = 48, 36, 60.0
    arrs = _scene_like_gbuffer(w, h, rng)
    cam = fw.Camera(eye=(0.0, 1.0, 3.5), target=(0.0, 1.0, 0.0), fov_y_deg=fov)
    cam_prev = fw.Camera(eye=(0.3, 1.1, 3.6), target=(0.1, 1.0, 0.0), fov_y_deg=fov)
    # surface points on the plane z = 0 seen through each pixel, and their previous pixels (random object motion)
    dirs = cam.ray_dirs(*(np.mgrid[0:h, 0:w][::-1] + 0.5), w, h)
    t = (0.0 - cam.eye[2]) / dirs[..., 2]
    pos = np.asarray(cam.eye) + dirs * t[..., None]
    prev_px = cam_prev.project(pos, w, h)[..., :2]
    moved = rng.normal(scale=4.0, size=(h, w, 2)) * (rng.random((h, w, 1)) < 0.3)
    arrs["position"] = pos.astype(np.float32)
    arrs["reproj_uv"] = (prev_px - moved).astype(np.float32)
    arrs["reproj_uv"][0, :5] = -1e4  # no previous position: no velocity
    hit = arrs["hit"] != 0
    arrs["reproj_uv"][~hit] = -1e4
    arrs["velocity"] = _velocity_of(arrs["reproj_uv"])
    g = _gbuffer(arrs, device)
    stage = SamplingStage(w, h, CFG.with_(dof={"aperture_m": 0.0}), device=device)
    stage.run(g, cam, (24.0, 18.0), 0, moving=True, first_frame=True, camera_prev=cam_prev)
    vel = np.where((arrs["reproj_uv"][..., :1] > -5e3), moved, 0.0)
    ref, _ = ref_saliency(arrs, (24.0, 18.0), fov, CFG, moving=True, focus=None, vel=vel)
    assert np.abs(stage.saliency.numpy() - ref).max() < 2e-3
    # without camera_prev the G-buffer velocity is used instead
    stage.run(g, cam, (24.0, 18.0), 0, moving=True, first_frame=True)
    ref_g, _ = ref_saliency(arrs, (24.0, 18.0), fov, CFG, moving=True, focus=None)
    assert np.abs(stage.saliency.numpy() - ref_g).max() < 2e-4
    assert np.abs(ref_g - ref).max() > 0.05


@settings(max_examples=25, deadline=None)
@given(data=st.data(), depth=st.sampled_from([0.0, 1e-30, 1.0, 1e30]), vscale=st.sampled_from([0.0, 1.0, 1e20, 1e37]),
       gx=st.floats(-1e12, 1e12), gy=st.floats(-1e12, 1e12), zero_normals=st.booleans(), block=st.integers(1, 6))
def test_stage_outputs_finite_and_in_range(data, depth, vscale, gx, gy, zero_normals, block):
    w, h = 13, 9
    seed = data.draw(st.integers(0, 2**31 - 1))
    r = np.random.default_rng(seed % 1000)
    arrs = {
        "albedo": r.random((h, w, 3)).astype(np.float32) * data.draw(st.sampled_from([0.0, 1.0, 1e3])),
        "normal": np.zeros((h, w, 3), np.float32) if zero_normals else r.normal(size=(h, w, 3)).astype(np.float32),
        "depth": np.full((h, w), depth, np.float32),
        "hit": (r.random((h, w)) < 0.7).astype(np.uint8),
        "position": (r.normal(size=(h, w, 3)) * data.draw(st.sampled_from([0.0, 1e30]))).astype(np.float32),
        # previous positions up to vscale pixels away (the velocities, up to 1e37 pixels)
        "reproj_uv": (_centres(h, w) - r.normal(size=(h, w, 2)) * vscale).astype(np.float32),
    }
    g = _gbuffer(arrs, "cpu")
    cfg = CFG.with_(foveation={"block": block}, dof={"aperture_m": data.draw(st.sampled_from([0.0, 0.01]))})
    stage = SamplingStage(w, h, cfg, device="cpu", seed=seed)
    stage.end_frame(g, g.hit)
    stage.run(g, fw.Camera(), (gx, gy), data.draw(st.integers(0, 10**6)), moving=True, first_frame=False,
              eye_prev=(0.0, 0.0, 0.0), camera_prev=fw.Camera(eye=(1.0, 1.0, 3.0)))
    xi = cfg.foveation.effective_min_probability
    for name in ("probability", "saliency"):
        a = getattr(stage, name).numpy()
        assert np.isfinite(a).all(), name
        assert a.min() >= np.float32(xi) - 1e-6 and a.max() <= 1.0, name
    s = stage.sample_map.numpy()
    assert set(np.unique(s)) <= {0, 1}
    ty, tx = -(-h // block), -(-w // block)
    pad = np.zeros((ty * block, tx * block), int)
    pad[:h, :w] = s
    assert pad.reshape(ty, block, tx, block).sum(axis=(1, 3)).min() >= 1
