"""Texture sampling (textures.py, kernels/texture.py) against an independent float64 NumPy reference: the mip chain
(area-weighted box filter as an overlap matrix), nearest / bilinear / trilinear lookups with repeat, clamp and
mirror wrap (OpenGL's MIRRORED_REPEAT index formula), glTF's UV origin, the ray-cone LOD formula, and degenerate
inputs (hypothesis)."""

import io
import math

import numpy as np
import pytest
import warp as wp
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from PIL import Image

from foveawarp.io.images import load_image
from foveawarp.kernels import texture as tk
from foveawarp.materials import ImageSource, Material, MaterialTable, TextureRef
from foveawarp.textures import (TextureSampler, TextureSet, build_mip_chain, footprint_spread_angle_rad,
                                mip_level_count, pixel_spread_angle_rad)

WRAPS = ("repeat", "clamp", "mirror")
# float32 lookups against the float64 reference: texel values are in [0, 1] and the bilinear weights carry a
# float32 rounding of the coordinate times the level width (<= 16 texels here)
ATOL = 1e-5
HYP = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])

# ---------------------------------------------------------------------------------------------------------------
# reference (float64)


def ref_box_matrix(n: int, m: int) -> np.ndarray:
    """(m, n) weights of the area-weighted box filter from n texels to m: output texel j covers the parent
    interval [j n / m, (j + 1) n / m) and weighs each parent texel by the length of their overlap."""
    w = np.zeros((m, n))
    for j in range(m):
        lo, hi = j * n / m, (j + 1) * n / m
        for i in range(n):
            w[j, i] = max(0.0, min(hi, i + 1) - max(lo, i))
    return w / w.sum(axis=1, keepdims=True)


def ref_mip_chain(img):
    img = np.asarray(img, np.float64)
    h, w = img.shape[:2]
    levels = [img]
    k = 1
    while max(h >> (k - 1), w >> (k - 1)) > 1:
        nh, nw = max(1, h >> k), max(1, w >> k)
        prev = levels[-1]
        fy = ref_box_matrix(prev.shape[0], nh)
        fx = ref_box_matrix(prev.shape[1], nw)
        levels.append(np.einsum("ja,abc,ib->jic", fy, prev, fx))
        k += 1
    return levels


def ref_wrap(i, n, mode):
    """Texel index i (integers) of an axis of n texels: GL_REPEAT, GL_CLAMP_TO_EDGE, GL_MIRRORED_REPEAT
    (``(n - 1) - mirror((i mod 2n) - n)`` with ``mirror(a) = a`` for a >= 0, ``-(1 + a)`` below)."""
    i = np.asarray(i, np.int64)
    if mode == "repeat":
        return np.mod(i, n)
    if mode == "clamp":
        return np.clip(i, 0, n - 1)
    a = np.mod(i, 2 * n) - n
    return (n - 1) - np.where(a >= 0, a, -(1 + a))


def ref_nearest(img, uv, ws, wt):
    """The texel covering uv: the coordinate reflected / repeated / clamped into [0, 1] first."""
    img = np.asarray(img, np.float64)
    h, w = img.shape[:2]

    def fold(u, mode):
        if mode == "repeat":
            return u - np.floor(u)
        if mode == "clamp":
            return np.clip(u, 0.0, 1.0)
        r = np.mod(u, 2.0)
        return np.where(r > 1.0, 2.0 - r, r)

    u = fold(np.asarray(uv[:, 0], np.float64), ws)
    v = fold(np.asarray(uv[:, 1], np.float64), wt)
    ix = np.minimum(np.floor(u * w).astype(np.int64), w - 1)
    iy = np.minimum(np.floor(v * h).astype(np.int64), h - 1)
    return img[iy, ix]


def ref_bilinear(img, uv, ws, wt):
    """Weights of the four texel centres around uv (centres at (i + 0.5) / w), taps wrapped per axis."""
    img = np.asarray(img, np.float64)
    h, w = img.shape[:2]
    x = np.asarray(uv[:, 0], np.float64) * w - 0.5
    y = np.asarray(uv[:, 1], np.float64) * h - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    ax, ay = (x - x0)[:, None], (y - y0)[:, None]
    i0, i1 = ref_wrap(x0, w, ws), ref_wrap(x0 + 1, w, ws)
    j0, j1 = ref_wrap(y0, h, wt), ref_wrap(y0 + 1, h, wt)
    return ((1 - ay) * ((1 - ax) * img[j0, i0] + ax * img[j0, i1])
            + ay * ((1 - ax) * img[j1, i0] + ax * img[j1, i1]))


def ref_trilinear(chain, uv, lod, ws, wt):
    lam = np.clip(np.nan_to_num(np.asarray(lod, np.float64), nan=0.0), 0.0, len(chain) - 1)
    out = np.zeros((len(uv), chain[0].shape[2]))
    for k in range(len(uv)):
        l0 = int(np.floor(lam[k]))
        t = lam[k] - l0
        c = ref_bilinear(chain[l0], uv[k:k + 1], ws, wt)[0]
        if t > 0 and l0 + 1 < len(chain):
            c = (1 - t) * c + t * ref_bilinear(chain[l0 + 1], uv[k:k + 1], ws, wt)[0]
        out[k] = c
    return out


