"""The path integrator (kernels/path.py, stages/path.py, ops/path.py) against independent references.

Statistical tests draw K independent passes (seeds per frame index) and compare with a Student t statistic from
the passes' spread: the image mean within ``T_MAX`` standard errors and a stated relative tolerance, every pixel
within ``T_PIXEL`` standard errors. The seeds are fixed, so each outcome is deterministic; the bounds say how far a
correct integrator may stray at that noise level (a 1-2 % bias is tens of standard errors of the image mean).
"""

import dataclasses
import math

import numpy as np
import pytest
import scipy.stats
import warp as wp
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import foveawarp as fw
from foveawarp.kernels.path import power_heuristic_kernel, sample_directions_kernel
from foveawarp.kernels.shade import AreaLightParams
from foveawarp.ops import render_converged
from foveawarp.scene import DeviceScene
from foveawarp.stages.path import PathStage, emitter_tables, material_from_blinn_phong
from foveawarp.surface import set_material_specular

# image-mean t statistic bound (K = 16 passes: df 15, two-sided p = 1.2e-3 at 4; less with more passes)
T_MAX = 4.0
# per-pixel t bound (df 15: two-sided p = 1.6e-4 per pixel at 5.0)
T_PIXEL = 5.0

LAMBERT = fw.ShadingConfig(specular=0.0)


def cam_basis(cam):
    """(eye, right, up, forward) of a camera from its eye, target and up (independent of Camera.basis)."""
    e = np.asarray(cam.eye, float)
    f = np.asarray(cam.target, float) - e
    f /= np.linalg.norm(f)
    r = np.cross(f, np.asarray(cam.up, float))
    r /= np.linalg.norm(r)
    return e, r, np.cross(r, f), f


def centre_rays(cam, w, h):
    """(H, W, 3) unit directions through the pixel centres (pinhole, vertical fov, square pixels)."""
    e, r, u, f = cam_basis(cam)
    t = math.tan(math.radians(cam.fov_y_deg) / 2.0)
    x, y = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    sx = (2.0 * x / w - 1.0) * t * w / h
    sy = (1.0 - 2.0 * y / h) * t
    d = f + sx[..., None] * r + sy[..., None] * u
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def passes(scene, cam, w, h, k, spp, config=LAMBERT, pixel_filter="centre", device="cpu", specular=None,
           **fields):
    """(k, H, W, 3): k independent path-traced images (frame index = pass) of ``spp`` paths per pixel;
    ``specular``: the materials' specular scale of a scene with materials (``set_material_specular``)."""
    sc = dataclasses.replace(config, integrator="path", spp=spp, **fields)
    ds = DeviceScene(scene, device=device)
    if specular is not None:
        set_material_specular(ds, specular)
    stage = PathStage(ds, sc, w, h, device, pixel_filter=pixel_filter)
    out = wp.zeros((h, w), dtype=wp.vec3, device=device)
    imgs = []
    for i in range(k):
        stage.run(cam, i, out)
        imgs.append(out.numpy().copy())
    return np.stack(imgs).astype(np.float64)


def check_statistically(imgs, ref, mask, rel_tol):
    """The passes' mean against ``ref`` on ``mask``: image mean within T_MAX standard errors and ``rel_tol``,
    every pixel within T_PIXEL standard errors (plus 1e-6 for noiseless pixels)."""
    k = imgs.shape[0]
    lum = imgs.mean(axis=-1)[:, mask]  # (k, P)
    rl = ref.mean(axis=-1)[mask]
    ratio = lum.mean(axis=1) / rl.mean()  # per-pass image-mean ratio
    m, se = ratio.mean(), ratio.std(ddof=1) / math.sqrt(k)
    assert abs(m - 1.0) <= max(T_MAX * se, 1e-6), (m, se)
    assert abs(m - 1.0) <= rel_tol, (m, se)
    pm = lum.mean(axis=0)
    pse = lum.std(axis=0, ddof=1) / math.sqrt(k)
    bad = np.abs(pm - rl) > T_PIXEL * pse + 1e-6 * np.maximum(rl, 1.0)
    assert not bad.any(), (np.count_nonzero(bad), pm[bad][:5], rl[bad][:5], pse[bad][:5])
    return m, se


