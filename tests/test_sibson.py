"""Discrete Sibson interpolation (ALGORITHMS.md A6) against plain NumPy scatter / gather references.

Both sides get the SAME nearest-seed map (SciPy's exact EDT indices), so ties cannot differ. Tolerance:
1e-5 absolute on colors in [0, 1] (float32 sums in a different order).
"""

import math

import numpy as np
import pytest
import warp as wp
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import ndimage

from foveawarp import ReconstructionConfig, ops
from foveawarp.kernels.sibson import disc_sum, isqrt
from foveawarp.stages.reconstruct import ReconstructStage, sibson_window_for_block

TOL = 1e-5

# -- independent references --------------------------------------------------------------------------------


def edt_nearest(mask):
    """(H, W, 2) int32 (x, y) of an exact nearest seed (SciPy), (-1, -1) without seeds."""
    h, w = mask.shape
    if not mask.any():
        return np.full((h, w, 2), -1, np.int32)
    _, (iy, ix) = ndimage.distance_transform_edt(~mask, return_indices=True)
    return np.stack([ix, iy], -1).astype(np.int32)


def _prep(colors, nearest):
    h, w = nearest.shape[:2]
    nx, ny = nearest[..., 0], nearest[..., 1]
    has = nx >= 0
    yy, xx = np.mgrid[0:h, 0:w]
    vor = np.where(has[..., None], colors[np.clip(ny, 0, h - 1), np.clip(nx, 0, w - 1)], 0.0).astype(np.float64)
    r2 = np.where(has, (nx - xx).astype(np.int64) ** 2 + (ny - yy).astype(np.int64) ** 2, -1)
    seed = has & (nx == xx) & (ny == yy)
    return vor, r2, seed


def ref_sibson(colors, nearest, window=None):
    """Park et al.'s scatter, written as a loop over seeds' disc offsets: each q adds color(seed(q)) to every
    p = q + (dx, dy) with dx^2 + dy^2 <= r_q^2 (|dx|, |dy| <= window when given, which is the thesis's
    bounded gather seen from the sender). Seeds keep their color; nothing received -> Voronoi color."""
    h, w = nearest.shape[:2]
    vor, r2, seed = _prep(colors, nearest)
    acc = np.zeros((h, w, 3))
    cnt = np.zeros((h, w))
    R = int(np.floor(np.sqrt(max(r2.max(), 0)))) + 1
    if window is not None:
        R = min(R, window)
    for dy in range(-R, R + 1):
        for dx in range(-R, R + 1):
            send = r2 >= dx * dx + dy * dy  # q's disc covers q + (dx, dy); r2 = -1 never sends
            qy, qx = np.nonzero(send)
            py, px = qy + dy, qx + dx
            ok = (py >= 0) & (py < h) & (px >= 0) & (px < w)
            np.add.at(acc, (py[ok], px[ok]), vor[qy[ok], qx[ok]])
            np.add.at(cnt, (py[ok], px[ok]), 1.0)
    out = np.where(cnt[..., None] > 0, acc / np.maximum(cnt, 1)[..., None], vor)
    out[seed] = vor[seed]
    return out


def uniform_mask(h, w, density, rng):
    m = rng.random((h, w)) < density
    if not m.any():
        m[rng.integers(h), rng.integers(w)] = True
    return m


def block_mask(h, w, k, extra, rng):
    m = rng.random((h, w)) < extra
    for ty in range(0, h, k):
        for tx in range(0, w, k):
            m[ty + rng.integers(min(k, h - ty)), tx + rng.integers(min(k, w - tx))] = True
    return m


def clustered_mask(h, w, rng):
    m = np.zeros((h, w), bool)
    for _ in range(4):
        cx, cy, s = rng.uniform(0, w), rng.uniform(0, h), rng.uniform(1, 4)
        m[np.clip(np.round(rng.normal(cy, s, 12)).astype(int), 0, h - 1),
          np.clip(np.round(rng.normal(cx, s, 12)).astype(int), 0, w - 1)] = True
    return m


# -- exact Sibson (scatter with atomics) -------------------------------------------------------------------


