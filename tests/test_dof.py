"""Depth of field by pixel-intensity scatter (ALGORITHMS.md B) and the thin-lens reference.

References written here, independently of the kernels: the CoC formula and a brute-force float64 scatter in
NumPy (one disc per source pixel, the weights of Lee et al. sec. 3-4 evaluated from their definitions).
"""

import math

import numpy as np
import pytest
import warp as wp
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import foveawarp as fw
from foveawarp import parallel
from foveawarp.config import DofConfig
from foveawarp.kernels.dof import FOCUS_FAR_M, DofParams, coc_kernel, dof_normalize_kernel
from foveawarp.ops.dof import circle_of_confusion_px, dof_scatter
from foveawarp.stages.dof import DofStage

LENS = dict(focal_length_m=0.05, focus_depth_m=3.0, aperture_m=0.02, px_per_m=20000.0)


# ---------------------------------------------------------------------------------------------------------
# independent NumPy references


def np_coc(depth, *, focal_length_m, focus_depth_m, aperture_m, px_per_m, max_coc_px=None):
    """(E F / (Z_f - F)) |Z - Z_f| / Z * px_per_m in float64; +inf -> far limit, Z <= 0 or NaN -> clamp."""
    z = np.asarray(depth, dtype=np.float64)
    e, f, zf = aperture_m, focal_length_m, focus_depth_m
    with np.errstate(divide="ignore", invalid="ignore"):
        c = (e * f / (zf - f)) * np.abs(z - zf) / z * px_per_m
    c = np.where(np.isposinf(z), e * f / (zf - f) * px_per_m, c)
    cmax = np.inf if max_coc_px is None else max_coc_px
    c = np.where((z > 0) & ~np.isnan(z), np.minimum(c, cmax), cmax)
    return c


def np_scatter(color, depth, *, focal_length_m, focus_depth_m, aperture_m, px_per_m, gamma=2.0, eps_px=1.0,
               max_coc_px=16.0, foreground_fix=True, background_fix=True, hit=None):
    """Brute-force pixel scatter: every source adds A = K / (pi R^2) times its color to the receivers
    within R = max(C / 2, 0.5) pixels; output = sum(A I) / sum(A) (source color where the sum is 0)."""
    col = np.asarray(color, dtype=np.float64)
    z = np.asarray(depth, dtype=np.float64).copy()
    h, w = z.shape
    if hit is not None:
        z[np.asarray(hit) == 0] = np.inf
    z = np.where(np.isnan(z) | (z < 0), 0.0, z)
    zf = focus_depth_m
    c = np_coc(z, focal_length_m=focal_length_m, focus_depth_m=zf, aperture_m=aperture_m, px_per_m=px_per_m,
               max_coc_px=max_coc_px)
    r = np.maximum(c / 2.0, 0.5)
    k = np.ones_like(z)
    fg = z < zf
    if foreground_fix:
        with np.errstate(divide="ignore", over="ignore"):
            k = np.where(fg, np.minimum((zf / np.maximum(z, 1e-300)) ** gamma, 1e8), 1.0)
    a = k / (np.pi * r * r)
    acc_i = np.zeros((h, w, 3))
    acc_a = np.zeros((h, w))
    yy, xx = np.mgrid[0:h, 0:w]
    for y in range(h):
        for x in range(w):
            cover = (yy - y) ** 2 + (xx - x) ** 2 <= r[y, x] ** 2
            wgt = np.where(cover, a[y, x], 0.0)
            if background_fix and not fg[y, x]:
                # W_q = 1 - lerp(clamp((C_p - C_q) / eps), 0, clamp(C_q / eps - 1))
                t = np.clip(c / eps_px - 1.0, 0.0, 1.0)
                lo = np.clip((c[y, x] - c) / eps_px, 0.0, 1.0)
                wgt = wgt * (1.0 - (lo * (1.0 - t) + 0.0 * t))
            acc_i += wgt[..., None] * col[y, x]
            acc_a += wgt
    out = col.copy()
    ok = acc_a > 0
    out[ok] = acc_i[ok] / acc_a[ok, None]
    return out