def quad_mesh(c, u, v):
    c, u, v = (np.asarray(x, float) for x in (c, u, v))
    return np.stack([c, c + u, c + u + v, c + v]), np.array([[0, 1, 2], [0, 2, 3]])


def box_mesh(lo, hi):
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    v = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    f = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1], [2, 3, 7], [2, 7, 6],
                  [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    return v, f


# ---------------------------------------------------------------------------------------------------------------
# configuration

def test_config_fields_and_validation():
    sc = fw.ShadingConfig()
    assert (sc.integrator, sc.max_depth, sc.spp, sc.rr_depth, sc.radiance_clamp) == ("direct", 5, 1, 5, None)
    c = fw.Config().with_(shading={"integrator": "path", "max_depth": 3, "spp": 4, "rr_depth": 2,
                                   "radiance_clamp": 20.0})
    assert c.shading.integrator == "path" and c.shading.radiance_clamp == 20.0
    for field, bad in (("integrator", "bdpt"), ("max_depth", 0), ("max_depth", 2.0), ("spp", 0), ("rr_depth", 0),
                       ("radiance_clamp", 0.0), ("radiance_clamp", -1.0), ("radiance_clamp", float("inf")),
                       ("radiance_clamp", "1")):
        with pytest.raises(ValueError, match=f"ShadingConfig.{field}"):
            fw.ShadingConfig(**{field: bad})


def test_stage_rejects_bad_input():
    v, f = quad_mesh((-1, 0, -1), (0, 0, 2), (2, 0, 0))
    ds = DeviceScene(fw.Scene(vertices=v, faces=f, face_albedo=np.full((2, 3), 0.5)), device="cpu")
    with pytest.raises(ValueError, match="pixel_filter"):
        PathStage(ds, LAMBERT, 4, 4, "cpu", pixel_filter="gauss")
    stage = PathStage(ds, LAMBERT, 4, 4, "cpu")
    with pytest.raises(ValueError, match="out must be"):
        stage.run(fw.Camera(), 0, wp.zeros((3, 4), dtype=wp.vec3, device="cpu"))
    with pytest.raises(ValueError, match="spp_total"):
        render_converged(ds.scene, None, 4, 4, 0, device="cpu")


def test_blinn_phong_stand_in():
    r, s = material_from_blinn_phong(0.15, 48.0)
    assert r == pytest.approx(math.sqrt(0.2)) and s == 1.0
    assert material_from_blinn_phong(0.0, 48.0)[1] == 0.0
    assert material_from_blinn_phong(0.02, 48.0)[1] == pytest.approx(0.5)


def test_emitter_tables_probabilities():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 0], [2, 0, 0], [0, 2, 0], [0, 0, 0], [1, 0, 0], [2, 0, 0]],
                 float)
    f = np.array([[0, 1, 2], [3, 4, 5], [6, 7, 8], [0, 1, 2]])
    e = np.array([[1, 1, 1], [1, 0, 0], [5, 5, 5], [0, 0, 0]], float)  # face 2 has no area, face 3 no emission
    face, cdf, prob = emitter_tables(v, f, e)
    assert face.tolist() == [0, 1] and cdf[0] == 0.0 and cdf[-1] == 1.0
    # weights area * summed emission: 0.5 * 3 and 2 * 1
    np.testing.assert_allclose(prob, [1.5 / 3.5, 2.0 / 3.5, 0.0, 0.0], rtol=1e-6)


# ---------------------------------------------------------------------------------------------------------------
# multiple importance sampling