def ref_ray_cone_lod(p, t, w, h, dist, alpha, n, d, num_levels, clamp=True):
    """lambda = 0.5 log2(w h |t-area| / |p-area|) + log2(2 dist tan(alpha / 2) / |n.d|) (Akenine-Moller et al.
    2019, with the exact cone width), |n.d| floored at 1e-6, clamped to [0, num_levels - 1]."""
    p = np.asarray(p, np.float64)
    t = np.asarray(t, np.float64)
    ta = np.abs((t[:, 1, 0] - t[:, 0, 0]) * (t[:, 2, 1] - t[:, 0, 1])
                - (t[:, 1, 1] - t[:, 0, 1]) * (t[:, 2, 0] - t[:, 0, 0]))
    pa = np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    delta = 0.5 * np.log2(np.asarray(w, np.float64) * h * ta / pa)
    width = 2.0 * np.asarray(dist, np.float64) * np.tan(0.5 * np.asarray(alpha, np.float64))
    n = np.asarray(n, np.float64)
    d = np.asarray(d, np.float64)
    cos = np.abs(np.sum(n * d, axis=1)) / (np.linalg.norm(n, axis=1) * np.linalg.norm(d, axis=1))
    lam = delta + np.log2(width / np.maximum(cos, 1e-6))
    if clamp:
        lam = np.clip(lam, 0.0, np.asarray(num_levels) - 1)
    return delta, lam


# ---------------------------------------------------------------------------------------------------------------
# helpers


def _set(images, wraps=("repeat", "repeat"), filt="linear", device="cpu"):
    if not isinstance(images, list):
        images = [images]
    samplers = [TextureSampler(i, wraps[0], wraps[1], filt) for i in range(len(images))]
    return TextureSet(images, samplers, device=device)


def _png(codes):
    buf = io.BytesIO()
    Image.fromarray(np.asarray(codes, np.uint8)).save(buf, format="PNG")
    return buf.getvalue()


def _srgb_eotf(code):
    x = np.asarray(code, np.float64) / 255.0
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)


def _centres_uv(rng, w, h, n, jitter=0.4, periods=1000):
    """UVs at texel centres of a w x h level, moved up to ``jitter`` texel off centre and by whole periods
    (positive and negative, up to ``periods``) so that none falls within 0.1 texel of a texel edge."""
    i = rng.integers(0, w, n)
    j = rng.integers(0, h, n)
    du = rng.uniform(-jitter, jitter, n)
    dv = rng.uniform(-jitter, jitter, n)
    ku = rng.integers(-periods, periods + 1, n)
    kv = rng.integers(-periods, periods + 1, n)
    return np.stack([(i + 0.5 + du) / w + ku, (j + 0.5 + dv) / h + kv], axis=1).astype(np.float32)


@wp.kernel(enable_backward=False)
def _hit_kernel(atlas: tk.TextureAtlas, tex: wp.array(dtype=wp.int32), p: wp.array2d(dtype=wp.vec3),
                t: wp.array2d(dtype=wp.vec2), uv: wp.array(dtype=wp.vec2), dist: wp.array(dtype=float),
                fov_y_rad: float, height_px: int, footprint_px: wp.array(dtype=float),
                normal: wp.array(dtype=wp.vec3), direction: wp.array(dtype=wp.vec3), lod_mode: int,
                out: wp.array(dtype=wp.vec4), lod_out: wp.array(dtype=float), spread_out: wp.array(dtype=float)):
    # the shading path of one hit: triangle Delta, a sparse sample's widened cone, the texture's LOD and lookup
    i = wp.tid()
    delta = tk.triangle_uv_lod_delta(p[i, 0], p[i, 1], p[i, 2], t[i, 0], t[i, 1], t[i, 2])
    alpha = tk.footprint_spread_angle(tk.pixel_spread_angle(fov_y_rad, height_px), footprint_px[i])
    fp = tk.cone_footprint_log2(tk.cone_width(dist[i], alpha), normal[i], direction[i])
    spread_out[i] = alpha
    lod_out[i] = tk.texture_ray_cone_lod(atlas, tex[i], delta, fp)
    out[i] = tk.sample_texture(atlas, tex[i], uv[i], lod_mode, delta, fp)


@wp.kernel(enable_backward=False)
def _cone_funcs_kernel(fov: wp.array(dtype=float), height: wp.array(dtype=int), fp_px: wp.array(dtype=float),
                       dist: wp.array(dtype=float), pixel_out: wp.array(dtype=float),
                       spread_out: wp.array(dtype=float), width_out: wp.array(dtype=float)):
    i = wp.tid()
    a = tk.pixel_spread_angle(fov[i], height[i])
    s = tk.footprint_spread_angle(a, fp_px[i])
    pixel_out[i] = a
    spread_out[i] = s
    width_out[i] = tk.cone_width(dist[i], s)


