"""The environment light (envmap.py, kernels/envmap.py) against float64 NumPy references written here: Mitsuba 3's
latitude-longitude mapping and bilinear lookup, the piecewise-constant importance distribution (pdf normalization
by quadrature and Monte Carlo, sample/pdf agreement, chi-square of sampled directions with a power check), the
irradiance of constant and varying maps, a single bright texel, degenerate maps and inputs; the lookup also
against Mitsuba 3's own ``envmap`` ``eval`` (scalar_rgb) when mitsuba is installed."""

import math

import numpy as np
import pytest
import warp as wp
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy import stats

from foveawarp.envmap import Environment, check_rotation
from foveawarp.kernels import envmap as ek

LUM = np.array([0.212671, 0.715160, 0.072169])
HYP = settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])

# ---------------------------------------------------------------------------------------------------------------
# reference (float64)


def ref_pad(a):
    """Mitsuba's Bitmap::pad_to(2, 3): at least 3 rows and 2 columns, the last row / column repeated."""
    a = np.asarray(a, np.float64)
    while a.shape[0] < 3:
        a = np.concatenate([a, a[-1:]], axis=0)
    while a.shape[1] < 2:
        a = np.concatenate([a, a[:, -1:]], axis=1)
    return a


def ref_local_uv(d):
    d = np.asarray(d, np.float64)
    d = d / np.linalg.norm(d, axis=-1, keepdims=True)
    u = np.arctan2(d[:, 0], -d[:, 2]) / (2 * np.pi)
    return u - np.floor(u), np.arccos(np.clip(d[:, 1], -1, 1)) / np.pi


def ref_uv_dir(u, v):
    phi, th = 2 * np.pi * np.asarray(u, np.float64), np.pi * np.asarray(v, np.float64)
    return np.stack([np.sin(phi) * np.sin(th), np.cos(th), -np.cos(phi) * np.sin(th)], axis=-1)


def ref_lookup_uv(img, u, v, scale=1.0):
    """Texel column i at u = (i + 0.5) / W (periodic), row j at v = j / (H - 1) (clamped), bilinear."""
    a = ref_pad(img)
    h, w = a.shape[:2]
    x = (u - np.floor(u)) * w - 0.5
    y = np.clip(v, 0, 1) * (h - 1)
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    ax, ay = (x - x0)[:, None], (y - y0)[:, None]
    i0, i1 = x0 % w, (x0 + 1) % w
    j0, j1 = np.clip(y0, 0, h - 1), np.clip(y0 + 1, 0, h - 1)
    return scale * ((1 - ay) * ((1 - ax) * a[j0, i0] + ax * a[j0, i1]) + ay * ((1 - ax) * a[j1, i0] + ax * a[j1, i1]))


def ref_eval(img, dirs, scale=1.0, to_world=np.eye(3)):
    local = np.asarray(dirs, np.float64) @ np.asarray(to_world)  # R^T d, row vectors
    u, v = ref_local_uv(local)
    return ref_lookup_uv(img, u, v, scale)


def ref_cells(img):
    """(cell pdf (B, W), cell solid angle (B, W), integral of luminance): cells between texel positions,
    weight = mean corner luminance, pdf = weight / sum(weight x solid angle); uniform 1 / (4 pi) for a black map."""
    a = ref_pad(img)
    lum = a @ LUM
    h, w = lum.shape
    b = h - 1
    cell = np.zeros((b, w))
    for j in range(b):
        for i in range(w):
            cell[j, i] = (lum[j, i] + lum[j, (i + 1) % w] + lum[j + 1, i] + lum[j + 1, (i + 1) % w]) / 4
    edges = np.cos(np.pi * np.arange(b + 1) / b)
    omega = np.repeat(((edges[:-1] - edges[1:]) * 2 * np.pi / w)[:, None], w, axis=1)
    total = float((cell * omega).sum())
    if total == 0:
        return np.full((b, w), 1 / (4 * np.pi)), omega, 0.0
    return cell / total, omega, total


