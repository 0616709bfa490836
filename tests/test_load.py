"""The unchecked native loads and stores of kernels/load.py against NumPy indexing, on contiguous and strided
views."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
import warp as wp

from foveawarp.kernels.load import (load1_i32, load1_u8, load1_vec3, load_f32, load_i32, load_u8, load_vec2, load_vec3,
                                   nine_equal_i32, nine_equal_mask64_i32, nine_equal_mask64_vec3, nine_equal_vec3,
                                   store1_i32, store1_vec3, store_f32, store_i32,
                                   store_u8, store_vec2, store_vec2i, store_vec3)


@wp.kernel(enable_backward=False)
def _gather2d(a3: wp.array2d(dtype=wp.vec3), ai: wp.array2d(dtype=wp.int32), ys: wp.array(dtype=wp.int32),
              xs: wp.array(dtype=wp.int32), out3: wp.array(dtype=wp.vec3), outi: wp.array(dtype=wp.int32)):
    i = wp.tid()
    out3[i] = load_vec3(a3, ys[i], xs[i])
    outi[i] = load_i32(ai, ys[i], xs[i])


@wp.kernel(enable_backward=False)
def _copy_through(a8: wp.array2d(dtype=wp.uint8), a3: wp.array2d(dtype=wp.vec3), ai: wp.array2d(dtype=wp.int32),
                  o3: wp.array2d(dtype=wp.vec3), oi: wp.array2d(dtype=wp.int32), o2: wp.array2d(dtype=wp.vec2i)):
    y, x = wp.tid()
    store_vec3(o3, y, x, load_vec3(a3, y, x))
    store_i32(oi, y, x, load_i32(ai, y, x) + int(load_u8(a8, y, x)))
    store_vec2i(o2, y, x, wp.vec2i(x, y))


@wp.kernel(enable_backward=False)
def _gather1d(a: wp.array(dtype=wp.vec3), idx: wp.array(dtype=wp.int32), out: wp.array(dtype=wp.vec3)):
    i = wp.tid()
    out[i] = load1_vec3(a, idx[i])


@pytest.mark.parametrize("view", ["contiguous", "strided"])
def test_loads_equal_numpy_indexing(device, view):
    rng = np.random.default_rng(4)
    big3 = rng.normal(size=(23, 34, 3)).astype(np.float32)
    bigi = rng.integers(-2**31, 2**31 - 1, size=(23, 34), dtype=np.int64).astype(np.int32)
    a3 = wp.array(big3, dtype=wp.vec3, device=device)
    ai = wp.array(bigi, dtype=wp.int32, device=device)
    n3, ni = big3, bigi
    if view == "strided":  # rows 2.. every 3rd, columns 1.. every 2nd: strides other than the element size
        a3, ai = a3[2::3, 1::2], ai[2::3, 1::2]
        n3, ni = big3[2::3, 1::2], bigi[2::3, 1::2]
        assert not a3.is_contiguous
    h, w = ni.shape
    ys, xs = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
    ys, xs = ys.ravel().astype(np.int32), xs.ravel().astype(np.int32)
    out3 = wp.zeros(ys.size, dtype=wp.vec3, device=device)
    outi = wp.zeros(ys.size, dtype=wp.int32, device=device)
    wp.launch(_gather2d, dim=ys.size, inputs=[a3, ai, wp.array(ys, device=device), wp.array(xs, device=device)],
              outputs=[out3, outi], device=device)
    np.testing.assert_array_equal(out3.numpy(), n3[ys, xs])
    np.testing.assert_array_equal(outi.numpy(), ni[ys, xs])

    table = rng.normal(size=(40, 3)).astype(np.float32)
    t = wp.array(table, dtype=wp.vec3, device=device)
    nt = table
    if view == "strided":
        t, nt = t[1::3], table[1::3]
    idx = rng.integers(0, nt.shape[0], size=200).astype(np.int32)
    out = wp.zeros(idx.size, dtype=wp.vec3, device=device)
    wp.launch(_gather1d, dim=idx.size, inputs=[t, wp.array(idx, device=device)], outputs=[out], device=device)
    np.testing.assert_array_equal(out.numpy(), nt[idx])


@pytest.mark.parametrize("view", ["contiguous", "strided"])
def test_stores_write_only_their_element(device, view):
    """Each store writes its element of a (possibly strided) view and nothing else of the array behind it."""
    rng = np.random.default_rng(9)
    H, W = 19, 27
    big8 = rng.integers(0, 256, size=(H, W), dtype=np.int64).astype(np.uint8)
    big3 = rng.normal(size=(H, W, 3)).astype(np.float32)
    bigi = rng.integers(-1000, 1000, size=(H, W)).astype(np.int32)
    sl = (slice(1, None, 2), slice(2, None, 3)) if view == "strided" else (slice(None), slice(None))
    a8 = wp.array(big8, dtype=wp.uint8, device=device)[sl]
    a3 = wp.array(big3, dtype=wp.vec3, device=device)[sl]
    ai = wp.array(bigi, dtype=wp.int32, device=device)[sl]
    fill3 = np.full((H, W, 3), -7.0, np.float32)
    filli = np.full((H, W), -7, np.int32)
    fill2 = np.full((H, W, 2), -7, np.int32)
    o3b = wp.array(fill3, dtype=wp.vec3, device=device)
    oib = wp.array(filli, dtype=wp.int32, device=device)
    o2b = wp.array(fill2, dtype=wp.vec2i, device=device)
    o3, oi, o2 = o3b[sl], oib[sl], o2b[sl]
    h, w = a8.shape
    wp.launch(_copy_through, dim=(h, w), inputs=[a8, a3, ai], outputs=[o3, oi, o2], device=device)
    exp3, expi, exp2 = fill3.copy(), filli.copy(), fill2.copy()
    exp3[sl] = big3[sl]
    expi[sl] = bigi[sl] + big8[sl].astype(np.int32)
    ys, xs = np.mgrid[0:h, 0:w]
    exp2[sl] = np.stack([xs, ys], -1)
    np.testing.assert_array_equal(o3b.numpy(), exp3)
    np.testing.assert_array_equal(oib.numpy(), expi)
    np.testing.assert_array_equal(o2b.numpy(), exp2)


@wp.kernel(enable_backward=False)
def _copy_more(af: wp.array2d(dtype=float), a2: wp.array2d(dtype=wp.vec2), a8: wp.array2d(dtype=wp.uint8),
               of: wp.array2d(dtype=float), o2: wp.array2d(dtype=wp.vec3), o8: wp.array2d(dtype=wp.uint8)):
    y, x = wp.tid()
    store_f32(of, y, x, load_f32(af, y, x))
    v = load_vec2(a2, y, x)
    store_vec3(o2, y, x, wp.vec3(v[0], v[1], 0.0))
    store_u8(o8, y, x, load_u8(a8, y, x))


@wp.kernel(enable_backward=False)
def _copy_flat(ai: wp.array(dtype=wp.int32), a3: wp.array(dtype=wp.vec3), idx: wp.array(dtype=wp.int32),
               oi: wp.array(dtype=wp.int32), o3: wp.array(dtype=wp.vec3)):
    k = wp.tid()
    i = idx[k]
    store1_i32(oi, i, load1_i32(ai, i))
    store1_vec3(o3, i, load1_vec3(a3, i))


@wp.kernel(enable_backward=False)
def _vec2_store_u8_gather(a2: wp.array2d(dtype=wp.vec2), f8: wp.array(dtype=wp.uint8), idx: wp.array(dtype=wp.int32),
                          o2: wp.array2d(dtype=wp.vec2), o8: wp.array2d(dtype=wp.uint8)):
    y, x = wp.tid()
    store_vec2(o2, y, x, load_vec2(a2, y, x))
    store_u8(o8, y, x, load1_u8(f8, idx[y * a2.shape[1] + x]))


@pytest.mark.parametrize("view", ["contiguous", "strided"])
def test_vec2_store_and_flat_u8_load(device, view):
    """``store_vec2`` writes its element of a (possibly strided) view and nothing else; ``load1_u8`` reads the
    element NumPy indexing reads (the G-buffer's stores and its per-face smooth flags)."""
    rng = np.random.default_rng(21)
    H, W = 13, 22
    sl = (slice(1, None, 2), slice(0, None, 3)) if view == "strided" else (slice(None), slice(None))
    b2 = rng.normal(size=(H, W, 2)).astype(np.float32)
    a2 = wp.array(b2, dtype=wp.vec2, device=device)[sl]
    o2b = wp.array(np.full((H, W, 2), -9.0, np.float32), dtype=wp.vec2, device=device)
    o8b = wp.array(np.full((H, W), 3, np.uint8), dtype=wp.uint8, device=device)
    flags = rng.integers(0, 256, size=150, dtype=np.int64).astype(np.uint8)
    f8 = wp.array(flags, dtype=wp.uint8, device=device)
    nf = flags
    if view == "strided":
        f8, nf = f8[2::5], flags[2::5]
    h, w = a2.shape
    idx = rng.integers(0, nf.shape[0], size=h * w).astype(np.int32)
    wp.launch(_vec2_store_u8_gather, dim=(h, w), inputs=[a2, f8, wp.array(idx, device=device)],
              outputs=[o2b[sl], o8b[sl]], device=device)
    e2 = np.full((H, W, 2), -9.0, np.float32)
    e2[sl] = b2[sl]
    e8 = np.full((H, W), 3, np.uint8)
    e8[sl] = nf[idx].reshape(h, w)
    np.testing.assert_array_equal(o2b.numpy(), e2)
    np.testing.assert_array_equal(o8b.numpy(), e8)


@pytest.mark.parametrize("view", ["contiguous", "strided"])
def test_float_vec2_u8_and_flat_loads_and_stores(device, view):
    """The float, vec2 and uint8 loads and stores (2D) and the flat int32 / vec3 ones, element for element and
    nothing else written, on contiguous and strided views."""
    rng = np.random.default_rng(13)
    H, W = 17, 29
    sl = (slice(2, None, 2), slice(1, None, 3)) if view == "strided" else (slice(None), slice(None))
    bf = rng.normal(size=(H, W)).astype(np.float32)
    b2 = rng.normal(size=(H, W, 2)).astype(np.float32)
    b8 = rng.integers(0, 256, size=(H, W), dtype=np.int64).astype(np.uint8)
    af = wp.array(bf, dtype=float, device=device)[sl]
    a2 = wp.array(b2, dtype=wp.vec2, device=device)[sl]
    a8 = wp.array(b8, dtype=wp.uint8, device=device)[sl]
    ofb = wp.array(np.full((H, W), -3.0, np.float32), dtype=float, device=device)
    o2b = wp.array(np.full((H, W, 3), -3.0, np.float32), dtype=wp.vec3, device=device)
    o8b = wp.array(np.full((H, W), 7, np.uint8), dtype=wp.uint8, device=device)
    h, w = af.shape
    wp.launch(_copy_more, dim=(h, w), inputs=[af, a2, a8], outputs=[ofb[sl], o2b[sl], o8b[sl]], device=device)
    ef, e2, e8 = np.full((H, W), -3.0, np.float32), np.full((H, W, 3), -3.0, np.float32), np.full((H, W), 7, np.uint8)
    ef[sl] = bf[sl]
    e2[sl] = np.concatenate([b2[sl], np.zeros(b2[sl].shape[:2] + (1,), np.float32)], -1)
    e8[sl] = b8[sl]
    np.testing.assert_array_equal(ofb.numpy(), ef)
    np.testing.assert_array_equal(o2b.numpy(), e2)
    np.testing.assert_array_equal(o8b.numpy(), e8)

    n = 60
    bi = rng.integers(-10**6, 10**6, size=3 * n).astype(np.int32)
    b3 = rng.normal(size=(3 * n, 3)).astype(np.float32)
    fl = slice(1, None, 3) if view == "strided" else slice(0, n)
    ai = wp.array(bi, dtype=wp.int32, device=device)[fl]
    a3 = wp.array(b3, dtype=wp.vec3, device=device)[fl]
    oib = wp.array(np.full(3 * n, -5, np.int32), dtype=wp.int32, device=device)
    o3b = wp.array(np.full((3 * n, 3), -5.0, np.float32), dtype=wp.vec3, device=device)
    idx = rng.permutation(ai.shape[0])[: ai.shape[0] // 2].astype(np.int32)  # half of the elements
    wp.launch(_copy_flat, dim=idx.size, inputs=[ai, a3, wp.array(idx, device=device)], outputs=[oib[fl], o3b[fl]],
              device=device)
    ei, e3 = np.full(3 * n, -5, np.int32), np.full((3 * n, 3), -5.0, np.float32)
    pos = np.arange(3 * n)[fl][idx]
    ei[pos] = bi[pos]
    e3[pos] = b3[pos]
    np.testing.assert_array_equal(oib.numpy(), ei)
    np.testing.assert_array_equal(o3b.numpy(), e3)


@wp.kernel(enable_backward=False)
def _nine_equal(a3: wp.array2d(dtype=wp.vec3), ai: wp.array2d(dtype=wp.int32), o3: wp.array2d(dtype=wp.int32),
                oi: wp.array2d(dtype=wp.int32)):
    y, x = wp.tid()
    o3[y, x] = nine_equal_vec3(a3, y, x)
    oi[y, x] = nine_equal_i32(ai, y, x)


def _nine_equal_reference(a, contiguous):
    """NumPy: 1 where the pixel is in an interior column of a row-contiguous array, and its 3x3 neighbourhood (rows
    clamped) holds nine bitwise-equal values, none of them NaN (for floats); else 0."""
    h, w = a.shape[:2]
    bits = a.view(np.uint32).reshape(h, w, -1)
    out = np.zeros((h, w), np.int32)
    if not contiguous:
        return out
    for y in range(h):
        rows = [max(y - 1, 0), y, min(y + 1, h - 1)]
        for x in range(1, w - 1):
            taps = bits[rows][:, x - 1:x + 2].reshape(9, -1)
            ok = (taps == bits[y, x]).all()
            if a.dtype == np.float32 and np.isnan(a[y, x]).any():
                ok = False
            out[y, x] = int(ok)
    return out


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), h=st.integers(1, 7), w=st.integers(1, 9), levels=st.integers(1, 3),
       strided=st.booleans())
