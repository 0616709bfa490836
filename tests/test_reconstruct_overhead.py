"""The reconstruction stage's lean frame path against independent references.

The stage skips work at seed pixels (one mask read per JFA pass, seed entries written once), fuses the JFA
init into the first pass and the Voronoi / radius / statistics pass into the last one, and clips the Sibson
gather's window to the largest radius of the 16 x 16 screen tiles the window overlaps. None of this may
change a bit of the result, so the references here are exact:

* ``ref_jfa``: plain ping-pong JFA in NumPy (init pass, then one 9-tap pass per step, strictly-nearer
  replacement in raster tap order): ``nearest`` must be EQUAL, and never nearer than SciPy's EDT.
* ``ref_gather_f32``: Code 4's gather in NumPy float32, accumulating the covering taps of the full
  [p - J, p + J]^2 box in raster order, then one division: the stage's colors must be BIT-EQUAL (colors in
  [0, 1], so the overflow-safe fallback is not involved).
Masks: mostly filled (a few clustered holes: the temporal fill), sparse, block-guarantee masks at block 1..8,
empty, all seeds, a single hole, one seed; masks that change from frame to frame (stale entries of the
skipped seed pixels must never leak).
"""

import math

import numpy as np
import pytest
import warp as wp
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import ndimage

from foveawarp import ReconstructionConfig, ops
from foveawarp.stages.reconstruct import ReconstructStage, jfa_start_step_for_block, sibson_window_for_block

# -- independent references --------------------------------------------------------------------------------


def ref_jfa(mask, steps):
    """Plain JFA: (H, W, 2) int32 (x, y), (-1, -1) for none."""
    h, w = mask.shape
    yy, xx = np.mgrid[0:h, 0:w]
    cur = np.where(mask[..., None], np.stack([xx, yy], -1), -1).astype(np.int64)
    for k in steps:
        best = cur.copy()
        bd = np.where(best[..., 0] >= 0, (best[..., 0] - xx) ** 2 + (best[..., 1] - yy) ** 2, np.iinfo(np.int64).max)
        for j in (-1, 0, 1):
            for i in (-1, 0, 1):
                if i == 0 and j == 0:
                    continue
                sy, sx = yy + j * k, xx + i * k
                ok = (sy >= 0) & (sy < h) & (sx >= 0) & (sx < w)
                cand = np.full((h, w, 2), -1, np.int64)
                cand[ok] = cur[sy[ok], sx[ok]]
                d = np.where(cand[..., 0] >= 0, (cand[..., 0] - xx) ** 2 + (cand[..., 1] - yy) ** 2,
                             np.iinfo(np.int64).max)
                better = d < bd
                best[better] = cand[better]
                bd[better] = d[better]
        cur = best
    return cur.astype(np.int32)


def ref_gather_f32(colors, nearest, window):
    """Bounded Sibson gather in float32, box window in raster order (no clipping besides the image)."""
    h, w = nearest.shape[:2]
    yy, xx = np.mgrid[0:h, 0:w]
    nx, ny = nearest[..., 0], nearest[..., 1]
    has = nx >= 0
    vor = np.where(has[..., None], colors[np.clip(ny, 0, h - 1), np.clip(nx, 0, w - 1)], 0).astype(np.float32)
    r2 = np.where(has, (nx - xx).astype(np.int64) ** 2 + (ny - yy).astype(np.int64) ** 2, -1)
    seed = has & (nx == xx) & (ny == yy)
    rw = min(window, math.isqrt(max(int(r2.max()), 0)))
    out = vor.copy()
    for y, x in zip(*np.nonzero(~seed)):
        acc = np.zeros(3, np.float32)
        n = 0
        for dy in range(max(-rw, -y), min(rw, h - 1 - y) + 1):
            for dx in range(max(-rw, -x), min(rw, w - 1 - x) + 1):
                if dx * dx + dy * dy <= r2[y + dy, x + dx]:
                    acc = (acc + vor[y + dy, x + dx]).astype(np.float32)
                    n += 1
        if n:
            out[y, x] = acc / np.float32(n)
    return out


def edt_d2(mask):
    h, w = mask.shape
    _, (iy, ix) = ndimage.distance_transform_edt(~mask, return_indices=True)
    yy, xx = np.mgrid[0:h, 0:w]
    return (iy - yy) ** 2 + (ix - xx) ** 2


def block_mask(h, w, k, extra, rng):
    m = rng.random((h, w)) < extra
    for ty in range(0, h, k):
        for tx in range(0, w, k):
            m[ty + rng.integers(min(k, h - ty)), tx + rng.integers(min(k, w - tx))] = True
    return m