def ref_cell_index(img, dirs, to_world=np.eye(3)):
    """(band j, column i, distance to the nearest cell edge in (u, v) units) of world directions."""
    a = ref_pad(img)
    h, w = a.shape[:2]
    b = h - 1
    u, v = ref_local_uv(np.asarray(dirs, np.float64) @ np.asarray(to_world))
    s = u * w - 0.5
    i = np.floor(s).astype(int) % w
    t = v * b
    j = np.minimum(np.floor(t).astype(int), b - 1)
    edge = np.minimum(np.minimum(s - np.floor(s), np.ceil(s) - s) / w, np.minimum(t - np.floor(t), np.ceil(t) - t) / b)
    return j, i, edge


def ref_pdf(img, dirs, to_world=np.eye(3)):
    pdf, _, _ = ref_cells(img)
    j, i, _ = ref_cell_index(img, dirs, to_world)
    return pdf[j, i]


def _rotation(rng):
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    if np.linalg.det(q) < 0:
        q[:, 0] *= -1
    return q


def _unit(rng, n):
    d = rng.normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def _sky(h, w):
    """A smooth map with a bright sun, colour varying with both angles."""
    v = (np.arange(h) / max(h - 1, 1))[:, None]
    u = ((np.arange(w) + 0.5) / w)[None, :]
    sun = 40.0 * np.exp(-(((u - 0.3) / 0.05) ** 2 + ((v - 0.3) / 0.08) ** 2))
    base = np.stack([0.2 + 0.8 * (1 - v) + 0 * u, 0.3 + 0.2 * np.cos(2 * np.pi * u) * (1 - v) + 0.5, 0.1 + v * u],
                    axis=-1)
    return (base + sun[..., None]).astype(np.float32)


@wp.kernel(enable_backward=False)
def _irradiance_kernel(env: ek.EnvironmentMap, normal: wp.vec3, seed: int, per_thread: int,
                       out: wp.array(dtype=wp.vec3)):
    # how a shading kernel uses the struct: draw directions, weight radiance x cosine by 1 / pdf
    tid = wp.tid()
    state = wp.rand_init(seed, tid)
    acc = wp.vec3(0.0, 0.0, 0.0)
    for _ in range(per_thread):
        d, radiance, pdf = ek.env_sample(env, wp.randf(state), wp.randf(state))
        c = wp.dot(d, normal)
        if c > 0.0 and pdf > 0.0:
            acc += radiance * (c / pdf)
    out[tid] = acc / float(per_thread)


def _irradiance(env, normal, device, threads=4096, per_thread=64, seed=3):
    out = wp.zeros(threads, dtype=wp.vec3, device=device)
    wp.launch(_irradiance_kernel, dim=threads, device=device,
              inputs=[env.to_device(device), wp.vec3(*normal), seed, per_thread], outputs=[out])
    est = out.numpy().astype(np.float64)  # per-thread means of per_thread samples each
    return est.mean(axis=0), est.std(axis=0, ddof=1) / math.sqrt(threads)


def _quadrature(fn, n_theta=1024, n_phi=2048):
    """Midpoint rule over the sphere of fn(directions (N, 3)) -> (N, C)."""
    th = (np.arange(n_theta) + 0.5) * np.pi / n_theta
    ph = (np.arange(n_phi) + 0.5) * 2 * np.pi / n_phi
    tt, pp = np.meshgrid(th, ph, indexing="ij")
    d = np.stack([np.sin(tt) * np.cos(pp), np.cos(tt), np.sin(tt) * np.sin(pp)], axis=-1).reshape(-1, 3)
    dw = (np.sin(tt) * (np.pi / n_theta) * (2 * np.pi / n_phi)).reshape(-1, 1)
    return (fn(d) * dw).sum(axis=0)


# ---------------------------------------------------------------------------------------------------------------
# mapping and lookup


@pytest.mark.parametrize("shape", [(5, 8), (1, 6), (7, 1), (2, 4), (1, 1), (3, 2)])
def test_lookup_matches_reference(device, rng, shape):
    img = rng.uniform(0.0, 5.0, shape + (3,)).astype(np.float32)
    r = _rotation(rng)
    env = Environment.from_array(img, scale=2.5, to_world=r)
    d = _unit(rng, 3000)
    np.testing.assert_allclose(env.eval(d, device=device), ref_eval(img, d, 2.5, r), rtol=2e-5, atol=1e-5)