def coc_unchecked(depth, *, focal_length_m, focus_depth_m, aperture_m, px_per_m, max_coc_px=None, device):
    """The CoC kernel launched directly, without the ops layer's host checks (which reject NaN / Inf): how
    per-frame device buffers reach it. 1-D depths."""
    p = DofParams()
    p.coc_scale = float(aperture_m * focal_length_m * px_per_m)
    p.focal_m = float(focal_length_m)
    p.max_coc_px = 3.0e38 if max_coc_px is None else float(max_coc_px)
    p.tan_half_fov_y = 0.0
    p.aspect = 1.0
    d = wp.array(np.asarray(depth, np.float32).reshape(1, -1), dtype=float, device=device)
    p.width, p.height = int(d.shape[1]), 1
    out = wp.zeros(d.shape, dtype=float, device=device)
    focus = wp.full(1, value=float(focus_depth_m), dtype=float, device=device)
    parallel.launch(coc_kernel, dim=d.shape, inputs=[p, focus, d], outputs=[out], device=device)
    return out.numpy().reshape(-1)


def stage_dof(color, depth, *, focal_length_m, focus_depth_m, aperture_m, px_per_m, gamma=2.0, eps_px=1.0,
              max_coc_px=16.0, foreground_fix=True, background_fix=True, method="gather", tile_px=8,
              device="cpu"):
    """DofStage.run on device arrays (no host scan of their contents, unlike ops.dof_scatter, which rejects
    NaN / Inf): the path the frame loop takes."""
    h, w = depth.shape
    cfg = DofConfig(aperture_m=aperture_m, focal_length_m=focal_length_m, px_per_m=px_per_m, gamma=gamma,
                    eps_px=eps_px, max_coc_px=max_coc_px, foreground_fix=foreground_fix,
                    background_fix=background_fix)
    st_ = DofStage(w, h, cfg, device, method=method, tile_px=tile_px)
    out = wp.zeros((h, w), dtype=wp.vec3, device=device)
    st_.run(wp.array(np.asarray(color, np.float32), dtype=wp.vec3, device=device),
            wp.array(np.asarray(depth, np.float32), dtype=float, device=device), None, focus_depth_m, out)
    return out.numpy().reshape(h, w, 3)


def random_scene(rng, h, w, zf=3.0):
    color = rng.random((h, w, 3)).astype(np.float32)
    kind = rng.integers(0, 3, size=(h, w))
    depth = np.where(kind == 0, rng.uniform(0.6, zf, (h, w)),
                     np.where(kind == 1, rng.uniform(zf, 40.0, (h, w)), zf)).astype(np.float32)
    return color, depth


# ---------------------------------------------------------------------------------------------------------
# circle of confusion


def test_coc_matches_numpy_formula(device, rng):
    depth = np.concatenate([rng.uniform(0.06, 50.0, 500), [0.5, 3.0, 1e3, 1e6, 1e30]]).astype(np.float32)
    got = circle_of_confusion_px(depth, **LENS, device=device)
    ref = np_coc(depth, **LENS)
    assert got.shape == depth.shape and got.dtype == np.float32
    np.testing.assert_allclose(got, ref, rtol=2e-5, atol=1e-5)
    assert got[np.argmin(np.abs(depth - 3.0))] == pytest.approx(0.0, abs=1e-5)
    clamped = circle_of_confusion_px(depth.reshape(5, -1), **LENS, max_coc_px=8.0, device=device)
    np.testing.assert_allclose(clamped.reshape(-1), np.minimum(ref, 8.0), rtol=2e-5, atol=1e-5)