def _ray_cone(device, p, t, w, h, dist, alpha, n, d, levels):
    m = len(dist)
    f = np.float32
    delta = wp.zeros(m, dtype=float, device=device)
    lod = wp.zeros(m, dtype=float, device=device)
    wp.launch(tk.ray_cone_lod_kernel, dim=m, device=device,
              inputs=[wp.array(np.asarray(p, f), dtype=wp.vec3, device=device),
                      wp.array(np.asarray(t, f), dtype=wp.vec2, device=device),
                      wp.array(np.broadcast_to(np.asarray(w, np.int32), (m,)).copy(), dtype=int, device=device),
                      wp.array(np.broadcast_to(np.asarray(h, np.int32), (m,)).copy(), dtype=int, device=device),
                      wp.array(np.asarray(dist, f), dtype=float, device=device),
                      wp.array(np.asarray(alpha, f), dtype=float, device=device),
                      wp.array(np.asarray(n, f), dtype=wp.vec3, device=device),
                      wp.array(np.asarray(d, f), dtype=wp.vec3, device=device),
                      wp.array(np.broadcast_to(np.asarray(levels, np.int32), (m,)).copy(), dtype=int, device=device)],
              outputs=[delta, lod])
    return delta.numpy(), lod.numpy()


# ---------------------------------------------------------------------------------------------------------------
# mip chain


@pytest.mark.parametrize("shape", [(8, 8), (4, 16), (5, 7), (1, 9), (13, 1), (3, 3), (1, 1), (6, 11)])
def test_mip_chain_matches_box_filter(rng, shape):
    img = rng.uniform(0.0, 1.0, shape + (4,)).astype(np.float32)
    chain = build_mip_chain(img)
    ref = ref_mip_chain(img)
    assert len(chain) == len(ref) == mip_level_count(shape[1], shape[0])
    for k, (a, b) in enumerate(zip(chain, ref)):
        assert a.shape == (max(1, shape[0] >> k), max(1, shape[1] >> k), 4)
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-6)
        # the area-weighted filter keeps the mean of level 0 on every level
        np.testing.assert_allclose(a.mean(axis=(0, 1)), img.astype(np.float64).mean(axis=(0, 1)), atol=1e-6)
    assert chain[-1].shape[:2] == (1, 1)


def test_power_of_two_level_is_mean_of_blocks(rng):
    img = rng.uniform(0.0, 1.0, (8, 4, 4)).astype(np.float32)
    chain = build_mip_chain(img)
    blocks = img.astype(np.float64).reshape(4, 2, 2, 2, 4).mean(axis=(1, 3))
    np.testing.assert_allclose(chain[1], blocks, atol=1e-7)
    np.testing.assert_allclose(chain[3][0, 0], img.mean(axis=(0, 1)), atol=1e-6)  # 8 x 4 -> 4 x 2 -> 2 x 1 -> 1 x 1
    assert len(build_mip_chain(img, num_levels=2)) == 2
    with pytest.raises(ValueError, match="num_levels must be"):
        build_mip_chain(img, num_levels=5)
    with pytest.raises(ValueError, match=r"\(H, W, C\) array"):
        build_mip_chain(np.zeros((4, 4)))


def test_srgb_decoded_before_the_chain(device):
    # a 2 x 2 sRGB checker of codes 30 and 220 through the material path (load_image with srgb=True)
    codes = np.array([[[30] * 3, [220] * 3], [[220] * 3, [30] * 3]])
    table = MaterialTable.build([Material(base_color_texture=TextureRef(0, color_space="srgb"),
                                          metallic_roughness_texture=TextureRef(0, color_space="linear"))])
    ts = TextureSet.from_materials(table, [ImageSource("checker", data=_png(codes), mime_type="image/png")],
                                   device=device)
    assert ts.num_textures == 2 and ts.num_levels == (2, 2)
    lin_mean = 0.5 * (_srgb_eotf(30) + _srgb_eotf(220))
    np.testing.assert_allclose(ts.level(0, 1)[0, 0, :3], lin_mean, rtol=1e-6)
    assert abs(lin_mean - _srgb_eotf(125)) > 0.1  # the mean of the codes would be a different colour
    np.testing.assert_allclose(ts.level(0, 0)[0, 1, :3], _srgb_eotf(220), rtol=1e-6)
    # the data texture of the same image keeps the codes / 255
    np.testing.assert_allclose(ts.level(1, 1)[0, 0, :3], 125 / 255.0, rtol=1e-6)
    # the device's 1 x 1 level read back by a lookup at any UV and an LOD past the chain
    got = ts.sample(0, [[0.3, 0.8]], lod=5.0)
    np.testing.assert_allclose(got[0, :3], lin_mean, rtol=1e-6)


# ---------------------------------------------------------------------------------------------------------------
# lookups


def test_uv_origin_is_top_left(device, tmp_path):
    # 4 x 2 image: red top-left, green top-right, blue bottom-left, and distinct greys elsewhere
    codes = np.zeros((2, 4, 3), np.uint8)
    codes[0, 0] = (255, 0, 0)
    codes[0, 3] = (0, 255, 0)
    codes[1, 0] = (0, 0, 255)
    codes[0, 1], codes[0, 2], codes[1, 1], codes[1, 2], codes[1, 3] = [(k * 40,) * 3 for k in range(1, 6)]
    (tmp_path / "t.png").write_bytes(_png(codes))
    img = load_image(tmp_path / "t.png", srgb=False)
    ts = _set(img, filt="nearest", device=device)
    uv = [[0.05, 0.1], [0.95, 0.2], [0.1, 0.9], [0.3, 0.3], [0.6, 0.7], [0.9, 0.9]]
    got = ts.sample(0, uv)
    expect = codes[[0, 0, 1, 0, 1, 1], [0, 3, 0, 1, 2, 3]] / 255.0
    np.testing.assert_allclose(got[:, :3], expect, atol=1e-7)
    # bilinear at a texel centre reads that texel alone
    lin = _set(img, device=device).sample(0, [[0.125, 0.25], [0.875, 0.25], [0.125, 0.75]])
    np.testing.assert_allclose(lin[:, :3], [[1, 0, 0], [0, 1, 0], [0, 0, 1]], atol=1e-6)