def test_texel_positions(device):
    # texel (j, i) is read alone at u = (i + 0.5) / W, v = j / (H - 1): +Y is the top row, u = 0 is -Z
    h, w = 5, 8
    img = np.arange(h * w * 3, dtype=np.float32).reshape(h, w, 3)
    env = Environment.from_array(img)
    jj, ii = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
    d = ref_uv_dir(((ii + 0.5) / w).ravel(), (jj / (h - 1)).ravel())
    got = env.eval(d, device=device)
    interior = (jj.ravel() > 0) & (jj.ravel() < h - 1)
    np.testing.assert_allclose(got[interior], img.reshape(-1, 3)[interior], rtol=1e-5, atol=1e-4)
    # at the poles every u meets the same row: +Y reads row 0 (at u = 0.5: between columns 3 and 4)
    np.testing.assert_allclose(env.eval([[0, 1, 0]], device=device)[0], 0.5 * (img[0, 3] + img[0, 4]), rtol=1e-5)
    np.testing.assert_allclose(env.eval([[0, -1, 0]], device=device)[0], 0.5 * (img[-1, 3] + img[-1, 4]), rtol=1e-5)
    # -Z is u = 0: halfway between the last and the first column, on the middle row
    np.testing.assert_allclose(env.eval([[0, 0, -1]], device=device)[0], 0.5 * (img[2, 0] + img[2, -1]), rtol=1e-5)
    # +X is u = 0.25: column 1.5
    np.testing.assert_allclose(env.eval([[1, 0, 0]], device=device)[0], 0.5 * (img[2, 1] + img[2, 2]), rtol=1e-5)


def test_rotation_and_scale(device, rng):
    img = rng.uniform(0.0, 1.0, (6, 10, 3)).astype(np.float32)
    r = _rotation(rng)
    env = Environment.from_array(img, scale=3.0, to_world=r)
    plain = Environment.from_array(img)
    d = _unit(rng, 500)
    # the rotated map seen along R d is the plain map seen along d, times the scale
    np.testing.assert_allclose(env.eval(d @ r.T, device=device), 3.0 * plain.eval(d, device=device),
                               rtol=1e-4, atol=1e-5)
    # a 4x4 affine transform: the translation does not move directions
    t = np.eye(4)
    t[:3, :3] = r
    t[:3, 3] = (5.0, -2.0, 1.0)
    np.testing.assert_allclose(Environment.from_array(img, to_world=t).to_world, r, atol=1e-12)


def test_lookup_matches_mitsuba(rng):
    mi = pytest.importorskip("mitsuba")
    mi.set_variant("scalar_rgb")
    for shape in [(6, 10), (1, 5), (4, 1), (2, 3), (1, 1), (9, 16)]:
        img = rng.uniform(0.0, 4.0, shape + (3,)).astype(np.float32)
        r = _rotation(rng)
        t = np.eye(4)
        t[:3, :3] = r
        emitter = mi.load_dict({"type": "envmap", "bitmap": mi.Bitmap(img), "scale": 1.7,
                                "to_world": mi.ScalarTransform4f(t.tolist())})
        d = _unit(rng, 400)
        # the u = 0 seam (-Z) and +X; not the poles, where u (so the column blend) is undefined in both
        d[:4] = np.array([[0, 0, -1], [1, 0, 0], [0, 0.6, -0.8], [0, -0.8, -0.6]]) @ r.T
        ref = []
        for k in range(len(d)):
            si = mi.SurfaceInteraction3f()
            si.wi = mi.Vector3f(*(-d[k]))  # eval looks along -wi, the direction the ray travels
            ref.append(np.array(emitter.eval(si)))
        got = Environment.from_array(img, scale=1.7, to_world=r).eval(d, device="cpu")
        # both in float32; 2e-5 relative covers the rotations, atan2 and acos of the two
        np.testing.assert_allclose(got, np.array(ref), rtol=2e-5, atol=2e-5)


# ---------------------------------------------------------------------------------------------------------------
# the importance distribution


def test_cell_pdf_matches_reference(device, rng):
    img = _sky(9, 16)
    r = _rotation(rng)
    env = Environment.from_array(img, scale=4.0, to_world=r)
    d = _unit(rng, 20000)
    j, i, edge = ref_cell_index(img, d, r)
    ok = edge > 1e-4  # away from cell edges, where float32 rounding may pick the neighbour
    np.testing.assert_allclose(env.pdf(d[ok], device=device), ref_pdf(img, d[ok], r), rtol=1e-5)
    pdf, _, total = ref_cells(img)
    np.testing.assert_allclose(env.distribution.cell_pdf, pdf, rtol=1e-12)
    np.testing.assert_allclose(env.distribution.luminance_integral, total, rtol=1e-12)
    assert env.to_device(device).luminance_integral == pytest.approx(4.0 * total, rel=1e-6)