def test_nine_equal_tests_against_numpy(seed, h, w, levels, strided):
    """The CPU's word compares of the Sobel terms' "nine taps equal" test (kernels/load.py) against NumPy, on
    images of few distinct values (so that flat neighbourhoods occur), with +0 / -0 and NaN among them; a strided
    view, a border column or CUDA answers 0, and a 1 is only ever given where every float compare is true."""
    rng = np.random.default_rng(seed)
    pal3 = np.array([[0.0, 0.0, 1.0], [-0.0, 0.0, 1.0], [np.nan, 0.0, 0.0], [0.5, 0.25, -1.0]], np.float32)
    big3 = pal3[rng.integers(0, levels + 1, size=(h * 2, w * 2))]
    bigi = rng.integers(-1, levels, size=(h * 2, w * 2)).astype(np.int32)
    a3 = wp.array(big3, dtype=wp.vec3, device="cpu")
    ai = wp.array(bigi, dtype=wp.int32, device="cpu")
    n3, ni = big3, bigi
    if strided:
        a3, ai, n3, ni = a3[::2, ::2], ai[::2, ::2], big3[::2, ::2], bigi[::2, ::2]
    else:
        a3, ai, n3, ni = a3[:h, :w], ai[:h, :w], big3[:h, :w], bigi[:h, :w]
    o3 = wp.zeros(n3.shape[:2], dtype=wp.int32, device="cpu")
    oi = wp.zeros(ni.shape, dtype=wp.int32, device="cpu")
    wp.launch(_nine_equal, dim=ni.shape, inputs=[a3, ai], outputs=[o3, oi], device="cpu")
    got3, goti = o3.numpy(), oi.numpy()
    np.testing.assert_array_equal(got3, _nine_equal_reference(np.ascontiguousarray(n3), not strided))
    np.testing.assert_array_equal(goti, _nine_equal_reference(np.ascontiguousarray(ni), not strided))
    # soundness: a 1 only where all nine float compares with the centre hold
    for y, x in zip(*np.nonzero(got3)):
        rows = [max(y - 1, 0), y, min(y + 1, n3.shape[0] - 1)]
        assert (n3[rows][:, x - 1:x + 2] == n3[y, x]).all()


