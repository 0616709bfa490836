"""Stress: reconstruction (jump flooding, Voronoi fill, bounded and exact Sibson; ALGORITHMS.md A5-A6) and
compaction (A3) on seed sets that are empty, a single pixel, full, collinear (rows, columns, diagonals,
arbitrary lines), on the border only, in clusters, random at any density; colors from 0 up to +-float max."""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st
from scipy import ndimage

from foveawarp import ops
from stress_util import F32_MAX, assert_finite, examples

VARIANTS = ("jfa", "jfa+1", "jfa+2", "1+jfa")
KINDS = ("empty", "single", "full", "row", "column", "diagonal", "line", "border", "cluster", "random",
         "two_tie", "corners")


def make_mask(kind, h, w, rng):
    m = np.zeros((h, w), dtype=bool)
    if kind == "empty":
        return m
    if kind == "single":
        m[rng.integers(h), rng.integers(w)] = True
    elif kind == "full":
        m[:] = True
    elif kind == "row":
        y = rng.integers(h)
        xs = rng.random(w) < rng.uniform(0.05, 1.0)
        xs[rng.integers(w)] = True
        m[y, xs] = True
    elif kind == "column":
        x = rng.integers(w)
        ys = rng.random(h) < rng.uniform(0.05, 1.0)
        ys[rng.integers(h)] = True
        m[ys, x] = True
    elif kind == "diagonal":
        n = min(h, w)
        t = np.arange(n)
        sel = rng.random(n) < rng.uniform(0.1, 1.0)
        sel[rng.integers(n)] = True
        if rng.random() < 0.5:
            m[t[sel], t[sel]] = True
        else:
            m[t[sel], (w - 1 - t)[sel]] = True
    elif kind == "line":  # pixels on an arbitrary digital line
        x0, y0 = rng.uniform(0, w), rng.uniform(0, h)
        ang = rng.uniform(0, np.pi)
        s = np.arange(-max(h, w), max(h, w), rng.uniform(0.7, 4.0))
        xs = np.floor(x0 + s * np.cos(ang)).astype(int)
        ys = np.floor(y0 + s * np.sin(ang)).astype(int)
        ok = (xs >= 0) & (xs < w) & (ys >= 0) & (ys < h)
        m[ys[ok], xs[ok]] = True
        if not m.any():
            m[min(int(y0), h - 1), min(int(x0), w - 1)] = True
    elif kind == "border":
        m[0, :] = m[-1, :] = m[:, 0] = m[:, -1] = True
        m &= rng.random((h, w)) < rng.uniform(0.2, 1.0)
        m[0, 0] = True
    elif kind == "cluster":
        cy, cx = rng.integers(h), rng.integers(w)
        m[max(cy - 1, 0):cy + 2, max(cx - 1, 0):cx + 2] = True
    elif kind == "random":
        m = rng.random((h, w)) < 10.0 ** rng.uniform(-3, 0)
    elif kind == "two_tie":  # two seeds symmetric about many pixels (distance ties)
        y = rng.integers(h)
        m[y, 0] = True
        m[y, w - 1] = True
        m[h - 1 - y, w // 2] = True
    elif kind == "corners":
        m[0, 0] = m[-1, -1] = m[0, -1] = m[-1, 0] = True
    return m


def exact_dist2(mask):
    """Squared Euclidean distance from every pixel to its nearest seed (SciPy's exact EDT)."""
    d = ndimage.distance_transform_edt(~mask)
    return np.rint(d * d).astype(np.int64)


def brute_sibson(colors, nearest):
    """Park et al. discrete Sibson in float64 from a nearest map: q scatters color(seed(q)) to every p with
    |p - q|^2 <= r_q^2; seeds keep their color; nothing received -> the Voronoi color."""
    h, w = nearest.shape[:2]
    yy, xx = np.mgrid[0:h, 0:w]
    nx, ny = nearest[..., 0], nearest[..., 1]
    has = nx >= 0
    vor = np.where(has[..., None], colors[np.clip(ny, 0, h - 1), np.clip(nx, 0, w - 1)].astype(np.float64), 0.0)
    r2 = np.where(has, (nx - xx) ** 2 + (ny - yy) ** 2, -1)
    acc = np.zeros((h, w, 3))
    cnt = np.zeros((h, w))
    rmax = int(np.sqrt(max(r2.max(), 0)))
    for dy in range(-rmax, rmax + 1):
        for dx in range(-rmax, rmax + 1):
            qy, qx = np.nonzero(r2 >= dx * dx + dy * dy)
            py, px = qy + dy, qx + dx
            ok = (py >= 0) & (py < h) & (px >= 0) & (px < w)
            np.add.at(acc, (py[ok], px[ok]), vor[qy[ok], qx[ok]])
            np.add.at(cnt, (py[ok], px[ok]), 1.0)
    out = np.where(cnt[..., None] > 0, acc / np.maximum(cnt, 1)[..., None], vor)
    seed = has & (nx == xx) & (ny == yy)
    return np.where(seed[..., None], vor, out)


def make_colors(mode, h, w, rng):
    if mode == "unit":
        return rng.random((h, w, 3)).astype(np.float32)
    if mode == "signed":
        return rng.normal(size=(h, w, 3)).astype(np.float32)
    if mode == "huge":  # shading of tiny scenes reaches ~1e30 (irradiance ~ I / r^2 with r^2 >= 1e-30)
        return (rng.choice([-1.0, 1.0], (h, w, 3)) * 10.0 ** rng.uniform(20, 30, (h, w, 3))).astype(np.float32)
    if mode == "f32max":
        return rng.choice([F32_MAX, -F32_MAX, 0.5 * F32_MAX, 0.0], (h, w, 3)).astype(np.float32)
    return rng.choice([0.0, 1e-45, 1e-38, 1.0], (h, w, 3)).astype(np.float32)


@examples(250, 2000)
@given(kind=st.sampled_from(KINDS), h=st.integers(1, 24), w=st.integers(1, 24), seed=st.integers(0, 2**32 - 1),
       tile=st.sampled_from([2, 4, 8, 64]), balance=st.sampled_from([0, 1, 2, 3, 8, 1024]))
def test_seed_sets_empty_single_full_collinear_jfa_and_compaction(device, cases, kind, h, w, seed, tile, balance):
    """Jump flooding (all variants) against the exact EDT, and compaction / row reordering, per seed set.
    JFA never reports a seed nearer than the nearest one, always finds one when a seed exists, keeps seeds
    on themselves, and is exact for empty / single / full sets; 1+JFA is exact on >= 99% of pixels."""
    rng = np.random.default_rng(seed)
    n = 4
    for _ in range(n):
        m = make_mask(kind, h, w, rng)
        ex = exact_dist2(m) if m.any() else None
        yy, xx = np.mgrid[0:h, 0:w]
        for variant in VARIANTS:
            near = ops.jump_flood(m.astype(np.uint8), variant=variant, device=device)
            assert near.shape == (h, w, 2)
            if not m.any():
                assert (near == -1).all()
                continue
            nx, ny = near[..., 0], near[..., 1]
            assert ((nx >= 0) & (nx < w) & (ny >= 0) & (ny < h)).all(), f"{kind} {variant}: unreached pixels"
            assert m[ny, nx].all(), f"{kind} {variant}: nearest is not a seed"
            assert ((nx == xx) & (ny == yy))[m].all(), f"{kind} {variant}: a seed lost itself"
            d2 = (nx - xx) ** 2 + (ny - yy) ** 2
            assert (d2 >= ex).all(), f"{kind} {variant}: nearer than the nearest seed"
            if kind in ("single", "full"):
                assert (d2 == ex).all(), f"{kind} {variant}: not exact"
            if variant == "1+jfa":
                assert (d2 == ex).mean() >= 0.99, f"{kind}: JFA wrong at {(d2 != ex).sum()} pixels"
        # compaction of the same masks
        flat = np.flatnonzero(m)
        for order in ("row", "tile"):
            idx = ops.compact(m, order=order, tile=tile, device=device)
            assert np.array_equal(np.sort(idx), flat), (kind, order)
            if order == "row":
                assert np.array_equal(idx, flat)
        coords, counts = ops.reorder_rows(m, device=device)
        assert np.array_equal(counts, m.sum(axis=1))
        for y in range(h):
            c = coords[y, :counts[y]]
            assert (c[:, 1] == y).all() and np.array_equal(np.sort(c[:, 0]), np.flatnonzero(m[y]))
        if balance:  # strategy 2: rows of a block within one of each other, every pixel exactly once
            coords, counts = ops.reorder_rows(m, balance_rows=balance, device=device)
            allc = np.concatenate([coords[y, :counts[y]] for y in range(h)]).astype(np.int64)
            assert np.array_equal(np.sort(allc[:, 1] * w + allc[:, 0]), flat), (kind, balance)
            for b0 in range(0, h, balance):
                assert np.ptp(counts[b0:b0 + balance]) <= 1
    cases.add("seed sets: JFA + compaction (masks)", n)


@examples(300, 2000)
@given(kind=st.sampled_from(KINDS), h=st.integers(1, 20), w=st.integers(1, 20), seed=st.integers(0, 2**32 - 1),
       cmode=st.sampled_from(["unit", "unit", "signed", "huge", "f32max", "tiny"]),
       window=st.sampled_from([None, 1, 2, 5, 40]))
def test_seed_sets_empty_single_full_collinear_voronoi_sibson(device, cases, kind, h, w, seed, cmode, window):
    """Voronoi fill and Sibson (exact scatter and bounded gather) on every seed-set family, with the exact
    nearest map (SciPy) and with JFA's: finite everywhere, seeds keep their color, every output channel
    within the seed colors' range (a mean of seed colors), zeros without seeds, and equal to a float64
    brute-force Park scatter (exact form, or bounded form when the window covers the largest radius)."""
    rng = np.random.default_rng(seed)
    m = make_mask(kind, h, w, rng)
    col = make_colors(cmode, h, w, rng)
    # values at non-seed pixels must be ignored
    col[~m] = rng.choice([F32_MAX, -F32_MAX, 7.0, -1e30], size=(int((~m).sum()), 3))
    if m.any():
        _, (iy, ix) = ndimage.distance_transform_edt(~m, return_indices=True)
        exact_near = np.stack([ix, iy], -1).astype(np.int32)
    else:
        exact_near = np.full((h, w, 2), -1, np.int32)
    vor = assert_finite("voronoi", ops.voronoi(col, m, nearest=exact_near, device=device))
    sib, rmax = ops.sibson(col, m, window=window, nearest=exact_near, return_max_radius=True, device=device)
    assert_finite(f"sibson window={window} colors={cmode}", sib)
    sib_jfa = assert_finite("sibson (JFA)", ops.sibson(col, m, window=window, device=device))
    vor_jfa = assert_finite("voronoi (JFA)", ops.voronoi(col, m, device=device))
    if not m.any():
        for a in (vor, sib, sib_jfa, vor_jfa):
            assert (a == 0).all()
        assert rmax == 0.0
        cases.add("seed sets: voronoi + sibson (masks)", 1)
        return
    sc = col[m].astype(np.float64)
    lo, hi = sc.min(axis=0), sc.max(axis=0)
    for name, a in (("voronoi", vor), ("sibson", sib), ("sibson (JFA)", sib_jfa), ("voronoi (JFA)", vor_jfa)):
        assert np.array_equal(a[m], col[m]), f"{name}: a seed changed color"
        slack = 1e-5 * np.maximum(np.abs(lo), np.abs(hi)) + 1e-6
        assert ((a >= lo - slack) & (a <= hi + slack)).all(), f"{name} ({cmode}): outside the seed color range"
    exact_r = float(np.sqrt(exact_dist2(m).max()))
    assert abs(rmax - exact_r) <= 1e-4 * max(exact_r, 1.0)
    assert np.array_equal(vor, col[exact_near[..., 1], exact_near[..., 0]])
    if window is None or window >= exact_r:
        ref = brute_sibson(col, exact_near)
        scale = np.maximum(np.abs(lo), np.abs(hi))
        np.testing.assert_allclose(sib, ref, rtol=1e-5, atol=float(1e-5 * scale.max() + 1e-6),
                                   err_msg=f"{kind} window={window} colors={cmode}")
    cases.add("seed sets: voronoi + sibson (masks)", 1)


# -- the stage's lean frame path over sequences of seed sets ---------------------------------------------


def plain_jfa(mask, steps):
    """Ping-pong JFA as ALGORITHMS.md A5 states it (init pass, then 9 taps per step, strictly nearer wins,
    taps in raster order), in NumPy: (H, W, 2) int (x, y), -1 for none."""
    h, w = mask.shape
    yy, xx = np.mgrid[0:h, 0:w]
    big = np.iinfo(np.int64).max
    cur = np.where(mask[..., None], np.stack([xx, yy], -1), -1).astype(np.int64)
    for k in steps:
        nxt = cur.copy()
        bd = np.where(cur[..., 0] >= 0, (cur[..., 0] - xx) ** 2 + (cur[..., 1] - yy) ** 2, big)
        for j in (-1, 0, 1):
            for i in (-1, 0, 1):
                if i or j:
                    sy, sx = yy + j * k, xx + i * k
                    ok = (sy >= 0) & (sy < h) & (sx >= 0) & (sx < w)
                    c = np.full((h, w, 2), -1, np.int64)
                    c[ok] = cur[sy[ok], sx[ok]]
                    d = np.where(c[..., 0] >= 0, (c[..., 0] - xx) ** 2 + (c[..., 1] - yy) ** 2, big)
                    better = d < bd
                    nxt[better], bd[better] = c[better], d[better]
        cur = nxt
    return cur


def code4_f32(colors, nearest, window):
    """Code 4's bounded gather in float32 over all pixels at once, offsets in raster order (a tap that does
    not cover adds +0.0, which changes no sum of non-negative colors): bit-equal to the kernel's sum."""
    h, w = nearest.shape[:2]
    yy, xx = np.mgrid[0:h, 0:w]
    nx, ny = nearest[..., 0], nearest[..., 1]
    has = nx >= 0
    vor = np.where(has[..., None], colors[ny.clip(0), nx.clip(0)], 0).astype(np.float32)
    r2 = np.where(has, (nx - xx) ** 2 + (ny - yy) ** 2, -1)
    rw = min(window, int(np.sqrt(max(int(r2.max()), 0))))
    acc = np.zeros((h, w, 3), np.float32)
    n = np.zeros((h, w), np.int64)
    for dy in range(-rw, rw + 1):
        for dx in range(-rw, rw + 1):
            qy, qx = yy + dy, xx + dx
            ok = (qy >= 0) & (qy < h) & (qx >= 0) & (qx < w)
            cov = np.zeros((h, w), bool)
            cov[ok] = dx * dx + dy * dy <= r2[qy[ok], qx[ok]]
            add = np.zeros((h, w, 3), np.float32)
            add[cov] = vor[qy[cov], qx[cov]]
            acc = (acc + add).astype(np.float32)
            n += cov
    out = np.where((n > 0)[..., None], acc / np.maximum(n, 1).astype(np.float32)[..., None], vor)
    seed = has & (nx == xx) & (ny == yy)
    return np.where(seed[..., None], vor, out).astype(np.float32)


@examples(120, 1200)
@given(kinds=st.lists(st.sampled_from(KINDS + ("filled",)), min_size=2, max_size=4), h=st.integers(1, 22),
       w=st.integers(1, 22), seed=st.integers(0, 2**32 - 1), variant=st.sampled_from(VARIANTS),
       block=st.integers(1, 8), bounded=st.booleans(), window=st.sampled_from([None, 1, 2, 6]),
       sibson_on=st.booleans())
def test_stage_lean_path_over_frames(device, cases, kinds, h, w, seed, variant, block, bounded, window, sibson_on):
    """One ReconstructStage over a sequence of seed sets (entries it skips at seeds hold older frames'
    values): nearest equals the plain ping-pong JFA, colors equal Code 4's float32 gather (Sibson on) or the
    Voronoi fill (off) bit for bit, the statistics match, seeds keep their color."""
    import warp as wp

    from foveawarp import ReconstructionConfig
    from foveawarp.stages.reconstruct import ReconstructStage

    rng = np.random.default_rng(seed)
    cfg = ReconstructionConfig(jfa_variant=variant, sibson=sibson_on, sibson_window=window,
                               bounded_jfa_start=bounded)
    stage = ReconstructStage(w, h, cfg, block=block, device=device)
    out = wp.zeros((h, w), dtype=wp.vec3, device=device)
    yy, xx = np.mgrid[0:h, 0:w]
    for kind in kinds:
        if kind == "filled":
            m = ~(rng.random((h, w)) < 0.08) | (rng.random((h, w)) < 0.1)
        else:
            m = make_mask(kind, h, w, rng)
        col = make_colors("unit", h, w, rng)
        stage.run(wp.array(col, dtype=wp.vec3, device=device), wp.array(m.astype(np.uint8), dtype=wp.uint8,
                                                                        device=device), out)
        o = out.numpy()
        n = stage.nearest.numpy()
        ref_n = plain_jfa(m, stage.steps)
        assert np.array_equal(n, ref_n), f"{kind}: nearest differs from the plain JFA"
        reached = ref_n[..., 0] >= 0
        d2 = np.where(reached, (ref_n[..., 0] - xx) ** 2 + (ref_n[..., 1] - yy) ** 2, 0)
        assert int(stage.unreached.numpy()[0]) == int((~reached).sum())
        assert int(stage.max_radius_sq.numpy()[0]) == int(d2.max())
        if sibson_on:
            ref = code4_f32(col, ref_n, stage.window)
        else:
            ref = np.where(reached[..., None], col[ref_n[..., 1].clip(0), ref_n[..., 0].clip(0)], 0)
        assert np.array_equal(o, ref.astype(np.float32)), f"{kind}: colors differ ({np.abs(o - ref).max()})"
        assert np.array_equal(o[m], col[m])
    cases.add("stage lean path: frames of seed sets", len(kinds))
