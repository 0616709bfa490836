"""Stress: depth of field (ALGORITHMS.md B) at CoC zero (aperture 0, everything at the focus depth) and at
the maximum CoC (clamp reached everywhere, max_coc_px up to 128), with depths from behind the lens to float
max, focus just above the focal length or at 1e30, extreme colors, hit masks, both methods, and the DofStage
with distance depths, device-side focus values and gazes anywhere."""

from __future__ import annotations

import math

import numpy as np
import warp as wp
from hypothesis import given
from hypothesis import strategies as st

from foveawarp import DofConfig, ops
from foveawarp.stages.dof import DofStage
from stress_util import F32_MAX, assert_finite, batch, examples

FOCUS_MIN_REL = 1.0e-4  # kernels.dof: focus clamped to >= F (1 + 1e-4)
FOCUS_FAR = 1.0e30


def coc_reference(z, zf, f, e, k, cmax):
    """float64 CoC diameter in pixels with the kernel's conventions (focus clamp, z <= 0 -> clamp)."""
    zf = min(max(zf, f * (1.0 + FOCUS_MIN_REL)), FOCUS_FAR)
    z = np.asarray(z, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        c = e * f * k * (zf / (zf - f)) * np.abs(1.0 / zf - 1.0 / z)
    c = np.where(z > 0, c, cmax)
    return np.minimum(c, cmax) if np.float32(e * f * k) > 0 else np.zeros_like(c)


focal = st.one_of(st.sampled_from([1e-4, 0.05, 1.0, 10.0]), st.floats(1e-4, 10.0))
aperture = st.one_of(st.sampled_from([0.0, 0.0, 1e-9, 0.02, 10.0]), st.floats(0.0, 10.0))
px_per_m = st.one_of(st.sampled_from([1e-3, 1.0, 2e4, 1e9]), st.floats(1e-3, 1e9))


@examples(60, 600)
@given(f=focal, rel=st.one_of(st.sampled_from([1e-9, 1e-4, 1.0, 1e6, 1e25]), st.floats(1e-9, 1e6)), e=aperture,
       k=px_per_m, cmax=st.one_of(st.none(), st.sampled_from([1e-3, 1.0, 16.0, 128.0, 1e30])),
       seed=st.integers(0, 2**32 - 1))
def test_coc_zero_and_maximum_circle_of_confusion(device, cases, f, rel, e, k, cmax, seed):
    """CoC of packed depths (the focus itself, 0, negative, denormal, 1e30, float max, log-uniform): finite,
    in [0, clamp], exactly 0 at the focus depth and for aperture 0, the clamp at and behind the lens, and
    equal to a float64 reference (the focus clamp to F (1 + 1e-4) included)."""
    zf = f * (1.0 + rel)
    rng = np.random.default_rng(seed)
    n = batch(device, 64)
    special = [zf, np.float32(zf), 0.0, -1.0, -F32_MAX, 1e-45, 1e-30, 1e30, F32_MAX, f, zf * (1 + 1e-6)]
    z = np.concatenate([special, rng.choice([-1.0, 1.0], n - len(special)) * 10.0 ** rng.uniform(-40, 38.5,
                                                                                              n - len(special))])
    z = z.astype(np.float32)
    c = assert_finite("coc", ops.circle_of_confusion_px(z, focal_length_m=f, focus_depth_m=zf, aperture_m=e,
                                                        px_per_m=k, max_coc_px=cmax, device=device))
    lim = 3.0e38 if cmax is None else np.float32(cmax)
    assert c.min() >= 0.0 and c.max() <= lim
    if e * f * k < np.finfo(np.float32).tiny:  # zero aperture (or a lens scale below float32's normals): pinhole
        assert (c == 0).all()
    else:
        assert (c[z <= 0] == np.float32(lim)).all()
        ref = coc_reference(z, zf, f, e, k, lim)
        # float32 rounding: ~eps / rel in Z_f - F (rel >= 1e-4 after the clamp), and the cancellation in
        # 1 / Z_f - 1 / Z near the focus (bounded by eps (a / Z_f + a / Z))
        zc = min(max(zf, f * (1.0 + FOCUS_MIN_REL)), FOCUS_FAR)
        a = e * f * k * zc / (zc - f)
        with np.errstate(divide="ignore", over="ignore"):
            cancel = 8.0 * 1.2e-7 * (a / zc + a / np.abs(z.astype(np.float64)))
        err = np.abs(c - ref)
        ok = (err <= 3e-3 * ref + cancel + 1e-44) | ((c == lim) & (ref >= lim * (1 - 3e-3)))  # 1e-44: denormals
        assert ok.all(), f"f={f} zf={zf} e={e} k={k}: z={z[~ok][:4]} got {c[~ok][:4]} expected {ref[~ok][:4]}"
        if np.float32(zf) == zf and zf >= f * (1.0 + 2 * FOCUS_MIN_REL) and zf <= FOCUS_FAR:  # clear of the clamp
            assert c[1] == 0.0  # exactly at the focus depth
    cases.add("CoC (lens x depth)", n)


def _scene(kind, h, w, rng, zf):
    if kind == "focus":  # everything at the focus depth: CoC zero everywhere
        return np.full((h, w), zf)
    if kind == "near":  # everything at or behind the lens: CoC at the clamp everywhere
        return rng.choice([0.0, -1.0, 1e-30, zf * 1e-6], size=(h, w))
    if kind == "far":
        return rng.choice([1e30, F32_MAX, zf * 1e6], size=(h, w))
    if kind == "layers":
        return rng.choice([zf * 0.1, zf, zf * 10.0, 0.0, 1e30], size=(h, w))
    return zf * 10.0 ** rng.uniform(-3, 3, size=(h, w))


def scatter_reference(col, z, hit, coc, zf, gamma, eps, fg_fix, bg_fix):
    """float64 pixel-intensity scatter (module docstring of kernels.dof) from the op's CoC values: source p
    covers receiver q when |p - q|^2 <= R_p^2, R_p = max(C_p / 2, 0.5), with weight K_p / (pi R_p^2) (times
    W(C_p, C_q) for background sources with the background fix); the output is the weighted mean."""
    h, w = z.shape
    zz = z.astype(np.float64).copy()
    zz[~(zz >= 0)] = 0.0
    if hit is not None:
        zz[hit == 0] = np.inf
    c = coc.astype(np.float64).ravel()
    r = np.maximum(0.5 * c, 0.5)
    fg = (zz < zf).ravel()
    with np.errstate(divide="ignore", over="ignore"):
        k = np.where(fg & fg_fix, np.minimum((zf / np.maximum(zz.ravel(), 1e-30)) ** gamma, 1e8), 1.0)
    a_w = k / (np.pi * r * r)
    yy, xx = np.mgrid[0:h, 0:w]
    py, px = yy.ravel(), xx.ravel()
    d2 = (py[:, None] - py[None, :]) ** 2 + (px[:, None] - px[None, :]) ** 2  # [source, receiver]
    wgt = np.where(d2 <= (r * r)[:, None], a_w[:, None], 0.0)
    if bg_fix:
        aa = np.clip((c[:, None] - c[None, :]) / eps, 0.0, 1.0)
        tt = np.clip(c[None, :] / eps - 1.0, 0.0, 1.0)
        wgt = np.where((~fg)[:, None], wgt * (1.0 - aa * (1.0 - tt)), wgt)
    cf = col.reshape(-1, 3).astype(np.float64)
    sw = wgt.sum(axis=0)
    out = np.where(sw[:, None] > 0, (wgt.T @ cf) / np.where(sw > 0, sw, 1.0)[:, None], cf)
    return out.reshape(h, w, 3)


@examples(300, 2000)
@given(h=st.integers(1, 20), w=st.integers(1, 20), seed=st.integers(0, 2**32 - 1),
       kind=st.sampled_from(["focus", "near", "far", "layers", "random"]),
       lens=st.sampled_from(["pinhole", "max", "normal", "tiny_focus"]),
       cmax=st.sampled_from([1.0, 2.0, 16.0, 128.0]), gamma=st.sampled_from([0.0, 1.0, 2.0, 16.0]),
       eps=st.sampled_from([1e-30, 1e-3, 1.0, 1e30]), fixes=st.tuples(st.booleans(), st.booleans()),
       cmode=st.sampled_from(["unit", "unit", "hdr", "huge", "f32max", "zero"]), use_hit=st.booleans(),
       tile=st.sampled_from([1, 3, 8, 64]))
def test_coc_zero_and_maximum_dof_scatter(device, cases, h, w, seed, kind, lens, cmax, gamma, eps, fixes, cmode,
                                          use_hit, tile):
    """dof_scatter (gather and scatter methods) at CoC zero (pinhole, or all depths at the focus: the image
    is unchanged) and at the maximum CoC (a 10 m aperture: every pixel at the clamp), and in between, with
    colors from 0 to float max: finite, every output channel within the input's range (a weighted mean),
    both methods equal, and the gather equal to a float64 evaluation of the scatter model."""
    rng = np.random.default_rng(seed)
    f = 0.05
    zf = {"tiny_focus": f * (1.0 + 1e-7)}.get(lens, float(10.0 ** rng.uniform(-1, 2)))
    e = {"pinhole": 0.0, "max": 10.0}.get(lens, 0.02)
    z = _scene(kind, h, w, rng, max(zf, f * 1.001)).astype(np.float32)
    if cmode == "unit":
        col = rng.random((h, w, 3))
    elif cmode == "hdr":
        col = 10.0 ** rng.uniform(-3, 4, (h, w, 3))
    elif cmode == "huge":  # radiance of tiny scenes: up to ~1e30 and beyond
        col = 10.0 ** rng.uniform(20, 34, (h, w, 3))
    elif cmode == "f32max":
        col = 10.0 ** rng.uniform(36, 38.53, (h, w, 3))
    else:
        col = np.zeros((h, w, 3))
    col = col.astype(np.float32)
    hit = (rng.random((h, w)) > 0.3).astype(np.uint8) if use_hit else None
    kw = dict(focal_length_m=f, focus_depth_m=zf, aperture_m=e, px_per_m=2e4, gamma=gamma, eps_px=eps,
              max_coc_px=cmax, foreground_fix=fixes[0], background_fix=fixes[1], hit=hit, tile_px=tile,
              device=device)
    out_g = assert_finite(f"dof gather {kind}/{lens}", ops.dof_scatter(col, z, method="gather", **kw))
    out_s = assert_finite(f"dof scatter {kind}/{lens}", ops.dof_scatter(col, z, method="scatter", **kw))
    lo = col.reshape(-1, 3).min(axis=0).astype(np.float64)
    hi = col.reshape(-1, 3).max(axis=0).astype(np.float64)
    slack = 1e-5 * np.maximum(np.abs(lo), np.abs(hi)) + 1e-30
    for name, out in (("gather", out_g), ("scatter", out_s)):
        assert ((out >= lo - slack) & (out <= hi + slack)).all(), f"{name}: outside the input range"
    if cmode != "f32max":  # the atomic scatter (the reference method) has no overflow fallback
        np.testing.assert_allclose(out_g, out_s, rtol=2e-4, atol=float(2e-5 * hi.max() + 1e-30))
    coc = ops.circle_of_confusion_px(np.where(hit == 0, 1e30, z) if use_hit else z, focal_length_m=f,
                                     focus_depth_m=zf, aperture_m=e, px_per_m=2e4, max_coc_px=cmax, device=device)
    zf_eff = max(np.float32(zf), np.float32(f) * np.float32(1.0 + 1e-4))
    ref = scatter_reference(col, z, hit, coc, float(zf_eff), gamma, eps, fixes[0], fixes[1])
    np.testing.assert_allclose(out_g, ref, rtol=1e-3, atol=float(1e-4 * hi.max() + 1e-30),
                               err_msg=f"{kind}/{lens}/{cmode}: differs from the float64 scatter")
    if lens == "pinhole" or (kind == "focus" and not use_hit and lens != "tiny_focus"):
        assert (coc <= 1.0).all()
        # every disc is the pixel itself: the image is unchanged (up to the A I / A round trip)
        np.testing.assert_allclose(out_g, col, rtol=1e-6, atol=1e-30)
    if lens == "max" and kind == "near":
        assert (coc == np.float32(cmax)).all()
    cases.add("dof_scatter images (CoC zero / max)", 1)


@examples(200, 2000)
@given(h=st.integers(1, 24), w=st.integers(1, 24), seed=st.integers(0, 2**32 - 1),
       aperture_m=st.sampled_from([1e-9, 0.02, 10.0]), cmax=st.sampled_from([1.0, 128.0]),
       fov=st.sampled_from([None, 1e-3, 60.0, 179.0]),
       focus=st.sampled_from(["gaze", "nan", "zero", "negative", "huge", "inf", "focal"]),
       gaze=st.tuples(st.floats(-1e30, 1e30), st.floats(-1e30, 1e30)))
def test_coc_zero_and_maximum_dof_stage(device, cases, h, w, seed, aperture_m, cmax, fov, focus, gaze):
    """The DofStage as the FrameLoop drives it: G-buffer distances (with ``fov_y_deg``) or view depths, a
    hit mask, and the focus from ``focus_at_pixel`` at any gaze or as a device value that may be NaN, 0,
    negative, +inf or the focal length itself (clamped on the device). Output finite, within the input
    range; CoC in [0, max_coc_px]."""
    rng = np.random.default_rng(seed)
    dev = wp.get_device(device)
    cfg = DofConfig(aperture_m=aperture_m, focal_length_m=0.05, px_per_m=2e4, max_coc_px=cmax)
    st_ = DofStage(w, h, cfg, dev, method="gather" if seed % 2 else "scatter")
    depth = rng.choice([0.0, 1e-30, 0.05, 1.0, 7.0, 1e30], size=(h, w)).astype(np.float32)
    hit = (depth < 1e29).astype(np.uint8)
    col = rng.random((h, w, 3)).astype(np.float32)
    d_wp = wp.array(depth, dtype=float, device=dev)
    h_wp = wp.array(hit, dtype=wp.uint8, device=dev)
    c_wp = wp.array(col, dtype=wp.vec3, device=dev)
    out = wp.zeros((h, w), dtype=wp.vec3, device=dev)
    if focus == "gaze":
        fz = st_.focus_at_pixel(d_wp, h_wp, gaze, fov_y_deg=fov)
        fv = float(fz.numpy()[0])
        assert math.isfinite(fv) and fv > 0.0
    else:
        val = {"nan": np.nan, "zero": 0.0, "negative": -3.0, "huge": 1e38, "inf": np.inf, "focal": 0.05}[focus]
        fz = wp.array([val], dtype=float, device=dev)
    st_.run(c_wp, d_wp, h_wp, fz, out, fov_y_deg=fov)
    o = assert_finite(f"DofStage focus={focus}", out.numpy())
    assert ((o >= -1e-6) & (o <= 1.0 + 1e-5)).all()
    coc = assert_finite("DofStage coc", st_.coc.numpy())
    assert coc.min() >= 0.0 and coc.max() <= cmax
    cases.add("DofStage frames (focus / gaze)", 1)