@pytest.mark.parametrize("case", ["uniform-2%", "uniform-10%", "uniform-40%", "clustered", "block4"])
def test_exact_sibson_matches_numpy_scatter(case, device, rng):
    h, w = (37, 53) if case != "block4" else (48, 64)
    if case == "clustered":
        m = clustered_mask(h, w, rng)
    elif case == "block4":
        m = block_mask(h, w, 4, 0.0, rng)
    else:
        m = uniform_mask(h, w, float(case.split("-")[1][:-1]) / 100, rng)
    colors = rng.random((h, w, 3)).astype(np.float32)
    near = edt_nearest(m)
    out, rmax = ops.sibson(colors, m, nearest=near, return_max_radius=True, device=device)
    ref = ref_sibson(colors, near)
    assert out.shape == (h, w, 3) and out.dtype == np.float32
    np.testing.assert_allclose(out, ref, atol=TOL, rtol=0)
    assert np.array_equal(out[m], colors[m])  # seeds keep their color exactly
    d2 = (near[..., 0] - np.mgrid[0:h, 0:w][1]) ** 2 + (near[..., 1] - np.mgrid[0:h, 0:w][0]) ** 2
    assert abs(rmax - np.sqrt(d2.max())) < 1e-5
    # it is an interpolation, not the Voronoi fill (so this test could tell them apart)
    assert np.abs(out - ops.voronoi(colors, m, nearest=near, device=device)).max() > 0.05


# -- bounded gather ------------------------------------------------------------------------------------------


@pytest.mark.parametrize("k", [2, 3, 4, 8])
def test_bounded_equals_exact_under_block_guarantee(k, device, rng):
    """J = sibson_window_for_block(k) covers every r_q the k x k guarantee allows, so bounded == exact."""
    h, w = 50, 70
    for extra in (0.0, 0.05):
        m = block_mask(h, w, k, extra, rng)
        colors = rng.random((h, w, 3)).astype(np.float32)
        near = ops.jump_flood(m, device=device)  # same map for both
        J = sibson_window_for_block(k)
        b = ops.sibson(colors, m, window=J, nearest=near, device=device)
        e = ops.sibson(colors, m, nearest=near, device=device)
        np.testing.assert_allclose(b, e, atol=TOL, rtol=0)
        np.testing.assert_allclose(b, ref_sibson(colors, near), atol=TOL, rtol=0)


def test_bounded_equals_exact_when_window_covers_max_radius(device, rng):
    for dens in (0.01, 0.05, 0.2):
        h, w = 40, 61
        m = uniform_mask(h, w, dens, rng)
        colors = rng.random((h, w, 3)).astype(np.float32)
        near = edt_nearest(m)
        e, rmax = ops.sibson(colors, m, nearest=near, return_max_radius=True, device=device)
        J = int(np.ceil(rmax))
        if J > 256:
            continue
        b = ops.sibson(colors, m, window=max(J, 1), nearest=near, device=device)
        np.testing.assert_allclose(b, e, atol=TOL, rtol=0)


def test_bounded_small_window_is_code4(device, rng):
    """With J below the largest radius the gather is the thesis's bounded sum (not Park's)."""
    h, w = 40, 56
    m = uniform_mask(h, w, 0.01, rng)
    colors = rng.random((h, w, 3)).astype(np.float32)
    near = edt_nearest(m)
    for J in (1, 2, 5):
        b = ops.sibson(colors, m, window=J, nearest=near, device=device)
        np.testing.assert_allclose(b, ref_sibson(colors, near, window=J), atol=TOL, rtol=0)
        assert np.array_equal(b[m], colors[m])
    assert np.abs(ops.sibson(colors, m, window=2, nearest=near, device=device)
                  - ref_sibson(colors, near)).max() > 1e-3