def test_coc_guards_no_nan_or_inf(device):
    """The kernel's guards (ops rejects NaN / Inf on the host; device buffers are not scanned)."""
    depth = np.array([0.0, -1.0, -np.inf, np.nan, 1e-38, 1e-30, 1e30, 3e38, np.inf], dtype=np.float32)
    c = coc_unchecked(depth, **LENS, device=device)
    assert np.all(np.isfinite(c))
    far = LENS["aperture_m"] * LENS["focal_length_m"] / (LENS["focus_depth_m"] - LENS["focal_length_m"]) * 2e4
    assert c[-1] == pytest.approx(far, rel=1e-5)
    assert circle_of_confusion_px(depth[-3:-1], **LENS, device=device)[0] == pytest.approx(far, rel=1e-5)
    for bad in (np.nan, np.inf, -np.inf):
        with pytest.raises(ValueError, match="depth_m"):
            circle_of_confusion_px(np.array([1.0, bad]), **LENS, device=device)
    cc = coc_unchecked(depth, **LENS, max_coc_px=16.0, device=device)
    np.testing.assert_array_equal(cc[:6], 16.0)  # at or behind the lens, NaN, and near-zero depth: the clamp
    assert cc[-1] == pytest.approx(far, rel=1e-5)


@pytest.mark.parametrize("focus", [0.05, 0.04, -1.0, float("nan")])
def test_focus_not_beyond_focal_length_is_value_error(focus):
    with pytest.raises(ValueError, match="focus_depth_m"):
        circle_of_confusion_px(np.ones((2, 2)), focal_length_m=0.05, focus_depth_m=focus, aperture_m=0.01,
                               px_per_m=1e4, device="cpu")
    with pytest.raises(ValueError, match="focus_depth_m"):
        dof_scatter(np.zeros((2, 2, 3)), np.ones((2, 2)), focal_length_m=0.05, focus_depth_m=focus,
                    aperture_m=0.01, px_per_m=1e4, device="cpu")


def test_invalid_arguments_name_the_parameter():
    c, d = np.zeros((4, 4, 3)), np.ones((4, 4))
    with pytest.raises(ValueError, match="aperture_m"):
        dof_scatter(c, d, **{**LENS, "aperture_m": -0.1}, device="cpu")
    with pytest.raises(ValueError, match="eps_px"):
        dof_scatter(c, d, **LENS, eps_px=0.0, device="cpu")
    with pytest.raises(ValueError, match="method"):
        dof_scatter(c, d, **LENS, method="splat", device="cpu")
    with pytest.raises(ValueError, match="depth_m"):
        dof_scatter(c, np.ones((4, 5)), **LENS, device="cpu")
    with pytest.raises(ValueError, match="color"):
        dof_scatter(np.zeros((4, 4)), d, **LENS, device="cpu")
    st_ = DofStage(4, 4, DofConfig(aperture_m=0.01), "cpu")
    with pytest.raises(ValueError, match="focus_depth_m"):
        st_.set_focus(0.01)


def test_thin_lens_reference_refuses_a_textured_scene():
    """The thin-lens reference shades per-face colours: a scene with materials is refused by name, not rendered
    with its textures silently dropped."""
    from foveawarp.dof_reference import render_thin_lens

    room = fw.load_scene("room")
    with pytest.raises(ValueError, match="render_thin_lens shades with per-face colours.*'room' has materials"):
        render_thin_lens(room, room.camera, 16, 9, device="cpu")


# ---------------------------------------------------------------------------------------------------------
# scatter: against the brute-force reference, gather == scatter


@pytest.mark.parametrize("fg,bg", [(False, False), (True, False), (False, True), (True, True)])
def test_scatter_matches_numpy_brute_force(device, rng, fg, bg):
    h, w = 20, 26
    color, depth = random_scene(rng, h, w)
    hit = (rng.random((h, w)) > 0.1).astype(np.uint8)
    kw = dict(**LENS, gamma=1.5, eps_px=1.5, max_coc_px=9.0, foreground_fix=fg, background_fix=bg)
    ref = np_scatter(color, depth, hit=hit, **kw)
    for method in ("gather", "scatter"):
        got = dof_scatter(color, depth, hit=hit, method=method, device=device, **kw)
        np.testing.assert_allclose(got, ref, atol=1e-4, err_msg=method)
    # the blur does something: the reference differs from the input by far more than the tolerance
    assert np.abs(ref - color).max() > 0.1