@wp.kernel(enable_backward=False)
def _wrap_kernel(i: wp.array(dtype=wp.int32), n: int, mode: int, out: wp.array(dtype=wp.int32)):
    k = wp.tid()
    out[k] = tk.wrap_texel(i[k], n, mode)


@pytest.mark.parametrize("mode", WRAPS)
@pytest.mark.parametrize("n", [1, 2, 7, 16])
def test_wrap_texel_every_index(device, mode, n):
    """Every index within ten periods either side and indices near the int32 limits, against OpenGL's formulas."""
    i = np.concatenate([np.arange(-10 * n - 3, 10 * n + 4), [-(2 ** 31), -(2 ** 31) + 1, 2 ** 31 - 1, 2 ** 31 - 2]])
    i = i.astype(np.int32)
    out = wp.zeros(len(i), dtype=wp.int32, device=device)
    wp.launch(_wrap_kernel, dim=len(i), inputs=[wp.array(i, dtype=wp.int32, device=device), n,
                                                WRAPS.index(mode), out], device=device)
    np.testing.assert_array_equal(out.numpy(), ref_wrap(i, n, mode))


@pytest.mark.parametrize("ws", WRAPS)
@pytest.mark.parametrize("wt", WRAPS)
def test_nearest_with_wrap_far_outside(device, rng, ws, wt):
    img = rng.uniform(0.0, 1.0, (5, 7, 4)).astype(np.float32)
    uv = _centres_uv(rng, 7, 5, 400, periods=300)
    if "clamp" in (ws, wt):  # clamp: add UVs beyond the edges (no texel boundary there)
        far = rng.uniform(-300.0, 300.0, (200, 2)).astype(np.float32)
        far = far[(np.abs(far) > 1.5).all(axis=1)]
        uv = np.concatenate([uv, far])
    got = _set(img, (ws, wt), "nearest", device).sample(0, uv)
    np.testing.assert_allclose(got, ref_nearest(img, uv, ws, wt), rtol=0, atol=0)


@pytest.mark.parametrize("ws", WRAPS)
@pytest.mark.parametrize("wt", WRAPS)
def test_bilinear_with_wrap_far_outside(device, rng, ws, wt):
    img = rng.uniform(0.0, 1.0, (6, 9, 4)).astype(np.float32)
    k = rng.integers(-100, 101, (600, 2))
    uv = (rng.uniform(0.0, 1.0, (600, 2)) + k).astype(np.float32)
    uv[:8] = [[0, 0], [1, 1], [-1, -1], [0.5 / 9, 0.5 / 6], [-0.01, 1.01], [1.02, -0.03], [2.0, -3.0], [0.999, 0.001]]
    got = _set(img, (ws, wt), "linear", device).sample(0, uv)
    np.testing.assert_allclose(got, ref_bilinear(img, uv, ws, wt), rtol=0, atol=ATOL)
    # the filter override reads the same
    got2 = _set(img, (ws, wt), "nearest", device).sample(0, uv, filter="bilinear")
    np.testing.assert_allclose(got2, got, rtol=0, atol=1e-7)


def test_mirror_and_repeat_differ_where_they_should(device):
    # one row 0, 1, 2, 3: repeat at u in [1, 2) reads 0..3 again, mirror reads 3..0
    img = np.arange(4, dtype=np.float32).reshape(1, 4, 1)
    uv = np.array([[1.0 + (i + 0.5) / 4, 0.5] for i in range(4)], np.float32)
    rep = _set(img, ("repeat", "repeat"), "nearest", device).sample(0, uv)[:, 0]
    mir = _set(img, ("mirror", "repeat"), "nearest", device).sample(0, uv)[:, 0]
    clp = _set(img, ("clamp", "repeat"), "nearest", device).sample(0, uv)[:, 0]
    np.testing.assert_array_equal(rep, [0, 1, 2, 3])
    np.testing.assert_array_equal(mir, [3, 2, 1, 0])
    np.testing.assert_array_equal(clp, [3, 3, 3, 3])
    # bilinear across the seam at u = 0: repeat blends the last and first texels, mirror and clamp the first
    seam = np.array([[0.0, 0.5]], np.float32)
    np.testing.assert_allclose(_set(img, ("repeat", "repeat"), device=device).sample(0, seam)[0, 0], 1.5, atol=1e-6)
    np.testing.assert_allclose(_set(img, ("mirror", "repeat"), device=device).sample(0, seam)[0, 0], 0.0, atol=1e-6)
    np.testing.assert_allclose(_set(img, ("clamp", "repeat"), device=device).sample(0, seam)[0, 0], 0.0, atol=1e-6)


