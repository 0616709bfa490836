"""Albedo demodulation around the reconstruction (kernels/demodulate.py, stages/demodulate.py): the kernel's two
modes against a NumPy transcription of the module's formulas (1e-6 relative), the round trip at traced pixels,
finite output for any input (hypothesis), and inside FrameLoop: the traced pixels as without it, the texture kept
where the samples are sparse (a textured scene's periphery closer to the full-resolution frame), the auto rule,
the path defaults finite on degenerate scenes (hypothesis), and the configuration's validation."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp
from hypothesis import given, settings
from hypothesis import strategies as st

import foveawarp as fw
from foveawarp.kernels.demodulate import ALBEDO_FLOOR, modulate_kernel
from foveawarp.metrics import eccentricity_np

FLOOR = float(ALBEDO_FLOOR)


def np_demod(c, hit, a, e):
    d = np.maximum(c - e, 0.0) / np.maximum(a, FLOOR)
    return np.where(hit[..., None], d, c)


def np_remod(d, hit, a, e):
    r = np.maximum(d, 0.0) * np.maximum(a, FLOOR) + e
    return np.where(hit[..., None], r, d)


DEMOD, REMOD = 0, 1


def _launch(mode, src, hit, a, e, face=None, textured=True, dev="cpu"):
    """The kernel in ``mode`` (DEMOD, REMOD) over (H, W, 3) inputs: per pixel albedo and emission
    (``textured``), else by ``face`` into the (F, 3) tables ``a`` and ``e``."""
    h, w = hit.shape
    v3 = lambda x: wp.array(np.ascontiguousarray(x, np.float32), dtype=wp.vec3, device=dev)  # noqa: E731
    one = wp.zeros((1, 1), dtype=wp.vec3, device=dev)
    if textured:
        args = [1, v3(a), v3(e), wp.zeros((h, w), dtype=wp.int32, device=dev), wp.zeros(1, dtype=wp.vec3, device=dev),
                wp.zeros(1, dtype=wp.vec3, device=dev)]
    else:
        args = [0, one, one, wp.array(face.astype(np.int32), dtype=wp.int32, device=dev), v3(a), v3(e)]
    out = wp.zeros((h, w), dtype=wp.vec3, device=dev)
    wp.launch(modulate_kernel, dim=(h, w), inputs=[v3(src), wp.array(hit.astype(np.uint8), dtype=wp.uint8,
                                                                     device=dev), *args, mode, out, 0], device=dev)
    return out.numpy().astype(np.float64)


def _inputs(seed, h=7, w=9):
    rng = np.random.default_rng(seed)
    c = rng.uniform(0.0, 3.0, (h, w, 3))
    a = rng.uniform(0.0, 1.0, (h, w, 3))
    a[0, :3] = 0.0  # black texels: the floor
    a[1, :3] = FLOOR * 0.5
    e = np.where(rng.uniform(size=(h, w, 1)) < 0.2, rng.uniform(0.0, 4.0, (h, w, 3)), 0.0)
    hit = rng.uniform(size=(h, w)) > 0.15
    return (x.astype(np.float32).astype(np.float64) for x in (c, a, e)), hit


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_kernels_match_numpy(seed):
    (c, a, e), hit = _inputs(seed)
    np.testing.assert_allclose(_launch(DEMOD, c, hit, a, e), np_demod(c, hit, a, e), rtol=1e-6,
                               atol=1e-7)
    np.testing.assert_allclose(_launch(REMOD, c, hit, a, e), np_remod(c, hit, a, e), rtol=1e-6,
                               atol=1e-7)


def test_face_tables_match_numpy():
    """The untextured form: albedo and emission by face."""
    rng = np.random.default_rng(5)
    h, w, nf = 6, 8, 4
    fa = rng.uniform(0.0, 1.0, (nf, 3)).astype(np.float32).astype(np.float64)
    fa[0] = 0.0
    fe = np.zeros((nf, 3))
    fe[3] = (5.0, 4.0, 3.0)
    face = rng.integers(0, nf, (h, w))
    hit = rng.uniform(size=(h, w)) > 0.2
    c = rng.uniform(0.0, 6.0, (h, w, 3)).astype(np.float32).astype(np.float64)
    got = _launch(DEMOD, c, hit, fa, fe, face=face, textured=False)
    np.testing.assert_allclose(got, np_demod(c, hit, fa[face], fe[face]), rtol=1e-6, atol=1e-7)
    got = _launch(REMOD, c, hit, fa, fe, face=face, textured=False)
    np.testing.assert_allclose(got, np_remod(c, hit, fa[face], fe[face]), rtol=1e-6, atol=1e-7)


def test_round_trip_where_radiance_holds_the_emission():
    (c, a, e), hit = _inputs(3)
    c = c + e  # L >= E, as at every traced pixel
    back = _launch(REMOD, _launch(DEMOD, c, hit, a, e), hit, a, e)
    np.testing.assert_allclose(back, c, rtol=2e-6, atol=1e-6)


big = st.floats(min_value=-3e38, max_value=3e38, allow_nan=False, allow_infinity=False)


@settings(max_examples=60, deadline=None)
@given(st.lists(big, min_size=3, max_size=3), st.lists(st.floats(0.0, 1.0), min_size=3, max_size=3),
       st.lists(st.floats(0.0, 3e38), min_size=3, max_size=3),
       st.sampled_from([np.nan, np.inf, -np.inf, 0.0]))
def test_finite_for_any_input(c, a, e, bad):
    """Huge, negative and non-finite radiance in, finite radiance out (the non-finite pixel becomes 0)."""
    cc = np.array([c, c], np.float64).reshape(1, 2, 3)
    cc[0, 1, 0] = bad
    aa = np.broadcast_to(np.array(a), (1, 2, 3))
    ee = np.broadcast_to(np.array(e), (1, 2, 3))
    hit = np.ones((1, 2), bool)
    with np.errstate(all="ignore"):
        for k in (DEMOD, REMOD):
            assert np.isfinite(_launch(k, cc, hit, aa, ee)).all()


W, H = 192, 108


def _loop(scene, demod, device, **shading):
    cfg = fw.Config().with_(reconstruction={"demodulate": demod}, shading=shading)
    return fw.FrameLoop(scene, W, H, config=cfg, device=device, policy="foveated")


def test_textured_periphery_keeps_its_texture(device):
    """The eye chart (a textured built-in, deterministic direct light), along its camera path: the traced pixels are
    as without demodulation (1e-5 relative), and outside 10 degrees of the gaze the frame is closer to the
    full-resolution frame (RMSE of the tone-mapped values below 0.8 of the plain reconstruction's)."""
    scene = fw.load_scene("eyechart")
    gaze = (0.3 * W, 0.55 * H)
    hdr, filled = {}, None
    for demod in (False, True):
        loop = _loop(scene, demod, device)
        assert (loop.demodulation is not None) == demod
        for i in range(4):
            cam = scene.camera_at(i / 30.0)
            f = loop.render(cam, gaze_px=gaze)
        hdr[demod] = loop.hdr.numpy().copy()
        assert np.isfinite(hdr[demod]).all()
        if demod:
            filled = f.extras["filled"].numpy().astype(bool)
            loop.render_reference(cam)
            full = loop.hdr.numpy().copy()  # the full-resolution frame's radiance
    np.testing.assert_allclose(hdr[True][filled], hdr[False][filled], rtol=1e-5, atol=1e-6)
    far = eccentricity_np(W, H, gaze, cam.fov_y_deg) >= 10.0
    far &= ~filled
    assert far.sum() > 0.05 * far.size  # the gaps: history fills most of a deterministic frame
    tm = lambda x: x / (1.0 + x)  # noqa: E731
    err = {k: float(np.sqrt(np.mean((tm(v[far]) - tm(full[far])) ** 2))) for k, v in hdr.items()}
    assert err[True] < 0.8 * err[False], err


def test_auto_rule_and_validation(device):
    scene = fw.load_scene("cornell", area_light=True)
    assert _loop(scene, None, device).demodulation is None  # the direct integrator
    assert _loop(scene, None, device, integrator="path").demodulation is not None
    assert _loop(scene, False, device, integrator="path").demodulation is None
    sparse = fw.Config().with_(foveation={"gbuffer": "sparse"}, reconstruction={"demodulate": True})
    assert fw.FrameLoop(scene, W, H, config=sparse, device=device).demodulation is None
    for bad in ("yes", 1, 0.5):
        with pytest.raises(ValueError, match="ReconstructionConfig.demodulate must be True, False or None"):
            fw.ReconstructionConfig(demodulate=bad)


@settings(max_examples=12, deadline=None)
@given(st.integers(1, 24), st.integers(1, 16), st.floats(-2.0, 2.0), st.floats(-2.0, 2.0), st.integers(0, 3),
       st.booleans())
def test_path_defaults_finite_on_degenerate_scenes(w, h, gx, gy, kind, black):
    """The path integrator's defaults (demodulated reconstruction, periphery filter) on tiny frames, the gaze
    anywhere (off screen too), faces of albedo 0 and emitting faces: every frame finite and >= 0."""
    import dataclasses

    base = fw.load_scene("cornell", area_light=True)
    rng = np.random.default_rng(w * 31 + h)
    alb = np.asarray(base.face_albedo, np.float64).copy()
    emi = np.zeros_like(alb)
    pick = rng.uniform(size=len(alb))
    if black:
        alb[pick < 0.5] = 0.0
    emi[pick > 0.8] = rng.uniform(0.0, 50.0, (int((pick > 0.8).sum()), 3))
    scene = dataclasses.replace(base, face_albedo=alb, face_emission=emi)
    cfg = fw.Config().with_(shading={"integrator": "path", "max_depth": 1 + kind, "spp": 1})
    loop = fw.FrameLoop(scene, w, h, config=cfg, device="cpu", policy="foveated")
    for i in range(3):
        f = loop.render(scene.camera_at(i / 30.0), gaze_px=(gx * w, gy * h))
        for a in (loop.hdr.numpy(), f.numpy()):
            assert np.isfinite(a).all() and (a >= 0).all()