def test_jfa_driven_sibson_and_voronoi(device, rng):
    """Without ``nearest`` the op runs JFA first; compare with the references fed the op's own JFA map."""
    h, w = 33, 47
    m = uniform_mask(h, w, 0.08, rng)
    colors = rng.random((h, w, 3)).astype(np.float32)
    near = ops.jump_flood(m, device=device)
    np.testing.assert_allclose(ops.sibson(colors, m, device=device), ref_sibson(colors, near), atol=TOL, rtol=0)
    np.testing.assert_allclose(ops.sibson(colors, m, window=4, device=device),
                               ref_sibson(colors, near, window=4), atol=TOL, rtol=0)
    vor = ops.voronoi(colors, m, device=device)
    assert np.array_equal(vor, colors[near[..., 1], near[..., 0]])


# -- degenerate inputs and guards ---------------------------------------------------------------------------


@pytest.mark.parametrize("window", [None, 3])
def test_degenerate_seed_sets(window, device, rng):
    h, w = 11, 23
    colors = rng.random((h, w, 3)).astype(np.float32)
    # no seeds: zeros, radius 0, no NaN
    out, r = ops.sibson(colors, np.zeros((h, w)), window=window, return_max_radius=True, device=device)
    assert np.array_equal(out, np.zeros((h, w, 3), np.float32)) and r == 0.0
    # all seeds: identity
    out, r = ops.sibson(colors, np.ones((h, w)), window=window, return_max_radius=True, device=device)
    assert np.array_equal(out, colors) and r == 0.0
    # one seed: its color everywhere
    m = np.zeros((h, w), bool)
    m[2, 19] = True
    out, r = ops.sibson(colors, m, window=window, return_max_radius=True, device=device)
    np.testing.assert_allclose(out, np.broadcast_to(colors[2, 19], (h, w, 3)), atol=TOL, rtol=0)
    assert abs(r - np.hypot(19, 8)) < 1e-5
    # 1 x 1
    assert np.array_equal(ops.sibson(colors[:1, :1], np.ones((1, 1)), window=window, device=device),
                          colors[:1, :1])


def test_non_seed_garbage_is_ignored(device, rng):
    """Only seed pixels are read: NaN / Inf elsewhere must not leak into the output (through the stage: ops
    rejects NaN / Inf anywhere on the host, device buffers are not scanned)."""
    h, w = 30, 41
    m = uniform_mask(h, w, 0.05, rng)
    colors = rng.random((h, w, 3)).astype(np.float32)
    dirty = colors.copy()
    dirty[~m] = np.nan
    dirty[~m & (rng.random((h, w)) < 0.5)] = np.inf
    with pytest.raises(ValueError, match="colors"):
        ops.sibson(dirty, m, device=device)
    mw = wp.array(m.astype(np.uint8), dtype=wp.uint8, device=device)
    for window in (None, 4):
        stage = ReconstructStage(w, h, ReconstructionConfig(bounded_jfa_start=False), 1, device,
                                 exact_sibson=window is None, window=window)
        out = wp.zeros((h, w), dtype=wp.vec3, device=device)
        stage.run(wp.array(dirty, dtype=wp.vec3, device=device), mw, out)
        a = out.numpy().reshape(h, w, 3)
        assert np.all(np.isfinite(a))
        b = ops.sibson(colors, m, window=window, device=device)
        if window is None:
            # the exact form accumulates with atomics: on CUDA the summation order (last bits) varies
            np.testing.assert_allclose(a, b, atol=1e-6, rtol=0)
        else:
            assert np.array_equal(a, b)