@pytest.mark.parametrize("shape", [(9, 16), (1, 7), (6, 1), (2, 5)])
def test_pdf_integrates_to_one(device, rng, shape):
    img = _sky(*shape) if min(shape) > 1 else rng.uniform(0.0, 3.0, shape + (3,)).astype(np.float32)
    env = Environment.from_array(img, to_world=_rotation(rng))
    # quadrature: the pdf on a fine latitude-longitude grid times each pixel's solid angle
    total = _quadrature(lambda d: env.pdf(d, device=device)[:, None].astype(np.float64), 512, 1024)[0]
    assert total == pytest.approx(1.0, abs=2e-3)
    # Monte Carlo over uniform directions: E[4 pi pdf] = 1, within 5 standard errors
    x = 4 * np.pi * env.pdf(_unit(rng, 200_000), device=device).astype(np.float64)
    assert abs(x.mean() - 1.0) < 5 * x.std() / math.sqrt(len(x))


@pytest.mark.parametrize("shape", [(9, 16), (1, 7), (6, 1), (1, 1)])
def test_sample_pdf_and_radiance_agree(device, rng, shape):
    img = _sky(*shape) if min(shape) > 1 else rng.uniform(0.5, 3.0, shape + (3,)).astype(np.float32)
    r = _rotation(rng)
    env = Environment.from_array(img, scale=1.5, to_world=r)
    u = rng.uniform(0.0, 1.0, (50_000, 2))
    d, radiance, pdf = env.sample(u, device=device)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=2e-6)
    assert (pdf > 0).all() and np.isfinite(pdf).all()
    # env_pdf of the sampled direction is the sample's pdf (same cell) except within float32 rounding of a cell
    # edge, where the neighbour's pdf may be read
    again = env.pdf(d, device=device)
    same = np.isclose(again, pdf, rtol=1e-6, atol=0)
    assert same.mean() > 0.999
    _, _, edge = ref_cell_index(img, d[~same], r)
    assert (edge < 1e-5).all()
    # the sample's pdf is the reference pdf of its cell, its radiance the lookup along it
    _, _, edge = ref_cell_index(img, d, r)
    ok = edge > 1e-5
    np.testing.assert_allclose(pdf[ok], ref_pdf(img, d[ok], r), rtol=1e-5)
    np.testing.assert_allclose(radiance, ref_eval(img, d, 1.5, r), rtol=1e-4, atol=1e-5)


def _chi2_pvalue(img, d, to_world, sub_probs):
    """Chi-square p-value of directions binned by cell x 2 sub-bands (at the cell's theta midpoint) x 2
    sub-columns, against expected counts from the reference cell probabilities times ``sub_probs(j)`` (the
    share of band j's solid angle above its theta midpoint)."""
    pdf, omega, _ = ref_cells(img)
    b, w = pdf.shape
    j, i, _ = ref_cell_index(img, d, to_world)
    u, v = ref_local_uv(np.asarray(d, np.float64) @ to_world)
    s = u * w - 0.5
    half_i = ((s - np.floor(s)) >= 0.5).astype(int)
    half_j = ((v * b - j) >= 0.5).astype(int)
    obs = np.zeros((b, w, 2, 2))
    np.add.at(obs, (j, i, half_j, half_i), 1)
    p_cell = pdf * omega
    top = np.array([sub_probs(k) for k in range(b)])[:, None]
    exp = np.zeros_like(obs)
    exp[:, :, 0, :] = (p_cell * top)[..., None] / 2
    exp[:, :, 1, :] = (p_cell * (1 - top))[..., None] / 2
    exp = exp.ravel() * len(d)
    obs = obs.ravel()
    big = exp >= 5
    o = np.append(obs[big], obs[~big].sum())
    e = np.append(exp[big], exp[~big].sum())
    if e[-1] == 0:
        o, e = o[:-1], e[:-1]
    assert obs[exp == 0].sum() == 0  # nothing where the pdf is zero
    return stats.chisquare(o, e).pvalue