def test_power_heuristic_weights_sum_to_one():
    rng = np.random.default_rng(3)
    a = np.concatenate([10.0 ** rng.uniform(-30, 30, 2000), [0.0, 0.0, 1.0, 1e38, 3e38, 1e-38, 5.0, np.nan]])
    b = np.concatenate([10.0 ** rng.uniform(-30, 30, 2000), [0.0, 1.0, 0.0, 1e38, 1.0, 1e-38, 5.0, 1.0]])
    a, b = a.astype(np.float32), b.astype(np.float32)
    n = len(a)
    wa = wp.zeros(n, dtype=float, device="cpu")
    wb = wp.zeros(n, dtype=float, device="cpu")
    pa = wp.array(a, dtype=float, device="cpu")
    pb = wp.array(b, dtype=float, device="cpu")
    wp.launch(power_heuristic_kernel, dim=n, inputs=[pa, pb], outputs=[wa], device="cpu")
    wp.launch(power_heuristic_kernel, dim=n, inputs=[pb, pa], outputs=[wb], device="cpu")
    wa, wb = wa.numpy().astype(np.float64), wb.numpy().astype(np.float64)
    assert np.all(np.isfinite(wa)) and np.all((wa >= 0) & (wa <= 1))
    either = (np.nan_to_num(a) > 0) | (b > 0)
    np.testing.assert_allclose((wa + wb)[either], 1.0, atol=2e-7)
    assert np.all(wa[~either] == 0.0)
    # the formula pa^2 / (pa^2 + pb^2) in float64 where it does not overflow
    a64, b64 = np.nan_to_num(a.astype(np.float64)), b.astype(np.float64)
    ok = either & (a64 < 1e30) & (b64 < 1e30)
    expect = a64[ok] ** 2 / (a64[ok] ** 2 + b64[ok] ** 2)
    np.testing.assert_allclose(wa[ok], expect, rtol=1e-5, atol=1e-30)


# ---------------------------------------------------------------------------------------------------------------
# the sampled directions' pdf against the BSDF (chi-square)

def np_pdf(local, wo, base, rough, spec):
    """The lobe mixture's solid-angle pdf (glTF metallic 0) in NumPy, local frame: p_spec D(h) G1(wo) / (4 wo.z)
    + (1 - p_spec) cos / pi, lobe probabilities from the Fresnel weights at wo."""
    alpha = max(rough * rough, 1e-3)
    z = local[..., 2]
    h = local + wo
    h /= np.linalg.norm(h, axis=-1, keepdims=True)
    a2 = alpha * alpha
    t = h[..., 0] ** 2 + h[..., 1] ** 2 + a2 * h[..., 2] ** 2
    d = np.where(h[..., 2] > 0, a2 / (np.pi * t * t), 0.0)
    zo = wo[2]
    lam = 0.5 * (np.sqrt(1.0 + a2 * (1.0 - zo * zo) / (zo * zo)) - 1.0)
    g1 = 1.0 / (1.0 + lam)
    pdf_spec = d * g1 / (4.0 * zo)
    fd = spec * (0.04 + 0.96 * (1.0 - zo) ** 5)
    lum = 0.2126 * base[0] + 0.7152 * base[1] + 0.0722 * base[2]
    ws, wd = fd, (1.0 - fd) * lum
    ps = ws / (ws + wd) if ws + wd > 0 else 1.0
    return np.where(z > 0, ps * pdf_spec + (1.0 - ps) * z / np.pi, 0.0)


@pytest.mark.parametrize("base,rough,spec,theta_o", [((0.8, 0.6, 0.4), 0.5, 0.0, 0.7),
                                                    ((0.5, 0.5, 0.5), 0.45, 1.0, 0.5),
                                                    ((0.2, 0.2, 0.2), 0.6, 1.0, 1.2)])