def test_nine_equal_tests_answer_zero_on_cuda():
    """The CUDA build of the word compares answers 0 everywhere (the element compares then decide, as before), even
    on an image of one value. It needs a CUDA device to run that build (skipped elsewhere)."""
    if not wp.is_cuda_available():
        pytest.skip("needs a CUDA device")
    a3 = wp.zeros((4, 5), dtype=wp.vec3, device="cuda:0")
    ai = wp.zeros((4, 5), dtype=wp.int32, device="cuda:0")
    o3 = wp.full((4, 5), 7, dtype=wp.int32, device="cuda:0")
    oi = wp.full((4, 5), 7, dtype=wp.int32, device="cuda:0")
    wp.launch(_nine_equal, dim=(4, 5), inputs=[a3, ai], outputs=[o3, oi], device="cuda:0")
    assert (o3.numpy() == 0).all() and (oi.numpy() == 0).all()


@wp.kernel(enable_backward=False)
def _nine_equal_masks(a3: wp.array2d(dtype=wp.vec3), ai: wp.array2d(dtype=wp.int32), o3: wp.array2d(dtype=wp.int32),
                      oi: wp.array2d(dtype=wp.int32)):
    # a thread per row: each 64-pixel mask unpacked into the row, the bits past the row must be 0
    y = wp.tid()
    w = o3.shape[1]
    for x0 in range(0, w + 64, 64):
        m3 = nine_equal_mask64_vec3(a3, y, x0)
        mi = nine_equal_mask64_i32(ai, y, x0)
        for i in range(64):
            b3 = int((m3 >> wp.uint64(i)) & wp.uint64(1))
            bi = int((mi >> wp.uint64(i)) & wp.uint64(1))
            if x0 + i < w:
                o3[y, x0 + i] = b3
                oi[y, x0 + i] = bi
            elif b3 != 0 or bi != 0:
                o3[y, 0] = -1  # a bit past the row


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), h=st.integers(1, 6), w=st.integers(1, 200), levels=st.integers(1, 3),
       strided=st.booleans(), flat_rows=st.booleans())