def test_chi2_sampled_directions_follow_pdf(device, rng):
    img = _sky(7, 12)
    r = _rotation(rng)
    env = Environment.from_array(img, to_world=r)
    d, _, _ = env.sample(rng.uniform(0.0, 1.0, (400_000, 2)), device=device)
    b = 6
    c = np.cos(np.pi * np.arange(b + 1) / b)
    cm = np.cos(np.pi * (np.arange(b) + 0.5) / b)

    def uniform_solid_angle(k):  # inside a band the directions are uniform in cos(theta)
        return (c[k] - cm[k]) / (c[k] - c[k + 1])

    assert _chi2_pvalue(img, d, r, uniform_solid_angle) > 1e-3
    # power: the same samples reject a within-band distribution uniform in theta
    assert _chi2_pvalue(img, d, r, lambda k: 0.5) < 1e-6


def test_constant_map_irradiance(device):
    env = Environment.constant((0.5, 1.0, 2.0), scale=2.0)
    # a constant map is sampled uniformly over the sphere
    d, radiance, pdf = env.sample(np.random.default_rng(1).uniform(size=(1000, 2)), device=device)
    np.testing.assert_allclose(pdf, 1 / (4 * np.pi), rtol=1e-6)
    np.testing.assert_allclose(radiance, np.tile([1.0, 2.0, 4.0], (1000, 1)), rtol=1e-6)
    mean, se = _irradiance(env, (0.0, 1.0, 0.0), device)
    expect = np.pi * np.array([1.0, 2.0, 4.0])
    assert (np.abs(mean - expect) < 5 * se).all(), (mean, expect, se)
    assert (se < 0.01 * expect).all()  # the bound is tight enough to mean something
    # any normal: the same irradiance
    mean, se = _irradiance(env, (0.6, 0.0, -0.8), device, seed=11)
    assert (np.abs(mean - expect) < 5 * se).all()


def test_varying_map_irradiance_matches_quadrature(device, rng):
    img = _sky(17, 32)
    r = _rotation(rng)
    env = Environment.from_array(img, scale=0.5, to_world=r)
    for normal in ((0.0, 1.0, 0.0), tuple(_unit(rng, 1)[0])):
        n = np.asarray(normal)
        expect = _quadrature(lambda d: ref_eval(img, d, 0.5, r) * np.maximum(d @ n, 0.0)[:, None], 512, 1024)
        mean, se = _irradiance(env, normal, device, seed=5)
        assert (np.abs(mean - expect) < 5 * se + 1e-3 * expect).all(), (mean, expect, se)
        assert (se < 0.01 * expect).all()


def test_bright_texel_is_sampled_there(device, rng):
    h, w = 8, 16
    img = np.zeros((h, w, 3), np.float32)
    img[3, 5] = (1000.0, 800.0, 1200.0)
    env = Environment.from_array(img)
    d, radiance, pdf = env.sample(rng.uniform(size=(20_000, 2)), device=device)
    u, v = ref_local_uv(d)
    # the texel's bilinear support: u within a texel of its centre (i + 0.5) / W, v within a row of j / (H - 1)
    assert (np.abs(u - 5.5 / w) <= 1.0 / w + 1e-6).all()
    assert (np.abs(v - 3.0 / (h - 1)) <= 1.0 / (h - 1) + 1e-6).all()
    assert (radiance.sum(axis=1) > 0).mean() > 0.999
    # only the four cells with the texel as a corner have a pdf, the same in each (equal corner means)
    pdf_ref, _, _ = ref_cells(img)
    assert {tuple(x) for x in np.argwhere(pdf_ref > 0)} == {(2, 4), (2, 5), (3, 4), (3, 5)}
    np.testing.assert_allclose(pdf_ref[pdf_ref > 0], pdf_ref[2, 4], rtol=1e-12)
    # the importance-sampled estimate of the integral of the radiance over the sphere, within 5 standard errors
    integral = _quadrature(lambda dd: ref_eval(img, dd))
    x = radiance.astype(np.float64) / pdf[:, None]
    assert (np.abs(x.mean(axis=0) - integral) < 5 * x.std(axis=0) / math.sqrt(len(x)) + 1e-3 * integral).all()
    # directions away from it have pdf 0
    far = ref_uv_dir([0.9, 0.1], [0.9, 0.05])
    np.testing.assert_array_equal(env.pdf(far, device=device), 0.0)