@pytest.mark.parametrize("max_coc,tile", [(6.0, 8), (16.0, 8), (40.0, 4), (23.0, 16)])
def test_gather_equals_scatter_random(device, rng, max_coc, tile):
    h, w = 37, 51  # not multiples of the tile
    color, depth = random_scene(rng, h, w)
    kw = dict(focal_length_m=0.05, focus_depth_m=3.0, aperture_m=0.05, px_per_m=2e4, max_coc_px=max_coc)
    a = dof_scatter(color, depth, method="gather", tile_px=tile, device=device, **kw)
    b = dof_scatter(color, depth, method="scatter", device=device, **kw)
    assert np.abs(a - b).max() < 1e-4
    c = circle_of_confusion_px(depth, **kw, device=device)
    assert c.max() == pytest.approx(max_coc)  # the largest discs are present


_special = st.sampled_from([0.0, -2.0, 1e-30, 1e30, np.inf, np.nan, 3.0])


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    h=st.integers(1, 9), w=st.integers(1, 11), seed=st.integers(0, 2**31 - 1),
    gamma=st.floats(0.0, 16.0), eps=st.floats(0.05, 8.0), max_coc=st.floats(1.0, 30.0),
    aperture=st.sampled_from([0.0, 1e-4, 0.02, 0.5]), fg=st.booleans(), bg=st.booleans(),
    tile=st.integers(1, 9), n_special=st.integers(0, 6), special=_special,
)
def test_property_gather_scatter_finite_convex(h, w, seed, gamma, eps, max_coc, aperture, fg, bg, tile,
                                               n_special, special):
    rng = np.random.default_rng(seed)
    color, depth = random_scene(rng, h, w)
    idx = rng.integers(0, h * w, size=n_special)
    depth.reshape(-1)[idx] = special
    kw = dict(focal_length_m=0.05, focus_depth_m=3.0, aperture_m=aperture, px_per_m=2e4, gamma=gamma,
              eps_px=eps, max_coc_px=max_coc, foreground_fix=fg, background_fix=bg)
    a = stage_dof(color, depth, method="gather", tile_px=tile, device="cpu", **kw)
    b = stage_dof(color, depth, method="scatter", device="cpu", **kw)
    assert np.all(np.isfinite(a)) and np.all(np.isfinite(b))
    assert np.abs(a - b).max() < 1e-4
    # a normalized sum of non-negative weights: each channel stays within the input's range
    lo, hi = color.reshape(-1, 3).min(0), color.reshape(-1, 3).max(0)
    assert np.all(a >= lo - 1e-5) and np.all(a <= hi + 1e-5)


def test_in_focus_image_is_unchanged(device, rng):
    color = rng.random((24, 30, 3)).astype(np.float32)
    depth = np.full((24, 30), LENS["focus_depth_m"], np.float32)
    out = dof_scatter(color, depth, **LENS, device=device)
    np.testing.assert_allclose(out, color, atol=1e-6)
    # a pinhole (aperture 0) leaves any depth image unchanged
    _, d2 = random_scene(rng, 24, 30)
    out = dof_scatter(color, d2, **{**LENS, "aperture_m": 0.0}, device=device)
    np.testing.assert_allclose(out, color, atol=1e-6)
    # and a wide aperture does change it (the test above can fail)
    out = dof_scatter(color, d2, **{**LENS, "aperture_m": 0.05}, device=device)
    assert np.abs(out - color).max() > 0.1


# ---------------------------------------------------------------------------------------------------------
# step edges: foreground discontinuity and background leakage (Lee et al. sec. 4)

EDGE = dict(focal_length_m=0.05, focus_depth_m=3.0, aperture_m=0.0177, px_per_m=2e4, max_coc_px=16.0)
EDGE_X = 48  # columns [0, 48) hold the left object