@pytest.mark.parametrize("ws,wt", [("repeat", "mirror"), ("clamp", "repeat"), ("mirror", "clamp")])
def test_trilinear_matches_reference(device, rng, ws, wt):
    img = rng.uniform(0.0, 1.0, (12, 10, 4)).astype(np.float32)
    chain = ref_mip_chain(img)
    n = 300
    uv = (rng.uniform(-3.0, 4.0, (n, 2))).astype(np.float32)
    lod = rng.uniform(-1.0, len(chain) + 1.0, n).astype(np.float32)
    lod[:4] = [0.0, 0.5, len(chain) - 1, 1.25]
    ts = _set(img, (ws, wt), "linear", device)
    got = ts.sample(0, uv, lod=lod)
    np.testing.assert_allclose(got, ref_trilinear(chain, uv, lod, ws, wt), rtol=0, atol=ATOL)
    np.testing.assert_allclose(ts.sample(0, uv, lod=lod, filter="trilinear"), got, atol=1e-7)


def test_levels_packed_in_the_atlas(device, rng):
    # nearest at each level's texel centres (filter override, integer LOD) reads the reference chain
    imgs = [rng.uniform(0.0, 1.0, s + (4,)).astype(np.float32) for s in ((7, 5), (1, 1), (4, 16))]
    ts = _set(imgs, device=device)
    for t, img in enumerate(imgs):
        for k, lev in enumerate(ref_mip_chain(img)):
            h, w = lev.shape[:2]
            jj, ii = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
            uv = np.stack([(ii.ravel() + 0.5) / w, (jj.ravel() + 0.5) / h], axis=1).astype(np.float32)
            got = ts.sample(t, uv, lod=float(k), filter="nearest")
            np.testing.assert_allclose(got, lev.reshape(-1, 4), atol=1e-6)
            np.testing.assert_allclose(ts.level(t, k), lev, atol=1e-6)


def test_lod_none_is_finest_bilinear_and_lod_clamps(device, rng):
    img = rng.uniform(0.0, 1.0, (8, 8, 4)).astype(np.float32)
    chain = ref_mip_chain(img)
    ts = _set(img, device=device)
    uv = rng.uniform(-2.0, 2.0, (64, 2)).astype(np.float32)
    np.testing.assert_allclose(ts.sample(0, uv), ref_bilinear(img, uv, "repeat", "repeat"), atol=ATOL)
    np.testing.assert_allclose(ts.sample(0, uv, lod=-3.0), ts.sample(0, uv), atol=0)
    np.testing.assert_allclose(ts.sample(0, uv, lod=np.nan), ts.sample(0, uv), atol=0)
    top = np.broadcast_to(chain[-1][0, 0], (64, 4))
    for lod in (3.0, 3.5, 40.0, np.inf):
        np.testing.assert_allclose(ts.sample(0, uv, lod=lod), top, atol=1e-6)
    # a nearest texture with ray cones: the nearest texel of the level nearest the LOD
    tn = _set(img, filt="nearest", device=device)
    for lod, level in ((0.4, 0), (0.6, 1), (1.49, 1), (2.7, 3), (9.0, 3)):
        np.testing.assert_allclose(tn.sample(0, uv, lod=lod), ref_nearest(chain[level], uv, "repeat", "repeat"),
                                   atol=1e-6)
    # no texture (-1) is white
    np.testing.assert_array_equal(ts.sample(-1, uv[:3]), 1.0)


def test_texture_set_errors(monkeypatch):
    good = np.zeros((2, 2, 3), np.float32)
    with pytest.raises(ValueError, match="images must be a list or tuple"):
        TextureSet(good)
    with pytest.raises(ValueError, match=r"images\[1\] must hold finite values.*\(0, 1, 2\)"):
        bad = good.copy()
        bad[0, 1, 2] = np.nan
        TextureSet([good, bad])
    with pytest.raises(ValueError, match=r"images\[0\] must hold linear floating-point values"):
        TextureSet([np.zeros((2, 2, 3), np.uint8)])
    with pytest.raises(ValueError, match=r"images\[0\] must be an \(H, W\)"):
        TextureSet([np.zeros((2, 2, 5), np.float32)])
    with pytest.raises(ValueError, match=r"textures\[0\].image must be in \[0, 0\]"):
        TextureSet([good], [TextureSampler(1)])
    with pytest.raises(ValueError, match="wrap_s must be one of"):
        TextureSampler(0, wrap_s="border")
    ts = TextureSet([good])
    with pytest.raises(ValueError, match=r"texture must be in \[-1, 0\], got 3"):
        ts.sample(3, [[0.0, 0.0]])
    with pytest.raises(ValueError, match=r"uv must be an \(N, 2\)"):
        ts.sample(0, [0.0, 0.0])
    with pytest.raises(ValueError, match="filter must be one of"):
        ts.sample(0, [[0.0, 0.0]], filter="cubic")
    # the atlas is indexed with int32: too many texels in all are refused (the limit lowered to show it; 8 x 8
    # and 5 x 5 chains hold 85 + 30 texels)
    import foveawarp.textures as textures_module

    monkeypatch.setattr(textures_module, "MAX_ATLAS_TEXELS", 100)
    with pytest.raises(ValueError, match=r"at most 100 texels in all .* got 115 by images\[1\]"):
        TextureSet([np.zeros((8, 8, 4), np.float32), np.zeros((5, 5, 4), np.float32)])
    monkeypatch.undo()
    # no images at all: the atlas still has one white texel, every lookup is the white "no texture"
    empty = TextureSet([])
    assert empty.num_textures == 0
    np.testing.assert_array_equal(empty.sample(-1, [[0.5, 0.5]]), 1.0)