def test_stage_sibson_off_and_stats(device, rng):
    h, w = 36, 52
    k = 4
    m = block_mask(h, w, k, 0.02, rng)
    colors = rng.random((h, w, 3)).astype(np.float32)
    cin = wp.array(colors, dtype=wp.vec3, device=device)
    mk = wp.array(m.astype(np.uint8), dtype=wp.uint8, device=device)
    out = wp.zeros((h, w), dtype=wp.vec3, device=device)
    # sibson off: Voronoi color of the stage's own nearest map
    st_off = ReconstructStage(w, h, ReconstructionConfig(sibson=False), block=k, device=device)
    st_off.run(cin, mk, out)
    n = st_off.nearest.numpy()
    assert np.array_equal(out.numpy(), colors[n[..., 1], n[..., 0]])
    # sibson on (defaults: 1+jfa, bounded start, J from the block)
    stage = ReconstructStage(w, h, ReconstructionConfig(), block=k, device=device)
    assert stage.window == sibson_window_for_block(k) and stage.start_step == 8
    stage.run(cin, mk, out)
    n = stage.nearest.numpy()
    np.testing.assert_allclose(out.numpy(), ref_sibson(colors, n), atol=TOL, rtol=0)
    yy, xx = np.mgrid[0:h, 0:w]
    d2 = (n[..., 0] - xx) ** 2 + (n[..., 1] - yy) ** 2
    assert int(stage.max_radius_sq.numpy()[0]) == d2.max()
    assert abs(float(stage.max_radius.numpy()[0]) - np.sqrt(d2.max())) < 1e-5
    assert int(stage.unreached.numpy()[0]) == 0
    # next frame with a different mask reuses the buffers and resets the stats
    m2 = np.ones((h, w), np.uint8)
    stage.run(cin, wp.array(m2, dtype=wp.uint8, device=device), out)
    assert np.array_equal(out.numpy(), colors) and float(stage.max_radius.numpy()[0]) == 0.0
    # exact stage agrees with the bounded one under the guarantee
    ex = ReconstructStage(w, h, ReconstructionConfig(), block=k, device=device, exact_sibson=True)
    out2 = wp.zeros((h, w), dtype=wp.vec3, device=device)
    stage.run(cin, mk, out)
    ex.run(cin, mk, out2)
    np.testing.assert_allclose(out.numpy(), out2.numpy(), atol=TOL, rtol=0)


@pytest.mark.parametrize("shape", [(1, 1), (7, 300), (17, 16), (61, 97)])
def test_max_radius_reduction_sizes(shape, device, rng):
    """The block-tiled max reduction covers every pixel whatever the image size."""
    h, w = shape
    m = np.zeros((h, w), bool)
    m[rng.integers(h), rng.integers(w)] = True
    _, r = ops.sibson(np.zeros((h, w, 3)), m, window=1, return_max_radius=True, device=device)
    assert abs(r - np.sqrt(ops_exact_max_d2(m))) < 1e-4


def ops_exact_max_d2(mask):
    h, w = mask.shape
    n = edt_nearest(mask)
    yy, xx = np.mgrid[0:h, 0:w]
    return int(((n[..., 0] - xx) ** 2 + (n[..., 1] - yy) ** 2).max())


@wp.kernel(enable_backward=False)
def _isqrt_test_kernel(n: wp.array(dtype=wp.int32), r: wp.array(dtype=wp.int32)):
    i = wp.tid()
    r[i] = isqrt(n[i])


@wp.kernel(enable_backward=False)
def _disc_sum_kernel(vor: wp.array2d(dtype=wp.vec3), r2: wp.array2d(dtype=wp.int32), rw: int, rmax2: int,
                     scale: float, out: wp.array2d(dtype=wp.vec4)):
    y, x = wp.tid()
    out[y, x] = disc_sum(vor, r2, x, y, rw, rmax2, scale)


def _disc_sums(vor, r2, rw, rmax2, scale, device):
    h, w = r2.shape
    out = wp.zeros((h, w), dtype=wp.vec4, device=device)
    wp.launch(_disc_sum_kernel, dim=(h, w), inputs=[wp.array(vor, dtype=wp.vec3, device=device),
              wp.array(r2, dtype=wp.int32, device=device), rw, rmax2, scale], outputs=[out], device=device)
    return out.numpy()