def _edge_profile(device, left_depth, right_depth, left_color, right_color, **kw):
    h, w = 24, 96
    color = np.zeros((h, w, 3), np.float32)
    depth = np.empty((h, w), np.float32)
    color[:, :EDGE_X], color[:, EDGE_X:] = left_color, right_color
    depth[:, :EDGE_X], depth[:, EDGE_X:] = left_depth, right_depth
    out = dof_scatter(color, depth, **EDGE, **kw, device=device)
    # rows at least R = 8 px from the top and bottom borders see every source: they are all alike
    assert np.allclose(out[8:16], out[12:13], atol=1e-6)
    return out[12, :, 0].astype(np.float64)


def test_foreground_edge_is_continuous_with_the_fix(device):
    """A bright foreground (Z = 1 m, C = 12 px) in front of a dark in-focus plane (Z = Z_f = 3 m).

    Criteria: the profile across the edge falls monotonically from the foreground color to the in-focus
    color; the blur spreads about R = 6 px onto the in-focus side; the largest step between neighbouring
    pixels (the discontinuity at the silhouette) is below 0.35 with the foreground fix and above 0.6 without.
    """
    c = circle_of_confusion_px(np.array([1.0]), **{k: v for k, v in EDGE.items() if k != "max_coc_px"})
    assert c[0] == pytest.approx(12.0, rel=1e-3)
    steps = {}
    for fix in (False, True):
        prof = _edge_profile(device, 1.0, 3.0, 1.0, 0.0, foreground_fix=fix, background_fix=True)
        assert np.all(np.diff(prof) <= 1e-6), "profile must be monotone"
        assert prof[0] == pytest.approx(1.0) and prof[-1] == pytest.approx(0.0, abs=1e-6)
        assert prof[EDGE_X + 4] > 0.005  # blurred onto the in-focus side ...
        assert np.all(prof[EDGE_X + 7:] < 1e-6)  # ... but no farther than R = 6 px
        steps[fix] = np.abs(np.diff(prof)).max()
    assert steps[True] < 0.35 < 0.6 < steps[False]


def test_background_does_not_leak_into_in_focus_foreground(device):
    """A dark in-focus object (Z = Z_f) next to a bright far background (Z = 30 m, C = 5.4 px).

    Criteria: with the background fix every in-focus pixel receives < 1% of the background's intensity;
    without it the pixels next to the edge receive > 5%. The background side stays background.
    """
    leak = {}
    for fix in (False, True):
        prof = _edge_profile(device, 3.0, 30.0, 0.0, 1.0, foreground_fix=True, background_fix=fix)
        leak[fix] = prof[:EDGE_X].max()
        assert np.all(prof[EDGE_X:] > 0.99)
    assert leak[True] < 0.01
    assert leak[False] > 0.05


# ---------------------------------------------------------------------------------------------------------
# guards


def test_no_nan_with_degenerate_depths_and_colors(device, rng):
    h, w = 12, 14
    color, depth = random_scene(rng, h, w)
    depth[0, :] = 0.0
    depth[1, :] = -3.0
    depth[2, :] = np.nan
    depth[3, :] = np.inf
    depth[4, :] = 1e30
    depth[5, :] = 1e-30
    color[6, 0] = np.nan
    color[6, 1] = np.inf
    for fg in (False, True):
        for method in ("gather", "scatter"):
            out = stage_dof(color, depth, **{**LENS, "aperture_m": 0.05}, gamma=16.0, foreground_fix=fg,
                            method=method, device=device)
            assert np.all(np.isfinite(out))
    with pytest.raises(ValueError, match="depth_m"):
        dof_scatter(np.zeros((h, w, 3)), depth, **LENS, device=device)
    with pytest.raises(ValueError, match="color"):
        dof_scatter(color, np.ones((h, w)), **LENS, device=device)