# ---------------------------------------------------------------------------------------------------------------
# ray cones


def _random_triangles(rng, n):
    p = rng.uniform(-2.0, 2.0, (n, 3, 3))
    t = rng.uniform(-1.0, 2.0, (n, 3, 2))
    pa = np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    e1, e2 = t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]
    ta = np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    keep = (pa > 0.2) & (ta > 0.05)  # well-conditioned areas: the float32 cross products lose < 1e-5 relative
    return p[keep].astype(np.float32), t[keep].astype(np.float32)


def test_ray_cone_lod_matches_formula(device, rng):
    p, t = _random_triangles(rng, 400)
    m = len(p)
    w = rng.choice([1, 64, 256, 1000, 4096], m)
    h = rng.choice([1, 32, 512, 3000], m)
    dist = rng.uniform(0.01, 100.0, m).astype(np.float32)
    alpha = rng.uniform(1e-4, 0.05, m).astype(np.float32)
    n = rng.normal(size=(m, 3)).astype(np.float32)
    d = rng.normal(size=(m, 3)).astype(np.float32)
    cos = np.abs(np.sum(n * d, 1)) / np.linalg.norm(n, axis=1) / np.linalg.norm(d, axis=1)
    keep = cos > 0.05
    args = [a[keep] for a in (p, t, w, h, dist, alpha, n, d)]
    levels = 1000  # no upper clamp in effect
    delta, lod = _ray_cone(device, *args, levels)
    rd, rl = ref_ray_cone_lod(*args, levels, clamp=False)
    np.testing.assert_allclose(delta, rd, rtol=0, atol=1e-4)
    np.testing.assert_allclose(lod, np.maximum(rl, 0.0), rtol=0, atol=1e-4)
    assert rl.min() < -1.0 and rl.max() > 1.0  # the cases cover both signs of lambda
    # clamped to a 10-level chain
    _, lod10 = _ray_cone(device, *args, 10)
    np.testing.assert_allclose(lod10, np.clip(rl, 0.0, 9.0), atol=1e-4)
    assert (lod10 == 0.0).any() and (lod10 == 9.0).any()


def test_ray_cone_known_case(device):
    # a 2 x 2 m square's half in the z = 0 plane with UVs spanning [0, 1]^2, a 1024^2 texture: Delta =
    # 0.5 log2(1024^2 * 1 / 4) = 9; a cone of width 2 t tan(alpha / 2) = 2^-9 m head-on: lambda = 0
    p = [[[0, 0, 0], [2, 0, 0], [0, 2, 0]]]
    t = [[[0, 0], [1, 0], [0, 1]]]
    dist = 1.0
    alpha = 2.0 * math.atan(2.0 ** -10)
    delta, lod = _ray_cone(device, p, t, 1024, 1024, [dist], [alpha], [[0, 0, 1]], [[0, 0, -1]], 1000)
    np.testing.assert_allclose(delta, [9.0], atol=1e-5)
    np.testing.assert_allclose(lod, [0.0], atol=1e-5)
    # four times farther: two levels coarser; at 60 degrees incidence one more level (1 / cos = 2)
    d60 = [[math.sin(math.radians(60)), 0.0, -math.cos(math.radians(60))]]
    _, lod = _ray_cone(device, p, t, 1024, 1024, [4.0], [alpha], [[0, 0, 1]], [[0, 0, -1]], 1000)
    np.testing.assert_allclose(lod, [2.0], atol=1e-5)
    _, lod = _ray_cone(device, p, t, 1024, 1024, [4.0], [alpha], [[0, 0, 1]], d60, 1000)
    np.testing.assert_allclose(lod, [3.0], atol=1e-5)


def test_ray_cone_grazing_guard(device):
    p = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]]] * 5, np.float32)
    t = np.array([[[0, 0], [1, 0], [0, 1]]] * 5, np.float32)
    n = np.array([[0, 0, 1]] * 5, np.float32)
    d = np.array([[1, 0, 0], [1, 0, 1e-9], [1, 0, 1e-7], [1, 0, -1e-3], [1, 0, 0]], np.float32)
    n[4] = 0.0  # a zero-length normal counts as head-on
    dist = np.full(5, 2.0, np.float32)
    alpha = np.full(5, 1e-3, np.float32)
    _, lod = _ray_cone(device, p, t, 4096, 4096, dist, alpha, n, d, 1000)
    base = 0.5 * math.log2(4096 * 4096) + math.log2(2 * 2.0 * math.tan(0.5e-3))
    assert base > 1.0
    expect = [base - math.log2(1e-6), base - math.log2(1e-6), base - math.log2(1e-6), base - math.log2(1e-3), base]
    np.testing.assert_allclose(lod, expect, atol=1e-3)
    assert np.isfinite(lod).all()