def test_sampled_directions_match_pdf(base, rough, spec, theta_o):
    n_samples = 200_000
    normal = np.array([0.3, 0.8, -0.52])
    normal /= np.linalg.norm(normal)
    # a tangent frame built here, x towards the azimuth of wo
    t0 = np.cross(normal, [1.0, 0.0, 0.0])
    t0 /= np.linalg.norm(t0)
    b0 = np.cross(normal, t0)
    wo_world = math.sin(theta_o) * t0 + math.cos(theta_o) * normal
    wo_local = np.array([math.sin(theta_o), 0.0, math.cos(theta_o)])
    wi = wp.zeros(n_samples, dtype=wp.vec3, device="cpu")
    pdf_s = wp.zeros(n_samples, dtype=float, device="cpu")
    pdf_e = wp.zeros(n_samples, dtype=float, device="cpu")
    wp.launch(sample_directions_kernel, dim=n_samples, device="cpu",
              inputs=[wp.vec3(*base), rough, spec, wp.vec3(*normal), wp.vec3(*wo_world), 11],
              outputs=[wi, pdf_s, pdf_e])
    wi, pdf_s, pdf_e = wi.numpy().astype(np.float64), pdf_s.numpy(), pdf_e.numpy()
    ok = pdf_s > 0
    np.testing.assert_allclose(pdf_s[ok], pdf_e[ok], rtol=1e-4)
    loc = np.stack([wi @ t0, wi @ b0, wi @ normal], axis=-1)
    # the sampled pdf is the NumPy pdf of the direction
    np.testing.assert_allclose(pdf_s[ok], np_pdf(loc[ok], wo_local, base, rough, spec), rtol=2e-3)
    nt, nphi = 16, 24
    ti = np.clip((np.arccos(np.clip(loc[ok, 2], -1, 1)) / (np.pi / 2) * nt).astype(int), 0, nt - 1)
    pi_ = ((np.arctan2(loc[ok, 1], loc[ok, 0]) % (2 * np.pi)) / (2 * np.pi) * nphi).astype(int) % nphi
    obs = np.bincount(ti * nphi + pi_, minlength=nt * nphi).astype(float)
    # expected bin masses: the NumPy pdf integrated by the midpoint rule on 12 x 12 cells per bin
    sub = 12
    th = (np.arange(nt * sub) + 0.5) / (nt * sub) * (np.pi / 2)
    ph = (np.arange(nphi * sub) + 0.5) / (nphi * sub) * (2 * np.pi)
    T, P = np.meshgrid(th, ph, indexing="ij")
    dirs = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], axis=-1)
    mass = np_pdf(dirs, wo_local, base, rough, spec) * np.sin(T) * (np.pi / 2 / (nt * sub)) * (2 * np.pi / (nphi * sub))
    exp = mass.reshape(nt, sub, nphi, sub).sum(axis=(1, 3)).ravel() * n_samples
    failed = n_samples - np.count_nonzero(ok)
    obs = np.append(obs, failed)
    exp = np.append(exp, max(n_samples - exp.sum(), 0.0))
    # pool the bins expecting fewer than 5 samples
    small = exp < 5
    obs = np.append(obs[~small], obs[small].sum())
    exp = np.append(exp[~small], exp[small].sum())
    if exp[-1] < 5:
        obs[-2] += obs[-1]
        exp[-2] += exp[-1]
        obs, exp = obs[:-1], exp[:-1]
    exp *= obs.sum() / exp.sum()
    chi2, p = scipy.stats.chisquare(obs, exp)
    assert p > 1e-3, (chi2, p, len(obs))


# ---------------------------------------------------------------------------------------------------------------
# unbiasedness

@pytest.mark.parametrize("rr_depth", [1, 5])
def test_white_furnace(rr_depth):
    """A closed diffuse box of albedo a, every face emitting Le: L = Le (1 - a^D) / (1 - a) at max_depth D."""
    a, le, depth = 0.5, 0.3, 40
    v, f = box_mesh((-1, -1, -1), (1, 1, 1))
    sc = fw.Scene(vertices=v, faces=f, face_albedo=np.full((12, 3), a), face_emission=np.full((12, 3), le))
    cam = fw.Camera(eye=(0.2, 0.1, 0.3), target=(-0.3, -0.2, -1.0), up=(0, 1, 0), fov_y_deg=70)
    imgs = passes(sc, cam, 12, 8, 32, 16, max_depth=depth, rr_depth=rr_depth, pixel_filter="box")
    expect = le * (1 - a ** depth) / (1 - a)
    check_statistically(imgs, np.full(imgs.shape[1:], expect), np.ones(imgs.shape[1:3], bool), 0.01)


def test_white_furnace_converged_reference():
    a, le = 0.7, 1.0
    v, f = box_mesh((-2, -1, -1), (1, 1, 2))
    sc = fw.Scene(vertices=v, faces=f, face_albedo=np.full((12, 3), a), face_emission=np.full((12, 3), le))
    img = render_converged(sc, fw.Camera(eye=(0, 0, 0), target=(1, 0.2, 0.3), up=(0, 1, 0)), 8, 6, 256,
                           max_depth=60, seed=5, device="cpu", spp_per_pass=64, shading=LAMBERT)
    assert img.shape == (6, 8, 3) and img.dtype == np.float32
    assert img.mean() == pytest.approx(le * (1 - a ** 60) / (1 - a), rel=0.01)


