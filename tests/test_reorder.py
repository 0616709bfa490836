"""Compaction / reordering against NumPy references (thesis A3 strategies 1 and 2, scan and Morton tiles)."""

import numpy as np
import pytest
import warp as wp
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

import foveawarp as fw
from foveawarp.stages.reorder import ReorderStage


def morton_ref(tx, ty):
    """Bit-by-bit interleave (independent of the stage's magic-number version)."""
    code = 0
    for b in range(16):
        code |= ((tx >> b) & 1) << (2 * b)
        code |= ((ty >> b) & 1) << (2 * b + 1)
    return code


def tile_order_ref(mask, tile):
    h, w = mask.shape
    out = []
    tiles = [(morton_ref(tx, ty), ty, tx) for ty in range((h + tile - 1) // tile) for tx in range((w + tile - 1) // tile)]
    for _, ty, tx in sorted(tiles):
        for y in range(ty * tile, min(h, ty * tile + tile)):
            for x in range(tx * tile, min(w, tx * tile + tile)):
                if mask[y, x]:
                    out.append(y * w + x)
    return np.array(out, dtype=np.int64)


def rows_ref(mask):
    h, w = mask.shape
    coords = [[(x, y) for x in range(w) if mask[y, x]] for y in range(h)]
    return coords


def balance_ref(rows, k):
    rows = [list(r) for r in rows]
    for b0 in range(0, len(rows), k):
        blk = list(range(b0, min(b0 + k, len(rows))))
        while True:
            lens = [len(rows[r]) for r in blk]
            imax = blk[int(np.argmax(lens))]  # argmax/argmin take the first (lowest index) on ties
            imin = blk[int(np.argmin(lens))]
            if len(rows[imax]) - len(rows[imin]) <= 1:
                break
            rows[imin].append(rows[imax].pop())
    return rows


MASKS = {
    "random30": lambda r: r.random((45, 67)) < 0.3,
    "foveated": lambda r: r.random((45, 67)) < np.clip(
        1.0 - np.hypot(*np.meshgrid(np.arange(67) - 20, np.arange(45) - 30)) / 40.0, 0.05, 1.0),
    "empty": lambda r: np.zeros((45, 67), bool),
    "full": lambda r: np.ones((45, 67), bool),
}


@pytest.mark.parametrize("kind", list(MASKS))
def test_compact_row_and_tile(kind, device, rng):
    m = MASKS[kind](rng)
    row = fw.ops.compact(m, order="row", device=device)
    np.testing.assert_array_equal(row, np.flatnonzero(m))
    tile = fw.ops.compact(m, order="tile", tile=8, device=device)
    np.testing.assert_array_equal(tile, tile_order_ref(m, 8))
    assert len(np.unique(tile)) == len(tile) == m.sum()


@pytest.mark.parametrize("kind", list(MASKS))
@pytest.mark.parametrize("k", [0, 1, 4, 8])
def test_reorder_rows_strategies(kind, k, device, rng):
    m = MASKS[kind](rng)
    coords, counts = fw.ops.reorder_rows(m, balance_rows=k, device=device)
    ref = rows_ref(m)
    if k:
        ref = balance_ref(ref, k)
    np.testing.assert_array_equal(counts, [len(r) for r in ref])
    for y, r in enumerate(ref):
        np.testing.assert_array_equal(coords[y, : len(r)], np.array(r, dtype=np.int32).reshape(-1, 2))
    # every sampled pixel appears exactly once
    allc = np.concatenate([coords[y, : counts[y]] for y in range(m.shape[0])]) if counts.sum() else np.zeros((0, 2))
    got = np.sort(allc[:, 1].astype(np.int64) * m.shape[1] + allc[:, 0]) if len(allc) else np.zeros(0)
    np.testing.assert_array_equal(got, np.flatnonzero(m))
    if k:
        for b0 in range(0, m.shape[0], k):
            c = counts[b0:b0 + k]
            assert c.max() - c.min() <= 1


@settings(max_examples=40, deadline=None)
@given(arrays(np.bool_, st.tuples(st.integers(1, 19), st.integers(1, 23))), st.integers(1, 5))
def test_compaction_properties(mask, k):
    row = fw.ops.compact(mask, order="row", device="cpu")
    np.testing.assert_array_equal(row, np.flatnonzero(mask))
    tile = fw.ops.compact(mask, order="tile", tile=4, device="cpu")
    np.testing.assert_array_equal(np.sort(tile), np.flatnonzero(mask))
    _, counts = fw.ops.reorder_rows(mask, balance_rows=k, device="cpu")
    assert counts.sum() == mask.sum()


def test_count_stays_on_device_and_list_is_capacity_sized(device, rng):
    m = rng.random((30, 40)) < 0.2
    st_ = ReorderStage(40, 30, fw.ReorderConfig(strategy="tile"), device)
    st_.run(wp.array(m.astype(np.uint8), dtype=wp.uint8, device=device))
    assert st_.work.shape[0] == 1200 and isinstance(st_.count, wp.array)
    assert int(st_.count.numpy()[0]) == m.sum()


def test_bad_arguments():
    with pytest.raises(ValueError, match="order"):
        fw.ops.compact(np.ones((4, 4)), order="zigzag")
    with pytest.raises(ValueError, match="mask"):
        fw.ops.compact(np.ones(4))
    with pytest.raises(ValueError, match="balance_rows"):
        fw.ops.reorder_rows(np.ones((4, 4)), balance_rows=-1)


# -- count + one-block scan + scatter, block-local prefix sums --------------------------------------------


def filled_mask(h, w, rng):
    """~95 % set, a few clustered holes (what the temporal fill leaves), plus sparse samples inside them."""
    m = np.ones((h, w), bool)
    for _ in range(5):
        y, x = rng.integers(h), rng.integers(w)
        m[max(0, y - 3):y + 4, max(0, x - 6):x + 7] = False
    return m | (rng.random((h, w)) < 0.1)


@pytest.mark.parametrize("tile", [2, 4, 8, 16, 64])
@pytest.mark.parametrize("shape", [(45, 67), (130, 70), (1, 300), (300, 1), (64, 64)])
def test_compact_many_blocks_and_partial_tiles(tile, shape, device, rng):
    """Images larger than a compaction block (256 x 4 positions on CUDA, 256 on the CPU) and tiles that do
    not divide the image: exactly the reference order."""
    h, w = shape
    for m in (filled_mask(h, w, rng), rng.random((h, w)) < 0.3, np.ones((h, w), bool), np.zeros((h, w), bool)):
        np.testing.assert_array_equal(fw.ops.compact(m, order="tile", tile=tile, device=device),
                                      tile_order_ref(m, tile))
    np.testing.assert_array_equal(fw.ops.compact(m, order="row", device=device), np.flatnonzero(m))


def test_stage_reuse_and_strategy_switch(device, rng):
    """One stage, masks that change every frame and strategies switched per call (the frame loop compacts a
    "scan" list after a "rows" one): every result equals the reference; the count is exact each time."""
    h, w = 70, 90
    st_ = ReorderStage(w, h, fw.ReorderConfig(strategy="tile", tile=8), device)
    for i, m in enumerate([filled_mask(h, w, rng), rng.random((h, w)) < 0.05, np.zeros((h, w), bool),
                           np.ones((h, w), bool), rng.random((h, w)) < 0.5]):
        mk = wp.array(m.astype(np.uint8), dtype=wp.uint8, device=device)
        for s in ("tile", "scan", "rows", "rows+balance", "tile"):
            st_.run(mk, strategy=s)
            if s in ("tile", "scan"):
                n = int(st_.count.numpy()[0])
                ref = tile_order_ref(m, 8) if s == "tile" else np.flatnonzero(m)
                np.testing.assert_array_equal(st_.work.numpy()[:n], ref)
            else:
                counts = st_.counts.numpy()
                ref = rows_ref(m)
                if s == "rows+balance":
                    ref = balance_ref(ref, st_.config.balance_rows)
                np.testing.assert_array_equal(counts, [len(r) for r in ref])
                coords = st_.coords.numpy()
                for y, r in enumerate(ref):
                    np.testing.assert_array_equal(coords[y, :len(r)], np.array(r, np.int32).reshape(-1, 2))


@settings(max_examples=50, deadline=None)
@given(arrays(np.bool_, st.tuples(st.integers(1, 40), st.integers(1, 40))),
       st.sampled_from([2, 4, 8, 16, 32, 64]), st.sampled_from(["random", "filled", "empty", "full"]))
def test_compaction_exact_order_properties(mask, tile, kind):
    h, w = mask.shape
    if kind == "filled":
        mask = mask | (np.add.outer(np.arange(h), np.arange(w)) % 7 != 0)
    elif kind == "empty":
        mask = np.zeros_like(mask)
    elif kind == "full":
        mask = np.ones_like(mask)
    np.testing.assert_array_equal(fw.ops.compact(mask, order="tile", tile=tile, device="cpu"),
                                  tile_order_ref(mask, tile))
    np.testing.assert_array_equal(fw.ops.compact(mask, order="row", device="cpu"), np.flatnonzero(mask))
    coords, counts = fw.ops.reorder_rows(mask, device="cpu")
    np.testing.assert_array_equal(counts, mask.sum(axis=1))
    for y in range(h):
        np.testing.assert_array_equal(coords[y, :counts[y], 0], np.flatnonzero(mask[y]))
        assert np.all(coords[y, :counts[y], 1] == y)


def _words_run(stage, m, strategy, packed):
    """The stage's list and count for uint8 mask ``m`` with the word kernels on (``packed``) or off."""
    stage.packed = packed
    mk = wp.array(np.ascontiguousarray(m, dtype=np.uint8), dtype=wp.uint8, device=stage.device)
    stage.run(mk, strategy=strategy)
    n = int(stage.count.numpy()[0])
    return stage.work.numpy()[:n]


@pytest.mark.parametrize("shape", [(45, 64), (130, 72), (1, 8), (300, 8), (64, 64), (17, 264)])
def test_compaction_by_words_equals_reference(shape, device, rng):
    """The 8-pixel-word kernels (CUDA's default where the width is a multiple of 8): the reference order for
    "tile" (8 x 8 tiles, partial bottom tiles included) and "scan", for sparse, filled, full and empty masks and
    for mask bytes other than 0 / 1 (any nonzero byte is a sample), on every device."""
    h, w = shape
    stage = ReorderStage(w, h, fw.ReorderConfig(strategy="tile", tile=8), device)
    assert stage._word_blocks, "the word kernels apply at this width"
    values = rng.integers(1, 256, (h, w)).astype(np.uint8)  # nonzero bytes of every value
    for m in (filled_mask(h, w, rng), rng.random((h, w)) < 0.3, rng.random((h, w)) < 0.02, np.ones((h, w), bool),
              np.zeros((h, w), bool)):
        mb = np.where(m, values, 0).astype(np.uint8)
        for s, ref in (("tile", tile_order_ref(m, 8)), ("scan", np.flatnonzero(m))):
            np.testing.assert_array_equal(_words_run(stage, mb, s, True), ref)
            np.testing.assert_array_equal(_words_run(stage, mb, s, False), ref)


@settings(max_examples=40, deadline=None)
@given(arrays(np.uint8, st.tuples(st.integers(1, 30), st.integers(1, 6).map(lambda k: 8 * k))),
       st.sampled_from(["tile", "scan"]))
def test_compaction_by_words_properties(mask, strategy):
    """Any bytes, any height, widths that are multiples of 8: the word kernels give the byte kernels' list."""
    h, w = mask.shape
    stage = ReorderStage(w, h, fw.ReorderConfig(strategy=strategy, tile=8), "cpu")
    ref = tile_order_ref(mask != 0, 8) if strategy == "tile" else np.flatnonzero(mask)
    np.testing.assert_array_equal(_words_run(stage, mask, strategy, True), ref)


def test_compaction_by_words_only_where_it_applies(rng):
    """Widths that are not a multiple of 8, other tile sizes and non-contiguous masks take the byte kernels
    (same list); a new mask array gets its own word view."""
    st_ = ReorderStage(70, 20, fw.ReorderConfig(strategy="tile", tile=8), "cpu")
    assert not st_._word_blocks
    m = rng.random((20, 70)) < 0.3
    np.testing.assert_array_equal(_words_run(st_, m, "tile", True), tile_order_ref(m, 8))
    st4 = ReorderStage(64, 20, fw.ReorderConfig(strategy="tile", tile=4), "cpu")
    m = rng.random((20, 64)) < 0.3
    np.testing.assert_array_equal(_words_run(st4, m, "tile", True), tile_order_ref(m, 4))
    st8 = ReorderStage(64, 20, fw.ReorderConfig(strategy="tile", tile=8), "cpu")
    st8.packed = True
    big = wp.array(np.zeros((20, 128), np.uint8), dtype=wp.uint8, device="cpu")
    strided = big[:, ::2]
    assert not strided.is_contiguous
    st8.run(strided)
    assert int(st8.count.numpy()[0]) == 0
    for _ in range(2):  # two masks in turn: each compacted from its own bytes
        m1, m2 = rng.random((20, 64)) < 0.2, rng.random((20, 64)) < 0.6
        np.testing.assert_array_equal(_words_run(st8, m1, "tile", True), tile_order_ref(m1, 8))
        np.testing.assert_array_equal(_words_run(st8, m2, "tile", True), tile_order_ref(m2, 8))


# -- the second mask (``keep``): the frame loop lists only the sampled pixels that hit a surface -----------


def _keep_run(stage, m, k, strategy):
    """(work list or row CSR) of the stage for uint8 masks ``m`` and ``k`` (``keep``)."""
    dev = stage.device
    mk = wp.array(np.ascontiguousarray(m, dtype=np.uint8), dtype=wp.uint8, device=dev)
    kk = wp.array(np.ascontiguousarray(k, dtype=np.uint8), dtype=wp.uint8, device=dev)
    stage.run(mk, strategy=strategy, keep=kk)
    if strategy in ("tile", "scan"):
        return stage.work.numpy()[:int(stage.count.numpy()[0])]
    return stage.coords.numpy(), stage.counts.numpy()


@pytest.mark.parametrize("packed", [True, False])
@pytest.mark.parametrize("shape", [(45, 64), (130, 72), (1, 8), (37, 50)])
def test_compaction_keep_equals_reference(shape, packed, device, rng):
    """``run(mask, keep=k)`` lists exactly the pixels set in both, in the reference order, for every strategy,
    by words (where the width allows) and by bytes; bytes other than 0 / 1 count as set in both masks."""
    h, w = shape
    stage = ReorderStage(w, h, fw.ReorderConfig(strategy="tile", tile=8), device)
    stage.packed = packed
    vm = rng.integers(1, 256, (h, w)).astype(np.uint8)
    vk = rng.integers(1, 256, (h, w)).astype(np.uint8)
    for m, k in ((rng.random((h, w)) < 0.3, rng.random((h, w)) < 0.6),
                 (filled_mask(h, w, rng), rng.random((h, w)) < 0.5), (np.ones((h, w), bool), np.zeros((h, w), bool)), (np.ones((h, w), bool), np.ones((h, w), bool))):
        mb, kb = np.where(m, vm, 0), np.where(k, vk, 0)
        both = m & k
        np.testing.assert_array_equal(_keep_run(stage, mb, kb, "tile"), tile_order_ref(both, 8))
        np.testing.assert_array_equal(_keep_run(stage, mb, kb, "scan"), np.flatnonzero(both))
        for s in ("rows", "rows+balance"):
            coords, counts = _keep_run(stage, mb, kb, s)
            ref = rows_ref(both)
            if s == "rows+balance":
                ref = balance_ref(ref, stage.config.balance_rows)
            np.testing.assert_array_equal(counts, [len(r) for r in ref])
            for y, r in enumerate(ref):
                np.testing.assert_array_equal(coords[y, :len(r)], np.array(r, np.int32).reshape(-1, 2))
        # the same stage without keep: every set pixel of the mask again (no state left from the keep run)
        stage.run(wp.array(mb, dtype=wp.uint8, device=device), strategy="tile")
        np.testing.assert_array_equal(stage.work.numpy()[:int(stage.count.numpy()[0])], tile_order_ref(m, 8))


@settings(max_examples=40, deadline=None)
@given(arrays(np.uint8, st.tuples(st.integers(1, 24), st.integers(1, 5).map(lambda k: 8 * k))),
       st.integers(0, 2**32 - 1), st.sampled_from(["tile", "scan"]))
def test_compaction_keep_properties(mask, seed, strategy):
    """Any bytes in both masks: the word kernels and the byte kernels list the pixels set in both."""
    h, w = mask.shape
    keep = np.random.default_rng(seed).integers(0, 3, (h, w)).astype(np.uint8)
    stage = ReorderStage(w, h, fw.ReorderConfig(strategy=strategy, tile=8), "cpu")
    both = (mask != 0) & (keep != 0)
    ref = tile_order_ref(both, 8) if strategy == "tile" else np.flatnonzero(both)
    for packed in (True, False):
        stage.packed = packed
        np.testing.assert_array_equal(_keep_run(stage, mask, keep, strategy), ref)


def test_compaction_keep_bad_arguments():
    st_ = ReorderStage(16, 8, fw.ReorderConfig(strategy="tile"), "cpu")
    m = wp.zeros((8, 16), dtype=wp.uint8, device="cpu")
    for bad in (np.ones((8, 16), np.uint8), wp.zeros((8, 15), dtype=wp.uint8, device="cpu"),
                wp.zeros((8, 16), dtype=wp.int32, device="cpu")):
        with pytest.raises(ValueError, match="keep must be a \\(8, 16\\) uint8"):
            st_.run(m, keep=bad)
    with pytest.raises(ValueError, match="ReorderConfig.skip_misses"):
        fw.ReorderConfig(skip_misses="yes")