def _disc_sum_numpy(vor, r2, rw, rmax2):
    """(sum, count) of the taps the gather visits, |dy| <= rw and (dx == 0, or |dx| <= rw and dx^2 + dy^2 <=
    rmax2), inside the image, that reach p (dx^2 + dy^2 <= r2[q]): summed in float32 one tap at a time in raster
    order (dy, then dx), the order the gather adds them in, so the sums must match bit for bit."""
    h, w = r2.shape
    out = np.zeros((h, w, 4), np.float32)
    for y in range(h):
        for x in range(w):
            acc = np.zeros(3, np.float32)
            n = 0
            for dy in range(-rw, rw + 1):
                for dx in range(-rw, rw + 1):
                    d2 = dx * dx + dy * dy
                    qy, qx = y + dy, x + dx
                    if (dx != 0 and d2 > rmax2) or not (0 <= qy < h and 0 <= qx < w) or d2 > r2[qy, qx]:
                        continue
                    acc = (acc + vor[qy, qx]).astype(np.float32)
                    n += 1
            out[y, x, :3] = acc
            out[y, x, 3] = n
    return out


@pytest.mark.parametrize("rmax2", [0, 2, 5, 9, 13, 18])
def test_disc_sum_row_loop(rmax2, device, rng):
    """The gather's tap loop (native code: row addresses formed once, taps by offsets, the row half-width counted
    down from the window) against a float32 NumPy sum of the same taps in the same order, bit for bit, at windows
    0..5; a border of non-reaching pixels (r^2 = -1) around the image leaves every sum the same bits (the border
    clipping skips only taps that cannot reach)."""
    h, w = 21, 26
    r2 = rng.integers(-1, rmax2 + 1, size=(h, w)).astype(np.int32)
    vor = (rng.normal(size=(h, w, 3)) * 5).astype(np.float32)
    for rw in range(6):
        ref = _disc_sum_numpy(vor, r2, rw, rmax2)
        got = _disc_sums(vor, r2, rw, rmax2, 1.0, device)
        np.testing.assert_array_equal(got.view(np.uint32), ref.view(np.uint32))
    pr2 = np.pad(r2, 5, constant_values=-1)
    pvor = np.pad(vor, ((5, 5), (5, 5), (0, 0)), constant_values=1e30)  # never read: r^2 = -1 reaches nothing
    four = _disc_sums(vor, r2, 4, rmax2, 1.0, device)
    padded = _disc_sums(pvor, pr2, 4, rmax2, 1.0, device)[5:-5, 5:-5]
    np.testing.assert_array_equal(padded.view(np.uint32), four.view(np.uint32))


@pytest.mark.parametrize("rw, rmax2", [(16, 200), (17, 300), (20, 120)])
def test_disc_sum_wide_windows(rw, rmax2, device, rng):
    """Windows above 16 take the square-root form of the row half-width: the same taps and sums, bit for bit."""
    h, w = 23, 45
    r2 = rng.integers(-1, rmax2 + 1, size=(h, w)).astype(np.int32)
    vor = (rng.normal(size=(h, w, 3)) * 5).astype(np.float32)
    ref = _disc_sum_numpy(vor, r2, rw, rmax2)
    got = _disc_sums(vor, r2, rw, rmax2, 1.0, device)
    np.testing.assert_array_equal(got.view(np.uint32), ref.view(np.uint32))


def test_isqrt_exact(device):
    """floor(sqrt(n)) must be exact for every squared distance of a 16384 x 16384 image (< 2^29.1)."""
    k = np.arange(0, 23200, dtype=np.int64)
    n = np.unique(np.concatenate([k * k - 1, k * k, k * k + 1, np.arange(0, 5000), [2 * 16383**2, -5]]))
    n = n[n >= -5].astype(np.int32)
    r = wp.zeros(n.size, dtype=wp.int32, device=device)
    wp.launch(_isqrt_test_kernel, dim=n.size, inputs=[wp.array(n, dtype=wp.int32, device=device)], outputs=[r],
              device=device)
    ref = np.array([math.isqrt(int(v)) if v > 0 else 0 for v in n])
    assert np.array_equal(r.numpy(), ref)


