"""The unchecked native loads of kernels/load.py against NumPy indexing, on contiguous and strided views."""

import numpy as np
import pytest
import warp as wp

from foveawarp.kernels.load import load1_vec3, load_i32, load_vec3


@wp.kernel(enable_backward=False)
def _gather2d(a3: wp.array2d(dtype=wp.vec3), ai: wp.array2d(dtype=wp.int32), ys: wp.array(dtype=wp.int32),
              xs: wp.array(dtype=wp.int32), out3: wp.array(dtype=wp.vec3), outi: wp.array(dtype=wp.int32)):
    i = wp.tid()
    out3[i] = load_vec3(a3, ys[i], xs[i])
    outi[i] = load_i32(ai, ys[i], xs[i])


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