def test_zero_map(device, rng):
    env = Environment.from_array(np.zeros((4, 8, 3), np.float32))
    assert env.is_black and env.distribution.luminance_integral == 0.0
    assert env.to_device(device).luminance_integral == 0.0
    d, radiance, pdf = env.sample(rng.uniform(size=(4000, 2)), device=device)
    np.testing.assert_array_equal(radiance, 0.0)
    np.testing.assert_allclose(pdf, 1 / (4 * np.pi), rtol=1e-6)  # uniform over the sphere
    np.testing.assert_allclose(env.pdf(_unit(rng, 100), device=device), 1 / (4 * np.pi), rtol=1e-6)
    assert abs(d.mean(axis=0)).max() < 0.05
    assert Environment.constant((1, 1, 1), scale=0.0).is_black


@pytest.mark.parametrize("shape", [(1, 9), (9, 1)])
def test_one_row_and_one_column_maps(device, rng, shape):
    img = rng.uniform(0.1, 2.0, shape + (3,)).astype(np.float32)
    env = Environment.from_array(img)
    assert (env.height, env.width) == (max(shape[0], 3), max(shape[1], 2))
    d = _unit(rng, 500)
    got = env.eval(d, device=device)
    u, v = ref_local_uv(d)
    if shape[0] == 1:  # one row: constant in v, bilinear in u
        np.testing.assert_allclose(got, ref_lookup_uv(img, u, np.zeros_like(v)), rtol=2e-5)
    else:  # one column: constant in u
        np.testing.assert_allclose(got, ref_lookup_uv(img, np.zeros_like(u), v), rtol=2e-5)
    _, _, pdf = env.sample(rng.uniform(size=(1000, 2)), device=device)
    assert (pdf > 0).all()


def test_from_file(tmp_path, device):
    # a 3 x 4 flat Radiance file: mantissas (10 k, 20, 30) with exponent byte 129 -> (m + 0.5) / 128
    px = np.zeros((3, 4, 4), np.uint8)
    px[..., 0] = (np.arange(12) * 10 + 10).reshape(3, 4)
    px[..., 1], px[..., 2], px[..., 3] = 20, 30, 129
    (tmp_path / "sky.hdr").write_bytes(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 3 +X 4\n" + px.tobytes())
    env = Environment.from_file(tmp_path / "sky.hdr", scale=2.0)
    expect = (px[..., :3].astype(np.float64) + 0.5) / 128
    np.testing.assert_allclose(env.radiance, expect, rtol=1e-7)
    d = ref_uv_dir([1.5 / 4], [0.5])  # column 1, row 1 (the middle row)
    np.testing.assert_allclose(env.eval(d, device=device)[0], 2.0 * expect[1, 1], rtol=1e-5)
    with pytest.raises(ValueError, match=r"nothere\.hdr.*not found"):
        Environment.from_file(tmp_path / "nothere.hdr")
    with pytest.raises(ValueError, match=r"sky\.png.*extension must be one of"):
        Environment.from_file(tmp_path / "sky.png")


def test_bad_input():
    good = np.ones((4, 8, 3), np.float32)
    for value, what in ((np.nan, "NaN"), (np.inf, "Inf"), (-0.5, "negative")):
        bad = good.copy()
        bad[2, 5, 1] = value
        with pytest.raises(ValueError, match=rf"radiance must hold finite radiance values >= 0, got 1 {what} "
                                             rf"value.*\(2, 5, 1\)"):
            Environment.from_array(bad)
    with pytest.raises(ValueError, match=r"\(H, W, 3\) array .* got shape \(4, 8\)"):
        Environment.from_array(np.ones((4, 8)))
    with pytest.raises(ValueError, match=r"got shape \(0, 8, 3\)"):
        Environment.from_array(np.ones((0, 8, 3)))
    with pytest.raises(ValueError, match="scale must be"):
        Environment.from_array(good, scale=-1.0)
    with pytest.raises(ValueError, match="scale must be"):
        Environment.from_array(good, scale=float("nan"))
    with pytest.raises(ValueError, match="to_world must be a rotation"):
        Environment.from_array(good, to_world=np.diag([1.0, 1.0, -1.0]))  # a reflection
    with pytest.raises(ValueError, match="to_world must be a rotation"):
        Environment.from_array(good, to_world=2.0 * np.eye(3))
    with pytest.raises(ValueError, match="to_world must be a finite 3x3"):
        Environment.from_array(good, to_world=np.eye(2))
    with pytest.raises(ValueError, match="last row 0, 0, 0, 1"):
        Environment.from_array(good, to_world=np.ones((4, 4)))
    with pytest.raises(ValueError, match="rgb must be 3 numbers"):
        Environment.constant((1.0, 2.0))
    with pytest.raises(ValueError, match=r"u must be an \(N, 2\)"):
        Environment.constant((1, 1, 1)).sample(np.zeros(3))
    with pytest.raises(ValueError, match=r"directions must be an \(N, 3\)"):
        Environment.constant((1, 1, 1)).eval(np.zeros((2, 2)))
    # a near-rotation (float32 round-off) is accepted and re-orthonormalized
    r = check_rotation("m", np.eye(3) + 1e-6)
    np.testing.assert_allclose(r.T @ r, np.eye(3), atol=1e-12)


# ---------------------------------------------------------------------------------------------------------------
# degenerate inputs (hypothesis)

_f = st.one_of(st.floats(allow_nan=True, allow_infinity=True, width=32),
               st.sampled_from([0.0, 1.0, 0.99999994, -0.0, np.nan, np.inf, -np.inf, 1e30]))


@HYP
@given(u=st.lists(st.tuples(_f, _f), min_size=1, max_size=8), dirs=st.lists(st.tuples(_f, _f, _f), min_size=1,
                                                                             max_size=8))
def test_any_numbers_give_finite_results(device, u, dirs):
    img = np.zeros((5, 6, 3), np.float32)
    img[1, 2] = 7.0
    img[4, :] = 0.5
    env = Environment.from_array(img, scale=2.0)
    d, radiance, pdf = env.sample(np.asarray(u, np.float32), device=device)
    assert np.isfinite(d).all() and np.isfinite(radiance).all() and np.isfinite(pdf).all()
    assert (pdf > 0).all()  # a sample always lands in a cell of positive probability
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=2e-6)
    dd = np.asarray(dirs, np.float32)
    for out in (env.eval(dd, device=device), env.pdf(dd, device=device)):
        assert np.isfinite(out).all() and (out >= 0).all()
    n = np.linalg.norm(dd.astype(np.float64), axis=1)
    invalid = ~np.isfinite(n) | (n == 0)
    np.testing.assert_array_equal(env.pdf(dd[invalid], device=device), 0.0)