def test_nine_equal_masks_against_numpy(seed, h, w, levels, strided, flat_rows):
    """The 64-pixel masks of the same tests (the sampling rows kernel's) against the NumPy reference, bit for bit,
    over widths of one to four masks (chunk edges, the last partial chunk, widths 1 and 2 with no interior column),
    +0 / -0 and NaN among the values, long flat runs (``flat_rows``: one value per row band), and strided views
    (all 0)."""
    rng = np.random.default_rng(seed)
    pal3 = np.array([[0.0, 0.0, 1.0], [-0.0, 0.0, 1.0], [np.nan, 0.0, 0.0], [0.5, 0.25, -1.0]], np.float32)
    if flat_rows:
        idx = np.repeat(rng.integers(0, levels + 1, size=(h * 2, 1)), w * 2, axis=1)
        idx[rng.random(idx.shape) < 0.03] = levels  # a few odd pixels in the runs
    else:
        idx = rng.integers(0, levels + 1, size=(h * 2, w * 2))
    big3 = pal3[idx]
    bigi = (idx - 1).astype(np.int32)
    a3 = wp.array(big3, dtype=wp.vec3, device="cpu")
    ai = wp.array(bigi, dtype=wp.int32, device="cpu")
    if strided:
        a3, ai, n3, ni = a3[::2, ::2], ai[::2, ::2], big3[::2, ::2], bigi[::2, ::2]
    else:
        a3, ai, n3, ni = a3[:h, :w], ai[:h, :w], big3[:h, :w], bigi[:h, :w]
    o3 = wp.zeros(ni.shape, dtype=wp.int32, device="cpu")
    oi = wp.zeros(ni.shape, dtype=wp.int32, device="cpu")
    wp.launch(_nine_equal_masks, dim=ni.shape[0], inputs=[a3, ai], outputs=[o3, oi], device="cpu")
    np.testing.assert_array_equal(o3.numpy(), _nine_equal_reference(np.ascontiguousarray(n3), not strided))
    np.testing.assert_array_equal(oi.numpy(), _nine_equal_reference(np.ascontiguousarray(ni), not strided))