def test_zero_weight_keeps_the_source_color(device):
    acc = np.zeros((2, 3, 4), np.float32)
    acc[0, 1] = (2.0, 4.0, 6.0, 2.0)
    acc[1, 2] = (np.inf, 0.0, 0.0, 1.0)  # non-finite ratio -> source color
    src = np.arange(18, dtype=np.float32).reshape(2, 3, 3)
    src[1, 0] = np.nan  # zero weight and a non-finite source -> 0
    out = wp.zeros((2, 3), dtype=wp.vec3, device=device)
    parallel.launch(dof_normalize_kernel, dim=(2, 3), inputs=[wp.array(acc, dtype=wp.vec4, device=device),
                    wp.array(src, dtype=wp.vec3, device=device)], outputs=[out], device=device)
    o = out.numpy()
    expect = src.copy()
    expect[0, 1] = (1.0, 2.0, 3.0)
    expect[1, 0] = 0.0
    np.testing.assert_array_equal(o, expect)


# ---------------------------------------------------------------------------------------------------------
# the stage


def _stage_inputs(rng, h, w, device):
    color, depth = random_scene(rng, h, w)
    hit = (rng.random((h, w)) > 0.2).astype(np.uint8)
    return (color, depth, hit, wp.array(color, dtype=wp.vec3, device=device),
            wp.array(depth, dtype=float, device=device), wp.array(hit, dtype=wp.uint8, device=device))


def test_stage_focus_sources_misses_and_in_place(device, rng):
    h, w = 18, 22
    cfg = DofConfig(aperture_m=0.03, focal_length_m=0.05, px_per_m=2e4, max_coc_px=12.0)
    color, depth, hit, cw, dw, hw = _stage_inputs(rng, h, w, device)
    ref = np_scatter(color, depth, hit=hit, focal_length_m=0.05, focus_depth_m=2.5, aperture_m=0.03,
                     px_per_m=2e4, max_coc_px=12.0)
    stage = DofStage(w, h, cfg, device)
    out = wp.zeros((h, w), dtype=wp.vec3, device=device)
    stage.run(cw, dw, hw, 2.5, out)  # float focus
    np.testing.assert_allclose(out.numpy(), ref, atol=1e-4)
    out.zero_()
    stage.run(cw, dw, hw, wp.full(1, 2.5, dtype=float, device=device), out)  # device focus
    np.testing.assert_allclose(out.numpy(), ref, atol=1e-4)
    out.zero_()
    stage.set_focus(2.5)
    stage.run(cw, dw, hw, None, out)  # the stage's own focus array
    np.testing.assert_allclose(out.numpy(), ref, atol=1e-4)
    # misses behave as infinitely far background whatever their depth
    d_inf = np.where(hit == 0, np.inf, depth).astype(np.float32)
    stage.run(cw, wp.array(d_inf, dtype=float, device=device), None, 2.5, out)
    np.testing.assert_allclose(out.numpy(), ref, atol=1e-4)
    # in place
    stage.run(cw, dw, hw, 2.5, cw)
    np.testing.assert_allclose(cw.numpy(), ref, atol=1e-4)
    # a device focus at or below the focal length (or NaN) is clamped, never NaN
    for bad in (0.0, 0.05, float("nan"), -1.0):
        stage.run(wp.array(color, dtype=wp.vec3, device=device), dw, hw, wp.full(1, bad, dtype=float,
                  device=device), out)
        assert np.all(np.isfinite(out.numpy()))