def test_plane_under_constant_environment():
    """A diffuse plane under a constant environment Le sees the whole upper hemisphere: L = a Le on it, Le off
    it; the environment lights it by its own sampling and by BSDF rays, combined by MIS."""
    a, le = np.array([0.7, 0.5, 0.3]), np.array([0.8, 1.0, 1.2])
    v, f = quad_mesh((-1, 0, -1), (0, 0, 2), (2, 0, 0))
    sc = fw.Scene(vertices=v, faces=f, face_albedo=np.tile(a, (2, 1)), environment=np.tile(le, (4, 8, 1)))
    cam = fw.Camera(eye=(0.0, 1.6, 2.4), target=(0, 0, 0), up=(0, 1, 0), fov_y_deg=50)
    w, h = 16, 12
    d = centre_rays(cam, w, h)
    e = np.asarray(cam.eye)
    t = -e[1] / d[..., 1]
    p = e + t[..., None] * d
    on = (t > 0) & (np.abs(p[..., 0]) < 1) & (np.abs(p[..., 2]) < 1)
    ref = np.where(on[..., None], a * le, le)
    assert on.any() and (~on).any()
    for depth in (2, 5):
        imgs = passes(sc, cam, w, h, 16, 8, max_depth=depth)
        check_statistically(imgs, ref, on, 0.01)
        np.testing.assert_allclose(imgs[:, ~on], np.broadcast_to(le, imgs[:, ~on].shape), rtol=1e-5)


def plane_hits(cam, w, h, size):
    d = centre_rays(cam, w, h)
    e = np.asarray(cam.eye)
    t = -e[1] / d[..., 1]
    p = e + t[..., None] * d
    on = (t > 0) & (np.abs(p[..., 0]) < size) & (np.abs(p[..., 2]) < size)
    return p, on


@pytest.mark.parametrize("kind", ["point", "spot"])
def test_depth2_point_light_exact(kind):
    """Depth 2 under a point or spot light over a plane is deterministic: (a / pi) I att cos / r^2, computed here
    from the ray-plane hits and the spot's smoothstep."""
    a = np.array([0.6, 0.4, 0.2])
    v, f = quad_mesh((-2, 0, -2), (0, 0, 4), (4, 0, 0))
    light = fw.Light(kind=kind, position=(0.3, 1.2, -0.2), direction=(0.2, -1.0, 0.1), cone_deg=40.0,
                     intensity=(3.0, 2.0, 1.0), penumbra=0.4)
    sc = fw.Scene(vertices=v, faces=f, face_albedo=np.tile(a, (2, 1)), lights=[light])
    cam = fw.Camera(eye=(0.0, 1.5, 2.5), target=(0, 0, 0), up=(0, 1, 0), fov_y_deg=50)
    w, h = 16, 12
    cfg = dataclasses.replace(LAMBERT, background=(0.0, 0.0, 0.0))
    img = passes(sc, cam, w, h, 1, 1, config=cfg, max_depth=2)[0]
    p, on = plane_hits(cam, w, h, 2.0)
    dl = np.asarray(light.position) - p
    r2 = (dl ** 2).sum(-1)
    wi = dl / np.sqrt(r2)[..., None]
    cos_i = np.clip(wi[..., 1], 0, None)
    att = np.ones_like(cos_i)
    if kind == "spot":
        c = (-wi * np.asarray(light.direction)).sum(-1)
        outer = math.radians(light.cone_deg)
        c0, c1 = math.cos(outer), math.cos(outer * (1 - light.penumbra))
        s = np.clip((c - c0) / (c1 - c0), 0, 1)
        att = s * s * (3 - 2 * s)
    ref = np.where(on[..., None], a / np.pi * np.asarray(light.intensity) * (att * cos_i / r2)[..., None], 0.0)
    assert on.sum() > 0.5 * on.size
    np.testing.assert_allclose(img, ref, rtol=2e-4, atol=1e-7)


def np_gltf_f(wo, wi, base, rough, spec):
    """glTF metallic-roughness f (metallic 0) in NumPy, local frame: GGX D, height-correlated Smith V, Schlick
    dielectric Fresnel Fd = s (0.04 + 0.96 (1 - wo.h)^5) on the lobe, (1 - Fd) base / pi diffuse."""
    alpha = max(rough * rough, 1e-3)
    h = wo + wi
    h /= np.linalg.norm(h, axis=-1, keepdims=True)
    a2 = alpha * alpha
    d = a2 / (np.pi * (h[..., 0] ** 2 + h[..., 1] ** 2 + a2 * h[..., 2] ** 2) ** 2)
    zo, zi = wo[..., 2], wi[..., 2]
    ao = np.sqrt(zo * zo + a2 * (1 - zo * zo))
    ai = np.sqrt(zi * zi + a2 * (1 - zi * zi))
    v = 0.5 / (zi * ao + zo * ai)
    fd = spec * (0.04 + 0.96 * (1.0 - np.clip((wo * h).sum(-1), 0, 1)) ** 5)
    return (d * v * fd)[..., None] + ((1.0 - fd) / np.pi)[..., None] * np.asarray(base)