@pytest.mark.parametrize("w", [1, 2, 3, 63, 64, 65, 66, 130, 200])
@pytest.mark.parametrize("value", [(0.0, 0.0, 1.0), (-0.0, 0.0, 1.0), (np.nan, 0.0, 0.0), (0.0, np.inf, 0.0)])
def test_nine_equal_masks_on_one_value(w, value):
    """An image of one value: every interior column passes (the chunk edges at 63/64/65 included), except a NaN
    value, which never passes (its float compares are false); the integer mask of a constant image passes too."""
    h = 3
    n3 = np.broadcast_to(np.array(value, np.float32), (h, w, 3)).copy()
    ni = np.full((h, w), 7, np.int32)
    o3 = wp.zeros((h, w), dtype=wp.int32, device="cpu")
    oi = wp.zeros((h, w), dtype=wp.int32, device="cpu")
    wp.launch(_nine_equal_masks, dim=h, inputs=[wp.array(n3, dtype=wp.vec3, device="cpu"),
                                               wp.array(ni, device="cpu")], outputs=[o3, oi], device="cpu")
    interior = np.zeros((h, w), np.int32)
    interior[:, 1:w - 1] = 1
    np.testing.assert_array_equal(oi.numpy(), interior)
    np.testing.assert_array_equal(o3.numpy(), 0 * interior if np.isnan(value).any() else interior)
    np.testing.assert_array_equal(o3.numpy(), _nine_equal_reference(n3, True))
