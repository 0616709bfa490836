"""The unchecked native loads and stores of kernels/load.py against NumPy indexing, on contiguous and strided
views."""

import numpy as np
import pytest
import warp as wp

from foveawarp.kernels.load import (load1_vec3, load_i32, load_u8, load_vec3, store_i32, store_vec2i,
                                   store_vec3)


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