def test_depth2_point_light_glossy():
    """Depth 2 with the Blinn-Phong stand-in lobe (specular 0.15, shininess 48: roughness 0.447, specularFactor 1)
    under a point light: f cos I / r^2 with f from the NumPy glTF BSDF at the pixel-centre hits."""
    a = np.array([0.3, 0.5, 0.7])
    v, f = quad_mesh((-2, 0, -2), (0, 0, 4), (4, 0, 0))
    light = fw.Light(position=(0.2, 0.7, -0.6), intensity=(2.0, 2.0, 2.0))
    sc = fw.Scene(vertices=v, faces=f, face_albedo=np.tile(a, (2, 1)), lights=[light])
    cam = fw.Camera(eye=(0.0, 1.2, 1.8), target=(0, 0, -0.4), up=(0, 1, 0), fov_y_deg=50)
    w, h = 16, 12
    cfg = fw.ShadingConfig(specular=0.15, shininess=48.0, background=(0.0, 0.0, 0.0))
    img = passes(sc, cam, w, h, 1, 1, config=cfg, max_depth=2)[0]
    p, on = plane_hits(cam, w, h, 2.0)
    dl = np.asarray(light.position) - p
    r2 = (dl ** 2).sum(-1)
    wi = dl / np.sqrt(r2)[..., None]
    wo = np.asarray(cam.eye) - p
    wo /= np.linalg.norm(wo, axis=-1, keepdims=True)
    # the plane's frame: z = +y; any tangent frame gives the same isotropic BSDF
    loc = lambda x: np.stack([x[..., 0], x[..., 2], x[..., 1]], axis=-1)  # noqa: E731
    fv = np_gltf_f(loc(wo), loc(wi), a, math.sqrt(math.sqrt(2.0 / 50.0)), 1.0)
    ref = np.where(on[..., None], fv * np.asarray(light.intensity) * (wi[..., 1] / r2)[..., None], 0.0)
    assert on.sum() > 0.5 * on.size
    # the highlight is in view: somewhere the lobe gives over 1.5 times the Lambert term alone
    lambert = a / np.pi * np.asarray(light.intensity) * (wi[..., 1] / r2)[..., None]
    assert (ref[on] / lambert[on]).max() > 1.5
    np.testing.assert_allclose(img, ref, rtol=1e-3, atol=1e-6)


def test_depth2_area_light():
    """Depth 2 under an area light over a plane: the light-sampled and BSDF-sampled estimates (MIS) against the
    irradiance integral (a / pi) Le int cos_i cos_l / r^2 dA by 48 x 48 Gauss-Legendre quadrature; no light
    seen directly."""
    a = np.array([0.6, 0.5, 0.4])
    v, f = quad_mesh((-2, 0, -2), (0, 0, 4), (4, 0, 0))
    light = fw.AreaLight(corner=(-0.5, 1.0, -0.4), edge_u=(0.9, 0.0, 0.0), edge_v=(0.0, 0.0, 0.6),
                         radiance=(4.0, 3.0, 2.0))
    assert np.cross(light.edge_u, light.edge_v)[1] < 0  # faces the plane
    sc = fw.Scene(vertices=v, faces=f, face_albedo=np.tile(a, (2, 1)), area_lights=[light])
    cam = fw.Camera(eye=(0.0, 0.8, 2.2), target=(0, 0, 0), up=(0, 1, 0), fov_y_deg=40)
    w, h = 16, 12
    cfg = dataclasses.replace(LAMBERT, background=(0.0, 0.0, 0.0))
    imgs = passes(sc, cam, w, h, 16, 16, config=cfg, max_depth=2)
    p, on = plane_hits(cam, w, h, 2.0)
    assert on.sum() > 0.5 * on.size
    x, wq = np.polynomial.legendre.leggauss(48)
    s = 0.5 * (x + 1)
    wq = 0.5 * wq
    c, eu, ev = (np.asarray(q, float) for q in (light.corner, light.edge_u, light.edge_v))
    area = np.linalg.norm(np.cross(eu, ev))
    nl = np.cross(eu, ev) / area
    q = c + s[:, None, None] * eu + s[None, :, None] * ev  # (48, 48, 3)
    irr = np.zeros(p.shape[:2])
    for i in range(48):
        dl = q[i][None, None] - p[:, :, None]  # (H, W, 48, 3)
        r2 = (dl ** 2).sum(-1)
        cos_i = np.clip(dl[..., 1], 0, None) / np.sqrt(r2)
        cos_l = np.clip(-(dl * nl).sum(-1), 0, None) / np.sqrt(r2)
        irr += (cos_i * cos_l / r2 * wq[i] * wq[None, None, :]).sum(-1) * area
    ref = a / np.pi * np.asarray(light.radiance) * irr[..., None]
    check_statistically(imgs, ref, on, 0.01)
    assert np.all(imgs[:, ~on] == 0.0)