def test_spread_angles_and_cone_width(device, rng):
    m = 50
    fov = rng.uniform(0.1, 3.0, m).astype(np.float32)
    height = rng.integers(1, 4000, m).astype(np.int32)
    fp_px = rng.uniform(0.0, 40.0, m).astype(np.float32)
    fp_px[:3] = [0.0, 1.0, 1e9]  # 1e9 pixels: capped at SPREAD_ANGLE_MAX
    dist = rng.uniform(0.0, 50.0, m).astype(np.float32)
    outs = [wp.zeros(m, dtype=float, device=device) for _ in range(3)]
    wp.launch(_cone_funcs_kernel, dim=m, device=device,
              inputs=[wp.array(fov, dtype=float, device=device), wp.array(height, dtype=int, device=device),
                      wp.array(fp_px, dtype=float, device=device), wp.array(dist, dtype=float, device=device)],
              outputs=outs)
    pixel, spread, width = (o.numpy() for o in outs)
    ref_pixel = np.arctan(2.0 * np.tan(fov.astype(np.float64) / 2.0) / height)
    ref_spread = np.minimum(ref_pixel * fp_px, 3.0)
    np.testing.assert_allclose(pixel, ref_pixel, rtol=1e-5)
    np.testing.assert_allclose(spread, ref_spread, rtol=1e-5)
    np.testing.assert_allclose(width, 2.0 * dist * np.tan(ref_spread / 2.0), rtol=1e-4)
    # the host helpers agree
    for k in range(5):
        a = pixel_spread_angle_rad(math.degrees(float(fov[k])), int(height[k]))
        assert a == pytest.approx(ref_pixel[k], rel=1e-5)
        assert footprint_spread_angle_rad(a, float(fp_px[k])) == pytest.approx(ref_spread[k], rel=1e-5)
    with pytest.raises(ValueError, match=r"fov_y_deg must be in \(0(\.0)?, 180(\.0)?\)"):
        pixel_spread_angle_rad(180.0, 100)
    with pytest.raises(ValueError, match="footprint_px must be"):
        footprint_spread_angle_rad(0.01, -1.0)


def test_hit_path_lod_and_lookup(device, rng):
    # texture_ray_cone_lod / sample_texture (the shading path) against the NumPy lambda and trilinear lookup,
    # with the cone widened by the foveated sample spacing (footprint_px pixels per sample)
    img = rng.uniform(0.0, 1.0, (64, 32, 4)).astype(np.float32)
    chain = ref_mip_chain(img)
    ts = _set(img, ("repeat", "mirror"), device=device)
    p, t = _random_triangles(rng, 200)
    m = len(p)
    uv = rng.uniform(-2.0, 3.0, (m, 2)).astype(np.float32)
    dist = rng.uniform(0.5, 20.0, m).astype(np.float32)
    fp_px = rng.choice([1.0, 2.0, 4.0, 8.0], m).astype(np.float32)
    n = np.tile(np.float32([0, 1, 0]), (m, 1))
    d = rng.normal(size=(m, 3)).astype(np.float32)
    d[:, 1] = -np.abs(d[:, 1]) - 0.2
    fov, height = math.radians(60.0), 120
    dev = device
    outs = [wp.zeros(m, dtype=wp.vec4, device=dev), wp.zeros(m, dtype=float, device=dev),
            wp.zeros(m, dtype=float, device=dev)]
    for mode in (tk.LOD_RAY_CONE, tk.LOD_NONE):
        wp.launch(_hit_kernel, dim=m, device=dev,
                  inputs=[ts.atlas, wp.zeros(m, dtype=wp.int32, device=dev), wp.array(p, dtype=wp.vec3, device=dev),
                          wp.array(t, dtype=wp.vec2, device=dev), wp.array(uv, dtype=wp.vec2, device=dev),
                          wp.array(dist, dtype=float, device=dev), fov, height,
                          wp.array(fp_px, dtype=float, device=dev), wp.array(n, dtype=wp.vec3, device=dev),
                          wp.array(d, dtype=wp.vec3, device=dev), int(mode)], outputs=outs)
        col, lod, spread = (o.numpy() for o in outs)
        alpha = fp_px * math.atan(2.0 * math.tan(fov / 2.0) / height)
        np.testing.assert_allclose(spread, alpha, rtol=1e-5)
        _, ref_lod = ref_ray_cone_lod(p, t, 32, 64, dist, alpha, n, d, len(chain))
        np.testing.assert_allclose(lod, ref_lod, atol=1e-4)
        if mode == tk.LOD_RAY_CONE:
            assert (ref_lod > 0.5).sum() > m // 4  # most lookups are not at level 0
            np.testing.assert_allclose(col, ref_trilinear(chain, uv, ref_lod, "repeat", "mirror"), atol=2e-4)
        else:  # "none": level 0 bilinear whatever the cone
            np.testing.assert_allclose(col, ref_bilinear(img, uv, "repeat", "mirror"), atol=ATOL)


# ---------------------------------------------------------------------------------------------------------------
# degenerate inputs (hypothesis)