def test_stage_guards_non_finite_seed_colors(device):
    """ops rejects NaN seeds; the stage (per frame, no host checks) must still emit finite colors: a seed
    whose color is not finite counts as black."""
    h, w = 9, 12
    m = np.zeros((h, w), np.uint8)
    m[2, 3] = m[6, 9] = 1
    colors = np.zeros((h, w, 3), np.float32)
    colors[2, 3] = (np.nan, 1.0, 0.0)
    colors[6, 9] = (0.5, np.inf, 0.25)
    stage = ReconstructStage(w, h, ReconstructionConfig(), block=4, device=device)
    out = wp.zeros((h, w), dtype=wp.vec3, device=device)
    stage.run(wp.array(colors, dtype=wp.vec3, device=device), wp.array(m, dtype=wp.uint8, device=device), out)
    o = out.numpy()
    assert np.all(np.isfinite(o)) and np.all(o == 0.0)


def test_max_radius_one(device):
    """Checkerboard seeds: every r_q is 0 or 1, so the largest radius is exactly 1."""
    h, w = 10, 13
    m = (np.add.outer(np.arange(h), np.arange(w)) % 2) == 0
    rng = np.random.default_rng(5)
    colors = rng.random((h, w, 3)).astype(np.float32)
    out, r = ops.sibson(colors, m, window=1, return_max_radius=True, device=device)
    assert r == 1.0
    np.testing.assert_allclose(out, ref_sibson(colors, ops.jump_flood(m, device=device)),
                               atol=TOL, rtol=0)


def test_input_validation(device):
    c = np.zeros((4, 5, 3))
    m = np.ones((4, 5))
    with pytest.raises(ValueError, match="window"):
        ops.sibson(c, m, window=0, device=device)
    with pytest.raises(ValueError, match="window"):
        ops.sibson(c, m, window=257, device=device)
    with pytest.raises(ValueError, match="colors"):
        ops.sibson(np.zeros((4, 5, 4)), m, device=device)
    with pytest.raises(ValueError, match="colors"):
        ops.sibson(np.full((4, 5, 3), np.nan), m, device=device)
    bad = edt_nearest(m > 0)
    bad[0, 0] = (3, 3)  # a seed must map to itself
    with pytest.raises(ValueError, match="nearest"):
        ops.sibson(c, m, nearest=bad, device=device)
    m2 = np.zeros((4, 5))
    m2[1, 1] = 1
    bad = edt_nearest(m2 > 0)
    bad[3, 3] = (4, 3)  # not a seed
    with pytest.raises(ValueError, match="nearest"):
        ops.sibson(c, m2, nearest=bad, device=device)
    with pytest.raises(ValueError, match="nearest"):
        ops.sibson(c, m2, nearest=np.zeros((4, 5, 3), np.int32), device=device)
    stage = ReconstructStage(5, 4, ReconstructionConfig(), block=4, device=device)
    a = wp.zeros((4, 5), dtype=wp.vec3, device=device)
    with pytest.raises(ValueError, match="color_out"):
        stage.run(a, wp.zeros((4, 5), dtype=wp.uint8, device=device), a)
    with pytest.raises(ValueError, match="color_in"):
        stage.run(wp.zeros((4, 6), dtype=wp.vec3, device=device), wp.zeros((4, 5), dtype=wp.uint8, device=device),
                  a)


@settings(max_examples=30, deadline=None)
@given(h=st.integers(1, 14), w=st.integers(1, 14), density=st.sampled_from([0.0, 0.03, 0.15, 0.6, 1.0]),
       seed=st.integers(0, 2**31 - 1), window=st.sampled_from([None, 1, 3, 20]))
def test_sibson_properties(h, w, density, seed, window):
    rng = np.random.default_rng(seed)
    m = rng.random((h, w)) < density
    colors = rng.uniform(-2.0, 5.0, (h, w, 3)).astype(np.float32)
    near = edt_nearest(m)
    out = ops.sibson(colors, m, window=window, nearest=near, device="cpu")
    assert np.all(np.isfinite(out))
    assert np.array_equal(out[m], colors[m])
    if m.any():
        lo, hi = colors[m].min(0), colors[m].max(0)
        assert np.all(out >= lo - 1e-5) and np.all(out <= hi + 1e-5)  # a convex combination of seed colors
    else:
        assert np.all(out == 0.0)
    np.testing.assert_allclose(out, ref_sibson(colors, near, window), atol=1e-5, rtol=1e-6)