def test_stage_distance_depth_and_focus_at_pixel(device, rng):
    h, w, fov = 20, 30, 50.0
    cfg = DofConfig(aperture_m=0.03, focal_length_m=0.05, px_per_m=2e4, max_coc_px=12.0)
    color, zview, hit, cw, _, hw = _stage_inputs(rng, h, w, device)
    # distance from the eye of the point at view depth z along each pixel's ray (pixel centres)
    t = math.tan(math.radians(fov) / 2)
    sx = (2 * (np.arange(w) + 0.5) / w - 1) * t * (w / h)
    sy = (1 - 2 * (np.arange(h) + 0.5) / h) * t
    dist = (zview * np.sqrt(1 + sx[None, :] ** 2 + sy[:, None] ** 2)).astype(np.float32)
    stage = DofStage(w, h, cfg, device)
    gaze = (7.3, 11.9)
    hit[11, 7] = 1
    hw = wp.array(hit, dtype=wp.uint8, device=device)
    stage.focus_at_pixel(wp.array(dist, dtype=float, device=device), hw, gaze, fov_y_deg=fov)
    zf = float(stage.focus_m.numpy()[0])
    assert zf == pytest.approx(float(zview[11, 7]), rel=1e-5)
    out = wp.zeros((h, w), dtype=wp.vec3, device=device)
    stage.run(cw, wp.array(dist, dtype=float, device=device), hw, None, out, fov_y_deg=fov)
    ref = np_scatter(color, zview, hit=hit, focal_length_m=0.05, focus_depth_m=zf, aperture_m=0.03,
                     px_per_m=2e4, max_coc_px=12.0)
    np.testing.assert_allclose(out.numpy(), ref, atol=2e-4)
    # gaze on a miss: focus at infinity; off screen: the nearest pixel
    hit[0, w - 1] = 0
    stage.focus_at_pixel(wp.array(dist, dtype=float, device=device), wp.array(hit, dtype=wp.uint8, device=device),
                         (w + 40.0, -9.0), fov_y_deg=fov)
    assert float(stage.focus_m.numpy()[0]) == pytest.approx(float(FOCUS_FAR_M), rel=1e-6)
    stage.focus_at_pixel(wp.array(zview, dtype=float, device=device), None, (-5.0, 1e9))
    assert float(stage.focus_m.numpy()[0]) == pytest.approx(float(zview[h - 1, 0]), rel=1e-6)


def test_stage_rejects_wrong_buffers():
    stage = DofStage(8, 6, DofConfig(aperture_m=0.01), "cpu")
    good_c = wp.zeros((6, 8), dtype=wp.vec3, device="cpu")
    good_d = wp.zeros((6, 8), dtype=float, device="cpu")
    with pytest.raises(ValueError, match="color_in"):
        stage.run(wp.zeros((8, 6), dtype=wp.vec3, device="cpu"), good_d, None, 2.0, good_c)
    with pytest.raises(ValueError, match="depth"):
        stage.run(good_c, wp.zeros((6, 8), dtype=wp.vec3, device="cpu"), None, 2.0, good_c)
    with pytest.raises(ValueError, match="focus_depth_m"):
        stage.run(good_c, good_d, None, wp.zeros(2, dtype=float, device="cpu"), good_c)
    with pytest.raises(ValueError, match="fov_y_deg"):
        stage.run(good_c, good_d, None, 2.0, good_c, fov_y_deg=180.0)
    with pytest.raises(ValueError, match="config"):
        DofStage(8, 6, {"aperture_m": 0.01}, "cpu")


# ---------------------------------------------------------------------------------------------------------
# thin-lens reference


def _checker_scene(plane_z=-2.0, square=0.25, n=8):
    from foveawarp.camera import Camera
    from foveawarp.scene import Light
    from foveawarp.scenes import SceneBuilder

    b = SceneBuilder()
    for i in range(n):
        for j in range(n):
            alb = (0.9, 0.9, 0.9) if (i + j) % 2 == 0 else (0.08, 0.08, 0.08)
            b.add_quad(((i - n / 2) * square, (j - n / 2) * square, plane_z), (square, 0, 0), (0, square, 0), alb)
    cam = Camera(eye=(0.0, 0.0, 0.0), target=(0.0, 0.0, -1.0), up=(0.0, 1.0, 0.0), fov_y_deg=40.0)
    light = Light(kind="point", position=(0.3, 0.4, -0.2), intensity=(6.0, 6.0, 6.0))
    return b.build(lights=[light], camera=cam, name="checker")