# ---------------------------------------------------------------------------------------------------------------
# launches, clamp, determinism

def test_work_list_matches_full_frame():
    v, f = box_mesh((-1, -1, -1), (1, 1, 1))
    sc = fw.Scene(vertices=v, faces=f, face_albedo=np.full((12, 3), 0.6),
                  area_lights=[fw.AreaLight(corner=(-0.3, 0.95, -0.3), edge_u=(0.6, 0, 0), edge_v=(0, 0, 0.6))])
    cam = fw.Camera(eye=(0, 0, 0.8), target=(0, -0.2, -1), up=(0, 1, 0))
    w, h = 10, 7
    ds = DeviceScene(sc, device="cpu")
    stage = PathStage(ds, fw.ShadingConfig(integrator="path", spp=2, max_depth=4), w, h, "cpu")
    full = wp.zeros((h, w), dtype=wp.vec3, device="cpu")
    stage.run(cam, 3, full)
    idx = np.array([5, 0, 69, 33, 12, 40], np.int32)
    work = wp.array(np.concatenate([idx, [7, 8]]).astype(np.int32), dtype=wp.int32, device="cpu")
    count = wp.array([len(idx)], dtype=wp.int32, device="cpu")
    part = wp.full((h, w), value=wp.vec3(-1.0, -1.0, -1.0), dtype=wp.vec3, device="cpu")
    stage.run(cam, 3, part, work, count)
    fa, pa = full.numpy().reshape(-1, 3), part.numpy().reshape(-1, 3)
    np.testing.assert_array_equal(pa[idx], fa[idx])
    rest = np.setdiff1d(np.arange(w * h), idx)
    assert np.all(pa[rest] == -1.0)
    assert fa.max() > 0
    # another frame index is another estimate
    stage.run(cam, 4, part)
    assert not np.array_equal(part.numpy(), full.numpy())


def test_radiance_clamp_bounds_each_path():
    v, f = quad_mesh((-1, 0, -1), (0, 0, 2), (2, 0, 0))
    light = fw.Light(position=(0.0, 0.05, 0.0), intensity=(50.0, 50.0, 50.0))
    sc = fw.Scene(vertices=v, faces=f, face_albedo=np.full((2, 3), 0.8), lights=[light])
    cam = fw.Camera(eye=(0, 1.0, 1.5), target=(0, 0, 0), up=(0, 1, 0))
    free = passes(sc, cam, 12, 8, 1, 4, max_depth=3)[0]
    clamped = passes(sc, cam, 12, 8, 1, 4, max_depth=3, radiance_clamp=2.0)[0]
    assert free.max() > 2.0
    assert clamped.max() <= 2.0 * (1 + 1e-6)
    assert np.all(clamped <= free + 1e-6)


# ---------------------------------------------------------------------------------------------------------------
# degenerate scenes: no NaN, no Inf