_any_float = st.one_of(st.floats(allow_nan=True, allow_infinity=True, width=32),
                       st.sampled_from([0.0, -0.0, 1.0, -1.0, 1e30, -1e30, 16777217.0, np.nan, np.inf, -np.inf]))


@HYP
@given(u=st.lists(_any_float, min_size=8, max_size=8), v=st.lists(_any_float, min_size=8, max_size=8),
       lod=st.lists(_any_float, min_size=8, max_size=8), ws=st.sampled_from(WRAPS), wt=st.sampled_from(WRAPS),
       filt=st.sampled_from(["linear", "nearest"]))
def test_any_uv_and_lod_give_finite_convex_values(device, u, v, lod, ws, wt, filt):
    img = np.linspace(0.2, 0.9, 5 * 3 * 4, dtype=np.float32).reshape(5, 3, 4)
    ts = _set(img, (ws, wt), filt, device)
    uv = np.stack([u, v], axis=1).astype(np.float32)
    for out in (ts.sample(0, uv), ts.sample(0, uv, lod=np.asarray(lod, np.float32))):
        assert np.isfinite(out).all()
        assert (out >= 0.2 - 1e-6).all() and (out <= 0.9 + 1e-6).all()


@HYP
@given(uv=st.lists(st.tuples(_any_float, _any_float), min_size=1, max_size=6), lod=_any_float,
       ws=st.sampled_from(WRAPS), wt=st.sampled_from(WRAPS), filt=st.sampled_from(["linear", "nearest"]),
       texel=st.tuples(*[st.floats(0.0, 10.0, width=32)] * 4))
def test_one_texel_image_reads_its_texel(device, uv, lod, ws, wt, filt, texel):
    ts = _set(np.array(texel, np.float32).reshape(1, 1, 4), (ws, wt), filt, device)
    assert ts.num_levels == (1,)
    uv = np.asarray(uv, np.float32)
    for out in (ts.sample(0, uv), ts.sample(0, uv, lod=lod)):
        np.testing.assert_allclose(out, np.broadcast_to(texel, out.shape), rtol=1e-6, atol=0)


@HYP
@given(h=st.integers(1, 11), w=st.integers(1, 11), seed=st.integers(0, 2**31 - 1), ws=st.sampled_from(WRAPS),
       wt=st.sampled_from(WRAPS))
def test_non_power_of_two_sizes(device, h, w, seed, ws, wt):
    rng = np.random.default_rng(seed)
    img = rng.uniform(0.0, 1.0, (h, w, 4)).astype(np.float32)
    chain = ref_mip_chain(img)
    ts = _set(img, (ws, wt), device=device)
    assert ts.num_levels == (len(chain),) and ts.sizes == ((w, h),)
    for k, lev in enumerate(chain):
        np.testing.assert_allclose(ts.level(0, k), lev, atol=1e-6)
    uv = rng.uniform(-2.0, 3.0, (16, 2)).astype(np.float32)
    lod = rng.uniform(0.0, len(chain) - 1.0, 16).astype(np.float32)
    np.testing.assert_allclose(ts.sample(0, uv), ref_bilinear(img, uv, ws, wt), atol=ATOL)
    np.testing.assert_allclose(ts.sample(0, uv, lod=lod), ref_trilinear(chain, uv, lod, ws, wt), atol=ATOL)


_coord = st.one_of(st.floats(-4.0, 4.0, width=32), st.sampled_from([0.0, np.nan, np.inf, -np.inf, 1e30]))


@HYP
@given(uv0=st.tuples(_coord, _coord), kind=st.sampled_from(["point", "line", "any"]),
       uvs=st.lists(st.tuples(_coord, _coord), min_size=2, max_size=2),
       ps=st.lists(st.tuples(_coord, _coord, _coord), min_size=3, max_size=3),
       dist=_any_float, alpha=_any_float, nrm=st.tuples(_coord, _coord, _coord),
       dirn=st.tuples(_coord, _coord, _coord), levels=st.integers(1, 14))
def test_ray_cone_lod_never_nan(device, uv0, kind, uvs, ps, dist, alpha, nrm, dirn, levels):
    uv0 = np.asarray(uv0, np.float32)
    if kind == "point":  # zero-area UV triangle: all three UVs equal
        t = np.stack([uv0, uv0, uv0])
    elif kind == "line":  # collinear UVs
        t = np.stack([uv0, uv0 + 0.5, uv0 + 1.0])
    else:
        t = np.stack([uv0, np.asarray(uvs[0], np.float32), np.asarray(uvs[1], np.float32)])
    delta, lod = _ray_cone(device, [ps], [t], 512, 256, [dist], [alpha], [nrm], [dirn], levels)
    assert np.isfinite(delta).all() and np.isfinite(lod).all()
    assert 0.0 <= lod[0] <= levels - 1
    if kind == "point" and np.isfinite(t).all() and np.isfinite(np.asarray(ps, np.float32)).all():
        # the UV area is floored at AREA_MIN: Delta is tiny, far below any footprint
        pa = np.linalg.norm(np.cross(np.subtract(ps[1], ps[0]), np.subtract(ps[2], ps[0])))
        if 1e-20 < pa < 1e20:
            assert delta[0] < -30.0