@HYP
@given(h=st.integers(1, 6), w=st.integers(1, 6), seed=st.integers(0, 2**31 - 1),
       zeros=st.floats(0.0, 1.0))
def test_random_small_maps_are_normalized_and_consistent(device, h, w, seed, zeros):
    rng = np.random.default_rng(seed)
    img = rng.uniform(0.0, 10.0, (h, w, 3)) * (rng.uniform(size=(h, w, 1)) >= zeros)
    env = Environment.from_array(img.astype(np.float32), to_world=_rotation(rng))
    dist = env.distribution
    assert (dist.cell_pdf * dist.cell_solid_angle).sum() == pytest.approx(1.0, abs=1e-12)
    assert dist.cell_solid_angle.sum() == pytest.approx(4 * np.pi, rel=1e-12)
    # the device's pdf at each cell's centre direction, times the cell's solid angle, sums to 1
    b, ww = dist.cell_pdf.shape
    jj, ii = np.meshgrid(np.arange(b), np.arange(ww), indexing="ij")
    c0, c1 = np.cos(np.pi * jj / b), np.cos(np.pi * (jj + 1) / b)
    v = np.arccos(0.5 * (c0 + c1)) / np.pi
    centres = ref_uv_dir(((ii + 1.0) / ww).ravel(), v.ravel()) @ env.to_world.T
    got = env.pdf(centres, device=device)
    np.testing.assert_allclose(got, dist.cell_pdf.ravel(), rtol=1e-5)
    assert (got * dist.cell_solid_angle.ravel()).sum() == pytest.approx(1.0, rel=1e-5)
    d, _, pdf = env.sample(rng.uniform(size=(256, 2)), device=device)
    assert (pdf > 0).all()
    assert np.mean(np.isclose(env.pdf(d, device=device), pdf, rtol=1e-6)) > 0.98