def filled_mask(h, w, k, rng, holes=6):
    """Block-guarantee samples plus everything outside a few random slivers / blobs (the temporal fill)."""
    hole = np.zeros((h, w), bool)
    yy, xx = np.mgrid[0:h, 0:w]
    for _ in range(holes):
        cx, cy = rng.uniform(0, w), rng.uniform(0, h)
        a, b, t = rng.uniform(2, 9), rng.uniform(0.7, 3), rng.uniform(0, np.pi)
        u = (xx - cx) * np.cos(t) + (yy - cy) * np.sin(t)
        v = -(xx - cx) * np.sin(t) + (yy - cy) * np.cos(t)
        hole |= (u / a) ** 2 + (v / b) ** 2 <= 1
    return block_mask(h, w, k, 0.0, rng) | ~hole


def half_mask(h, w, rng):
    """Dense left half, sparse right half: tiles with very different largest radii (local window clip)."""
    m = np.zeros((h, w), bool)
    m[:, : w // 2] = rng.random((h, w // 2)) < 0.7
    m[:, w // 2:] = rng.random((h, w - w // 2)) < 0.03
    m[rng.integers(h), rng.integers(w)] = True
    return m


def run_stage(stage, colors, mask, device):
    h, w = mask.shape
    out = wp.zeros((h, w), dtype=wp.vec3, device=device)
    stage.run(wp.array(colors, dtype=wp.vec3, device=device), wp.array(mask.astype(np.uint8), dtype=wp.uint8,
                                                                         device=device), out)
    return out.numpy()


MASKS = {
    "filled-k4": lambda h, w, r: filled_mask(h, w, 4, r),
    "filled-k8": lambda h, w, r: filled_mask(h, w, 8, r, holes=3),
    "block4": lambda h, w, r: block_mask(h, w, 4, 0.1, r),
    "sparse": lambda h, w, r: r.random((h, w)) < 0.05,
    "half": half_mask,
    "one-hole": lambda h, w, r: ~(np.arange(h * w).reshape(h, w) == r.integers(h * w)),
    "one-seed": lambda h, w, r: np.arange(h * w).reshape(h, w) == r.integers(h * w),
    "empty": lambda h, w, r: np.zeros((h, w), bool),
    "all": lambda h, w, r: np.ones((h, w), bool),
}

# -- JFA: equal to the plain ping-pong JFA -----------------------------------------------------------------


@pytest.mark.parametrize("kind", list(MASKS))
@pytest.mark.parametrize("variant", ["jfa", "1+jfa", "jfa+2"])
def test_jfa_equals_plain_pingpong(kind, variant, device, rng):
    h, w = 37, 70
    m = MASKS[kind](h, w, rng)
    for bounded in (False, True):
        stage = ReconstructStage(w, h, ReconstructionConfig(jfa_variant=variant, bounded_jfa_start=bounded),
                                 block=4, device=device)
        stage.run_jfa(wp.array(m.astype(np.uint8), dtype=wp.uint8, device=device))
        n = stage.nearest.numpy()
        np.testing.assert_array_equal(n, ref_jfa(m, stage.steps))
        if m.any():
            yy, xx = np.mgrid[0:h, 0:w]
            d2 = (n[..., 0] - xx) ** 2 + (n[..., 1] - yy) ** 2
            assert np.all(d2[n[..., 0] >= 0] >= edt_d2(m)[n[..., 0] >= 0])
            # statistics of the fused last pass
            reached = n[..., 0] >= 0
            assert int(stage.unreached.numpy()[0]) == int((~reached).sum())
            assert int(stage.max_radius_sq.numpy()[0]) == int(d2[reached].max())
            assert float(stage.max_radius.numpy()[0]) == np.float32(np.sqrt(np.float32(d2[reached].max())))
            r2 = stage.radius_sq.numpy()
            # r_q^2 at the non-seeds, -1 at the seeds (the gather's taps read nothing else)
            np.testing.assert_array_equal(r2, np.where(m | ~reached, -1, d2))
            t = stage.tile_radius_sq.numpy()
            for ty in range(t.shape[0]):
                for tx in range(t.shape[1]):
                    blk = np.where(~m & reached, d2, 0)[ty * 16:ty * 16 + 16, tx * 16:tx * 16 + 16]
                    assert t[ty, tx] == blk.max()
        else:
            assert np.all(n == -1) and int(stage.unreached.numpy()[0]) == h * w


@pytest.mark.parametrize("k", range(1, 9))
def test_block_guarantee_masks_block_1_to_8(k, device, rng):
    """Under the k x k guarantee the bounded start reaches every pixel, JFA stays within the bound, and the
    stage (1+JFA, bounded start, J from the block) equals the float32 Code 4 gather bit for bit."""
    h, w = 29, 45
    for extra in (0.0, 0.3):
        m = block_mask(h, w, k, extra, rng) if extra == 0.0 else filled_mask(h, w, k, rng, holes=4)
        colors = rng.random((h, w, 3)).astype(np.float32)
        stage = ReconstructStage(w, h, ReconstructionConfig(), block=k, device=device)
        assert stage.start_step == jfa_start_step_for_block(k) and stage.window == sibson_window_for_block(k)
        out = run_stage(stage, colors, m, device)
        n = stage.nearest.numpy()
        assert int(stage.unreached.numpy()[0]) == 0
        assert int(stage.max_radius_sq.numpy()[0]) <= 2 * (k - 1) ** 2
        np.testing.assert_array_equal(n, ref_jfa(m, stage.steps))
        assert np.array_equal(out, ref_gather_f32(colors, n, stage.window))
        assert np.array_equal(out[m], colors[m])


# -- the gather: bit-equal to Code 4 in raster order -------------------------------------------------------


@pytest.mark.parametrize("kind", list(MASKS))
def test_gather_bit_equal_to_code4(kind, device, rng):
    h, w = 40, 57
    m = MASKS[kind](h, w, rng)
    colors = rng.random((h, w, 3)).astype(np.float32)
    for window in (1, 4, 9):
        stage = ReconstructStage(w, h, ReconstructionConfig(bounded_jfa_start=False), block=4, device=device,
                                 window=window)
        out = run_stage(stage, colors, m, device)
        ref = ref_gather_f32(colors, stage.nearest.numpy(), window)
        assert np.array_equal(out, ref), (kind, window, np.abs(out - ref).max())


def test_local_window_clip_is_exact(device, rng):
    """Dense and sparse halves: tiles of the dense half have a much smaller largest radius than the image's,
    so their windows are clipped harder; the result must still be the full-window gather's, and the exact
    scatter's when J covers every radius."""
    h, w = 48, 80
    m = half_mask(h, w, rng)
    colors = rng.random((h, w, 3)).astype(np.float32)
    stage = ReconstructStage(w, h, ReconstructionConfig(bounded_jfa_start=False), block=4, device=device,
                             window=64)
    out = run_stage(stage, colors, m, device)
    t = stage.tile_radius_sq.numpy()
    assert t[:, 0].max() * 4 < int(stage.max_radius_sq.numpy()[0])  # the clip really differs per tile
    n = stage.nearest.numpy()
    assert np.array_equal(out, ref_gather_f32(colors, n, 64))
    exact = ops.sibson(colors, m, nearest=n, device=device)
    np.testing.assert_allclose(out, exact, atol=1e-5, rtol=0)


def test_sibson_off_voronoi_fill(device, rng):
    h, w = 33, 50
    for kind in ("filled-k4", "sparse", "empty", "all"):
        m = MASKS[kind](h, w, rng)
        colors = rng.random((h, w, 3)).astype(np.float32)
        stage = ReconstructStage(w, h, ReconstructionConfig(sibson=False), block=4, device=device)
        out = run_stage(stage, colors, m, device)
        n = ref_jfa(m, stage.steps)
        ref = np.where((n[..., 0] >= 0)[..., None], colors[n[..., 1].clip(0), n[..., 0].clip(0)], 0.0)
        assert np.array_equal(out, ref.astype(np.float32)), kind


# -- frame to frame: skipped seed entries must never leak ---------------------------------------------------


@pytest.mark.parametrize("variant", ["jfa", "1+jfa", "jfa+1", "jfa+2"])
def test_changing_masks_match_a_fresh_stage(variant, device, rng):
    """One stage run over a sequence of masks (seeds appear and disappear, so the entries it does not rewrite
    at seeds hold older frames' values) gives exactly what a fresh stage gives for each mask."""
    h, w = 35, 52
    cfg = ReconstructionConfig(jfa_variant=variant)
    seq = [MASKS[k](h, w, rng) for k in ("sparse", "filled-k4", "half", "all", "one-hole", "empty", "block4",
                                         "filled-k8")]
    for sibson_on in (True, False):
        cfg_i = ReconstructionConfig(jfa_variant=variant, sibson=sibson_on)
        stage = ReconstructStage(w, h, cfg_i, block=4, device=device)
        for m in seq:
            colors = rng.random((h, w, 3)).astype(np.float32)
            a = run_stage(stage, colors, m, device)
            fresh = ReconstructStage(w, h, cfg_i, block=4, device=device)
            b = run_stage(fresh, colors, m, device)
            assert np.array_equal(a, b)
            np.testing.assert_array_equal(stage.nearest.numpy(), fresh.nearest.numpy())
            for name in ("max_radius_sq", "max_radius", "unreached", "tile_radius_sq"):
                np.testing.assert_array_equal(getattr(stage, name).numpy(), getattr(fresh, name).numpy())
    assert cfg.jfa_variant == variant


def test_run_interpolate_standalone(device, rng):
    """run_jfa without colors, then run_interpolate: the Voronoi colors are recomputed for these colors;
    a given nearest map works without run_jfa; neither map given is a ValueError naming nearest."""
    h, w = 30, 41
    m = filled_mask(h, w, 4, rng)
    colors = rng.random((h, w, 3)).astype(np.float32)
    cin = wp.array(colors, dtype=wp.vec3, device=device)
    out = wp.zeros((h, w), dtype=wp.vec3, device=device)
    stage = ReconstructStage(w, h, ReconstructionConfig(), block=4, device=device)
    with pytest.raises(ValueError, match="nearest"):
        stage.run_interpolate(cin, out)
    stage.run_jfa(wp.array(m.astype(np.uint8), dtype=wp.uint8, device=device))
    stage.run_interpolate(cin, out)
    ref = ref_gather_f32(colors, stage.nearest.numpy(), stage.window)
    assert np.array_equal(out.numpy(), ref)
    # the same colors again with other contents: not stale
    colors2 = rng.random((h, w, 3)).astype(np.float32)
    cin.assign(colors2)
    stage.run_interpolate(cin, out)
    assert np.array_equal(out.numpy(), ref_gather_f32(colors2, stage.nearest.numpy(), stage.window))
    # given nearest map on a fresh stage
    st2 = ReconstructStage(w, h, ReconstructionConfig(), block=4, device=device)
    near = wp.array(stage.nearest.numpy(), dtype=wp.vec2i, device=device)
    st2.run_interpolate(cin, out, nearest=near)
    assert np.array_equal(out.numpy(), ref_gather_f32(colors2, stage.nearest.numpy(), stage.window))


# -- property tests for degenerate cases -------------------------------------------------------------------


@st.composite
def masks(draw):
    h = draw(st.integers(1, 24))
    w = draw(st.integers(1, 24))
    kind = draw(st.sampled_from(["random", "holes", "empty", "all", "one-hole", "one-seed", "row", "column"]))
    seed = draw(st.integers(0, 2**31 - 1))
    rng = np.random.default_rng(seed)
    if kind == "random":
        m = rng.random((h, w)) < draw(st.sampled_from([0.02, 0.2, 0.6, 0.95]))
    elif kind == "holes":
        m = ~(rng.random((h, w)) < 0.04)
        m = ~ndimage.binary_dilation(~m, iterations=int(rng.integers(0, 3)))
    elif kind == "empty":
        m = np.zeros((h, w), bool)
    elif kind == "all":
        m = np.ones((h, w), bool)
    elif kind in ("one-hole", "one-seed"):
        m = np.arange(h * w).reshape(h, w) == rng.integers(h * w)
        m = ~m if kind == "one-hole" else m
    elif kind == "row":
        m = np.zeros((h, w), bool)
        m[rng.integers(h)] = True
    else:
        m = np.zeros((h, w), bool)
        m[:, rng.integers(w)] = True
    return m, rng.random((h, w, 3)).astype(np.float32)


@settings(max_examples=60, deadline=None)
@given(mc=masks(), variant=st.sampled_from(["jfa", "jfa+1", "jfa+2", "1+jfa"]), block=st.integers(1, 8),
       bounded=st.booleans(), window=st.sampled_from([None, 1, 3, 12]))
def test_stage_properties(mc, variant, block, bounded, window):
    m, colors = mc
    h, w = m.shape
    stage = ReconstructStage(w, h, ReconstructionConfig(jfa_variant=variant, bounded_jfa_start=bounded,
                                                        sibson_window=window), block=block, device="cpu")
    out = run_stage(stage, colors, m, "cpu")
    n = stage.nearest.numpy()
    np.testing.assert_array_equal(n, ref_jfa(m, stage.steps))
    assert np.array_equal(out, ref_gather_f32(colors, n, stage.window))
    assert np.all(np.isfinite(out))
    assert np.array_equal(out[m], colors[m])
    if not m.any():
        assert np.all(out == 0.0)