def test_thin_lens_with_zero_aperture_is_the_pinhole_render(device):
    import foveawarp as fw
    from foveawarp.dof_reference import render_thin_lens

    scene = fw.load_scene("cornell")
    loop = fw.FrameLoop(scene, 48, 32, device=device)
    cam = scene.camera
    pin = loop.render_reference(cam).numpy().copy()
    img = render_thin_lens(loop, cam, 48, 32, DofConfig(aperture_m=0.0, focus_depth_m=3.0), samples=4)
    np.testing.assert_allclose(img, pin, atol=1e-5)
    assert pin.std() > 0.05  # a real picture


def test_thin_lens_keeps_the_focal_plane_sharp_and_blurs_by_the_coc(device):
    """A checkerboard plane at view depth 2 m. Focused on it, the thin-lens image equals the pinhole one.
    Focused at 1.5 m its blur is the CoC of the scatter: the scatter of the pinhole radiance with the CoC of
    the formula matches the ray-traced radiance better than with a CoC 0.6x or 1.6x as large."""
    import foveawarp as fw
    from foveawarp.dof_reference import render_thin_lens

    w, h = 64, 48
    scene = _checker_scene()
    # diffuse only: a view-dependent highlight would legitimately change across the lens
    cfg = fw.Config(shading=fw.ShadingConfig(specular=0.0))
    loop = fw.FrameLoop(scene, w, h, config=cfg, device=device)
    cam = scene.camera
    loop.render_reference(cam)
    pin_hdr = loop.radiance.numpy().reshape(h, w, 3).copy()
    pin = loop.image.numpy().reshape(h, w, 3).copy()
    g = loop.gbuffer
    zview = (g.position.numpy().reshape(h, w, 3) @ np.array([0.0, 0.0, -1.0])).astype(np.float32)
    assert g.hit.numpy().all() and np.allclose(zview, 2.0, atol=1e-4)

    lens = dict(aperture_m=0.035, focal_length_m=0.05, px_per_m=2e4)
    sharp = render_thin_lens(loop, cam, w, h, DofConfig(**lens, focus_depth_m=2.0), samples=32)
    assert np.abs(sharp - pin).max() < 1e-3

    coc = circle_of_confusion_px(np.array([2.0]), focus_depth_m=1.5, **lens)[0]
    assert 5.0 < coc < 8.0
    _, tl_hdr = render_thin_lens(loop, cam, w, h, DofConfig(**lens, focus_depth_m=1.5), samples=128,
                                 return_hdr=True)
    crop = (slice(8, h - 8), slice(8, w - 8))  # away from the borders the scatter renormalizes at
    assert np.abs(tl_hdr - pin_hdr)[crop].mean() > 0.02  # visibly blurred

    def err(scale):
        s = dof_scatter(pin_hdr, zview, focus_depth_m=1.5, **{**lens, "aperture_m": lens["aperture_m"] * scale},
                        max_coc_px=32.0, foreground_fix=False, background_fix=False, device=device)
        return float(np.abs(s - tl_hdr)[crop].mean())

    e1, e_small, e_big = err(1.0), err(0.6), err(1.6)
    assert e1 < 0.6 * min(e_small, e_big)
    assert e1 < 0.3 * float(np.abs(pin_hdr - tl_hdr)[crop].mean())


def test_dof_comparison_images(device):
    import foveawarp as fw
    from foveawarp.dof_reference import COMPARISON_VARIANTS, render_dof_comparison

    scene = fw.load_scene("cornell")
    imgs = render_dof_comparison(scene, scene.camera, 48, 32, samples=4, device=device)
    assert set(imgs) == {"pinhole", "thin_lens", *COMPARISON_VARIANTS}
    for k, v in imgs.items():
        assert v.shape == (32, 48, 3) and np.all(np.isfinite(v)) and v.min() >= 0.0 and v.max() <= 1.0, k
    for k in ("scatter", "corrected", "thin_lens"):
        assert np.abs(imgs[k] - imgs["pinhole"]).max() > 0.05, k  # the default lens blurs visibly
