"""Stress: the sampling-map ops (ALGORITHMS.md A2) with gazes anywhere (far off screen included), extreme
fields of view and image shapes, extreme probabilities, saliency inputs, and cache-test depth ties."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import example, given
from hypothesis import strategies as st

from foveawarp import ops

from stress_util import F32_MAX, assert_binary, assert_finite, batch, examples

GAZE_LIMIT = 1.0e6  # stages.sampling.GAZE_LIMIT_PX: gazes farther off screen are clamped to it



# -- references (float64) -------------------------------------------------------------------------------------


def _plane(px, py, w, h, t):
    return np.stack([(2.0 * px / w - 1.0) * t * (w / h), (1.0 - 2.0 * py / h) * t, np.ones_like(px)], axis=-1)


def _angle_deg(a, b):
    return np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1)))


def ecc_reference(w, h, gaze, fov):
    gx = min(max(gaze[0], -GAZE_LIMIT), w + GAZE_LIMIT)
    gy = min(max(gaze[1], -GAZE_LIMIT), h + GAZE_LIMIT)
    t = math.tan(math.radians(fov) * 0.5)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64) + 0.5
    g = _plane(np.array(gx), np.array(gy), w, h, t)
    return _angle_deg(_plane(xx, yy, w, h, t), g), (gx, gy), t


def ecc_rounding_bound_deg(w, h, g_clamped, t):
    """Bound (degrees) of the float32 rounding error of ``kernels.sampling.eccentricity_at``.

    The kernel takes the z component of ``g x p`` as ``g_x d_y - g_y d_x`` (d = p - g from pixel
    differences). For gazes far off screen both products are large and nearly equal, so the difference
    loses up to ``eps32 (|g_x d_y| + |g_y d_x|)``; the angle then errs by about that over ``|g| |p|``
    (reported as an accuracy issue: up to ~7 degrees at fov 170 on a 64 x 1 image; taking
    ``g_x p_y - g_y p_x`` instead when its terms are smaller brings it to ~5e-5 degrees). The bound
    grants 8 x that loss; near the gaze it is ~0."""
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64) + 0.5
    g = _plane(np.array(g_clamped[0]), np.array(g_clamped[1]), w, h, t)
    p = _plane(xx, yy, w, h, t)
    d = p - g
    loss = np.abs(g[0] * d[..., 1]) + np.abs(g[1] * d[..., 0])
    eps32 = float(np.finfo(np.float32).eps)
    return np.degrees(8.0 * eps32 * loss / (np.linalg.norm(g) * np.linalg.norm(p, axis=-1)))


def e_max_reference(w, h, g_clamped, t, n=257, iters=40):
    """Largest eccentricity over the screen rectangle's boundary: each edge sampled at ``n`` points, then a
    ternary search around the best sample (the angle along an edge is unimodal near its maximum, which can
    be a cusp when the antipode of the gaze direction lies on the edge's great circle). Vectorized over the
    four edges."""
    g = _plane(np.array(g_clamped[0]), np.array(g_clamped[1]), w, h, t)
    p0 = np.array([[0, 0], [w, 0], [w, h], [0, h]], dtype=np.float64)
    p1 = np.roll(p0, -1, axis=0)

    def ang(s):  # s: (4, k) edge parameters
        pts = p0[:, None, :] + s[..., None] * (p1 - p0)[:, None, :]
        return _angle_deg(_plane(pts[..., 0], pts[..., 1], w, h, t), g)

    s = np.broadcast_to(np.linspace(0.0, 1.0, n), (4, n))
    a = ang(s)
    i = np.argmax(a, axis=1)
    lo = s[0][np.maximum(i - 1, 0)]
    hi = s[0][np.minimum(i + 1, n - 1)]
    for _ in range(iters):
        m1, m2 = lo + (hi - lo) / 3, hi - (hi - lo) / 3
        v = ang(np.stack([m1, m2], axis=1))
        left = v[:, 0] < v[:, 1]
        lo = np.where(left, m1, lo)
        hi = np.where(left, hi, m2)
    return float(max(a.max(), ang((0.5 * (lo + hi))[:, None]).max()))


# -- strategies -------------------------------------------------------------------------------------------------


def _special_coords(limit):
    return [0.0, -0.0, 0.5, limit, limit - 1e-3, limit * 0.5, -1.0, limit + 1.0, GAZE_LIMIT, -GAZE_LIMIT,
            GAZE_LIMIT + limit, -GAZE_LIMIT - 1.0, 1e7, -1e7, 1e20, -1e20, F32_MAX, -F32_MAX, 1.7e308, -1.7e308,
            5e-324, -1e-45]


def gaze_coord(limit):
    far = st.builds(lambda s, e: s * 10.0 ** e, st.sampled_from([-1.0, 1.0]), st.floats(0.0, 38.5))
    return st.one_of(
        st.floats(0.0, float(limit)),
        st.floats(-4.0 * limit, 5.0 * limit),
        far,
        st.sampled_from(_special_coords(float(limit))),
        st.floats(allow_nan=False, allow_infinity=False),
    )


def _random_gazes(rng, n, w, h):
    """n gazes: a third on screen, a third near it, a third log-uniform far off screen (any direction)."""
    k = n // 3
    on = rng.uniform([0, 0], [w, h], size=(k, 2))
    near = rng.uniform([-3 * w, -3 * h], [4 * w, 4 * h], size=(k, 2))
    far = rng.choice([-1.0, 1.0], size=(n - 2 * k, 2)) * 10.0 ** rng.uniform(0, 38.5, size=(n - 2 * k, 2))
    return np.concatenate([on, near, far])


sizes = st.one_of(st.tuples(st.integers(1, 40), st.integers(1, 40)),
                  st.sampled_from([(1, 1), (1, 64), (64, 1), (256, 2), (3, 200), (33, 17)]))
fovs = st.one_of(st.floats(1.0, 150.0), st.sampled_from([1e-4, 0.01, 0.5, 90.0, 170.0, 178.0, 179.0]))


# -- gaze anywhere ----------------------------------------------------------------------------------------------


@examples(60, 250)
@given(size=sizes, fov=fovs, special=st.lists(st.tuples(gaze_coord(64), gaze_coord(64)), max_size=8),
       seed=st.integers(0, 2**32 - 1), mar=st.tuples(st.floats(1e-4, 1.0), st.floats(1e-4, 1.0)),
       xi=st.sampled_from([0.0, 1e-6, 0.05, 0.5, 1.0]), block=st.sampled_from([1, 2, 3, 4, 8, 16]))
@example(size=(1, 1), fov=179.0, special=[(1e30, -1e30), (-F32_MAX, F32_MAX)], seed=0, mar=(1.0, 1.0), xi=0.0,
         block=1)
def test_gaze_anywhere_including_far_off_screen(device, cases, size, fov, special, seed, mar, xi, block):
    """Eccentricity, eq. 2 probability and the sampling map for many gazes (on screen, near it, up to
    float max away): finite, eccentricity in [0, 180] and equal to a float64 reference, probability in
    [xi, 1] and equal to its reference, maps binary with the tile guarantee."""
    w, h = size
    rng = np.random.default_rng(seed)
    n = batch(device, 24, cuda_factor=2)  # the cost is the float64 reference on the host
    gazes = list(special) + [tuple(g) for g in _random_gazes(rng, max(n - len(special), 3), w, h)]
    m, b = mar
    for gaze in gazes:
        ecc = assert_finite(f"eccentricity gaze={gaze}", ops.eccentricity_deg(w, h, gaze, fov, device=device))
        assert ecc.shape == (h, w)
        assert ecc.min() >= 0.0 and ecc.max() <= 180.0 + 1e-3, (gaze, ecc.min(), ecc.max())
        ref, gc, t = ecc_reference(w, h, gaze, fov)
        tol = 5e-3 + ecc_rounding_bound_deg(w, h, gc, t)
        err = np.abs(ecc - ref)
        assert (err <= tol).all(), (f"gaze={gaze} fov={fov}: eccentricity error {err.max()} deg > bound "
                                    f"{tol.ravel()[np.argmax(err)]}")

        p = assert_finite(f"probability gaze={gaze}", ops.foveation_probability(
            w, h, gaze, fov, mar_slope=m, mar_fovea_deg=b, min_probability=xi, device=device))
        assert p.min() >= np.float32(xi) and p.max() <= 1.0, (gaze, p.min(), p.max())
        g = _plane(np.array(gc[0]), np.array(gc[1]), w, h, t)
        step = np.array([2.0 / w * t * (w / h), 0.0, 0.0])
        w_min = float(_angle_deg(g, g + step))
        w_far = m * e_max_reference(w, h, gc, t) + b
        p_ref = np.clip(1.0 - (m * ref + b - w_min) / w_far, xi, 1.0)
        perr = np.abs(p - p_ref)
        assert (perr <= 2e-3 + m * tol / w_far).all(), f"gaze={gaze} fov={fov}: probability error {perr.max()}"

        smap = assert_binary("sample_map", ops.sample_map(p, block=block, device=device))
        assert smap[p >= 1.0].all()
        for ty in range(0, h, block):
            for tx in range(0, w, block):
                assert smap[ty:ty + block, tx:tx + block].any(), (gaze, ty, tx)
    cases.add("gaze anywhere (ecc + p + map)", len(gazes))


# -- sample_map with extreme probabilities ------------------------------------------------------------------------


prob_values = st.one_of(
    st.sampled_from([0.0, -0.0, 1.0, 1.0 - 2**-24, 2**-24, 1e-45, 0.5, -1.0, 2.0, 1e30, -1e30, F32_MAX, -F32_MAX]),
    st.floats(0.0, 1.0, width=32),
    st.floats(-F32_MAX, F32_MAX, width=32),
)


@examples(200, 2000)
@given(h=st.integers(1, 70), w=st.integers(1, 70), block=st.integers(1, 64), fill=prob_values,
       spots=st.lists(st.tuples(st.integers(0, 69), st.integers(0, 69), prob_values), max_size=20),
       frame=st.one_of(st.integers(0, 5000), st.sampled_from([2**31 - 1, 2**40])),
       seed=st.sampled_from([0, 1, 12345, 2**31 - 1]))
def test_sample_map_extreme_probabilities(device, cases, h, w, block, fill, spots, frame, seed):
    """Constant maps of any finite value with spikes (0, 1, denormals, +-float max): binary, p >= 1 always
    sampled, every aligned tile (partial ones too) holds a sample, and p <= 0 pixels are sampled only as the
    one guaranteed pixel of a full tile or partial tile."""
    p = np.full((h, w), fill, dtype=np.float32)
    for y, x, v in spots:
        p[y % h, x % w] = v
    m = assert_binary("sample_map", ops.sample_map(p, block=block, frame_index=frame, seed=seed, device=device))
    assert m.shape == (h, w)
    assert m[p >= 1.0].all()
    for ty in range(0, h, block):
        for tx in range(0, w, block):
            tile_m = m[ty:ty + block, tx:tx + block]
            assert tile_m.any()
            if (p[ty:ty + block, tx:tx + block] <= 0.0).all():
                assert tile_m.sum() == 1
    cases.add("sample_map extreme probabilities", 1)


# -- saliency inputs ----------------------------------------------------------------------------------------------


@examples(150, 1000)
@given(h=st.integers(1, 24), w=st.integers(1, 24), seed=st.integers(0, 2**32 - 1),
       mode=st.sampled_from(["uniform", "binary", "tiny", "const", "checker"]))
def test_saliency_terms_extreme_albedo_and_normals(device, cases, h, w, seed, mode):
    """Lab conversion and Sobel gradients of albedo in [0, 1] (exact 0 / 1, denormals, checkerboards) and of
    normal buffers (unit, zero = background, mixed): finite, L in [0, 100], gradients >= 0 and bounded."""
    rng = np.random.default_rng(seed)
    n = batch(device, 4)
    for _ in range(n):
        if mode == "uniform":
            a = rng.random((h, w, 3))
        elif mode == "binary":
            a = rng.integers(0, 2, (h, w, 3)).astype(np.float64)
        elif mode == "tiny":
            a = rng.choice([0.0, 1e-45, 1e-38, 1e-20, 0.008856, 1.0], size=(h, w, 3))
        elif mode == "const":
            a = np.full((h, w, 3), rng.choice([0.0, 1.0, 1e-45]))
        else:
            yy, xx = np.mgrid[0:h, 0:w]
            a = np.repeat(((yy + xx) % 2)[..., None], 3, axis=2).astype(np.float64)
        a = a.astype(np.float32)
        lab = assert_finite("albedo_to_lab", ops.albedo_to_lab(a, device=device))
        assert lab[..., 0].min() >= -1e-3 and lab[..., 0].max() <= 100.0 + 1e-3
        ga = assert_finite("albedo_gradient", ops.albedo_gradient(a, device=device))
        assert ga.min() >= 0.0 and ga.max() <= 4.0 * 4.0 * 600.0

        nrm = rng.normal(size=(h, w, 3))
        nrm /= np.maximum(np.linalg.norm(nrm, axis=-1, keepdims=True), 1e-30)
        nrm[rng.random((h, w)) < 0.3] = 0.0  # background pixels have a zero normal
        gn = assert_finite("normal_gradient", ops.normal_gradient(nrm.astype(np.float32), device=device))
        assert gn.min() >= 0.0 and gn.max() <= 4.0 * 4.0 * 2.0 + 1e-3
    cases.add("saliency terms (lab, sobel)", n)


depth_values = st.sampled_from([0.0, 1e-45, 1e-30, 1e-4, 0.05, 1.0, 1e5, 1e20, 1e30, F32_MAX])


@examples(60, 600)
@given(focus=st.one_of(depth_values.filter(lambda v: v > 0), st.floats(1e-6, 1e6)),
       s1=st.one_of(st.sampled_from([0.0, 1e-30, 1e30]), st.floats(0.0, 1e3)),
       s2=st.one_of(st.sampled_from([1e-30, 1e-10, 1e30, F32_MAX]), st.floats(1e-6, 1e3)),
       floor=st.sampled_from([0.0, 0.25, 1.0]), seed=st.integers(0, 2**32 - 1))
def test_dof_sampling_factor_extreme_depths(device, cases, focus, s1, s2, floor, seed):
    """F_DoF over depths from 0 to float max (the G-buffer writes 1e30 on misses): finite, in [floor, 1],
    and exactly 1 at the focus depth (CoC zero)."""
    rng = np.random.default_rng(seed)
    n = batch(device, 64)
    d = np.concatenate([[focus, 0.0, 1e30, F32_MAX], 10.0 ** rng.uniform(-45, 38.5, n - 4)]).astype(np.float32)
    out = assert_finite("dof_sampling_factor", ops.dof_sampling_factor(
        d.reshape(1, -1), focus_depth_m=focus, sigma1_m=s1, sigma2_m=s2, dof_floor=floor, device=device))[0]
    assert out.min() >= np.float32(floor) - 1e-6 and out.max() <= 1.0
    assert out[0] == 1.0
    cases.add("dof sampling factor (depth x lens)", n)


# -- cache test: depth ties ---------------------------------------------------------------------------------------


def _cache_reference(uv, pos, hit, depth, dprev, vprev, eye, eps):
    """float64 cache test; ``amb`` marks pixels within rounding of the depth threshold (either answer ok)."""
    h, w = depth.shape
    u, v = uv[..., 0].astype(np.float64), uv[..., 1].astype(np.float64)
    on = (u >= 0) & (u < w) & (v >= 0) & (v < h)  # NaN compares false
    ix = np.clip(np.floor(np.nan_to_num(u)), 0, w - 1).astype(int)
    iy = np.clip(np.floor(np.nan_to_num(v)), 0, h - 1).astype(int)
    dp = dprev[iy, ix].astype(np.float64)
    dist = np.linalg.norm(pos.astype(np.float64) - eye.astype(np.float64), axis=-1)
    x = np.abs(dp - dist)
    thr = np.float64(np.float32(eps)) * depth.astype(np.float64)
    ok = (hit != 0) & on & (vprev[iy, ix] != 0)
    exp = ok & (x < thr)
    # float32 rounding: of the distance and the depths, and of ``pos - eye`` (relative to the coordinates)
    sub = 2.4e-7 * (np.linalg.norm(pos.astype(np.float64), axis=-1) + np.linalg.norm(eye.astype(np.float64)))
    amb = ok & (np.abs(x - thr) <= 4e-7 * (np.abs(dp) + dist + np.abs(thr)) + 2.0 * sub + 1e-37)
    return exp, amb, iy * w + ix


@examples(30, 300)
@given(seed=st.integers(0, 2**32 - 1), scale=st.sampled_from([1e-4, 1e-2, 1.0, 1e3, 1e5]),
       eps=st.one_of(st.sampled_from([1e-7, 1e-6, 1e-3, 0.01, 0.5, 1.0]), st.floats(1e-6, 1.0)),
       shape=st.sampled_from([(16, 16), (8, 32), (1, 256), (256, 1)]))
def test_cache_test_depth_ties(device, cases, seed, scale, eps, shape):
    """Thesis eq. 4 on pixels packed with independent cases: exact depth ties (depth_prev equal to the
    float32 reprojected distance), ties offset by +-1 ulp, differences exactly at and next to the
    eps * depth boundary, zero depth, uv on pixel edges / the screen border / far off it / NO_REPROJ, invalid
    history (inputs are finite: the op rejects NaN / Inf). Outputs agree with a float64 reference wherever the
    answer is not within rounding of the threshold; exact ties always hit when eps * depth is well above the
    float32 rounding of the distance."""
    h, w = shape[0] * batch(device, 1), shape[1]
    rng = np.random.default_rng(seed)
    eye = (rng.normal(size=3) * scale).astype(np.float32)
    pos = (eye + rng.normal(size=(h, w, 3)) * scale * 10.0 ** rng.uniform(-2, 2, (h, w, 1))).astype(np.float32)
    # the distance as the kernel forms it: float32 difference, then its length
    dist32 = np.linalg.norm((pos - eye).astype(np.float64), axis=-1).astype(np.float32)
    coord = np.maximum(np.abs(pos).max(axis=-1), np.abs(eye).max())
    yy, xx = np.mgrid[0:h, 0:w]
    frac = rng.choice([0.0, 0.5, 1.0 - 2**-20, 1e-7], size=(h, w, 2))
    uv = np.stack([xx + frac[..., 0], yy + frac[..., 1]], axis=-1).astype(np.float32)
    kind = rng.integers(0, 8, size=(h, w))
    depth = (dist32 * 10.0 ** rng.uniform(-1, 1, (h, w))).astype(np.float32)
    dprev = dist32.copy()  # kind 0: exact tie
    up = np.nextafter(dist32, np.float32(np.inf))
    dn = np.nextafter(dist32, np.float32(0))
    dprev = np.where(kind == 1, up, dprev)
    dprev = np.where(kind == 2, dn, dprev)
    thr = (np.float32(eps) * depth).astype(np.float32)
    dprev = np.where(kind == 3, dist32 + thr, dprev)  # exactly at the boundary (after rounding: either side)
    dprev = np.where(kind == 4, dist32 - thr * np.float32(0.999), dprev)
    dprev = np.where(kind == 5, dist32 + thr * np.float32(1.001), dprev)
    depth = np.where(kind == 6, np.float32(0.0), depth)  # zero depth: never a hit
    dprev = np.maximum(dprev, 0.0).astype(np.float32)  # distances are >= 0 (the op rejects negative ones)
    special_uv = rng.choice(5, size=(h, w))
    sel = kind == 7
    uv[sel & (special_uv == 0)] = [1e30, -F32_MAX]
    uv[sel & (special_uv == 1)] = [-1.0e4, -1.0e4]
    uv[sel & (special_uv == 2)] = [w, 0.0]
    uv[sel & (special_uv == 3)] = [-0.0, h - 2**-10]
    uv[sel & (special_uv == 4)] = [np.float32(w) - np.float32(w) * 2**-23, 0.0]
    hit = (rng.random((h, w)) > 0.05).astype(np.uint8)
    vprev = (rng.random((h, w)) > 0.05).astype(np.uint8)
    out_hit, out_idx = ops.cache_test(uv, pos, hit, depth, dprev, vprev, eye, depth_eps_rel=eps, device=device)
    assert_binary("cache hit", out_hit)
    exp, amb, idx = _cache_reference(uv, pos, hit, depth, dprev, vprev, eye, eps)
    bad = (out_hit.astype(bool) != exp) & ~amb
    assert not bad.any(), (f"{int(bad.sum())} disagreements, e.g. kind {kind[bad][:5]}, "
                           f"got {out_hit[bad][:5]}, expected {exp[bad][:5]}")
    assert (out_idx[out_hit == 0] == -1).all()
    assert (out_idx[out_hit == 1] == idx[out_hit == 1]).all()
    assert not out_hit[depth == 0].any()
    # exact ties must hit whenever the tolerance is well above float32 rounding of the distance
    own = (np.floor(uv[..., 0]) == xx) & (np.floor(uv[..., 1]) == yy)  # float32 x + frac may round up
    tie = (kind == 0) & own & (hit != 0) & (vprev != 0) & (thr > 64 * (np.spacing(dist32) + np.spacing(coord)))
    assert out_hit[tie].all()
    cases.add("cache test depth ties (pixels)", h * w)