@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    seed=st.integers(0, 2**31 - 1),
    albedo=st.sampled_from([0.0, 0.5, 1.0]),
    emission=st.sampled_from([0.0, 1.0, 1e30]),
    specular=st.sampled_from([0.0, 0.15, 1.0]),
    shininess=st.sampled_from([1.0, 48.0, 4096.0]),
    inside=st.booleans(),
    zero_area=st.booleans(),
    light_on_surface=st.booleans(),
    depth=st.integers(1, 6),
    degenerate_faces=st.booleans(),
)
def test_no_nan_or_inf(seed, albedo, emission, specular, shininess, inside, zero_area, light_on_surface, depth,
                       degenerate_faces):
    rng = np.random.default_rng(seed)
    v, f = box_mesh((-1, -1, -1), (1, 1, 1))
    if degenerate_faces:  # a zero-area emissive triangle and a sliver
        v = np.concatenate([v, [[0.2, 0.2, 0.2]] * 3, [[0, 0, 0], [1e-20, 0, 0], [0, 1e-20, 0]]])
        f = np.concatenate([f, [[8, 9, 10], [11, 12, 13]]])
    nf = len(f)
    em = np.zeros((nf, 3))
    em[rng.integers(0, nf, 3)] = emission
    lights = [fw.Light(kind="spot", position=(1.0, 0.0, 0.0) if light_on_surface else tuple(rng.uniform(-0.5, 0.5, 3)),
                       direction=(-1.0, 0.0, 0.0), cone_deg=float(rng.uniform(1, 180)), intensity=(2.0, 2.0, 2.0))]
    areas = [fw.AreaLight(corner=(-0.2, 0.9, -0.2), edge_u=(1e-20, 0, 0), edge_v=(0, 0, 1e-20)),
             fw.AreaLight(corner=(-0.2, -0.5, -0.2), edge_u=(0.4, 0, 0), edge_v=(0, 0, 0.4))]
    sc = fw.Scene(vertices=v, faces=f, face_albedo=np.full((nf, 3), albedo), face_emission=em, lights=lights,
                  area_lights=areas)
    eye = (0.0, 0.0, 0.5) if inside else (0.3, 0.4, 4.0)
    cam = fw.Camera(eye=eye, target=(0.0, 0.0, 0.0) if not inside else (0.0, -0.3, -1.0), up=(0, 1, 0))
    ds = DeviceScene(sc, device="cpu")
    if zero_area:  # an area light of exactly zero area, past the host's validation
        p = AreaLightParams()
        p.corner = wp.vec3(0.0, 0.0, 0.0)
        p.edge_u = wp.vec3(0.0, 0.0, 0.0)
        p.edge_v = wp.vec3(0.0, 0.0, 0.0)
        p.radiance = wp.vec3(1e30, 1e30, 1e30)
        ds.area_lights = wp.array([p, areas_params(areas[1])], dtype=AreaLightParams, device="cpu")
    cfg = fw.ShadingConfig(integrator="path", spp=2, max_depth=depth, rr_depth=1, seed=seed % 1000,
                           specular=specular, shininess=shininess)
    stage = PathStage(ds, cfg, 6, 4, "cpu")
    out = wp.zeros((4, 6), dtype=wp.vec3, device="cpu")
    stage.run(cam, seed % 7, out)
    img = out.numpy()
    assert np.all(np.isfinite(img)) and np.all(img >= 0.0)


def areas_params(a):
    p = AreaLightParams()
    p.corner = wp.vec3(*a.corner)
    p.edge_u = wp.vec3(*a.edge_u)
    p.edge_v = wp.vec3(*a.edge_v)
    p.radiance = wp.vec3(*a.radiance)
    return p


@pytest.mark.needs_cuda
def test_cpu_cuda_parity():
    """The same kernels on CUDA: the furnace's image mean agrees with the CPU's within the noise (different float
    rounding may take different Russian roulette branches)."""
    v, f = box_mesh((-1, -1, -1), (1, 1, 1))
    sc = fw.Scene(vertices=v, faces=f, face_albedo=np.full((12, 3), 0.5), face_emission=np.full((12, 3), 0.3))
    cam = fw.Camera(eye=(0.2, 0.1, 0.3), target=(-0.3, -0.2, -1.0), up=(0, 1, 0), fov_y_deg=70)
    imgs = {d: render_converged(sc, cam, 16, 12, 256, max_depth=30, device=d, shading=LAMBERT)
            for d in ("cpu", "cuda:0")}
    assert imgs["cuda:0"].mean() == pytest.approx(imgs["cpu"].mean(), rel=0.01)
    assert imgs["cpu"].mean() == pytest.approx(0.6, rel=0.01)

